//! CPU per reading of `fieldcal run` with 1, 16 and 64 Falcon-GX IMUs on
//! pseudo-terminals, 20 frames a second each (the device's 50 ms), beside
//! its floor, measured in the same run.
//!
//! The floor is the least a daemon can do for each reading: a thread per
//! sensor that reads its port, decodes the frames with fieldcal's own
//! decoder and writes one READING line per frame to stdout. Both run as
//! child processes, their stdout counted by this one. After a warm-up,
//! their CPU (user and system, every thread, those that have ended too:
//! the process's CPU-time clock, read at the start and the end of the
//! window) is divided by the READING lines they wrote meanwhile. The compass turns
//! once every 10 s, so the daemon also fits its rotations, as it does in
//! the field.
//!
//! Run: `cargo bench --bench run`; `FIELDCAL_BENCH_SENSORS=1,16,64` and
//! `FIELDCAL_BENCH_SECONDS=10` choose the runs, `FIELDCAL_BENCH_RUNS=3`
//! how many times each is measured (the daemon and the floor alternated;
//! the best of each, and the range, are printed), `FIELDCAL_BENCH_BIN`
//! another build of `fieldcal` to measure.

use std::io::{BufRead, BufReader, Read, Write};
use std::os::fd::AsRawFd;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime};

use fieldcal::protocol::falcon::{FalconDecoder, FalconFrame};
use serialport::{SerialPort, TTYPort};

/// Frames a second from each IMU.
const RATE_HZ: u32 = 20;
/// Frames a turn of the compass: 10 s.
const FRAMES_A_TURN: usize = 200;
/// Seconds before the measurement starts: the daemon is up and reading.
const WARM_UP: Duration = Duration::from_secs(3);
/// Set in the environment of the child that is the floor.
const FLOOR_ENV: &str = "FIELDCAL_RUN_FLOOR";

/// serialport opens pty pairs without close-on-exec.
fn close_on_exec(fd: std::os::fd::RawFd) {
    // SAFETY: fcntl on a descriptor we own; no memory is touched.
    let rc = unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) };
    assert_eq!(rc, 0, "fcntl(FD_CLOEXEC) failed");
}

/// Frame `i` of a compass turning once every [`FRAMES_A_TURN`] frames.
fn frame(i: usize) -> [u8; 23] {
    let angle = std::f64::consts::TAU * (i % FRAMES_A_TURN) as f64 / FRAMES_A_TURN as f64;
    FalconFrame {
        mag: [
            (400.0 * angle.cos() + 30.0) as i16,
            (380.0 * angle.sin() - 20.0) as i16,
            200,
        ],
        accel: [0, 0, 4096],
        rate: [0, 0, 0],
        timer: (i as u64 * 50 % 65_536) as u16,
    }
    .encode()
}

