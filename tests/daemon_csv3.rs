//! A csv source in 3-D and on several files of one clock: the real
//! sunsided tilt-sphere recording (an HMC5883L magnetometer and an MPU-6050
//! accelerometer logged to two CSV files) through `fieldcal run --config`
//! gives a 3-D CALIBRATION of the compass and READINGs with the heading
//! tilt-compensated by the accelerometer's latest row; a stale
//! accelerometer leaves the heading out and says so; files that do not
//! share a clock, and the configuration's mistakes, are refused by name.

mod common;

use std::path::{Path, PathBuf};

use common::{repo_path, run};
use fieldcal::daemon::config::{ConfigError, Gyro3Choice, SourceKind, load, parse};
use serde_json::Value;

const SET: &str = "../shared/data/real/sunsided-set-1/tilt-sphere";

fn real(name: &str) -> PathBuf {
    repo_path(&format!("{SET}/{name}"))
}

/// A configuration of the two files (`mag`, `accel`) as one csv source
/// with a 3-axis compass tilted by a 3-axis accelerometer.
fn pair_config(dir: &Path, mag: &Path, accel: &Path) -> PathBuf {
    let path = dir.join("pair.toml");
    std::fs::write(
        &path,
        format!(
            r#"
[daemon]
state_dir = "{state}"
status_interval_s = 0.05

[outputs]
stdout = true

[[source]]
name = "board"
kind = "csv"
files = ["{mag}", "{accel}"]
speed = "max"

[[sensor]]
name = "compass"
source = "board"
axes = ["mag_x", "mag_y", "mag_z"]
field = "mag"
lsb_per_gauss = 1.0
tilt = "level"

[[sensor]]
name = "level"
source = "board"
axes = ["acc_x", "acc_y", "acc_z"]
field = "accel"
lsb_per_g = 1.0
"#,
            state = dir.join("state").display(),
            mag = mag.display(),
            accel = accel.display(),
        ),
    )
    .unwrap();
    path
}

