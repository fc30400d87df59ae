//! Live insight: the daemon's CALIBRATION says what the rotation's residual
//! shows (its noise floor, an effect the model lacks), and the
//! configuration can add that effect.

mod common;

use common::run_ok;
use serde_json::Value;

fn calibration(capture: &str, model: &str, dir: &std::path::Path) -> Value {
    let config = dir.join(format!("{}.toml", model.len()));
    std::fs::write(
        &config,
        format!(
            "[outputs]\nstdout = true\n[[source]]\nname = \"imu\"\nkind = \"replay\"\nfile = \"{capture}\"\n\
             [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\nmodel = {model}\n"
        ),
    )
    .unwrap();
    let out = run_ok(&[
        "replay",
        capture,
        "--config",
        config.to_str().unwrap(),
        "--speed",
        "max",
    ]);
    out.lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .find(|v| v["class"] == "CALIBRATION")
        .expect("a CALIBRATION")
}

#[test]
fn calibration_suggests_the_missing_effect_and_the_configuration_adds_it() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("xa.fcap");
    let capture = capture.to_str().unwrap();
    run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--effect",
        "cross-axis=3deg",
        "--turns",
        "2",
        "--noise",
        "2",
        "--offset-x",
        "100",
        "-o",
        capture,
    ]);
    let paper = calibration(capture, "\"paper\"", dir.path());
    assert_eq!(paper["accepted"], true, "{paper}");
    assert_eq!(paper["suggested"], "cross-axis", "{paper}");
    // Two turns and a clear second harmonic: no rival comes close.
    assert!(paper.get("close_second").is_none(), "{paper}");
    let floor = paper["noise_floor"].as_f64().unwrap();
    // Noise of 2 counts on a field of 1000.
    assert!((0.0015..0.003).contains(&floor), "noise floor {floor}");
    assert!(paper["rms"].as_f64().unwrap() > 5.0 * floor, "{paper}");

    let added = calibration(capture, "[\"paper\", \"cross-axis\"]", dir.path());
    assert_eq!(added["model"], "offset+scale+cross-axis");
    assert!(
        added.get("suggested").is_none(),
        "nothing more to add: {added}"
    );
    let rms = added["rms"].as_f64().unwrap();
    assert!(rms < 1.2 * floor, "rms {rms} vs noise floor {floor}");
    // 3° of non-orthogonality: c = -tan(3°).
    let c = added["terms"]["c"].as_f64().unwrap();
    assert!((c + 3f64.to_radians().tan()).abs() < 0.003, "c {c}");
}
