//! The daemon in 3-D: a Falcon-GX capture of a tumbling IMU
//! (tests/data/falcon_tumble.fcap, made by the command in
//! tests/data/README.md) replayed through `fieldcal run` gives a 3-D
//! CALIBRATION of the magnetometer and of the accelerometer, READINGs with
//! the corrected x, y, z and the tilt-compensated heading; a cap of
//! directions gives none and says what is missing.

mod common;

use std::path::Path;

use common::{repo_path, run};
use serde_json::Value;

/// The shipped capture's command, without `--format`, `-o` and its file:
/// the truth per sample comes from the same command with `--format csv`.
fn tumble_command() -> Vec<String> {
    let readme = std::fs::read_to_string(repo_path("tests/data/README.md")).unwrap();
    let line = readme
        .lines()
        .find(|l| l.contains("`falcon_tumble.fcap` |"))
        .expect("the capture's row in tests/data/README.md");
    let command = line
        .split('`')
        .find(|s| s.starts_with("fieldcal simulate"))
        .unwrap();
    let words: Vec<String> = command
        .split_whitespace()
        .skip(1)
        .map(String::from)
        .collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < words.len() {
        if words[i] == "--format" || words[i] == "-o" {
            i += 2;
            continue;
        }
        out.push(words[i].clone());
        i += 1;
    }
    out
}

/// The configuration: a 3-axis magnetometer tilt-compensated by a 3-axis
/// accelerometer of the same replayed Falcon-GX, as fast as it goes.
fn config(dir: &Path, capture: &Path) -> std::path::PathBuf {
    common::daemon::tumble_config(dir, capture, "\"max\"", "stdout = true")
}

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

fn numbers(v: &Value) -> Vec<f64> {
    match v {
        Value::Array(items) => items.iter().flat_map(numbers).collect(),
        Value::Number(n) => vec![n.as_f64().unwrap()],
        other => panic!("not numbers: {other}"),
    }
}

fn sensor_status<'a>(status: &'a Value, name: &str) -> &'a Value {
    status["sensors"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["sensor"] == name)
        .unwrap()
}

