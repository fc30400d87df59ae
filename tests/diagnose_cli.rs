//! `fieldcal diagnose` as a user runs it.

mod common;

use common::{repo_path, run, run_err, run_ok};
use serde_json::Value;

fn sim_mild() -> String {
    repo_path("tests/data/sim_mild.csv")
        .to_str()
        .unwrap()
        .to_string()
}

#[test]
fn json_on_a_clean_recording_suggests_nothing() {
    let out = run_ok(&["diagnose", &sim_mild(), "--json"]);
    let v: Value = serde_json::from_str(&out).unwrap();
    for key in [
        "baseline",
        "candidates",
        "suggested",
        "close_second",
        "ladder",
        "noise_floor",
        "noise_floor_method",
        "verdict",
        "criterion",
    ] {
        assert!(v.get(key).is_some(), "missing {key}: {out}");
    }
    assert_eq!(
        v["baseline"]["effects"],
        serde_json::json!(["offset", "scale"])
    );
    assert!(v["baseline"]["rms"].as_f64().unwrap() > 0.0);
    assert!(v["suggested"].is_null(), "{out}");
    assert!(v["close_second"].is_null(), "{out}");
    assert!(v["candidates"].is_array());
    for c in v["candidates"].as_array().unwrap() {
        assert!(c["effect"].is_string() && c["rms"].is_number(), "{c}");
    }
    let ladder = v["ladder"].as_array().unwrap();
    assert!(!ladder.is_empty());
    assert!(ladder[0]["effects"].is_array() && ladder[0]["rms"].is_number());
    // Noise of 3 counts on a field of 1000.
    let floor = v["noise_floor"].as_f64().unwrap();
    assert!((floor / 0.003 - 1.0).abs() < 0.3, "noise floor {floor}");
    assert!(v["noise_floor_method"].as_str().unwrap().contains("MAD"));
    assert!(
        v["verdict"]
            .as_str()
            .unwrap()
            .starts_with("what remains is noise"),
        "{out}"
    );
    assert!(v["criterion"].as_str().unwrap().contains("BIC"));
}

#[test]
fn text_report_names_its_parts() {
    let out = run_ok(&["diagnose", &sim_mild()]);
    for part in ["baseline", "noise floor", "ladder", "verdict", "criterion"] {
        assert!(out.contains(part), "missing {part}: {out}");
    }
}

