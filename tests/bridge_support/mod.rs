//! Test support for the bridge source: a simulated USB-ISS on the far end of
//! a real pseudo-terminal, an event collector and a captured log.
#![allow(dead_code)]

use std::io::{self, Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use fieldcal::mock::usb_iss::{MockEvent, MockUsbIss};
use fieldcal::source::SourceEvent;
use serialport::{SerialPort, TTYPort};

/// Locks a mutex even if a failed test poisoned it.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// One test at a time: the timing assertions want the two cores to
/// themselves.
pub fn one_at_a_time() -> MutexGuard<'static, ()> {
    static SERIAL: Mutex<()> = Mutex::new(());
    lock(&SERIAL)
}

/// A mock event with the harness's receive time.
#[derive(Debug, Clone)]
pub struct Logged {
    pub at: Instant,
    pub event: MockEvent,
}

/// A [`MockUsbIss`] answering on the master side of a pty pair. The bridge
/// opens [`Harness::port`], the slave side.
pub struct Harness {
    pub port: PathBuf,
    mock: Arc<Mutex<MockUsbIss>>,
    log: Arc<Mutex<Vec<Logged>>>,
    delay: Arc<Mutex<Option<(u8, Duration)>>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    // Held open so the pty stays up while the bridge closes and reopens it.
    _slave: TTYPort,
}

impl Harness {
    pub fn start(mock: MockUsbIss) -> Harness {
        let (mut master, slave) = TTYPort::pair().expect("a pty pair");
        // serialport opens pty pairs without close-on-exec: a fieldcal
        // spawned by a test must not inherit them.
        for fd in [
            std::os::fd::AsRawFd::as_raw_fd(&master),
            std::os::fd::AsRawFd::as_raw_fd(&slave),
        ] {
            // SAFETY: fcntl on descriptors this function owns.
            unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) };
        }
        let port = PathBuf::from(slave.name().expect("the slave pty has a name"));
        master
            .set_timeout(Duration::from_millis(10))
            .expect("set the master's timeout");
        let mock = Arc::new(Mutex::new(mock));
        let log = Arc::new(Mutex::new(Vec::new()));
        let delay = Arc::new(Mutex::new(None));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (mock, log, delay, stop) = (mock.clone(), log.clone(), delay.clone(), stop.clone());
            thread::spawn(move || serve(master, mock, log, delay, stop))
        };
        Harness {
            port,
            mock,
            log,
            delay,
            stop,
            thread: Some(thread),
            _slave: slave,
        }
    }

    pub fn with_mock<R>(&self, f: impl FnOnce(&mut MockUsbIss) -> R) -> R {
        f(&mut lock(&self.mock))
    }

    /// Holds the reply to the next poll of the chip at `address` back by
    /// `delay`.
    pub fn delay_next_poll(&self, address: u8, delay: Duration) {
        *lock(&self.delay) = Some((address, delay));
    }

    /// Everything the mock did so far, timestamped.
    pub fn log(&self) -> Vec<Logged> {
        lock(&self.log).clone()
    }

    /// Receive times of the read commands at `address` that start a poll
    /// (the chip's first data register).
    pub fn poll_times(&self, address: u8, first_register: u8) -> Vec<Instant> {
        lock(&self.log)
            .iter()
            .filter_map(|l| match &l.event {
                MockEvent::Read {
                    address: a,
                    register,
                    acked: true,
                    ..
                } if *a == address && *register == first_register => Some(l.at),
                _ => None,
            })
            .collect()
    }
}

