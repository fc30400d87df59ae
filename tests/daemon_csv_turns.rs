//! A robot's 10 Hz log through `fieldcal run` with a csv source and the
//! default rotation settings: a turn at uneven speed with pauses completes,
//! and so does the first of several turns; readings that never went all the
//! way round (still, sliding, back and forth) never give a calibration.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::daemon::{Daemon, write_config};
use serde_json::Value;

/// An LSM303-like compass in counts: field 450 counts, unequal gains, an
/// offset of about a radius, noise 2 counts, rounded to whole counts.
fn compass_row(heading_deg: f64, rng: &mut u64) -> (f64, f64) {
    let mut gauss = || {
        // Box-Muller on a 64-bit LCG: deterministic, no dependency.
        let mut u = || {
            *rng = rng
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((*rng >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u1, u2) = (u(), u());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    let h = heading_deg.to_radians();
    let x = 380.0 + 1.07 * 450.0 * h.cos() + 2.0 * gauss();
    let y = -260.0 + 0.94 * 450.0 * h.sin() + 2.0 * gauss();
    (x.round(), y.round())
}

/// Writes `t,mag_x_lsb,mag_z_lsb,temp_c` at 10 Hz for `seconds`, the raw
/// readings given by `reading(t, rng)`.
fn write_log(path: &Path, seconds: f64, mut reading: impl FnMut(f64, &mut u64) -> (f64, f64)) {
    let mut rng = 0x2545_F491_4F6C_DD1D_u64;
    let mut text = String::from("t,mag_x_lsb,mag_z_lsb,temp_c\n");
    let n = (seconds * 10.0).round() as usize;
    for i in 0..n {
        let t = i as f64 * 0.1;
        let (x, y) = reading(t, &mut rng);
        text.push_str(&format!("{t:.1},{x},{y},24.5\n"));
    }
    std::fs::write(path, text).unwrap();
}

/// A heading profile from legs of (seconds, degrees per second).
fn legs(t: f64, legs: &[(f64, f64)]) -> f64 {
    let (mut start, mut heading) = (0.0, 0.0);
    for &(seconds, rate) in legs {
        if t < start + seconds {
            return heading + rate * (t - start);
        }
        start += seconds;
        heading += rate * seconds;
    }
    heading
}

fn config(dir: &Path, csv: &Path) -> PathBuf {
    write_config(
        dir,
        &format!(
            r#"
[daemon]
state_dir = "{state}"

[outputs]
stdout = true

[[source]]
name = "log"
kind = "csv"
file = "{csv}"
speed = "max"

[[sensor]]
name = "robot"
source = "log"
axes = ["mag_x_lsb", "mag_z_lsb"]
"#,
            state = dir.join("state").display(),
            csv = csv.display(),
        ),
    )
}

/// Runs the daemon on the log to its end; its CALIBRATION messages (times
/// made relative to the first reading) and stderr.
fn calibrations(dir: &Path, csv: &Path) -> (Vec<(f64, Value)>, String) {
    let (lines, stderr) = run_log(dir, csv);
    let first = lines
        .iter()
        .find(|v| v["class"] == "READING")
        .and_then(|v| v["time"].as_f64())
        .expect("no READING");
    let cals = lines
        .iter()
        .filter(|v| v["class"] == "CALIBRATION")
        .map(|v| (v["time"].as_f64().unwrap() - first, v.clone()))
        .collect();
    (cals, stderr)
}

/// Runs the daemon on the log to its end: every line it published, and
/// its stderr.
fn run_log(dir: &Path, csv: &Path) -> (Vec<Value>, String) {
    let mut daemon = Daemon::start(&config(dir, csv), &[]);
    let lines = daemon.drain(Duration::from_secs(60));
    assert!(
        daemon.wait(Duration::from_secs(10)).success(),
        "{}",
        daemon.stderr()
    );
    (lines, daemon.stderr())
}

fn accepted(cals: &[(f64, Value)]) -> Vec<&(f64, Value)> {
    cals.iter().filter(|(_, v)| v["accepted"] == true).collect()
}

#[test]
fn one_turn_at_uneven_speed_with_pauses_is_calibrated_with_the_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("turn.csv");
    // 100° quickly, a 3 s stop, 150° slowly, a 2 s stop, the last 130°
    // quickly (2-4 samples per 10°), then 3 s still: 380° in all, 21.5 s.
    let profile = [
        (3.3, 30.0),
        (3.0, 0.0),
        (10.0, 15.0),
        (2.0, 0.0),
        (3.2, 40.6),
    ];
    write_log(&csv, 24.5, |t, rng| compass_row(legs(t, &profile), rng));
    let (cals, stderr) = calibrations(dir.path(), &csv);
    let ok = accepted(&cals);
    assert_eq!(ok.len(), 1, "calibrations {cals:?}\n{stderr}");
    let (at, cal) = ok[0];
    // Complete within the turn: after 330° (20.7 s) and by its end (21.5 s).
    assert!((18.0..=21.6).contains(at), "completed at {at} s: {cal}");
    let a = cal["params"]["a"].as_f64().unwrap();
    assert!((a - 0.94 / 1.07).abs() < 0.02, "gain ratio {a}: {cal}");
    assert!(cal["rms"].as_f64().unwrap() < 0.02, "{cal}");
}

#[test]
fn the_first_of_several_uneven_turns_is_calibrated() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("turns.csv");
    // Three turns of 12 s each, speed swinging between 10 and 50 °/s.
    write_log(&csv, 36.0, |t, rng| {
        let heading =
            30.0 * t - 60.0 / std::f64::consts::TAU * 4.0 * (std::f64::consts::TAU * t / 4.0).cos();
        compass_row(heading, rng)
    });
    let (cals, stderr) = calibrations(dir.path(), &csv);
    let ok = accepted(&cals);
    assert_eq!(ok.len(), 1, "calibrations {cals:?}\n{stderr}");
    assert!(
        ok[0].0 <= 12.5,
        "completed at {} s, after the first turn",
        ok[0].0
    );
}

fn assert_never_calibrated(
    name: &str,
    seconds: f64,
    reading: impl FnMut(f64, &mut u64) -> (f64, f64),
) -> Vec<(f64, Value)> {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join(format!("{name}.csv"));
    write_log(&csv, seconds, reading);
    let (cals, stderr) = calibrations(dir.path(), &csv);
    assert!(
        accepted(&cals).is_empty(),
        "{name}: calibrated: {cals:?}\n{stderr}"
    );
    cals
}

#[test]
fn a_still_robot_is_never_calibrated_and_told_to_turn() {
    let cals = assert_never_calibrated("still", 40.0, |_, rng| compass_row(75.0, rng));
    assert!(
        !cals.is_empty(),
        "the still log was never reported as not turning"
    );
    for (_, c) in &cals {
        let reason = c["reason"].as_str().unwrap_or_default();
        assert!(reason.contains("not turning"), "{c}");
    }
}

#[test]
fn a_robot_that_slides_without_turning_is_never_calibrated() {
    // Driven 30 s in a straight line past a steel cabinet: the field moves
    // by a quarter of its size along one direction and back.
    assert_never_calibrated("slide", 40.0, |t, rng| {
        let (x, y) = compass_row(40.0, rng);
        let bump = 110.0 * (std::f64::consts::PI * t / 40.0).sin();
        (x + bump, y + 0.4 * bump)
    });
}

#[test]
fn a_robot_that_turns_back_and_forth_is_never_calibrated() {
    // ±150° swings every 8 s for 90 s: every heading but a 60° gap, twice a
    // swing, never all the way round.
    assert_never_calibrated("swing", 90.0, |t, rng| {
        compass_row(150.0 * (std::f64::consts::TAU * t / 8.0).sin(), rng)
    });
}

#[test]
fn one_bad_row_is_refused_as_a_spike_and_the_first_turn_is_still_calibrated() {
    // Six steady turns of 10 s; one row mid-way through the first carries
    // garbage on one axis (a bad frame, EMI, a loose connector).
    for (column, bad) in [(0, 65535.0), (0, 1e6), (1, 1e9), (0, -4096.0), (1, 5000.0)] {
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("spike.csv");
        write_log(&csv, 60.0, |t, rng| {
            let (x, y) = compass_row(36.0 * t, rng);
            let spoilt = (t - 4.3).abs() < 0.05;
            match (spoilt, column) {
                (true, 0) => (bad, y),
                (true, _) => (x, bad),
                _ => (x, y),
            }
        });
        let (lines, stderr) = run_log(dir.path(), &csv);
        let cals: Vec<&Value> = lines
            .iter()
            .filter(|v| v["class"] == "CALIBRATION")
            .collect();
        let why = format!("{bad} in column {column}: {cals:?}\n{stderr}");
        // The first turn gives the calibration, and no refusal comes
        // before it.
        let first_fit = cals.first().unwrap_or_else(|| panic!("no fit: {why}"));
        assert!(first_fit["accepted"] == true, "{why}");
        let readings_before = lines
            .iter()
            .take_while(|v| v["class"] != "CALIBRATION")
            .filter(|v| v["class"] == "READING")
            .count();
        assert!(readings_before <= 110, "{readings_before} readings: {why}");
        let a = first_fit["params"]["a"].as_f64().unwrap();
        assert!((a - 0.94 / 1.07).abs() < 0.02, "gain ratio {a}: {why}");
        // Every row was published, the spike among them, and counted.
        let readings = lines.iter().filter(|v| v["class"] == "READING").count();
        assert_eq!(readings, 600, "{why}");
        let status = lines
            .iter()
            .rfind(|v| v["class"] == "STATUS")
            .expect("a STATUS");
        let robot = &status["sensors"][0];
        assert_eq!(robot["spikes"], 1, "{status}");
        let axis = ["x", "y"][column];
        let said = robot["last_spike"].as_str().unwrap_or_default();
        // At the spoilt row's time, on the readings' clock.
        let first = lines
            .iter()
            .find(|v| v["class"] == "READING")
            .and_then(|v| v["time"].as_f64())
            .unwrap();
        assert!(
            said.starts_with(&format!("a spike at t = {:.3} s: {axis} = ", first + 4.3)),
            "{said}"
        );
        assert!(stderr.contains(said), "{stderr}");
    }
}
