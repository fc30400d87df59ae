//! Helpers for the fault tests (tests/faults.rs, tests/soak.rs): long
//! captures, free ports, subscribers, resident memory and descriptors,
//! leftover temporaries, a small tmpfs to fill. The daemon child
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
    try_vm_rss_kb(pid).unwrap_or_else(|| panic!("no VmRSS in /proc/{pid}/status"))
}

/// [`vm_rss_kb`], or None when the process is gone.
pub fn try_vm_rss_kb(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
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

/// A small tmpfs mounted over a directory for the life of the guard.
pub struct TmpfsMount(PathBuf);

impl TmpfsMount {
    /// Mounts a tmpfs of `size` bytes at `at` (created), or says why not.
    pub fn mount(at: &Path, size: usize) -> Result<TmpfsMount, std::io::Error> {
        use std::ffi::CString;
        std::fs::create_dir_all(at)?;
        let target = CString::new(at.as_os_str().as_encoded_bytes()).unwrap();
        let options = CString::new(format!("size={size},mode=0755")).unwrap();
        // SAFETY: mount(2) with NUL-terminated strings that outlive the call.
        let rc = unsafe {
            libc::mount(
                c"tmpfs".as_ptr(),
                target.as_ptr(),
                c"tmpfs".as_ptr(),
                0,
                options.as_ptr().cast(),
            )
        };
        if rc == 0 {
            Ok(TmpfsMount(at.to_path_buf()))
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
}

impl Drop for TmpfsMount {
    fn drop(&mut self) {
        let target = std::ffi::CString::new(self.0.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: umount2(2) on the path this guard mounted; a lazy detach,
        // so a daemon still holding it open cannot keep the mount.
        unsafe { libc::umount2(target.as_ptr(), libc::MNT_DETACH) };
    }
}

impl TmpfsMount {
    /// Makes the mounted tmpfs read-only (MS_REMOUNT | MS_RDONLY).
    pub fn remount_read_only(&self) -> Result<(), std::io::Error> {
        let target = std::ffi::CString::new(self.0.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: mount(2) with NUL-terminated strings that outlive the call.
        let rc = unsafe {
            libc::mount(
                c"tmpfs".as_ptr(),
                target.as_ptr(),
                c"tmpfs".as_ptr(),
                libc::MS_REMOUNT | libc::MS_RDONLY,
                std::ptr::null(),
            )
        };
        if rc == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
}

/// How many descriptors a process has open (the entries of
/// /proc/<pid>/fd), or None when the process is gone.
pub fn fd_count(pid: u32) -> Option<usize> {
    Some(std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count())
}
