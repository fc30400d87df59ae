//! Issue 12, numeric half: values whose squares overflow end a fit at once
//! with that reason (no hang), and every speed, fraction and duration a user
//! gives on the command line has a range, refused with a message, never a
//! panic or "unexpected argument".

mod common;

use std::io::Read;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use common::fieldcal;

/// What a run that had to end in time printed.
struct Ended {
    code: Option<i32>,
    stdout: String,
    stderr: String,
    took: Duration,
}

/// Runs fieldcal and waits at most `cap`; a run still going then is killed
/// and the test fails (a hang is the defect these tests catch).
fn run_within(args: &[&str], cap: Duration) -> Ended {
    let started = Instant::now();
    let mut child: Child = fieldcal()
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start fieldcal");
    loop {
        if let Some(status) = child.try_wait().expect("wait for fieldcal") {
            let mut stdout = String::new();
            let mut stderr = String::new();
            child
                .stdout
                .take()
                .unwrap()
                .read_to_string(&mut stdout)
                .ok();
            child
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut stderr)
                .ok();
            return Ended {
                code: status.code(),
                stdout,
                stderr,
                took: started.elapsed(),
            };
        }
        if started.elapsed() > cap {
            child.kill().ok();
            child.wait().ok();
            panic!("fieldcal {args:?} still ran after {cap:?}: killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

const CAP: Duration = Duration::from_secs(30);

/// `n` points of a circle of radius 1e307 centred at (1.5e308, 0): every
/// value is finite, and every square overflows.
fn huge_circle(dir: &tempfile::TempDir, n: usize) -> String {
    let mut text = String::from("t,x,y\n");
    for i in 0..n {
        let h = (i as f64 / n as f64 * 360.0).to_radians();
        text.push_str(&format!(
            "{},{:e},{:e}\n",
            i as f64 * 0.05,
            1.5e308 + 1e307 * h.cos(),
            1e307 * h.sin()
        ));
    }
    let path = dir.path().join(format!("huge{n}.csv"));
    std::fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn assert_too_large(ended: &Ended, what: &str) {
    assert_eq!(ended.code, Some(1), "{what}: {}", ended.stderr);
    assert!(
        ended.took < Duration::from_secs(10),
        "{what} took {:?}",
        ended.took
    );
    let err = &ended.stderr;
    assert!(err.contains("too large to square in f64"), "{what}: {err}");
    assert!(!err.contains("degenerate"), "{what}: {err}");
    // The column and the line are named.
    assert!(err.contains("'x'"), "{what}: {err}");
    assert!(err.contains(".csv:2: column 'x'"), "{what}: {err}");
    assert!(ended.stdout.is_empty(), "{what}: {}", ended.stdout);
}

#[test]
fn a_fit_of_values_whose_squares_overflow_ends_at_once_with_that_reason() {
    let dir = tempfile::tempdir().unwrap();
    for n in [8, 16, 64] {
        let file = huge_circle(&dir, n);
        for solver in ["lsq", "paper-gd"] {
            let ended = run_within(&["fit", &file, "--solver", solver], CAP);
            assert_too_large(&ended, &format!("fit --solver {solver} on {n} points"));
        }
        let ended = run_within(&["diagnose", &file], CAP);
        assert_too_large(&ended, &format!("diagnose on {n} points"));
    }
}

#[test]
fn the_turn_gate_refuses_values_whose_squares_overflow_naming_the_column() {
    use fieldcal::model::FitError;
    use fieldcal::model::turn::check_turn_of;
    use fieldcal::sample::Dataset;
    let n = 40;
    let (x, y): (Vec<f64>, Vec<f64>) = (0..n)
        .map(|i| {
            let h = (i as f64 / n as f64 * 360.0).to_radians();
            (1e3 * h.cos(), 1e152 + 1e151 * h.sin())
        })
        .unzip();
    // A Dataset refuses them too, naming the column and row.
    let err = Dataset::new("mag_x", "mag_z", None, x.clone(), y.clone(), vec![]).unwrap_err();
    let message = err.to_string();
    assert!(
        message.contains("'mag_z'") && message.contains("row 0"),
        "{message}"
    );
    assert!(message.contains("too large to square in f64"), "{message}");
    // The gate, for data built without the Dataset's check.
    let data = Dataset {
        x_name: "mag_x".into(),
        y_name: "mag_z".into(),
        t: None,
        x,
        y,
        covariates: vec![],
    };
    match check_turn_of(&data, 300.0) {
        Err(FitError::TooLarge { column, index, .. }) => {
            assert_eq!((column.as_str(), index), ("mag_z", 0));
        }
        other => panic!("{other:?}"),
    }
    // Values up to the limit still pass the gate: a 1e149 turn is a turn.
    let (x, y): (Vec<f64>, Vec<f64>) = (0..n)
        .map(|i| {
            let h = (i as f64 / n as f64 * 360.0).to_radians();
            (1e149 * h.cos(), 1e149 * h.sin())
        })
        .unzip();
    let data = Dataset::from_xy(x, y).unwrap();
    check_turn_of(&data, 300.0).unwrap();
}

fn assert_refused(args: &[&str], words: &[&str]) {
    let ended = run_within(args, CAP);
    assert_eq!(ended.code, Some(2), "{args:?}: {}", ended.stderr);
    let err = &ended.stderr;
    assert!(!err.contains("panicked"), "{args:?}: {err}");
    assert!(!err.contains("unexpected argument"), "{args:?}: {err}");
    for w in words {
        assert!(err.contains(w), "no '{w}' for {args:?} in: {err}");
    }
}

#[test]
fn replay_speeds_out_of_range_are_refused_without_a_panic() {
    let capture = common::repo_path("tests/data/falcon_garbage.fcap");
    let capture = capture.to_str().unwrap();
    for speed in ["1e-300", "1e-9", "0", "-1", "nan", "inf", "1e7"] {
        assert_refused(
            &["replay", capture, "--speed", speed],
            &["--speed", "from 0.001 to 1e6"],
        );
    }
    // The ends of the range are taken.
    let ended = run_within(&["replay", capture, "--speed", "1e6"], CAP);
    assert_eq!(ended.code, Some(0), "{}", ended.stderr);
}

#[test]
fn simulate_refuses_a_garbage_fraction_that_would_take_gigabytes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("g.fcap");
    let out = out.to_str().unwrap();
    for garbage in ["0.9999999", "0.99999", "0.95", "1", "-0.1"] {
        assert_refused(
            &[
                "simulate",
                "--format",
                "falcon",
                "--garbage",
                garbage,
                "-o",
                out,
            ],
            &["--garbage", "from 0 to 0.9"],
        );
        assert!(!std::path::Path::new(out).exists());
    }
    // The largest fraction allowed writes a bounded file: 23 bytes a frame
    // and nine garbage bytes for each, about 46 kB for 200 frames.
    let ended = run_within(
        &[
            "simulate",
            "--format",
            "falcon",
            "--garbage",
            "0.9",
            "-o",
            out,
        ],
        CAP,
    );
    assert_eq!(ended.code, Some(0), "{}", ended.stderr);
    let len = std::fs::metadata(out).unwrap().len();
    assert!((20_000..100_000).contains(&len), "{len} bytes");
}

#[test]
fn simulate_refuses_a_capture_beyond_its_size_bound_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("big.fcap");
    let out = out.to_str().unwrap();
    // 20 M frames (the most samples) at 0.9 garbage: 4.6 GB.
    let ended = run_within(
        &[
            "simulate",
            "--format",
            "falcon",
            "--garbage",
            "0.9",
            "--turns",
            "1000",
            "--turn-seconds",
            "1000",
            "-o",
            out,
        ],
        CAP,
    );
    assert_eq!(ended.code, Some(1), "{}", ended.stderr);
    assert!(
        ended.stderr.contains("bytes, more than the"),
        "{}",
        ended.stderr
    );
    assert!(ended.took < Duration::from_secs(5), "{:?}", ended.took);
}

#[test]
fn negative_numbers_get_a_range_error_not_unexpected_argument() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("n.csv");
    let out = out.to_str().unwrap();
    for (flag, words) in [
        ("--noise", &["noise", "zero or more"][..]),
        ("--period", &["period", "positive"][..]),
        ("--field", &["field", "positive"][..]),
    ] {
        let ended = run_within(&["simulate", flag, "-1", "-o", out], CAP);
        assert_eq!(ended.code, Some(1), "{flag}: {}", ended.stderr);
        assert!(
            !ended.stderr.contains("unexpected argument"),
            "{flag}: {}",
            ended.stderr
        );
        for w in words {
            assert!(ended.stderr.contains(w), "{flag}: {}", ended.stderr);
        }
    }
    assert_refused(
        &[
            "record",
            "--port",
            "/nonexistent",
            "--duration",
            "-1",
            "-o",
            out,
        ],
        &["--duration", "above 0"],
    );
    assert_refused(
        &[
            "record",
            "--port",
            "/nonexistent",
            "--duration",
            "1e300",
            "-o",
            out,
        ],
        &["--duration", "a year"],
    );
}

#[test]
fn a_count_of_one_is_singular() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("one.csv");
    std::fs::write(&file, "x,y\n1,2\n").unwrap();
    let ended = run_within(&["fit", file.to_str().unwrap()], CAP);
    assert_eq!(ended.code, Some(1), "{}", ended.stderr);
    assert!(
        ended.stderr.contains("1 sample is too few to show a turn"),
        "{}",
        ended.stderr
    );
    let out = dir.path().join("s.csv");
    let ended = run_within(
        &[
            "simulate",
            "--turn-seconds",
            "0.05",
            "-o",
            out.to_str().unwrap(),
        ],
        CAP,
    );
    assert_eq!(ended.code, Some(0), "{}", ended.stderr);
    assert!(
        ended.stderr.contains("wrote 1 sample to"),
        "{}",
        ended.stderr
    );
}

