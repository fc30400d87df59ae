//! A jump in a CSV's time (issue 23, finding 6): a last row at t = 1e140,
//! or rows shifted by +1.7e9 s (still increasing), left the source
//! "connected" and publishing nothing: `replay` spun on STATUS lines it
//! could not count past, and a paced source slept for 54 years. A jump
//! beyond an hour is said with its line and played on at once.

mod common;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::daemon::{Daemon, write_config};

/// `rows` rows at 10 Hz of a turning compass, `t,x,y`, with `shift`
/// added to the time of the rows from `from` on.
fn csv(path: &Path, rows: usize, from: usize, shift: impl Fn(f64) -> f64) {
    let mut text = String::from("t,x,y\n");
    for i in 0..rows {
        let t = i as f64 * 0.1;
        let t = if i >= from { shift(t) } else { t };
        let heading = i as f64 * 0.05;
        text.push_str(&format!(
            "{t},{},{}\n",
            120.0 + 450.0 * heading.cos(),
            -60.0 + 430.0 * heading.sin()
        ));
    }
    std::fs::write(path, text).unwrap();
}

fn config(dir: &Path, csv: &Path, speed: &str) -> PathBuf {
    write_config(
        dir,
        &format!(
            "[daemon]\nstate_dir = \"{}\"\nstatus_interval_s = 0.2\n[outputs]\nstdout = true\n\
             [[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\nspeed = {speed}\n\
             [[sensor]]\nname = \"robot\"\nsource = \"log\"\naxes = [\"x\", \"y\"]\n",
            dir.join("state").display(),
            csv.display()
        ),
    )
}

#[test]
fn replay_plays_past_a_row_at_1e140_and_names_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("jump.csv");
    csv(&path, 300, 299, |_| 1e140);
    let cfg = config(dir.path(), &path, "\"max\"");
    let started = Instant::now();
    let r = common::run(&[
        "replay",
        path.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
    ]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert!(started.elapsed() < Duration::from_secs(30));
    let readings = r
        .stdout
        .lines()
        .filter(|l| l.contains("\"READING\""))
        .count();
    assert_eq!(readings, 300);
    assert!(
        r.stderr.contains("line 301: the time jumps 1.000e140 s"),
        "{}",
        r.stderr
    );
    // No 141-digit number in what a person reads.
    assert!(!r.stderr.contains("00000000000000000000"), "{}", r.stderr);
}

#[test]
fn a_paced_source_plays_on_past_a_shifted_clock() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("shift.csv");
    // 2 s of rows, then 1 s more shifted by 1.7e9 s; played as recorded.
    csv(&path, 30, 20, |t| t + 1.7e9);
    let cfg = config(dir.path(), &path, "1.0");
    let started = Instant::now();
    let mut daemon = Daemon::start(&cfg, &[]);
    let lines = daemon.drain(Duration::from_secs(30));
    assert!(daemon.wait(Duration::from_secs(10)).success());
    let took = started.elapsed();
    assert!(took < Duration::from_secs(20), "took {took:?}");
    let readings = lines.iter().filter(|v| v["class"] == "READING").count();
    assert_eq!(readings, 30);
    assert!(
        daemon
            .stderr()
            .contains("line 22: the time jumps 1.700e9 s"),
        "{}",
        daemon.stderr()
    );
}
