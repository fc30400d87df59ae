//! Trust at every reading: a calibrated READING says `"trusted": false`,
//! with the deciding numbers, while a magnet near the compass moves the
//! field or swings the heading the gyro did not see, and `true` otherwise,
//! turning or still. STATUS counts both.

mod common;

use serde_json::Value;

/// A 2-axis compass at 20 Hz with a gyro about its turn: `heading(t)` the
/// true heading (degrees), `rate(t)` the gyro (deg/s), and
/// `magnet(t) -> (field factor, heading swing)` what a magnet does.
fn recording(
    seconds: f64,
    heading: impl Fn(f64) -> f64,
    rate: impl Fn(f64) -> f64,
    magnet: impl Fn(f64) -> (f64, f64),
) -> String {
    let mut text = String::from("t,x,y,gyro_z\n");
    let mut noise = xorshift(0x2545_f491_4f6c_dd1d);
    let n = (seconds * 20.0) as usize;
    for k in 0..n {
        let t = k as f64 / 20.0;
        let (factor, swing) = magnet(t);
        let h = (heading(t) + swing).to_radians();
        let b = 500.0 * factor;
        let x = 120.0 + 1.1 * b * h.cos() + noise();
        let y = -80.0 + b * h.sin() + noise();
        text.push_str(&format!("{t:.2},{x:.3},{y:.3},{:.4}\n", rate(t)));
    }
    text
}

/// Deterministic noise from `seed` (xorshift), about uniform in (-1, 1).
fn xorshift(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % 20_001) as f64 / 10_000.0 - 1.0
    }
}

/// The counts of the [`board`]'s magnetometer and accelerometer for the
/// field `m` and the specific force `g` in body axes, with a hard iron
/// `iron`: the magnetometer mounted as mag x = −body x, mag y = body z,
/// mag z = −body y, with an offset and a scale per axis; each axis with
/// `noise` (drawn in that order: mx, my, mz, ax, ay, az).
fn board_counts(
    m: [f64; 3],
    g: [f64; 3],
    iron: [f64; 3],
    noise: &mut impl FnMut() -> f64,
) -> ([f64; 3], [f64; 3]) {
    let mag = [-m[0], m[2], -m[1]];
    let counts = [
        30.0 + iron[0] + 1.04 * mag[0] + noise(),
        -45.0 + iron[1] + 0.97 * mag[1] + noise(),
        12.0 + iron[2] + mag[2] + noise(),
    ];
    let accel = [
        g[0] + 0.002 * noise(),
        g[1] + 0.002 * noise(),
        g[2] + 0.002 * noise(),
    ];
    (counts, accel)
}

/// The 2-axis compass of a [`recording`]: columns x, y, its gyro gyro_z.
const COMPASS: &str =
    "[[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"x\", \"y\"]\ngyro = \"gyro_z\"\n";

/// A configuration beside `name`.csv in `dir`: a csv source "log" of it,
/// played as fast as it goes, and `sensors` (its `[[sensor]]` sections).
fn write_config(dir: &std::path::Path, name: &str, sensors: &str) -> std::path::PathBuf {
    let config = dir.join(format!("{name}.toml"));
    std::fs::write(
        &config,
        format!(
            "[daemon]\nstate_dir = \"{}\"\nstatus_interval_s = 1.0\n[outputs]\nstdout = true\n\
             [[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{name}.csv\"\nspeed = \"max\"\n{sensors}",
            dir.join("state").display()
        ),
    )
    .unwrap();
    config
}

