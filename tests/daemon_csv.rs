//! CSV recordings through the daemon: a `kind = "csv"` source under `run`,
//! and `replay FILE.csv --config`; the replay speed, the sources' counters
//! and the one clock of each command.

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, unix_now, write_config};
use fieldcal::sim::SimSensor;
use serde_json::Value;

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

fn of_class<'a>(lines: &'a [Value], class: &str) -> Vec<&'a Value> {
    lines.iter().filter(|v| v["class"] == class).collect()
}

/// A simulated robot compass logged at 10 Hz, 200 samples a turn (20 s),
/// as `t,mag_x_lsb,mag_z_lsb,gyro_y,temp_c` (gyro_y in deg/s, `rad` in
/// rad/s instead), with the lines `bad` (1-based data rows) replaced by a
/// row that is not numbers. Returns the rows' (t, x, y).
fn robot_csv(path: &Path, turns: f64, rad: bool, bad: &[usize]) -> Vec<(f64, f64, f64)> {
    let sim = SimSensor {
        field: 450.0,
        gain_x: 1.08,
        gain_y: 0.95,
        offset_x: 120.0,
        offset_y: -60.0,
        noise: 1.5,
        period: 0.1,
        turns,
        turn_seconds: 20.0,
        seed: 7,
        ..SimSensor::default()
    };
    let data = sim.simulate().unwrap();
    let t = data.t.clone().unwrap();
    let rate = 360.0 / sim.turn_seconds;
    let rate = if rad { rate.to_radians() } else { rate };
    let mut text = String::from("t,mag_x_lsb,mag_z_lsb,gyro_y,temp_c\n");
    let mut rows = Vec::new();
    for (i, ((&t, &x), &y)) in t.iter().zip(&data.x).zip(&data.y).enumerate() {
        if bad.contains(&(i + 1)) {
            text.push_str(&format!("{t},oops,{y},{rate},21.5\n"));
            continue;
        }
        let temp = 21.0 + 0.001 * i as f64;
        text.push_str(&format!("{t},{x},{y},{rate},{temp}\n"));
        rows.push((t, x, y));
    }
    std::fs::write(path, text).unwrap();
    rows
}

/// A configuration of one csv source playing `csv` and one sensor on it.
fn csv_config(dir: &Path, csv: &Path, source_extra: &str, sensor_extra: &str) -> PathBuf {
    write_config(
        dir,
        &format!(
            r#"
[daemon]
state_dir = "{state}"
status_interval_s = 0.2

[outputs]
stdout = true

[[source]]
name = "log"
kind = "csv"
file = "{csv}"
{source_extra}

[[sensor]]
name = "robot"
source = "log"
axes = ["mag_x_lsb", "mag_z_lsb"]
{sensor_extra}
"#,
            state = dir.join("state").display(),
            csv = csv.display(),
        ),
    )
}

fn parse_lines(stdout: &str) -> Vec<Value> {
    stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .collect()
}

/// `fieldcal replay FILE --config CONFIG [args]`, which must succeed.
fn replay_config(file: &Path, config: &Path, args: &[&str]) -> (Vec<Value>, String) {
    let mut all = vec![
        "replay",
        file.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ];
    all.extend(args);
    let r = common::run(&all);
    assert_eq!(r.code, Some(0), "replay failed: {}", r.stderr);
    (parse_lines(&r.stdout), r.stderr)
}

/// Runs the daemon until its sources end (a played file ends it) and
/// returns every line it published, with the Unix times around the run.
fn run_to_end(config: &Path) -> (Vec<Value>, String, f64, f64) {
    let started = unix_now();
    let mut daemon = Daemon::start(config, &[]);
    let lines = daemon.drain(Duration::from_secs(60));
    assert!(daemon.wait(Duration::from_secs(10)).success());
    (lines, daemon.stderr(), started, unix_now())
}

