//! The Falcon-GX-style serial source end to end, over real pseudo-terminal
//! pairs: a mock device streams a simulated rotation every 50 ms.

mod common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use common::pty::FalconPty;
use fieldcal::protocol::falcon::{FalconDecoder, FalconFrame};
use fieldcal::sample::Reading;
use fieldcal::sim::{FalconWire, SimSensor};
use fieldcal::source::serial::{SerialConfig, run_serial_source};
use fieldcal::source::{SourceCounters, SourceEvent};
use tokio::sync::{mpsc, watch};

const PERIOD: Duration = Duration::from_millis(50);

/// Chunks a simulated device sends, and the frames a decoder must find in them.
fn simulated(frames: usize, garbage: f64, seed: u64) -> (Vec<Vec<u8>>, Vec<FalconFrame>) {
    let sensor = SimSensor {
        turns: frames as f64 / 200.0,
        noise: 2.0,
        offset_x: 150.0,
        seed,
        ..Default::default()
    };
    let (_, chunks) = sensor
        .falcon_capture(&FalconWire {
            garbage,
            ..Default::default()
        })
        .unwrap();
    let chunks: Vec<Vec<u8>> = chunks.into_iter().map(|c| c.bytes).collect();
    let mut decoder = FalconDecoder::new();
    let mut expected = Vec::new();
    for c in &chunks {
        decoder.decode(c, |f| expected.push(f));
    }
    assert_eq!(expected.len(), frames);
    (chunks, expected)
}

fn fields(r: &Reading) -> ([i16; 3], [i16; 3], [i16; 3], u16) {
    (
        r.mag.unwrap(),
        r.accel.unwrap(),
        r.gyro.unwrap(),
        r.timer.unwrap(),
    )
}

fn frame_fields(f: &FalconFrame) -> ([i16; 3], [i16; 3], [i16; 3], u16) {
    (f.mag, f.accel, f.rate, f.timer)
}

struct Running {
    events: mpsc::Receiver<SourceEvent>,
    counters: Arc<SourceCounters>,
    stop: watch::Sender<bool>,
    task: tokio::task::JoinHandle<()>,
}

fn start(pty: &FalconPty) -> Running {
    start_with(SerialConfig {
        retry_interval: Duration::from_millis(100),
        ..SerialConfig::new(pty.path())
    })
}

fn start_with(config: SerialConfig) -> Running {
    let (tx, events) = mpsc::channel(4096);
    let counters = Arc::new(SourceCounters::default());
    let (stop, stop_rx) = watch::channel(false);
    let task = tokio::spawn(run_serial_source(config, tx, counters.clone(), stop_rx));
    Running {
        events,
        counters,
        stop,
        task,
    }
}

impl Running {
    /// The first `n` readings, and the other events before them (fails
    /// after 15 s).
    async fn first(&mut self, n: usize) -> (Vec<Reading>, Vec<SourceEvent>) {
        let (mut readings, mut others) = (Vec::new(), Vec::new());
        collect(
            &mut self.events,
            &mut readings,
            &mut others,
            Duration::from_secs(15),
            |r, _| r.len() >= n,
        )
        .await;
        (readings, others)
    }

    /// Asks the source to stop, and waits for it to end.
    async fn stop_and_wait(&mut self) {
        self.stop.send(true).unwrap();
        (&mut self.task).await.unwrap();
    }
}

