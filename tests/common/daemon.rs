//! Running the real `fieldcal run` in a child process and reading what it
//! publishes, line by line, with the time each line arrived.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::fieldcal;

pub struct Daemon {
    child: Child,
    lines: Receiver<(Instant, Value)>,
    stderr: Arc<Mutex<String>>,
    /// The thread that copies stderr: finished once the child's stderr closes.
    stderr_reader: Option<std::thread::JoinHandle<()>>,
    /// Every line seen so far, in order.
    pub seen: Vec<Value>,
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// Writes a configuration file into `dir` and returns its path.
pub fn write_config(dir: &Path, text: &str) -> PathBuf {
    let path = dir.join("fieldcal.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The `[daemon]`, `[outputs]` and replay `[[source]]` "imu" sections of
/// a configuration replaying `capture` at `speed` (a TOML value: `20.0`,
/// `"max"`) with a state directory `<dir>/state`, STATUS every 0.2 s, and
/// the given `[outputs]` lines; the sensors follow.
fn replay_sections(dir: &Path, capture: &Path, speed: &str, outputs: &str) -> String {
    format!(
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
"#,
        state = dir.join("state").display(),
        capture = capture.display(),
    )
}

/// A configuration replaying `capture` at `speed` into a 2-axis compass
/// (the sections of [`replay_sections`]).
pub fn replay_config(dir: &Path, capture: &Path, speed: &str, outputs: &str) -> PathBuf {
    let head = replay_sections(dir, capture, speed, outputs);
    write_config(
        dir,
        &format!(
            r#"{head}
[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]
"#
        ),
    )
}

/// A configuration replaying `capture` (a Falcon-GX capture of a tumbling
/// IMU) at `speed` into a 3-axis magnetometer `compass` (2000 counts per
/// gauss) tilt-compensated by a 3-axis accelerometer `level` (4096 per g)
/// (the sections of [`replay_sections`]).
pub fn tumble_config(dir: &Path, capture: &Path, speed: &str, outputs: &str) -> PathBuf {
    let head = replay_sections(dir, capture, speed, outputs);
    write_config(
        dir,
        &format!(
            r#"{head}
[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y", "z"]
lsb_per_gauss = 2000.0
tilt = "level"

[[sensor]]
name = "level"
source = "imu"
field = "accel"
axes = ["x", "y", "z"]
lsb_per_g = 4096.0
"#
        ),
    )
}

impl Daemon {
    pub fn start(config: &Path, env: &[(&str, &str)]) -> Daemon {
        Daemon::start_with(config, |command| {
            for (k, v) in env {
                command.env(k, v);
            }
        })
    }

    /// Starts the daemon; `adjust` may change the command before the spawn
    /// (environment, a `pre_exec` for signal dispositions or limits).
    pub fn start_with(config: &Path, adjust: impl FnOnce(&mut Command)) -> Daemon {
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
                if tx.send((Instant::now(), value)).is_err() {
                    break;
                }
            }
        });
        let stderr = Arc::new(Mutex::new(String::new()));
        let stderr_reader = {
            let stderr = stderr.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stderr_pipe).lines() {
                    let Ok(line) = line else { break };
                    let mut s = stderr.lock().unwrap();
                    s.push_str(&line);
                    s.push('\n');
                }
            })
        };
        Daemon {
            child,
            lines,
            stderr,
            stderr_reader: Some(stderr_reader),
            seen: Vec::new(),
        }
    }

    pub fn stderr(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// True while the child has not exited.
    pub fn is_running(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
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

    /// The next line that satisfies `want`, with its arrival time.
    pub fn wait_for(
        &mut self,
        timeout: Duration,
        what: &str,
        want: impl Fn(&Value) -> bool,
    ) -> (Instant, Value) {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok((at, v)) => {
                    self.seen.push(v.clone());
                    if want(&v) {
                        return (at, v);
                    }
                }
                Err(RecvTimeoutError::Timeout) => {
                    panic!("no {what} within {timeout:?}; stderr:\n{}", self.stderr())
                }
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("fieldcal ended before {what}; stderr:\n{}", self.stderr())
                }
            }
        }
    }

    /// [`Daemon::wait_for`] when the arrival time does not matter.
    pub fn wait_for_value(
        &mut self,
        timeout: Duration,
        what: &str,
        want: impl Fn(&Value) -> bool,
    ) -> Value {
        self.wait_for(timeout, what, want).1
    }

    /// Every remaining line until the daemon closes its stdout.
    pub fn drain(&mut self, timeout: Duration) -> Vec<Value> {
        let deadline = Instant::now() + timeout;
        let mut out = Vec::new();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok((_, v)) => {
                    self.seen.push(v.clone());
                    out.push(v);
                }
                Err(RecvTimeoutError::Disconnected) => return out,
                Err(RecvTimeoutError::Timeout) => {
                    panic!("fieldcal still running after {timeout:?}")
                }
            }
        }
    }

    /// SIGTERM, then the exit status (10 s at most).
    pub fn terminate(&mut self) -> ExitStatus {
        // SAFETY: kill(2) on our own child's pid; no memory is touched.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        self.wait(Duration::from_secs(10))
    }

    /// Waits for the child to exit, then (for up to 5 s) for the last of
    /// its stderr to be copied, so that `stderr()` afterwards holds all of it.
    pub fn wait(&mut self, timeout: Duration) -> ExitStatus {
        let stderr = self.stderr.clone();
        let status = wait_child(&mut self.child, timeout, || stderr.lock().unwrap().clone());
        if let Some(reader) = self.stderr_reader.take() {
            let deadline = Instant::now() + Duration::from_secs(5);
            while !reader.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(5));
            }
            if reader.is_finished() {
                let _ = reader.join();
            }
        }
        status
    }
}

/// Waits for a child to exit; past `timeout` it is killed and the test
/// fails with what the child wrote on stderr.
pub fn wait_child(child: &mut Child, timeout: Duration, stderr: impl Fn() -> String) -> ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!(
                "fieldcal did not exit within {timeout:?}; stderr:\n{}",
                stderr()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn is_class(v: &Value, class: &str) -> bool {
    v["class"] == class
}

/// Sends one command line to a TCP subscriber and returns the answer's
/// lines up to its STATUS reply, or its ERROR when refused.
pub fn ask(stream: &mut std::net::TcpStream, command: &str) -> Vec<Value> {
    use std::io::Write;
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    writeln!(stream, "{command}").unwrap();
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut out = Vec::new();
    loop {
        let mut line = String::new();
        assert!(reader.read_line(&mut line).unwrap() > 0, "closed: {out:?}");
        let v: Value = serde_json::from_str(&line).unwrap();
        let done = (is_class(&v, "STATUS") && v.get("subscriber").is_some())
            || (is_class(&v, "ERROR") && v.get("sensor").is_none());
        out.push(v);
        if done {
            return out;
        }
    }
}

/// The messages of the ERROR lines of an answer.
pub fn errors(answer: &[Value]) -> Vec<String> {
    answer
        .iter()
        .filter(|v| is_class(v, "ERROR"))
        .map(|v| v["message"].as_str().unwrap_or_default().to_owned())
        .collect()
}