/// `fieldcal args`' lines out, as JSON.
fn lines_of(args: &[&str]) -> Vec<Value> {
    common::run_ok(args)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Replays `csv`, written as `name`.csv in `dir`, through the daemon with
/// `sensors`; the lines out.
fn replay_with(dir: &std::path::Path, name: &str, csv: &str, sensors: &str) -> Vec<Value> {
    let file = dir.join(format!("{name}.csv"));
    std::fs::write(&file, csv).unwrap();
    let config = write_config(dir, name, sensors);
    lines_of(&[
        "replay",
        file.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--speed",
        "max",
    ])
}

/// Replays `csv` through the daemon with a gyro; the lines out.
fn replay(csv: &str, dir: &std::path::Path) -> Vec<Value> {
    replay_with(dir, "robot", csv, COMPASS)
}

/// The calibrated readings with `from <= t < to`: (all, distrusted).
fn judged(lines: &[Value], from: f64, to: f64) -> (usize, usize) {
    let inside: Vec<&Value> = lines
        .iter()
        .filter(|v| v["class"] == "READING" && v["calibrated"] == true)
        .filter(|v| (from..to).contains(&v["time"].as_f64().unwrap()))
        .collect();
    let bad = inside.iter().filter(|v| v["trusted"] == false).count();
    (inside.len(), bad)
}

/// Turning at 18 °/s for 60 s (the daemon calibrates on the first
/// turn), then still, with a magnet between 70 and 75 s, then turning
/// again from 100 s.
fn heading(t: f64) -> f64 {
    if t < 60.0 {
        18.0 * t
    } else if t < 100.0 {
        0.0
    } else {
        18.0 * (t - 100.0)
    }
}

fn rate(t: f64) -> f64 {
    if (60.0..100.0).contains(&t) {
        0.0
    } else {
        18.0
    }
}

#[test]
fn a_field_five_percent_low_is_distrusted_with_its_numbers_and_nothing_else_is() {
    let dir = tempfile::tempdir().unwrap();
    let csv = recording(140.0, heading, rate, |t| {
        if (70.0..75.0).contains(&t) {
            (0.95, 0.0)
        } else {
            (1.0, 0.0)
        }
    });
    let lines = replay(&csv, dir.path());
    let (all, bad) = judged(&lines, 70.0, 75.0);
    assert_eq!((all, bad), (100, 100), "every reading near the magnet");
    let first = lines
        .iter()
        .find(|v| v["class"] == "READING" && v["time"].as_f64() == Some(70.0))
        .unwrap();
    let reason = first["distrust"][0].as_str().unwrap();
    assert!(reason.starts_with("the field is "), "{reason}");
    assert!(
        reason.contains("% below the calibration's r (limit"),
        "{reason}"
    );
    // Turning after calibration, and still, away from the magnet.
    for (from, to) in [(20.0, 70.0), (75.05, 140.0)] {
        let (all, bad) = judged(&lines, from, to);
        assert!(all > 500, "{from}..{to}: {all}");
        assert_eq!(bad, 0, "{from}..{to}");
    }
    let status = lines.iter().rev().find(|v| v["class"] == "STATUS").unwrap();
    let trust = &status["sensors"][0]["trust"];
    assert_eq!(trust["distrusted"], 100, "{status}");
    assert!((trust["longest_distrusted_s"].as_f64().unwrap() - 4.95).abs() < 1e-6);
}

/// A 2-axis compass whose configuration names the axis across its turn
/// (`out_of_plane = "z"`): a magnet above it that moves only that axis
/// (by 50 counts, 9.9 % of r; the level pair unchanged) is distrusted for as
/// long as it is there, and nothing else is; the calibration keeps the
/// axis's median and spread over its rotation.
#[test]
fn a_field_across_the_turn_that_moved_is_distrusted_when_its_axis_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let turning = recording(140.0, heading, rate, |_| (1.0, 0.0));
    let mut state: u64 = 0x1234_5678_9abc_def1;
    let mut csv = String::new();
    for (k, line) in turning.lines().enumerate() {
        if k == 0 {
            csv.push_str(&format!("{line},z\n"));
            continue;
        }
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let noise = (state % 20_001) as f64 / 10_000.0 - 1.0;
        let t: f64 = line.split(',').next().unwrap().parse().unwrap();
        let magnet = if (70.0..75.0).contains(&t) { 50.0 } else { 0.0 };
        csv.push_str(&format!("{line},{:.3}\n", 300.0 + magnet + noise));
    }
    let sensors = format!("{COMPASS}out_of_plane = \"z\"\n");
    let lines = replay_with(dir.path(), "robot", &csv, &sensors);
    let (all, bad) = judged(&lines, 70.0, 75.0);
    assert_eq!((all, bad), (100, 100), "every reading under the magnet");
    let first = lines
        .iter()
        .find(|v| v["class"] == "READING" && v["time"].as_f64() == Some(70.0))
        .unwrap();
    let reason = first["distrust"][0].as_str().unwrap();
    assert!(
        reason.starts_with(
            "the field across the turn moved by +9.9 % of r from the calibration's (limit"
        ),
        "{reason}"
    );
    for (from, to) in [(20.0, 70.0), (75.05, 140.0)] {
        let (all, bad) = judged(&lines, from, to);
        assert!(all > 500, "{from}..{to}: {all}");
        assert_eq!(bad, 0, "{from}..{to}");
    }
    // Published (and stored) with the calibration: the axis's median and
    // spread over the rotation.
    let cal = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["accepted"] == true)
        .unwrap();
    let across = &cal["across"];
    assert!(
        (across["median"].as_f64().unwrap() - 300.0).abs() < 0.2,
        "{cal}"
    );
    assert!(across["spread"].as_f64().unwrap() < 1.0, "{cal}");
}

