//! `fieldcal run`'s standard output as a pipe (written by the workers
//! without blocking) and as a file (written by a thread of its own): the
//! same lines either way, the pipe left as it was found, and a pipe
//! nobody reads never keeps the daemon from ending.

mod common;

use std::fs::File;
use std::io::Read;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use common::daemon::replay_config;

/// A pipe: (read end, write end), both closed on exec.
fn pipe() -> (File, OwnedFd) {
    let mut fds = [0; 2];
    // SAFETY: pipe2 writes two descriptors into the array it is given.
    let rc = unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) };
    assert_eq!(rc, 0, "pipe2: {}", std::io::Error::last_os_error());
    // SAFETY: both descriptors were just opened and are owned here alone.
    unsafe { (File::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) }
}

fn nonblocking(fd: &OwnedFd) -> bool {
    // SAFETY: fcntl on a descriptor owned here; no memory is touched.
    let flags = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_GETFL) };
    assert!(flags >= 0, "fcntl: {}", std::io::Error::last_os_error());
    flags & libc::O_NONBLOCK != 0
}

/// `fieldcal run` replaying `capture` at full speed, its own state, with
/// `stdout` as its standard output.
fn start(dir: &Path, capture: &Path, stdout: Stdio) -> Child {
    start_with(dir, capture, "\"max\"", stdout, Stdio::null())
}

fn start_with(dir: &Path, capture: &Path, speed: &str, stdout: Stdio, stderr: Stdio) -> Child {
    let config = replay_config(dir, capture, speed, "stdout = true");
    common::fieldcal()
        .args(["run", "--config"])
        .arg(&config)
        .stdout(stdout)
        .stderr(stderr)
        .spawn()
        .expect("fieldcal run starts")
}

