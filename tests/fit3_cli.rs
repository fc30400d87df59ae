//! `fieldcal fit` on three axes, as a user runs it: simulated tumbles with
//! known truth, partial coverage, still poses, and the real tumble of
//! sunsided-set-1/tilt-sphere.

mod common;

use std::fs;

use common::{run_err, run_ok, shared_path};
use fieldcal::sim3::{Motion3, SimSensor3};
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde_json::Value;

const SOFT_IRON: [[f64; 3]; 3] = [[1.2, 0.15, -0.1], [0.15, 0.85, 0.2], [-0.1, 0.2, 1.05]];

fn tilt_sphere(name: &str) -> String {
    shared_path(&format!("data/real/sunsided-set-1/tilt-sphere/{name}"))
        .to_str()
        .unwrap()
        .to_string()
}

fn tumble(noise: f64, n: usize, seed: u64) -> SimSensor3 {
    SimSensor3 {
        matrix: SOFT_IRON,
        offset: [0.3, -0.2, 0.45],
        r: 0.5,
        noise,
        n,
        motion: Motion3::Tumble {
            turns: 20.0,
            axis_path_rad: 10.0,
        },
        seed,
    }
}

/// Writes `t,<x>,<y>,<z>` at 100 Hz.
fn write_csv(
    dir: &tempfile::TempDir,
    name: &str,
    header: [&str; 3],
    points: &[[f64; 3]],
) -> String {
    let mut text = format!("t,{},{},{}\n", header[0], header[1], header[2]);
    for (i, p) in points.iter().enumerate() {
        text.push_str(&format!("{},{},{},{}\n", i as f64 * 0.01, p[0], p[1], p[2]));
    }
    let path = dir.path().join(name);
    fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn json_of_a_simulated_tumble_holds_the_truth_within_its_standard_errors() {
    let dir = tempfile::tempdir().unwrap();
    let sim = tumble(0.002, 2000, 3);
    let raw = sim.simulate().unwrap();
    let (o, w, r) = sim.truth();
    // Columns x, y, z: the 3-D fit is the default, no flag needed.
    let file = write_csv(&dir, "tumble.csv", ["x", "y", "z"], &raw);
    let v: Value = serde_json::from_str(&run_ok(&["fit", &file, "--json"])).unwrap();
    assert_eq!(v["axes"], 3);
    assert_eq!(v["x_column"], "x");
    assert_eq!(v["y_column"], "y");
    assert_eq!(v["z_column"], "z");
    assert_eq!(v["model"], "offset+scale+cross-axis");
    assert_eq!(
        v["effects"],
        serde_json::json!(["offset", "scale", "cross-axis"])
    );
    assert_eq!(v["n"], 2000);
    assert_eq!(v["units"], Value::Null);
    for i in 0..3 {
        let (value, se) = (f(&v["params"]["offset"][i]), f(&v["se"]["offset"][i]));
        assert!(
            se > 0.0 && (value - o[i]).abs() <= 4.0 * se,
            "o{i}: {value} ± {se} vs {}",
            o[i]
        );
        for j in 0..3 {
            let (value, se) = (f(&v["params"]["matrix"][i][j]), f(&v["se"]["matrix"][i][j]));
            assert!(
                se > 0.0 && (value - w[i][j]).abs() <= 4.0 * se,
                "W{i}{j}: {value} ± {se} vs {}",
                w[i][j]
            );
        }
    }
    let (value, se) = (f(&v["params"]["r"]), f(&v["se"]["r"]));
    assert!((value - r).abs() <= 4.0 * se, "r: {value} ± {se} vs {r}");
    // det W = 1.
    let m = Matrix3::from_fn(|i, j| f(&v["params"]["matrix"][i][j]));
    assert!((m.determinant() - 1.0).abs() < 1e-9);
    // Noise 0.002 per axis on r = 0.5: the radial error is 0.4 % of r.
    let rms = f(&v["rms"]);
    assert!((0.0036..0.0044).contains(&rms), "rms {rms}");
    let cov = &v["coverage"];
    assert_eq!(cov["regions"], 100);
    assert!(f(&cov["fraction"]) >= 0.85, "{cov}");
    assert_eq!(
        f(&cov["fraction"]),
        cov["covered"].as_f64().unwrap() / 100.0
    );
    assert!(cov["missing"].is_array());
    assert_eq!(
        v["supported_models"],
        serde_json::json!(["offset+scale+cross-axis", "offset+scale", "offset"])
    );
    let models = v["models"].as_array().unwrap();
    assert_eq!(models.len(), 3);
    // Nested models on the same samples: the rms grows as the model shrinks.
    let rms_of = |k: usize| f(&models[k]["rms"]);
    assert_eq!(rms_of(0), rms);
    assert!(rms_of(0) < rms_of(1) && rms_of(1) < rms_of(2));
    assert!(v["iterations"].as_u64().unwrap() >= 1);
    assert!(f(&v["fit_seconds"]) >= 0.0);
    assert_eq!(v["still"], Value::Null);
}

#[test]
fn output_writes_calibrated_samples_on_the_sphere() {
    let dir = tempfile::tempdir().unwrap();
    let sim = tumble(0.002, 800, 8);
    let raw = sim.simulate().unwrap();
    let file = write_csv(&dir, "tumble.csv", ["mx", "my", "mz"], &raw);
    let out = dir.path().join("calibrated.csv");
    let v: Value = serde_json::from_str(&run_ok(&[
        "fit",
        &file,
        "--x",
        "mx",
        "--y",
        "my",
        "--z",
        "mz",
        "--json",
        "--output",
        out.to_str().unwrap(),
    ]))
    .unwrap();
    let r = f(&v["params"]["r"]);
    let text = fs::read_to_string(&out).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t,x,y,z"));
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|c| c.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 800);
    let mut sq = 0.0;
    for (i, row) in rows.iter().enumerate() {
        assert!((row[0] - i as f64 * 0.01).abs() < 1e-12);
        let m = (row[1] * row[1] + row[2] * row[2] + row[3] * row[3]).sqrt();
        // Within 5 noise SDs (0.002 per axis) of r.
        assert!((m - r).abs() < 5.0 * 0.002, "row {i}: |c| = {m}, r = {r}");
        sq += (m / r - 1.0).powi(2);
    }
    // The rms of the written samples is the reported rms.
    let rms = (sq / rows.len() as f64).sqrt();
    assert!((rms - f(&v["rms"])).abs() < 1e-9, "{rms} vs {}", v["rms"]);
}