#[test]
fn a_robot_turn_in_a_csv_is_calibrated_under_run_on_the_hosts_clock() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    let rows = robot_csv(&csv, 1.5, false, &[]);
    let config = csv_config(dir.path(), &csv, "speed = \"max\"", "gyro = \"gyro_y\"");
    let (lines, log, started, ended) = run_to_end(&config);

    let calibrations = of_class(&lines, "CALIBRATION");
    let accepted = calibrations
        .iter()
        .find(|c| c["accepted"] == true)
        .unwrap_or_else(|| panic!("no accepted CALIBRATION: {calibrations:?}\n{log}"));
    // The gyro column about the turn's axis checks the heading.
    let heading = &accepted["heading_vs_gyro"];
    assert_eq!(heading["gyro_column"], "gyro_y", "{accepted}");
    assert!(f(&heading["rms_deg"]) < 1.0, "{accepted}");
    assert!(
        (f(&heading["gyro_scale"]).abs() - 1.0).abs() < 0.05,
        "{accepted}"
    );

    // Every row became a READING, with the other columns beside it.
    let readings = of_class(&lines, "READING");
    assert_eq!(readings.len(), rows.len());
    let first = readings[0];
    assert_eq!(first["raw"][0], rows[0].1, "{first}");
    assert_eq!(first["raw"][1], rows[0].2, "{first}");
    assert_eq!(first["columns"]["gyro_y"], 18.0, "{first}");
    assert_eq!(first["columns"]["temp_c"], 21.0, "{first}");
    assert!(first["columns"].get("t").is_none(), "{first}");
    assert!(first["columns"].get("mag_x_lsb").is_none(), "{first}");

    // One clock: the host's. Readings keep the file's spacing from the
    // moment the source started.
    let span = rows.last().unwrap().0 - rows[0].0;
    for v in readings.iter().chain(&calibrations) {
        let t = f(&v["time"]);
        assert!(
            t >= started - 1.0 && t <= ended + span + 1.0,
            "{t} is not on the host's clock ({started}..{ended}): {v}"
        );
    }
    let spacing = f(&readings[1]["time"]) - f(&readings[0]["time"]);
    assert!(
        (spacing - (rows[1].0 - rows[0].0)).abs() < 1e-6,
        "{spacing}"
    );
    let statuses = of_class(&lines, "STATUS");
    let last = statuses.last().expect("a STATUS");
    let t = f(&last["time"]);
    assert!(t >= started && t <= ended + 1.0, "{last}");
    // The source's counters: every byte and row of the file.
    let source = &last["sources"][0];
    assert_eq!(source["source"], "log");
    assert_eq!(source["frames_good"], rows.len(), "{last}");
    assert_eq!(source["frames_bad"], 0, "{last}");
    assert_eq!(
        source["bytes_read"],
        std::fs::metadata(&csv).unwrap().len(),
        "{last}"
    );
}

#[test]
fn replay_of_a_csv_with_its_config_is_on_the_files_clock_and_skips_bad_rows() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    // Rad/s this time; rows 50, 51 and 250 are not numbers.
    let rows = robot_csv(&csv, 1.5, true, &[50, 51, 250]);
    let config = csv_config(
        dir.path(),
        &csv,
        "speed = \"max\"",
        "gyro = \"gyro_y\"\ngyro_units = \"rad/s\"",
    );
    let (lines, log) = replay_config(&csv, &config, &[]);
    let readings = of_class(&lines, "READING");
    assert_eq!(readings.len(), rows.len());
    // The file's own clock, to the digit.
    for (v, row) in readings.iter().zip(&rows) {
        assert_eq!(f(&v["time"]), row.0, "{v}");
    }
    let accepted: Vec<_> = of_class(&lines, "CALIBRATION")
        .into_iter()
        .filter(|c| c["accepted"] == true)
        .collect();
    assert!(!accepted.is_empty(), "no accepted calibration\n{log}");
    let heading = &accepted[0]["heading_vs_gyro"];
    assert!(
        (f(&heading["gyro_scale"]).abs() - 1.0).abs() < 0.05,
        "rad/s was not converted: {}",
        accepted[0]
    );
    // The bad rows are named (line = data row + 1 for the header), counted
    // and skipped; the replay goes on.
    assert!(
        log.contains("robot.csv: line 51: column 'mag_x_lsb' (field 2): 'oops' is not a number"),
        "{log}"
    );
    let statuses = of_class(&lines, "STATUS");
    let last = statuses.last().unwrap();
    assert_eq!(last["sources"][0]["frames_bad"], 3, "{last}");
    assert!(f(&last["time"]) <= rows.last().unwrap().0, "{last}");
    assert!(f(&last["sources"][0]["bytes_read"]) > 0.0, "{last}");
}

