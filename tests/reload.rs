//! SIGHUP reloads the configuration of `fieldcal run` (issue 12, point 6):
//! the real binary on a replayed capture, two sensors on one source.

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, ask, errors, is_class, write_config};
use common::faults::{free_port, long_capture};
use common::http::{live_address, request};
use serde_json::Value;

/// A capture of 60 turns (10 s each), replayed at 10 times real time: a
/// turn a second, a minute in all.
const SPEED: &str = "10.0";

/// Two sensors on the same magnetometer axes: `compass` and `heading`
/// (whose `[[sensor]]` section ends with `heading_extra`); STATUS every
/// `status` s; `outputs` as `[outputs]` lines.
fn config_text(
    dir: &Path,
    capture: &Path,
    speed: &str,
    status: &str,
    outputs: &str,
    heading_extra: &str,
) -> String {
    format!(
        r#"
[daemon]
state_dir = "{state}"
status_interval_s = {status}

[outputs]
stdout = true
{outputs}

[[source]]
name = "imu"
kind = "replay"
file = "{capture}"
speed = {speed}

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]

[[sensor]]
name = "heading"
source = "imu"
field = "mag"
axes = ["x", "y"]
{heading_extra}
"#,
        state = dir.join("state").display(),
        capture = capture.display(),
    )
}

struct Setup {
    dir: tempfile::TempDir,
    capture: PathBuf,
    config: PathBuf,
}

fn setup(status: &str, outputs: &str) -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let capture = long_capture(dir.path(), 60);
    let config = write_config(
        dir.path(),
        &config_text(dir.path(), &capture, SPEED, status, outputs, ""),
    );
    Setup {
        dir,
        capture,
        config,
    }
}

fn signal(daemon: &Daemon, signal: libc::c_int) {
    // SAFETY: kill(2) on our own child's pid; no memory is touched.
    let rc = unsafe { libc::kill(daemon.pid() as libc::pid_t, signal) };
    assert_eq!(rc, 0);
}

fn calibration_of(v: &Value, sensor: &str) -> bool {
    is_class(v, "CALIBRATION") && v["sensor"] == sensor && v["accepted"] == true
}

/// Both sensors calibrated from the first turn: calibration 1 each.
fn both_calibrated(daemon: &mut Daemon) {
    for sensor in ["compass", "heading"] {
        let c = daemon.wait_for_value(Duration::from_secs(20), "a CALIBRATION", |v| {
            calibration_of(v, sensor)
        });
        assert_eq!(c["id"], 1, "{c}");
        assert_eq!(c["model"], "offset+scale", "{c}");
    }
}

/// The next `n` STATUS lines, and every line up to the last of them.
fn next_statuses(daemon: &mut Daemon, n: usize) -> (Vec<Value>, Vec<Value>) {
    let from = daemon.seen.len();
    let mut statuses = Vec::new();
    for _ in 0..n {
        statuses.push(
            daemon.wait_for_value(Duration::from_secs(10), "a STATUS", |v| {
                is_class(v, "STATUS")
            }),
        );
    }
    (statuses, daemon.seen[from..].to_vec())
}

fn sensor_status<'a>(status: &'a Value, name: &str) -> &'a Value {
    status["sensors"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["sensor"] == name)
        .unwrap_or_else(|| panic!("no {name} in {status}"))
}

fn reload_summary(daemon: &mut Daemon) -> Value {
    daemon.wait_for_value(Duration::from_secs(10), "the RELOAD summary", |v| {
        is_class(v, "RELOAD")
            && v["message"]
                .as_str()
                .is_some_and(|m| m.starts_with("reload of ") && !m.contains("refused"))
            && v.get("sensor").is_none()
            && v.get("restart").is_none()
            && !v["message"].as_str().unwrap().contains("status_interval_s")
    })
}