#[test]
fn a_heading_swing_the_gyro_did_not_see_is_distrusted_until_it_ends() {
    let dir = tempfile::tempdir().unwrap();
    let csv = recording(140.0, heading, rate, |t| {
        if (70.0..85.0).contains(&t) {
            (1.0, 20.0)
        } else {
            (1.0, 0.0)
        }
    });
    let lines = replay(&csv, dir.path());
    let (all, bad) = judged(&lines, 70.0, 85.0);
    assert_eq!((all, bad), (300, 300), "every swung reading");
    let reason = lines
        .iter()
        .find(|v| v["class"] == "READING" && v["time"].as_f64() == Some(70.0))
        .unwrap()["distrust"][0]
        .as_str()
        .unwrap()
        .to_string();
    assert!(reason.starts_with("the heading moved 2"), "{reason}");
    assert!(reason.contains("while the gyro turned 0.0°"), "{reason}");
    for (from, to) in [(20.0, 70.0), (85.0, 140.0)] {
        assert_eq!(judged(&lines, from, to).1, 0, "{from}..{to}");
    }
}

#[test]
fn a_three_axis_compass_distrusts_a_field_six_percent_high_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    // A spiral over the whole sphere for 100 s (the daemon calibrates on
    // it), then still, with a magnet between 110 and 115 s.
    let mut text = String::from("t,x,y,z\n");
    let n = 2600;
    let spiral = 2000;
    for k in 0..n {
        let t = k as f64 / 20.0;
        let i = k.min(spiral - 1) as f64;
        let zc = 1.0 - 2.0 * (i + 0.5) / spiral as f64;
        let ring = (1.0 - zc * zc).sqrt();
        let phi = i * 2.399_963_229_728_653;
        let factor = if (110.0..115.0).contains(&t) {
            1.06
        } else {
            1.0
        };
        let b = 500.0 * factor;
        let wobble = ((k as f64) * 1.7).sin() * 0.8;
        let (x, y, z) = (
            40.0 + 1.05 * b * ring * phi.cos() + wobble,
            -25.0 + b * ring * phi.sin() - wobble,
            10.0 + 0.97 * b * zc + 0.5 * wobble,
        );
        text.push_str(&format!("{t:.2},{x:.3},{y:.3},{z:.3}\n"));
    }
    let lines = replay_with(
        dir.path(),
        "board",
        &text,
        "[[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"x\", \"y\", \"z\"]\n\
         field = \"mag\"\nlsb_per_gauss = 1090\n",
    );
    let calibrated = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["accepted"] == true);
    assert!(
        calibrated.is_some(),
        "no calibration in {} lines",
        lines.len()
    );
    let (all, bad) = judged(&lines, 110.0, 115.0);
    assert_eq!((all, bad), (100, 100));
    let (all, bad) = judged(&lines, 0.0, 110.0);
    assert!(all > 100, "{all}");
    assert_eq!(bad, 0);
    assert_eq!(judged(&lines, 115.05, 1e9).1, 0);
}

#[test]
fn a_gyro_in_another_file_of_the_source_checks_the_heading() {
    let dir = tempfile::tempdir().unwrap();
    // The compass in one file, the gyro in another (as a magnetometer and
    // an MPU-6050 logged apart on one clock), the gyro's rows 25 ms later.
    let one = recording(140.0, heading, rate, |t| {
        if (70.0..85.0).contains(&t) {
            (1.0, 20.0)
        } else {
            (1.0, 0.0)
        }
    });
    let (mut mag, mut gyro) = (String::from("t,x,y\n"), String::from("t,gyro_z\n"));
    for line in one.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        mag.push_str(&format!("{},{},{}\n", f[0], f[1], f[2]));
        let t: f64 = f[0].parse().unwrap();
        gyro.push_str(&format!("{:.3},{}\n", t + 0.025, f[3]));
    }
    std::fs::write(dir.path().join("mag.csv"), mag).unwrap();
    std::fs::write(dir.path().join("imu.csv"), gyro).unwrap();
    let config = dir.path().join("two.toml");
    std::fs::write(
        &config,
        format!(
            "[daemon]\nstate_dir = \"{}\"\n[outputs]\nstdout = true\n\
             [[source]]\nname = \"log\"\nkind = \"csv\"\nfiles = [\"mag.csv\", \"imu.csv\"]\n\
             speed = \"max\"\n\
             [[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"x\", \"y\"]\ngyro = \"gyro_z\"\n",
            dir.path().join("state").display()
        ),
    )
    .unwrap();
    let r = common::run(&[
        "run",
        "--config",
        config.to_str().unwrap(),
        "--progress",
        "never",
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let lines: Vec<Value> = r
        .stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let calibration = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["accepted"] == true)
        .unwrap_or_else(|| panic!("no calibration: {}", r.stderr));
    assert_eq!(
        calibration["heading_vs_gyro"]["gyro_column"], "gyro_z",
        "{calibration}"
    );
    // Times are on the host's clock under `run`: count from the first.
    let t0 = lines
        .iter()
        .find(|v| v["class"] == "READING")
        .and_then(|v| v["time"].as_f64())
        .unwrap();
    let shifted: Vec<Value> = lines
        .iter()
        .filter(|v| v["class"] == "READING")
        .map(|v| {
            let mut v = v.clone();
            v["time"] = serde_json::json!(v["time"].as_f64().unwrap() - t0);
            v
        })
        .collect();
    let (all, bad) = judged(&shifted, 70.0, 85.0);
    assert!(all >= 290 && bad == all, "{bad} of {all}");
    assert_eq!(judged(&shifted, 20.0, 69.9).1, 0);
    assert_eq!(judged(&shifted, 85.1, 140.0).1, 0);
}

