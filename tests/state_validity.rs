//! Impossible calibrations (issue 23, finding 4): a hand-edited state file,
//! a `--mag-calibration` or a `check` CAL whose numbers cannot correct a
//! reading is refused by name, never applied. The daemon publishes the
//! refusal as an ERROR, moves the file aside and starts uncalibrated; a
//! state file of the other geometry is refused the same way.

mod common;

use std::fs;
use std::path::Path;
use std::time::Duration;

use common::daemon::{Daemon, replay_config};
use fieldcal::daemon::Calibration;
use fieldcal::daemon::state::{StateError, StateStore};
use fieldcal::model::calibration::Ellipsoid3Params;
use fieldcal::model::check::{CheckError, parse_stored};
use fieldcal::model::paper::PaperCalibration;
use fieldcal::model::tilt::{Calibration3, Calibration3Error};
use serde_json::{Value, json};

fn calibration(a: f64, b: f64) -> Calibration {
    Calibration {
        sensor: "compass".to_string(),
        id: 5,
        model: "offset+scale".into(),
        params: PaperCalibration {
            a,
            b,
            d: -80.0,
            r: 1000.0,
        },
        rms: 0.003,
        coverage_deg: 359.5,
        n: 412,
        time: 1_700_000_000.5,
        terms: Default::default(),
        ellipsoid: None,
        se: Default::default(),
        parent: None,
        history: Vec::new(),
        gyro: None,
        dip: None,
        across: None,
        level: None,
    }
}

fn sphere(matrix: [[f64; 3]; 3], offset: [f64; 3]) -> Ellipsoid3Params {
    Ellipsoid3Params {
        offset,
        matrix,
        r: 1000.0,
        coverage: 0.9,
    }
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// Writes `c` as the daemon stores it, bypassing the store's own checks.
fn write_state(state: &Path, c: &Calibration) {
    fs::create_dir_all(state).unwrap();
    let text = json!({ "format": 1, "calibration": c }).to_string();
    fs::write(state.join(format!("{}.json", c.sensor)), text).unwrap();
}

fn moved_aside(state: &Path) -> usize {
    fs::read_dir(state)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("compass.json.corrupt-")
        })
        .count()
}

/// The daemon on `falcon_turn.fcap` with `c` stored: the ERROR it publishes
/// at start and its first READING.
fn start_with_stored(c: &Calibration) -> (Value, Value, usize) {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    write_state(&state, c);
    let capture = common::repo_path("tests/data/falcon_turn.fcap");
    let config = replay_config(dir.path(), &capture, "\"max\"", "stdout = true");
    let mut daemon = Daemon::start(&config, &[]);
    let (_, error) = daemon.wait_for(Duration::from_secs(10), "an ERROR", |v| {
        v["class"] == "ERROR"
    });
    let (_, reading) = daemon.wait_for(Duration::from_secs(10), "a READING", |v| {
        v["class"] == "READING"
    });
    daemon.drain(Duration::from_secs(20));
    (error, reading, moved_aside(&state))
}

#[test]
fn a_stored_gain_ratio_of_1e308_is_refused_said_and_set_aside() {
    for c in [
        calibration(1e308, 150.0),
        calibration(5e-324, 150.0),
        calibration(1.1, 1.7e308),
    ] {
        let (error, reading, moved) = start_with_stored(&c);
        let message = error["message"].as_str().unwrap();
        assert!(message.contains("compass.json"), "{message}");
        assert!(
            message.contains("max_scale_ratio") || message.contains("max_offset_ratio"),
            "{message}"
        );
        assert!(message.contains("starts uncalibrated"), "{message}");
        assert_eq!(reading["calibrated"], false, "{reading}");
        assert_eq!(moved, 1);
    }
}