#[test]
fn a_csv_without_a_time_column_is_timed_by_its_period() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    robot_csv(&csv, 1.2, false, &[]);
    // Drop the time column.
    let text = std::fs::read_to_string(&csv).unwrap();
    let untimed: String = text
        .lines()
        .map(|l| l.split_once(',').unwrap().1.to_string() + "\n")
        .collect();
    let untimed_csv = dir.path().join("untimed.csv");
    std::fs::write(&untimed_csv, untimed).unwrap();
    let config = csv_config(dir.path(), &untimed_csv, "period_s = 0.1", "");
    let (lines, _) = replay_config(&untimed_csv, &config, &["--speed", "max"]);
    let readings = of_class(&lines, "READING");
    assert_eq!(f(&readings[0]["time"]), 0.0);
    assert_eq!(f(&readings[7]["time"]), 0.7);
    assert!(
        of_class(&lines, "CALIBRATION")
            .iter()
            .any(|c| c["accepted"] == true)
    );

    // The period where there is a time column, and none where there is
    // not, are refused at the key, naming the file, its line and column.
    let config = csv_config(dir.path(), &csv, "period_s = 0.1", "");
    let err = common::run_err(&[
        "replay",
        csv.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert!(err.contains("source[0].period_s"), "{err}");
    assert!(
        err.contains("robot.csv:1: the header has time column 't'"),
        "{err}"
    );
    assert!(err.contains("remove period_s"), "{err}");
    let config = csv_config(dir.path(), &untimed_csv, "", "");
    let err = common::run_err(&[
        "replay",
        untimed_csv.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert!(err.contains("untimed.csv:1: no time column"), "{err}");
    assert!(err.contains("give period_s"), "{err}");
}

#[test]
fn an_unknown_column_is_named_with_the_columns_the_file_has() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    robot_csv(&csv, 1.0, false, &[]);
    let config = write_config(
        dir.path(),
        &format!(
            "[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\n\n[[sensor]]\nname = \"r\"\n\
             source = \"log\"\naxes = [\"mag_x_lsb\", \"mag_y_lsb\"]\n",
            csv.display()
        ),
    );
    for command in ["run", "replay"] {
        let args: Vec<&str> = match command {
            "run" => vec!["run", "--config", config.to_str().unwrap()],
            _ => vec![
                "replay",
                csv.to_str().unwrap(),
                "--config",
                config.to_str().unwrap(),
            ],
        };
        let r = common::run(&args);
        assert_ne!(r.code, Some(0), "{command}: {}", r.stderr);
        assert!(r.stdout.is_empty(), "{command} published: {}", r.stdout);
        let err = r.stderr;
        // The configuration's key and line, the file, its line 1, the
        // column and the columns it has.
        assert!(err.contains("fieldcal.toml:9:"), "{err}");
        assert!(err.contains("sensor[0].axes[1]"), "{err}");
        assert!(
            err.contains(&format!(
                "{}:1: no column 'mag_y_lsb' in the header (columns: t, mag_x_lsb, mag_z_lsb, gyro_y, temp_c)",
                csv.display()
            )),
            "{err}"
        );
    }
}

#[test]
fn times_that_do_not_increase_stop_the_daemon_before_it_is_ready() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    std::fs::write(
        &csv,
        "t,a,b\n0.0,1,2\n0.1,2,3\n# a comment\n0.05,3,4\n0.2,4,5\n",
    )
    .unwrap();
    let config = write_config(
        dir.path(),
        &format!(
            "[daemon]\nstate_dir = \"{}\"\n[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\n\n\
             [[sensor]]\nname = \"r\"\nsource = \"log\"\naxes = [\"a\", \"b\"]\n",
            dir.path().join("state").display(),
            csv.display()
        ),
    );
    let want = "robot.csv:5: column 't': time 0.05 s is not after 0.1 s on line 3";
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert_ne!(r.code, Some(0), "{}", r.stderr);
    assert!(r.stderr.contains(want), "{}", r.stderr);
    assert!(r.stderr.contains("sort the file by 't'"), "{}", r.stderr);
    assert!(!r.stderr.contains("fieldcal is running"), "{}", r.stderr);
    let err = common::run_err(&[
        "replay",
        csv.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert!(err.contains(want), "{err}");
}

#[test]
fn a_csv_without_a_config_is_told_to_name_its_columns() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    robot_csv(&csv, 1.0, false, &[]);
    let err = common::run_err(&["replay", csv.to_str().unwrap()]);
    assert!(err.contains("is a CSV recording"), "{err}");
    assert!(err.contains("--config"), "{err}");
    assert!(err.contains("kind = \"csv\""), "{err}");
    assert!(!err.contains("neither a fieldcal capture"), "{err}");
    // Also without the .csv name: its first line gives it away.
    let renamed = dir.path().join("robot.log");
    std::fs::copy(&csv, &renamed).unwrap();
    let err = common::run_err(&["replay", renamed.to_str().unwrap()]);
    assert!(err.contains("is a CSV recording"), "{err}");
    // A replay source playing a CSV is refused before anything starts (it
    // used to log a warning and exit 0).
    let config = common::daemon::replay_config(dir.path(), &csv, "\"max\"", "stdout = true");
    let r = common::run(&["run", "--config", config.to_str().unwrap()]);
    assert_ne!(r.code, Some(0), "{}", r.stderr);
    assert!(r.stdout.is_empty(), "{}", r.stdout);
    assert!(r.stderr.contains("source[0].file"), "{}", r.stderr);
    assert!(
        r.stderr
            .contains("is a CSV recording, not a capture: give this source kind = \"csv\""),
        "{}",
        r.stderr
    );
}

/// A capture of `span_s` seconds of a simulated compass (Falcon frames).
fn short_capture(dir: &Path, span_s: f64) -> PathBuf {
    let capture = dir.join("short.fcap");
    common::run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--turns",
        &(span_s / 10.0).to_string(),
        "-o",
        capture.to_str().unwrap(),
    ]);
    capture
}