/// (a) and (e): the same file again changes nothing (calibrations, states,
/// no new rotation), and SIGTERM after it still stops cleanly.
#[test]
fn sighup_with_the_same_file_changes_nothing_and_sigterm_still_stops_cleanly() {
    let sock_dir = tempfile::tempdir().unwrap();
    let sock = sock_dir.path().join("fieldcal.sock");
    let s = setup("0.2", &format!("unix = \"{}\"", sock.display()));
    let mut daemon = Daemon::start(&s.config, &[]);
    both_calibrated(&mut daemon);

    signal(&daemon, libc::SIGHUP);
    let summary = reload_summary(&mut daemon);
    assert_eq!(
        summary["message"],
        format!("reload of {}: no change", s.config.display()),
        "{summary}"
    );
    assert_eq!(summary["file"], s.config.display().to_string());
    // Two seconds of readings (two turns): a rotation started by the
    // reload would have been fitted within them.
    let (statuses, lines) = next_statuses(&mut daemon, 10);
    assert!(
        !lines.iter().any(|v| is_class(v, "CALIBRATION")),
        "no new rotation: {:?}",
        lines
            .iter()
            .filter(|v| is_class(v, "CALIBRATION"))
            .collect::<Vec<_>>()
    );
    for status in &statuses {
        for name in ["compass", "heading"] {
            let sensor = sensor_status(status, name);
            assert_eq!(sensor["state"], "calibrated", "{status}");
            assert_eq!(sensor["calibration"], 1, "{status}");
        }
    }
    let reading = daemon.wait_for_value(Duration::from_secs(5), "a READING", |v| {
        is_class(v, "READING")
    });
    assert_eq!(reading["calibration"], 1, "{reading}");
    assert!(daemon.is_running());

    // (e) A second SIGHUP, then SIGTERM: a clean stop.
    signal(&daemon, libc::SIGHUP);
    reload_summary(&mut daemon);
    let status = daemon.terminate();
    assert_eq!(status.code(), Some(0), "{status:?}\n{}", daemon.stderr());
    let log = daemon.stderr();
    assert!(log.contains("stopping"), "{log}");
    assert!(!sock.exists(), "the socket is removed at the stop");
    drop(s);
}

/// (b): a model changed for one sensor starts a new rotation for it, whose
/// CALIBRATION is of the new model; its old calibration corrects meanwhile;
/// the other sensor keeps its calibration and state.
#[test]
fn a_changed_model_starts_a_new_rotation_for_that_sensor_only() {
    let http = "http = \"127.0.0.1:0\"";
    let s = setup("0.2", http);
    let mut daemon = Daemon::start(&s.config, &[]);
    let page = live_address(&daemon.wait_for_log(Duration::from_secs(10), "live page at http://"));
    let model_on_page = |name: &str| {
        let cfg = request(&page, "GET", "/api/config", None, Duration::from_secs(5)).json();
        let sensor = cfg["sensors"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == name)
            .cloned();
        sensor.map(|s| s["model"].clone())
    };
    assert_eq!(model_on_page("heading"), Some("offset+scale".into()));
    both_calibrated(&mut daemon);

    write_config(
        s.dir.path(),
        &config_text(
            s.dir.path(),
            &s.capture,
            SPEED,
            "0.2",
            http,
            "model = [\"paper\", \"cross-axis\"]",
        ),
    );
    signal(&daemon, libc::SIGHUP);
    let from = daemon.seen.len();
    let changed = daemon.wait_for_value(Duration::from_secs(10), "the RELOAD of heading", |v| {
        is_class(v, "RELOAD") && v["sensor"] == "heading"
    });
    let message = changed["message"].as_str().unwrap();
    assert!(
        message.starts_with(
            "sensor 'heading': model offset+scale -> offset+scale+cross-axis: a new rotation starts"
        ),
        "{changed}"
    );
    assert!(
        message.contains("calibration #1 (offset+scale) keeps correcting"),
        "{changed}"
    );
    let summary = reload_summary(&mut daemon);
    assert!(
        summary["message"].as_str().unwrap().contains(
            "1 sensor changed, 0 added, 0 removed, 1 unchanged; 0 changes need a restart"
        ),
        "{summary}"
    );
    // The live page's configuration follows the reload.
    assert_eq!(
        model_on_page("heading"),
        Some("offset+scale+cross-axis".into())
    );
    assert_eq!(model_on_page("compass"), Some("offset+scale".into()));
    // The next reading of heading is still corrected by calibration 1,
    // and the status says it recalibrates.
    let reading = daemon.wait_for_value(Duration::from_secs(5), "a READING of heading", |v| {
        is_class(v, "READING") && v["sensor"] == "heading"
    });
    assert_eq!(reading["calibration"], 1, "{reading}");
    let status = daemon.wait_for_value(Duration::from_secs(5), "a STATUS", |v| {
        is_class(v, "STATUS")
    });
    assert_eq!(
        sensor_status(&status, "heading")["state"],
        "recalibrating",
        "{status}"
    );
    assert_eq!(
        sensor_status(&status, "compass")["state"],
        "calibrated",
        "{status}"
    );

    let new = daemon.wait_for_value(Duration::from_secs(20), "heading's new CALIBRATION", |v| {
        calibration_of(v, "heading")
    });
    assert_eq!(new["id"], 2, "{new}");
    assert_eq!(new["model"], "offset+scale+cross-axis", "{new}");
    let (statuses, _) = next_statuses(&mut daemon, 3);
    let last = statuses.last().unwrap();
    assert_eq!(sensor_status(last, "heading")["calibration"], 2, "{last}");
    assert_eq!(
        sensor_status(last, "heading")["state"],
        "calibrated",
        "{last}"
    );
    assert_eq!(sensor_status(last, "compass")["calibration"], 1, "{last}");
    assert_eq!(
        sensor_status(last, "compass")["state"],
        "calibrated",
        "{last}"
    );
    // compass had no CALIBRATION since the reload: it kept its state.
    assert!(
        !daemon.seen[from..]
            .iter()
            .any(|v| is_class(v, "CALIBRATION") && v["sensor"] == "compass"),
        "compass was left alone"
    );
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}