/// Static poses (each held `hold` s at 100 Hz) joined by turns at
/// 90 °/s along great circles, noise 0.003 g per axis, as an
/// accelerometer with gyro columns (rate about a bias of (1, −2, 0.5)
/// °/s, the gyro's noise 0.1 °/s).
fn poses_csv(dir: &tempfile::TempDir, name: &str, dirs: &[Vector3<f64>], hold: f64) -> String {
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let w = [[1.03, 0.0, 0.0], [0.0, 0.98, 0.0], [0.0, 0.0, 0.99]];
    let winv = Matrix3::from_fn(|i, j| w[i][j]).try_inverse().unwrap();
    let o = Vector3::new(0.04, -0.03, 0.06);
    let mut text = String::from("t,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z\n");
    let mut k = 0usize;
    let mut push = |u: Vector3<f64>, rate: Vector3<f64>, rng: &mut ChaCha8Rng| {
        let n = Vector3::from_fn(|_, _| StandardNormal.sample(rng)) * 0.003;
        let p = winv * u + o + n;
        let g = rate
            + Vector3::new(1.0, -2.0, 0.5)
            + Vector3::from_fn(|_, _| StandardNormal.sample(rng)) * 0.1;
        text.push_str(&format!(
            "{},{},{},{},{},{},{}\n",
            k as f64 * 0.01,
            p[0],
            p[1],
            p[2],
            g[0],
            g[1],
            g[2]
        ));
        k += 1;
    };
    for (i, &u) in dirs.iter().enumerate() {
        for _ in 0..(hold * 100.0) as usize {
            push(u, Vector3::zeros(), &mut rng);
        }
        if let Some(&next) = dirs.get(i + 1) {
            let angle = u.dot(&next).clamp(-1.0, 1.0).acos();
            let axis = if u.cross(&next).norm() > 1e-9 {
                u.cross(&next).normalize()
            } else {
                u.cross(&Vector3::new(0.3, 0.5, 0.8)).normalize()
            };
            let steps = (angle.to_degrees() / 90.0 * 100.0).ceil() as usize;
            for s in 1..steps {
                let rot = Rotation3::from_axis_angle(
                    &Unit::new_normalize(axis),
                    angle * s as f64 / steps as f64,
                );
                push(rot * u, axis * 90.0, &mut rng);
            }
        }
    }
    let path = dir.path().join(name);
    fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn six() -> Vec<Vector3<f64>> {
    vec![
        Vector3::z(),
        -Vector3::x(),
        Vector3::y(),
        Vector3::x(),
        -Vector3::y(),
        -Vector3::z(),
    ]
}

fn acc(file: &str) -> Vec<&str> {
    vec!["fit", file, "--x", "acc_x", "--y", "acc_y", "--z", "acc_z"]
}

#[test]
fn six_still_poses_are_found_and_support_offset_scale_only() {
    let dir = tempfile::tempdir().unwrap();
    let file = poses_csv(&dir, "six.csv", &six(), 3.0);
    let mut args = acc(&file);
    args.extend(["--still", "--json"]);
    // The full model by default: refused, naming the missing directions,
    // the model the poses support and how to ask for it.
    let message = run_err(&args);
    for needle in [
        "no 3-D calibration (on 6 still poses",
        "offset+scale+cross-axis model",
        "covered only 12 of 100 regions: +x",
        "the data still support the offset+scale model",
        "--effects offset+scale",
    ] {
        assert!(message.contains(needle), "{needle:?} not in {message}");
    }
    args.extend(["--effects", "offset+scale"]);
    let v: Value = serde_json::from_str(&run_ok(&args)).unwrap();
    assert_eq!(v["model"], "offset+scale");
    assert_eq!(v["units"], "g");
    let still = &v["still"];
    assert_eq!(still["poses"], 6, "{still}");
    assert_eq!(
        still["gyro_columns"],
        serde_json::json!(["gyro_x", "gyro_y", "gyro_z"])
    );
    let bias = &still["gyro_bias_deg_s"];
    assert!(
        (f(&bias[0]) - 1.0).abs() < 0.05 && (f(&bias[1]) + 2.0).abs() < 0.05,
        "{bias}"
    );
    // Each pose: 300 samples held; the turns' samples are left out.
    let samples = still["samples"].as_u64().unwrap();
    assert!((6 * 250..=6 * 300).contains(&samples), "{samples}");
    assert_eq!(v["n"].as_u64().unwrap(), samples);
    // The truth: o = (0.04, -0.03, 0.06) g, gains 1.03, 0.98, 0.99 (det
    // W = 1 divides them by their geometric mean, r = 1 g ÷ it).
    let truth_o = [0.04, -0.03, 0.06];
    for i in 0..3 {
        let (value, se) = (f(&v["params"]["offset"][i]), f(&v["se"]["offset"][i]));
        assert!(
            (value - truth_o[i]).abs() <= 4.0 * se,
            "o{i}: {value} ± {se}"
        );
    }
    let scale = (1.03f64 * 0.98 * 0.99).cbrt();
    let (r, se) = (f(&v["params"]["r"]), f(&v["se"]["r"]));
    assert!((r - 1.0 / scale).abs() <= 4.0 * se, "r {r} ± {se}");
    assert_eq!(
        v["supported_models"],
        serde_json::json!(["offset+scale", "offset"])
    );
    // Six poses, each on the edge of up to four regions (±x, ±y lie on
    // the equator, a band edge, at region edges): a sixth of the sphere or
    // less.
    let covered = v["coverage"]["covered"].as_u64().unwrap();
    assert!((6..=24).contains(&covered), "{covered}");
}

#[test]
fn the_still_option_reports_every_pose_of_a_longer_session() {
    // 14 poses: the six axes and the eight octant diagonals, each held
    // 1.5 s.
    let mut dirs = six();
    for sx in [1.0, -1.0] {
        for sy in [1.0, -1.0] {
            for sz in [1.0, -1.0] {
                dirs.push(Vector3::new(sx, sy, sz).normalize());
            }
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let file = poses_csv(&dir, "fourteen.csv", &dirs, 1.5);
    let mut args = acc(&file);
    args.extend(["--still", "--json", "--effects", "offset+scale"]);
    let v: Value = serde_json::from_str(&run_ok(&args)).unwrap();
    assert_eq!(v["still"]["poses"], 14, "{}", v["still"]);
    assert_eq!(v["still"]["segments"].as_array().unwrap().len(), 14);
    // Without the gyro, the readings alone find the same poses.
    args.extend(["--still-gyro", "none"]);
    let v: Value = serde_json::from_str(&run_ok(&args)).unwrap();
    assert_eq!(v["still"]["poses"], 14);
    assert_eq!(v["still"]["gyro_columns"], Value::Null);
}

#[test]
fn partial_coverage_is_refused_naming_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let raw = SimSensor3 {
        motion: Motion3::Cap {
            half_angle_deg: 90.0,
        },
        ..tumble(0.002, 1000, 4)
    }
    .simulate()
    .unwrap();
    let file = write_csv(&dir, "half.csv", ["x", "y", "z"], &raw);
    for effects in [None, Some("offset"), Some("full+drift+outliers")] {
        let mut args = vec!["fit", file.as_str()];
        if let Some(e) = effects {
            args.extend(["--effects", e]);
        }
        let message = run_err(&args);
        assert!(
            message.contains("half.csv: no 3-D calibration"),
            "{message}"
        );
        assert!(message.contains("missing: -z"), "{message}");
        assert!(
            message.contains("the data support no 3-D model"),
            "{message}"
        );
    }
}

#[test]
fn effects_lists_map_onto_the_3d_models() {
    let dir = tempfile::tempdir().unwrap();
    let raw = tumble(0.002, 300, 1).simulate().unwrap();
    let file = write_csv(&dir, "t.csv", ["x", "y", "z"], &raw);
    // cubic-centred is defined about a turn's centre in its plane: no 3-D
    // form, refused by name with what to use instead.
    let message = run_err(&["fit", &file, "--effects", "full,cubic-centred"]);
    assert!(
        message.contains("t.csv: no 3-D calibration")
            && message.contains("the effect cubic-centred has no 3-D form")
            && message.contains("use cubic"),
        "{message}"
    );
    // The base models' names map onto the 3-D models.
    for (list, model) in [
        ("offset", "offset"),
        ("offset,scale", "offset+scale"),
        ("paper", "offset+scale"),
        ("offset+scale+cross-axis", "offset+scale+cross-axis"),
        ("full", "offset+scale+cross-axis"),
    ] {
        let v: Value =
            serde_json::from_str(&run_ok(&["fit", &file, "--effects", list, "--json"])).unwrap();
        assert_eq!(v["model"], model, "--effects {list}");
    }
    // `full` is no 2-axis effect list: the 2-D fit refuses it as before.
    let two = common::repo_path("tests/data/sim_mild.csv");
    let message = run_err(&["fit", two.to_str().unwrap(), "--effects", "full"]);
    assert!(
        message.starts_with("fieldcal: error: --effects: "),
        "{message}"
    );
}

#[test]
fn real_magnetometer_tumble_fits_in_3d() {
    let file = tilt_sphere("hmc5883l_mag.csv");
    let v: Value = serde_json::from_str(&run_ok(&[
        "fit", &file, "--x", "mag_x", "--y", "mag_y", "--z", "mag_z", "--json",
    ]))
    .unwrap();
    assert_eq!(v["model"], "offset+scale+cross-axis");
    // 4322 readings; the spike gate leaves out one of them (row 1483:
    // mag_z 23 counts off the 7 around it, 6.2 σ).
    assert_eq!(v["n"], 4321);
    assert_eq!(v["units"], Value::Null);
    let r = f(&v["params"]["r"]);
    // The Earth's field is 0.22 to 0.67 G everywhere (WMM2025 total
    // intensity); the HMC5883L reads gauss at gain 1090 counts/G.
    assert!((0.22..0.67).contains(&r), "r {r}");
    // ArduPilot's fitness limit (COMPASS_CAL_FIT, default 16 mG rms): the
    // full model passes it, the offset alone does not on this board.
    let models = v["models"].as_array().unwrap();
    let mg = |k: usize| f(&models[k]["rms"]) * f(&models[k]["r"]) * 1000.0;
    assert_eq!(models[0]["model"], "offset+scale+cross-axis");
    assert!(mg(0) < 16.0, "full: {} mG", mg(0));
    assert!(mg(2) > 16.0, "offset: {} mG", mg(2));
    assert!(mg(0) < mg(1) && mg(1) < mg(2));
    assert!(f(&v["coverage"]["fraction"]) >= 0.85);
    // --output: the calibrated samples lie on the sphere of radius r, with
    // the reported rms.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mag3.csv");
    run_ok(&[
        "fit",
        &file,
        "--x",
        "mag_x",
        "--y",
        "mag_y",
        "--z",
        "mag_z",
        "--output",
        out.to_str().unwrap(),
    ]);
    let text = fs::read_to_string(&out).unwrap();
    assert!(text.starts_with("t,x,y,z\n"));
    let magnitudes: Vec<f64> = text
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|c| c.parse().unwrap()).collect();
            (c[1] * c[1] + c[2] * c[2] + c[3] * c[3]).sqrt()
        })
        .collect();
    // Every sample fitted: the 4322 rows less the one the spike gate left
    // out.
    assert_eq!(magnitudes.len(), 4321);
    let rms = (magnitudes
        .iter()
        .map(|m| (m / r - 1.0).powi(2))
        .sum::<f64>()
        / magnitudes.len() as f64)
        .sqrt();
    assert!((rms - f(&v["rms"])).abs() < 1e-9, "{rms} vs {}", v["rms"]);
    // The text report names the units as unknown and every model's rms.
    let text = run_ok(&[
        "fit", &file, "--x", "mag_x", "--y", "mag_y", "--z", "mag_z", "--units", "G",
    ]);
    for needle in [
        "r         0.534",
        " G",
        "rms of each model",
        "offset+scale 2.",
        "W  ",
    ] {
        assert!(text.contains(needle), "{needle:?} not in\n{text}");
    }
    // The solver's start is named for the model it fits: Li & Griffiths'
    // ellipsoid, or for `offset` the sphere.
    assert!(
        text.contains("from the closed-form ellipsoid (Li & Griffiths)"),
        "{text}"
    );
    let mut args = vec!["fit", file.as_str(), "--x", "mag_x", "--y", "mag_y"];
    args.extend(["--z", "mag_z", "--effects", "offset"]);
    let text = run_ok(&args);
    assert!(
        text.contains("from the closed-form sphere (linear least squares)"),
        "{text}"
    );
}

