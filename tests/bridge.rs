//! The bridge poll source against a simulated USB-ISS over a real
//! pseudo-terminal pair: values, schedule, failures and recovery.

mod bridge_support;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use bridge_support::{
    Harness, capture_log, collect, joins_within, log_lines, one_at_a_time, thread_cpu_ticks,
    wait_for,
};
use fieldcal::mock::usb_iss::{MockEvent, MockUsbIss};
use fieldcal::protocol::chips::Chip;
use fieldcal::protocol::chips::mpu6050;
use fieldcal::sample::Reading;
use fieldcal::source::bridge::{BridgeConfig, I2cSpeed, spawn_bridge_source};
use fieldcal::source::{SourceCounters, SourceEvent};

const PERIOD: Duration = Duration::from_millis(30);

/// The n-th sample the simulated chip serves: every axis different, so a
/// swapped axis or a lost sample shows.
fn sample(chip: Chip, n: u64) -> Reading {
    let n = n as i16;
    let mut r = Reading::default();
    match chip {
        Chip::Adxl345 => r.accel = Some([n, -n, 256 + n]),
        Chip::Mpu6050 => {
            r.accel = Some([n, 2 * n, -3 * n]);
            r.gyro = Some([-n, 7, 3 * n]);
            r.temp_raw = Some(n - 100);
        }
        Chip::Lsm303dlhcAccel => r.accel = Some([n, -n, 1000 - n]),
        Chip::Lsm303dlhcMag => {
            r.mag = Some([n, 500 + n, -n]);
            r.temp_raw = Some(n % 64 - 32);
        }
    }
    r
}

/// What the source must report for the n-th sample (time aside).
fn expected(chip: Chip, n: u64) -> Reading {
    let mut r = sample(chip, n);
    if chip == Chip::Mpu6050 {
        r.temp_c = r.temp_raw.map(mpu6050::temp_c);
    }
    r
}

/// A reading without what the source stamps on it: time and stream.
fn without_time(r: &Reading) -> Reading {
    Reading {
        time: 0.0,
        stream: 0,
        ..*r
    }
}

/// The sample number a reading carries (its first accel or mag value).
fn number(r: &Reading) -> u64 {
    let first = r.accel.or(r.mag).map_or(-1, |v| v[0]);
    u64::try_from(first).expect("a sample number")
}

fn mock_with(chips: &[Chip]) -> MockUsbIss {
    let mut mock = MockUsbIss::with_chips(chips);
    for &chip in chips {
        mock.set_generator(chip.default_address(), Box::new(move |n| sample(chip, n)));
    }
    mock
}

fn config(harness: &Harness, chips: &[Chip]) -> BridgeConfig {
    let mut config = BridgeConfig::new(
        &harness.port,
        chips.iter().map(|&c| (c, c.default_address())).collect(),
    );
    config.period = PERIOD;
    config.retry_interval = Duration::from_millis(200);
    config
}

struct Running {
    handle: thread::JoinHandle<()>,
    events: std::sync::mpsc::Receiver<(Instant, SourceEvent)>,
    counters: Arc<SourceCounters>,
    stop: Arc<AtomicBool>,
}

fn start(config: BridgeConfig) -> Running {
    let (tx, rx) = tokio::sync::mpsc::channel(1024);
    let counters = Arc::new(SourceCounters::default());
    let stop = Arc::new(AtomicBool::new(false));
    let handle =
        spawn_bridge_source(config, tx, counters.clone(), stop.clone()).expect("the source starts");
    Running {
        handle,
        events: collect(rx),
        counters,
        stop,
    }
}

impl Running {
    fn wait_for(
        &self,
        within: Duration,
        what: &str,
        want: impl Fn(&SourceEvent) -> bool,
    ) -> Vec<SourceEvent> {
        wait_for(&self.events, within, what, want)
    }

    fn readings(&self, n: usize) -> Vec<Reading> {
        let mut out = Vec::new();
        while out.len() < n {
            for event in self.wait_for(Duration::from_secs(5), "a reading", |e| {
                matches!(e, SourceEvent::Reading(_))
            }) {
                if let SourceEvent::Reading(r) = event {
                    out.push(r);
                }
            }
        }
        out
    }

