//! The daemon shares the turn gate of `fit` and `diagnose`: a rotation
//! buffer that completes on readings that never traced a ring (the
//! sunsided tilt-sphere tumble, whose two axes fill a disc) gets a
//! CALIBRATION refused with the gate's reason, and no calibration.

mod common;

use fieldcal::capture::{CaptureHeader, CaptureWriter, StreamInfo, StreamKind, VERSION};
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
    let header = CaptureHeader {
        version: VERSION,
        streams: vec![StreamInfo {
            id: 0,
            kind: StreamKind::Chip {
                chip: Chip::Lsm303dlhcMag,
                address: Chip::Lsm303dlhcMag.default_address(),
            },
        }],
        port: None,
        baud: None,
        started_unix: 0.0,
        nominal_period_s: 0.0133,
        note: Some("sunsided set 1, tilt-sphere".into()),
    };
    let file = std::fs::File::create(&capture).unwrap();
    let mut out = CaptureWriter::new(std::io::BufWriter::new(file), &header).unwrap();
    for line in text.lines().skip(1) {
        let v: Vec<f64> = line.split(',').map(|v| v.trim().parse().unwrap()).collect();
        let counts = |g: f64| (g * 1090.0).round() as i16;
        let reading = Reading {
            mag: Some([counts(v[1]), counts(v[2]), counts(v[3])]),
            ..Reading::default()
        };
        out.write_chunk(v[0], 0, &Chip::Lsm303dlhcMag.encode(&reading))
            .unwrap();
    }
    out.flush().unwrap();
    drop(out);

    let sensors = "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";
    let (lines, log) = common::replay_through(&capture, sensors, dir.path());
    let calibrations: Vec<&Value> = lines
        .iter()
        .filter(|v| v["class"] == "CALIBRATION")
        .collect();
    assert!(!calibrations.is_empty(), "no rotation completed: {log}");
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
        "a tumble corrected readings"
    );
}
