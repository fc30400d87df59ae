//! The daemon's heading check: each CALIBRATION of a sensor whose source
//! carries a gyro says how far the fitted model's heading strays from the
//! integrated gyro (`heading_vs_gyro`), or why no check was possible
//! (`heading_check`); a failed check never rejects a calibration.

mod common;

use std::path::Path;

use fieldcal::protocol::chips::Chip;
use fieldcal::sample::Reading;
use fieldcal::sim::SimSensor;
use serde_json::Value;

/// Replays `capture` through the daemon's pipeline with the `[[sensor]]`
/// tables `sensors` on a replay source `imu`; returns the CALIBRATION
/// lines and the log (stderr).
fn calibrations(capture: &Path, sensors: &str, dir: &Path) -> (Vec<Value>, String) {
    let (lines, log) = common::replay_through(capture, sensors, dir);
    let found = lines
        .into_iter()
        .filter(|v| v["class"] == "CALIBRATION")
        .collect();
    (found, log)
}

const COMPASS: &str =
    "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// The rms heading error the noise alone makes, in degrees: per sample the
/// noise across the circle is sqrt(sigma^2 + 1/12) counts per raw axis (the
/// frame's rounding to whole counts adds 1/12), the x axis scaled by the
/// fitted a, over the calibrated radius r.
fn noise_heading_deg(sigma: f64, calibration: &Value) -> f64 {
    let a = f(&calibration["params"]["a"]);
    let r = f(&calibration["params"]["r"]);
    let per_axis = (sigma * sigma + 1.0 / 12.0).sqrt();
    (per_axis * ((a * a + 1.0) / 2.0).sqrt() / r).to_degrees()
}

#[test]
fn a_falcon_turn_is_checked_against_its_gyro_to_within_the_noise() {
    let dir = tempfile::tempdir().unwrap();
    for (noise, seed, gain_x, offset_x) in [
        (1.0, 4, 1.0, 0.0),
        (3.0, 5, 1.1, 150.0),
        (10.0, 6, 0.8, -900.0),
    ] {
        let capture = dir.path().join(format!("turn{seed}.fcap"));
        common::run_ok(&[
            "simulate",
            "--format",
            "falcon",
            "--noise",
            &noise.to_string(),
            "--seed",
            &seed.to_string(),
            "--gain-x",
            &gain_x.to_string(),
            "--offset-x",
            &offset_x.to_string(),
            "--turns",
            "1.5",
            "-o",
            capture.to_str().unwrap(),
        ]);
        let (found, log) = calibrations(&capture, COMPASS, dir.path());
        let calibration = &found[0];
        assert_eq!(calibration["accepted"], true, "{calibration}");
        let check = &calibration["heading_vs_gyro"];
        assert_eq!(check["gyro_column"], "gyro_z", "{calibration}");
        assert_eq!(check["n"], calibration["n"], "{calibration}");
        assert!(calibration.get("heading_check").is_none(), "{calibration}");
        // The simulated frames carry the true rate at the frame's scale.
        assert!(
            (f(&check["gyro_scale"]) - 1.0).abs() < 0.01,
            "{calibration}"
        );
        // The gyro is exact: what remains is the field sensor's noise, whose
        // rms over ~200 samples is within a few percent of its deviation.
        let expected = noise_heading_deg(noise, calibration);
        let rms = f(&check["rms_deg"]);
        assert!(
            (0.8 * expected..1.25 * expected).contains(&rms),
            "noise {noise}: heading rms {rms}°, the noise makes {expected}°: {calibration}"
        );
        assert!(f(&check["peak_to_peak_deg"]) > 2.0 * rms, "{calibration}");
        assert!(log.contains("heading against gyro_z"), "{log}");
    }
}

