//! Latency from the last byte of a Falcon-GX frame written to a
//! pseudo-terminal to its READING arriving at a TCP subscriber, through the
//! daemon (`fieldcal::daemon::run::run`, in process, on the same runtime
//! `fieldcal run` builds). 10,000 frames 1 ms apart, each carrying its
//! counter in mag x; prints p50, p99, p99.9 and the maximum.
//!
//! First the floor: the same frames through a bare pty to a reading thread.
//! Then three runs through the daemon: on a quiet machine; with both cores kept busy by two spinning
//! threads at normal priority (what a build or a second program beside the
//! daemon does); and busy again with the daemon's threads at SCHED_FIFO
//! priority 20, as `config/fieldcal.service` starts it, while the writer and
//! the subscriber stay at normal priority (skipped where the process may not
//! use real-time scheduling).
//!
//! Run: `cargo bench --bench latency`

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
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

/// The conditions a run measures under.
struct Scenario {
    name: &'static str,
    /// Threads spinning at normal priority for the whole run.
    hogs: usize,
    /// The daemon's threads at SCHED_FIFO; the pty writer and the
    /// subscriber stay at normal priority, as other programs would.
    realtime: bool,
}

const SCENARIOS: [Scenario; 3] = [
    Scenario {
        name: "quiet machine",
        hogs: 0,
        realtime: false,
    },
    Scenario {
        name: "both cores busy (2 spinning threads), normal priority",
        hogs: 2,
        realtime: false,
    },
    Scenario {
        name: "both cores busy, daemon at SCHED_FIFO 20 as fieldcal.service runs it, writer and subscriber at normal priority",
        hogs: 2,
        realtime: true,
    },
];

/// The priority `config/fieldcal.service` gives the daemon.
const FIFO_PRIORITY: i32 = 20;

/// Sets the calling thread's scheduling policy; threads it spawns inherit it.
fn set_realtime(on: bool) -> std::io::Result<()> {
    let (policy, priority) = if on {
        (libc::SCHED_FIFO, FIFO_PRIORITY)
    } else {
        (libc::SCHED_OTHER, 0)
    };
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pthread_setschedparam on the calling thread with a valid param.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), policy, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::from_raw_os_error(rc))
    }
}