/// Whether the pipe's mode was ever non-blocking while `child` ran (looked
/// at every 5 ms until it ended).
fn ever_nonblocking_while_running(child: &mut Child, kept: &OwnedFd) -> bool {
    let start = Instant::now();
    let mut seen = false;
    while child.try_wait().expect("waiting for fieldcal").is_none() {
        seen |= nonblocking(kept);
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "fieldcal run did not end"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    seen
}

/// Reads `file` to its end on a thread of its own.
fn read_all(mut file: File) -> std::thread::JoinHandle<std::io::Result<String>> {
    std::thread::spawn(move || {
        let mut text = String::new();
        file.read_to_string(&mut text).map(|_| text)
    })
}

fn wait(child: &mut Child, within: Duration) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("waiting for fieldcal") {
            return status;
        }
        if start.elapsed() > within {
            let _ = child.kill();
            panic!("fieldcal run did not end within {within:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Each published line's class and, for a READING, its raw axes (the
/// time is the host's clock, different on every run).
fn outline(text: &str) -> Vec<String> {
    text.lines()
        .map(|line| {
            let v: serde_json::Value = serde_json::from_str(line).expect("a JSON line");
            match v["class"].as_str() {
                Some("READING") => format!("READING {} {}", v["raw"], v["corrected"]),
                Some(class) => class.to_owned(),
                None => panic!("a line without a class: {line}"),
            }
        })
        .filter(|l| l != "STATUS")
        .collect()
}

#[test]
fn a_pipe_gets_the_lines_a_file_does_and_is_left_blocking() {
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");

    let file_dir = tempfile::tempdir().unwrap();
    let out_path = file_dir.path().join("out.jsonl");
    let file = File::create(&out_path).unwrap();
    let mut child = start(file_dir.path(), &capture, Stdio::from(file));
    assert!(wait(&mut child, Duration::from_secs(60)).success());
    let to_file = std::fs::read_to_string(&out_path).unwrap();

    let pipe_dir = tempfile::tempdir().unwrap();
    let (mut read_end, write_end) = pipe();
    // The test keeps a copy of the write end: the pipe's mode is shared.
    let kept = write_end.try_clone().unwrap();
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        read_end.read_to_string(&mut text).map(|_| text)
    });
    let mut child = start(pipe_dir.path(), &capture, Stdio::from(write_end));
    assert!(wait(&mut child, Duration::from_secs(60)).success());
    assert!(
        !nonblocking(&kept),
        "fieldcal left its standard output (a pipe) non-blocking"
    );
    drop(kept);
    let to_pipe = reader.join().unwrap().expect("the pipe reads to its end");

    let (by_file, by_pipe) = (outline(&to_file), outline(&to_pipe));
    assert!(by_file.iter().filter(|l| l.starts_with("READING")).count() > 300);
    assert_eq!(by_file.iter().filter(|l| *l == "CALIBRATION").count(), 1);
    assert_eq!(by_pipe, by_file);
}

#[test]
fn a_pipe_nobody_reads_does_not_keep_the_daemon_from_ending() {
    let dir = tempfile::tempdir().unwrap();
    // 4,000 frames: several times what a pipe holds in lines.
    let capture = dir.path().join("long.fcap");
    let sim = common::run(&[
        "simulate",
        "--format",
        "falcon",
        "--turns",
        "20",
        "-o",
        capture.to_str().unwrap(),
    ]);
    assert_eq!(sim.code, Some(0), "{}", sim.stderr);
    let (read_end, write_end) = pipe();
    let kept = write_end.try_clone().unwrap();
    let mut child = start(dir.path(), &capture, Stdio::from(write_end));
    // Never read: the replay ends, the writer's grace (1 s) runs out, and
    // the daemon ends with what the pipe could not take dropped.
    let status = wait(&mut child, Duration::from_secs(30));
    assert!(status.success(), "{status}");
    assert!(!nonblocking(&kept));
    drop(read_end);
}

/// What a daemon replaying the garbage capture at ten times real time
/// (about two seconds of readings) did to a pipe that is read to its end.
struct PipeRun {
    /// The pipe was non-blocking at some moment while the daemon ran.
    nonblocking_while_running: bool,
    /// The pipe was non-blocking after the daemon ended.
    nonblocking_after: bool,
    /// Everything the pipe carried.
    text: String,
}

/// Runs that daemon with its stdout a pipe; `stderr_too` gives it the same
/// pipe as stderr (`2>&1`).
fn run_into_pipe(stderr_too: bool) -> PipeRun {
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");
    let dir = tempfile::tempdir().unwrap();
    let (read_end, write_end) = pipe();
    let kept = write_end.try_clone().unwrap();
    let stderr = if stderr_too {
        Stdio::from(write_end.try_clone().unwrap())
    } else {
        Stdio::null()
    };
    let reader = read_all(read_end);
    let mut child = start_with(dir.path(), &capture, "10.0", Stdio::from(write_end), stderr);
    let nonblocking_while_running = ever_nonblocking_while_running(&mut child, &kept);
    assert!(child.wait().unwrap().success());
    let nonblocking_after = nonblocking(&kept);
    drop(kept);
    let text = reader.join().unwrap().unwrap();
    let readings = text.lines().filter(|l| l.contains("\"READING\"")).count();
    assert!(readings > 300, "{readings} readings");
    PipeRun {
        nonblocking_while_running,
        nonblocking_after,
        text,
    }
}

#[test]
fn a_pipe_is_written_without_blocking_while_the_daemon_runs() {
    let run = run_into_pipe(false);
    assert!(
        run.nonblocking_while_running,
        "the pipe was never made non-blocking: the writer thread wrote it"
    );
    assert!(!run.nonblocking_after, "the pipe's mode was not put back");
}

#[test]
fn a_pipe_that_is_stderr_too_is_never_made_non_blocking() {
    // `fieldcal run 2>&1 | …`: its log lines share the pipe, and a
    // non-blocking pipe would fail them when it is full.
    let run = run_into_pipe(true);
    assert!(!run.nonblocking_while_running);
    assert!(!run.nonblocking_after);
    assert!(
        run.text.contains("calibration accepted"),
        "the log shares the pipe"
    );
}
