//! The state-file loader (`StateStore::load`'s decoding, issue 23): any
//! bytes give a calibration or a reason, never a panic; a calibration it
//! gives is one of this sensor, with an id in range, and one that the
//! daemon's validity check passes corrects every raw reading a device can
//! send to finite numbers.
#![no_main]

use fieldcal::daemon::state::{MAX_ID, decode_state};
use fieldcal::model::validity::{POSSIBLE_OFFSET_RATIO, POSSIBLE_SCALE_RATIO, plane_problem};
use libfuzzer_sys::fuzz_target;

/// Raw readings at the corners and the middle of an i16 device's range.
const RAW: [f64; 5] = [-32768.0, -1.0, 0.0, 1.0, 32767.0];

fuzz_target!(|data: &[u8]| {
    let Ok(c) = decode_state(data, "compass") else {
        return;
    };
    assert_eq!(c.sensor, "compass");
    assert!((1..=MAX_ID).contains(&c.id), "id {}", c.id);
    for h in &c.history {
        assert_eq!(h.sensor, "compass");
        assert_eq!(h.ellipsoid.is_some(), c.ellipsoid.is_some());
    }
    match &c.ellipsoid {
        Some(e) => {
            if e.calibration().validate().is_ok() {
                for x in RAW {
                    for y in RAW {
                        for z in RAW {
                            let out = e.correct([x, y, z]);
                            assert!(out.iter().all(|v| v.is_finite()), "{out:?}");
                        }
                    }
                }
            }
        }
        None => {
            if plane_problem(&c.params, &c.terms, POSSIBLE_SCALE_RATIO, POSSIBLE_OFFSET_RATIO)
                .is_none()
            {
                for x in RAW {
                    for y in RAW {
                        let (sx, sy) = c.apply(x, y);
                        assert!(sx.is_finite() && sy.is_finite(), "{sx} {sy}");
                    }
                }
            }
        }
    }
});
