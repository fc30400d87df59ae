//! `fieldcal fit` and `fieldcal simulate` as a user runs them.

mod common;

use std::fs;

use common::{repo_path, run, run_err, run_ok, shared_path};
use serde_json::Value;

fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> String {
    let path = dir.path().join(name);
    fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

fn circle_csv(n: usize, arc_deg: f64) -> String {
    let mut text = String::from("t,x,y,temp\n");
    for i in 0..n {
        let h = (i as f64 / n as f64 * arc_deg).to_radians();
        text.push_str(&format!(
            "{},{},{},{}\n",
            i as f64 * 0.05,
            500.0 * h.cos() + 40.0,
            450.0 * h.sin() - 10.0,
            20.0
        ));
    }
    text
}

#[test]
fn json_report_has_the_documented_fields() {
    let file = repo_path("tests/data/sim_mild.csv");
    let out = run_ok(&["fit", file.to_str().unwrap(), "--json"]);
    let v: Value = serde_json::from_str(&out).unwrap();
    for key in ["a", "b", "d", "r"] {
        assert!(v["params"][key].is_f64(), "params.{key} in {v}");
    }
    assert_eq!(v["n"], 200);
    assert_eq!(v["solver"], "lsq");
    assert_eq!(v["model"], "offset+scale");
    assert!(
        v.get("iterations").is_none(),
        "lsq reports no iterations: {v}"
    );
    assert!(v["coverage_deg"].as_f64().unwrap() > 355.0);
    let rms = v["rms"].as_f64().unwrap();
    assert!(
        (0.002..0.004).contains(&rms),
        "rms {rms} for noise 3 on a field of 1000"
    );
    // The true calibration of this file (see tests/data/README.md).
    let a = v["params"]["a"].as_f64().unwrap();
    assert!((a - 1.0 / 1.05).abs() < 0.003, "a {a}");
}

#[test]
fn paper_gd_reports_its_iterations_and_agrees_with_lsq() {
    let file = repo_path("tests/data/sim_mild.csv");
    let file = file.to_str().unwrap();
    let gd: Value =
        serde_json::from_str(&run_ok(&["fit", file, "--solver", "paper-gd", "--json"])).unwrap();
    let lsq: Value = serde_json::from_str(&run_ok(&["fit", file, "--json"])).unwrap();
    assert_eq!(gd["solver"], "paper-gd");
    let iterations = gd["iterations"].as_u64().unwrap();
    assert!((100..1000).contains(&iterations), "{iterations}");
    for key in ["a", "b", "d", "r"] {
        let (g, l) = (
            gd["params"][key].as_f64().unwrap(),
            lsq["params"][key].as_f64().unwrap(),
        );
        assert!((g - l).abs() <= 1e-5 * l.abs(), "{key}: {g} vs {l}");
    }
}

#[test]
fn text_report_names_everything_a_person_needs() {
    let file = repo_path("tests/data/sim_strong.csv");
    let out = run_ok(&["fit", file.to_str().unwrap(), "--solver", "paper-gd"]);
    for needle in [
        "samples   200",
        "coverage  ",
        "a         ",
        "r         ",
        "rms       ",
        "paper-gd (the paper's gradient descent, ",
    ] {
        assert!(out.contains(needle), "missing {needle:?} in\n{out}");
    }
}

#[test]
fn output_writes_every_calibrated_sample_in_input_order() {
    let dir = tempfile::tempdir().unwrap();
    let input = write(&dir, "in.csv", &circle_csv(90, 360.0));
    let output = dir.path().join("out.csv");
    let report: Value = serde_json::from_str(&run_ok(&[
        "fit",
        &input,
        "--json",
        "--output",
        output.to_str().unwrap(),
    ]))
    .unwrap();
    let r = report["params"]["r"].as_f64().unwrap();
    let text = fs::read_to_string(&output).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t,x,y"));
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 90);
    for (i, row) in rows.iter().enumerate() {
        assert!(
            (row[0] - i as f64 * 0.05).abs() < 1e-12,
            "t out of order at {i}"
        );
        assert!(
            (row[1].hypot(row[2]) - r).abs() < 1e-6 * r,
            "row {i} off the circle"
        );
    }
    // Heading of the first sample: the input starts at heading 0.
    assert!(rows[0][2].abs() < 1e-6 * r);
}