/// The rotation matrix (row-major) of `angle` radians about unit `axis`.
fn rotation(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = axis;
    let t = 1.0 - c;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

fn times(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn product(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum::<f64>()))
}

fn transpose(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[j][i]))
}

/// A board with a 3-axis magnetometer (columns mx, my, mz) and an
/// accelerometer (ax, ay, az) at 20 Hz: tumbling through every orientation
/// for 150 s, then still and level. `magnet(t)` turns the Earth's field
/// (dip 65°, 500 counts) about the east axis by that many degrees, its
/// magnitude kept. The magnetometer lies on the board as body x = −mag x,
/// body y = −mag z, body z = mag y (`mag_axes = "-x,-z,y"`).
fn board(magnet: impl Fn(f64) -> f64) -> String {
    board_with(200.0, 150.0, magnet, |_| [0.0; 3])
}

/// [`board`] for `seconds`, tumbling until `tumble_s`, with a hard iron
/// `iron(t)` added to the magnetometer's counts (a magnet fixed to the
/// board).
fn board_with(
    seconds: f64,
    tumble_s: f64,
    magnet: impl Fn(f64) -> f64,
    iron: impl Fn(f64) -> [f64; 3],
) -> String {
    let mut text = String::from("t,mx,my,mz,ax,ay,az\n");
    let mut noise = xorshift(0x9e37_79b9_7f4a_7c15);
    let dip = 65f64.to_radians();
    for k in 0..(seconds * 20.0) as usize {
        let t = k as f64 / 20.0;
        // Body to world (north, east, down): yaw, pitch and roll at rates
        // that do not divide one another, until `tumble_s`; then level.
        let tumble = t.min(tumble_s);
        let level = t >= tumble_s;
        let r = if level {
            rotation([0.0, 0.0, 1.0], 0.6)
        } else {
            let a = rotation([0.0, 0.0, 1.0], 0.53 * tumble);
            let b = rotation([0.0, 1.0, 0.0], 0.31 * tumble);
            let c = rotation([1.0, 0.0, 0.0], 0.17 * tumble);
            product(&product(&a, &b), &c)
        };
        let turn = rotation([0.0, 1.0, 0.0], magnet(t).to_radians());
        let field = times(&turn, [500.0 * dip.cos(), 0.0, 500.0 * dip.sin()]);
        let to_body = transpose(&r);
        let m = times(&to_body, field);
        // The specific force points up: −down.
        let g = times(&to_body, [0.0, 0.0, -1.0]);
        // Magnetometer axes from body axes: mag x = −body x, mag y = body
        // z, mag z = −body y; with an offset and a scale per axis.
        let ([mx, my, mz], [ax, ay, az]) = board_counts(m, g, iron(t), &mut noise);
        text.push_str(&format!(
            "{t:.2},{mx:.3},{my:.3},{mz:.3},{ax:.5},{ay:.5},{az:.5}\n"
        ));
    }
    text
}

/// Replays a [`board`] with the compass's `mag_axes`; the lines out.
fn replay_board(csv: &str, mag_axes: &str, dir: &std::path::Path) -> Vec<Value> {
    replay_with(dir, "board", csv, &board_sensors(mag_axes))
}

/// The [`board`]'s compass, tilt-compensated by its accelerometer, and the
/// accelerometer.
fn board_sensors(mag_axes: &str) -> String {
    format!(
        "[[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"mx\", \"my\", \"mz\"]\n\
         field = \"mag\"\nlsb_per_gauss = 1000\ntilt = \"level\"\nmag_axes = \"{mag_axes}\"\n\
         [[sensor]]\nname = \"level\"\nsource = \"log\"\naxes = [\"ax\", \"ay\", \"az\"]\n\
         field = \"accel\"\nlsb_per_g = 1\n"
    )
}

/// The compass's calibrated readings with a heading, `from <= t < to`:
/// (all, distrusted), and the first reason.
fn compass_judged(lines: &[Value], from: f64, to: f64) -> (usize, usize, String) {
    let inside: Vec<&Value> = lines
        .iter()
        .filter(|v| v["class"] == "READING" && v["sensor"] == "compass")
        .filter(|v| v["calibrated"] == true && v.get("heading_deg").is_some())
        .filter(|v| (from..to).contains(&v["time"].as_f64().unwrap()))
        .collect();
    let bad: Vec<&&Value> = inside.iter().filter(|v| v["trusted"] == false).collect();
    let why = bad
        .first()
        .map(|v| v["distrust"][0].as_str().unwrap().to_string())
        .unwrap_or_default();
    (inside.len(), bad.len(), why)
}

