//! The daemon shares the turn gate of `fit` and `diagnose`: a rotation
//! buffer that completed on readings that never traced a ring (the
//! sunsided tilt-sphere tumble, whose two axes fill a disc) would get a
//! CALIBRATION refused with the gate's reason; either way, no calibration.

mod common;

use fieldcal::protocol::chips::Chip;
use fieldcal::sample::Reading;
use serde_json::Value;

#[test]
fn a_tumble_through_the_daemon_is_refused_as_a_disc() {
    // The HMC5883L of the tumble, in counts (gauss × 1090), as the
    // magnetometer stream of a bridge capture.
    let run_dir = common::shared_path("data/real/sunsided-set-1/tilt-sphere");
    let text = std::fs::read_to_string(run_dir.join("hmc5883l_mag.csv")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("tumble.fcap");
    let records = text
        .lines()
        .skip(1)
        .map(|line| {
            let v: Vec<f64> = line.split(',').map(|v| v.trim().parse().unwrap()).collect();
            let counts = |g: f64| (g * 1090.0).round() as i16;
            let reading = Reading {
                mag: Some([counts(v[1]), counts(v[2]), counts(v[3])]),
                ..Reading::default()
            };
            (v[0], 0, reading)
        })
        .collect();
    common::write_bridge_capture(
        &capture,
        &[Chip::Lsm303dlhcMag],
        0.0133,
        "sunsided set 1, tilt-sphere",
        records,
    );

    let sensors = "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";
    let (lines, log) = common::replay_through(&capture, sensors, dir.path());
    let calibrations: Vec<&Value> = lines
        .iter()
        .filter(|v| v["class"] == "CALIBRATION")
        .collect();
    // The rotation buffer itself no longer completes on the tumble (its
    // readings never sweep 330° in one direction round one circle), so no
    // fit is tried; should one complete, the gate must refuse it.
    for c in &calibrations {
        assert_eq!(c["accepted"], false, "{c}");
        let reason = c["reason"].as_str().unwrap_or_default();
        assert!(
            reason.contains("fill a disc") && reason.contains("did not turn"),
            "{c}"
        );
    }
    // Nothing was ever corrected.
    assert!(
        !lines.iter().any(|v| v["calibrated"] == true),
        "a tumble corrected readings: {log}"
    );
}