    fn stop_within(self, within: Duration) {
        self.stop.store(true, Ordering::Relaxed);
        assert!(
            joins_within(self.handle, within),
            "the source did not end within {within:?} of stop"
        );
    }
}

fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .expect("a clock after 1970")
        .as_secs_f64()
}

fn gaps_ms(times: &[Instant]) -> Vec<f64> {
    times
        .windows(2)
        .map(|w| (w[1] - w[0]).as_secs_f64() * 1000.0)
        .collect()
}

#[test]
fn four_chips_are_decoded_in_order_on_a_steady_schedule() {
    let _serial = one_at_a_time();
    capture_log();
    let harness = Harness::start(mock_with(&Chip::ALL));
    let mut config = config(&harness, &Chip::ALL);
    config.speed = I2cSpeed::Khz400;
    config.timeout = Duration::from_millis(500);
    let t_start = unix_now();
    let run = start(config);

    let first = run.wait_for(Duration::from_secs(5), "Connected", |e| {
        matches!(e, SourceEvent::Connected { .. })
    });
    assert_eq!(first.len(), 1, "Connected comes first: {first:?}");
    let SourceEvent::Connected { device } = &first[0] else {
        unreachable!()
    };
    assert!(
        device.contains(&harness.port.display().to_string()),
        "{device}"
    );
    assert!(
        device.contains("LSM303DLHC magnetometer at 0x1E"),
        "{device}"
    );

    // 101 polls of four chips: each a Raw then a Reading, chips in order.
    const POLLS: usize = 101;
    let mut readings: Vec<Vec<(Reading, Vec<u8>)>> = vec![Vec::new(); 4];
    let mut raw: Option<(u8, Vec<u8>)> = None;
    let mut next_stream = 0u8;
    while readings[3].len() < POLLS {
        let (_, event) = run
            .events
            .recv_timeout(Duration::from_secs(5))
            .expect("events keep coming");
        match event {
            SourceEvent::Raw { stream, bytes, .. } => {
                assert_eq!(stream, next_stream, "chips in poll order");
                next_stream = (next_stream + 1) % 4;
                raw = Some((stream, bytes));
            }
            SourceEvent::Reading(r) => {
                let (stream, bytes) = raw.take().expect("a Raw before each Reading");
                readings[usize::from(stream)].push((r, bytes));
            }
            other => panic!("unexpected event {other:?}"),
        }
    }
    let t_end = unix_now();
    // After the stop, so the last poll has been counted.
    let counters = run.counters.clone();
    run.stop_within(Duration::from_secs(1));
    let counters = counters.snapshot();

    for (i, chip) in Chip::ALL.into_iter().enumerate() {
        let mut last_time = t_start;
        for (k, (reading, bytes)) in readings[i].iter().enumerate() {
            let want = expected(chip, k as u64);
            assert_eq!(
                reading.stream as usize, i,
                "{chip:?}: the stream is the chip's place in the poll list"
            );
            assert_eq!(without_time(reading), want, "{chip:?} poll {k}");
            // The raw bytes are the chip's own layout and replay to the same
            // reading.
            assert_eq!(bytes, &chip.encode(&want), "{chip:?} poll {k} raw");
            assert_eq!(
                chip.decode(bytes, reading.time).unwrap(),
                Reading {
                    stream: 0,
                    ..*reading
                }
            );
            assert!(
                reading.time >= last_time && reading.time <= t_end,
                "{chip:?} time"
            );
            last_time = reading.time;
        }
    }
    assert!(counters.polls >= POLLS as u64, "{counters:?}");
    assert_eq!(counters.poll_errors, 0, "{counters:?}");
    assert_eq!(counters.reconnects, 0, "{counters:?}");
    assert!(counters.bytes_read >= (POLLS * 34) as u64, "{counters:?}");

    let modes: Vec<_> = harness
        .log()
        .into_iter()
        .filter_map(|l| match l.event {
            MockEvent::ModeSet { mode, io, .. } => Some((mode, io)),
            _ => None,
        })
        .collect();
    assert_eq!(modes, vec![(0x70, 0x0A)]);

    // The schedule, from when the simulated bridge received each poll's
    // first read command. Five pty round trips a poll: on a saturated
    // machine a poll can overrun its 30 ms and skip a slot (+0.3 ms on the
    // mean each), so the bound here is looser than the one-chip test's.
    let times = harness.poll_times(0x53, 0x32);
    assert!(times.len() >= POLLS, "{} polls seen", times.len());
    let (mean, min) = mean_and_min(&times[..POLLS]);
    eprintln!(
        "four chips: mean poll period over {} polls {mean:.3} ms, min gap {min:.1} ms",
        POLLS - 1
    );
    assert!((27.0..=36.0).contains(&mean), "mean period {mean:.2} ms");
    assert!(min >= 10.0, "two polls {min:.1} ms apart");
}

