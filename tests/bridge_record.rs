//! `fieldcal record --device usb-iss` from a simulated USB-ISS bridge on a
//! real pty, then `fieldcal replay` of the capture: the same samples, in the
//! same order, at the poll period.

mod bridge_support;
mod common;

use bridge_support::{Harness, one_at_a_time};
use common::run_ok;
use fieldcal::mock::usb_iss::{MockEvent, MockUsbIss};
use fieldcal::protocol::chips::Chip;
use fieldcal::sample::Reading;
use serde_json::Value;

fn sample(chip: Chip, n: u64) -> Reading {
    let n = n as i16;
    let mut r = Reading::default();
    match chip {
        Chip::Mpu6050 => {
            r.accel = Some([3 * n, -2 * n, 16384 - n]);
            r.gyro = Some([n, 0, -n]);
            r.temp_raw = Some(-500 + n);
        }
        Chip::Lsm303dlhcMag => r.mag = Some([400 + n, -300 + 2 * n, 150 - n]),
        _ => unreachable!("this test polls two chips"),
    }
    r
}

fn triple(v: &Value) -> Option<Vec<i64>> {
    v.as_array()
        .map(|a| a.iter().map(|x| x.as_i64().unwrap()).collect())
}

#[test]
fn a_capture_recorded_from_the_bridge_replays_to_the_samples_it_served() {
    let _serial = one_at_a_time();
    let chips = [Chip::Mpu6050, Chip::Lsm303dlhcMag];
    let mut mock = MockUsbIss::with_chips(&chips);
    for chip in chips {
        mock.set_generator(chip.default_address(), Box::new(move |n| sample(chip, n)));
    }
    let harness = Harness::start(mock);
    let dir = tempfile::tempdir().unwrap();
    let capture = dir.path().join("bridge.fcap");
    let capture = capture.to_str().unwrap();
    run_ok(&[
        "record",
        "--device",
        "usb-iss",
        "--port",
        harness.port.to_str().unwrap(),
        "--chip",
        "mpu6050",
        "--chip",
        "lsm303dlhc-mag@0x1e",
        "--duration",
        "1.5",
        "--output",
        capture,
    ]);

    // What the mock served, chip by chip, in order.
    let served: Vec<(u8, Reading)> = harness
        .log()
        .into_iter()
        .filter_map(|logged| match logged.event {
            MockEvent::Read {
                address,
                sample: Some(s),
                ..
            } => Some((address, s)),
            _ => None,
        })
        .collect();
    assert!(
        served.len() >= 60,
        "1.5 s at 30 ms serves about 100 samples, got {}",
        served.len()
    );

    let out = run_ok(&["replay", capture, "--speed", "max"]);
    let replayed: Vec<Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // Every poll the recorder finished is in the capture; the last one the
    // mock served may have been cut off by the end of the recording.
    assert!(
        replayed.len() + 2 >= served.len() && replayed.len() <= served.len(),
        "{} vs {}",
        replayed.len(),
        served.len()
    );
    for (v, (address, s)) in replayed.iter().zip(&served) {
        match *address {
            0x68 => {
                assert_eq!(
                    triple(&v["accel"]),
                    s.accel.map(|a| a.map(i64::from).to_vec())
                );
                assert_eq!(
                    triple(&v["gyro"]),
                    s.gyro.map(|a| a.map(i64::from).to_vec())
                );
                assert_eq!(v["temp_raw"], s.temp_raw.unwrap());
                // MPU-6050: deg C = raw / 340 + 36.53.
                let c = v["temp_c"].as_f64().unwrap();
                assert!((c - (f64::from(s.temp_raw.unwrap()) / 340.0 + 36.53)).abs() < 1e-9);
            }
            0x1E => assert_eq!(triple(&v["mag"]), s.mag.map(|a| a.map(i64::from).to_vec())),
            other => panic!("unexpected address {other:#x}"),
        }
    }
    // Polls of the MPU-6050 are about 30 ms apart in the recorded times.
    let t: Vec<f64> = replayed
        .iter()
        .filter(|v| v.get("gyro").is_some())
        .map(|v| v["time"].as_f64().unwrap())
        .collect();
    let mean = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    assert!((0.027..0.036).contains(&mean), "mean poll period {mean}");
}