/// Collects events until `done` says so, or fails after `timeout`.
async fn collect(
    events: &mut mpsc::Receiver<SourceEvent>,
    readings: &mut Vec<Reading>,
    others: &mut Vec<SourceEvent>,
    timeout: Duration,
    mut done: impl FnMut(&[Reading], &[SourceEvent]) -> bool,
) {
    let deadline = tokio::time::Instant::now() + timeout;
    while !done(readings, others) {
        match tokio::time::timeout_at(deadline, events.recv()).await {
            Ok(Some(SourceEvent::Reading(r))) => readings.push(r),
            Ok(Some(other)) => others.push(other),
            Ok(None) => panic!("the source ended"),
            Err(_) => panic!(
                "timed out with {} readings and events {others:?}",
                readings.len()
            ),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_from_the_device_come_out_decoded_in_order() {
    let (chunks, expected) = simulated(60, 0.01, 7);
    let pty = FalconPty::plug_in(chunks, PERIOD);
    let mut run = start(&pty);
    let (readings, others) = run.first(expected.len()).await;
    run.stop_and_wait().await;

    let got: Vec<_> = readings.iter().map(fields).collect();
    let want: Vec<_> = expected.iter().map(frame_fields).collect();
    assert_eq!(got, want);
    assert!(
        matches!(others.first(), Some(SourceEvent::Connected { .. })),
        "{others:?}"
    );
    // Host receive times: increasing, about one period apart.
    let span = readings.last().unwrap().time - readings[0].time;
    let mean = span / (readings.len() - 1) as f64;
    assert!((0.040..0.065).contains(&mean), "mean period {mean}");
    assert!(readings.windows(2).all(|w| w[1].time >= w[0].time));

    let c = run.counters.snapshot();
    assert_eq!(c.frames_good, 60);
    assert_eq!(c.frames_lost, 0);
    assert_eq!(c.reconnects, 0);
    assert!(c.bytes_skipped > 0, "1 % garbage was spliced in: {c:?}");
    // The device was started, and told to stop when the source stopped.
    let deadline = Instant::now() + Duration::from_secs(2);
    while pty.commands_seen() != (1, 1) {
        assert!(
            Instant::now() < deadline,
            "commands seen {:?}",
            pty.commands_seen()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// A frame cut short by a line that goes quiet is dropped once nothing
/// more comes for `idle_timeout`, so it is not glued to the next frame
/// (the two together would fail the checksum: a bad frame counted where
/// there was none).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_partial_frame_is_dropped_when_the_line_goes_quiet() {
    let frame = |timer: u16| {
        FalconFrame {
            mag: [100 + timer as i16, -200, 300],
            accel: [0, 0, 4096],
            rate: [0, 0, 0],
            timer,
        }
        .encode()
        .to_vec()
    };
    let cut = frame(2)[..11].to_vec();
    let chunks = vec![frame(1), cut, frame(3), frame(4)];
    // A chunk every 800 ms, quiet after 100 ms: the cut frame is dropped
    // some 700 ms before the next arrives (the device catches up on a
    // late chunk, so a stalled test thread narrows that gap).
    let pty = FalconPty::plug_in(chunks, Duration::from_millis(800));
    let mut run = start_with(SerialConfig {
        idle_timeout: Duration::from_millis(100),
        ..SerialConfig::new(pty.path())
    });
    let (readings, _) = run.first(3).await;
    run.stop_and_wait().await;
    let timers: Vec<u16> = readings.iter().map(|r| r.timer.unwrap()).collect();
    assert_eq!(timers, [1, 3, 4]);
    let c = run.counters.snapshot();
    assert_eq!(
        (c.frames_good, c.frames_bad, c.bytes_skipped),
        (3, 0, 11),
        "{c:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unplugged_device_comes_back_and_samples_resume() {
    let (chunks, expected) = simulated(70, 0.0, 11);
    let mut pty = FalconPty::plug_in(chunks, PERIOD);
    let mut run = start(&pty);
    let (mut readings, mut others) = run.first(20).await;

    pty.unplug();
    let sent_before = pty.sent();
    collect(
        &mut run.events,
        &mut readings,
        &mut others,
        Duration::from_secs(5),
        |_, o| {
            o.iter()
                .any(|e| matches!(e, SourceEvent::Disconnected { .. }))
        },
    )
    .await;
    // Stay unplugged for a few retry intervals: the path is gone meanwhile.
    tokio::time::sleep(Duration::from_millis(400)).await;
    pty.plug();
    collect(
        &mut run.events,
        &mut readings,
        &mut others,
        Duration::from_secs(20),
        |r, _| r.last().and_then(|r| r.timer) == expected.last().map(|f| f.timer),
    )
    .await;
    run.stop_and_wait().await;

    // Nothing twice, nothing out of order.
    let timers: Vec<u16> = readings.iter().map(|r| r.timer.unwrap()).collect();
    assert!(timers.windows(2).all(|w| w[1] > w[0]), "{timers:?}");
    // Every frame sent after the plug came back arrived; at most the one
    // frame in flight when the cable was pulled is lost, as on a real line.
    let want: Vec<_> = expected.iter().map(frame_fields).collect();
    let got: Vec<_> = readings.iter().map(fields).collect();
    assert_eq!(&got[got.len() - (70 - sent_before)..], &want[sent_before..]);
    assert!(got.len() >= 69, "lost {} frames", 70 - got.len());
    for g in &got {
        assert!(want.contains(g));
    }

    let connects = others
        .iter()
        .filter(|e| matches!(e, SourceEvent::Connected { .. }))
        .count();
    assert_eq!(connects, 2, "{others:?}");
    assert_eq!(run.counters.snapshot().reconnects, 1);
    // The source sent the start command again to the replugged device.
    assert_eq!(pty.commands_seen().0, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_port_is_retried_without_spinning_and_stops_promptly() {
    let dir = tempfile::tempdir().unwrap();
    let (tx, mut events) = mpsc::channel(16);
    let counters = Arc::new(SourceCounters::default());
    let (stop, stop_rx) = watch::channel(false);
    let config = SerialConfig {
        retry_interval: Duration::from_millis(100),
        ..SerialConfig::new(dir.path().join("ttyNOPE"))
    };
    let started = Instant::now();
    let task = tokio::spawn(run_serial_source(config, tx, counters, stop_rx));
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert!(events.try_recv().is_err(), "no device, no events");
    stop.send(true).unwrap();
    tokio::time::timeout(Duration::from_secs(1), task)
        .await
        .expect("source stops within a second")
        .unwrap();
    assert!(started.elapsed() < Duration::from_secs(2));
}

/// A port the user may not open: `record`, run as an unprivileged user,
/// says so with what to do (the dialout group), keeps retrying, and
/// records once the permission is granted, with no restart. Needs root to
/// make the port unreadable to another user and to run as `nobody`.
#[test]
fn a_port_without_permission_is_explained_and_retried() {
    use std::io::Write;
    use std::os::unix::fs::PermissionsExt;
    use std::os::unix::process::CommandExt;
    use std::process::{Command, Stdio};

    // SAFETY: geteuid(2) has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("skipped: needs root to open a port as another user");
        return;
    }
    const NOBODY: u32 = 65_534;
    let (mut master, slave) = serialport::TTYPort::pair().expect("pty pair");
    let port = serialport::SerialPort::name(&slave).expect("pty name");
    std::fs::set_permissions(&port, std::fs::Permissions::from_mode(0o600)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o777)).unwrap();
    let output = dir.path().join("denied.fcap");
    let mut command = Command::new(env!("CARGO_BIN_EXE_fieldcal"));
    command
        .args(["record", "--port", &port, "--duration", "4", "-o"])
        .arg(&output)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        // As root, std drops the supplementary groups before setuid.
        .uid(NOBODY)
        .gid(NOBODY);
    let child = match command.spawn() {
        Ok(child) => child,
        // The checkout may sit where that user cannot reach it.
        Err(e) if e.raw_os_error() == Some(libc::EACCES) => {
            eprintln!(
                "skipped: user {NOBODY} cannot execute {} ({e})",
                env!("CARGO_BIN_EXE_fieldcal")
            );
            return;
        }
        Err(e) => panic!("cannot start fieldcal: {e}"),
    };
    // Denied for a while, then granted: the next retry (every 2 s) opens it.
    std::thread::sleep(Duration::from_millis(700));
    std::fs::set_permissions(&port, std::fs::Permissions::from_mode(0o666)).unwrap();
    let frame = FalconFrame {
        mag: [100, 200, 300],
        accel: [0, 0, 4096],
        rate: [0, 0, 0],
        timer: 0,
    }
    .encode();
    let deadline = Instant::now() + Duration::from_millis(3800);
    while Instant::now() < deadline {
        let _ = master.write_all(&frame);
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = child.wait_with_output().expect("fieldcal record");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains(&format!("{port}: permission denied")) && stderr.contains("dialout"),
        "no advice naming the port and the group:\n{stderr}"
    );
    // Said once, not at every retry.
    assert_eq!(stderr.matches("permission denied").count(), 1, "{stderr}");
    assert!(
        !stdout.contains("recorded 0 chunks"),
        "nothing recorded after the permission was granted: {stdout}\n{stderr}"
    );
    drop(slave);
}