#[test]
fn a_stored_calibration_of_the_other_geometry_is_refused_not_ignored() {
    let mut c = calibration(1.0, 0.0);
    c.ellipsoid = Some(sphere(IDENTITY, [0.0; 3]));
    let (error, reading, moved) = start_with_stored(&c);
    let message = error["message"].as_str().unwrap();
    assert!(message.contains("3-axis calibration"), "{message}");
    assert!(message.contains("now has 2 axes"), "{message}");
    assert_eq!(reading["calibrated"], false);
    assert_eq!(moved, 1);
}

#[test]
fn impossible_3d_state_files_are_moved_aside() {
    let mirror = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let skew = [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let huge = [[1e308, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for (matrix, offset, words) in [
        (mirror, [0.0; 3], "positive definite"),
        ([[0.0; 3]; 3], [0.0; 3], "positive definite"),
        (skew, [0.0; 3], "not symmetric"),
        (huge, [0.0; 3], "stretches"),
        (IDENTITY, [1.7e308, 0.0, 0.0], "offset on x"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let mut c = calibration(1.0, 0.0);
        c.ellipsoid = Some(sphere(matrix, offset));
        write_state(dir.path(), &c);
        let store = StateStore::open(dir.path()).unwrap();
        match store.load("compass") {
            Err(e @ StateError::Corrupt { .. }) => {
                assert!(e.to_string().contains(words), "{e}");
            }
            other => panic!("{matrix:?} {offset:?}: {other:?}"),
        }
        assert_eq!(moved_aside(dir.path()), 1);
    }
}

#[test]
fn heading_refuses_a_matrix_no_sensor_has() {
    let mirror = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for matrix in [
        mirror,
        [[0.0; 3]; 3],
        [[1e308, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    ] {
        let text = json!({
            "axes": 3, "x_column": "mx", "y_column": "my", "z_column": "mz",
            "model": "full", "effects": [],
            "params": {"offset": [0.0, 0.0, 0.0], "matrix": matrix, "r": 1.0},
            "rms": 0.01, "n": 100,
        })
        .to_string();
        match Calibration3::from_json(&text) {
            Err(e @ Calibration3Error::Impossible { .. }) => {
                assert!(e.to_string().contains("cannot be a calibration"), "{e}")
            }
            other => panic!("{matrix:?}: {other:?}"),
        }
    }
}

#[test]
fn check_refuses_impossible_2d_numbers_by_name() {
    for (a, b, words) in [
        (1e308, 0.0, "max_scale_ratio"),
        (5e-324, 0.0, "max_scale_ratio"),
        (1.1, 1.7e308, "max_offset_ratio"),
    ] {
        let text = json!({
            "solver": "lsq",
            "params": {"a": a, "b": b, "d": 0.0, "r": 1000.0},
        })
        .to_string();
        match parse_stored(text.as_bytes()) {
            Err(e @ CheckError::Invalid { .. }) => assert!(e.to_string().contains(words), "{e}"),
            other => panic!("a = {a}, b = {b}: {other:?}"),
        }
    }
}

/// Finding 5: a stored id of 2^64 − 1 wrapped the next one to 0. Ids run
/// from 1 to 2^53 − 1 (what a JSON client reads exactly); beyond, the file
/// is refused and moved aside.
#[test]
fn a_stored_id_that_would_wrap_is_refused() {
    for id in [u64::MAX, 1 << 53, 0] {
        let dir = tempfile::tempdir().unwrap();
        let mut c = calibration(1.1, 150.0);
        c.id = id;
        write_state(dir.path(), &c);
        let store = StateStore::open(dir.path()).unwrap();
        match store.load("compass") {
            Err(e @ StateError::Corrupt { .. }) => {
                assert!(e.to_string().contains("ids run from 1"), "{e}")
            }
            other => panic!("id {id}: {other:?}"),
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let mut c = calibration(1.1, 150.0);
    c.id = (1 << 53) - 1;
    write_state(dir.path(), &c);
    let loaded = StateStore::open(dir.path())
        .unwrap()
        .load("compass")
        .unwrap();
    assert_eq!(loaded.map(|c| c.id), Some((1 << 53) - 1));
}