#[test]
fn real_accelerometer_tumble_fits_in_g() {
    let file = tilt_sphere("mpu6050.csv");
    let v: Value = serde_json::from_str(&run_ok(&[
        "fit", &file, "--x", "acc_x", "--y", "acc_y", "--z", "acc_z", "--json",
    ]))
    .unwrap();
    assert_eq!(v["units"], "g");
    let r = f(&v["params"]["r"]);
    // MPU-6050 datasheet (PS-MPU-6000A-00 table 6.2): sensitivity ±3 %,
    // zero-g offset ±50 mg (x, y) and ±80 mg (z), cross-axis ±2 %.
    assert!((r - 1.0).abs() <= 0.03, "r {r} g");
    for (i, limit) in [0.05, 0.05, 0.08].into_iter().enumerate() {
        let o = f(&v["params"]["offset"][i]);
        assert!(o.abs() <= limit, "offset {i}: {o} g");
        for j in 0..3 {
            let wij = f(&v["params"]["matrix"][i][j]);
            let bound = if i == j { 0.03 } else { 0.02 };
            let truth = if i == j { 1.0 } else { 0.0 };
            assert!((wij - truth).abs() <= bound, "W{i}{j} {wij}");
        }
    }
    // The hand's own acceleration never rests 0.5 s on this tumble:
    // --still finds no pose, and says so.
    let message = run_err(&[
        "fit", &file, "--x", "acc_x", "--y", "acc_y", "--z", "acc_z", "--still",
    ]);
    assert!(message.contains("the sensor never held still"), "{message}");
}