/// Mean gap (first to last over the count) and smallest gap, in ms.
fn mean_and_min(times: &[Instant]) -> (f64, f64) {
    let n = times.len() - 1;
    let mean = (times[n] - times[0]).as_secs_f64() * 1000.0 / n as f64;
    let min = gaps_ms(times).into_iter().fold(f64::INFINITY, f64::min);
    (mean, min)
}

/// 100 polls on schedule, then one poll held back by 100 ms: the polls
/// after it keep to the schedule (skipping the missed slots) instead of
/// catching up in a burst.
#[test]
fn polls_keep_a_steady_schedule_and_a_late_one_causes_no_burst() {
    let _serial = one_at_a_time();
    capture_log();
    let harness = Harness::start(mock_with(&[Chip::Adxl345]));
    let mut config = config(&harness, &[Chip::Adxl345]);
    config.timeout = Duration::from_millis(500);
    let run = start(config);

    const STEADY: usize = 101;
    let mut readings = run.readings(STEADY);
    harness.delay_next_poll(0x53, Duration::from_millis(100));
    readings.extend(run.readings(30));
    let counters = run.counters.clone();
    run.stop_within(Duration::from_secs(1));
    let counters = counters.snapshot();

    // Nothing lost: the late poll is one slow poll, not an error.
    for (k, r) in readings.iter().enumerate() {
        assert_eq!(
            without_time(r),
            expected(Chip::Adxl345, k as u64),
            "poll {k}"
        );
    }
    assert_eq!(counters.poll_errors, 0, "{counters:?}");

    let times = harness.poll_times(0x53, 0x32);
    assert!(times.len() >= STEADY + 30, "{} polls seen", times.len());
    let (mean, min) = mean_and_min(&times[..STEADY]);
    eprintln!(
        "one chip: mean poll period over {} polls {mean:.3} ms, min gap {min:.1} ms",
        STEADY - 1
    );
    assert!((27.0..=33.0).contains(&mean), "mean period {mean:.2} ms");
    assert!(min >= 10.0, "two polls {min:.1} ms apart");

    let gaps = gaps_ms(&times[STEADY - 1..STEADY + 30]);
    let late: Vec<usize> = (0..gaps.len()).filter(|&i| gaps[i] > 60.0).collect();
    assert_eq!(late.len(), 1, "one long gap expected: {gaps:.1?}");
    let late = late[0];
    assert!(
        (100.0..250.0).contains(&gaps[late]),
        "the late poll's gap {:.1} ms",
        gaps[late]
    );
    let min = gaps.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        min >= 10.0,
        "a catch-up burst: polls {min:.1} ms apart in {gaps:.1?}"
    );
    // Back on schedule afterwards.
    let after = &gaps[late + 1..];
    assert!(
        after.len() >= 20,
        "{} polls after the late one",
        after.len()
    );
    let mean = after.iter().sum::<f64>() / after.len() as f64;
    eprintln!(
        "late poll: gap {:.1} ms, then mean {mean:.2} ms, min gap overall {min:.1} ms",
        gaps[late]
    );
    assert!(
        (27.0..=33.0).contains(&mean),
        "mean after the late poll {mean:.2} ms"
    );
}

