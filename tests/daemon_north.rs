//! True north in the daemon: a magnetometer with `declination_deg` or a
//! location publishes `true_heading_deg` = `heading_deg` + D (mod 360)
//! beside every heading, its CALIBRATION says D and where it came from,
//! and with a location a 3-axis magnetometer's CALIBRATION puts the
//! fitted field beside the World Magnetic Model's (`earth`).

mod common;

use std::path::Path;

use common::{repo_path, run};
use fieldcal::geomag::{CivilDate, Place, model_field};
use serde_json::Value;

fn run_daemon(config: &Path) -> Vec<Value> {
    let r = run(&["run", "--config", config.to_str().unwrap()]);
    assert_eq!(r.code, Some(0), "run failed: {}", r.stderr);
    assert!(!r.stderr.contains("panicked"), "{}", r.stderr);
    r.stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect()
}

fn of<'a>(lines: &'a [Value], class: &str, sensor: &str) -> Vec<&'a Value> {
    lines
        .iter()
        .filter(|v| v["class"] == class && v["sensor"] == sensor)
        .collect()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// The difference of two angles in degrees, in [-180, 180).
fn angle_diff(a: f64, b: f64) -> f64 {
    (a - b + 180.0).rem_euclid(360.0) - 180.0
}

/// Asserts every READING of `sensor` with a heading has a true heading
/// `d` degrees further clockwise, in [0, 360); returns how many.
#[track_caller]
fn true_headings_follow(lines: &[Value], sensor: &str, d: f64, tolerance: f64) -> usize {
    let mut n = 0;
    for r in of(lines, "READING", sensor) {
        match (r.get("heading_deg"), r.get("true_heading_deg")) {
            (Some(h), Some(t)) => {
                let (h, t) = (f(h), f(t));
                assert!((0.0..360.0).contains(&t), "{r}");
                assert!(angle_diff(t, h + d).abs() <= tolerance, "{sensor}: {r}");
                n += 1;
            }
            (None, None) => {}
            _ => panic!("{sensor}: a heading without its true heading, or the reverse: {r}"),
        }
    }
    n
}

/// NOAA's WMM2025 test point (Technical Report Table 6, epoch 2025.0,
/// height 0): 80° S 120° W, D = 68.78°, I = -72.00°, F = 54698.2 nT. The
/// table's rounding and the crate's f32 arithmetic: 0.011°.
const PLACE: &str =
    "[sensor.location]\nlatitude = -80.0\nlongitude = -120.0\ndate = \"2025-01-01\"";
const NOAA_D: f64 = 68.78;

#[test]
fn a_2_axis_compass_publishes_its_heading_from_true_north() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("turn.toml");
    std::fs::write(
        &config,
        format!(
            r#"
[daemon]
state_dir = "{state}"

[outputs]
stdout = true

[[source]]
name = "imu"
kind = "replay"
file = "{capture}"
speed = "max"

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]
declination_deg = -7.25

[[sensor]]
name = "wmm"
source = "imu"
field = "mag"
axes = ["x", "y"]
{PLACE}

[[sensor]]
name = "plain"
source = "imu"
field = "mag"
axes = ["x", "y"]
"#,
            state = dir.path().join("state").display(),
            capture = repo_path("tests/data/falcon_turn.fcap").display(),
        ),
    )
    .unwrap();
    let lines = run_daemon(&config);

    let c = of(&lines, "CALIBRATION", "compass");
    assert_eq!(c.len(), 1, "{c:?}");
    assert_eq!(c[0]["declination_deg"], -7.25);
    assert_eq!(c[0]["declination_source"], "config");
    assert!(c[0].get("declination_uncertainty_deg").is_none());
    // Exactly D, to rounding.
    let n = true_headings_follow(&lines, "compass", -7.25, 1e-9);
    assert!(n > 10, "{n} headings");

    let c = of(&lines, "CALIBRATION", "wmm");
    let d = f(&c[0]["declination_deg"]);
    assert!((d - NOAA_D).abs() < 0.011, "{}", c[0]);
    assert_eq!(c[0]["declination_source"], "WMM2025 at -80,-120,2025-01-01");
    assert!(f(&c[0]["declination_uncertainty_deg"]) > 0.0);
    // A 2-axis sensor has no units and no tilt: no field comparison.
    assert!(c[0].get("earth").is_none());
    assert!(true_headings_follow(&lines, "wmm", NOAA_D, 0.011) > 10);

    // Without the keys nothing changes.
    let c = of(&lines, "CALIBRATION", "plain");
    assert!(c[0].get("declination_deg").is_none(), "{}", c[0]);
    assert!(
        of(&lines, "READING", "plain")
            .iter()
            .all(|r| r.get("true_heading_deg").is_none())
    );
}

