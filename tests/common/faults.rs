//! Helpers for the fault tests (tests/faults.rs): long captures, free ports,
//! subscribers, resident memory and leftover temporaries. The daemon child
//! itself is [`super::daemon::Daemon`].

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

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
