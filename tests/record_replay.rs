//! `fieldcal record`, `fieldcal replay` and `fieldcal simulate --format
//! falcon`, as a user runs them.

mod common;

use std::fs;
use std::time::{Duration, Instant};

use common::pty::FalconPty;
use common::{fieldcal, repo_path, run, run_err, run_ok};
use fieldcal::protocol::falcon::FalconDecoder;
use fieldcal::sim::{FalconWire, SimSensor};
use serde_json::Value;

fn samples(stdout: &str) -> Vec<Value> {
    stdout
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .filter(|v| v["class"] == "SAMPLE")
        .collect()
}

fn mag(v: &Value) -> Vec<i64> {
    v["mag"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_i64().unwrap())
        .collect()
}

#[test]
fn a_capture_recorded_from_the_device_replays_to_the_same_samples() {
    let sensor = SimSensor {
        turns: 40.0 / 200.0,
        noise: 2.0,
        offset_y: -80.0,
        seed: 5,
        ..Default::default()
    };
    let (_, chunks) = sensor
        .falcon_capture(&FalconWire {
            garbage: 0.02,
            ..Default::default()
        })
        .unwrap();
    let chunks: Vec<Vec<u8>> = chunks.into_iter().map(|c| c.bytes).collect();
    let mut expected = Vec::new();
    let mut decoder = FalconDecoder::new();
    for c in &chunks {
        decoder.decode(c, |f| expected.push(f));
    }
    let pty = FalconPty::plug_in(chunks, Duration::from_millis(50));

    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("run.fcap");
    let capture = capture.to_str().unwrap();
    let out = run_ok(&[
        "record",
        "--port",
        pty.path().to_str().unwrap(),
        "--output",
        capture,
        "--duration",
        "3.5",
        "--json",
    ]);
    let summary: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    assert_eq!(summary["counters"]["frames_good"], 40, "{summary}");
    assert_eq!(pty.sent(), 40);

    let replayed = samples(&run_ok(&["replay", capture, "--speed", "max"]));
    assert_eq!(replayed.len(), 40);
    for (v, f) in replayed.iter().zip(&expected) {
        assert_eq!(mag(v), f.mag.map(i64::from).to_vec());
        assert_eq!(v["timer"], f.timer);
        assert_eq!(v["accel"][2], f.accel[2]);
    }
    // Receive times are one period apart: the device's own, 50 ms, or
    // longer when a loaded machine wakes the pty's thread late (CI once
    // read a mean of 108 ms against the 40-65 ms this test then allowed).
    let t: Vec<f64> = replayed
        .iter()
        .map(|v| v["time"].as_f64().unwrap())
        .collect();
    assert!(t.windows(2).all(|w| w[1] >= w[0]), "{t:?}");
    let mean = (t[39] - t[0]) / 39.0;
    let sent = |i| pty.sent_at(i).expect("the device sent 40 frames");
    let device = sent(39).duration_since(sent(0)).as_secs_f64() / 39.0;
    assert!(
        (mean - device).abs() < 0.010,
        "mean period {mean}, the device's {device}"
    );
}

#[test]
fn simulated_capture_replays_in_real_time_faster_and_at_max() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("sim.fcap");
    let capture = capture.to_str().unwrap();
    // 40 frames at 50 ms: 1.95 s of recording.
    run_ok(&[
        "simulate", "--format", "falcon", "--turns", "0.2", "--noise", "1", "-o", capture,
    ]);
    let timed = |speed: &str| {
        let started = Instant::now();
        let out = run_ok(&["replay", capture, "--speed", speed]);
        (started.elapsed(), samples(&out).len())
    };
    let (real, n) = timed("1");
    assert_eq!(n, 40);
    assert!(
        real >= Duration::from_millis(1900) && real < Duration::from_millis(3500),
        "{real:?}"
    );
    let (fast, _) = timed("4");
    assert!(
        fast >= Duration::from_millis(480) && fast < Duration::from_millis(1500),
        "{fast:?}"
    );
    let (max, n) = timed("max");
    assert_eq!(n, 40);
    assert!(max < Duration::from_millis(480), "{max:?}");
}