#[test]
fn replay_with_a_config_plays_at_the_sources_speed_unless_told() {
    let dir = tempfile::tempdir().unwrap();
    // A capture of 0.5 s at a configured speed of 0.25: 2 s at least.
    let capture = short_capture(dir.path(), 0.5);
    let config = common::daemon::replay_config(dir.path(), &capture, "0.25", "stdout = true");
    let started = Instant::now();
    let (lines, _) = replay_config(&capture, &config, &[]);
    let took = started.elapsed();
    assert!(!of_class(&lines, "READING").is_empty());
    assert!(took >= Duration::from_millis(1800), "took {took:?}");
    // --speed on the command line wins.
    let started = Instant::now();
    replay_config(&capture, &config, &["--speed", "max"]);
    assert!(started.elapsed() < took, "--speed max was not faster");

    // A csv source too: 0.5 s of rows at 0.25.
    let csv = dir.path().join("short.csv");
    let text: String = std::iter::once("t,a,b\n".to_string())
        .chain((0..=5).map(|i| format!("{},{},{}\n", f64::from(i) * 0.1, i, -i)))
        .collect();
    std::fs::write(&csv, text).unwrap();
    let config = write_config(
        dir.path(),
        &format!(
            "[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\nspeed = 0.25\n\
             [[sensor]]\nname = \"r\"\nsource = \"log\"\naxes = [\"a\", \"b\"]\n",
            csv.display()
        ),
    );
    let started = Instant::now();
    let (lines, _) = replay_config(&csv, &config, &[]);
    assert_eq!(of_class(&lines, "READING").len(), 6);
    assert!(
        started.elapsed() >= Duration::from_millis(1800),
        "took {:?}",
        started.elapsed()
    );
}

