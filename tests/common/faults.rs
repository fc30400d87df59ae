//! Helpers for the fault tests (tests/faults.rs): a `fieldcal run` child
//! whose spawn can be adjusted (signal dispositions, limits) and whose pid
//! is known (resident memory, `prlimit`), plus small utilities.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::fieldcal;

/// A running `fieldcal run --config FILE` with its stdout parsed line by
/// line and its stderr collected.
pub struct FaultDaemon {
    child: Child,
    lines: Receiver<Value>,
    stderr: Arc<Mutex<String>>,
}

impl FaultDaemon {
    /// Starts the daemon; `adjust` may change the command before the spawn
    /// (for example add a `pre_exec`).
    pub fn start(config: &Path, adjust: impl FnOnce(&mut Command)) -> FaultDaemon {
        let mut command = fieldcal();
        command
            .args(["run", "--config", config.to_str().unwrap()])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        adjust(&mut command);
        let mut child = command.spawn().expect("start fieldcal run");
        let stdout = child.stdout.take().unwrap();
        let stderr_pipe = child.stderr.take().unwrap();
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                let value: Value = serde_json::from_str(&line)
                    .unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
                if tx.send(value).is_err() {
                    break;
                }
            }
        });
        let stderr = Arc::new(Mutex::new(String::new()));
        {
            let stderr = stderr.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stderr_pipe).lines() {
                    let Ok(line) = line else { break };
                    let mut s = stderr.lock().unwrap();
                    s.push_str(&line);
                    s.push('\n');
                }
            });
        }
        FaultDaemon {
            child,
            lines,
            stderr,
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn stderr(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }

    /// True while the child has not exited.
    pub fn is_running(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// The next stdout line that satisfies `want`.
    pub fn wait_for(
        &mut self,
        timeout: Duration,
        what: &str,
        want: impl Fn(&Value) -> bool,
    ) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(v) if want(&v) => return v,
                Ok(_) => {}
                Err(RecvTimeoutError::Timeout) => {
                    panic!("no {what} within {timeout:?}; stderr:\n{}", self.stderr())
                }
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("fieldcal ended before {what}; stderr:\n{}", self.stderr())
                }
            }
        }
    }

    /// Waits until the log (stderr) contains `needle`.
    pub fn wait_for_log(&self, timeout: Duration, needle: &str) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let log = self.stderr();
            if log.contains(needle) {
                return log;
            }
            if Instant::now() > deadline {
                panic!("no log line with {needle:?} within {timeout:?}; stderr:\n{log}");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// SIGTERM, then the exit status (10 s at most).
    pub fn terminate(&mut self) -> ExitStatus {
        // SAFETY: kill(2) on our own child's pid; no memory is touched.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let stderr = self.stderr.clone();
        super::daemon::wait_child(&mut self.child, Duration::from_secs(10), || {
            stderr.lock().unwrap().clone()
        })
    }
}

impl Drop for FaultDaemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A falcon capture of `turns` turns of a noisy simulated compass (10 s a
/// turn, 50 ms a frame), written into `dir`.
pub fn long_capture(dir: &Path, turns: u32) -> PathBuf {
    let capture = dir.join("long.fcap");
    super::run_ok(&[
        "simulate",
        "--format",
        "falcon",
        "--turns",
        &turns.to_string(),
        "--noise",
        "2",
        "--offset-x",
        "120",
        "--offset-y",
        "-60",
        "-o",
        capture.to_str().unwrap(),
    ]);
    capture
}

/// A configuration replaying `capture` at `speed` with a state directory
/// `<dir>/state`, STATUS every 0.2 s, and the given outputs.
pub fn replay_config(dir: &Path, capture: &Path, speed: &str, outputs: &str) -> PathBuf {
    super::daemon::write_config(
        dir,
        &format!(
            r#"
[daemon]
state_dir = "{state}"
status_interval_s = 0.2

[outputs]
{outputs}

[[source]]
name = "imu"
kind = "replay"
file = "{capture}"
speed = {speed}

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]
"#,
            state = dir.join("state").display(),
            capture = capture.display(),
        ),
    )
}

/// A loopback port that was free a moment ago.
pub fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// Connects, retrying for up to 10 s while the daemon starts listening.
pub fn connect_tcp(port: u16) -> std::net::TcpStream {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match std::net::TcpStream::connect(("127.0.0.1", port)) {
            Ok(s) => return s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("cannot connect to 127.0.0.1:{port}: {e}"),
        }
    }
}

/// Sends one command line over the daemon's Unix socket and closes it.
pub fn send_unix_command(socket: &Path, command: &str) {
    use std::io::Write;
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut stream = loop {
        match std::os::unix::net::UnixStream::connect(socket) {
            Ok(s) => break s,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("cannot connect to {}: {e}", socket.display()),
        }
    };
    writeln!(stream, "{command}").unwrap();
    stream.flush().unwrap();
    // Give the daemon a moment to read it before the close.
    std::thread::sleep(Duration::from_millis(100));
}

/// The resident set of a process in kB, from /proc/<pid>/status.
pub fn vm_rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .unwrap_or_else(|| panic!("no VmRSS in /proc/{pid}/status"));
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// Names of the AtomicFile temporaries (`.<name>.tmp.<pid>.<n>`) in `dir`.
pub fn temp_files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') && n.contains(".tmp."))
        .collect();
    names.sort();
    names
}

/// A small xorshift generator: random kill delays without a dependency.
pub struct XorShift(pub u64);

impl XorShift {
    pub fn seeded() -> XorShift {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as u64;
        XorShift(nanos | 1)
    }

    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}
