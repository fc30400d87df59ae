//! A mock Falcon-GX-style device on a real pseudo-terminal pair. The port
//! the code under test opens is a symlink to the pty's slave, so the device
//! can be unplugged (the pty closed, the path gone) and plugged back (a new
//! pty behind the same path), as a USB adapter does. A looped device
//! ([`FalconPty::plug_in_looped`]) starts its chunks over when they run
//! out, so it can stream for hours.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use fieldcal::mock::falcon::MockFalcon;
use serialport::{SerialPort, TTYPort};

pub struct FalconPty {
    _dir: tempfile::TempDir,
    link: PathBuf,
    device: Arc<Mutex<MockFalcon>>,
    /// When each chunk was written to the pty, in order.
    sent_at: Arc<Mutex<Vec<Instant>>>,
    period: Duration,
    running: Option<(Arc<AtomicBool>, JoinHandle<()>)>,
    /// The chunks again, for a looped device.
    looped: Option<Arc<Vec<Vec<u8>>>>,
    /// Chunks sent and start and stop commands seen by the devices before
    /// the current one, which a loop replaced.
    carried: Arc<Mutex<(usize, u32, u32)>>,
}

impl FalconPty {
    /// Plugs in a device that sends one chunk per `period` once started.
    pub fn plug_in(chunks: Vec<Vec<u8>>, period: Duration) -> Self {
        Self::plug_in_with(chunks, period, false)
    }

    /// A device that, once it has sent its last chunk, starts over from the
    /// first (still streaming), for as long as it stays plugged in. Give it
    /// whole turns, so the heading runs on smoothly.
    pub fn plug_in_looped(chunks: Vec<Vec<u8>>, period: Duration) -> Self {
        Self::plug_in_with(chunks, period, true)
    }

    fn plug_in_with(chunks: Vec<Vec<u8>>, period: Duration, looped: bool) -> Self {
        let dir = tempfile::tempdir().expect("tempdir");
        let link = dir.path().join("ttyFALCON");
        let looped = looped.then(|| Arc::new(chunks.clone()));
        let mut pty = FalconPty {
            _dir: dir,
            link,
            device: Arc::new(Mutex::new(MockFalcon::new(chunks))),
            sent_at: Arc::new(Mutex::new(Vec::new())),
            period,
            running: None,
            looped,
            carried: Arc::new(Mutex::new((0, 0, 0))),
        };
        pty.plug();
        pty
    }

    /// True while the device is plugged in.
    pub fn is_plugged(&self) -> bool {
        self.running.is_some()
    }

    /// The port path the code under test opens.
    pub fn path(&self) -> &Path {
        &self.link
    }

    /// Pulls the cable: the pty closes and the path disappears.
    pub fn unplug(&mut self) {
        if let Some((run, thread)) = self.running.take() {
            run.store(false, Ordering::Relaxed);
            thread.join().expect("pty thread");
        }
        let _ = std::fs::remove_file(&self.link);
        self.device.lock().unwrap().power_cycle();
    }

    /// Plugs the device (back) in, behind the same path.
    pub fn plug(&mut self) {
        assert!(self.running.is_none(), "already plugged in");
        let (mut master, slave) = TTYPort::pair().expect("pty pair");
        use std::os::fd::AsRawFd;
        super::close_on_exec(master.as_raw_fd());
        super::close_on_exec(slave.as_raw_fd());
        let slave_name = slave.name().expect("pty slave name");
        let _ = std::fs::remove_file(&self.link);
        std::os::unix::fs::symlink(&slave_name, &self.link).expect("symlink to pty");
        master
            .set_timeout(Duration::from_millis(2))
            .expect("pty timeout");
        let run = Arc::new(AtomicBool::new(true));
        let device = self.device.clone();
        let sent_at = self.sent_at.clone();
        let period = self.period;
        let looped = self.looped.clone();
        let carried = self.carried.clone();
        let thread = {
            let run = run.clone();
            std::thread::spawn(move || {
                // Keep the slave open so the master never sees EIO while
                // the code under test reopens the port.
                let _slave = slave;
                let mut buf = [0u8; 256];
                let mut next = Instant::now() + period;
                while run.load(Ordering::Relaxed) {
                    match master.read(&mut buf) {
                        Ok(n) if n > 0 => device.lock().unwrap().receive(&buf[..n]),
                        _ => {}
                    }
                    if Instant::now() >= next {
                        next += period;
                        let mut device = device.lock().unwrap();
                        if let Some(chunks) = &looped
                            && device.is_streaming()
                            && device.remaining() == 0
                        {
                            // Start over, still streaming: the new device
                            // is told to start, a command the host never
                            // sent, so it is not carried.
                            let (starts, stops) = device.commands_seen();
                            let mut carried = carried.lock().unwrap();
                            carried.0 += device.sent();
                            carried.1 += starts - 1;
                            carried.2 += stops;
                            *device = MockFalcon::new(chunks.to_vec());
                            device.receive(&fieldcal::protocol::falcon::START_CONTINUOUS);
                        }
                        let chunk = device.tick().map(<[u8]>::to_vec);
                        drop(device);
                        if let Some(chunk) = chunk {
                            let _ = master.write_all(&chunk);
                            // A looped device may stream for hours: its
                            // times are not kept.
                            if looped.is_none() {
                                sent_at.lock().unwrap().push(Instant::now());
                            }
                        }
                    }
                }
            })
        };
        self.running = Some((run, thread));
    }

    pub fn sent(&self) -> usize {
        let device = self.device.lock().unwrap();
        self.carried.lock().unwrap().0 + device.sent()
    }

    /// When chunk `index` was sent, if it has been.
    pub fn sent_at(&self, index: usize) -> Option<Instant> {
        self.sent_at.lock().unwrap().get(index).copied()
    }

    pub fn commands_seen(&self) -> (u32, u32) {
        let device = self.device.lock().unwrap();
        let (starts, stops) = device.commands_seen();
        let carried = self.carried.lock().unwrap();
        (carried.1 + starts, carried.2 + stops)
    }

    /// Waits until the device has sent `n` chunks in all.
    pub fn wait_sent(&self, n: usize, timeout: Duration) {
        let deadline = Instant::now() + timeout;
        while self.sent() < n {
            assert!(
                Instant::now() < deadline,
                "device sent only {} of {n} chunks in {timeout:?}",
                self.sent()
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

impl Drop for FalconPty {
    fn drop(&mut self) {
        if let Some((run, thread)) = self.running.take() {
            run.store(false, Ordering::Relaxed);
            let _ = thread.join();
        }
    }
}
