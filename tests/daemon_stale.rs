//! A calibration watched after it is accepted: each later rotation is
//! fitted and compared with it. A permanent magnet (an offset step) gives a
//! `STALE` line on the next complete rotation and never before; a drift
//! within the noise, or a robot that stands still, gives none; with
//! `learn = true` the calibration is refined by each rotation that agrees;
//! `rollback` returns to the calibration before.

mod common;

use std::time::Duration;

use common::daemon::{Daemon, is_class, replay_config};
use common::faults::{long_capture, send_unix_command};
use serde_json::Value;

/// Seconds a turn takes (18 °/s).
const TURN_S: f64 = 20.0;

/// A 2-axis compass at 20 Hz turning at 18 °/s for `turning_s`, then still,
/// with a gyro about its turn: hard iron (120, -80) plus `offset(t)` on x,
/// gain 1.1 on x, field 500 counts, uniform noise of ±`noise` counts.
fn recording(seconds: f64, turning_s: f64, noise: f64, offset: impl Fn(f64) -> f64) -> String {
    let mut text = String::from("t,x,y,gyro_z\n");
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut uniform = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % 20_001) as f64 / 10_000.0 - 1.0
    };
    for k in 0..(seconds * 20.0) as usize {
        let t = k as f64 / 20.0;
        let (heading, rate) = if t < turning_s {
            (18.0 * t, 18.0)
        } else {
            (18.0 * turning_s, 0.0)
        };
        let h = f64::to_radians(heading);
        let x = 120.0 + offset(t) + 1.1 * 500.0 * h.cos() + noise * uniform();
        let y = -80.0 + 500.0 * h.sin() + noise * uniform();
        text.push_str(&format!("{t:.2},{x:.3},{y:.3},{rate:.1}\n"));
    }
    text
}

/// Replays `csv` through the daemon (`fieldcal replay`: no state read or
/// written), the sensor's section ending with `extra`; the lines out.
fn replay(csv: &str, extra: &str) -> Vec<Value> {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), csv, extra, "");
    let file = dir.path().join("robot.csv");
    lines_of(&common::run_ok(&[
        "replay",
        file.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--speed",
        "max",
    ]))
}

/// Runs the daemon (`fieldcal run`, its state directory in `dir`, kept
/// between calls) on `csv` at full speed; the lines out.
fn run_in(dir: &std::path::Path, csv: &str) -> Vec<Value> {
    let config = write_config(dir, csv, "", "speed = \"max\"\n");
    lines_of(&common::run_ok(&[
        "run",
        "--config",
        config.to_str().unwrap(),
        "--progress",
        "never",
    ]))
}

fn write_config(dir: &std::path::Path, csv: &str, extra: &str, source: &str) -> std::path::PathBuf {
    std::fs::write(dir.join("robot.csv"), csv).unwrap();
    let config = dir.join("robot.toml");
    std::fs::write(
        &config,
        format!(
            "[daemon]\nstate_dir = \"{}\"\nstatus_interval_s = 1000.0\n[outputs]\nstdout = true\n\
             [[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"robot.csv\"\n{source}\
             [[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"x\", \"y\"]\ngyro = \"gyro_z\"\n{extra}\n",
            dir.join("state").display()
        ),
    )
    .unwrap();
    config
}

fn lines_of(out: &str) -> Vec<Value> {
    out.lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn of_class<'a>(lines: &'a [Value], class: &str) -> Vec<&'a Value> {
    lines.iter().filter(|v| is_class(v, class)).collect()
}

fn calibrated_readings(lines: &[Value]) -> Vec<&Value> {
    lines
        .iter()
        .filter(|v| is_class(v, "READING") && v["calibrated"] == true)
        .collect()
}

/// The paper's parameters of the simulated compass: a = 1/1.1, b = −a·120,
/// d = 80, r = 500.
fn truth(name: &str) -> f64 {
    let a = 1.0 / 1.1;
    match name {
        "a" => a,
        "b" => -a * 120.0,
        "d" => 80.0,
        "r" => 500.0,
        _ => unreachable!(),
    }
}