/// A tumbled IMU simulated at the NOAA test point's field: the magnitude
/// `F` at 2000 counts per gauss, the inclination I, no soft iron (so the
/// fitted r is the field).
fn tumble_at_the_test_point(dir: &Path) -> (std::path::PathBuf, f64, f64) {
    let model = model_field(&Place {
        latitude_deg: -80.0,
        longitude_deg: -120.0,
        altitude_m: 0.0,
        date: CivilDate::parse("2025-01-01").unwrap(),
    })
    .unwrap();
    let counts = model.total_intensity_nt / 1e5 * 2000.0;
    let capture = dir.join("tumble.fcap");
    let field = format!("{counts:.3}");
    let inclination = format!("{:.3}", model.inclination_deg);
    let r = run(&[
        "simulate",
        "--axes",
        "3",
        "--format",
        "falcon",
        "--turns",
        "24",
        "--turn-seconds",
        "6",
        "--axis-path",
        "12",
        "--field",
        &field,
        "--inclination",
        &inclination,
        "--offset-x",
        "150",
        "--offset-y",
        "-80",
        "--offset-z",
        "60",
        "--noise",
        "3",
        "--accel-offset",
        "40,-25,60",
        "--accel-noise",
        "8",
        "--seed",
        "7",
        "-o",
        capture.to_str().unwrap(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    (capture, counts, model.inclination_deg)
}

#[test]
fn a_3_axis_compass_compares_its_field_with_the_world_magnetic_models() {
    let dir = tempfile::tempdir().unwrap();
    let (capture, counts, inclination) = tumble_at_the_test_point(dir.path());
    let config = dir.path().join("tumble.toml");
    let mag = |name: &str, extra: &str| {
        format!(
            "[[sensor]]\nname = \"{name}\"\nsource = \"imu\"\nfield = \"mag\"\n\
             axes = [\"x\", \"y\", \"z\"]\n{extra}\n\n"
        )
    };
    std::fs::write(
        &config,
        format!(
            r#"
[daemon]
state_dir = "{state}"
status_interval_s = 1.0

[outputs]
stdout = true

[[source]]
name = "imu"
kind = "replay"
file = "{capture}"
speed = "max"

[[sensor]]
name = "level"
source = "imu"
field = "accel"
axes = ["x", "y", "z"]
lsb_per_g = 4096.0

{compass}{wrong}{bare}"#,
            state = dir.path().join("state").display(),
            capture = capture.display(),
            compass = mag(
                "compass",
                &format!("lsb_per_gauss = 2000.0\ntilt = \"level\"\n{PLACE}")
            ),
            // Units 30 % off: the chip's gain setting mistaken.
            wrong = mag(
                "wrong",
                &format!("lsb_per_gauss = 2600.0\ntilt = \"level\"\n{PLACE}")
            ),
            // Neither units nor tilt.
            bare = mag("bare", PLACE),
        ),
    )
    .unwrap();
    let lines = run_daemon(&config);

    let cal = |name| {
        let c = of(&lines, "CALIBRATION", name);
        assert_eq!(c.len(), 1, "{name}: {c:?}");
        assert_eq!(c[0]["accepted"], true, "{}", c[0]);
        c[0].clone()
    };
    let c = cal("compass");
    assert!((f(&c["declination_deg"]) - NOAA_D).abs() < 0.011, "{c}");
    let e = &c["earth"];
    eprintln!(
        "compass: declination {} ({})\nearth: {e}",
        c["declination_deg"], c["declination_source"]
    );
    assert_eq!(e["model"], "WMM2025");
    assert!((f(&e["field_nt"]) - 54698.2).abs() < 1.0, "{e}");
    assert!((f(&e["inclination_deg"]) + 72.00).abs() < 0.011, "{e}");
    // The fitted r is the simulated field within its standard error
    // (0.1 count of 1094 here): r/F within 0.5 % of 1.
    let ratio = f(&e["ratio"]);
    assert!((ratio - 1.0).abs() < 0.005, "{e}");
    assert!((f(&e["r_nt"]) - f(&c["r"]) / 2000.0 * 1e5).abs() < 1e-6);
    assert!((f(&c["r"]) - counts).abs() < 0.005 * counts);
    assert_eq!(e["magnitude_agrees"], true);
    // The inclination over the fitted samples: the simulated one, within
    // what the noise and the accelerometer's calibration leave (0.11° of
    // 8/4096 tilt, 0.16° of 3 counts across the field; the median of
    // about 1500).
    let measured = f(&e["measured_inclination_deg"]);
    assert!(
        (measured - inclination).abs() < 0.3,
        "{measured} vs {inclination}"
    );
    // Every fitted sample had the accelerometer's reading beside it.
    assert_eq!(e["measured_inclination_n"], c["n"], "{e}");
    assert_eq!(e["inclination_agrees"], true);
    assert!(
        e["verdict"]
            .as_str()
            .unwrap()
            .starts_with("the measured field agrees"),
        "{e}"
    );
    // Its every heading is from true north as well.
    assert!(true_headings_follow(&lines, "compass", f(&c["declination_deg"]), 1e-9) > 1000);

    // The wrong units: r/F = 2000/2600, and the verdict says what to check.
    let e = &cal("wrong")["earth"];
    eprintln!("wrong: {e}");
    assert!((f(&e["ratio"]) - 2000.0 / 2600.0).abs() < 0.005, "{e}");
    assert_eq!(e["magnitude_agrees"], false);
    assert_eq!(e["inclination_agrees"], true);
    let verdict = e["verdict"].as_str().unwrap();
    assert!(verdict.contains("disagrees"), "{verdict}");
    assert!(verdict.contains("r/F = 0.769"), "{verdict}");
    assert!(verdict.contains("lsb_per_gauss"), "{verdict}");

    // No units, no tilt: the model is shown, nothing measured compared.
    let c = cal("bare");
    let e = &c["earth"];
    assert!(
        e.get("ratio").is_none() && e.get("measured_inclination_deg").is_none(),
        "{e}"
    );
    let verdict = e["verdict"].as_str().unwrap();
    assert!(
        verdict.contains("the magnitude cannot be compared"),
        "{verdict}"
    );
    assert!(verdict.contains("no tilt accelerometer"), "{verdict}");
    // No tilt, no heading, no true heading.
    assert_eq!(true_headings_follow(&lines, "bare", 0.0, 0.0), 0);
    // The accelerometer takes no north.
    assert!(cal("level").get("declination_deg").is_none());
}