#[test]
fn report_flag_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let r = run(&[
        "diagnose",
        &sim_mild(),
        "--json",
        "--report",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
}

#[test]
fn bad_input_is_a_clean_error() {
    let message = run_err(&["diagnose", "/nonexistent/file.csv"]);
    assert!(message.contains("nonexistent"), "{message}");
    let message = run_err(&["diagnose", &sim_mild(), "--effects", "magic"]);
    assert!(message.contains("magic"), "{message}");
    let message = run_err(&["diagnose", &sim_mild(), "--effects", "covariate:temp"]);
    assert!(message.contains("temp"), "{message}");
}

/// A real accelerometer turned about its y axis, diagnosed on (acc_y, acc_z):
/// acc_y is the axis of the turn, so the points never go round. The answer
/// names the cause (the columns, or the turn), not only the fit's failure.
#[test]
fn axes_that_did_not_turn_are_named_as_the_cause() {
    let file = common::shared_path(
        "data/real/sunsided-set-1/rotate-360ccw-around-y-pointing-left/mpu6050.csv",
    );
    assert!(file.exists(), "missing {}", file.display());
    let file = file.to_str().unwrap();
    let msg = run_err(&["diagnose", file, "--x", "acc_y", "--y", "acc_z"]);
    assert!(msg.contains("mpu6050.csv: no diagnosis"), "{msg}");
    // 103°: the two jolts the spike gate leaves out (rows 568 and 672)
    // reached 1° further.
    assert!(msg.contains("go only 103° round"), "{msg}");
    assert!(msg.contains("--x and --y"), "{msg}");
    // The axes that did turn are diagnosed.
    let out = run_ok(&["diagnose", file, "--x", "acc_x", "--y", "acc_z", "--json"]);
    let v: Value = serde_json::from_str(&out).unwrap();
    assert!(v["baseline"]["rms"].as_f64().unwrap() < 0.1, "{out}");
}

/// Without --gyro the diagnosis says the heading was not checked; every
/// ladder step lists its parameters with standard errors; the columns set
/// aside are listed (none here).
#[test]
fn json_says_the_heading_was_not_checked_and_lists_parameters() {
    let out = run_ok(&["diagnose", &sim_mild(), "--json"]);
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        v["heading"].as_str().unwrap(),
        "heading: not checked — no gyro given (--gyro); effects were held to physical limits instead, a cubic to 1 % at full scale (the datasheets' figure; 10 % with a gyro)"
    );
    assert!(v["set_aside"].is_array(), "{out}");
    let params = v["ladder"][0]["params"].as_array().unwrap();
    let names: Vec<&str> = params.iter().map(|p| p["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["a", "b", "d", "r"]);
    assert!(
        params.iter().all(|p| p["se"].as_f64().unwrap() > 0.0),
        "{out}"
    );
    assert!(v["ladder"][0]["heading_vs_gyro"].is_null());
    let text = run_ok(&["diagnose", &sim_mild()]);
    assert!(
        text.contains("heading: not checked — no gyro given (--gyro)"),
        "{text}"
    );
    assert!(text.contains("a = ") && text.contains(" ± "), "{text}");
}

/// With --gyro, each ladder step reports its heading error against it.
#[test]
fn gyro_heading_is_reported_for_every_step() {
    let dir =
        common::shared_path("data/real/sunsided-set-1/rotate-360ccw-around-x-pointing-forward");
    let file = dir.join("hmc5883l_mag.csv");
    let gyro = format!("{}:gyro_x", dir.join("mpu6050.csv").display());
    let out = run_ok(&[
        "diagnose",
        file.to_str().unwrap(),
        "--x",
        "mag_y",
        "--y",
        "mag_z",
        "--gyro",
        &gyro,
        "--json",
    ]);
    let v: Value = serde_json::from_str(&out).unwrap();
    assert!(
        v["heading"]
            .as_str()
            .unwrap()
            .starts_with("heading: checked against gyro_x")
    );
    for step in v["ladder"].as_array().unwrap() {
        let rms = step["heading_vs_gyro"]["rms_deg"].as_f64().unwrap();
        assert!(rms > 0.5 && rms < 5.0, "{step}");
    }
    for c in v["candidates"].as_array().unwrap() {
        assert!(c["heading_vs_gyro"]["rms_deg"].is_number(), "{c}");
    }
}

/// The gyro named by the recording's own path (as a person does who passes
/// the same mpu6050.csv twice) is the heading reference, not a covariate
/// candidate, and the diagnosis names it among the columns set aside.
#[test]
fn a_gyro_of_the_recording_itself_is_set_aside_not_a_covariate() {
    let dir =
        common::shared_path("data/real/sunsided-set-1/rotate-360ccw-around-x-pointing-forward");
    let file = dir.join("mpu6050.csv");
    let gyro = format!("{}:gyro_x", file.display());
    for spec in [gyro.as_str(), "gyro_x"] {
        let out = run_ok(&[
            "diagnose",
            file.to_str().unwrap(),
            "--x",
            "acc_y",
            "--y",
            "acc_z",
            "--gyro",
            spec,
            "--json",
        ]);
        let v: Value = serde_json::from_str(&out).unwrap();
        let candidates: Vec<&str> = v["candidates"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["effect"].as_str().unwrap())
            .collect();
        assert!(
            !candidates.contains(&"covariate:gyro_x"),
            "{spec}: {candidates:?}"
        );
        assert!(
            candidates.contains(&"covariate:gyro_z"),
            "{spec}: {candidates:?}"
        );
        let aside = v["set_aside"].as_array().unwrap();
        assert!(
            aside.iter().any(|a| a["column"] == "gyro_x"
                && a["reason"].as_str().unwrap().contains("heading reference")),
            "{spec}: {aside:?}"
        );
    }
}

/// With --gyro, the report plots each ladder model's heading error against
/// the gyro; without, there is no such figure.
#[test]
fn report_plots_the_heading_error_against_the_gyro() {
    let dir =
        common::shared_path("data/real/sunsided-set-1/rotate-360ccw-around-x-pointing-forward");
    let file = dir.join("mpu6050.csv");
    let out = tempfile::tempdir().unwrap();
    let report = out.path().join("with");
    run_ok(&[
        "diagnose",
        file.to_str().unwrap(),
        "--x",
        "acc_y",
        "--y",
        "acc_z",
        "--gyro",
        "gyro_x",
        "--report",
        report.to_str().unwrap(),
    ]);
    let svg = std::fs::read_to_string(report.join("heading_gyro.svg")).expect("heading figure");
    assert!(
        svg.contains("Heading error against gyro_x"),
        "title missing"
    );
    assert!(
        svg.contains("offset+scale+outliers"),
        "ladder model missing from the legend"
    );
    let index = std::fs::read_to_string(report.join("index.html")).unwrap();
    assert!(index.contains("heading_gyro.svg"));
    let without = out.path().join("without");
    run_ok(&[
        "diagnose",
        &sim_mild(),
        "--report",
        without.to_str().unwrap(),
    ]);
    assert!(!without.join("heading_gyro.svg").exists());
}