fn main() {
    if std::env::var_os(FLOOR_ENV).is_some() {
        floor(
            std::env::args()
                .skip(1)
                .filter(|a| a.starts_with('/'))
                .collect(),
        );
        return;
    }
    // `cargo test --benches` runs this too: measure under `cargo bench`.
    if !std::env::args().any(|a| a == "--bench") {
        println!("run: measure with `cargo bench --bench run`");
        return;
    }
    let sensors: Vec<usize> = std::env::var("FIELDCAL_BENCH_SENSORS")
        .unwrap_or_else(|_| "1,16,64".into())
        .split(',')
        .filter_map(|n| n.trim().parse().ok())
        .collect();
    let seconds: u64 = std::env::var("FIELDCAL_BENCH_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    println!(
        "| sensors, 20 Hz each | fieldcal run, CPU per reading | floor (a thread per sensor) | fieldcal / floor | fieldcal RSS |"
    );
    println!("|---|---|---|---|---|");
    // Best of several alternated runs (the machine's own wake-up costs
    // move the floor by a third from one run to the next). A pair that
    // failed prints its own row; the best-of row says of how many runs.
    let runs: usize = std::env::var("FIELDCAL_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3)
        .max(1);
    for &n in &sensors {
        let (mut daemon, mut floor) = (Vec::new(), Vec::new());
        for _ in 0..runs {
            match (
                measure(n, seconds, Kind::Daemon),
                measure(n, seconds, Kind::Floor),
            ) {
                (Ok(d), Ok(f)) => {
                    daemon.push(d);
                    floor.push(f);
                }
                (d, f) => println!("| {n} | {:?} | {:?} | – | – |", d.err(), f.err()),
            }
        }
        let best = |all: &[Measured]| {
            all.iter()
                .min_by(|a, b| a.cpu_per_reading_us.total_cmp(&b.cpu_per_reading_us))
                .map(|m| (m.cpu_per_reading_us, m.readings, m.rss_mb))
        };
        let range = |all: &[Measured]| {
            let (low, high) = all.iter().fold((f64::INFINITY, 0.0f64), |(l, h), m| {
                (l.min(m.cpu_per_reading_us), h.max(m.cpu_per_reading_us))
            });
            format!("{low:.1}–{high:.1}")
        };
        if let (Some(d), Some(f)) = (best(&daemon), best(&floor)) {
            println!(
                "| {n} | {:.1} µs ({} readings; {} of {} runs: {} µs) | {:.1} µs ({} readings; {} µs) | {:.1}× | {:.1} MB |",
                d.0,
                d.1,
                daemon.len(),
                runs,
                range(&daemon),
                f.0,
                f.1,
                range(&floor),
                d.0 / f.0,
                d.2,
            );
        }
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Daemon,
    Floor,
}

struct Measured {
    cpu_per_reading_us: f64,
    readings: u64,
    rss_mb: f64,
}

/// One child (the daemon or the floor) reading `n` IMUs for `seconds`.
fn measure(n: usize, seconds: u64, kind: Kind) -> Result<Measured, String> {
    let dir = tempfile::tempdir().map_err(|e| format!("tempdir: {e}"))?;
    let mut masters = Vec::new();
    let mut slaves = Vec::new();
    for _ in 0..n {
        let (master, slave) = TTYPort::pair().map_err(|e| format!("pty pair: {e}"))?;
        close_on_exec(master.as_raw_fd());
        close_on_exec(slave.as_raw_fd());
        masters.push(master);
        slaves.push(slave);
    }
    let paths: Vec<String> = slaves
        .iter()
        .map(|s| s.name().ok_or("a pty without a name"))
        .collect::<Result<_, _>>()?;
    let mut child = match kind {
        Kind::Daemon => {
            let config = dir.path().join("fieldcal.toml");
            std::fs::write(&config, daemon_config(&paths, dir.path()))
                .map_err(|e| format!("config: {e}"))?;
            Command::new(daemon_binary())
                .arg("run")
                .arg("--config")
                .arg(&config)
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .spawn()
        }
        Kind::Floor => std::env::current_exe().and_then(|me| {
            Command::new(me)
                .args(&paths)
                .env(FLOOR_ENV, "1")
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .spawn()
        }),
    }
    .map_err(|e| format!("cannot start the child: {e}"))?;
    let readings = Arc::new(AtomicU64::new(0));
    let counter = match count_readings(&mut child, &readings) {
        Ok(counter) => counter,
        Err(e) => {
            let _ = child.kill();
            let _ = child.wait();
            return Err(e);
        }
    };
    let running = Arc::new(AtomicBool::new(true));
    let writer = {
        let running = running.clone();
        std::thread::spawn(move || write_frames(masters, &running))
    };

    std::thread::sleep(WARM_UP);
    let pid = child.id() as i32;
    let cpu_before = process_cpu(pid);
    let read_before = readings.load(Ordering::Relaxed);
    std::thread::sleep(Duration::from_secs(seconds));
    let read_after = readings.load(Ordering::Relaxed);
    let cpu_after = process_cpu(pid);
    let rss_mb = rss_mb(pid);
    let exited = child.try_wait();
    let _ = child.kill();
    let _ = child.wait();
    running.store(false, Ordering::Relaxed);
    let _ = writer.join();
    let _ = counter.join();
    drop(slaves);

    if let Ok(Some(status)) = exited {
        return Err(format!("the child ended before the window did: {status}"));
    }
    let read = read_after - read_before;
    let expected = n as u64 * u64::from(RATE_HZ) * seconds;
    if read < expected * 9 / 10 {
        return Err(format!(
            "{read} readings of {expected} sent: the child fell behind"
        ));
    }
    let cpu = cpu_after?.saturating_sub(cpu_before?);
    Ok(Measured {
        cpu_per_reading_us: cpu.as_secs_f64() * 1e6 / read as f64,
        readings: read,
        rss_mb,
    })
}

/// The daemon measured: this build's, or another build's given in
/// `FIELDCAL_BENCH_BIN` (to compare two commits in one run).
fn daemon_binary() -> std::ffi::OsString {
    std::env::var_os("FIELDCAL_BENCH_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_fieldcal").into())
}

fn daemon_config(paths: &[String], dir: &std::path::Path) -> String {
    let mut text = format!(
        "[daemon]\nstate_dir = \"{}\"\nstatus_interval_s = 1.0\n\n[outputs]\nstdout = true\n",
        dir.join("state").display()
    );
    for (k, path) in paths.iter().enumerate() {
        text.push_str(&format!(
            "\n[[source]]\nname = \"imu{k}\"\nkind = \"falcon\"\nport = \"{path}\"\nretry_s = 0.2\n\n[[sensor]]\nname = \"compass{k}\"\nsource = \"imu{k}\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
        ));
    }
    text
}

/// Counts the READING lines of the child's stdout into `readings`.
fn count_readings(
    child: &mut Child,
    readings: &Arc<AtomicU64>,
) -> Result<std::thread::JoinHandle<()>, String> {
    let stdout = child.stdout.take().ok_or("no stdout from the child")?;
    let readings = readings.clone();
    Ok(std::thread::spawn(move || {
        let mut lines = BufReader::with_capacity(1 << 16, stdout);
        let mut line = Vec::new();
        while matches!(lines.read_until(b'\n', &mut line), Ok(n) if n > 0) {
            if line.starts_with(b"{\"class\":\"READING\"") {
                readings.fetch_add(1, Ordering::Relaxed);
            }
            line.clear();
        }
    }))
}

/// Writes frame after frame to every pty, [`RATE_HZ`] a second each, until
/// `running` is cleared.
fn write_frames(mut masters: Vec<TTYPort>, running: &AtomicBool) {
    let period = Duration::from_secs(1) / RATE_HZ;
    let start = Instant::now();
    let mut i = 0usize;
    while running.load(Ordering::Relaxed) {
        let bytes = frame(i);
        for master in &mut masters {
            // A child that is gone is noticed by its count.
            let _ = master.write_all(&bytes);
        }
        i += 1;
        if let Some(wait) = (start + period * i as u32).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
}

/// CPU time of process `pid` so far: every thread's, user and system,
/// those that have ended included (its CPU-time clock, to the nanosecond).
fn process_cpu(pid: i32) -> Result<Duration, String> {
    let mut clock: libc::clockid_t = 0;
    // SAFETY: both calls write only into the locals passed by pointer.
    let (rc, time) = unsafe {
        let rc = libc::clock_getcpuclockid(pid, &mut clock);
        if rc != 0 {
            return Err(format!("clock_getcpuclockid({pid}): error {rc}"));
        }
        let mut time: libc::timespec = std::mem::zeroed();
        (libc::clock_gettime(clock, &mut time), time)
    };
    if rc != 0 {
        return Err(format!(
            "clock_gettime of process {pid}: {}",
            std::io::Error::last_os_error()
        ));
    }
    Ok(Duration::new(time.tv_sec as u64, time.tv_nsec as u32))
}

/// Resident memory of process `pid`, in MB.
fn rss_mb(pid: i32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|kb| kb.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1000.0)
}

/// The floor: a thread per port, each reading and decoding its frames and
/// writing one line per reading, as the daemon's READING.
fn floor(paths: Vec<String>) {
    let threads: Vec<_> = paths
        .into_iter()
        .enumerate()
        .map(|(k, path)| {
            std::thread::spawn(move || {
                let Ok(mut port) = serialport::new(&path, 115_200)
                    .timeout(Duration::from_millis(500))
                    .open_native()
                else {
                    return;
                };
                let mut decoder = FalconDecoder::new();
                let mut buf = [0u8; 4096];
                let mut line = Vec::with_capacity(128);
                let mut floats = ryu::Buffer::new();
                let mut ints = itoa::Buffer::new();
                loop {
                    let n = match port.read(&mut buf) {
                        Ok(n) => n,
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                        Err(_) => return,
                    };
                    decoder.decode(&buf[..n], |frame| {
                        let time = SystemTime::now()
                            .duration_since(SystemTime::UNIX_EPOCH)
                            .map_or(0.0, |d| d.as_secs_f64());
                        line.clear();
                        line.extend_from_slice(b"{\"class\":\"READING\",\"sensor\":\"compass");
                        line.extend_from_slice(ints.format(k).as_bytes());
                        line.extend_from_slice(b"\",\"time\":");
                        line.extend_from_slice(floats.format(time).as_bytes());
                        line.extend_from_slice(b",\"raw\":[");
                        line.extend_from_slice(floats.format(f64::from(frame.mag[0])).as_bytes());
                        line.push(b',');
                        line.extend_from_slice(floats.format(f64::from(frame.mag[1])).as_bytes());
                        line.extend_from_slice(b"],\"calibrated\":false}\n");
                        let _ = std::io::stdout().lock().write_all(&line);
                    });
                }
            })
        })
        .collect();
    for thread in threads {
        let _ = thread.join();
    }
}