#[test]
fn a_magnet_that_turns_the_field_without_changing_it_is_caught_by_the_dip() {
    let dir = tempfile::tempdir().unwrap();
    // 20° about the east axis, between 170 and 175 s: the magnitude is the
    // same, the dip is 45° where it was 65°.
    let csv = board(|t| {
        if (170.0..175.0).contains(&t) {
            20.0
        } else {
            0.0
        }
    });
    let lines = replay_board(&csv, "-x,-z,y", dir.path());
    let cal = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["sensor"] == "compass" && v["accepted"] == true)
        .unwrap_or_else(|| panic!("no calibration"));
    // The calibration's dip: 65° over the tumble, and the mapping fits.
    let dip = &cal["dip"];
    assert!(
        (dip["median_deg"].as_f64().unwrap() - 65.0).abs() < 0.5,
        "{dip}"
    );
    assert!(dip.get("mounting").is_none(), "{dip}");
    let (all, bad, why) = compass_judged(&lines, 170.0, 175.0);
    assert_eq!((all, bad), (100, 100), "{why}");
    assert!(
        why.starts_with("the dip is 45.0° where the calibration measured 65.0°"),
        "{why}"
    );
    // Before and after it, turning or still, every heading is trusted.
    let (all, bad, why) = compass_judged(&lines, 0.0, 170.0);
    assert!(all > 500, "{all}");
    assert_eq!(bad, 0, "{why}");
    let (all, bad, why) = compass_judged(&lines, 175.05, 1e9);
    assert!(all > 400, "{all}");
    assert_eq!(bad, 0, "{why}");
}

#[test]
fn a_magnetometer_mounted_otherwise_than_configured_has_every_heading_distrusted() {
    let dir = tempfile::tempdir().unwrap();
    let csv = board(|_| 0.0);
    // The identity: the dip wanders as the board tumbles.
    let lines = replay_board(&csv, "x,y,z", dir.path());
    let cal = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["sensor"] == "compass" && v["accepted"] == true)
        .unwrap_or_else(|| panic!("no calibration"));
    let why = cal["dip"]["mounting"]
        .as_str()
        .unwrap_or_else(|| panic!("{cal}"));
    // The tumble tells the mapping up to its mirror; with no place, the
    // right-handed one of the two is named.
    assert!(why.contains("with mag_axes = \"x,y,z\""), "{why}");
    assert!(why.ends_with("set mag_axes = \"x,z,-y\""), "{why}");
    let (all, bad, first) = compass_judged(&lines, 0.0, 1e9);
    assert!(all > 1000, "{all}");
    assert_eq!(bad, all);
    assert_eq!(first, why);
}