#[test]
fn output_without_time_has_only_x_and_y() {
    let dir = tempfile::tempdir().unwrap();
    let text: String = circle_csv(60, 360.0)
        .lines()
        .map(|l| l.split_once(',').unwrap().1.to_string() + "\n")
        .collect();
    let input = write(&dir, "in.csv", &text);
    let output = dir.path().join("out.csv");
    run_ok(&["fit", &input, "--output", output.to_str().unwrap()]);
    assert!(fs::read_to_string(&output).unwrap().starts_with("x,y\n"));
}

#[test]
fn columns_can_be_chosen() {
    let dir = tempfile::tempdir().unwrap();
    let text = circle_csv(60, 360.0).replace("t,x,y,temp", "time_s,bx,by,temp");
    let input = write(&dir, "in.csv", &text);
    let v: Value = serde_json::from_str(&run_ok(&[
        "fit", &input, "--x", "bx", "--y", "by", "--json",
    ]))
    .unwrap();
    assert_eq!(v["x_column"], "bx");
    assert!((v["params"]["r"].as_f64().unwrap() - 450.0).abs() < 1e-6);
}

#[test]
fn real_magnetometer_recording_fits() {
    let file =
        shared_path("data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up/hmc5883l_mag.csv");
    assert!(
        file.exists(),
        "the real recordings must sit beside the checkout: {}",
        file.display()
    );
    let v: Value = serde_json::from_str(&run_ok(&[
        "fit",
        file.to_str().unwrap(),
        "--x",
        "mag_x",
        "--y",
        "mag_z",
        "--json",
    ]))
    .unwrap();
    assert_eq!(v["n"], 1766);
    assert!(v["coverage_deg"].as_f64().unwrap() > 350.0, "{v}");
    let a = v["params"]["a"].as_f64().unwrap();
    assert!(
        (0.9..1.2).contains(&a),
        "HMC5883L axes differ by a few percent, got a = {a}"
    );
    let rms = v["rms"].as_f64().unwrap();
    assert!(rms < 0.15, "hand-held turn: rms {rms}");
    // Both solvers succeed on it.
    let gd: Value = serde_json::from_str(&run_ok(&[
        "fit",
        file.to_str().unwrap(),
        "--x",
        "mag_x",
        "--y",
        "mag_z",
        "--solver",
        "paper-gd",
        "--json",
    ]))
    .unwrap();
    assert!(gd["iterations"].as_u64().unwrap() > 10);
}

#[test]
fn simulate_reproduces_the_shipped_files_byte_for_byte() {
    let readme = fs::read_to_string(repo_path("tests/data/README.md")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut checked = 0;
    for line in readme.lines().filter(|l| l.contains("`fieldcal simulate")) {
        let command = line
            .split('`')
            .find(|s| s.starts_with("fieldcal simulate"))
            .unwrap();
        let mut args: Vec<String> = command
            .split_whitespace()
            .skip(1)
            .map(String::from)
            .collect();
        let o = args.iter().position(|a| a == "-o").unwrap();
        let shipped = repo_path(&args[o + 1]);
        // A file of its own each time: simulate never overwrites one.
        let fresh = dir.path().join(format!("fresh{checked}.csv"));
        args[o + 1] = fresh.to_str().unwrap().to_string();
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        run_ok(&args);
        assert_eq!(
            fs::read(&fresh).unwrap(),
            fs::read(&shipped).unwrap(),
            "{command}"
        );
        checked += 1;
    }
    assert_eq!(checked, 6);
}

#[test]
fn simulate_json_gives_the_truth_and_fit_finds_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.csv");
    let out = out.to_str().unwrap();
    let truth: Value = serde_json::from_str(&run_ok(&[
        "simulate",
        "--gain-x",
        "0.5",
        "--offset-x",
        "-200",
        "--offset-y",
        "75",
        "--turns",
        "2",
        "--period",
        "0.03",
        "-o",
        out,
        "--json",
    ]))
    .unwrap();
    assert_eq!(truth["n"], 667);
    let fit: Value = serde_json::from_str(&run_ok(&["fit", out, "--json"])).unwrap();
    for key in ["a", "b", "d", "r"] {
        let (f, t) = (
            fit["params"][key].as_f64().unwrap(),
            truth["truth"][key].as_f64().unwrap(),
        );
        assert!((f - t).abs() < 1e-6 * t.abs().max(1.0), "{key}: {f} vs {t}");
    }
}