/// (c): an invalid file is refused with its file, line and key, and the
/// running configuration goes on unchanged.
#[test]
fn an_invalid_file_is_refused_with_its_key_and_the_old_configuration_keeps_running() {
    let s = setup("0.2", "");
    let mut daemon = Daemon::start(&s.config, &[]);
    both_calibrated(&mut daemon);

    let good = std::fs::read_to_string(&s.config).unwrap();
    write_config(
        s.dir.path(),
        &config_text(
            s.dir.path(),
            &s.capture,
            SPEED,
            "0.2",
            "",
            "modle = [\"paper\", \"cross-axis\"]",
        ),
    );
    let bad_line = std::fs::read_to_string(&s.config)
        .unwrap()
        .lines()
        .position(|l| l.starts_with("modle"))
        .unwrap()
        + 1;
    signal(&daemon, libc::SIGHUP);
    let error = daemon.wait_for_value(Duration::from_secs(10), "an ERROR", |v| {
        is_class(v, "ERROR")
    });
    let message = error["message"].as_str().unwrap();
    let file = s.config.display().to_string();
    assert!(
        message.starts_with(&format!("reload of {file} refused: {file}:{bad_line}:")),
        "{error}"
    );
    assert!(message.contains("sensor[1].modle"), "{error}");
    assert!(
        message.ends_with("; the running configuration is kept"),
        "{error}"
    );
    assert_eq!(error["key"], "sensor[1].modle");
    assert_eq!(error["line"], bad_line);
    let log = daemon.wait_for_log(Duration::from_secs(5), "refused");
    assert!(log.contains("ERROR"), "logged at error: {log}");

    // The old configuration runs on: same sensors, same calibrations, no
    // rotation started.
    let (statuses, lines) = next_statuses(&mut daemon, 10);
    assert!(
        !lines.iter().any(|v| is_class(v, "CALIBRATION")),
        "no new rotation"
    );
    for name in ["compass", "heading"] {
        let sensor = sensor_status(statuses.last().unwrap(), name);
        assert_eq!(sensor["state"], "calibrated");
        assert_eq!(sensor["calibration"], 1);
    }
    assert!(daemon.is_running());
    // And the original file, back in place, is no change from what runs.
    std::fs::write(&s.config, good).unwrap();
    signal(&daemon, libc::SIGHUP);
    let summary = reload_summary(&mut daemon);
    assert!(
        summary["message"]
            .as_str()
            .unwrap()
            .ends_with(": no change"),
        "{summary}"
    );
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}