/// A 3-axis compass tumbled on after its calibration: each later covered
/// sphere is compared with it. Unchanged, they agree (no STALE); a magnet
/// fixed to the board at 330 s (40 counts on x, 8 % of the field) gives
/// one STALE on the first sphere after it, naming the offset that moved,
/// and from then on every reading is distrusted as stale.
#[test]
fn a_magnet_fixed_to_a_tumbling_board_makes_its_3d_calibration_stale_on_the_next_sphere() {
    let dir = tempfile::tempdir().unwrap();
    let step = 330.0;
    let csv = board_with(
        660.0,
        660.0,
        |_| 0.0,
        |t| {
            if t >= step {
                [40.0, 0.0, 0.0]
            } else {
                [0.0; 3]
            }
        },
    );
    let lines = replay_board(&csv, "-x,-z,y", dir.path());
    let compass = |class: &str| -> Vec<&Value> {
        lines
            .iter()
            .filter(|v| v["class"] == class && v["sensor"] == "compass")
            .collect()
    };
    let accepted: Vec<_> = compass("CALIBRATION")
        .into_iter()
        .filter(|v| v["accepted"] == true)
        .collect();
    assert_eq!(accepted.len(), 1, "{accepted:?}");
    let calibrated_at = accepted[0]["time"].as_f64().unwrap();
    assert!(calibrated_at < step / 2.0, "{calibrated_at}");
    let stale = compass("STALE");
    assert_eq!(stale.len(), 1, "{stale:?}");
    let s = stale[0];
    let at = s["time"].as_f64().unwrap();
    assert!(at > step, "STALE at {at}, before the magnet at {step}");
    assert_eq!(s["calibration"], accepted[0]["id"]);
    assert_eq!(s["action"], "warn");
    let moved: Vec<&str> = s["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["moved"] == true)
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert!(moved.contains(&"o_x"), "{s}");
    let o_x = s["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "o_x")
        .unwrap();
    let shift = o_x["refitted"].as_f64().unwrap() - o_x["stored"].as_f64().unwrap();
    assert!((shift - 40.0).abs() < 2.0, "o_x moved by {shift}: {s}");
    assert!(s["heading_error_deg"].as_f64().unwrap() > s["heading_limit_deg"].as_f64().unwrap());
    // Readings: trusted up to the magnet; distrusted as stale after STALE.
    let readings = compass("READING");
    let calibrated = |from: f64, to: f64| -> Vec<&&Value> {
        readings
            .iter()
            .filter(|v| v["calibrated"] == true)
            .filter(|v| (from..to).contains(&v["time"].as_f64().unwrap()))
            .collect()
    };
    let before = calibrated(0.0, step);
    assert!(before.len() > 1000, "{}", before.len());
    assert!(before.iter().all(|v| v["trusted"] == true));
    let after = calibrated(at + 0.01, 1e9);
    assert!(after.len() > 100, "{}", after.len());
    for v in &after {
        assert_eq!(v["trusted"], false, "{v}");
        let why = v["distrust"][0].as_str().unwrap();
        assert!(
            why.starts_with(&format!(
                "calibration #{} is stale: a later sphere moved",
                s["calibration"]
            )),
            "{why}"
        );
    }
}

/// The mounting verdict and the dip belong to the `mag_axes` they were
/// measured with: after the user sets the mapping the calibration named
/// (and restarts on the stored calibration), no heading is distrusted for
/// the old mapping, and the old dip is not compared with the new one.
#[test]
fn setting_the_mapping_the_calibration_named_ends_its_distrust_after_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("board.csv"), board(|_| 0.0)).unwrap();
    let run = |mag_axes: &str| -> Vec<Value> {
        let config = write_config(dir.path(), "board", &board_sensors(mag_axes));
        lines_of(&[
            "run",
            "--config",
            config.to_str().unwrap(),
            "--progress",
            "never",
        ])
    };
    let first = run("x,y,z");
    let mounting = |lines: &[Value]| {
        lines
            .iter()
            .filter(|v| v["class"] == "READING" && v["sensor"] == "compass")
            .filter(|v| {
                v["distrust"]
                    .as_array()
                    .is_some_and(|d| d.iter().any(|r| r.as_str().unwrap().contains("mag_axes")))
            })
            .count()
    };
    assert!(mounting(&first) > 1000, "{}", mounting(&first));
    let second = run("x,z,-y");
    let readings: Vec<&Value> = second
        .iter()
        .filter(|v| v["class"] == "READING" && v["sensor"] == "compass")
        .filter(|v| v.get("heading_deg").is_some())
        .collect();
    assert!(readings.len() > 1000, "{}", readings.len());
    assert_eq!(mounting(&second), 0);
    assert!(
        readings.iter().all(|v| v["trusted"] == true),
        "a reading distrusted after the fix"
    );
}

/// A robot's level 2-axis compass (columns mx, my: body x and y, with an
/// offset and a scale each) and its accelerometer (ax, ay, az) at 20 Hz,
/// turning as [`heading`] (about the vertical: dip 65°, 500 counts), and
/// rolled `roll(t)` degrees about its x axis, which points north while it
/// is still. No gyro, no axis across the turn.
fn rolled_compass(roll: impl Fn(f64) -> f64) -> String {
    let mut text = String::from("t,mx,my,ax,ay,az\n");
    let mut noise = xorshift(0x2545_f491_4f6c_dd1d);
    let dip = 65f64.to_radians();
    let field = [500.0 * dip.cos(), 0.0, 500.0 * dip.sin()];
    for k in 0..(140.0 * 20.0) as usize {
        let t = k as f64 / 20.0;
        // Body to world (north, east, down): the heading, then the roll.
        let r = product(
            &rotation([0.0, 0.0, 1.0], heading(t).to_radians()),
            &rotation([1.0, 0.0, 0.0], roll(t).to_radians()),
        );
        let to_body = transpose(&r);
        let m = times(&to_body, field);
        let g = times(&to_body, [0.0, 0.0, -1.0]);
        let (mx, my) = (120.0 + 1.1 * m[0] + noise(), -80.0 + m[1] + noise());
        let (ax, ay, az) = (
            g[0] + 0.002 * noise(),
            g[1] + 0.002 * noise(),
            g[2] + 0.002 * noise(),
        );
        text.push_str(&format!("{t:.2},{mx:.3},{my:.3},{ax:.5},{ay:.5},{az:.5}\n"));
    }
    text
}