#[test]
fn simulate_to_stdout_writes_csv() {
    let out = run_ok(&["simulate", "--turns", "0.5"]);
    assert!(out.starts_with("t,x,y\n0,1000,0\n"), "{}", &out[..40]);
    assert_eq!(out.lines().count(), 101);
}

// ---- bad input: one clear message, exit 1, never a panic or NaN ----

#[test]
fn missing_file() {
    let msg = run_err(&["fit", "/no/such/recording.csv"]);
    assert!(
        msg.contains("/no/such/recording.csv: cannot read the file"),
        "{msg}"
    );
    // The operating system's reason, once.
    assert_eq!(msg.matches("No such file or directory").count(), 1, "{msg}");
}

#[test]
fn missing_column_lists_what_there_is() {
    let dir = tempfile::tempdir().unwrap();
    let f = write(&dir, "a.csv", "t,mag_x,mag_y\n0,1,2\n");
    let msg = run_err(&["fit", &f]);
    assert!(msg.contains("a.csv: no column 'x' for the x axis"), "{msg}");
    assert!(
        msg.contains("(columns: t, mag_x, mag_y)") && msg.contains("--x"),
        "{msg}"
    );
    let msg = run_err(&["fit", &f, "--x", "mag_x", "--y", "mag_q"]);
    assert!(msg.contains("no column 'mag_q' for the y axis"), "{msg}");
}

#[test]
fn non_numeric_value_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let mut text = circle_csv(40, 360.0);
    text = text.replacen("\n1,", "\n1,12abc", 1); // corrupt line 22 (t = 1)
    let f = write(&dir, "bad.csv", &text);
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("bad.csv:22: column 'x' (field 2): '12abc"),
        "{msg}"
    );
    assert!(msg.contains("is not a number"), "{msg}");
}

#[test]
fn non_finite_value_names_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let mut lines: Vec<String> = circle_csv(40, 360.0).lines().map(String::from).collect();
    lines[5] = "0.2,30,inf,20".into();
    let f = write(&dir, "inf.csv", &(lines.join("\n") + "\n"));
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("inf.csv:6: column 'y' (field 3): 'inf' is not a finite number"),
        "{msg}"
    );
    lines[5] = "0.2,30,5,NaN".into();
    let f = write(&dir, "nan.csv", &(lines.join("\n") + "\n"));
    // A command that reads the column refuses it where it is; the paper's
    // model reads the axes and time alone, and fits.
    let msg = run_err(&["fit", &f, "--effects", "covariate:temp"]);
    assert!(msg.contains("nan.csv:6: column 'temp' (field 4)"), "{msg}");
    let msg = run_err(&["diagnose", &f]);
    assert!(msg.contains("nan.csv:6: column 'temp' (field 4)"), "{msg}");
    let fitted = run_ok(&["fit", &f, "--json"]);
    assert!(fitted.contains("\"n\":40"), "{fitted}");
}