/// What `replay --json` counts in a capture: (bytes skipped, frames good).
fn replay_json_counts(capture: &Path) -> (u64, u64) {
    let out = common::run_ok(&[
        "replay",
        capture.to_str().unwrap(),
        "--speed",
        "max",
        "--json",
    ]);
    let summary: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    let falcon = &summary["summary"]["falcon"];
    (
        falcon["bytes_skipped"].as_u64().unwrap(),
        falcon["frames_good"].as_u64().unwrap(),
    )
}

#[test]
fn a_replay_sources_counters_are_real_and_its_readings_on_the_hosts_clock() {
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");
    let (skipped, good) = replay_json_counts(&capture);
    assert!(skipped > 0, "the capture has garbage");
    let dir = tempfile::tempdir().unwrap();

    // Under run, the final STATUS has the whole file's counts.
    let config = common::daemon::replay_config(dir.path(), &capture, "\"max\"", "stdout = true");
    let (lines, log, started, ended) = run_to_end(&config);
    let statuses = of_class(&lines, "STATUS");
    let last = statuses
        .last()
        .unwrap_or_else(|| panic!("no STATUS\n{log}"));
    let source = &last["sources"][0];
    assert_eq!(source["bytes_skipped"], skipped, "{last}");
    assert_eq!(source["frames_good"], good, "{last}");
    assert!(
        f(&source["bytes_read"]) >= (23 * good + skipped) as f64,
        "{last}"
    );
    // One clock: readings re-stamped onto the host's, 50 ms apart as captured.
    let readings = of_class(&lines, "READING");
    assert_eq!(readings.len() as u64, good);
    for v in &readings {
        let t = f(&v["time"]);
        assert!(t >= started - 1.0 && t <= ended + 21.0, "{v}");
    }
    let spacing = f(&readings[1]["time"]) - f(&readings[0]["time"]);
    assert!((spacing - 0.05).abs() < 1e-6, "{spacing}");

    // Under replay --config, on the capture's clock, with the counts so far.
    let (lines, _) = replay_config(
        &capture,
        &common::repo_path("tests/data/pipeline.toml"),
        &["--speed", "max"],
    );
    let readings = of_class(&lines, "READING");
    assert_eq!(f(&readings[0]["time"]), 0.0);
    let last = *of_class(&lines, "STATUS").last().unwrap();
    let source = &last["sources"][0];
    assert!(f(&source["bytes_skipped"]) > 0.0, "{last}");
    assert!(f(&source["bytes_read"]) > 0.0, "{last}");
    assert!(f(&last["time"]) < 100.0, "{last}");
}

/// The real HMC5883L recording (gauss, floats) of two hand turns about z,
/// through the daemon's pipeline: every row becomes a reading with its
/// float values, and the turns reach the fit.
#[test]
fn a_real_recording_in_gauss_goes_through_the_pipeline() {
    let csv = common::shared_path(
        "data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up/hmc5883l_mag.csv",
    );
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(
        dir.path(),
        &format!(
            "[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\nspeed = \"max\"\n\
             [[sensor]]\nname = \"compass\"\nsource = \"log\"\naxes = [\"mag_x\", \"mag_z\"]\n",
            csv.display()
        ),
    );
    let (lines, log) = replay_config(&csv, &config, &[]);
    let readings = of_class(&lines, "READING");
    let rows = std::fs::read_to_string(&csv).unwrap().lines().count() - 1;
    assert_eq!(readings.len(), rows);
    // The first row: 0.013626575,0.17889908,-0.39541284,-0.12110092
    assert_eq!(f(&readings[0]["time"]), 0.013626575);
    assert_eq!(readings[0]["raw"][0], 0.17889908);
    assert_eq!(readings[0]["raw"][1], -0.12110092);
    assert_eq!(readings[0]["columns"]["mag_y"], -0.39541284);
    // Each turn reaches a fit over (nearly) the whole circle.
    let calibrations = of_class(&lines, "CALIBRATION");
    assert!(!calibrations.is_empty(), "no fit\n{log}");
    for c in &calibrations {
        assert!(f(&c["coverage_deg"]) > 300.0, "{c}");
    }
}