/// (d): a changed source and a changed TCP listener are reported as
/// needing a restart (saying what is kept); the STATUS interval applies at
/// once.
#[test]
fn source_and_output_changes_need_a_restart_and_the_status_interval_applies_live() {
    let port = free_port();
    let s = setup("0.2", &format!("tcp = \"127.0.0.1:{port}\""));
    let mut daemon = Daemon::start(&s.config, &[]);
    both_calibrated(&mut daemon);

    let other = free_port();
    write_config(
        s.dir.path(),
        &config_text(
            s.dir.path(),
            &s.capture,
            "20.0",
            "1.0",
            &format!("tcp = \"127.0.0.1:{other}\""),
            "",
        ),
    );
    signal(&daemon, libc::SIGHUP);
    let summary = reload_summary(&mut daemon);
    let reload: Vec<&Value> = daemon
        .seen
        .iter()
        .filter(|v| is_class(v, "RELOAD"))
        .collect();
    let messages: Vec<&str> = reload
        .iter()
        .map(|v| v["message"].as_str().unwrap())
        .collect();
    assert!(
        messages.contains(&"[daemon] status_interval_s changed from 0.2 s to 1 s: applied"),
        "{messages:?}"
    );
    let tcp = format!(
        "[outputs] tcp changed to 127.0.0.1:{other}: restart fieldcal to apply; kept 127.0.0.1:{port}"
    );
    assert!(messages.contains(&tcp.as_str()), "{messages:?}");
    let source =
        "[[source]] imu changed (speed): restart fieldcal to apply; it keeps running as it started";
    assert!(messages.contains(&source), "{messages:?}");
    for v in &reload {
        if v["message"] == tcp || v["message"] == source {
            assert_eq!(v["restart"], true, "{v}");
        }
    }
    assert!(
        summary["message"].as_str().unwrap().ends_with(
            "0 sensors changed, 0 added, 0 removed, 2 unchanged; 2 changes need a restart"
        ),
        "{summary}"
    );
    // stdout and stderr are separate pipes: the log line may come a little later.
    daemon.wait_for_log(Duration::from_secs(10), &tcp);
    // The old listener still serves.
    std::net::TcpStream::connect(("127.0.0.1", port)).expect("the TCP listener it started with");
    // STATUS now every second: after the first (at once), gaps of 1 s.
    let (statuses, _) = next_statuses(&mut daemon, 4);
    let times: Vec<f64> = statuses
        .iter()
        .map(|v| v["time"].as_f64().unwrap())
        .collect();
    for pair in times[1..].windows(2) {
        assert!(pair[1] - pair[0] > 0.9, "STATUS at {times:?}");
    }
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}

/// systemd hears RELOADING=1 with the monotonic clock, then READY=1.
#[test]
fn systemd_hears_reloading_then_ready() {
    use std::os::unix::net::UnixDatagram;
    let s = setup("0.2", "");
    let socket_path = s.dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    let mut daemon = Daemon::start(
        &s.config,
        &[("NOTIFY_SOCKET", socket_path.to_str().unwrap())],
    );
    let mut buf = [0u8; 4096];
    let mut receive = || {
        let n = socket.recv(&mut buf).expect("a notification");
        String::from_utf8_lossy(&buf[..n]).into_owned()
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    while !receive().contains("READY=1") {
        assert!(Instant::now() < deadline, "no READY=1");
    }
    let before = monotonic_usec();
    signal(&daemon, libc::SIGHUP);
    let reloading = loop {
        let m = receive();
        if m.contains("RELOADING=1") {
            break m;
        }
        assert!(!m.contains("READY=1"), "READY=1 before RELOADING=1");
    };
    let after = monotonic_usec();
    let usec: u64 = reloading
        .lines()
        .find_map(|l| l.strip_prefix("MONOTONIC_USEC="))
        .unwrap_or_else(|| panic!("no MONOTONIC_USEC in {reloading:?}"))
        .parse()
        .unwrap();
    assert!(
        (before..=after).contains(&usec),
        "{before} <= {usec} <= {after}"
    );
    loop {
        let m = receive();
        if m.contains("READY=1") {
            break;
        }
        assert!(!m.contains("RELOADING=1"), "{m}");
    }
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}

fn monotonic_usec() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    assert_eq!(rc, 0);
    ts.tv_sec as u64 * 1_000_000 + ts.tv_nsec as u64 / 1_000
}