/// The model's fit has no use for the times, and reads the axes alone (as
/// polars' `columns=` or pandas' `usecols=` would); a fit that writes or
/// integrates the times reads them, and refuses a bad one where it is.
#[test]
fn a_bad_time_stops_only_a_fit_that_uses_the_times() {
    let dir = tempfile::tempdir().unwrap();
    let mut lines: Vec<String> = circle_csv(40, 360.0).lines().map(String::from).collect();
    lines[5] = "0.2s,30,5,20".into();
    let f = write(&dir, "late.csv", &(lines.join("\n") + "\n"));
    let fitted = run_ok(&["fit", &f, "--json"]);
    assert!(fitted.contains("\"n\":40"), "{fitted}");
    let out = dir.path().join("out.csv");
    let msg = run_err(&["fit", &f, "--output", out.to_str().unwrap()]);
    assert!(
        msg.contains("late.csv:6: column 't' (field 1): '0.2s' is not a number"),
        "{msg}"
    );
    // In 3-D too: the axes alone, unless --output writes the times.
    let mut lines = vec!["t,x,y,z".to_string()];
    for i in 0..400 {
        let (a, b) = (i as f64 * 0.37, i as f64 * 0.071);
        let (x, y, z) = (b.cos() * a.cos(), b.cos() * a.sin(), b.sin());
        lines.push(format!(
            "{},{},{},{}",
            i as f64 * 0.05,
            30.0 + 500.0 * x,
            450.0 * y,
            480.0 * z
        ));
    }
    lines[7] = lines[7].replacen(|c: char| c.is_ascii_digit(), "x", 1);
    let f = write(&dir, "late3.csv", &(lines.join("\n") + "\n"));
    let fitted = run_ok(&["fit", &f, "--json"]);
    assert!(fitted.contains("\"n\":400"), "{fitted}");
    let out = dir.path().join("out3.csv");
    let msg = run_err(&["fit", &f, "--output", out.to_str().unwrap()]);
    assert!(msg.contains("late3.csv:8: column 't' (field 1)"), "{msg}");
    // A time column named with --t is among the columns a missing z is
    // told from, read or not.
    let msg = run_err(&["fit", &f, "--z", "zz", "--t", "t"]);
    assert!(msg.contains("(columns: x, y, t, z)"), "{msg}");
}

#[test]
fn a_message_names_the_line_the_bad_value_is_on() {
    let dir = tempfile::tempdir().unwrap();
    let mut lines: Vec<String> = circle_csv(40, 360.0).lines().map(String::from).collect();
    // Line 6 of the file: the header, then rows 1 to 4.
    lines[5] = "0.25,oops,5,20".into();
    // A recorder's CRLF, on the plain path and after a quoted field (the
    // csv crate's path).
    let f = write(&dir, "crlf.csv", &(lines.join("\r\n") + "\r\n"));
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("crlf.csv:6: column 'x' (field 2): 'oops'"),
        "{msg}"
    );
    let mut quoted = lines.clone();
    quoted[2] = quoted[2].replace(",20", ",\"20\"");
    assert!(quoted[2].ends_with(",\"20\""), "{}", quoted[2]);
    let f = write(&dir, "quoted.csv", &(quoted.join("\r\n") + "\r\n"));
    let msg = run_err(&["fit", &f]);
    assert!(msg.contains("quoted.csv:6: column 'x'"), "{msg}");
    // Blank lines and comments before it are lines of the file.
    let mut noted = lines.clone();
    noted.insert(5, String::new());
    noted.insert(6, "# the sensor was bumped here".into());
    let f = write(&dir, "noted.csv", &(noted.join("\n") + "\n"));
    let msg = run_err(&["fit", &f]);
    assert!(msg.contains("noted.csv:8: column 'x'"), "{msg}");
    // And in a second file, the gyro's, joined by time.
    let mut gyro = vec!["t,gyro".to_string()];
    gyro.extend((0..40).map(|i| format!("{},{}", f64::from(i) * 0.05, 360.0)));
    gyro.insert(2, String::new());
    gyro[6] = "0.2,fast".into();
    let g = write(&dir, "gyro.csv", &(gyro.join("\r\n") + "\r\n"));
    let f = write(&dir, "turn.csv", &(circle_csv(40, 360.0)));
    let msg = run_err(&["fit", &f, "--gyro", &format!("{g}:gyro")]);
    assert!(
        msg.contains("gyro.csv:7: column 'gyro' (field 2): 'fast'"),
        "{msg}"
    );
}