#[test]
fn two_axes_of_a_tumble_are_refused_pointing_to_the_third() {
    let file = tilt_sphere("hmc5883l_mag.csv");
    for (x, y, z) in [("mag_x", "mag_y", "mag_z"), ("mag_y", "mag_z", "mag_x")] {
        let message = run_err(&["fit", &file, "--x", x, "--y", y]);
        assert!(message.contains("fill a disc"), "{message}");
        assert!(
            message.contains(&format!("--x {x} --y {y} --z {z}")),
            "{message}"
        );
    }
}

#[test]
fn bad_readings_and_2d_options_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let real = fs::read_to_string(tilt_sphere("hmc5883l_mag.csv")).unwrap();
    let lines: Vec<&str> = real.lines().take(400).collect();
    for (value, needle) in [
        ("nan", "is not a finite number"),
        ("1e200", "too large to square"),
    ] {
        let mut bad = lines.clone();
        let row = format!("1.0,0.1,0.2,{value}");
        bad[49] = &row;
        let path = dir.path().join("bad.csv");
        fs::write(&path, bad.join("\n") + "\n").unwrap();
        let path = path.to_str().unwrap();
        let message = run_err(&["fit", path, "--x", "mag_x", "--y", "mag_y", "--z", "mag_z"]);
        assert!(
            message.contains("bad.csv:50: column 'mag_z'") && message.contains(needle),
            "{message}"
        );
    }
    let file = tilt_sphere("hmc5883l_mag.csv");
    let axes = ["fit", &file, "--x", "mag_x", "--y", "mag_y", "--z", "mag_z"];
    for (extra, needle) in [
        (&["--gyro", "gyro_z"][..], "--gyro checks a 2-axis heading"),
        (
            &["--solver", "paper-gd"][..],
            "--solver paper-gd fits the paper's 2-axis model",
        ),
        (&["--min-coverage", "200"][..], "sphere's coverage rule"),
    ] {
        let mut args = axes.to_vec();
        args.extend(extra);
        let message = run_err(&args);
        assert!(message.contains(needle), "{message}");
    }
    // --units and --still need a third axis.
    let message = run_err(&["fit", &file, "--x", "mag_x", "--y", "mag_y", "--units", "G"]);
    assert!(
        message.contains("name the third axis with --z"),
        "{message}"
    );
}