fn run_daemon(config: &Path) -> (Vec<Value>, String) {
    let r = run(&["run", "--config", config.to_str().unwrap()]);
    assert_eq!(r.code, Some(0), "run failed: {}", r.stderr);
    assert!(!r.stderr.contains("panicked"), "{}", r.stderr);
    let lines = r
        .stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    (lines, r.stderr)
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

fn rows(path: &Path) -> usize {
    std::fs::read_to_string(path).unwrap().lines().count() - 1
}

fn last_status(lines: &[Value]) -> &Value {
    lines.iter().rev().find(|v| v["class"] == "STATUS").unwrap()
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
fn the_real_tilt_sphere_pair_calibrates_the_compass_in_3d_with_tilt_compensated_headings() {
    let dir = tempfile::tempdir().unwrap();
    let (mag, accel) = (real("hmc5883l_mag.csv"), real("mpu6050.csv"));
    let (lines, _) = run_daemon(&pair_config(dir.path(), &mag, &accel));

    // Every row of both files played, merged in time order (the re-stamped
    // times of the READINGs of both sensors never go back).
    let compass = of(&lines, "READING", "compass");
    let level = of(&lines, "READING", "level");
    assert_eq!(compass.len(), rows(&mag));
    assert_eq!(level.len(), rows(&accel));
    let times: Vec<f64> = lines
        .iter()
        .filter(|v| v["class"] == "READING")
        .map(|v| f(&v["time"]))
        .collect();
    assert!(times.windows(2).all(|w| w[1] >= w[0]), "not in time order");
    let status = last_status(&lines);
    let source = &status["sources"][0];
    assert_eq!(
        source["frames_good"].as_u64(),
        Some((rows(&mag) + rows(&accel)) as u64),
        "{source}"
    );
    assert_eq!(source["frames_bad"].as_u64(), Some(0));

    // The compass: one accepted 3-D fit. `fieldcal fit FILE --z mag_z` on
    // the whole file gives rms 0.83 %; the daemon fits at most
    // max_samples = 3000 of the 4322 readings, thinned where they crowd, so
    // its rms differs a little: within 0.25 points of the file's (and far
    // inside ArduPilot's 16 mG, 3 % of this 0.53 G field). The radius is
    // the local field, 0.45-0.6 G.
    let fits = of(&lines, "CALIBRATION", "compass");
    let accepted: Vec<_> = fits.iter().filter(|c| c["accepted"] == true).collect();
    assert_eq!(accepted.len(), 1, "{fits:?}");
    let cal = accepted[0];
    assert_eq!(cal["axes"], 3);
    assert_eq!(cal["units"], "gauss");
    let rms = f(&cal["rms"]);
    assert!((rms - 0.0083).abs() < 0.0025, "rms {rms}");
    let r = f(&cal["r_units"]);
    assert!((0.45..0.6).contains(&r), "r {r}");
    assert!(cal["n"].as_u64().unwrap() <= 3000);

    // The accelerometer: a hand-turned board also accelerates, so its fit
    // is refused on ArduPilot's rms limit, with its radius near 1 g
    // (gravity, in the file's g).
    let level_fits = of(&lines, "CALIBRATION", "level");
    assert!(!level_fits.is_empty());
    for c in &level_fits {
        assert_eq!(c["units"], "g");
        let r = f(&c["r_units"]);
        assert!((0.95..1.1).contains(&r), "accelerometer r {r} g");
        if c["accepted"] == false {
            assert!(c["reason"].as_str().unwrap().contains("rms"), "{c}");
        }
    }

    // Once calibrated, the compass's READINGs carry the heading,
    // tilt-compensated with the accelerometer's row of the other file.
    let calibrated: Vec<_> = compass.iter().filter(|v| v["calibrated"] == true).collect();
    assert!(calibrated.len() > 1000, "{}", calibrated.len());
    let with_heading: Vec<_> = calibrated
        .iter()
        .filter(|v| v.get("heading_deg").is_some())
        .collect();
    assert!(
        with_heading.len() * 100 >= calibrated.len() * 95,
        "{} of {}",
        with_heading.len(),
        calibrated.len()
    );
    for v in &with_heading {
        let h = f(&v["heading_deg"]);
        assert!((0.0..360.0).contains(&h), "{v}");
        assert_eq!(v["tilt"]["sensor"], "level");
        assert!(f(&v["tilt"]["tilt_deg"]).is_finite());
    }
    // A calibrated READING without a heading says why: on a tumble, the
    // board stood on its end (forward axis vertical) or the field near
    // the vertical.
    for v in calibrated.iter().filter(|v| v.get("heading_deg").is_none()) {
        let why = v["heading_omitted"]
            .as_str()
            .unwrap_or_else(|| panic!("no reason: {v}"));
        assert!(why.contains("vertical"), "{why}");
    }
    // The heading turns with the board: the recording covers the sphere.
    let spread = with_heading
        .iter()
        .map(|v| f(&v["heading_deg"]))
        .fold((f64::MAX, f64::MIN), |(lo, hi), h| (lo.min(h), hi.max(h)));
    assert!(spread.1 - spread.0 > 180.0, "{spread:?}");
    // Both files' rows come close together: no heading was stale.
    assert_eq!(sensor_status(status, "compass")["headings_stale"], 0);
    assert!(
        sensor_status(status, "level")
            .get("headings_stale")
            .is_none()
    );
}

#[test]
fn a_stale_accelerometer_leaves_the_heading_out_and_says_why() {
    // The accelerometer's file cut at 20 s of the 56 s: the compass
    // calibrates later, when no accelerometer row is recent.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(real("mpu6050.csv")).unwrap();
    let cut: Vec<&str> = text
        .lines()
        .take_while(|l| {
            l.starts_with('t') || l.split(',').next().unwrap().parse::<f64>().unwrap() < 20.0
        })
        .collect();
    let accel = dir.path().join("mpu6050-20s.csv");
    std::fs::write(&accel, cut.join("\n") + "\n").unwrap();
    let config = pair_config(dir.path(), &real("hmc5883l_mag.csv"), &accel);
    let (lines, stderr) = run_daemon(&config);
    // Less than half the time shared: said before the play.
    assert!(stderr.contains("share only"), "{stderr}");

    let calibrated: Vec<_> = of(&lines, "READING", "compass")
        .into_iter()
        .filter(|v| v["calibrated"] == true)
        .collect();
    assert!(!calibrated.is_empty());
    let omitted: Vec<_> = calibrated
        .iter()
        .filter(|v| v.get("heading_omitted").is_some())
        .collect();
    for v in &calibrated {
        assert!(v.get("heading_deg").is_none(), "a stale heading: {v}");
    }
    assert_eq!(omitted.len(), calibrated.len());
    let why = omitted[0]["heading_omitted"].as_str().unwrap();
    assert!(
        why.contains("'level'") && why.contains("s old") && why.contains("0.1 s"),
        "{why}"
    );
    let status = last_status(&lines);
    assert_eq!(
        sensor_status(status, "compass")["headings_stale"].as_u64(),
        Some(omitted.len() as u64)
    );
}

#[test]
fn files_whose_clocks_do_not_overlap_are_refused_before_ready() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(real("mpu6050.csv")).unwrap();
    let mut shifted = String::new();
    for (i, line) in text.lines().enumerate() {
        if i == 0 {
            shifted.push_str(line);
        } else {
            let (t, rest) = line.split_once(',').unwrap();
            shifted.push_str(&format!("{},{rest}", t.parse::<f64>().unwrap() + 100.0));
        }
        shifted.push('\n');
    }
    let accel = dir.path().join("later.csv");
    std::fs::write(&accel, shifted).unwrap();
    let config = pair_config(dir.path(), &real("hmc5883l_mag.csv"), &accel);
    let r = run(&["run", "--config", config.to_str().unwrap()]);
    assert_ne!(r.code, Some(0));
    assert!(!r.stdout.contains("READING"), "{}", r.stdout);
    for word in [
        "hmc5883l_mag.csv",
        "later.csv",
        "do not overlap",
        "one clock",
    ] {
        assert!(r.stderr.contains(word), "no '{word}' in: {}", r.stderr);
    }
}

#[test]
fn the_shipped_example_names_the_real_pair() {
    let config = load(&repo_path("config/sunsided-tilt-sphere.toml")).unwrap();
    let SourceKind::Csv(fieldcal::daemon::source_kinds::Csv { files, .. }) =
        &config.sources[0].kind
    else {
        panic!("{:?}", config.sources[0].kind);
    };
    assert_eq!(files.len(), 2);
    for (file, name) in files.iter().zip(["hmc5883l_mag.csv", "mpu6050.csv"]) {
        assert_eq!(
            std::fs::canonicalize(file).unwrap(),
            std::fs::canonicalize(real(name)).unwrap()
        );
    }
    let three = config.sensors[0].sphere().unwrap();
    assert_eq!(three.tilt.as_ref().unwrap().sensor, "level");
    // Its heading is checked against the MPU-6050's gyro.
    assert_eq!(
        three.gyro,
        Gyro3Choice::Columns {
            names: ["gyro_x", "gyro_y", "gyro_z"].map(String::from),
            units: fieldcal::model::gyro::GyroUnits::DegPerSecond,
        }
    );
}

#[test]
fn a_3_axis_compass_names_its_gyros_three_columns_and_nothing_else_takes_them() {
    let mag3 = "axes = [\"mag_x\", \"mag_y\", \"mag_z\"]\nfield = \"mag\"\n";
    let level = "[[sensor]]\nname = \"level\"\nsource = \"board\"\n\
                 axes = [\"acc_x\", \"acc_y\", \"acc_z\"]\nfield = \"accel\"\n";
    let text = |extra: &str| with("", &format!("{COMPASS}{mag3}{extra}\n{level}"));
    let gyro = "tilt = \"level\"\ngyro = [\"gyro_x\", \"gyro_y\", \"gyro_z\"]\n";
    let config = parse(
        &text(&format!("{gyro}gyro_units = \"rad/s\"\n")),
        &config_path(),
    )
    .unwrap();
    assert_eq!(
        config.sensors[0].sphere().unwrap().gyro,
        Gyro3Choice::Columns {
            names: ["gyro_x", "gyro_y", "gyro_z"].map(String::from),
            units: fieldcal::model::gyro::GyroUnits::RadPerSecond,
        }
    );
    // None named: none.
    let config = parse(&text("tilt = \"level\"\n"), &config_path()).unwrap();
    assert_eq!(config.sensors[0].sphere().unwrap().gyro, Gyro3Choice::Off);
    for (extra, key, words) in [
        // One column is a 2-axis sensor's.
        (
            "tilt = \"level\"\ngyro = \"gyro_z\"\n",
            "sensor[0].gyro",
            &["three columns", "\"none\""][..],
        ),
        (
            "tilt = \"level\"\ngyro = [\"gyro_x\", \"gyro_y\"]\n",
            "sensor[0].gyro",
            &["2 columns given"][..],
        ),
        (
            "tilt = \"level\"\ngyro = [\"gyro_x\", \"gyro_y\", \"gyro_x\"]\n",
            "sensor[0].gyro[2]",
            &["already gyro[0]"][..],
        ),
        (
            "tilt = \"level\"\ngyro = [\"gyro_x\", \"gyro_y\", \"nope\"]\n",
            "sensor[0].gyro[2]",
            &["nope"][..],
        ),
        // Without the tilt, no vertical to turn about.
        (
            "gyro = [\"gyro_x\", \"gyro_y\", \"gyro_z\"]\n",
            "sensor[0].gyro",
            &["give `tilt`"][..],
        ),
        (
            "tilt = \"level\"\ngyro_units = \"rad/s\"\n",
            "sensor[0].gyro_units",
            &["without gyro columns"][..],
        ),
        (
            &format!("{gyro}gyro_units = \"rpm\"\n"),
            "sensor[0].gyro_units",
            &["\"rpm\""][..],
        ),
        // Neither a name nor names.
        (
            "tilt = \"level\"\ngyro = 5\n",
            "sensor[0].gyro",
            &["expected a gyro axis or column", "three gyro columns"][..],
        ),
    ] {
        refused(&text(extra), key, words);
    }
    // An accelerometer has no heading to check.
    refused(
        &with(
            "",
            &format!(
                "{COMPASS}axes = [\"acc_x\", \"acc_y\", \"acc_z\"]\nfield = \"accel\"\n{gyro}"
            ),
        ),
        "sensor[0].gyro",
        &["accel sensor has none"],
    );
    // Three columns on a 2-axis sensor.
    refused(
        &with(
            "",
            &format!(
                "{COMPASS}axes = [\"mag_x\", \"mag_y\"]\ngyro = [\"gyro_x\", \"gyro_y\", \"gyro_z\"]\n"
            ),
        ),
        "sensor[0].gyro",
        &["2-axis sensor's gyro is one column"],
    );
}

// ---- the configuration's refusals ----

fn two_files() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let mag = dir.path().join("mag.csv");
    let accel = dir.path().join("imu.csv");
    std::fs::write(&mag, "t_s,mag_x,mag_y,mag_z,temp_c\n0,1,2,3,20\n").unwrap();
    std::fs::write(
        &accel,
        "t_s,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z,temp_c\n0,1,2,3,4,5,6,20\n",
    )
    .unwrap();
    (dir, mag, accel)
}

