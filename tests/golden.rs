//! Golden outputs, in the manner of gpsd's regression logs: every shipped
//! capture is replayed at full speed and the output compared, line by line,
//! with the checked-in `.chk` file. `FIELDCAL_BLESS=1` rebuilds them.

mod common;

use std::fs;

use common::{repo_path, run_ok};

fn check(capture: &str) {
    let input = repo_path(&format!("tests/data/{capture}"));
    let golden = repo_path(&format!("tests/data/golden/{capture}.chk"));
    // Run from the repository root so file names in the output are stable.
    let out = run_ok(&[
        "replay",
        input.to_str().unwrap(),
        "--speed",
        "max",
        "--json",
    ]);
    let out = out.replace(&format!("{}/", env!("CARGO_MANIFEST_DIR")), "");
    if std::env::var_os("FIELDCAL_BLESS").is_some() {
        fs::write(&golden, &out).unwrap();
        return;
    }
    let want = fs::read_to_string(&golden)
        .unwrap_or_else(|e| panic!("{}: {e}; create it with FIELDCAL_BLESS=1", golden.display()));
    for (i, (got, want)) in out.lines().zip(want.lines()).enumerate() {
        assert_eq!(
            got,
            want,
            "{capture}: line {} differs from {}",
            i + 1,
            golden.display()
        );
    }
    assert_eq!(
        out.lines().count(),
        want.lines().count(),
        "{capture}: line count differs"
    );
}

#[test]
fn falcon_turn() {
    check("falcon_turn.fcap");
}

#[test]
fn falcon_garbage() {
    check("falcon_garbage.fcap");
}

#[test]
fn falcon_raw() {
    check("falcon_raw.bin");
}

#[test]
fn replay_is_stable_from_run_to_run() {
    let input = repo_path("tests/data/falcon_garbage.fcap");
    let a = run_ok(&["replay", input.to_str().unwrap(), "--speed", "max"]);
    let b = run_ok(&["replay", input.to_str().unwrap(), "--speed", "max"]);
    assert_eq!(a, b);
}