#[test]
fn two_axes_of_simulated_tumbles_are_refused_for_every_seed() {
    // Any two axes of a tumble fill a disc: the 2-D fit refuses (the turn
    // gate's hole test) and points to the third axis, for every seed.
    let dir = tempfile::tempdir().unwrap();
    for seed in 0..20 {
        let raw = tumble(0.005, 1500, 100 + seed).simulate().unwrap();
        let file = write_csv(&dir, "tumble.csv", ["mx", "my", "mz"], &raw);
        for (x, y, z) in [("mx", "my", "mz"), ("my", "mz", "mx"), ("mx", "mz", "my")] {
            let message = run_err(&["fit", &file, "--x", x, "--y", y]);
            assert!(
                message.contains(&format!("--x {x} --y {y} --z {z}")),
                "seed {seed}: {message}"
            );
        }
    }
}

/// A file with a `z` column fits in 3-D by default; naming the two axes
/// (even as `--x x --y y`) asks for the 2-D fit of a turn.
#[test]
fn naming_two_axes_asks_for_the_2d_fit_even_when_the_file_has_z() {
    let dir = tempfile::tempdir().unwrap();
    let raw = SimSensor3 {
        motion: fieldcal::sim3::Motion3::WobblingTurn {
            turns: 2.0,
            inclination_deg: 0.0,
            tilt_deg: 0.0,
        },
        ..tumble(0.002, 800, 5)
    }
    .simulate()
    .unwrap();
    let file = write_csv(&dir, "turn.csv", ["x", "y", "z"], &raw);
    // Default: three axes, and a turn is refused in 3-D.
    let message = run_err(&["fit", &file]);
    assert!(message.contains("no 3-D calibration"), "{message}");
    // Named axes: the paper's 2-D model.
    let v: Value =
        serde_json::from_str(&run_ok(&["fit", &file, "--x", "x", "--y", "y", "--json"])).unwrap();
    assert!(v["axes"].is_null(), "{v}");
    assert!(v["params"]["a"].is_f64(), "{v}");
}

