//! Latency from the last byte of a Falcon-GX frame written to a
//! pseudo-terminal to its READING arriving at a TCP subscriber, through the
//! daemon (`fieldcal::daemon::run::run`, in process, on the same runtime
//! `fieldcal run` builds). 10,000 frames 1 ms apart, each carrying its
//! counter in mag x; prints p50, p99 and the maximum.
//!
//! Run: `cargo bench --bench latency`

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use fieldcal::daemon::config::parse;
use fieldcal::protocol::falcon::FalconFrame;
use serialport::{SerialPort, TTYPort};
use tokio::sync::watch;

/// Frames measured, after a warm-up.
const FRAMES: usize = 10_000;
const WARM_UP: usize = 500;
const PERIOD: Duration = Duration::from_millis(1);
/// mag x of frame i is `i - OFFSET`, so every frame is told apart.
const OFFSET: i32 = 15_000;

/// serialport opens pty pairs without close-on-exec.
fn close_on_exec(fd: std::os::fd::RawFd) {
    // SAFETY: fcntl on a descriptor we own; no memory is touched.
    let rc = unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) };
    assert_eq!(rc, 0, "fcntl(FD_CLOEXEC) failed");
}

fn frame(i: usize) -> [u8; 23] {
    FalconFrame {
        mag: [(i as i32 - OFFSET) as i16, 400, 200],
        accel: [0, 0, 4096],
        rate: [0, 0, 0],
        timer: (i as u64 * 50 % 65_536) as u16,
    }
    .encode()
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` passes nothing
    // useful either: only run the measurement under `cargo bench`.
    if !std::env::args().any(|a| a == "--bench") {
        println!("latency: run with `cargo bench --bench latency`");
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    close_on_exec(master.as_raw_fd());
    close_on_exec(slave.as_raw_fd());
    let slave_name = slave.name().expect("pty slave name");
    master
        .set_timeout(Duration::from_millis(50))
        .expect("pty timeout");
    let port = TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port();
    let text = format!(
        r#"
[daemon]
state_dir = "{state}"
status_interval_s = 1.0

[outputs]
stdout = false
tcp = "127.0.0.1:{port}"
queue = 65536

[[source]]
name = "imu"
kind = "falcon"
port = "{slave_name}"
retry_s = 0.2

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]
"#,
        state = dir.path().join("state").display(),
    );
    let config = parse(&text, &dir.path().join("fieldcal.toml")).expect("configuration");

    let (stop_tx, stop_rx) = watch::channel(false);
    let daemon = std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .expect("runtime");
        runtime.block_on(fieldcal::daemon::run::run(config, stop_rx))
    });

    // The device side: notice the start command, drain whatever the daemon sends.
    let started = Arc::new(AtomicBool::new(false));
    let running = Arc::new(AtomicBool::new(true));
    let drain = {
        let mut reader = master.try_clone_native().expect("pty clone");
        let started = started.clone();
        let running = running.clone();
        std::thread::spawn(move || {
            let mut buf = [0u8; 256];
            while running.load(Ordering::Relaxed) {
                if let Ok(n) = reader.read(&mut buf) {
                    if n > 0 {
                        started.store(true, Ordering::Relaxed);
                    }
                }
            }
        })
    };

    let subscriber = {
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            match TcpStream::connect(("127.0.0.1", port)) {
                Ok(s) => break s,
                Err(_) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Err(e) => panic!("cannot connect to the daemon: {e}"),
            }
        }
    };
    subscriber.set_nodelay(true).ok();
    let deadline = Instant::now() + Duration::from_secs(10);
    while !started.load(Ordering::Relaxed) {
        assert!(
            Instant::now() < deadline,
            "the daemon never opened the port"
        );
        std::thread::sleep(Duration::from_millis(5));
    }

    let total = WARM_UP + FRAMES;
    let arrived: Arc<Mutex<Vec<Option<Instant>>>> = Arc::new(Mutex::new(vec![None; total]));
    let reader = {
        let arrived = arrived.clone();
        std::thread::spawn(move || {
            let mut seen = 0usize;
            for line in BufReader::new(subscriber).lines() {
                let Ok(line) = line else { break };
                let now = Instant::now();
                if !line.contains("\"READING\"") {
                    continue;
                }
                let v: serde_json::Value = serde_json::from_str(&line).expect("JSON line");
                let Some(x) = v["raw"][0].as_f64() else {
                    continue;
                };
                let i = (x as i32 + OFFSET) as usize;
                if i < total {
                    arrived.lock().unwrap()[i] = Some(now);
                    seen += 1;
                    if i == total - 1 || seen == total {
                        break;
                    }
                }
            }
        })
    };

    let mut sent = Vec::with_capacity(total);
    let begin = Instant::now();
    for i in 0..total {
        let due = begin + PERIOD * i as u32;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        master.write_all(&frame(i)).expect("write frame");
        sent.push(Instant::now());
    }
    master.flush().ok();
    let wait_until = Instant::now() + Duration::from_secs(5);
    while !reader.is_finished() && Instant::now() < wait_until {
        std::thread::sleep(Duration::from_millis(10));
    }

    let arrived = arrived.lock().unwrap().clone();
    let mut latencies: Vec<Duration> = (WARM_UP..total)
        .filter_map(|i| arrived[i].map(|a| a.saturating_duration_since(sent[i])))
        .collect();
    let missing = FRAMES - latencies.len();
    latencies.sort();
    let pct = |p: f64| {
        let k = ((latencies.len() as f64 * p).ceil() as usize).clamp(1, latencies.len()) - 1;
        latencies[k].as_secs_f64() * 1e6
    };
    if latencies.is_empty() {
        println!("latency: no READING arrived");
    } else {
        println!(
            "latency pty write -> TCP READING, {} frames {} ms apart: p50 {:.0} us, p99 {:.0} us, max {:.0} us, {} missing",
            latencies.len(),
            PERIOD.as_secs_f64() * 1e3,
            pct(0.50),
            pct(0.99),
            latencies.last().unwrap().as_secs_f64() * 1e6,
            missing
        );
    }

    stop_tx.send(true).ok();
    let outcome = daemon.join().expect("daemon thread");
    running.store(false, Ordering::Relaxed);
    drain.join().ok();
    drop(slave);
    if let Err(e) = outcome {
        eprintln!("daemon ended with: {e}");
    }
}