#[test]
fn a_tumbled_imu_calibrates_in_3d_and_publishes_a_tilt_compensated_heading() {
    let dir = tempfile::tempdir().unwrap();
    let capture = repo_path("tests/data/falcon_tumble.fcap");
    let lines = run_daemon(&config(dir.path(), &capture));

    // The truth: the same simulation as CSV (heading, tilt per sample) and
    // as JSON (the true o, W, r in the fit's convention).
    let truth_csv = dir.path().join("truth.csv");
    let mut args: Vec<String> = Vec::new();
    args.extend(tumble_command());
    args.extend([
        "--json".into(),
        "-o".into(),
        truth_csv.display().to_string(),
    ]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let r = run(&args);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let truth: Value = serde_json::from_str(&r.stdout).unwrap();
    let text = std::fs::read_to_string(&truth_csv).unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 2880);

    // One accepted 3-D CALIBRATION each, within 4 standard errors of the
    // truth (plus the i16 rounding of the frames, 0.29 counts rms, which
    // the noise already holds).
    for (sensor, key) in [("compass", "mag"), ("level", "accel")] {
        let cals = of(&lines, "CALIBRATION", sensor);
        assert_eq!(cals.len(), 1, "{sensor}: {cals:?}");
        let c = cals[0];
        assert_eq!(c["accepted"], true, "{c}");
        assert_eq!(c["axes"], 3);
        assert_eq!(c["model"], "offset+scale+cross-axis");
        assert!(c["coverage"]["fraction"].as_f64().unwrap() >= 0.8, "{c}");
        for (param, se) in [("offset", "offset"), ("matrix", "matrix")] {
            let got = numbers(&c[param]);
            let want = numbers(&truth[key][param]);
            let se = numbers(&c["se"][se]);
            for ((g, w), s) in got.iter().zip(&want).zip(&se) {
                assert!(
                    (g - w).abs() <= 4.0 * s,
                    "{sensor} {param}: {got:?} vs {want:?} (se {se:?})"
                );
            }
        }
        let (r_got, r_want) = (c["r"].as_f64().unwrap(), truth[key]["r"].as_f64().unwrap());
        let r_se = c["se"]["r"].as_f64().unwrap();
        assert!(
            (r_got - r_want).abs() <= 4.0 * r_se,
            "{sensor} r {r_got} vs {r_want}"
        );
    }
    let r = of(&lines, "CALIBRATION", "compass")[0]["r"]
        .as_f64()
        .unwrap();
    // In ArduPilot's units: 1000 counts at 2000 counts per gauss.
    let r_gauss = of(&lines, "CALIBRATION", "compass")[0]["r_units"]
        .as_f64()
        .unwrap();
    assert!((r_gauss - r / 2000.0).abs() < 1e-12);

    // STATUS showed the sphere's coverage while collecting, and the
    // missing directions in words.
    let collecting: Vec<&Value> = lines
        .iter()
        .filter(|v| v["class"] == "STATUS")
        .map(|s| sensor_status(s, "compass"))
        .filter(|s| s["state"] == "collecting")
        .collect();
    assert!(!collecting.is_empty());
    let first = &collecting[0]["sphere"];
    assert!(first["coverage_pct"].as_f64().unwrap() < 80.0, "{first}");
    let text = first["missing_text"].as_str().unwrap();
    assert!(!text.is_empty() && text != "nothing missing", "{first}");
    assert_eq!(first["regions"], 100);

    // Every compass READING, in order, is a frame of the capture: sample i.
    let readings = of(&lines, "READING", "compass");
    assert_eq!(readings.len(), rows.len());
    let calibrated: Vec<(usize, &Value)> = readings
        .iter()
        .copied()
        .enumerate()
        .filter(|(_, v)| v["calibrated"] == true)
        .collect();
    assert!(calibrated.len() > 1000, "{}", calibrated.len());
    // |corrected| ≈ r: the noise (3 counts of 1000) and nothing more.
    let mags: Vec<f64> = calibrated
        .iter()
        .map(|(_, v)| v["magnitude"].as_f64().unwrap())
        .collect();
    let mean = mags.iter().sum::<f64>() / mags.len() as f64;
    let sd = (mags.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / mags.len() as f64).sqrt();
    assert!(
        (mean / r - 1.0).abs() < 0.002,
        "mean |corrected| {mean} vs r {r}"
    );
    assert!(sd < 2.0 * 3.0, "sd of |corrected| {sd}");

    // The tilt-compensated heading against the truth. The noise's share:
    // the magnetometer's 3 counts across the horizontal field r·cos(60°),
    // and the accelerometer's 8 counts of 4096 tilting the vertical, which
    // moves the heading by tan(inclination) times as much.
    let inc = 60f64.to_radians();
    let sigma_deg = ((3.0 / (r * inc.cos())).powi(2) + (8.0 / 4096.0 * inc.tan()).powi(2))
        .sqrt()
        .to_degrees();
    let mut errors = Vec::new();
    let mut level_errors = Vec::new();
    let mut without = 0;
    for (i, v) in &calibrated {
        // No heading only when the forward axis is within a degree of the
        // vertical (model::tilt): a few samples of a tumble at most.
        let Some(heading) = v["heading_deg"].as_f64() else {
            assert!(v.get("tilt").is_none(), "{v}");
            without += 1;
            continue;
        };
        let tilt = &v["tilt"];
        assert_eq!(tilt["sensor"], "level");
        assert_eq!(tilt["calibrated"], true, "{v}");
        let (true_heading, true_tilt) = (rows[*i][10], rows[*i][11]);
        let d = (heading - true_heading + 540.0).rem_euclid(360.0) - 180.0;
        errors.push(d);
        if true_tilt <= 30.0 {
            level_errors.push(d);
        }
        assert!(
            (tilt["inclination_deg"].as_f64().unwrap() - 60.0).abs() < 2.0,
            "{v}"
        );
    }
    assert!(
        without * 100 <= calibrated.len(),
        "{without} without a heading"
    );
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    assert!(
        rms < 2.0 * sigma_deg,
        "heading rms {rms:.3}° vs noise {sigma_deg:.3}°"
    );
    assert!(level_errors.len() > 50, "{}", level_errors.len());
    let worst = level_errors.iter().fold(0f64, |m, e| m.max(e.abs()));
    assert!(
        worst < 5.0 * sigma_deg,
        "heading at tilts up to 30°: worst {worst:.3}° vs noise {sigma_deg:.3}°"
    );

    // The calibrations were stored: a second run (on a cap that could never
    // calibrate) corrects and gives headings from its first reading.
    let cap = dir.path().join("cap.fcap");
    let r = run(&[
        "simulate",
        "--axes",
        "3",
        "--format",
        "falcon",
        "--motion",
        "wobble",
        "--tilt",
        "30",
        "--turns",
        "2",
        "--turn-seconds",
        "10",
        "--field",
        "1000",
        "--offset-x",
        "150",
        "--offset-y",
        "-80",
        "--offset-z",
        "60",
        "--matrix",
        "1.08,0.04,-0.02,0.04,0.95,0.03,-0.02,0.03,1.0",
        "--noise",
        "3",
        "--accel-offset",
        "40,-25,60",
        "--accel-matrix",
        "1.01,0.99,1.0",
        "--accel-noise",
        "8",
        "--seed",
        "9",
        "-o",
        cap.to_str().unwrap(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let again = run_daemon(&config(dir.path(), &cap));
    let loaded = of(&again, "CALIBRATION", "compass");
    assert_eq!(loaded.len(), 1);
    assert_eq!(loaded[0]["origin"], "state");
    assert_eq!(loaded[0]["axes"], 3);
    let first = of(&again, "READING", "compass")[0];
    assert_eq!(first["calibrated"], true, "{first}");
    assert!(first["heading_deg"].is_number(), "{first}");
}

#[test]
fn a_cap_of_directions_gives_no_calibration_and_status_names_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let cap = dir.path().join("cap.fcap");
    // A wobbling turn: the field's directions stay within a band about
    // the inclination, gravity's within 30° of +z.
    let r = run(&[
        "simulate",
        "--axes",
        "3",
        "--format",
        "falcon",
        "--motion",
        "wobble",
        "--tilt",
        "30",
        "--turns",
        "4",
        "--turn-seconds",
        "10",
        "--noise",
        "3",
        "--accel-noise",
        "8",
        "--seed",
        "3",
        "-o",
        cap.to_str().unwrap(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let lines = run_daemon(&config(dir.path(), &cap));
    for sensor in ["compass", "level"] {
        assert!(
            of(&lines, "CALIBRATION", sensor).is_empty(),
            "{sensor}: {:?}",
            of(&lines, "CALIBRATION", sensor)
        );
        let readings = of(&lines, "READING", sensor);
        assert_eq!(readings.len(), 800);
        assert!(
            readings
                .iter()
                .all(|v| v["calibrated"] == false && v.get("heading_deg").is_none())
        );
    }
    let last = lines.iter().rev().find(|v| v["class"] == "STATUS").unwrap();
    for sensor in ["compass", "level"] {
        let s = sensor_status(last, sensor);
        assert_eq!(s["state"], "collecting");
        let sphere = &s["sphere"];
        let pct = sphere["coverage_pct"].as_f64().unwrap();
        assert!(pct > 5.0 && pct < 60.0, "{sensor}: {sphere}");
        assert_eq!(sphere["samples"], 800);
        assert!(sphere["supported"].is_null(), "{sensor}: {sphere}");
        let missing = sphere["missing"].as_array().unwrap();
        assert!(!missing.is_empty());
        let text = sphere["missing_text"].as_str().unwrap();
        // Below a third of the sphere the text names what is covered.
        assert!(
            text.starts_with("missing: ") || text.starts_with("covered only "),
            "{text}"
        );
    }
    // Gravity stays within 30° of +z: the whole lower half is missing.
    let level = &sensor_status(last, "level")["sphere"];
    let largest = &level["missing"][0];
    assert!(
        largest["toward"].as_str().unwrap().contains("-z"),
        "{level}"
    );
}

#[test]
fn tilt_and_the_3_axis_keys_are_checked_naming_the_key() {
    let base = r#"
[[source]]
name = "imu"
kind = "falcon"
port = "/dev/null"

[[source]]
name = "other"
kind = "falcon"
port = "/dev/null"
"#;
    let cases = [
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"nope\"\n",
            "sensor[0].tilt",
            "no sensor named 'nope'",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"flat\"\n\
             [[sensor]]\nname = \"flat\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\n",
            "sensor[0].tilt",
            "'flat' is a 2-axis sensor",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"acc\"\n\
             [[sensor]]\nname = \"acc\"\nsource = \"other\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n",
            "sensor[0].tilt",
            "not of 'imu'",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"m2\"\n\
             [[sensor]]\nname = \"m2\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\n",
            "sensor[0].tilt",
            "must be an accelerometer",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\nmag_axes = \"x,z,-y\"\n",
            "sensor[0].mag_axes",
            "for a 3-axis sensor",
        ),
        // A 2-axis compass's tilt is checked against its accelerometer: the
        // same rules name it.
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\ntilt = \"m2\"\n\
             [[sensor]]\nname = \"m2\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\n",
            "sensor[0].tilt",
            "must be an accelerometer",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"y\"]\n",
            "sensor[0].axes",
            "given twice",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\nlsb_per_g = 4096\n",
            "sensor[0].lsb_per_g",
            "lsb_per_gauss",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\nmodel = \"offset+cubic\"\n",
            "sensor[0].model",
            "unknown 3-D model",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\n[sensor.sphere]\nmax_samples = 5\n",
            "sensor[0].sphere",
            "max_samples",
        ),
        (
            "[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ngyro = \"z\"\n",
            "sensor[0].gyro",
            "checked against a 3-axis gyro",
        ),
    ];
    for (sensors, key, words) in cases {
        let text = format!("{base}{sensors}");
        let e = fieldcal::daemon::config::parse(&text, Path::new("t.toml"))
            .expect_err(sensors)
            .to_string();
        assert!(e.contains(key) && e.contains(words), "{sensors}\n-> {e}");
    }
    // A good one: the tilt resolves to the accelerometer's stream and axes.
    let text = format!(
        "{base}[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"acc\"\nmodel = \"offset+scale\"\n\
         [[sensor]]\nname = \"acc\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n"
    );
    let config = fieldcal::daemon::config::parse(&text, Path::new("t.toml")).unwrap();
    let three = config.sensors[0].sphere().unwrap();
    assert_eq!(three.tilt.as_ref().unwrap().sensor, "acc");
    assert_eq!(
        three.model,
        fieldcal::model::ellipsoid::Ellipsoid3Model::OffsetScale
    );
    assert!(config.sensors[1].sphere().unwrap().tilt.is_none());
    // A 2-axis compass of a device takes it the same way.
    let text = format!(
        "{base}[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\ntilt = \"acc\"\n\
         [[sensor]]\nname = \"acc\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n"
    );
    let config = fieldcal::daemon::config::parse(&text, Path::new("t.toml")).unwrap();
    let tilt = config.sensors[0].plane().unwrap().tilt.as_ref().unwrap();
    assert_eq!(
        (tilt.sensor.as_str(), tilt.columns.is_none()),
        ("acc", true)
    );
}

#[test]
fn simulate_axes_3_refuses_bad_values_before_simulating() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.fcap");
    let out = out.to_str().unwrap();
    let cases: [(&[&str], &str); 5] = [
        (
            &["--effect", "drift=1"],
            "--effect is for the 2-axis simulator",
        ),
        (&["--gain-x", "1.2"], "diagonal of --matrix"),
        (
            &["--matrix", "1,2,0,2,1,0,0,0,1"],
            "not symmetric positive definite",
        ),
        (&["--inclination", "95"], "inclination"),
        (
            &["--format", "falcon", "--turns", "1e6", "--garbage", "0.9"],
            "more than the",
        ),
    ];
    for (extra, words) in cases {
        let mut args = vec!["simulate", "--axes", "3", "-o", out];
        args.extend_from_slice(extra);
        let started = std::time::Instant::now();
        let r = run(&args);
        assert_eq!(r.code, Some(1), "{args:?}: {}", r.stderr);
        assert!(r.stderr.contains(words), "{args:?}: {}", r.stderr);
        assert!(started.elapsed().as_secs() < 5, "{args:?} took long");
        assert!(!Path::new(out).exists());
    }
    // Columns: the magnetometer as x, y, z, then the accelerometer, the
    // gyro and the truth.
    let r = run(&["simulate", "--axes", "3", "--turns", "0.1"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(
        r.stdout.lines().next(),
        Some("t,x,y,z,ax,ay,az,gx,gy,gz,heading,tilt")
    );
    assert_eq!(r.stdout.lines().count(), 21);
}