/// `simulate` killed (SIGKILL: nothing of it runs) while it writes a large
/// file leaves nothing in the output's directory: the content has no name
/// until it is complete.
#[test]
fn a_killed_simulate_leaves_no_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("big.csv");
    let mut child = fieldcal()
        .args(["simulate", "--turns", "1000", "--turn-seconds", "100", "-o"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start fieldcal simulate");
    // Wait until it has a file open in the directory, and written to it.
    let fd_dir = format!("/proc/{}/fd", child.id());
    let started = Instant::now();
    let writing = loop {
        let open_there = std::fs::read_dir(&fd_dir).ok().and_then(|fds| {
            fds.flatten()
                .filter_map(|fd| std::fs::read_link(fd.path()).ok())
                .find(|target| target.starts_with(dir.path()))
        });
        if let Some(target) = open_there {
            break target;
        }
        assert!(
            started.elapsed() < CAP,
            "simulate never opened a file in the directory"
        );
        assert!(child.try_wait().unwrap().is_none(), "simulate ended first");
        std::thread::sleep(Duration::from_millis(5));
    };
    std::thread::sleep(Duration::from_millis(200));
    child.kill().unwrap();
    child.wait().unwrap();
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(
        left.is_empty(),
        "left behind: {left:?} (it was writing {})",
        writing.display()
    );
}
