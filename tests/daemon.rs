//! `fieldcal run` end to end: real processes, real pseudo-terminals, real
//! sockets.

mod bridge_support;
mod common;

use std::io::{BufRead, BufReader, Write};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, is_class, replay_config, unix_now, write_config};
use common::pty::FalconPty;
use fieldcal::mock::usb_iss::MockUsbIss;
use fieldcal::protocol::chips::Chip;
use fieldcal::sample::Reading;
use fieldcal::sim::{FalconWire, SimSensor};
use serde_json::Value;

/// A compass turning once in 6 s, sampled every 50 ms: 120 frames a turn.
fn turning_compass(turns: f64) -> (SimSensor, Vec<Vec<u8>>) {
    let sensor = SimSensor {
        field: 1000.0,
        offset_x: 150.0,
        offset_y: -80.0,
        gain_x: 1.1,
        noise: 2.0,
        turn_seconds: 6.0,
        turns,
        seed: 21,
        ..Default::default()
    };
    let (_, chunks) = sensor.falcon_capture(&FalconWire::default()).unwrap();
    (sensor, chunks.into_iter().map(|c| c.bytes).collect())
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// After a calibration, corrected readings lie on its circle to within the
/// noise: `sigma` counts per raw axis, scaled by at most max(a, 1).
fn assert_on_circle(readings: &[Value], calibration: &Value, sigma: f64) {
    let r = f(&calibration["params"]["r"]);
    let a = f(&calibration["params"]["a"]);
    let bound = 5.0 * sigma * a.max(1.0);
    assert!(!readings.is_empty());
    for reading in readings {
        assert_eq!(reading["calibrated"], true, "{reading}");
        assert_eq!(reading["calibration"], calibration["id"], "{reading}");
        let c = &reading["corrected"];
        let magnitude = f(&c[0]).hypot(f(&c[1]));
        assert!(
            (magnitude - r).abs() < bound,
            "|corrected| = {magnitude}, r = {r}, bound {bound}: {reading}"
        );
        let heading = f(&reading["heading_deg"]);
        assert!((0.0..360.0).contains(&heading), "{reading}");
    }
}

fn falcon_config(dir: &std::path::Path, port: &std::path::Path, extra: &str) -> std::path::PathBuf {
    write_config(
        dir,
        &format!(
            r#"
[daemon]
state_dir = "{state}"
status_interval_s = 0.5

[outputs]
stdout = true
{extra}

[[source]]
name = "imu"
kind = "falcon"
port = "{port}"
retry_s = 0.2

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]
"#,
            state = dir.join("state").display(),
            port = port.display(),
        ),
    )
}