#[test]
fn a_level_compass_rolled_two_degrees_is_distrusted_by_its_accelerometer_alone() {
    let dir = tempfile::tempdir().unwrap();
    // Rolled 2° between 70 and 75 s, while still: the level pair takes
    // sin 2° of the vertical field, and the heading errs 4.3°; the field's
    // magnitude moves 0.28 %, within its own limit.
    let csv = rolled_compass(|t| if (70.0..75.0).contains(&t) { 2.0 } else { 0.0 });
    let sensors = "[[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"mx\", \"my\"]\n\
                   tilt = \"level\"\n\
                   [[sensor]]\nname = \"level\"\nsource = \"log\"\naxes = [\"ax\", \"ay\", \"az\"]\n\
                   field = \"accel\"\nlsb_per_g = 1\n";
    let lines = replay_with(dir.path(), "robot", &csv, sensors);
    let cal = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["sensor"] == "compass" && v["accepted"] == true)
        .unwrap_or_else(|| panic!("no calibration"));
    // The attitude over the rotation: level, its vertical the board's z.
    let level = &cal["level"];
    let up: Vec<f64> = (0..3).map(|k| level["up"][k].as_f64().unwrap()).collect();
    assert!(
        up[2] < -0.9999 && up[0].abs() < 0.01 && up[1].abs() < 0.01,
        "{level}"
    );
    assert!(level["tilt_sd_deg"].as_f64().unwrap() < 0.2, "{level}");
    let (all, bad, why) = compass_judged(&lines, 70.0, 75.0);
    assert_eq!((all, bad), (100, 100), "{why}");
    assert!(
        why.starts_with(
            "the compass is tilted 2.0° from the attitude it was calibrated in (limit 0.5°"
        ),
        "{why}"
    );
    // Turning before it and still after it, every heading is trusted.
    let (all, bad, why) = compass_judged(&lines, 0.0, 70.0);
    assert!(all > 900, "{all}");
    assert_eq!(bad, 0, "{why}");
    let (all, bad, why) = compass_judged(&lines, 75.0, 1e9);
    assert!(all > 1200, "{all}");
    assert_eq!(bad, 0, "{why}");
}

/// A board with a 3-axis magnetometer (mx, my, mz, mounted as in
/// [`board`]), an accelerometer (ax, ay, az) and a gyro (gx, gy, gz, deg/s,
/// the accelerometer's axes, with a bias on each) at 20 Hz: tumbling as
/// [`board`] for 150 s, then held still where the tumble left it. A magnet
/// turns the Earth's field `swing(t)` degrees about the vertical: the
/// field's size and dip stay, only the heading moves.
fn gyro_board(swing: impl Fn(f64) -> f64) -> String {
    let mut text = String::from("t,mx,my,mz,ax,ay,az,gx,gy,gz\n");
    let mut noise = xorshift(0x9e37_79b9_7f4a_7c15);
    let dip = 65f64.to_radians();
    let rates = [0.53, 0.31, 0.17];
    let bias = [1.5, -2.0, 0.8];
    for k in 0..(200.0 * 20.0) as usize {
        let t = k as f64 / 20.0;
        let tumbling = t < 150.0;
        let s = t.min(150.0);
        let (a, b, c) = (
            rotation([0.0, 0.0, 1.0], rates[0] * s),
            rotation([0.0, 1.0, 0.0], rates[1] * s),
            rotation([1.0, 0.0, 0.0], rates[2] * s),
        );
        let r = product(&product(&a, &b), &c);
        // The body's rate: each Euler rate carried into the body's axes.
        let (ct, bt) = (transpose(&c), transpose(&b));
        let yaw = times(&ct, times(&bt, [0.0, 0.0, rates[0]]));
        let pitch = times(&ct, [0.0, rates[1], 0.0]);
        let omega: Vec<f64> = (0..3)
            .map(|i| {
                if tumbling {
                    (yaw[i] + pitch[i] + [rates[2], 0.0, 0.0][i]).to_degrees()
                } else {
                    0.0
                }
            })
            .collect();
        let turn = rotation([0.0, 0.0, 1.0], swing(t).to_radians());
        let field = times(&turn, [500.0 * dip.cos(), 0.0, 500.0 * dip.sin()]);
        let to_body = transpose(&r);
        let m = times(&to_body, field);
        let g = times(&to_body, [0.0, 0.0, -1.0]);
        let ([mx, my, mz], [ax, ay, az]) = board_counts(m, g, [0.0; 3], &mut noise);
        let (gx, gy, gz) = (
            omega[0] + bias[0] + 0.05 * noise(),
            omega[1] + bias[1] + 0.05 * noise(),
            omega[2] + bias[2] + 0.05 * noise(),
        );
        text.push_str(&format!(
            "{t:.2},{mx:.3},{my:.3},{mz:.3},{ax:.5},{ay:.5},{az:.5},{gx:.4},{gy:.4},{gz:.4}\n"
        ));
    }
    text
}