#[test]
fn simulated_capture_with_garbage_recovers_every_frame() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("g.fcap");
    let capture = capture.to_str().unwrap();
    run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--garbage",
        "0.05",
        "--seed",
        "3",
        "-o",
        capture,
    ]);
    let out = run_ok(&["replay", capture, "--speed", "max", "--json"]);
    assert_eq!(samples(&out).len(), 200);
    let summary: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    assert_eq!(summary["class"], "SUMMARY");
    assert_eq!(summary["summary"]["falcon"]["frames_good"], 200);
    assert!(
        summary["summary"]["falcon"]["bytes_skipped"]
            .as_u64()
            .unwrap()
            > 100
    );
}

#[test]
fn a_raw_dump_replays_at_the_nominal_period() {
    let sensor = SimSensor {
        turns: 0.1,
        ..Default::default()
    };
    let (_, chunks) = sensor.falcon_capture(&FalconWire::default()).unwrap();
    let mut raw: Vec<u8> = b"\x00\xffline noise before the first frame".to_vec();
    for c in &chunks {
        raw.extend_from_slice(&c.bytes);
    }
    raw.extend_from_slice(&chunks[0].bytes[..10]); // cut mid-frame, as `cat` does
    let dir = tempfile::tempdir().unwrap();
    let dump = dir.path().join("ttyUSB0.bin");
    fs::write(&dump, &raw).unwrap();
    let r = run(&["replay", dump.to_str().unwrap(), "--speed", "max"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    let s = samples(&r.stdout);
    assert_eq!(s.len(), 20);
    assert_eq!(s[1]["time"], 0.05);
    assert_eq!(s[19]["time"], 0.95);
    assert!(r.stderr.contains("incomplete frame"), "{}", r.stderr);
}

#[test]
fn a_truncated_capture_replays_what_is_intact_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("cut.fcap");
    run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--turns",
        "0.1",
        "-o",
        capture.to_str().unwrap(),
    ]);
    let bytes = fs::read(&capture).unwrap();
    fs::write(&capture, &bytes[..bytes.len() - 7]).unwrap(); // tear the last record
    let r = run(&["replay", capture.to_str().unwrap(), "--speed", "max"]);
    assert_eq!(r.code, Some(0), "{}", r.stderr);
    assert_eq!(samples(&r.stdout).len(), 19);
    assert!(r.stderr.contains("cut.fcap"), "{}", r.stderr);
}

#[test]
fn a_file_that_is_not_a_capture_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("notes.txt");
    fs::write(&junk, "these are my notes, not a capture\n".repeat(20)).unwrap();
    let msg = run_err(&["replay", junk.to_str().unwrap()]);
    assert!(
        msg.contains("notes.txt") && msg.contains("neither a fieldcal capture nor a raw dump"),
        "{msg}"
    );
    let msg = run_err(&["replay", "/no/such/capture.fcap"]);
    assert!(msg.contains("/no/such/capture.fcap"), "{msg}");
}

#[test]
fn record_on_a_missing_port_says_which_keeps_trying_and_fails_with_nothing_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("none.fcap");
    let r = run(&[
        "record",
        "--port",
        "/dev/ttyNOPE42",
        "--output",
        out.to_str().unwrap(),
        "--duration",
        "1",
    ]);
    assert_eq!(r.code, Some(1), "{}", r.stderr);
    assert!(
        r.stderr
            .contains("/dev/ttyNOPE42: no such device: check the cable and the port path"),
        "{}",
        r.stderr
    );
    // Said once while it retries, and once more as the reason it failed.
    assert_eq!(
        r.stderr.matches("no such device").count(),
        2,
        "{}",
        r.stderr
    );
    assert!(
        r.stderr.contains(
            "error: /dev/ttyNOPE42: no such device, so nothing was recorded in 1.0 s: plug the device in"
        ),
        "{}",
        r.stderr
    );
    assert!(!r.stderr.contains("recorded 0 chunks"), "{}", r.stderr);
    assert!(
        r.stderr
            .contains(&format!("removed the empty capture {}", out.display())),
        "{}",
        r.stderr
    );
    assert!(!out.exists(), "an empty capture was left behind");
}