fn config_path() -> PathBuf {
    repo_path("config/test.toml")
}

fn with(source: &str, sensors: &str) -> String {
    let (_, mag, accel) = FILES.with(|f| f.clone());
    format!(
        "[[source]]\nname = \"board\"\nkind = \"csv\"\nfiles = [\"{}\", \"{}\"]\n{source}\n\n{sensors}",
        mag.display(),
        accel.display()
    )
}

thread_local! {
    static FILES: (std::rc::Rc<tempfile::TempDir>, PathBuf, PathBuf) = {
        let (dir, mag, accel) = two_files();
        (std::rc::Rc::new(dir), mag, accel)
    };
}

const COMPASS: &str = "[[sensor]]\nname = \"compass\"\nsource = \"board\"\n";

#[track_caller]
fn refused(text: &str, key: &str, words: &[&str]) {
    let err: ConfigError = match parse(text, &config_path()) {
        Ok(c) => panic!("accepted: {c:?}"),
        Err(e) => e,
    };
    let message = err.to_string();
    assert_eq!(err.key(), Some(key), "{message}");
    for w in words {
        assert!(message.contains(w), "no '{w}' in: {message}");
    }
}

#[test]
fn a_3_axis_csv_sensor_and_a_source_of_several_files_are_checked_naming_the_key() {
    let mag3 = "axes = [\"mag_x\", \"mag_y\", \"mag_z\"]\n";
    // Accepted: both sensors, each from its own file, the tilt linked.
    let ok = with(
        "",
        &format!(
            "{COMPASS}{mag3}field = \"mag\"\ntilt = \"level\"\n\n[[sensor]]\nname = \"level\"\n\
             source = \"board\"\naxes = [\"acc_x\", \"acc_y\", \"acc_z\"]\nfield = \"accel\"\n"
        ),
    );
    let config = parse(&ok, &config_path()).unwrap();
    let three = config.sensors[0].sphere().unwrap();
    assert_eq!(
        three.columns,
        Some(["mag_x".to_string(), "mag_y".into(), "mag_z".into()])
    );
    assert_eq!(
        three.tilt.as_ref().unwrap().columns,
        Some(["acc_x".to_string(), "acc_y".into(), "acc_z".into()])
    );

    // Three columns carry no field.
    refused(
        &with("", &format!("{COMPASS}{mag3}")),
        "sensor[0].field",
        &["columns carry no field", "\"mag\"", "\"accel\""],
    );
    refused(
        &with("", &format!("{COMPASS}{mag3}field = \"gyro\"\n")),
        "sensor[0].field",
        &["gyro"],
    );
    // A column twice.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\", \"mag_x\"]\nfield = \"mag\"\n"),
        ),
        "sensor[0].axes[2]",
        &["'mag_x' is already axes[0]"],
    );
    // A column of no file: every file's columns listed.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\", \"mag_w\"]\nfield = \"mag\"\n"),
        ),
        "sensor[0].axes[2]",
        &[
            "no column 'mag_w'",
            "t_s, mag_x, mag_y, mag_z, temp_c in",
            "mag.csv",
            "acc_x",
            "imu.csv",
        ],
    );
    // A column in both files is ambiguous.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\", \"temp_c\"]\nfield = \"mag\"\n"),
        ),
        "sensor[0].axes[2]",
        &["'temp_c' is a column of both", "mag.csv", "imu.csv"],
    );
    // Columns of two files.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\", \"acc_z\"]\nfield = \"mag\"\n"),
        ),
        "sensor[0].axes[2]",
        &[
            "'acc_z' is a column of",
            "imu.csv",
            "'mag_x' is of",
            "mag.csv",
            "one file",
        ],
    );
    // The time column.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\", \"t_s\"]\nfield = \"mag\"\n"),
        ),
        "sensor[0].axes[2]",
        &["time column"],
    );
    // A 2-axis sensor's keys on a 3-axis one.
    for (line, key) in [
        ("gyro = \"gyro_z\"", "gyro"),
        ("gyro_units = \"rad/s\"", "gyro_units"),
        ("chip = \"x\"", "chip"),
        ("[sensor.rotation]\nmax_gap_deg = 20", "rotation"),
    ] {
        refused(
            &with("", &format!("{COMPASS}{mag3}field = \"mag\"\n{line}\n")),
            &format!("sensor[0].{key}"),
            &[key],
        );
    }
    // 3-axis keys on a 2-axis csv sensor.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\"]\nlsb_per_gauss = 1090\n"),
        ),
        "sensor[0].lsb_per_gauss",
        &["three columns in axes, with field"],
    );
    // The tilt source must be a 3-axis accelerometer of the source.
    refused(
        &with(
            "",
            &format!(
                "{COMPASS}{mag3}field = \"mag\"\ntilt = \"flat\"\n\n[[sensor]]\nname = \"flat\"\n\
                 source = \"board\"\naxes = [\"acc_x\", \"acc_y\"]\n"
            ),
        ),
        "sensor[0].tilt",
        &["2-axis sensor"],
    );
    // And a 2-axis compass's too (its tilt is checked, not compensated).
    refused(
        &with(
            "",
            &format!(
                "{COMPASS}axes = [\"mag_x\", \"mag_y\"]\ntilt = \"flat\"\n\n[[sensor]]\nname = \"flat\"\n\
                 source = \"board\"\naxes = [\"acc_x\", \"acc_y\"]\n"
            ),
        ),
        "sensor[0].tilt",
        &["2-axis sensor", "3-axis accelerometer"],
    );
    // The source: file and files, period_s, the count, a file twice.
    let sensor = format!("{COMPASS}{mag3}field = \"mag\"\n");
    let (_, mag, _) = FILES.with(|f| f.clone());
    refused(
        &with(&format!("file = \"{}\"", mag.display()), &sensor),
        "source[0].files",
        &["both `file` and `files`"],
    );
    refused(
        &with("period_s = 0.01", &sensor),
        "source[0].period_s",
        &["single file"],
    );
    let many = vec![format!("\"{}\"", mag.display()); 17].join(", ");
    refused(
        &format!("[[source]]\nname = \"board\"\nkind = \"csv\"\nfiles = [{many}]\n\n{sensor}"),
        "source[0].files",
        &["17 files", "1 to 16"],
    );
    refused(
        &format!(
            "[[source]]\nname = \"board\"\nkind = \"csv\"\nfiles = [\"{0}\", \"{0}\"]\n\n{sensor}",
            mag.display()
        ),
        "source[0].files[1]",
        &["already files[0]"],
    );
    refused(
        &format!(
            "[[source]]\nname = \"board\"\nkind = \"csv\"\nfiles = [\"{}\", \"nowhere.csv\"]\n\n{sensor}",
            mag.display()
        ),
        "source[0].files[1]",
        &["nowhere.csv"],
    );
}