#[test]
fn a_nacking_chip_is_named_counted_and_recovers() {
    let _serial = one_at_a_time();
    capture_log();
    let chips = [Chip::Adxl345, Chip::Lsm303dlhcMag];
    let harness = Harness::start(mock_with(&chips));
    let port = harness.port.display().to_string();
    let mut config = config(&harness, &chips);
    config.timeout = Duration::from_millis(200);
    let run = start(config);
    run.readings(6);

    harness.with_mock(|m| m.set_nack(0x1E, true));
    let seen = run.wait_for(Duration::from_secs(3), "Disconnected", |e| {
        matches!(e, SourceEvent::Disconnected { .. })
    });
    let Some(SourceEvent::Disconnected { device, reason }) = seen.last() else {
        unreachable!()
    };
    assert!(device.contains(&port), "{device}");
    assert!(
        reason.starts_with("LSM303DLHC magnetometer at 0x1E:") && reason.contains("not answering"),
        "{reason}"
    );
    assert!(run.counters.snapshot().poll_errors >= 1);

    // Retries fail while the chip stays away, each counted.
    thread::sleep(Duration::from_millis(700));
    let errors = run.counters.snapshot().poll_errors;
    assert!((2..=6).contains(&errors), "{errors} errors in 0.7 s");
    let logged = log_lines(&port);
    assert!(
        logged
            .iter()
            .any(|l| l.contains("WARN") && l.contains("LSM303DLHC magnetometer at 0x1E")),
        "{logged:#?}"
    );

    harness.with_mock(|m| m.set_nack(0x1E, false));
    run.wait_for(Duration::from_secs(3), "Connected again", |e| {
        matches!(e, SourceEvent::Connected { .. })
    });
    let after = run.readings(4);
    for r in &after {
        let chip = if r.mag.is_some() {
            Chip::Lsm303dlhcMag
        } else {
            Chip::Adxl345
        };
        assert_eq!(without_time(r), expected(chip, number(r)));
    }
    assert!(after.iter().any(|r| r.mag.is_some()));
    let counters = run.counters.snapshot();
    assert_eq!(counters.reconnects, 1, "{counters:?}");
    run.stop_within(Duration::from_secs(1));
}

#[test]
fn a_silent_bridge_is_named_counted_and_recovers() {
    let _serial = one_at_a_time();
    capture_log();
    let harness = Harness::start(mock_with(&[Chip::Mpu6050]));
    let port = harness.port.display().to_string();
    let mut config = config(&harness, &[Chip::Mpu6050]);
    config.timeout = Duration::from_millis(100);
    let run = start(config);
    run.readings(3);

    harness.with_mock(|m| m.set_silent(true));
    let seen = run.wait_for(Duration::from_secs(3), "Disconnected", |e| {
        matches!(e, SourceEvent::Disconnected { .. })
    });
    let Some(SourceEvent::Disconnected { reason, .. }) = seen.last() else {
        unreachable!()
    };
    assert!(
        reason.starts_with("MPU-6050 accelerometer/gyroscope at 0x68:")
            && reason.contains("did not answer"),
        "{reason}"
    );

    thread::sleep(Duration::from_millis(700));
    assert!(run.counters.snapshot().poll_errors >= 2);
    let logged = log_lines(&port);
    assert!(
        logged
            .iter()
            .any(|l| l.contains("0x68") && l.contains("did not answer")),
        "{logged:#?}"
    );
    assert!(
        logged.iter().any(|l| l.contains("set I2C mode")),
        "the retries time out setting the mode: {logged:#?}"
    );

    harness.with_mock(|m| m.set_silent(false));
    run.wait_for(Duration::from_secs(3), "Connected again", |e| {
        matches!(e, SourceEvent::Connected { .. })
    });
    for r in run.readings(3) {
        assert_eq!(without_time(&r), expected(Chip::Mpu6050, number(&r)));
    }
    assert_eq!(run.counters.snapshot().reconnects, 1);
    run.stop_within(Duration::from_secs(1));
}