#[test]
fn a_magnet_that_turns_a_3d_compass_heading_alone_is_caught_by_its_gyro() {
    let dir = tempfile::tempdir().unwrap();
    // 20° about the vertical between 170 and 175 s, while the board is
    // still: the field's size and dip are the same, the heading is not.
    let csv = gyro_board(|t| {
        if (170.0..175.0).contains(&t) {
            20.0
        } else {
            0.0
        }
    });
    let sensors = board_sensors("-x,-z,y").replacen(
        "mag_axes = \"-x,-z,y\"\n",
        "mag_axes = \"-x,-z,y\"\ngyro = [\"gx\", \"gy\", \"gz\"]\n",
        1,
    );
    let lines = replay_with(dir.path(), "board", &csv, &sensors);
    let cal = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["sensor"] == "compass" && v["accepted"] == true)
        .unwrap_or_else(|| panic!("no calibration"));
    // The gyro over the calibration's samples: ±1, and its bias found
    // (but for the forward axis's, which turns no heading).
    let gyro = &cal["gyro"];
    assert!(
        (gyro["scale"].as_f64().unwrap().abs() - 1.0).abs() < 0.02,
        "{gyro}"
    );
    for (k, want) in [0.0, -2.0, 0.8].into_iter().enumerate() {
        let got = gyro["bias_xyz_deg_s"][k].as_f64().unwrap();
        assert!((got - want).abs() < 0.1, "{gyro}");
    }
    let at = cal["time"].as_f64().unwrap();
    assert!(at < 150.0, "calibrated while tumbling: {at}");
    let (all, bad, why) = compass_judged(&lines, 170.0, 175.0);
    assert_eq!((all, bad), (100, 100), "{why}");
    // The field turned 20° east about the vertical: the heading, 20° less.
    let moved: f64 = why
        .strip_prefix("the heading moved ")
        .and_then(|r| r.split('°').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{why}"));
    assert!((moved + 20.0).abs() < 1.0, "{why}");
    let turned: f64 = why
        .split("while the gyro turned ")
        .nth(1)
        .and_then(|r| r.split('°').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{why}"));
    assert!(turned.abs() < 0.1, "{why}");
    // Tumbling after the calibration, and still before and after the
    // magnet, every heading is trusted.
    let (all, bad, why) = compass_judged(&lines, at, 170.0);
    assert!(all > 400, "{all}");
    assert_eq!(bad, 0, "{why}");
    let (all, bad, why) = compass_judged(&lines, 175.0, 1e9);
    assert!(all > 400, "{all}");
    assert_eq!(bad, 0, "{why}");
}

/// A calibration's attitude is kept with the accelerometer it was measured
/// with: after a restart under another tilt sensor (the configuration
/// changed), the stored attitude is not compared with the other's vertical.
#[test]
fn a_stored_attitude_is_not_compared_with_another_accelerometer() {
    let dir = tempfile::tempdir().unwrap();
    let csv = rolled_compass(|t| if (70.0..75.0).contains(&t) { 2.0 } else { 0.0 });
    std::fs::write(dir.path().join("robot.csv"), &csv).unwrap();
    let sensors = |tilt: &str, axes: &str| {
        format!(
            "[[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"mx\", \"my\"]\n\
             tilt = \"{tilt}\"\n[[sensor]]\nname = \"{tilt}\"\nsource = \"log\"\naxes = {axes}\n\
             field = \"accel\"\nlsb_per_g = 1\n"
        )
    };
    let first = write_config(
        dir.path(),
        "robot",
        &sensors("level", "[\"ax\", \"ay\", \"az\"]"),
    );
    // `run` stamps the readings on its own clock: the log's 70-75 s are
    // 70-75 s after its first reading.
    let start = |lines: &[Value]| {
        lines
            .iter()
            .find(|v| v["class"] == "READING")
            .and_then(|v| v["time"].as_f64())
            .unwrap()
    };
    let lines = lines_of(&["run", "--config", first.to_str().unwrap()]);
    let t0 = start(&lines);
    let (all, bad, why) = compass_judged(&lines, t0 + 69.99, t0 + 74.99);
    assert_eq!((all, bad), (100, 100), "{why}");
    // The same log again, the stored calibration loaded, its attitude
    // measured with 'level': under 'swapped' it is not compared.
    let second = write_config(
        dir.path(),
        "robot",
        &sensors("swapped", "[\"ay\", \"ax\", \"az\"]"),
    );
    let lines = lines_of(&["run", "--config", second.to_str().unwrap()]);
    let loaded = lines
        .iter()
        .find(|v| v["class"] == "CALIBRATION" && v["sensor"] == "compass")
        .unwrap();
    assert_eq!(loaded["origin"], "state", "{loaded}");
    assert_eq!(loaded["level"]["tilt"], "level: ax,ay,az", "{loaded}");
    let t0 = start(&lines);
    let (all, bad, why) = compass_judged(&lines, t0 + 69.99, t0 + 74.99);
    assert_eq!((all, bad), (100, 0), "{why}");
}