#[test]
fn record_from_a_device_that_sends_nothing_fails_and_leaves_no_file() {
    // A port that opens and stays silent (wrong device, powered off behind
    // its USB adapter, wrong baud).
    let pty = FalconPty::plug_in(Vec::new(), Duration::from_millis(50));
    let port = pty.path().to_str().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("silent.fcap");
    let r = run(&[
        "record",
        "--port",
        port,
        "--output",
        out.to_str().unwrap(),
        "--duration",
        "1",
        "--json",
    ]);
    assert_eq!(r.code, Some(1), "{}", r.stderr);
    assert!(
        r.stderr.contains(&format!(
            "error: {port}: the device opened but sent no bytes in 1.0 s"
        )),
        "{}",
        r.stderr
    );
    assert!(
        r.stderr
            .contains("(this run: --device falcon --baud 38400)"),
        "{}",
        r.stderr
    );
    assert!(
        r.stdout.is_empty(),
        "no summary of a failed run: {}",
        r.stdout
    );
    assert!(!out.exists(), "an empty capture was left behind");
    // It did open the port and ask for data: the failure is the silence.
    assert!(pty.commands_seen().0 >= 1, "{:?}", pty.commands_seen());
}

#[test]
fn record_never_overwrites_a_capture() {
    let existing = repo_path("tests/data/sim_mild.csv");
    let msg = run_err(&[
        "record",
        "--port",
        "/dev/null",
        "--output",
        existing.to_str().unwrap(),
        "--duration",
        "1",
    ]);
    assert!(msg.contains("it must not exist yet"), "{msg}");
}

#[test]
fn record_stops_cleanly_on_sigterm() {
    let sensor = SimSensor {
        turns: 0.5,
        seed: 7,
        ..Default::default()
    };
    let (_, chunks) = sensor.falcon_capture(&FalconWire::default()).unwrap();
    let chunks: Vec<Vec<u8>> = chunks.into_iter().map(|c| c.bytes).collect();
    let pty = FalconPty::plug_in(chunks, Duration::from_millis(20));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("term.fcap");
    let mut child = fieldcal()
        .args([
            "record",
            "--port",
            pty.path().to_str().unwrap(),
            "--output",
            out.to_str().unwrap(),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    pty.wait_sent(5, Duration::from_secs(5));
    std::thread::sleep(Duration::from_millis(100));
    let pid = child.id().to_string();
    assert!(
        std::process::Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success()
    );
    let started = Instant::now();
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    assert!(started.elapsed() < Duration::from_secs(3));
    let replayed = samples(&run_ok(&[
        "replay",
        out.to_str().unwrap(),
        "--speed",
        "max",
    ]));
    assert!(replayed.len() >= 5, "{} samples kept", replayed.len());
}

#[test]
fn record_stopped_by_sigterm_before_any_byte_fails_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("term.fcap");
    let child = fieldcal()
        .args([
            "record",
            "--port",
            "/dev/ttyNOPE43",
            "--output",
            out.to_str().unwrap(),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let pid = child.id().to_string();
    assert!(
        std::process::Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success()
    );
    let started = Instant::now();
    let output = child.wait_with_output().unwrap();
    assert!(started.elapsed() < Duration::from_secs(3));
    assert_eq!(output.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("/dev/ttyNOPE43: no such device, so nothing was recorded"),
        "{stderr}"
    );
    assert!(!out.exists(), "an empty capture was left behind");
}

#[test]
fn simulate_never_overwrites_a_file_without_force() {
    let dir = tempfile::tempdir().unwrap();
    for (format, name) in [
        ("csv", "run.csv"),
        ("falcon", "run.fcap"),
        ("falcon-raw", "run.bin"),
    ] {
        let path = dir.path().join(name);
        let file = path.to_str().unwrap();
        fs::write(&path, "precious").unwrap();
        let r = run(&["simulate", "--format", format, "--turns", "0.2", "-o", file]);
        assert_eq!(r.code, Some(1), "{format}: {}", r.stderr);
        assert!(
            r.stderr.contains(&format!(
                "{file} exists: simulate never overwrites a file; choose another --output, or add --force to replace it"
            )),
            "{format}: {}",
            r.stderr
        );
        assert_eq!(fs::read_to_string(&path).unwrap(), "precious", "{format}");

        run_ok(&[
            "simulate", "--format", format, "--turns", "0.2", "-o", file, "--force",
        ]);
        let written = fs::read(&path).unwrap();
        assert!(written.len() > 100, "{format}: {} bytes", written.len());
        assert_ne!(&written[..8], b"precious", "{format}");
    }
    // Only the three files: no temporary file left beside them.
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 3);
    // A new file needs no --force.
    let new = dir.path().join("new.csv");
    run_ok(&["simulate", "--turns", "0.2", "-o", new.to_str().unwrap()]);
    assert!(fs::read_to_string(&new).unwrap().starts_with("t,x,y\n"));
}
