//! Resident memory of `fieldcal run` with four sensors, each on its own
//! replayed capture at ten times real speed (so rotations complete, fits run
//! and calibrations are stored): VmRSS and VmHWM from /proc after it settles.
//!
//! Needs the release binary: `cargo build --release && cargo bench --bench memory`

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use fieldcal::sim::SimSensor;

#[path = "support/mod.rs"]
mod support;

const SENSORS: usize = 4;

fn status_kib(pid: u32, key: &str) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find(|l| l.starts_with(key))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("memory: run with `cargo bench --bench memory`");
        return;
    }
    let binary = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/release/fieldcal");
    if !binary.exists() {
        eprintln!(
            "memory: {} is missing; run `cargo build --release` first",
            binary.display()
        );
        std::process::exit(1);
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let mut text = format!(
        "[daemon]\nstate_dir = \"{}\"\nstatus_interval_s = 1.0\n\n[outputs]\nstdout = true\n",
        dir.path().join("state").display()
    );
    for k in 0..SENSORS {
        // 20 turns of 200 frames, each sensor a different one.
        let sensor = SimSensor {
            offset_x: 30.0 + 10.0 * k as f64,
            seed: k as u64 + 1,
            ..support::compass(20.0)
        };
        let file = dir.path().join(format!("imu{k}.fcap"));
        let out = std::io::BufWriter::new(std::fs::File::create(&file).expect("capture file"));
        support::write_capture(out, &sensor)
            .flush()
            .expect("capture written");
        text.push_str(&format!(
            "\n[[source]]\nname = \"imu{k}\"\nkind = \"replay\"\nfile = \"{}\"\nspeed = 10.0\n\n[[sensor]]\nname = \"compass{k}\"\nsource = \"imu{k}\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n",
            file.display()
        ));
    }
    let config = dir.path().join("fieldcal.toml");
    std::fs::write(&config, text).expect("configuration");
    let mut child = Command::new(&binary)
        .args(["run", "--config", config.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start fieldcal run");
    let pid = child.id();
    // Each rotation is 10 s of recording: 1 s at ten times real speed.
    let mut rss = Vec::new();
    for _ in 0..10 {
        std::thread::sleep(Duration::from_millis(500));
        if let Some(kib) = status_kib(pid, "VmRSS:") {
            rss.push(kib);
        }
    }
    let hwm = status_kib(pid, "VmHWM:");
    let _ = child.kill();
    let _ = child.wait();
    let last = rss.last().copied().unwrap_or(0);
    println!(
        "memory, fieldcal run with {SENSORS} sensors on replayed captures: VmRSS {:.1} MB after 5 s (samples every 0.5 s: {:?} KiB), VmHWM {:.1} MB",
        last as f64 / 1024.0,
        rss,
        hwm.unwrap_or(0) as f64 / 1024.0
    );
}
