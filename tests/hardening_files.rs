//! Special files where a regular file is expected, the Unix socket's file,
//! and the mode of a replaced output (issue 12, findings 1, 5, 8, 9).
//!
//! Every child runs under a time cap (and, for `/dev/zero`, a memory cap):
//! on code that blocks on a FIFO or reads a device without end, the test
//! fails at the cap instead of hanging the suite or filling the machine.

mod common;

use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, is_class, replay_config, wait_child};
use common::faults::long_capture;
use common::{fieldcal, shared_path};

/// Far above what a refusal takes; far below a hang.
const CAP: Duration = Duration::from_secs(15);

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: mkfifo(2) with a NUL-terminated path that outlives the call.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

/// Runs `fieldcal ARGS` under [`CAP`] and an address-space limit of 2 GiB
/// (a command that reads `/dev/zero` whole fails on it rather than taking
/// the machine's memory). Returns the exit code, stderr and elapsed time.
fn run_capped(args: &[&str]) -> (Option<i32>, String, Duration) {
    let mut command = fieldcal();
    command
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: setrlimit(2) is async-signal-safe; it runs in the forked
    // child before exec and touches only the struct on its stack.
    unsafe {
        command.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 2 << 30,
                rlim_max: 2 << 30,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let started = Instant::now();
    let mut child = command.spawn().expect("start fieldcal");
    let stderr_pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = std::io::Read::read_to_string(&mut { stderr_pipe }, &mut text);
        text
    });
    let status = wait_child(&mut child, CAP, || format!("fieldcal {args:?}"));
    let elapsed = started.elapsed();
    (status.code(), reader.join().unwrap(), elapsed)
}

fn assert_refused(args: &[&str], needle: &str) {
    let (code, stderr, elapsed) = run_capped(args);
    assert_eq!(code, Some(1), "fieldcal {args:?}: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(stderr.contains(needle), "fieldcal {args:?}: {stderr}");
    assert!(stderr.contains("not a regular file"), "{stderr}");
    assert!(elapsed < Duration::from_secs(5), "took {elapsed:?}");
}

#[test]
fn replay_of_dev_zero_is_refused_at_once() {
    assert_refused(&["replay", "/dev/zero"], "character device");
    assert_refused(&["replay", "/dev/zero", "--speed", "max"], "/dev/zero");
}

#[test]
fn a_fifo_given_to_the_cli_is_refused_without_blocking() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("recording");
    mkfifo(&fifo);
    let fifo_csv = dir.path().join("recording.csv");
    mkfifo(&fifo_csv);
    let (f, c) = (fifo.to_str().unwrap(), fifo_csv.to_str().unwrap());
    assert_refused(&["replay", f], "FIFO");
    assert_refused(&["fit", c], "FIFO");
    assert_refused(&["diagnose", c], "FIFO");
    let real =
        shared_path("data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up/hmc5883l_mag.csv");
    let real = real.to_str().unwrap();
    assert_refused(
        &[
            "check",
            real,
            "--x",
            "mag_x",
            "--y",
            "mag_z",
            "--calibration",
            f,
        ],
        "FIFO",
    );
    assert_refused(&["run", "--config", f], "FIFO");
    assert_refused(&["replay", "/dev/null", "--config", f], "FIFO");
}

/// A FIFO in a state file's place used to hold the start in `open`, deaf to
/// SIGTERM. It is refused like any file that cannot be trusted (moved
/// aside), the daemon starts, publishes, and ends on SIGTERM.
#[test]
fn a_fifo_state_file_is_refused_and_the_daemon_runs_and_stops() {
    let dir = tempfile::tempdir().unwrap();
    let capture = long_capture(dir.path(), 20);
    let state = dir.path().join("state");
    std::fs::create_dir(&state).unwrap();
    mkfifo(&state.join("compass.json"));
    let config = replay_config(dir.path(), &capture, "20.0", "stdout = true");
    let started = Instant::now();
    let mut daemon = Daemon::start(&config, &[]);
    let status = daemon.wait_for_value(CAP, "a STATUS line", |v| is_class(v, "STATUS"));
    assert_eq!(status["sensors"][0]["sensor"], "compass", "{status}");
    assert!(started.elapsed() < Duration::from_secs(10));
    let log = daemon.wait_for_log(CAP, "FIFO");
    assert!(log.contains("compass.json"), "{log}");
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
    // Moved aside, so a calibration can be stored in its place later.
    assert!(std::fs::symlink_metadata(state.join("compass.json")).is_err());
}

fn unix_config(dir: &Path, socket: &Path) -> std::path::PathBuf {
    let capture = long_capture(dir, 20);
    let outputs = format!("stdout = true\nunix = \"{}\"", socket.display());
    replay_config(dir, &capture, "20.0", &outputs)
}

