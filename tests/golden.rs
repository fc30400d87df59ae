//! Golden outputs, in the manner of gpsd's regression logs: every shipped
//! capture is replayed at full speed, on its own and through the daemon's
//! pipeline, and the output compared line by line with the checked-in
//! `.chk` file. `FIELDCAL_BLESS=1 cargo test --test golden` rebuilds them.

mod common;

use std::fs;

use common::{repo_path, run_ok};

/// The time a fit took is the one field that differs from run to run, and
/// file names carry the checkout's path.
fn normalise(out: &str) -> String {
    const KEY: &str = "\"fit_ms\":";
    let mut text = String::with_capacity(out.len());
    let mut rest = out;
    while let Some(at) = rest.find(KEY) {
        let (head, tail) = rest.split_at(at + KEY.len());
        text.push_str(head);
        text.push('0');
        let end = tail.find([',', '}']).unwrap_or(tail.len());
        rest = &tail[end..];
    }
    text.push_str(rest);
    text.replace(&format!("{}/", env!("CARGO_MANIFEST_DIR")), "")
}

fn compare(golden: &str, out: &str) {
    let golden = repo_path(&format!("tests/data/golden/{golden}"));
    if std::env::var_os("FIELDCAL_BLESS").is_some() {
        fs::write(&golden, out).unwrap();
        return;
    }
    let want = fs::read_to_string(&golden)
        .unwrap_or_else(|e| panic!("{}: {e}; create it with FIELDCAL_BLESS=1", golden.display()));
    for (i, (got, want)) in out.lines().zip(want.lines()).enumerate() {
        assert_eq!(
            got,
            want,
            "line {} differs from {}",
            i + 1,
            golden.display()
        );
    }
    assert_eq!(
        out.lines().count(),
        want.lines().count(),
        "line count differs from {}",
        golden.display()
    );
}

fn replay_args(capture: &str, pipeline: bool) -> Vec<String> {
    let mut args = vec![
        "replay".to_string(),
        repo_path(&format!("tests/data/{capture}"))
            .display()
            .to_string(),
        "--speed".into(),
        "max".into(),
    ];
    if pipeline {
        args.push("--config".into());
        args.push(repo_path("tests/data/pipeline.toml").display().to_string());
    } else {
        args.push("--json".into());
    }
    args
}

fn check(capture: &str, pipeline: bool) {
    let args = replay_args(capture, pipeline);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = normalise(&run_ok(&args));
    let golden = if pipeline {
        format!("{capture}.pipeline.chk")
    } else {
        format!("{capture}.chk")
    };
    compare(&golden, &out);
}

#[test]
fn falcon_turn() {
    check("falcon_turn.fcap", false);
}

#[test]
fn falcon_garbage() {
    check("falcon_garbage.fcap", false);
}

#[test]
fn falcon_raw() {
    check("falcon_raw.bin", false);
}

#[test]
fn pipeline_falcon_turn() {
    check("falcon_turn.fcap", true);
}

#[test]
fn pipeline_falcon_garbage() {
    check("falcon_garbage.fcap", true);
}

#[test]
fn replays_are_stable_from_run_to_run() {
    for pipeline in [false, true] {
        let args = replay_args("falcon_garbage.fcap", pipeline);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        assert_eq!(normalise(&run_ok(&args)), normalise(&run_ok(&args)));
    }
}