#[test]
fn mag_axes_maps_a_tilted_compass_onto_its_accelerometer_and_is_refused_where_it_means_nothing() {
    let mag3 = "axes = [\"mag_x\", \"mag_y\", \"mag_z\"]\nfield = \"mag\"\n";
    let level = "[[sensor]]\nname = \"level\"\nsource = \"board\"\n\
                 axes = [\"acc_x\", \"acc_y\", \"acc_z\"]\nfield = \"accel\"\n";
    let text = |extra: &str| with("", &format!("{COMPASS}{mag3}{extra}\n{level}"));
    let config = parse(
        &text("tilt = \"level\"\nmag_axes = \" -x, -z,y \"\n"),
        &config_path(),
    )
    .unwrap();
    let three = config.sensors[0].sphere().unwrap();
    assert_eq!(three.mag_axes.to_string(), "-x,-z,y");
    assert_eq!(three.mag_axes.apply([1.0, 2.0, 3.0]), [-1.0, -3.0, 2.0]);
    // The default is the identity.
    let config = parse(&text("tilt = \"level\"\n"), &config_path()).unwrap();
    assert_eq!(
        config.sensors[0].sphere().unwrap().mag_axes.to_string(),
        "x,y,z"
    );
    // Not a mapping: an axis twice, two axes, a word.
    for bad in ["x,x,z", "x,y", "north"] {
        refused(
            &text(&format!("tilt = \"level\"\nmag_axes = \"{bad}\"\n")),
            "sensor[0].mag_axes",
            &[
                &format!("\"{bad}\" is not an axis mapping"),
                "x,-z,y",
                "--mag-axes auto",
            ],
        );
    }
    // Without tilt it maps onto nothing.
    refused(
        &text("mag_axes = \"x,z,-y\"\n"),
        "sensor[0].mag_axes",
        &["give `tilt`"],
    );
    // A csv plane's out_of_plane: a column of its axes' file, not an axis.
    let plane = |extra: &str| {
        with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\"]\n{extra}"),
        )
    };
    let config = parse(&plane("out_of_plane = \"mag_z\"\n"), &config_path()).unwrap();
    assert_eq!(
        config.sensors[0].plane().unwrap().out_of_plane,
        Some(fieldcal::daemon::config::OutOfPlane::Column("mag_z".into()))
    );
    refused(
        &plane("out_of_plane = \"mag_y\"\n"),
        "sensor[0].out_of_plane",
        &["'mag_y' is one of the axes that turn"],
    );
    refused(
        &plane("out_of_plane = \"mag_w\"\n"),
        "sensor[0].out_of_plane",
        &["no column 'mag_w'"],
    );
    refused(
        &plane("out_of_plane = \"acc_z\"\n"),
        "sensor[0].out_of_plane",
        &["imu.csv"],
    );
    // A 2-axis sensor has no tilt accelerometer.
    refused(
        &with(
            "",
            &format!("{COMPASS}axes = [\"mag_x\", \"mag_y\"]\nmag_axes = \"x,z,-y\"\n"),
        ),
        "sensor[0].mag_axes",
        &["has no `mag_axes`", "a 3-axis sensor names three columns"],
    );
}

