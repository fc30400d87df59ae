//! Helpers shared by the integration tests: run the real binary.
#![allow(dead_code)]

pub mod daemon;
pub mod faults;
pub mod fixtures;
pub mod http;
pub mod pty;
pub mod table;

use std::path::{Path, PathBuf};

/// Headless Chromium's flags for the browser tests: what it needs as root
/// and on a machine with no network (no sandbox, no GPU, no background
/// connections); each caller adds a fresh `--user-data-dir`.
pub const CHROMIUM_FLAGS: [&str; 9] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
];
use std::process::{Command, Output};

/// Marks a descriptor close-on-exec. serialport's pty pairs are opened
/// without it, so a daemon spawned later would inherit the master and keep
/// the line up after the test "unplugs" the device.
pub fn close_on_exec(fd: std::os::fd::RawFd) {
    // SAFETY: fcntl on a descriptor the caller owns; no memory is touched.
    let rc = unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) };
    assert_eq!(rc, 0, "fcntl(FD_CLOEXEC) failed");
}

pub fn fieldcal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_fieldcal"))
}

pub fn repo_path(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(relative)
}

/// The shared folder beside the checkout (real recordings live there).
pub fn shared_path(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared")
        .join(relative)
}

pub struct Run {
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
}

pub fn run(args: &[&str]) -> Run {
    let Output {
        status,
        stdout,
        stderr,
    } = fieldcal().args(args).output().expect("run fieldcal");
    Run {
        code: status.code(),
        stdout: String::from_utf8_lossy(&stdout).into_owned(),
        stderr: String::from_utf8_lossy(&stderr).into_owned(),
    }
}

/// Runs a command that must succeed and returns its stdout.
pub fn run_ok(args: &[&str]) -> String {
    let r = run(args);
    assert_eq!(r.code, Some(0), "fieldcal {args:?} failed: {}", r.stderr);
    r.stdout
}

/// Runs a command that must fail cleanly and returns its one-line message.
pub fn run_err(args: &[&str]) -> String {
    let r = run(args);
    assert_eq!(
        r.code,
        Some(1),
        "fieldcal {args:?} should fail with exit 1; stderr: {}",
        r.stderr
    );
    assert!(!r.stderr.contains("panicked"), "panic: {}", r.stderr);
    assert!(
        r.stdout.is_empty(),
        "a failed fit printed output: {}",
        r.stdout
    );
    assert_eq!(
        r.stderr.lines().count(),
        1,
        "expected one message line: {}",
        r.stderr
    );
    // A computed NaN must never reach a message; a quoted input value may,
    // and so may a word holding the letters (a random temporary directory
    // such as /tmp/.tmp0NaNIS).
    let unquoted = r.stderr.replace("'NaN'", "");
    assert!(!has_nan_word(&unquoted), "NaN in message: {}", r.stderr);
    r.stderr
}

/// Whether `text` holds "NaN" as a word of its own (not inside a longer
/// run of letters and digits).
pub fn has_nan_word(text: &str) -> bool {
    let bytes = text.as_bytes();
    text.match_indices("NaN").any(|(i, _)| {
        let before = i.checked_sub(1).map(|k| bytes[k]);
        let after = bytes.get(i + 3).copied();
        !before.is_some_and(|b| b.is_ascii_alphanumeric())
            && !after.is_some_and(|b| b.is_ascii_alphanumeric())
    })
}

/// Replays `capture` at full speed through the daemon's pipeline, with a
/// replay source `imu` and the `[[sensor]]` tables `sensors`; returns its
/// published lines (parsed) and its log (stderr). The configuration is
/// written into `dir`.
pub fn replay_through(
    capture: &Path,
    sensors: &str,
    dir: &Path,
) -> (Vec<serde_json::Value>, String) {
    let config = dir.join("replay.toml");
    std::fs::write(
        &config,
        format!(
            "[outputs]\nstdout = true\n[[source]]\nname = \"imu\"\nkind = \"replay\"\nfile = \"{}\"\n{sensors}",
            capture.display()
        ),
    )
    .expect("write the configuration");
    let r = run(&[
        "replay",
        capture.to_str().expect("a UTF-8 path"),
        "--config",
        config.to_str().expect("a UTF-8 path"),
        "--speed",
        "max",
    ]);
    assert_eq!(r.code, Some(0), "replay failed: {}", r.stderr);
    let lines = r
        .stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    (lines, r.stderr)
}

/// Writes a bridge capture: `chips` are the streams, in order (stream i is
/// chips[i] at its usual address), and `records` the readings as (time,
/// stream, reading), written in time order, each encoded as its chip's
/// registers.
pub fn write_bridge_capture(
    path: &Path,
    chips: &[fieldcal::protocol::chips::Chip],
    nominal_period_s: f64,
    note: &str,
    mut records: Vec<(f64, u8, fieldcal::sample::Reading)>,
) {
    use fieldcal::capture::{CaptureHeader, CaptureWriter, StreamInfo, StreamKind, VERSION};
    let header = CaptureHeader {
        version: VERSION,
        streams: chips
            .iter()
            .enumerate()
            .map(|(i, chip)| StreamInfo {
                id: u8::try_from(i).expect("a few streams"),
                kind: StreamKind::Chip {
                    chip: *chip,
                    address: chip.default_address(),
                },
            })
            .collect(),
        port: None,
        baud: None,
        started_unix: 0.0,
        nominal_period_s,
        note: Some(note.into()),
    };
    records.sort_by(|a, b| a.0.total_cmp(&b.0));
    let file = std::fs::File::create(path).expect("create the capture");
    let mut out = CaptureWriter::new(std::io::BufWriter::new(file), &header).expect("a header");
    for (time, stream, reading) in &records {
        let bytes = chips[usize::from(*stream)].encode(reading);
        out.write_chunk(*time, *stream, &bytes).expect("a chunk");
    }
    out.flush().expect("flush the capture");
}
