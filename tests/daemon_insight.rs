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

/// Two turns of a simulated Falcon-GX board (noise 2 counts, x offset
/// 100) with the hidden `effect`, into `capture`.
fn two_turns(capture: &str, effect: &str) {
    run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--effect",
        effect,
        "--turns",
        "2",
        "--noise",
        "2",
        "--offset-x",
        "100",
        "-o",
        capture,
    ]);
}

#[test]
fn calibration_suggests_the_missing_effect_and_the_configuration_adds_it() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("xa.fcap");
    let capture = capture.to_str().unwrap();
    two_turns(capture, "cross-axis=3deg");
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

/// A sensor whose non-linearity is about the turn's centre (an accelerometer
/// about its zero-g point): the daemon configured with `cubic-centred`
/// stores the term with its centre and radius, and corrects live readings
/// with it onto the circle to within the noise, where the paper's model
/// leaves the cubic's error.
#[test]
fn the_daemon_corrects_a_non_linearity_about_the_turns_centre() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("cc.fcap");
    let capture = capture.to_str().unwrap();
    run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--effect",
        "cubic-centred=0.04",
        "--turns",
        "3",
        "--noise",
        "2",
        "--offset-x",
        "1500",
        "--offset-y",
        "-1200",
        "-o",
        capture,
    ]);
    // The corrected readings after the calibration, as |s|/r - 1.
    let errors = |model: &str| -> (Value, Vec<f64>) {
        let config = dir.path().join(format!("{}.toml", model.len()));
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
        let lines: Vec<Value> = out
            .lines()
            .map(|l| serde_json::from_str::<Value>(l).unwrap())
            .collect();
        let cal = lines
            .iter()
            .find(|v| v["class"] == "CALIBRATION")
            .expect("a CALIBRATION")
            .clone();
        let r = cal["params"]["r"].as_f64().unwrap();
        let errors = lines
            .iter()
            .filter(|v| v["class"] == "READING" && v["calibrated"] == true)
            .map(|v| {
                let s = &v["corrected"];
                s[0].as_f64().unwrap().hypot(s[1].as_f64().unwrap()) / r - 1.0
            })
            .collect();
        (cal, errors)
    };
    let rms = |e: &[f64]| (e.iter().map(|e| e * e).sum::<f64>() / e.len() as f64).sqrt();
    let (cal, centred) = errors("[\"paper\", \"cubic-centred\"]");
    assert_eq!(cal["accepted"], true, "{cal}");
    assert_eq!(cal["model"], "offset+scale+cubic-centred");
    let terms = &cal["terms"];
    let centre = [
        terms["centre"][0].as_f64().unwrap(),
        terms["centre"][1].as_f64().unwrap(),
    ];
    assert!(
        (centre[0] - 1500.0).abs() < 5.0 && (centre[1] + 1200.0).abs() < 5.0,
        "{terms}"
    );
    let kc = terms["kc"][0].as_f64().unwrap();
    assert!((kc - 0.04).abs() < 0.02, "{terms}");
    assert!(centred.len() > 300, "{} corrected readings", centred.len());
    let (_, paper) = errors("\"paper\"");
    // Noise of 2 counts on a field of 1000, in the radial direction.
    assert!(rms(&centred) < 0.0025, "with the term: {}", rms(&centred));
    assert!(
        rms(&paper) > 2.0 * rms(&centred),
        "paper {} vs {}",
        rms(&paper),
        rms(&centred)
    );
}

/// A 3 % saturation on a board whose frames carry the gyro: the daemon's
/// suggestion checks each candidate's heading against that gyro, as
/// `fieldcal diagnose --gyro` does, so the cubic is held to the limit a
/// checked heading allows and is named; without the gyro it was held to
/// the datasheets' 1 %, and a drift took its place.
#[test]
fn the_gyro_in_the_frames_checks_the_daemons_suggestion() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("cubic.fcap");
    let capture = capture.to_str().unwrap();
    two_turns(capture, "cubic=0.03");
    let paper = calibration(capture, "\"paper\"", dir.path());
    assert_eq!(paper["accepted"], true, "{paper}");
    assert!(paper.get("heading_vs_gyro").is_some(), "{paper}");
    assert_eq!(paper["suggested"], "cubic", "{paper}");
}

/// One axis that saturates softly (x by 6 %, y not at all) on a board whose
/// frames carry the gyro: the daemon configured with `cubic-centred`
/// splits the term per axis, as the gyro pins the difference
/// (model/centred_split.rs), and corrects live readings with both.
#[test]
fn the_gyro_splits_a_centred_cubic_of_one_axis() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("one-axis.fcap");
    let capture = capture.to_str().unwrap();
    two_turns(capture, "cubic-centred=0.06,0");
    let cal = calibration(capture, "[\"paper\", \"cubic-centred\"]", dir.path());
    assert_eq!(cal["accepted"], true, "{cal}");
    let kc = &cal["terms"]["kc"];
    let (kx, ky) = (kc[0].as_f64().unwrap(), kc[1].as_f64().unwrap());
    assert!(kx > 0.05 && kx < 0.1, "{cal}");
    assert!(ky.abs() < 0.01, "{cal}");
}