/// An accelerometer in g, rested on its six faces for 2 s each and turned
/// between them at 90 °/s, at 100 Hz, with 3 mg of noise: `t_s, acc_x,
/// acc_y, acc_z` of W⁻¹u + o. Returns the file's text, o and W's diagonal.
fn six_faces_csv() -> (String, [f64; 3], [f64; 3]) {
    use nalgebra::{Rotation3, Unit, Vector3};
    let gain = [1.03, 0.97, 1.01];
    let offset = [0.015, -0.011, 0.022];
    // A fixed Gaussian sequence (Box-Muller on a 64-bit LCG).
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut gauss = move || {
        let (a, b) = (uniform(), uniform());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    };
    let faces = [
        Vector3::z(),
        Vector3::x(),
        -Vector3::z(),
        Vector3::y(),
        -Vector3::x(),
        -Vector3::y(),
    ];
    let mut text = String::from("t_s,acc_x,acc_y,acc_z\n");
    let mut n = 0;
    let mut row = |u: Vector3<f64>, text: &mut String| {
        let v = [0, 1, 2].map(|k| u[k] / gain[k] + offset[k] + 0.003 * gauss());
        text.push_str(&format!(
            "{:.3},{:.6},{:.6},{:.6}\n",
            n as f64 * 0.01,
            v[0],
            v[1],
            v[2]
        ));
        n += 1;
    };
    for (k, &u) in faces.iter().enumerate() {
        for _ in 0..200 {
            row(u, &mut text);
        }
        if let Some(&next) = faces.get(k + 1) {
            let angle = u.angle(&next);
            let axis = if u.cross(&next).norm() > 1e-9 {
                u.cross(&next)
            } else {
                Vector3::x()
            };
            let steps = (angle.to_degrees() / 90.0 * 100.0).ceil() as usize;
            for i in 1..steps {
                let r = Rotation3::from_axis_angle(
                    &Unit::new_normalize(axis),
                    angle * i as f64 / steps as f64,
                );
                row(r * u, &mut text);
            }
        }
    }
    // Picked up at the end: the last pose ends.
    for i in 1..50 {
        let r = Rotation3::from_axis_angle(&Vector3::x_axis(), (i as f64).to_radians() * 0.9);
        row(r * -Vector3::y(), &mut text);
    }
    (text, offset, gain)
}