/// Writes `t,x,y,z` at 100 Hz and the named extra columns.
fn write_csv_with(
    dir: &tempfile::TempDir,
    name: &str,
    points: &[[f64; 3]],
    time: bool,
    extra: &[(&str, &[f64])],
) -> String {
    let mut header: Vec<String> = Vec::new();
    if time {
        header.push("t".into());
    }
    header.extend(["x", "y", "z"].map(String::from));
    header.extend(extra.iter().map(|(n, _)| n.to_string()));
    let mut text = header.join(",") + "\n";
    for (i, p) in points.iter().enumerate() {
        let mut row: Vec<String> = Vec::new();
        if time {
            row.push((i as f64 * 0.01).to_string());
        }
        row.extend(p.iter().map(|v| v.to_string()));
        row.extend(extra.iter().map(|(_, v)| v[i].to_string()));
        text.push_str(&(row.join(",") + "\n"));
    }
    let path = dir.path().join(name);
    fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

const DRIFT: [f64; 3] = [0.002, -0.0015, 0.001];
const PER_DEGREE: [f64; 3] = [0.006, 0.004, -0.005];

/// A tumble at 100 Hz (r = 0.5, noise 0.002 per axis) whose offset moves
/// by DRIFT per second about the mid time, or by PER_DEGREE per degree of
/// a temperature that warms and cools twice about its mean; the
/// temperature, logged as `temp`.
fn moving_tumble(n: usize, seed: u64, drift: bool, covariate: bool) -> (Vec<[f64; 3]>, Vec<f64>) {
    let mut points = tumble(0.002, n, seed).simulate().unwrap();
    let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
    let span = t[n - 1];
    let temp: Vec<f64> = t
        .iter()
        .map(|&s| 25.0 + 8.0 * (std::f64::consts::TAU * 2.0 * s / span).sin() + 0.3 * s)
        .collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (t_mean, temp_mean) = (mean(&t), mean(&temp));
    for (i, p) in points.iter_mut().enumerate() {
        for j in 0..3 {
            if drift {
                p[j] += DRIFT[j] * (t[i] - t_mean);
            }
            if covariate {
                p[j] += PER_DEGREE[j] * (temp[i] - temp_mean);
            }
        }
    }
    (points, temp)
}

/// `fit --effects full+drift` and `full+covariate:temp` in 3-D: over
/// seeds, every fitted extra lies within 3 reported SEs of the truth, and
/// the base parameters keep theirs; the JSON keeps the 3-D contract and
/// adds the extras by name.
#[test]
fn drift_and_a_covariate_are_fitted_in_3d_within_their_standard_errors() {
    let dir = tempfile::tempdir().unwrap();
    for seed in 0..5 {
        for (effects, drift, covariate, stem, truth) in [
            ("full+drift", true, false, "drift", DRIFT),
            ("full+covariate:temp", false, true, "temp", PER_DEGREE),
        ] {
            let (raw, temp) = moving_tumble(2000, 40 + seed, drift, covariate);
            let file = write_csv_with(&dir, "m.csv", &raw, true, &[("temp", &temp)]);
            let v: Value =
                serde_json::from_str(&run_ok(&["fit", &file, "--effects", effects, "--json"]))
                    .unwrap();
            let what = format!("seed {seed}, {effects}");
            for (i, axis) in ["x", "y", "z"].iter().enumerate() {
                let name = format!("{stem}_{axis}");
                let value = f(&v["params"]["extra"][&name]);
                let se = f(&v["se"]["extra"][&name]);
                assert!(
                    se > 0.0 && (value - truth[i]).abs() <= 3.0 * se,
                    "{what}: {name} = {value} ± {se}, truth {}",
                    truth[i]
                );
            }
            let (o, _, r) = tumble(0.002, 2000, 40 + seed).truth();
            for i in 0..3 {
                let (value, se) = (f(&v["params"]["offset"][i]), f(&v["se"]["offset"][i]));
                assert!(
                    (value - o[i]).abs() <= 4.0 * se,
                    "{what}: o{i} {value} ± {se}"
                );
            }
            let (value, se) = (f(&v["params"]["r"]), f(&v["se"]["r"]));
            assert!((value - r).abs() <= 4.0 * se, "{what}: r {value} ± {se}");
            // With the offset moving, the base model alone is worse; with
            // it removed, what remains is the noise (0.002 on 0.5: 0.4 %).
            let rms = f(&v["rms"]);
            assert!((0.0036..0.0044).contains(&rms), "{what}: rms {rms}");
            assert!(f(&v["base_rms"]) > 1.5 * rms, "{what}: {v}");
            // The contract: every key of the base report, and the extras.
            assert_eq!(v["axes"], 3);
            assert_eq!(v["base_model"], "offset+scale+cross-axis");
            let extra = if drift { "drift" } else { "covariate:temp" };
            assert_eq!(v["model"], format!("offset+scale+cross-axis+{extra}"));
            assert_eq!(
                v["effects"],
                serde_json::json!(["offset", "scale", "cross-axis", extra])
            );
            assert_eq!(v["params"]["matrix"].as_array().unwrap().len(), 3);
            assert_eq!(v["se"]["offset"].as_array().unwrap().len(), 3);
            assert!(v["se"]["r"].is_f64() && v["params"]["r"].is_f64());
            assert_eq!(v["params"]["extra"].as_object().unwrap().len(), 3);
            assert_eq!(v["n"], 2000);
            assert_eq!(v["unknowns"], 12);
            assert_eq!(v["flagged"]["count"], 0);
            for key in ["units", "coverage", "models", "supported_models", "still"] {
                assert!(v.get(key).is_some(), "{what}: no {key}");
            }
            assert_eq!(
                v["supported_models"],
                serde_json::json!(["offset+scale+cross-axis", "offset+scale", "offset"])
            );
        }
    }
}

/// The text report lists each extra with its SE, its units and what it
/// means, and the rms with and without the extras.
#[test]
fn the_text_report_explains_the_extras() {
    let dir = tempfile::tempdir().unwrap();
    let (raw, temp) = moving_tumble(2000, 7, true, true);
    let file = write_csv_with(&dir, "m.csv", &raw, true, &[("temp", &temp)]);
    let text = run_ok(&[
        "fit",
        &file,
        "--effects",
        "full+drift+covariate:temp+outliers",
        "--units",
        "uT",
    ]);
    let line = |label: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("{label} ")))
            .unwrap_or_else(|| panic!("no {label} line in\n{text}"))
            .to_string()
    };
    assert!(
        line("model").contains("offset+scale+cross-axis+drift+covariate:temp+outliers"),
        "{text}"
    );
    let drift = line("drift_x");
    assert!(
        drift.contains(" ± ") && drift.contains("uT/s") && drift.contains("uT per hour"),
        "{drift}"
    );
    let temp_line = line("temp_y");
    assert!(
        temp_line.contains("uT/unit") && temp_line.contains("per unit of the column 'temp'"),
        "{temp_line}"
    );
    assert!(
        line("flagged").contains("samples set aside as outliers"),
        "{text}"
    );
    assert!(line("rms").contains("% of r"), "{text}");
    assert!(
        line("without").contains("the offset+scale+cross-axis model alone, no extras"),
        "{text}"
    );
}