#[test]
fn falcon_rotation_is_calibrated_within_a_second_and_corrected_after() {
    let (sensor, chunks) = turning_compass(1.6);
    let pty = FalconPty::plug_in(chunks, Duration::from_millis(50));
    let dir = tempfile::tempdir().unwrap();
    let config = falcon_config(dir.path(), pty.path(), "");
    let mut daemon = Daemon::start(&config, &[]);

    let (_, first) = daemon.wait_for(Duration::from_secs(10), "a READING", |v| {
        is_class(v, "READING")
    });
    assert_eq!(first["calibrated"], false, "no calibration yet: {first}");
    assert!(first.get("corrected").is_none());
    let (_, calibration) = daemon.wait_for(Duration::from_secs(20), "a CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    let received = unix_now();
    assert_eq!(calibration["accepted"], true, "{calibration}");
    assert_eq!(calibration["id"], 1);
    assert_eq!(calibration["model"], "offset+scale");
    // Published within a second of the rotation's last sample...
    let last_sample = f(&calibration["time"]);
    assert!(
        received - last_sample < 1.0,
        "published {:.3} s after the last sample",
        received - last_sample
    );
    // ...and the rotation ended within the first turn and a bit (6 s a turn).
    let first_time = f(&first["time"]);
    assert!(
        last_sample - first_time < 6.6,
        "rotation took {:.2} s",
        last_sample - first_time
    );
    // The fit is the simulated sensor's, to within the noise.
    let truth = sensor.truth();
    assert!(
        (f(&calibration["params"]["a"]) - truth.a).abs() < 0.01,
        "{calibration}"
    );
    assert!(
        (f(&calibration["params"]["r"]) - truth.r).abs() < 3.0,
        "{calibration}"
    );

    let mut after = Vec::new();
    while after.len() < 30 {
        let (_, v) = daemon.wait_for(Duration::from_secs(5), "a READING", |v| {
            is_class(v, "READING")
        });
        after.push(v);
    }
    assert_on_circle(&after, &calibration, sensor.noise);
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
    // SIGTERM: the Falcon was told to stop streaming.
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(pty.commands_seen(), (1, 1));
    // The calibration was stored.
    let stored: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("state/compass.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(stored["calibration"]["id"], 1, "{stored}");
    assert_eq!(
        stored["calibration"]["params"], calibration["params"],
        "{stored}"
    );
}

#[test]
fn bridge_rotation_at_30_ms_is_calibrated_and_corrected() {
    let _serial = bridge_support::one_at_a_time();
    const PER_TURN: f64 = 200.0; // 6 s at 30 ms
    let mut mock = MockUsbIss::with_chips(&[Chip::Lsm303dlhcMag]);
    let mut noise = 0x2545_f491_4f6c_dd1du64;
    mock.set_generator(
        Chip::Lsm303dlhcMag.default_address(),
        Box::new(move |n| {
            // A small deterministic dither of up to +-2 counts.
            let mut dither = || {
                noise ^= noise << 13;
                noise ^= noise >> 7;
                noise ^= noise << 17;
                (noise % 5) as f64 - 2.0
            };
            let h = n as f64 / PER_TURN * std::f64::consts::TAU;
            let x = 120.0 + 450.0 * 0.9 * h.cos() + dither();
            let y = -60.0 + 450.0 * h.sin() + dither();
            Reading {
                mag: Some([x.round() as i16, y.round() as i16, -300]),
                ..Reading::default()
            }
        }),
    );
    let harness = bridge_support::Harness::start(mock);
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(
        dir.path(),
        &format!(
            r#"
[daemon]
state_dir = "{state}"

[outputs]
stdout = true

[[source]]
name = "bridge"
kind = "usb-iss"
port = "{port}"
chips = ["lsm303dlhc-mag"]
poll_ms = 30
retry_s = 0.2

[[sensor]]
name = "compass"
source = "bridge"
chip = "lsm303dlhc-mag"
field = "mag"
axes = ["x", "y"]
"#,
            state = dir.path().join("state").display(),
            port = harness.port.display()
        ),
    );
    let mut daemon = Daemon::start(&config, &[]);
    let (_, first) = daemon.wait_for(Duration::from_secs(10), "a READING", |v| {
        is_class(v, "READING")
    });
    let (_, calibration) = daemon.wait_for(Duration::from_secs(20), "a CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    let received = unix_now();
    assert_eq!(calibration["accepted"], true, "{calibration}");
    let last_sample = f(&calibration["time"]);
    assert!(
        received - last_sample < 1.0,
        "published {:.3} s after the last sample",
        received - last_sample
    );
    // One turn is PER_TURN polls however late the polls come (the mock
    // turns by the poll, not by the clock): the rotation completes at the
    // end of the turn, within its last sector, not a second turn later. A
    // loaded machine delays polls, so this counts readings, not seconds.
    let readings = daemon
        .seen
        .iter()
        .filter(|v| is_class(v, "READING"))
        .count();
    assert!(
        (readings as f64) < 1.1 * PER_TURN,
        "{readings} readings before the calibration"
    );
    assert!(last_sample > f(&first["time"]));
    assert!(
        (f(&calibration["params"]["a"]) - 1.0 / 0.9).abs() < 0.02,
        "{calibration}"
    );
    let mut after = Vec::new();
    while after.len() < 30 {
        let (_, v) = daemon.wait_for(Duration::from_secs(5), "a READING", |v| {
            is_class(v, "READING")
        });
        after.push(v);
    }
    // Dither of +-2 counts: a standard deviation of about 1.4.
    assert_on_circle(&after, &calibration, 1.5);
    assert!(daemon.terminate().success());
}

#[test]
fn a_restart_corrects_the_first_reading_with_the_stored_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");
    let config = replay_config(dir.path(), &capture, "\"max\"", "stdout = true");
    let mut first_run = Daemon::start(&config, &[]);
    let (_, calibration) = first_run.wait_for(Duration::from_secs(20), "a CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    assert_eq!(calibration["accepted"], true);
    // The daemon ends when its only source, a replay, has ended.
    first_run.drain(Duration::from_secs(20));
    assert!(first_run.wait(Duration::from_secs(5)).success());

    let mut second_run = Daemon::start(&config, &[]);
    let (_, loaded) = second_run.wait_for(Duration::from_secs(10), "the stored CALIBRATION", |v| {
        is_class(v, "CALIBRATION")
    });
    assert_eq!(loaded["origin"], "state");
    assert_eq!(loaded["params"], calibration["params"]);
    let (_, reading) = second_run.wait_for(Duration::from_secs(10), "a READING", |v| {
        is_class(v, "READING")
    });
    assert_eq!(reading["calibrated"], true, "{reading}");
    assert_eq!(reading["calibration"], 1);
    // No READING came before the first corrected one.
    assert_eq!(
        second_run
            .seen
            .iter()
            .filter(|v| is_class(v, "READING"))
            .count(),
        1
    );
    second_run.drain(Duration::from_secs(20));
}

#[test]
fn a_corrupt_state_file_is_set_aside_and_reported() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    std::fs::create_dir_all(&state).unwrap();
    std::fs::write(
        state.join("compass.json"),
        "{\"sensor\": \"compass\", \"id\": ",
    )
    .unwrap();
    let capture = common::repo_path("tests/data/falcon_turn.fcap");
    let config = replay_config(dir.path(), &capture, "\"max\"", "stdout = true");
    let mut daemon = Daemon::start(&config, &[]);
    let (_, reading) = daemon.wait_for(Duration::from_secs(10), "a READING", |v| {
        is_class(v, "READING")
    });
    assert_eq!(
        reading["calibrated"], false,
        "a corrupt file is never trusted"
    );
    daemon.drain(Duration::from_secs(20));
    let moved: Vec<String> = std::fs::read_dir(&state)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("compass.json.corrupt-"))
        .collect();
    assert_eq!(moved.len(), 1, "{moved:?}");
    daemon.wait_for_log(Duration::from_secs(10), "compass.json");
}

#[test]
fn an_unplugged_device_comes_back_counted_with_nothing_published_twice() {
    let (_, chunks) = turning_compass(1.0);
    let mut pty = FalconPty::plug_in(chunks, Duration::from_millis(50));
    let dir = tempfile::tempdir().unwrap();
    let config = falcon_config(dir.path(), pty.path(), "");
    let mut daemon = Daemon::start(&config, &[]);
    for _ in 0..20 {
        daemon.wait_for(Duration::from_secs(10), "a READING", |v| {
            is_class(v, "READING")
        });
    }
    pty.unplug();
    std::thread::sleep(Duration::from_millis(600));
    pty.plug();
    let (_, status) = daemon.wait_for(Duration::from_secs(10), "a STATUS with a reconnect", |v| {
        is_class(v, "STATUS")
            && v["sources"][0]["reconnects"] == 1
            && v["sources"][0]["connected"] == true
    });
    assert_eq!(status["sources"][0]["source"], "imu");
    for _ in 0..20 {
        daemon.wait_for(Duration::from_secs(10), "a READING after the replug", |v| {
            is_class(v, "READING")
        });
    }
    assert!(daemon.terminate().success());
    // Frames decoded from one read of the port share its receive time, so
    // times may repeat; a READING published twice repeats its raw values
    // too.
    let readings: Vec<(f64, String)> = daemon
        .seen
        .iter()
        .filter(|v| is_class(v, "READING"))
        .map(|v| (f(&v["time"]), v["raw"].to_string()))
        .collect();
    assert!(
        readings
            .windows(2)
            .all(|w| w[1].0 > w[0].0 || (w[1].0 == w[0].0 && w[1].1 != w[0].1)),
        "a READING published twice or out of order"
    );
}

#[test]
fn a_subscriber_that_never_reads_slows_nobody_and_its_drops_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    // 30,000 frames (25 min at 50 ms), replayed at 1000x: 1.5 s.
    let capture = dir.path().join("long.fcap");
    common::run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--turns",
        "150",
        "--noise",
        "2",
        "-o",
        capture.to_str().unwrap(),
    ]);
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let outputs = format!("stdout = false\ntcp = \"127.0.0.1:{port}\"\nqueue = 256");
    let config = replay_config(dir.path(), &capture, "1000.0", &outputs);
    let started = Instant::now();
    let mut daemon = Daemon::start(&config, &[]);
    let connect = || {
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            match std::net::TcpStream::connect(("127.0.0.1", port)) {
                Ok(s) => return s,
                Err(_) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Err(e) => panic!("cannot connect: {e}"),
            }
        }
    };
    let stuck = connect(); // never read
    let stream = connect();
    let mut ask = stream.try_clone().unwrap();
    let reader = BufReader::new(stream);
    // The reading subscriber asks for its own accounting every 1000
    // readings: on a loaded machine (2 cores, the other tests beside) it
    // may itself fall behind and lose readings, but only ones counted as
    // dropped for it, never because of the stuck one.
    let mut readings = Vec::new();
    let mut last_status = Value::Null;
    // (READINGs received before the reply, the reply's accounting)
    let mut replies: Vec<(usize, Value)> = Vec::new();
    for line in reader.lines() {
        let Ok(line) = line else { break };
        let v: Value = serde_json::from_str(&line).unwrap();
        if is_class(&v, "READING") {
            readings.push(f(&v["time"]));
            if readings.len() % 1000 == 0 {
                let _ = ask.write_all(b"{\"command\":\"status\"}\n");
            }
        } else if is_class(&v, "STATUS") {
            if v.get("subscriber").is_some() {
                replies.push((readings.len(), v["subscriber"].clone()));
            } else {
                last_status = v;
            }
        }
    }
    assert!(daemon.wait(Duration::from_secs(20)).success());
    let elapsed = started.elapsed();
    drop(stuck);
    // In order, each one sample period or a whole number of them apart.
    let missing_after = |i: usize| {
        let periods = (readings[i + 1] - readings[i]) / 0.05;
        assert!(
            periods.round() >= 1.0 && (periods - periods.round()).abs() < 1e-4,
            "readings {} and {} are not a whole number of periods apart",
            readings[i],
            readings[i + 1]
        );
        periods.round() as u64 - 1
    };
    // Every reading the subscriber did not get is one counted as dropped
    // for it: exactly, as its own accounting says.
    let (before, last) = replies
        .last()
        .expect("no STATUS reply reached the reading subscriber");
    let (given, dropped) = (f(&last["readings"]) as u64, f(&last["dropped"]) as u64);
    assert!(
        *before >= 10_000,
        "the last reply came after {before} readings: {last}"
    );
    assert_eq!(
        *before as u64,
        given - dropped,
        "READINGs received before the reply vs its accounting {last}"
    );
    let missed: u64 = (0..before.saturating_sub(1)).map(missing_after).sum();
    assert!(
        missed <= dropped,
        "{missed} readings missing before the reply, {dropped} counted as dropped: {last}"
    );
    let missed_later: u64 = (before.saturating_sub(1)..readings.len() - 1)
        .map(missing_after)
        .sum();
    eprintln!(
        "reading subscriber: {} readings, {missed} + {missed_later} missed, {} replies, last {last}",
        readings.len(),
        replies.len()
    );
    // The final STATUS counts the drops of both: the stuck subscriber's
    // are what is beyond the reading subscriber's own.
    assert!(
        f(&last_status["dropped"]) > (dropped + missed_later) as f64,
        "the stuck subscriber's drops are counted: {last_status}"
    );
    // 1.5 s of replay. A stuck subscriber that held the sensor path back
    // would stop it for good (it never reads), so the bound is loose: it
    // only has to hold on a machine loaded 10 deep (2 cores, CI beside
    // builds), where 8 s was once too tight.
    assert!(elapsed < Duration::from_secs(20), "took {elapsed:?}");
}