/// A reply that comes after its poll timed out waits in the port; the
/// source must drop it, not read it as the answer to its next command.
#[test]
fn a_late_reply_is_not_taken_for_the_next_one() {
    let _serial = one_at_a_time();
    capture_log();
    let harness = Harness::start(mock_with(&[Chip::Adxl345]));
    let mut config = config(&harness, &[Chip::Adxl345]);
    config.timeout = Duration::from_millis(80);
    config.retry_interval = Duration::from_millis(400);
    let run = start(config);
    let before = run.readings(5);

    harness.delay_next_poll(0x53, Duration::from_millis(200));
    let seen = run.wait_for(Duration::from_secs(3), "Disconnected", |e| {
        matches!(e, SourceEvent::Disconnected { .. })
    });
    let Some(SourceEvent::Disconnected { reason, .. }) = seen.last() else {
        unreachable!()
    };
    assert!(
        reason.starts_with("ADXL345 accelerometer at 0x53:"),
        "{reason}"
    );
    run.wait_for(Duration::from_secs(3), "Connected again", |e| {
        matches!(e, SourceEvent::Connected { .. })
    });
    let after = run.readings(10);
    let counters = run.counters.clone();
    run.stop_within(Duration::from_secs(1));
    let counters = counters.snapshot();

    // Exactly one failure: the stale 6 bytes did not spoil the mode reply
    // or a data read after the reconnect.
    assert_eq!(counters.poll_errors, 1, "{counters:?}");
    assert_eq!(counters.reconnects, 1, "{counters:?}");
    let mut last = number(before.last().expect("readings before"));
    for event in &seen {
        if let SourceEvent::Reading(r) = event {
            last = number(r);
        }
    }
    // Sample last + 1 went out in the late reply and was dropped.
    let first_after = number(&after[0]);
    assert_eq!(
        first_after,
        last + 2,
        "the late sample is dropped, not read"
    );
    for (i, r) in after.iter().enumerate() {
        assert_eq!(
            without_time(r),
            expected(Chip::Adxl345, first_after + i as u64),
            "reading {i} after the reconnect"
        );
    }
}

#[test]
fn a_missing_port_is_retried_without_spinning_and_stops_promptly() {
    let _serial = one_at_a_time();
    capture_log();
    let port = "/dev/fieldcal-test-no-such-port";
    let mut config = BridgeConfig::new(port, vec![(Chip::Lsm303dlhcMag, 0x1E)]);
    config.retry_interval = Duration::from_millis(200);
    let run = start(config);

    thread::sleep(Duration::from_millis(1000));
    let attempts = run.counters.snapshot().poll_errors;
    let cpu = thread_cpu_ticks("fieldcal-bridge");
    eprintln!("missing port: {attempts} attempts in 1 s, {cpu:?} CPU ticks");
    // One at once, then one per 200 ms.
    assert!((4..=7).contains(&attempts), "{attempts} attempts in 1 s");
    if let Some(ticks) = cpu {
        assert!(
            ticks <= 10,
            "the retrying thread used {ticks} ticks of CPU in 1 s"
        );
    }
    let logged = log_lines(port);
    assert!(
        logged
            .iter()
            .any(|l| l.contains("WARN") && l.contains(&format!("cannot open {port}"))),
        "{logged:#?}"
    );
    // The same failure is logged at warn level once, not once per retry.
    let warns = logged.iter().filter(|l| l.contains("WARN")).count();
    assert_eq!(warns, 1, "{logged:#?}");
    assert!(run.events.try_recv().is_err(), "no events without a device");

    let stopped = Instant::now();
    run.stop_within(Duration::from_millis(300));
    eprintln!("ended {:?} after stop", stopped.elapsed());
}

#[test]
fn dropping_the_receiver_ends_the_source() {
    let _serial = one_at_a_time();
    capture_log();
    let harness = Harness::start(mock_with(&[Chip::Lsm303dlhcAccel]));
    let config = config(&harness, &[Chip::Lsm303dlhcAccel]);
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let handle = spawn_bridge_source(
        config,
        tx,
        Arc::new(SourceCounters::default()),
        Arc::new(AtomicBool::new(false)),
    )
    .expect("the source starts");
    let connected = rx.blocking_recv();
    assert!(
        matches!(connected, Some(SourceEvent::Connected { .. })),
        "{connected:?}"
    );
    drop(rx);
    assert!(joins_within(handle, Duration::from_secs(1)));
}

#[test]
fn a_bad_configuration_is_refused_up_front() {
    let (tx, _rx) = tokio::sync::mpsc::channel(1);
    let config = BridgeConfig::new("/dev/null", vec![]);
    let err = spawn_bridge_source(
        config,
        tx,
        Arc::new(SourceCounters::default()),
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap_err();
    assert_eq!(err.kind(), std::io::ErrorKind::InvalidInput);
    assert!(err.to_string().contains("/dev/null"), "{err}");
}