/// `--output` writes every sample with the extras removed: the drifting
/// tumble lands on the sphere with the reported rms; with outliers, the
/// columns stay t,x,y,z (as in 2-D; the flagged samples are in the JSON).
#[test]
fn output_removes_the_drift() {
    let dir = tempfile::tempdir().unwrap();
    let (raw, _) = moving_tumble(1500, 11, true, false);
    let file = write_csv_with(&dir, "d.csv", &raw, true, &[]);
    let out = dir.path().join("c.csv");
    for effects in ["full+drift", "full+drift+outliers"] {
        let v: Value = serde_json::from_str(&run_ok(&[
            "fit",
            &file,
            "--effects",
            effects,
            "--json",
            "--output",
            out.to_str().unwrap(),
        ]))
        .unwrap();
        let r = f(&v["params"]["r"]);
        let text = fs::read_to_string(&out).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("t,x,y,z"));
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|c| c.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 1500);
        let flagged: Vec<u64> = v["flagged"]["indices"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i.as_u64().unwrap())
            .collect();
        let mut sq = 0.0;
        let mut used = 0;
        for (i, row) in rows.iter().enumerate() {
            assert!((row[0] - i as f64 * 0.01).abs() < 1e-12);
            let m = (row[1] * row[1] + row[2] * row[2] + row[3] * row[3]).sqrt();
            // Within 5 noise SDs of r (the drift moves the offset by 0.03
            // over the run, 15 noise SDs).
            assert!(
                (m - r).abs() < 5.0 * 0.002,
                "{effects} row {i}: |c| = {m}, r = {r}"
            );
            if !flagged.contains(&(i as u64)) {
                sq += (m / r - 1.0).powi(2);
                used += 1;
            }
        }
        let rms = (sq / used as f64).sqrt();
        assert!(
            (rms - f(&v["rms"])).abs() < 1e-9,
            "{effects}: {rms} vs {}",
            v["rms"]
        );
    }
}