#[test]
fn a_check_that_fails_is_said_and_does_not_reject_the_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let capture = common::repo_path("tests/data/falcon_turn.fcap");
    // 16 counts per deg/s on frames written at 10: the gyro reads 1.6 times
    // too slow, beyond any gyro about the turn's axis (±3 % sensitivity, or
    // cos 45° of the rate when tilted).
    let sensor = format!("{COMPASS}gyro_lsb_per_deg_s = 16.0\n");
    let (found, log) = calibrations(&capture, &sensor, dir.path());
    let calibration = &found[0];
    assert_eq!(calibration["accepted"], true, "{calibration}");
    assert!(
        calibration.get("heading_vs_gyro").is_none(),
        "{calibration}"
    );
    let why = calibration["heading_check"].as_str().unwrap();
    assert!(
        why.starts_with("no heading check against gyro_z: the heading turns 1.60 times"),
        "{why}"
    );
    assert!(
        why.contains("is not the axis about which the sensor turned"),
        "{why}"
    );
    assert!(
        log.contains("calibration accepted; heading not checked: no heading check against gyro_z"),
        "{log}"
    );

    // 131 counts per deg/s (an MPU-6050's): the gyro seems not to turn
    // (the rotation completes once the readings turned 330°, which the gyro
    // reads as 330 x 10 / 131 = 25°).
    let sensor = format!("{COMPASS}gyro_lsb_per_deg_s = 131.0\n");
    let (found, _) = calibrations(&capture, &sensor, dir.path());
    assert_eq!(found[0]["accepted"], true, "{}", found[0]);
    let why = found[0]["heading_check"].as_str().unwrap();
    assert!(
        why.starts_with(
            "no heading check against gyro_z: the gyro 'gyro_z' turns through only 25°"
        ),
        "{why}"
    );

    // Turned off in the configuration: said so.
    let sensor = format!("{COMPASS}gyro = \"none\"\n");
    let (found, _) = calibrations(&capture, &sensor, dir.path());
    assert_eq!(
        found[0]["heading_check"],
        "no heading check: gyro = \"none\" in the configuration"
    );
    assert!(found[0].get("heading_vs_gyro").is_none());
}

/// A bridge polling an LSM303DLHC magnetometer (stream 0) turning once in
/// 6 s, and an MPU-6050 (stream 1) 4 ms after it whose gyro z reads the true
/// rate at 131 counts per deg/s: a capture of two streams on one clock.
fn bridge_capture(path: &Path, noise: f64) {
    let sim = SimSensor {
        field: 500.0,
        offset_x: 60.0,
        offset_y: -40.0,
        gain_x: 1.05,
        noise,
        period: 0.03,
        turn_seconds: 6.0,
        turns: 1.5,
        seed: 9,
        ..Default::default()
    };
    let data = sim.simulate().unwrap();
    let rate = (360.0 / sim.turn_seconds * 131.0).round() as i16;
    let t = data.t.as_ref().unwrap();
    let mut records = Vec::new();
    for ((&time, &x), &y) in t.iter().zip(&data.x).zip(&data.y) {
        let mag = Reading {
            mag: Some([x.round() as i16, y.round() as i16, 100]),
            ..Reading::default()
        };
        let imu = Reading {
            accel: Some([0, 0, 16384]),
            gyro: Some([3, -2, rate]),
            temp_c: Some(25.0),
            ..Reading::default()
        };
        records.push((time, 0, mag));
        records.push((time + 0.004, 1, imu));
    }
    common::write_bridge_capture(
        path,
        &[Chip::Lsm303dlhcMag, Chip::Mpu6050],
        sim.period,
        "test: mag and gyro on one bridge",
        records,
    );
}

#[test]
fn a_gyro_on_another_chip_of_the_bridge_is_joined_by_time_and_a_chip_without_one_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("bridge.fcap");
    let noise = 2.0;
    bridge_capture(&capture, noise);
    let sensors = "[[sensor]]\nname = \"alone\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n\
                   [[sensor]]\nname = \"joined\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n\
                   gyro_chip = \"mpu6050\"\ngyro = \"z\"\n";
    let (found, _) = calibrations(&capture, sensors, dir.path());
    let alone = found.iter().find(|c| c["sensor"] == "alone").unwrap();
    assert_eq!(alone["accepted"], true, "{alone}");
    assert!(alone.get("heading_vs_gyro").is_none(), "{alone}");
    assert_eq!(
        alone["heading_check"],
        "no heading check: lsm303dlhc-mag@0x1e of source 'imu' has no gyro (give gyro_chip for another chip's)"
    );
    let joined = found.iter().find(|c| c["sensor"] == "joined").unwrap();
    assert_eq!(joined["accepted"], true, "{joined}");
    // Both sensors fitted the same samples.
    assert_eq!(joined["params"], alone["params"]);
    let check = &joined["heading_vs_gyro"];
    assert_eq!(check["gyro_column"], "gyro_z", "{joined}");
    // All but the first and last sample: the first gyro poll came 4 ms after
    // the first, and the one after the last had not come when the rotation
    // completed, so those two lie outside the gyro's time span.
    assert_eq!(f(&check["n"]), f(&joined["n"]) - 2.0, "{joined}");
    assert!((f(&check["gyro_scale"]) - 1.0).abs() < 0.01, "{joined}");
    let expected = noise_heading_deg(noise, joined);
    let rms = f(&check["rms_deg"]);
    assert!(
        (0.8 * expected..1.25 * expected).contains(&rms),
        "heading rms {rms}°, the noise makes {expected}°: {joined}"
    );
}