/// Threads that keep a core busy until `running` is cleared.
fn spawn_hogs(count: usize, running: &Arc<AtomicBool>) -> Vec<JoinHandle<()>> {
    (0..count)
        .map(|_| {
            let running = running.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while running.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect()
}

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --benches` passes nothing
    // useful either: only run the measurement under `cargo bench`.
    if !std::env::args().any(|a| a == "--bench") {
        println!("latency: run with `cargo bench --bench latency`");
        return;
    }
    match measure_pty_alone() {
        Ok(summary) => println!(
            "latency pty write -> read on the other end, no fieldcal (the floor): {summary}"
        ),
        Err(why) => println!("latency of a bare pty: {why}"),
    }
    for scenario in &SCENARIOS {
        if scenario.realtime {
            // Asked on a throwaway thread, so this one keeps its policy.
            let permitted = std::thread::spawn(|| set_realtime(true))
                .join()
                .expect("probe thread");
            if let Err(e) = permitted {
                println!(
                    "latency pty write -> TCP READING, {}: skipped, real-time scheduling not permitted ({e}); run as root or with CAP_SYS_NICE",
                    scenario.name
                );
                continue;
            }
        }
        let hogs_running = Arc::new(AtomicBool::new(true));
        let hogs = spawn_hogs(scenario.hogs, &hogs_running);
        let outcome = measure(scenario.realtime);
        hogs_running.store(false, Ordering::Relaxed);
        for hog in hogs {
            hog.join().ok();
        }
        match outcome {
            Ok(summary) => println!(
                "latency pty write -> TCP READING, {}: {summary}",
                scenario.name
            ),
            Err(why) => println!("latency pty write -> TCP READING, {}: {why}", scenario.name),
        }
    }
}

/// One run: a fresh pty pair, daemon and subscriber; the summary line.
/// `realtime` puts the daemon's threads (only) at SCHED_FIFO.
fn measure(realtime: bool) -> Result<String, String> {
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
        if realtime {
            // The runtime's worker and blocking threads inherit the policy.
            set_realtime(true).expect("real-time scheduling (checked before)");
        }
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .expect("runtime");
        // As `fieldcal run` runs it: the loop is a task on the workers.
        runtime.block_on(async {
            tokio::spawn(fieldcal::daemon::run::run(config, stop_rx))
                .await
                .expect("the daemon's task")
        })
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
                if let Ok(n) = reader.read(&mut buf)
                    && n > 0
                {
                    started.store(true, Ordering::Relaxed);
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

    let sent = write_frames(&mut master, total);
    let wait_until = Instant::now() + Duration::from_secs(5);
    while !reader.is_finished() && Instant::now() < wait_until {
        std::thread::sleep(Duration::from_millis(10));
    }

    let arrived = arrived.lock().unwrap().clone();
    let summary = summarize(&sent, &arrived);

    stop_tx.send(true).ok();
    let outcome = daemon.join().expect("daemon thread");
    running.store(false, Ordering::Relaxed);
    drain.join().ok();
    drop(slave);
    if let Err(e) = outcome {
        eprintln!("daemon ended with: {e}");
    }
    summary
}

/// p50, p99, p99.9 and the maximum of frame i's arrival minus its write,
/// over the frames after the warm-up.
fn summarize(sent: &[Instant], arrived: &[Option<Instant>]) -> Result<String, String> {
    let mut latencies: Vec<Duration> = (WARM_UP..sent.len().min(arrived.len()))
        .filter_map(|i| arrived[i].map(|a| a.saturating_duration_since(sent[i])))
        .collect();
    if latencies.is_empty() {
        return Err("nothing arrived".to_string());
    }
    let missing = FRAMES - latencies.len();
    latencies.sort();
    let pct = |p: f64| {
        let k = ((latencies.len() as f64 * p).ceil() as usize).clamp(1, latencies.len()) - 1;
        latencies[k].as_secs_f64() * 1e6
    };
    Ok(format!(
        "{} frames {} ms apart: p50 {:.0} us, p99 {:.0} us, p99.9 {:.0} us, max {:.0} us, {} missing",
        latencies.len(),
        PERIOD.as_secs_f64() * 1e3,
        pct(0.50),
        pct(0.99),
        pct(0.999),
        pct(1.0),
        missing
    ))
}

/// Writes `total` frames on the pty master, one every PERIOD, stamping each
/// just before its write.
fn write_frames(master: &mut TTYPort, total: usize) -> Vec<Instant> {
    let mut sent = Vec::with_capacity(total);
    let begin = Instant::now();
    for i in 0..total {
        let due = begin + PERIOD * i as u32;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        // Stamped before the write: a writer preempted between its write and
        // a later stamp would make a late arrival look early.
        let bytes = frame(i);
        sent.push(Instant::now());
        master.write_all(&bytes).expect("write frame");
    }
    master.flush().ok();
    sent
}

/// The floor under every figure: the same frames through a bare pty pair to
/// a thread reading the other end, no fieldcal in between.
fn measure_pty_alone() -> Result<String, String> {
    let (mut master, slave) = TTYPort::pair().map_err(|e| format!("pty pair: {e}"))?;
    close_on_exec(master.as_raw_fd());
    close_on_exec(slave.as_raw_fd());
    let slave_name = slave.name().ok_or("pty slave has no name")?;
    // Opened by name, as the daemon opens it: raw, 8N1.
    let mut port = serialport::new(&slave_name, 115_200)
        .timeout(Duration::from_millis(200))
        .open_native()
        .map_err(|e| format!("open {slave_name}: {e}"))?;
    let total = WARM_UP + FRAMES;
    let reader = std::thread::spawn(move || {
        let frame_len = frame(0).len();
        let mut arrived = Vec::with_capacity(total);
        let mut pending = 0usize;
        let mut buf = [0u8; 4096];
        while arrived.len() < total {
            match port.read(&mut buf) {
                Ok(n) if n > 0 => {
                    let now = Instant::now();
                    pending += n;
                    while pending >= frame_len && arrived.len() < total {
                        pending -= frame_len;
                        arrived.push(Some(now));
                    }
                }
                Ok(_) => {}
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => break,
                Err(_) => break,
            }
        }
        arrived
    });
    let sent = write_frames(&mut master, total);
    let arrived = reader.join().map_err(|_| "reader thread panicked")?;
    drop(slave);
    summarize(&sent, &arrived)
}