/// `[sensor.sphere] still = true`: an accelerometer rested on its six
/// faces is calibrated from the poses (ArduPilot's six positions), through
/// the daemon on a csv file; the hand-held real tumble, never at rest, is
/// not, and STATUS says why.
#[test]
fn an_accelerometer_on_its_six_faces_is_calibrated_from_its_still_poses() {
    let dir = tempfile::tempdir().unwrap();
    let (text, offset, gain) = six_faces_csv();
    let file = dir.path().join("six.csv");
    std::fs::write(&file, text).unwrap();
    let config = dir.path().join("six.toml");
    std::fs::write(
        &config,
        format!(
            "[daemon]\nstate_dir = \"{}\"\nstatus_interval_s = 0.05\n[outputs]\nstdout = true\n\
             [[source]]\nname = \"board\"\nkind = \"csv\"\nfiles = [\"{}\"]\nspeed = \"max\"\n\
             [[sensor]]\nname = \"level\"\nsource = \"board\"\naxes = [\"acc_x\", \"acc_y\", \"acc_z\"]\n\
             field = \"accel\"\nlsb_per_g = 1.0\nmodel = \"offset+scale\"\n[sensor.sphere]\nstill = true\n",
            dir.path().join("state").display(),
            file.display()
        ),
    )
    .unwrap();
    let (lines, log) = run_daemon(&config);
    let cals = of(&lines, "CALIBRATION", "level");
    assert_eq!(cals.len(), 1, "{cals:?}\n{log}");
    let c = cals[0];
    assert_eq!(c["accepted"], true, "{c}");
    assert_eq!(c["model"], "offset+scale");
    let r = f(&c["r"]);
    for k in 0..3 {
        // 3 mg of noise over six poses of ~200 samples.
        let o = f(&c["offset"][k]);
        assert!(
            (o - offset[k]).abs() < 1e-3,
            "offset {k}: {o} vs {}",
            offset[k]
        );
        // det W = 1: the gain is W's diagonal over r (r in g).
        let g = f(&c["matrix"][k][k]) / r;
        assert!((g - gain[k]).abs() < 2e-3, "gain {k}: {g} vs {}", gain[k]);
    }
    assert!(f(&c["rms"]) < 0.01, "{c}");
    // The noise alone remains: 3 mg over three axes of 1 g.
    assert!(f(&c["rms"]) > 0.002, "{c}");
    assert_eq!(c["poses"], 6, "{c}");
    assert!(log.contains("level: 6 poses held still"), "{log}");

    // The real hand-held tumble: the hand never rests 0.5 s. (A state
    // directory of its own: the first one holds the six faces' fit.)
    let dir = tempfile::tempdir().unwrap();
    let config = pair_config(dir.path(), &real("hmc5883l_mag.csv"), &real("mpu6050.csv"));
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(
        &config,
        format!("{text}model = \"offset+scale\"\n[sensor.sphere]\nstill = true\n"),
    )
    .unwrap();
    let (lines, _) = run_daemon(&config);
    assert!(of(&lines, "CALIBRATION", "level").is_empty());
    let still = &sensor_status(last_status(&lines), "level")["sphere"]["still"];
    assert_eq!(still["never_still"], true, "{still}");
    assert!(f(&still["poses"]) < 6.0, "{still}");
    // The compass beside it calibrates as before.
    assert!(
        of(&lines, "CALIBRATION", "compass")
            .iter()
            .any(|c| c["accepted"] == true)
    );
}