#[test]
fn fewer_samples_than_unknowns() {
    let dir = tempfile::tempdir().unwrap();
    let f = write(&dir, "few.csv", "x,y\n1,0\n0,1\n-1,0\n");
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("few.csv") && msg.contains("3 samples are too few"),
        "{msg}"
    );
    // The turn gate needs more samples than the model's unknowns.
    assert!(msg.contains("too few to show a turn"), "{msg}");
    assert!(msg.contains("at least 12"), "{msg}");
    // A header and nothing after it: said so, in 2-D and in 3-D (not a
    // missing z column).
    let f = write(&dir, "none.csv", "x,y\n");
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("none.csv: the header (x, y) has no sample after it"),
        "{msg}"
    );
    let f = write(&dir, "none3.csv", "x,y,z\n");
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("none3.csv: the header (x, y, z) has no sample after it"),
        "{msg}"
    );
    let f = write(&dir, "empty.csv", "");
    assert!(run_err(&["fit", &f]).contains("empty.csv: the file is empty"));
}

#[test]
fn readings_that_do_not_cover_the_turn() {
    let dir = tempfile::tempdir().unwrap();
    let f = write(&dir, "arc.csv", &circle_csv(50, 120.0));
    for solver in ["lsq", "paper-gd"] {
        let msg = run_err(&["fit", &f, "--solver", solver]);
        assert!(msg.contains("arc.csv"), "{msg}");
        assert!(msg.contains("go only 118° round their centre"), "{msg}");
        assert!(msg.contains("a fit needs 300°"), "{msg}");
    }
    // The user may accept a shorter turn on purpose.
    let out = run_ok(&["fit", &f, "--min-coverage", "100", "--json"]);
    assert!(out.contains("\"coverage_deg\":117.6"), "{out}");
}

#[test]
fn points_on_no_ellipse_of_the_family() {
    let dir = tempfile::tempdir().unwrap();
    // Two pairs of hyperbola branches, y^2 - x^2 = +-1e4: they surround
    // their centre on every heading, yet y^2 grows with x^2 (theta1 = 1).
    // Each branch is traced in turn, as a moving sensor would.
    let mut rows = [String::new(), String::new(), String::new(), String::new()];
    for i in 0..100 {
        let u = i as f64 / 25.0 - 2.0;
        let (s, c) = (100.0 * u.sinh(), 100.0 * u.cosh());
        for (row, (x, y)) in rows.iter_mut().zip([(s, c), (s, -c), (c, s), (-c, s)]) {
            row.push_str(&format!("{x},{y}\n"));
        }
    }
    let text = String::from("x,y\n") + &rows.concat();
    let f = write(&dir, "hyp.csv", &text);
    let msg = run_err(&["fit", &f]);
    assert!(
        msg.contains("hyp.csv") && msg.contains("fit no ellipse of the paper's family"),
        "{msg}"
    );
    assert!(msg.contains(">= 0"), "{msg}");
}

#[test]
fn gradient_descent_that_hits_its_cap() {
    let file = repo_path("tests/data/sim_strong.csv");
    let msg = run_err(&[
        "fit",
        file.to_str().unwrap(),
        "--solver",
        "paper-gd",
        "--max-iterations",
        "1000",
    ]);
    assert!(msg.contains("sim_strong.csv"), "{msg}");
    assert!(
        msg.contains("did not converge within 1000 iterations"),
        "{msg}"
    );
    assert!(
        msg.contains("--max-iterations") && msg.contains("--solver lsq"),
        "{msg}"
    );
}