#[test]
fn systemd_hears_ready_and_watchdog_and_stopping() {
    use std::os::unix::net::UnixDatagram;
    let dir = tempfile::tempdir().unwrap();
    let socket_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let config = falcon_config(dir.path(), &dir.path().join("ttyNONE"), "");
    let mut daemon = Daemon::start(
        &config,
        &[
            ("NOTIFY_SOCKET", socket_path.to_str().unwrap()),
            ("WATCHDOG_USEC", "400000"),
        ],
    );
    let mut heard = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = Instant::now() + Duration::from_secs(10);
    while !(heard.iter().any(|m: &String| m.contains("READY=1"))
        && heard.iter().filter(|m| m.contains("WATCHDOG=1")).count() >= 2)
    {
        assert!(Instant::now() < deadline, "heard only {heard:?}");
        let n = socket.recv(&mut buf).expect("a notification");
        heard.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
    assert!(heard.iter().any(|m| m.contains("STATUS=")), "{heard:?}");
    assert!(daemon.terminate().success(), "{}", daemon.stderr());
    let mut stopping = false;
    while let Ok(n) = socket.recv(&mut buf) {
        if String::from_utf8_lossy(&buf[..n]).contains("STOPPING=1") {
            stopping = true;
            break;
        }
    }
    assert!(stopping, "STOPPING=1 on SIGTERM");
}

#[test]
fn subscribers_can_ask_for_status_and_recalibration() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("fieldcal.sock");
    let config = falcon_config(
        dir.path(),
        &dir.path().join("ttyNONE"),
        &format!("unix = \"{}\"", sock.display()),
    );
    let mut daemon = Daemon::start(&config, &[]);
    daemon.wait_for(Duration::from_secs(10), "a STATUS", |v| {
        is_class(v, "STATUS")
    });
    let stream = std::os::unix::net::UnixStream::connect(&sock).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(5)))
        .unwrap();
    let mut writer = stream.try_clone().unwrap();
    writeln!(
        writer,
        "{{\"command\":\"recalibrate\",\"sensor\":\"compass\"}}"
    )
    .unwrap();
    writeln!(writer, "{{\"command\":\"launch\"}}").unwrap();
    let mut reader = BufReader::new(stream);
    let mut got_status = false;
    let mut got_error = false;
    let deadline = Instant::now() + Duration::from_secs(5);
    while !(got_status && got_error) && Instant::now() < deadline {
        let mut line = String::new();
        if reader.read_line(&mut line).unwrap_or(0) == 0 {
            break;
        }
        let v: Value = serde_json::from_str(&line).unwrap();
        got_status |= is_class(&v, "STATUS") && v["sensors"][0]["sensor"] == "compass";
        got_error |= is_class(&v, "ERROR");
    }
    assert!(got_status && got_error);
    assert!(daemon.terminate().success());
    assert!(!sock.exists(), "the socket file is removed on exit");
}