impl Drop for Harness {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn serve(
    mut master: TTYPort,
    mock: Arc<Mutex<MockUsbIss>>,
    log: Arc<Mutex<Vec<Logged>>>,
    delay: Arc<Mutex<Option<(u8, Duration)>>>,
    stop: Arc<AtomicBool>,
) {
    let mut buf = [0u8; 256];
    while !stop.load(Ordering::Relaxed) {
        let n = match master.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::TimedOut => continue,
            Err(_) => {
                thread::sleep(Duration::from_millis(5));
                continue;
            }
        };
        let at = Instant::now();
        let (reply, events) = {
            let mut mock = lock(&mock);
            let reply = mock.feed(&buf[..n]);
            (reply, mock.take_events())
        };
        let mut hold = None;
        {
            let mut delay = lock(&delay);
            if let Some((address, d)) = *delay {
                let polled = events.iter().any(|e| {
                    matches!(e, MockEvent::Read { address: a, sample: Some(_), .. } if *a == address)
                });
                if polled {
                    hold = Some(d);
                    *delay = None;
                }
            }
        }
        lock(&log).extend(events.into_iter().map(|event| Logged { at, event }));
        if let Some(d) = hold {
            thread::sleep(d);
        }
        if !reply.is_empty() {
            let _ = master.write_all(&reply);
        }
    }
}

/// Moves the source's events to a std channel, stamped on arrival, so tests
/// can wait with a timeout.
pub fn collect(
    mut rx: tokio::sync::mpsc::Receiver<SourceEvent>,
) -> std_mpsc::Receiver<(Instant, SourceEvent)> {
    let (tx, out) = std_mpsc::channel();
    thread::spawn(move || {
        while let Some(event) = rx.blocking_recv() {
            if tx.send((Instant::now(), event)).is_err() {
                break;
            }
        }
    });
    out
}

/// Events until one matches `want` (returned last), or panics after
/// `within`.
pub fn wait_for(
    events: &std_mpsc::Receiver<(Instant, SourceEvent)>,
    within: Duration,
    what: &str,
    want: impl Fn(&SourceEvent) -> bool,
) -> Vec<SourceEvent> {
    let deadline = Instant::now() + within;
    let mut seen = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match events.recv_timeout(left) {
            Ok((_, event)) => {
                let done = want(&event);
                seen.push(event);
                if done {
                    return seen;
                }
            }
            Err(_) => panic!(
                "no {what} within {within:?}; saw {} events, last: {:?}",
                seen.len(),
                seen.last()
            ),
        }
    }
}

/// Waits until `handle` finishes, at most `within`; true if it did.
pub fn joins_within(handle: JoinHandle<()>, within: Duration) -> bool {
    let deadline = Instant::now() + within;
    while !handle.is_finished() {
        if Instant::now() >= deadline {
            return false;
        }
        thread::sleep(Duration::from_millis(2));
    }
    handle.join().is_ok()
}

static LOG: Mutex<Vec<u8>> = Mutex::new(Vec::new());

struct LogWriter;

impl Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        lock(&LOG).extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Sends every tracing event of the test binary to a buffer (once).
pub fn capture_log() {
    static INIT: OnceLock<()> = OnceLock::new();
    INIT.get_or_init(|| {
        let _ = tracing_subscriber::fmt()
            .with_writer(|| LogWriter)
            .with_ansi(false)
            .with_max_level(tracing::Level::DEBUG)
            .try_init();
    });
}

/// The captured log lines that mention `needle`.
pub fn log_lines(needle: &str) -> Vec<String> {
    String::from_utf8_lossy(&lock(&LOG))
        .lines()
        .filter(|l| l.contains(needle))
        .map(str::to_string)
        .collect()
}

/// CPU time (user + system, in clock ticks of usually 10 ms) of this
/// process's thread named `name`, from /proc; None if not found.
pub fn thread_cpu_ticks(name: &str) -> Option<u64> {
    let tasks = std::fs::read_dir("/proc/self/task").ok()?;
    for task in tasks.flatten() {
        let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
        if comm.trim() != name {
            continue;
        }
        let stat = std::fs::read_to_string(task.path().join("stat")).ok()?;
        // Fields after the ")" that closes the command name: state is the
        // 1st, utime the 12th and stime the 13th.
        let rest = &stat[stat.rfind(')')? + 1..];
        let fields: Vec<&str> = rest.split_whitespace().collect();
        let utime: u64 = fields.get(11)?.parse().ok()?;
        let stime: u64 = fields.get(12)?.parse().ok()?;
        return Some(utime + stime);
    }
    None
}
