//! Fault tests of `fieldcal run` and its state store: an unusable or full
//! state directory, kills in the middle of a state write, subscribers that
//! vanish mid-line or come and go by the hundred, and configuration
//! mistakes. Real processes, real sockets, real files.
//!
//! CI runs these as root, so permissions never stop a write: the faults are
//! made by other means, each stated at its test.

mod common;

use std::io::{BufRead, BufReader, Read};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, is_class, replay_config};
use common::faults::{
    TmpfsMount, XorShift, connect_tcp, free_port, long_capture, send_unix_command, temp_files,
    vm_rss_kb,
};
use fieldcal::daemon::Calibration;
use fieldcal::daemon::state::StateStore;
use fieldcal::model::paper::PaperCalibration;
use serde_json::Value;

/// Generous: these machines are shared with fuzzers and benchmarks.
const LONG: Duration = Duration::from_secs(30);

fn stored_id(path: &Path) -> u64 {
    let v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    v["calibration"]["id"].as_u64().unwrap()
}

/// A daemon replaying a long capture (100 turns of 10 s at 20x: 50 s at
/// most, ended by the test long before) with a Unix socket for commands,
/// past its first stored calibration. Returns it with the stored file's
/// bytes.
fn daemon_with_a_stored_calibration(
    dir: &Path,
    adjust: impl FnOnce(&mut Command),
) -> (Daemon, std::path::PathBuf, Vec<u8>) {
    let capture = long_capture(dir, 100);
    let socket = dir.join("fieldcal.sock");
    let outputs = format!("stdout = true\nunix = \"{}\"", socket.display());
    let config = replay_config(dir, &capture, "20.0", &outputs);
    let mut daemon = Daemon::start_with(&config, adjust);
    let first = daemon.wait_for_value(LONG, "the first CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    assert_eq!(first["accepted"], true, "{first}");
    assert_eq!(first["id"], 1, "{first}");
    // The save follows the publication: wait for the file.
    let file = dir.join("state/compass.json");
    let deadline = Instant::now() + LONG;
    while !(file.exists() && stored_id(&file) == 1) {
        assert!(Instant::now() < deadline, "compass.json was never written");
        std::thread::sleep(Duration::from_millis(20));
    }
    let before = std::fs::read(&file).unwrap();
    (daemon, socket, before)
}

/// After a recalibration whose save failed: an ERROR line for the sensor,
/// a log line naming the file, and READINGs that go on corrected by the
/// new calibration (id 2), held in memory only.
fn assert_failed_save_reported_and_readings_go_on(daemon: &mut Daemon, socket: &Path) {
    send_unix_command(socket, r#"{"command":"recalibrate"}"#);
    let second = daemon.wait_for_value(LONG, "the second CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    assert_eq!(second["accepted"], true, "{second}");
    assert_eq!(second["id"], 2, "{second}");
    let error = daemon.wait_for_value(LONG, "an ERROR line", |v| is_class(v, "ERROR"));
    assert_eq!(error["sensor"], "compass", "{error}");
    let message = error["message"].as_str().unwrap();
    assert!(message.contains("compass.json"), "{error}");
    let log = daemon.wait_for_log(LONG, "compass.json");
    assert!(
        log.lines().any(|l| l.contains("ERROR")
            && l.contains("cannot write")
            && l.contains("compass.json")),
        "no error log line naming the file:\n{log}"
    );
    for _ in 0..20 {
        let reading = daemon.wait_for_value(LONG, "a READING after the failed save", |v| {
            is_class(v, "READING")
        });
        assert_eq!(reading["calibrated"], true, "{reading}");
        assert_eq!(reading["calibration"], 2, "{reading}");
    }
    assert!(daemon.is_running(), "{}", daemon.stderr());
}

/// Once the state directory works again: a recalibration is accepted as
/// number `id` and reaches `file`.
fn assert_next_calibration_stored(daemon: &mut Daemon, socket: &Path, file: &Path, id: u64) {
    send_unix_command(socket, r#"{"command":"recalibrate"}"#);
    let next = daemon.wait_for_value(LONG, "the next CALIBRATION", |v| is_class(v, "CALIBRATION"));
    assert_eq!(next["id"], id, "{next}");
    let deadline = Instant::now() + LONG;
    while stored_id(file) != id {
        assert!(
            Instant::now() < deadline,
            "calibration {id} was never stored"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Simulates a state directory that became unusable while the daemon runs
/// (as root, chmod would not stop the write): the directory is renamed
/// away and a regular file put at its path, so every write under it fails
/// with ENOTDIR. The directory, with the old file in it, is then put back:
/// the old file is unchanged, and the next calibration is stored again.
#[test]
fn an_unusable_state_directory_keeps_the_old_file_and_readings_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let (mut daemon, socket, before) = daemon_with_a_stored_calibration(dir.path(), |_| {});
    let state = dir.path().join("state");
    let aside = dir.path().join("state.aside");
    std::fs::rename(&state, &aside).unwrap();
    std::fs::write(&state, "not a directory").unwrap();

    assert_failed_save_reported_and_readings_go_on(&mut daemon, &socket);

    std::fs::remove_file(&state).unwrap();
    std::fs::rename(&aside, &state).unwrap();
    assert_eq!(
        std::fs::read(state.join("compass.json")).unwrap(),
        before,
        "the stored calibration changed"
    );
    assert!(temp_files(&state).is_empty(), "{:?}", temp_files(&state));
    // The directory is back: the next accepted calibration is stored.
    assert_next_calibration_stored(&mut daemon, &socket, &state.join("compass.json"), 3);
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// The state directory deleted under a running daemon: the failed save
/// must not claim "the calibration stored before is unchanged" (none is
/// left); it says the directory is gone.
#[test]
fn a_deleted_state_directory_is_told_apart_from_an_unchanged_one() {
    let dir = tempfile::tempdir().unwrap();
    let (mut daemon, socket, _) = daemon_with_a_stored_calibration(dir.path(), |_| {});
    let state = dir.path().join("state");
    std::fs::remove_dir_all(&state).unwrap();
    send_unix_command(&socket, r#"{"command":"recalibrate"}"#);
    let second = daemon.wait_for_value(LONG, "the second CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    assert_eq!(second["id"], 2, "{second}");
    let error = daemon.wait_for_value(LONG, "an ERROR line", |v| is_class(v, "ERROR"));
    let message = error["message"].as_str().unwrap();
    assert!(
        message.contains(&format!("the state directory {} is gone", state.display())),
        "{message}"
    );
    assert!(!message.contains("unchanged"), "{message}");
    let reading = daemon.wait_for_value(LONG, "a READING", |v| is_class(v, "READING"));
    assert_eq!(reading["calibration"], 2, "{reading}");
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// Simulates a full disk: once the first calibration is stored, the
/// daemon's file-size limit (RLIMIT_FSIZE, set on the running process with
/// prlimit) is lowered to 0, so every write to a regular file fails with
/// EFBIG, as a write to a full disk fails with ENOSPC — the same error path
/// in the store. SIGXFSZ, which would otherwise kill the process, is
/// ignored in the child from its start (an ignored disposition survives
/// exec). The daemon's stdout and stderr are pipes, which the limit spares.
#[test]
fn a_full_disk_keeps_the_old_file_and_readings_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let ignore_sigxfsz = |command: &mut Command| {
        // SAFETY: signal(2) is async-signal-safe; the closure runs in the
        // forked child just before exec and touches no memory.
        unsafe {
            command.pre_exec(|| {
                if libc::signal(libc::SIGXFSZ, libc::SIG_IGN) == libc::SIG_ERR {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    };
    let (mut daemon, socket, before) = daemon_with_a_stored_calibration(dir.path(), ignore_sigxfsz);
    let limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: libc::RLIM_INFINITY,
    };
    // SAFETY: prlimit(2) on our own child with a valid rlimit; no old value.
    let rc = unsafe {
        libc::prlimit(
            daemon.pid() as libc::pid_t,
            libc::RLIMIT_FSIZE,
            &limit,
            std::ptr::null_mut(),
        )
    };
    assert_eq!(rc, 0, "prlimit: {}", std::io::Error::last_os_error());

    assert_failed_save_reported_and_readings_go_on(&mut daemon, &socket);
    let log = daemon.wait_for_log(Duration::from_secs(10), "too large");
    assert!(
        log.contains("File too large") || log.contains("too large"),
        "the write failed for another reason than the size limit:\n{log}"
    );
    let state = dir.path().join("state");
    assert_eq!(std::fs::read(state.join("compass.json")).unwrap(), before);
    assert!(temp_files(&state).is_empty(), "{:?}", temp_files(&state));
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// A read-only state directory (a tmpfs remounted read-only: refused even
/// to root, EROFS) no longer stops the start: the calibration in it is
/// loaded and corrects from the first reading, an ERROR line and the log
/// say new calibrations cannot be stored, and readings go on.
#[test]
fn a_read_only_state_directory_loads_reports_and_readings_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let mount = match TmpfsMount::mount(&state, 1 << 20) {
        Ok(mount) => mount,
        Err(e) => {
            eprintln!("skipped: cannot mount a tmpfs here ({e})");
            return;
        }
    };
    let stored = calibration(7);
    StateStore::open(&state).unwrap().save(&stored).unwrap();
    if let Err(e) = mount.remount_read_only() {
        eprintln!("skipped: cannot remount the tmpfs read-only ({e})");
        return;
    }
    let refused = std::fs::write(state.join("probe"), "x").unwrap_err();
    assert_eq!(refused.raw_os_error(), Some(libc::EROFS));

    let capture = long_capture(dir.path(), 20);
    let config = replay_config(dir.path(), &capture, "20.0", "stdout = true");
    let mut daemon = Daemon::start(&config, &[]);
    let error = daemon.wait_for_value(LONG, "an ERROR line", |v| is_class(v, "ERROR"));
    let message = error["message"].as_str().unwrap();
    assert!(message.contains("cannot be written"), "{message}");
    assert!(message.contains("Read-only file system"), "{message}");
    assert!(message.contains(&state.display().to_string()), "{message}");
    let loaded = daemon.wait_for_value(LONG, "the loaded CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    assert_eq!(loaded["origin"], "state", "{loaded}");
    assert_eq!(loaded["id"], 7, "{loaded}");
    // The first readings, before any rotation can end, use the stored one.
    for _ in 0..5 {
        let reading = daemon.wait_for_value(LONG, "a READING", |v| is_class(v, "READING"));
        assert_eq!(reading["calibrated"], true, "{reading}");
        assert_eq!(reading["calibration"], 7, "{reading}");
    }
    let log = daemon.wait_for_log(LONG, "cannot be written");
    assert!(
        log.lines()
            .any(|l| l.contains("ERROR") && l.contains("cannot be written")),
        "{log}"
    );
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// A real full disk, where the machine lets the test mount one: the state
/// directory is a 1 MiB tmpfs; once the first calibration is stored, a
/// filler file takes every free block, so the next save fails with ENOSPC.
/// The filler removed, the following calibration is stored again. (Where
/// mounting is not permitted, the RLIMIT_FSIZE test above covers the same
/// path with EFBIG.)
#[test]
fn a_really_full_filesystem_keeps_the_old_file_and_readings_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let _mount = match TmpfsMount::mount(&state, 1 << 20) {
        Ok(mount) => mount,
        Err(e) => {
            eprintln!(
                "skipped: cannot mount a tmpfs here ({e}); the RLIMIT_FSIZE test covers this path"
            );
            return;
        }
    };
    let (mut daemon, socket, before) = daemon_with_a_stored_calibration(dir.path(), |_| {});

    // Fill every free block. tmpfs counts pages, so write until refused.
    let filler = state.join("filler");
    {
        use std::io::Write;
        let mut file = std::fs::File::create(&filler).unwrap();
        let block = vec![0xA5u8; 4096];
        let error = loop {
            if let Err(e) = file.write_all(&block) {
                break e;
            }
        };
        assert_eq!(
            error.raw_os_error(),
            Some(libc::ENOSPC),
            "filling the tmpfs: {error}"
        );
    }

    assert_failed_save_reported_and_readings_go_on(&mut daemon, &socket);
    let log = daemon.wait_for_log(Duration::from_secs(10), "No space left on device");
    assert!(
        log.contains("No space left on device"),
        "the write failed for another reason than a full disk:\n{log}"
    );
    assert_eq!(std::fs::read(state.join("compass.json")).unwrap(), before);
    assert!(temp_files(&state).is_empty(), "{:?}", temp_files(&state));

    // Space again: the next accepted calibration is stored.
    std::fs::remove_file(&filler).unwrap();
    assert_next_calibration_stored(&mut daemon, &socket, &state.join("compass.json"), 3);
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// Calibration number `id` as the writer child stores it: every field is
/// derived from the id, so a file mixing two writes would not match. The
/// numbers are short binary fractions, which survive the JSON round trip
/// exactly (serde_json, without its `float_roundtrip` feature, may read a
/// long decimal back one ulp off: 1e-3 + 6e-9 did).
fn calibration(id: u64) -> Calibration {
    let k = id as f64;
    Calibration {
        sensor: "compass".into(),
        id,
        model: "offset+scale".into(),
        params: PaperCalibration {
            a: 1.0 + (id % 64) as f64 / 64.0,
            b: -k,
            d: 0.5 * k,
            r: 1000.0 + k,
        },
        rms: (id % 128) as f64 / 1024.0,
        coverage_deg: 300.0 + (id % 60) as f64,
        n: id as usize,
        time: 1.7e9 + k,
        terms: Default::default(),
        ellipsoid: None,
        se: Default::default(),
        parent: None,
        history: Vec::new(),
        gyro: None,
        dip: None,
        across: None,
        level: None,
    }
}

/// The writer for `killed_mid_write_...`: saves calibrations with
/// increasing ids in a tight loop, after the one on disk, until killed.
/// Run only as that test's child (it needs FIELDCAL_FAULT_STATE_DIR).
#[test]
#[ignore = "a child process of killed_mid_write_the_state_file_is_old_or_new"]
fn state_writer_child() {
    let Some(dir) = std::env::var_os("FIELDCAL_FAULT_STATE_DIR") else {
        return;
    };
    let store = StateStore::open(Path::new(&dir)).unwrap();
    let mut id = match store.load("compass").unwrap() {
        Some(c) => c.id + 1,
        None => 1,
    };
    println!("WRITER READY");
    loop {
        store.save(&calibration(id)).unwrap();
        id += 1;
    }
}

/// Killed with SIGKILL at random moments (mostly 0–20 ms after it
/// started writing), over and over, the writer leaves either the old calibration or
/// the new one, whole: `load` returns one of the calibrations it wrote, ids
/// never going back, and never reports a corrupt file. A kill may leave the
/// killed writer's temporary file; the next `StateStore::open` removes the
/// temporaries of writers that are gone, so they never accumulate.
#[test]
fn killed_mid_write_the_state_file_is_old_or_new() {
    const KILLS: usize = 100;
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    std::fs::create_dir_all(&state).unwrap();
    let mut rng = XorShift::seeded();
    let seed = rng.0;
    let mut last_id = 0;
    let mut writes_seen = 0;
    let mut temps_seen = 0;
    for round in 0..KILLS {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args(["--ignored", "--exact", "state_writer_child", "--nocapture"])
            .env("FIELDCAL_FAULT_STATE_DIR", &state)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut out = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        loop {
            line.clear();
            let n = out.read_line(&mut line).unwrap();
            assert!(
                n > 0,
                "the writer ended before it was ready (round {round})"
            );
            if line.contains("WRITER READY") {
                break;
            }
        }
        // 0–20 ms; every tenth round longer (20–200 ms), so that even on a
        // machine whose fsyncs are slow some saves complete.
        let delay_us = if round % 10 == 9 {
            20_000 + rng.below(180_000)
        } else {
            rng.below(20_000)
        };
        std::thread::sleep(Duration::from_micros(delay_us));
        child.kill().unwrap(); // SIGKILL
        let status = child.wait().unwrap();
        assert!(!status.success(), "the writer ended by itself: {status}");
        drop(out);

        // What a kill leaves: at most the killed writer's own temporaries
        // (a state file's and the open probe's), none of an earlier writer.
        let temps = temp_files(&state);
        let own = format!(".tmp.{}.", child.id());
        assert!(
            temps.len() <= 2 && temps.iter().all(|t| t.contains(&own)),
            "round {round} (seed {seed}): temporaries accumulate: {temps:?}"
        );
        temps_seen += temps.len();

        let store = StateStore::open(&state).unwrap();
        assert!(
            temp_files(&state).is_empty(),
            "open left stale temporaries: {:?}",
            temp_files(&state)
        );
        match store.load("compass") {
            Ok(Some(c)) => {
                assert_eq!(
                    c,
                    calibration(c.id),
                    "round {round} (seed {seed}): a torn mix"
                );
                assert!(
                    c.id >= last_id,
                    "round {round} (seed {seed}): id went back from {last_id} to {}",
                    c.id
                );
                if c.id > last_id {
                    writes_seen += 1;
                }
                last_id = c.id;
            }
            // Killed before its first save completed.
            Ok(None) => assert_eq!(last_id, 0, "round {round}: the file vanished"),
            Err(e) => panic!("round {round} (seed {seed}): {e}"),
        }
        let names: Vec<_> = std::fs::read_dir(&state)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            names.iter().all(|n| n == "compass.json"),
            "round {round}: unexpected files {names:?}"
        );
    }
    eprintln!(
        "{KILLS} kills (seed {seed}): last id {last_id}, {writes_seen} rounds advanced the file, \
         {temps_seen} temporaries left by kills and cleaned at open"
    );
    assert!(writes_seen > 0, "the writer never completed a save");
}

/// The subscriber count of the next STATUS on the daemon's stdout.
fn next_subscribers(daemon: &mut Daemon) -> u64 {
    let status = daemon.wait_for_value(LONG, "a STATUS", |v| is_class(v, "STATUS"));
    status["subscribers"].as_u64().unwrap()
}

/// Waits for a STATUS with exactly `n` subscribers.
fn wait_subscribers(daemon: &mut Daemon, n: u64) {
    daemon.wait_for_value(LONG, &format!("a STATUS with {n} subscribers"), |v| {
        is_class(v, "STATUS") && v["subscribers"] == n
    });
}

fn streaming_daemon(dir: &Path) -> (Daemon, u16) {
    let capture = long_capture(dir, 100);
    let port = free_port();
    let outputs = format!("stdout = true\ntcp = \"127.0.0.1:{port}\"");
    let config = replay_config(dir, &capture, "20.0", &outputs);
    let mut daemon = Daemon::start_with(&config, |_| {});
    daemon.wait_for_value(LONG, "a READING", |v| is_class(v, "READING"));
    (daemon, port)
}

/// Reads whole lines from a subscriber until `n` READINGs came.
fn read_readings(reader: &mut BufReader<std::net::TcpStream>, n: usize) {
    let mut got = 0;
    while got < n {
        let mut line = String::new();
        let len = reader
            .read_line(&mut line)
            .expect("the subscriber was cut off");
        assert!(len > 0, "the daemon closed a subscriber");
        let v: Value = serde_json::from_str(&line).unwrap();
        if is_class(&v, "READING") {
            got += 1;
        }
    }
}

/// TCP subscribers that read half a line and close (some with unread data
/// left, which resets the connection) harm neither the daemon nor the
/// subscriber that stays.
#[test]
fn a_subscriber_leaving_mid_line_harms_nobody() {
    let dir = tempfile::tempdir().unwrap();
    let (mut daemon, port) = streaming_daemon(dir.path());
    let baseline = next_subscribers(&mut daemon);
    let stays = connect_tcp(port);
    stays.set_read_timeout(Some(LONG)).unwrap();
    let mut stays = BufReader::new(stays);
    wait_subscribers(&mut daemon, baseline + 1);
    read_readings(&mut stays, 5);
    for i in 0..10 {
        let mut leaves = connect_tcp(port);
        leaves.set_read_timeout(Some(LONG)).unwrap();
        let mut half = [0u8; 17];
        leaves.read_exact(&mut half).unwrap();
        assert!(
            !half.contains(&b'\n'),
            "{:?}",
            String::from_utf8_lossy(&half)
        );
        if i % 2 == 0 {
            // Let unread lines pile up: closing then resets the connection.
            std::thread::sleep(Duration::from_millis(100));
        }
        drop(leaves);
        read_readings(&mut stays, 5);
    }
    wait_subscribers(&mut daemon, baseline + 1);
    assert!(daemon.is_running(), "{}", daemon.stderr());
    read_readings(&mut stays, 20);
    drop(stays);
    wait_subscribers(&mut daemon, baseline);
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// 20 rounds of 50 TCP subscribers connecting, reading a line and leaving
/// while the sensor streams: the subscriber count returns to its baseline
/// every round and the resident memory stays flat after a warm-up round.
#[test]
fn fifty_subscribers_coming_and_going_leak_nothing() {
    const ROUNDS: usize = 20;
    const WARM_UP: usize = 2;
    let dir = tempfile::tempdir().unwrap();
    let (mut daemon, port) = streaming_daemon(dir.path());
    let pid = daemon.pid();
    let baseline = next_subscribers(&mut daemon);
    let mut rss_after_warm_up = 0;
    for round in 0..ROUNDS {
        let mut streams: Vec<_> = (0..50).map(|_| connect_tcp(port)).collect();
        wait_subscribers(&mut daemon, baseline + 50);
        for s in &mut streams {
            s.set_read_timeout(Some(LONG)).unwrap();
            let mut reader = BufReader::new(&*s);
            let mut line = String::new();
            assert!(reader.read_line(&mut line).unwrap() > 0, "round {round}");
        }
        drop(streams);
        wait_subscribers(&mut daemon, baseline);
        if round + 1 == WARM_UP {
            rss_after_warm_up = vm_rss_kb(pid);
        }
    }
    let rss_end = vm_rss_kb(pid);
    eprintln!("VmRSS after warm-up {rss_after_warm_up} kB, after {ROUNDS} rounds {rss_end} kB");
    assert!(
        rss_end < rss_after_warm_up + 2048,
        "resident memory grew from {rss_after_warm_up} kB to {rss_end} kB"
    );
    assert!(daemon.is_running(), "{}", daemon.stderr());
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
}

/// `fieldcal run` refuses representative configuration mistakes with exit
/// status 1 and a message naming the key, and opens nothing: no state
/// directory, no Unix socket, no TCP listener.
#[test]
fn configuration_mistakes_exit_1_and_open_nothing() {
    let mistakes: [(&str, &str, &str, &str); 4] = [
        ("unknown key", "state_dri = \"/nowhere\"", "", "state_dri"),
        (
            "wrong type",
            "status_interval_s = \"fast\"",
            "",
            "status_interval_s",
        ),
        ("missing source", "", "source = \"gps\"", "gps"),
        (
            "effect not live-correctable",
            "",
            "model = [\"paper\", \"drift\"]",
            "drift",
        ),
    ];
    for (what, daemon_extra, sensor_extra, key) in mistakes {
        let dir = tempfile::tempdir().unwrap();
        let state = dir.path().join("state");
        let socket = dir.path().join("fieldcal.sock");
        let port = free_port();
        let sensor_source = if sensor_extra.starts_with("source") {
            sensor_extra.to_string()
        } else {
            format!("source = \"imu\"\n{sensor_extra}")
        };
        let config = common::daemon::write_config(
            dir.path(),
            &format!(
                r#"
[daemon]
state_dir = "{state}"
{daemon_extra}

[outputs]
tcp = "127.0.0.1:{port}"
unix = "{socket}"

[[source]]
name = "imu"
kind = "falcon"
port = "/dev/ttyNONE"

[[sensor]]
name = "compass"
{sensor_source}
field = "mag"
axes = ["x", "y"]
"#,
                state = state.display(),
                socket = socket.display(),
            ),
        );
        let started = Instant::now();
        let r = common::run(&["run", "--config", config.to_str().unwrap()]);
        assert_eq!(r.code, Some(1), "{what}: {}", r.stderr);
        assert!(!r.stderr.contains("panicked"), "{what}: {}", r.stderr);
        assert!(r.stderr.contains("fieldcal.toml"), "{what}: {}", r.stderr);
        assert!(r.stderr.contains(key), "{what}: no {key:?} in {}", r.stderr);
        assert!(r.stdout.is_empty(), "{what}: {}", r.stdout);
        assert!(!state.exists(), "{what}: the state directory was created");
        assert!(!socket.exists(), "{what}: the socket was created");
        // Nothing listened on the port: it is still free to bind.
        std::net::TcpListener::bind(("127.0.0.1", port))
            .unwrap_or_else(|e| panic!("{what}: port {port} taken: {e}"));
        assert!(
            started.elapsed() < LONG,
            "{what}: took {:?}",
            started.elapsed()
        );
    }
}