#[test]
fn a_regular_file_at_the_socket_path_is_named_as_such() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("fieldcal.sock");
    std::fs::write(&socket, "notes").unwrap();
    let config = unix_config(dir.path(), &socket);
    let mut daemon = Daemon::start(&config, &[]);
    let status = daemon.wait(CAP);
    assert_eq!(status.code(), Some(1), "{}", daemon.stderr());
    let log = daemon.stderr();
    assert!(
        log.contains(&format!(
            "a regular file is at the Unix socket path {}: remove it or choose another [outputs] unix",
            socket.display()
        )),
        "{log}"
    );
    assert_eq!(std::fs::read_to_string(&socket).unwrap(), "notes");
}

/// Started with umask 0, the socket used to be 0777 (anyone could connect
/// and send commands); its mode is set explicitly. At shutdown a regular
/// file put at the path meanwhile is left alone.
#[test]
fn the_socket_mode_is_explicit_and_only_our_socket_is_removed() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("fieldcal.sock");
    let config = unix_config(dir.path(), &socket);
    let mut daemon = Daemon::start_with(&config, |command: &mut Command| {
        // SAFETY: umask(2) is async-signal-safe and cannot fail.
        unsafe {
            command.pre_exec(|| {
                libc::umask(0);
                Ok(())
            });
        }
    });
    daemon.wait_for_value(CAP, "a STATUS line", |v| is_class(v, "STATUS"));
    let mode = std::fs::symlink_metadata(&socket)
        .unwrap()
        .permissions()
        .mode()
        & 0o777;
    assert_eq!(mode, 0o660, "socket mode {mode:o}");
    // Someone replaces the socket by a file of theirs.
    std::fs::remove_file(&socket).unwrap();
    std::fs::write(&socket, "someone's file").unwrap();
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
    assert_eq!(
        std::fs::read_to_string(&socket).unwrap(),
        "someone's file",
        "the daemon removed a file that was not its socket"
    );

    // Its own socket it does remove.
    std::fs::remove_file(&socket).unwrap();
    let mut daemon = Daemon::start(&config, &[]);
    daemon.wait_for_value(CAP, "a STATUS line", |v| is_class(v, "STATUS"));
    assert!(std::fs::symlink_metadata(&socket).is_ok());
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
    assert!(std::fs::symlink_metadata(&socket).is_err());
}

#[test]
fn fit_output_over_a_private_file_keeps_its_mode() {
    let dir = tempfile::tempdir().unwrap();
    let output = dir.path().join("out.csv");
    std::fs::write(&output, "old").unwrap();
    std::fs::set_permissions(&output, std::fs::Permissions::from_mode(0o600)).unwrap();
    let real =
        shared_path("data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up/hmc5883l_mag.csv");
    common::run_ok(&[
        "fit",
        real.to_str().unwrap(),
        "--x",
        "mag_x",
        "--y",
        "mag_z",
        "--output",
        output.to_str().unwrap(),
    ]);
    let text = std::fs::read_to_string(&output).unwrap();
    // 1766 samples of the real z run (see tests/fit_cli.rs), and a header.
    assert_eq!(text.lines().count(), 1767);
    let mode = std::fs::metadata(&output).unwrap().permissions().mode() & 0o7777;
    assert_eq!(mode, 0o600, "mode {mode:o}");
}

/// A huge field (here 20 MB of digits with a letter in it) in a CSV:
/// `fit` and `diagnose` say which line and column are wrong without
/// echoing the field whole to stderr.
#[test]
fn a_huge_bad_field_is_named_not_echoed() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("huge.csv");
    let mut text = String::from("t,x,y\n0,1,0\n0.1,0,1\n0.2,");
    text.push_str(&"7".repeat(10_000_000));
    text.push('x');
    text.push_str(&"7".repeat(10_000_000));
    text.push_str(",0\n");
    std::fs::write(&csv, text).unwrap();
    let file = csv.to_str().unwrap();
    for command in ["fit", "diagnose"] {
        let (code, stderr, _) = run_capped(&[command, file]);
        assert_eq!(code, Some(1), "{command}: {stderr}");
        assert!(
            stderr.contains("line 4") || stderr.contains(":4:"),
            "{command}: {stderr}"
        );
        assert!(stderr.contains("column 'x'"), "{command}: {stderr}");
        assert!(stderr.contains("(20000001 bytes)"), "{command}: {stderr}");
        assert!(
            stderr.len() < 4096,
            "{command}: {} bytes of stderr",
            stderr.len()
        );
    }
    // The same in a header: a 1 MB column name.
    let header = dir.path().join("header.csv");
    std::fs::write(&header, format!("t,{},y\n0,1,0\n", "n".repeat(1_000_000))).unwrap();
    let (code, stderr, _) = run_capped(&["fit", header.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("no column 'x'"), "{stderr}");
    assert!(stderr.len() < 4096, "{} bytes of stderr", stderr.len());
}