/// The real tumble with the MPU-6050's gyro: the gyro's scale against the
/// tilt-compensated heading is ±1 within the chip's tolerance, and every
/// calibrated heading but the one a jolt of the hand threw 100° off (the
/// accelerometer read a 40° tilt for one row) is trusted.
#[test]
fn the_real_tumble_fits_its_gyro_against_the_heading_and_distrusts_only_a_jolt() {
    let dir = tempfile::tempdir().unwrap();
    let config = pair_config(dir.path(), &real("hmc5883l_mag.csv"), &real("mpu6050.csv"));
    let text = std::fs::read_to_string(&config).unwrap().replacen(
        "tilt = \"level\"\n",
        "tilt = \"level\"\nmag_axes = \"-x,-z,y\"\ngyro = [\"gyro_x\", \"gyro_y\", \"gyro_z\"]\n",
        1,
    );
    std::fs::write(&config, text).unwrap();
    let (lines, _) = run_daemon(&config);
    let fits = of(&lines, "CALIBRATION", "compass");
    let cal = fits
        .iter()
        .find(|c| c["accepted"] == true)
        .unwrap_or_else(|| panic!("{fits:?}"));
    let gyro = &cal["gyro"];
    let scale = f(&gyro["scale"]);
    assert!((scale.abs() - 1.0).abs() < 0.05, "{gyro}");
    // A hand's tumble: the heading errs by degrees (its accelerometer
    // feels the hand's accelerations), and the limit widens with it.
    let noise = f(&gyro["heading_rms_deg"]);
    assert!((1.0..30.0).contains(&noise), "{gyro}");
    let headings: Vec<&Value> = of(&lines, "READING", "compass")
        .into_iter()
        .filter(|v| v["calibrated"] == true && v.get("heading_deg").is_some())
        .collect();
    let distrusted = headings.iter().filter(|v| v["trusted"] == false).count();
    assert!(headings.len() > 1000, "{}", headings.len());
    assert!(
        distrusted * 100 <= headings.len(),
        "{distrusted} of {}",
        headings.len()
    );
}