/// Rows of a CSV of numbers, after its header.
fn rows(path: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
        .collect()
}

#[test]
fn a_real_hand_turn_is_checked_against_the_boards_mpu6050() {
    use fieldcal::daemon::Terms;
    use fieldcal::daemon::apply;
    use fieldcal::model::fit::{FitOptions, fit_paper};
    use fieldcal::model::gyro::{GyroUnits, HeadingReference};

    // sunsided set 1, the turns about z: the HMC5883L's x and z turn (in
    // gauss = counts / 1090), the MPU-6050's gyro z reads the turn (deg/s),
    // on one clock. Put back into counts on a bridge capture: the
    // magnetometer as stream 0 (an LSM303DLHC's registers carry the same
    // 12-bit counts), the MPU-6050 as stream 1 at its 131 counts per deg/s.
    let run = common::shared_path("data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up");
    let mag = rows(&run.join("hmc5883l_mag.csv"));
    let imu = rows(&run.join("mpu6050.csv"));
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("real-z.fcap");
    let counts = |v: f64, per_unit: f64| (v * per_unit).round() as i16;
    let mut records = Vec::new();
    for r in &mag {
        let reading = Reading {
            mag: Some([
                counts(r[1], 1090.0),
                counts(r[2], 1090.0),
                counts(r[3], 1090.0),
            ]),
            ..Reading::default()
        };
        records.push((r[0], 0, reading));
    }
    for r in &imu {
        let reading = Reading {
            accel: Some([
                counts(r[1], 16384.0),
                counts(r[2], 16384.0),
                counts(r[3], 16384.0),
            ]),
            gyro: Some([
                counts(r[4], 131.0),
                counts(r[5], 131.0),
                counts(r[6], 131.0),
            ]),
            temp_c: Some(r[7]),
            ..Reading::default()
        };
        records.push((r[0], 1, reading));
    }
    common::write_bridge_capture(
        &capture,
        &[Chip::Lsm303dlhcMag, Chip::Mpu6050],
        0.01,
        "sunsided set 1, z run",
        records,
    );

    let sensors = "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"z\"]\n\
                   gyro_chip = \"mpu6050\"\ngyro = \"z\"\n";
    let (found, _) = calibrations(&capture, sensors, dir.path());
    let calibration = &found[0];
    let check = &calibration["heading_vs_gyro"];
    assert_eq!(check["gyro_column"], "gyro_z", "{calibration}");

    // The same check made offline on the rotation the daemon fitted (its
    // first n magnetometer samples, in counts), with the gyro's readings
    // that had come when the rotation completed (those before its last
    // sample): the daemon reports exactly what the model's functions give.
    let n = calibration["n"].as_u64().unwrap() as usize;
    let t: Vec<f64> = mag[..n].iter().map(|r| r[0]).collect();
    let x: Vec<f64> = mag[..n]
        .iter()
        .map(|r| f64::from(counts(r[1], 1090.0)))
        .collect();
    let z: Vec<f64> = mag[..n]
        .iter()
        .map(|r| f64::from(counts(r[3], 1090.0)))
        .collect();
    let fit = fit_paper(&x, &z, &FitOptions::default(), &mut |_| {}).unwrap();
    let headings: Vec<f64> = x
        .iter()
        .zip(&z)
        .map(|(&x, &z)| {
            let (cx, cz) = apply(&fit.calibration, &Terms::default(), x, z);
            cz.atan2(cx)
        })
        .collect();
    let last = t[n - 1];
    let joined: Vec<&Vec<f64>> = {
        let after = imu.iter().position(|r| r[0] >= last).unwrap();
        imu[..after].iter().collect()
    };
    let gyro_t: Vec<f64> = joined.iter().map(|r| r[0]).collect();
    let rate: Vec<f64> = joined
        .iter()
        .map(|r| f64::from(counts(r[6], 131.0)) / 131.0)
        .collect();
    let offline =
        HeadingReference::from_rates("gyro_z", &t, &gyro_t, &rate, GyroUnits::DegPerSecond)
            .unwrap()
            .check(&headings, &[])
            .unwrap();
    assert_eq!(f(&check["n"]), offline.n as f64, "{calibration}");
    for (key, value) in [
        ("rms_deg", offline.rms_deg),
        ("peak_to_peak_deg", offline.peak_to_peak_deg),
        ("gyro_scale", offline.gyro_scale),
        ("gyro_bias_deg_s", offline.gyro_bias_deg_s),
    ] {
        assert!(
            (f(&check[key]) - value).abs() <= 1e-9 * value.abs().max(1.0),
            "{key}: daemon {} offline {value}",
            check[key]
        );
    }
}