#[test]
fn gradient_descent_that_diverges() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("far.csv");
    run_ok(&[
        "simulate",
        "--offset-x",
        "2500",
        "--offset-y",
        "2500",
        "-o",
        out.to_str().unwrap(),
    ]);
    let msg = run_err(&["fit", out.to_str().unwrap(), "--solver", "paper-gd"]);
    assert!(
        msg.contains("far.csv") && msg.contains("gradient descent diverged"),
        "{msg}"
    );
    // The closed form has no such limit.
    run_ok(&["fit", out.to_str().unwrap()]);
}

#[test]
fn unwritable_output_is_reported_and_nothing_is_left() {
    let file = repo_path("tests/data/sim_mild.csv");
    let msg = run_err(&[
        "fit",
        file.to_str().unwrap(),
        "--output",
        "/no/such/dir/out.csv",
    ]);
    assert!(
        msg.contains("cannot write the calibrated samples to /no/such/dir/out.csv"),
        "{msg}"
    );
}

#[test]
fn bad_options_are_refused_by_name() {
    let file = repo_path("tests/data/sim_mild.csv");
    let r = run(&["fit", file.to_str().unwrap(), "--min-coverage", "400"]);
    assert_eq!(r.code, Some(2));
    assert!(r.stderr.contains("--min-coverage"), "{}", r.stderr);
    let r = run(&["fit", file.to_str().unwrap(), "--solver", "newton"]);
    assert_eq!(r.code, Some(2));
    assert!(
        r.stderr.contains("lsq") && r.stderr.contains("paper-gd"),
        "{}",
        r.stderr
    );
    let msg = run_err(&["simulate", "--period=-1"]);
    assert!(msg.contains("--period must be a positive number"), "{msg}");
}

#[test]
fn nan_words_are_told_from_letters_in_a_name() {
    assert!(common::has_nan_word("rms NaN %"));
    assert!(common::has_nan_word("r = NaN"));
    assert!(common::has_nan_word("(NaN)"));
    assert!(!common::has_nan_word("/tmp/.tmp0NaNIS/few.csv"));
    assert!(!common::has_nan_word("/tmp/.tmpNaN1/x"));
    assert!(!common::has_nan_word("no number here"));
}

/// Issue 23, finding 7: one garbage row in a 6-turn recording cost the fit
/// ("the readings go only 182° round their centre"). The spike gate leaves
/// it out, names it on stderr, and the fit is the clean recording's.
#[test]
fn one_garbage_row_is_left_out_of_the_fit_and_named() {
    let dir = tempfile::tempdir().unwrap();
    let clean = dir.path().join("clean.csv");
    run_ok(&[
        "simulate",
        "--turns",
        "6",
        "--noise",
        "2",
        "--seed",
        "3",
        "--output",
        clean.to_str().unwrap(),
    ]);
    let text = std::fs::read_to_string(&clean).unwrap();
    for bad in ["65535", "1e6", "-4096", "5000"] {
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        let mut row: Vec<String> = lines[50].split(',').map(str::to_string).collect();
        row[1] = bad.to_string();
        lines[50] = row.join(",");
        let spoilt = write(&dir, "spoilt.csv", &(lines.join("\n") + "\n"));
        let r = common::run(&["fit", &spoilt, "--json"]);
        assert_eq!(r.code, Some(0), "{bad}: {}", r.stderr);
        assert!(
            r.stderr
                .contains("spoilt.csv: 1 reading left out as spikes")
                && r.stderr.contains("row 50 after the header: x = "),
            "{bad}: {}",
            r.stderr
        );
        let fit: serde_json::Value = serde_json::from_str(&r.stdout).unwrap();
        let reference: serde_json::Value =
            serde_json::from_str(&run_ok(&["fit", clean.to_str().unwrap(), "--json"])).unwrap();
        assert_eq!(
            fit["n"].as_u64().unwrap() + 1,
            reference["n"].as_u64().unwrap(),
            "{bad}"
        );
        let a = fit["params"]["a"].as_f64().unwrap();
        let a0 = reference["params"]["a"].as_f64().unwrap();
        assert!((a - a0).abs() < 0.002, "{bad}: a {a} against {a0}");
    }
}