/// An effect the recording cannot determine is refused naming the effect
/// or the column and what to do.
#[test]
fn effects_the_recording_cannot_determine_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let (raw, temp) = moving_tumble(600, 2, true, false);
    let constant = vec![21.5; raw.len()];
    let no_time = write_csv_with(&dir, "no_t.csv", &raw, false, &[("temp", &temp)]);
    let file = write_csv_with(
        &dir,
        "m.csv",
        &raw,
        true,
        &[("temp", &temp), ("board", &constant)],
    );
    for (args, needles) in [
        (
            vec!["fit", no_time.as_str(), "--effects", "full+drift"],
            vec![
                "no_t.csv: no 3-D calibration",
                "the drift effect needs sample times",
                "no time column",
                "--t",
            ],
        ),
        (
            vec!["fit", file.as_str(), "--effects", "full+covariate:humidity"],
            vec![
                "m.csv: no 3-D calibration",
                "no column 'humidity' for the effect covariate:humidity",
                "its covariate columns are: temp, board",
            ],
        ),
        (
            vec!["fit", file.as_str(), "--effects", "full+covariate:board"],
            vec![
                "m.csv: no 3-D calibration",
                "do not determine the parameter 'board_x'",
                "its column is constant",
                "drop the effect",
            ],
        ),
    ] {
        let message = run_err(&args);
        for needle in needles {
            assert!(message.contains(needle), "{needle:?} not in {message}");
        }
    }
}

/// Extras keep the coverage rule and --still: six poses refuse the full
/// model with the extras kept in the hint; fourteen poses fit with drift,
/// on the still samples, and --output writes every sample.
#[test]
fn extras_keep_the_coverage_rule_and_still_poses() {
    let dir = tempfile::tempdir().unwrap();
    let six_file = poses_csv(&dir, "six.csv", &six(), 3.0);
    let mut args = acc(&six_file);
    args.extend(["--still", "--effects", "full+outliers"]);
    let message = run_err(&args);
    assert!(
        message.contains("no 3-D calibration (on 6 still poses")
            && message.contains("to fit it: --effects offset+scale+outliers"),
        "{message}"
    );
    let mut dirs = six();
    for sx in [1.0, -1.0] {
        for sy in [1.0, -1.0] {
            for sz in [1.0, -1.0] {
                dirs.push(Vector3::new(sx, sy, sz).normalize());
            }
        }
    }
    let file = poses_csv(&dir, "fourteen.csv", &dirs, 1.5);
    let out = dir.path().join("c.csv");
    let mut args = acc(&file);
    args.extend([
        "--still",
        "--effects",
        "offset+scale+drift",
        "--json",
        "--output",
        out.to_str().unwrap(),
    ]);
    let v: Value = serde_json::from_str(&run_ok(&args)).unwrap();
    assert_eq!(v["still"]["poses"], 14);
    assert_eq!(v["units"], "g");
    assert_eq!(v["n"], v["still"]["samples"]);
    assert_eq!(v["model"], "offset+scale+drift");
    // No drift was simulated: each rate within 3 SE of zero.
    for axis in ["x", "y", "z"] {
        let name = format!("drift_{axis}");
        let (value, se) = (f(&v["params"]["extra"][&name]), f(&v["se"]["extra"][&name]));
        assert!(value.abs() <= 3.0 * se, "{name} = {value} ± {se}");
    }
    // Every sample of the recording is written, the moving ones too.
    let rows = fs::read_to_string(&out).unwrap().lines().count() - 1;
    assert_eq!(rows, v["still"]["of"].as_u64().unwrap() as usize);
}

/// The real tumble: `fit --effects full+drift` and `full+drift+outliers`
/// give what `fieldcal diagnose` reports for the same models on the same
/// file (its ladder's steps), and the drift lowers the rms of the full
/// model (0.83 % to 0.68 %).
#[test]
fn real_magnetometer_fit_with_drift_agrees_with_diagnose() {
    let file = tilt_sphere("hmc5883l_mag.csv");
    let axes = ["--x", "mag_x", "--y", "mag_y", "--z", "mag_z"];
    let mut args = vec!["diagnose", file.as_str()];
    args.extend(axes);
    args.push("--json");
    let diagnosis: Value = serde_json::from_str(&run_ok(&args)).unwrap();
    for effects in ["full+drift", "full+drift+outliers"] {
        let mut args = vec!["fit", file.as_str()];
        args.extend(axes);
        args.extend(["--units", "G", "--effects", effects, "--json"]);
        let v: Value = serde_json::from_str(&run_ok(&args)).unwrap();
        let step = diagnosis["ladder"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["model"] == v["model"])
            .unwrap_or_else(|| panic!("no ladder step {} in {diagnosis}", v["model"]));
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1e-12);
        assert!(
            close(f(&v["rms"]), f(&step["rms"])),
            "{effects}: {} vs {}",
            v["rms"],
            step["rms"]
        );
        assert_eq!(v["flagged"]["count"], step["flagged"]);
        for p in step["params"].as_array().unwrap() {
            let name = p["name"].as_str().unwrap();
            if let Some(value) = v["params"]["extra"].get(name) {
                assert!(close(f(value), f(&p["value"])), "{effects}: {name}");
                assert!(
                    close(f(&v["se"]["extra"][name]), f(&p["se"])),
                    "{effects}: se {name}"
                );
            }
        }
        assert_eq!(v["params"]["extra"].as_object().unwrap().len(), 3);
        assert!(
            f(&v["rms"]) < 0.0069 && f(&v["base_rms"]) > 0.0083,
            "{effects}: {v}"
        );
    }
}