#[test]
fn a_configuration_mistake_starts_nothing_and_names_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let sock = dir.path().join("fieldcal.sock");
    let config = write_config(
        dir.path(),
        &format!(
            r#"
[outputs]
unix = "{}"

[[source]]
name = "imu"
kind = "falcon"
port = "/dev/ttyUSB0"

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "x"]
"#,
            sock.display()
        ),
    );
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert_eq!(r.code, Some(1), "{}", r.stderr);
    assert!(r.stderr.contains("fieldcal.toml"), "{}", r.stderr);
    assert!(r.stderr.contains("axes"), "{}", r.stderr);
    assert!(!sock.exists(), "nothing was started");
}

#[test]
fn the_service_unit_verifies_where_systemd_analyze_exists() {
    let unit = common::repo_path("config/fieldcal.service");
    let text = std::fs::read_to_string(&unit).unwrap();
    for needed in [
        "Type=notify",
        // SIGHUP reloads the configuration (tests/reload.rs).
        "ExecReload=/bin/kill -HUP $MAINPID",
        "WatchdogSec=",
        "StateDirectory=",
        "SupplementaryGroups=dialout",
        "ProtectSystem=strict",
        // The latency under load that the README states depends on it.
        "CPUSchedulingPolicy=fifo",
    ] {
        assert!(text.contains(needed), "{needed} missing from the unit");
    }
    if std::process::Command::new("systemd-analyze")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!(
            "systemd-analyze is not installed here: the unit's text was checked, not verified"
        );
        return;
    }
    // Verify a copy whose ExecStart points at the binary under test.
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("fieldcal.service");
    let text = text.replace("/usr/local/bin/fieldcal", env!("CARGO_BIN_EXE_fieldcal"));
    std::fs::write(&copy, text).unwrap();
    let out = std::process::Command::new("systemd-analyze")
        .args(["verify", copy.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let problems: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("fieldcal.service"))
        .collect();
    assert!(
        out.status.success() && problems.is_empty(),
        "systemd-analyze verify: {stderr}"
    );
}