/// A csv sensor's columns change on a real recording (the HMC5883L turning
/// about z, in gauss): the sensor binds the new columns in the header of
/// the file its source is playing, and its readings carry them at once.
#[test]
fn a_csv_sensor_takes_new_columns_of_the_running_recording() {
    let csv = common::shared_path(
        "data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up/hmc5883l_mag.csv",
    );
    let dir = tempfile::tempdir().unwrap();
    let text = |axes: &str| {
        format!(
            "[daemon]\nstate_dir = \"{}\"\n[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\nspeed = 1.0\n\
             [[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = {axes}\n",
            dir.path().join("state").display(),
            csv.display()
        )
    };
    let config = write_config(dir.path(), &text(r#"["mag_x", "mag_z"]"#));
    let mut daemon = Daemon::start(&config, &[]);
    let first = daemon.wait_for_value(Duration::from_secs(10), "a READING", |v| {
        is_class(v, "READING")
    });
    assert!(first["columns"].get("mag_y").is_some(), "{first}");

    write_config(dir.path(), &text(r#"["mag_x", "mag_y"]"#));
    signal(&daemon, libc::SIGHUP);
    let changed = daemon.wait_for_value(Duration::from_secs(10), "the RELOAD of compass", |v| {
        is_class(v, "RELOAD") && v["sensor"] == "compass"
    });
    assert!(
        changed["message"]
            .as_str()
            .unwrap()
            .starts_with("sensor 'compass': axes changed: a new rotation starts"),
        "{changed}"
    );
    let after = daemon.wait_for_value(Duration::from_secs(10), "a READING", |v| {
        is_class(v, "READING")
    });
    assert!(after["columns"].get("mag_y").is_none(), "{after}");
    let mag_z = after["columns"]["mag_z"].as_f64().unwrap();
    assert!((-1.0..1.0).contains(&mag_z), "gauss: {after}");
    let status = daemon.wait_for_value(Duration::from_secs(5), "a STATUS", |v| {
        is_class(v, "STATUS")
    });
    assert_eq!(
        sensor_status(&status, "compass")["state"],
        "collecting",
        "{status}"
    );
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}

/// Issue 23, finding 5: a reload that takes a sensor from 2 axes to 3 and
/// back says that its calibration cannot correct the new axes (it did say
/// "keeps correcting"), and keeps its counts and ids: the next calibration
/// after coming back is #2, never #1 again.
#[test]
fn a_reload_to_the_other_number_of_axes_says_so_and_keeps_ids_and_counts() {
    let s = setup("0.2", "");
    let mut daemon = Daemon::start(&s.config, &[]);
    both_calibrated(&mut daemon);
    let (before, _) = next_statuses(&mut daemon, 1);
    let readings_before = sensor_status(&before[0], "heading")["readings"]
        .as_u64()
        .unwrap();
    let axes = |n: &str| {
        // The second sensor's axes (heading's).
        let text = config_text(s.dir.path(), &s.capture, SPEED, "0.2", "", "");
        let at = text.rfind("axes = [\"x\", \"y\"]").unwrap();
        format!(
            "{}{n}{}",
            &text[..at],
            &text[at + "axes = [\"x\", \"y\"]".len()..]
        )
    };
    write_config(s.dir.path(), &axes("axes = [\"x\", \"y\", \"z\"]"));
    signal(&daemon, libc::SIGHUP);
    let changed = daemon.wait_for_value(Duration::from_secs(10), "the RELOAD of heading", |v| {
        is_class(v, "RELOAD") && v["sensor"] == "heading"
    });
    let message = changed["message"].as_str().unwrap();
    assert!(!message.contains("keeps correcting"), "{message}");
    assert!(
        message.contains(
            "its axes went from 2 to 3, so calibration #1 (offset+scale) cannot correct it"
        ),
        "{message}"
    );
    let reading = daemon.wait_for_value(Duration::from_secs(5), "a READING of heading", |v| {
        is_class(v, "READING") && v["sensor"] == "heading"
    });
    assert_eq!(reading["calibrated"], false, "{reading}");
    let (after, _) = next_statuses(&mut daemon, 2);
    let status = sensor_status(after.last().unwrap(), "heading");
    assert!(
        status["readings"].as_u64().unwrap() > readings_before,
        "the count restarted: {status}"
    );
    assert_eq!(status["fits_accepted"], 1, "{status}");
    // Back to two axes: a new turn gives calibration #2.
    write_config(s.dir.path(), &axes("axes = [\"x\", \"y\"]"));
    signal(&daemon, libc::SIGHUP);
    let new = daemon.wait_for_value(Duration::from_secs(30), "heading's next CALIBRATION", |v| {
        calibration_of(v, "heading")
    });
    assert_eq!(new["id"], 2, "{new}");
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}

/// Writes a token file of mode 600.
fn token_file(dir: &Path, token: &str) -> PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let path = dir.join("token");
    std::fs::write(&path, format!("{token}\n")).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    path
}

#[test]
fn a_new_token_applies_at_the_reload_and_the_old_one_is_refused_from_then_on() {
    let (old, new) = ("old-token-0123456789", "new-token-9876543210");
    let port = free_port();
    let dir = tempfile::tempdir().unwrap();
    let file = token_file(dir.path(), old);
    let s = setup(
        "0.2",
        &format!(
            "tcp = \"127.0.0.1:{port}\"\ntoken_file = \"{}\"",
            file.display()
        ),
    );
    let mut daemon = Daemon::start(&s.config, &[]);
    both_calibrated(&mut daemon);
    let mut client = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    let recalibrate = |token: &str| format!(r#"{{"command":"recalibrate","token":"{token}"}}"#);
    assert!(errors(&ask(&mut client, &recalibrate(old))).is_empty());

    // The file now holds another token (the old one leaked).
    token_file(dir.path(), new);
    signal(&daemon, libc::SIGHUP);
    let summary = reload_summary(&mut daemon);
    assert!(
        summary["message"]
            .as_str()
            .unwrap()
            .ends_with("0 changes need a restart"),
        "{summary}"
    );
    assert!(
        daemon.seen.iter().any(|v| is_class(v, "RELOAD")
            && v["message"]
                == "[outputs] token_file holds a new token: applied; the old one is refused from now on"),
        "{:?}",
        daemon.seen
    );
    let refused = errors(&ask(&mut client, &recalibrate(old)));
    assert!(
        refused.len() == 1 && refused[0].contains("does not match"),
        "{refused:?}"
    );
    assert!(errors(&ask(&mut client, &recalibrate(new))).is_empty());

    // token_file removed from the file: no token is accepted any more.
    write_config(
        s.dir.path(),
        &config_text(
            s.dir.path(),
            &s.capture,
            SPEED,
            "0.2",
            &format!("tcp = \"127.0.0.1:{port}\""),
            "",
        ),
    );
    signal(&daemon, libc::SIGHUP);
    reload_summary(&mut daemon);
    assert!(daemon.seen.iter().any(|v| is_class(v, "RELOAD")
        && v["message"]
            == "[outputs] token_file removed: applied; no token is accepted from now on"));
    let refused = errors(&ask(&mut client, &recalibrate(new)));
    assert!(refused.len() == 1, "{refused:?}");
    assert_eq!(daemon.terminate().code(), Some(0), "{}", daemon.stderr());
}