#[test]
fn a_permanent_magnet_gives_stale_on_the_next_rotation_and_never_before() {
    // 25 counts (5 % of the field) on x from 130 s, turning throughout.
    let step = 130.0;
    let csv = recording(260.0, 260.0, 1.0, |t| if t >= step { 25.0 } else { 0.0 });
    let lines = replay(&csv, "");
    let stale = of_class(&lines, "STALE");
    assert_eq!(
        stale.len(),
        1,
        "one STALE, then the sensor waits: {stale:?}"
    );
    let s = stale[0];
    let time = s["time"].as_f64().unwrap();
    assert!(
        time > step && time <= step + TURN_S + 1.0,
        "STALE on the first rotation completed after the step, not at {time}"
    );
    assert_eq!(s["sensor"], "compass");
    assert_eq!(s["calibration"], 1);
    assert_eq!(s["action"], "warn");
    let moved: Vec<&str> = s["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["moved"] == true)
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert!(moved.contains(&"b"), "the x offset moved: {s}");
    let b = s["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "b")
        .unwrap();
    assert!(b["z"].as_f64().unwrap().abs() > s["z_threshold"].as_f64().unwrap());
    let error = s["heading_error_deg"].as_f64().unwrap();
    assert!(
        error > s["heading_limit_deg"].as_f64().unwrap() && error > 1.0,
        "{s}"
    );
    assert!(
        s["message"].as_str().unwrap().contains("recalibrate"),
        "{s}"
    );
    // Every reading before the step is trusted; after the STALE none is,
    // each saying why.
    let readings = calibrated_readings(&lines);
    let before: Vec<_> = readings
        .iter()
        .filter(|v| v["time"].as_f64().unwrap() < step)
        .collect();
    assert!(before.iter().all(|v| v["trusted"] == true));
    let after: Vec<_> = readings
        .iter()
        .filter(|v| v["time"].as_f64().unwrap() > time)
        .collect();
    assert!(after.len() > 1000);
    for v in after {
        assert_eq!(v["trusted"], false, "{v}");
        let reason = v["distrust"][0].as_str().unwrap();
        assert!(reason.starts_with("calibration #1 is stale"), "{reason}");
    }
}

#[test]
fn with_on_stale_replace_a_clean_rotation_becomes_the_calibration() {
    let step = 130.0;
    let csv = recording(260.0, 260.0, 1.0, |t| if t >= step { 25.0 } else { 0.0 });
    let lines = replay(&csv, "on_stale = \"replace\"");
    let stale = of_class(&lines, "STALE");
    assert_eq!(stale.len(), 1, "{stale:?}");
    assert_eq!(stale[0]["action"], "replace");
    // The rotation that showed the change straddled it: not taken as the
    // calibration, a clean one is collected.
    let message = stale[0]["message"].as_str().unwrap();
    assert!(
        message.contains("the rotation straddled the change"),
        "{message}"
    );
    let stale_time = stale[0]["time"].as_f64().unwrap();
    let replaced: Vec<_> = of_class(&lines, "CALIBRATION")
        .into_iter()
        .filter(|v| v["origin"] == "replaced")
        .collect();
    assert_eq!(replaced.len(), 1, "{replaced:?}");
    let r = replaced[0];
    assert_eq!(
        (r["accepted"].clone(), r["id"].clone(), r["parent"].clone()),
        (true.into(), 2.into(), 1.into())
    );
    let replaced_time = r["time"].as_f64().unwrap();
    assert!(replaced_time > stale_time && replaced_time <= stale_time + TURN_S + 1.0);
    // The sensor as it is now: the x offset 145, so b = −145/1.1.
    let b = r["params"]["b"].as_f64().unwrap();
    assert!((b + 145.0 / 1.1).abs() < 0.5, "b = {b}");
    let readings = calibrated_readings(&lines);
    let between: Vec<_> = readings
        .iter()
        .filter(|v| (stale_time + 0.01..replaced_time).contains(&v["time"].as_f64().unwrap()))
        .collect();
    assert!(between.len() > 300);
    for v in between {
        assert_eq!(v["trusted"], false, "{v}");
        let reason = v["distrust"][0].as_str().unwrap();
        assert!(
            reason.contains("a new rotation is being collected to replace it"),
            "{reason}"
        );
    }
    let after: Vec<_> = readings
        .iter()
        .filter(|v| v["time"].as_f64().unwrap() > replaced_time)
        .collect();
    assert!(after.len() > 1000);
    assert!(
        after
            .iter()
            .all(|v| v["calibration"] == 2 && v["trusted"] == true)
    );
}

#[test]
fn a_drift_within_the_noise_and_a_robot_standing_still_give_no_stale() {
    // The x offset drifts by 1.5 counts while it turns (a warming sensor):
    // far beyond its standard error (about 0.07), but a heading change (at
    // most 0.16°) within the band of a reading's noise (uniform ±1 count
    // of 500: 0.066° rms, 3 σ 0.2°); it turns for 200 s, then stands still
    // for 200 s.
    let csv = recording(400.0, 200.0, 1.0, |t| 1.5 * t.min(200.0) / 200.0);
    let lines = replay(&csv, "");
    assert!(of_class(&lines, "STALE").is_empty());
    let calibrations = of_class(&lines, "CALIBRATION");
    assert_eq!(calibrations.len(), 1, "{calibrations:?}");
    let readings = calibrated_readings(&lines);
    assert!(readings.len() > 7000);
    let distrusted: Vec<_> = readings.iter().filter(|v| v["trusted"] == false).collect();
    assert!(distrusted.is_empty(), "{:?}", distrusted.first());
}

#[test]
fn learning_from_ten_rotations_shrinks_the_standard_errors_within_them() {
    let csv = recording(260.0, 260.0, 1.0, |_| 0.0);
    let lines = replay(&csv, "learn = true");
    assert!(of_class(&lines, "STALE").is_empty());
    let calibrations = of_class(&lines, "CALIBRATION");
    let refined: Vec<_> = calibrations
        .iter()
        .filter(|v| v["origin"] == "refined")
        .collect();
    assert!(refined.len() >= 10, "{} refinements", refined.len());
    let mut parent = calibrations[0];
    assert_eq!(parent["origin"], "rotation");
    for r in refined {
        assert_eq!(r["parent"], parent["id"], "{r}");
        assert_eq!(r["id"].as_u64(), parent["id"].as_u64().map(|i| i + 1));
        for name in ["a", "b", "d", "r"] {
            let (old, new) = (&parent["params"][name], &r["params"][name]);
            let (old_se, new_se) = (
                parent["se"][name].as_f64().unwrap(),
                r["se"][name].as_f64().unwrap(),
            );
            assert!(new_se < old_se, "{name}: {new_se} after {old_se}");
            let moved = (new.as_f64().unwrap() - old.as_f64().unwrap()).abs();
            assert!(
                moved <= old_se,
                "{name} moved {moved}, beyond its SE {old_se}"
            );
        }
        assert!(r["rms"].as_f64().unwrap() < 0.0025, "{r}");
        parent = r;
    }
    for name in ["a", "b", "d", "r"] {
        let (value, se) = (
            parent["params"][name].as_f64().unwrap(),
            parent["se"][name].as_f64().unwrap(),
        );
        assert!(
            (value - truth(name)).abs() <= 3.0 * se,
            "{name} = {value} ± {se}, truth {}",
            truth(name)
        );
    }
    assert!(
        calibrated_readings(&lines)
            .iter()
            .all(|v| v["trusted"] == true)
    );
}

#[test]
fn rollback_returns_to_the_calibration_before_and_stores_it() {
    let dir = tempfile::tempdir().unwrap();
    let capture = long_capture(dir.path(), 100);
    let socket = dir.path().join("fieldcal.sock");
    let outputs = format!("stdout = true\nunix = \"{}\"", socket.display());
    let config = replay_config(dir.path(), &capture, "20.0", &outputs);
    let mut daemon = Daemon::start(&config, &[]);
    let long = Duration::from_secs(60);
    let calibration = |daemon: &mut Daemon| {
        daemon.wait_for_value(long, "a CALIBRATION", |v| is_class(v, "CALIBRATION"))
    };
    assert_eq!(calibration(&mut daemon)["id"], 1);
    send_unix_command(&socket, r#"{"command":"recalibrate"}"#);
    assert_eq!(calibration(&mut daemon)["id"], 2);
    send_unix_command(&socket, r#"{"command":"rollback","sensor":"compass"}"#);
    let back = calibration(&mut daemon);
    assert_eq!(
        (back["id"].clone(), back["origin"].clone()),
        (1.into(), "rollback".into()),
        "{back}"
    );
    let reading = daemon.wait_for_value(long, "a READING", |v| is_class(v, "READING"));
    assert_eq!(reading["calibration"], 1, "{reading}");
    // Stored: calibration 1 again, with nothing kept before it.
    let file = dir.path().join("state/compass.json");
    let deadline = std::time::Instant::now() + long;
    loop {
        let stored: Value =
            serde_json::from_str(&std::fs::read_to_string(&file).unwrap_or_default())
                .unwrap_or_default();
        if stored["calibration"]["id"] == 1 {
            assert!(stored["calibration"].get("history").is_none(), "{stored}");
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "calibration 1 never stored again"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    // Nothing before it to return to: said, and nothing changes.
    let error = ask(&socket, r#"{"command":"rollback"}"#, "ERROR");
    assert!(
        error["message"]
            .as_str()
            .unwrap()
            .contains("cannot roll back: no earlier calibration is kept"),
        "{error}"
    );
    daemon.terminate();
}

/// Sends `command` over the Unix socket and returns the first line of
/// `class` the daemon sends back on that connection.
fn ask(socket: &std::path::Path, command: &str, class: &str) -> Value {
    use std::io::{BufRead, BufReader, Write};
    let mut stream = std::os::unix::net::UnixStream::connect(socket).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    writeln!(stream, "{command}").unwrap();
    for line in BufReader::new(stream).lines() {
        let v: Value = serde_json::from_str(&line.unwrap()).unwrap();
        if is_class(&v, class) {
            return v;
        }
    }
    panic!("no {class} line came back");
}

#[test]
fn a_stored_calibration_keeps_its_gyro_check_after_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let first = run_in(dir.path(), &recording(40.0, 40.0, 1.0, |_| 0.0));
    let accepted = of_class(&first, "CALIBRATION");
    assert_eq!(accepted[0]["accepted"], true);
    let stored: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("state/compass.json")).unwrap(),
    )
    .unwrap();
    let gyro = &stored["calibration"]["gyro"];
    assert!(
        (gyro["scale"].as_f64().unwrap() - 1.0).abs() < 0.01,
        "{stored}"
    );
    // Restarted on the stored calibration: still, with a swing of 20° the
    // gyro does not see between 10 and 15 s.
    let mut text = String::from("t,x,y,gyro_z\n");
    for k in 0..600 {
        let t = k as f64 / 20.0;
        let h = f64::to_radians(if (10.0..15.0).contains(&t) {
            50.0
        } else {
            30.0
        });
        let (x, y) = (120.0 + 550.0 * h.cos(), -80.0 + 500.0 * h.sin());
        text.push_str(&format!("{t:.2},{x:.3},{y:.3},0.0\n"));
    }
    let second = run_in(dir.path(), &text);
    assert_eq!(of_class(&second, "CALIBRATION")[0]["origin"], "state");
    // `run` puts the recording on the wall clock: times from its first row.
    let readings = calibrated_readings(&second);
    let t0 = readings[0]["time"].as_f64().unwrap();
    let swung: Vec<_> = readings
        .into_iter()
        .filter(|v| (9.99..14.99).contains(&(v["time"].as_f64().unwrap() - t0)))
        .collect();
    assert_eq!(swung.len(), 100);
    for v in &swung {
        assert_eq!(v["trusted"], false, "{v}");
    }
    let reason = swung[0]["distrust"][0].as_str().unwrap();
    assert!(reason.starts_with("the heading moved 20.0°"), "{reason}");
}
