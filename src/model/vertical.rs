//! The board's vertical from its accelerometer steadied by its gyroscope.
//!
//! An accelerometer reads gravity plus every acceleration of the board: a
//! hand that turns a board accelerates it by a few tenths of a g, and each
//! 0.02 g across the vertical tilts the accelerometer's "up" by a degree,
//! which a compass at a dip of 60° turns into two degrees of heading. A
//! gyroscope follows the same rotations without seeing accelerations, but
//! its bias makes its angle walk. The complementary filter (Mahony et al.,
//! "Nonlinear complementary filters on the special orthogonal group", IEEE
//! TAC 2008; the filter of MotionCal's and ArduPilot's DCM attitude
//! estimates) takes the vertical from the gyro over times shorter than
//! `tau` and from the accelerometer over longer ones:
//!
//! ```text
//! up ← normalise( up − (ω × up)·dt + (a/|a| − up)·dt/τ )
//! ```
//!
//! A gyro bias b tilts the fused vertical by about b·τ (1° for 1 °/s over
//! τ = 1 s), an acceleration at frequencies above 1/(2πτ) is attenuated.
//! [`DEFAULT_TAU_S`] is chosen from both: a hand's movements and tremor lie
//! above 0.5 Hz (a turn by hand takes seconds, its jolts and tremor are
//! faster), and the gyro of a board whose bias was trimmed at power-on
//! (the MPU-6050's factory trim leaves up to ±20 °/s, its driver's power-on
//! calibration brings that to a fraction of a degree per second) keeps the
//! vertical within a degree over one second.

use nalgebra::Vector3;

/// The filter's time constant by default, seconds (see the module's text).
pub const DEFAULT_TAU_S: f64 = 1.0;

/// The range of time constants accepted, seconds: shorter than 0.05 s is
/// the accelerometer alone at every rate a board is read at (20 Hz and
/// above); longer than 60 s lets any uncalibrated gyro walk the vertical
/// far off.
pub const TAU_RANGE_S: (f64, f64) = (0.05, 60.0);

/// A gap between samples longer than this many time constants restarts
/// the filter from the accelerometer: the gyro's angle over the gap is
/// unknown.
pub const MAX_GAP_TAUS: f64 = 1.0;

/// Why the vertical cannot be fused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VerticalError {
    #[error(
        "the time constant {tau_s} s is outside {} to {} s: give the seconds over which the gyro is trusted before the accelerometer (1 s for a hand-held board)",
        TAU_RANGE_S.0,
        TAU_RANGE_S.1
    )]
    Tau { tau_s: f64 },
    #[error(
        "{times} times, {accel} accelerometer readings and {rates} gyro readings: each sample needs all three"
    )]
    Lengths {
        times: usize,
        accel: usize,
        rates: usize,
    },
}

/// The board's vertical ("up", a unit vector in the accelerometer's frame)
/// at each of `t` (seconds, increasing), from specific forces `accel` (any
/// units) and rotation rates `rates_rad_s` (rad/s, the gyro's axes mapped to
/// the accelerometer's) at the same times, with time constant `tau_s`.
/// NaN where no vertical is known (before the first usable accelerometer
/// reading). A sample whose accelerometer reading is missing, zero or not
/// finite is carried by the gyro alone; one whose rate is missing restarts
/// from the accelerometer; so does a gap longer than [`MAX_GAP_TAUS`]·τ, or
/// time that does not increase.
pub fn fuse_vertical(
    t: &[f64],
    accel: &[[f64; 3]],
    rates_rad_s: &[[f64; 3]],
    tau_s: f64,
) -> Result<Vec<[f64; 3]>, VerticalError> {
    if !(tau_s >= TAU_RANGE_S.0 && tau_s <= TAU_RANGE_S.1) {
        return Err(VerticalError::Tau { tau_s });
    }
    if accel.len() != t.len() || rates_rad_s.len() != t.len() {
        return Err(VerticalError::Lengths {
            times: t.len(),
            accel: accel.len(),
            rates: rates_rad_s.len(),
        });
    }
    let direction = |a: &[f64; 3]| {
        let v = Vector3::from(*a);
        let n = v.norm();
        (v.iter().all(|c| c.is_finite()) && n > 0.0 && n.is_finite()).then(|| v / n)
    };
    let rate = |w: &[f64; 3]| {
        let v = Vector3::from(*w);
        v.iter().all(|c| c.is_finite()).then_some(v)
    };
    let mut out = Vec::with_capacity(t.len());
    let mut up: Option<Vector3<f64>> = None;
    for i in 0..t.len() {
        let measured = direction(&accel[i]);
        let next = match (up, i.checked_sub(1)) {
            (Some(previous), Some(j)) => {
                let dt = t[i] - t[j];
                match (rate(&rates_rad_s[j]), rate(&rates_rad_s[i])) {
                    (Some(w0), Some(w1)) if dt > 0.0 && dt <= MAX_GAP_TAUS * tau_s => {
                        // The rate at the interval's middle; a fixed vector
                        // seen from a body turning at ω turns at −ω.
                        let w = (w0 + w1) * 0.5;
                        let mut v = previous - w.cross(&previous) * dt;
                        if let Some(a) = measured {
                            v += (a - v) * (dt / tau_s).min(1.0);
                        }
                        let n = v.norm();
                        if n > 0.0 && n.is_finite() {
                            Some(v / n)
                        } else {
                            measured
                        }
                    }
                    _ => measured,
                }
            }
            _ => measured,
        };
        up = next;
        out.push(up.map_or([f64::NAN; 3], |u| [u.x, u.y, u.z]));
    }
    Ok(out)
}

/// The rotation rate about the vertical at each sample: ω·up, in the units
/// of `rates` (NaN where either is missing). Integrated, it is the gyro's
/// measure of the heading's change for any orientation of the board, where
/// one gyro axis serves only while that axis stays vertical.
pub fn rate_about_vertical(rates: &[[f64; 3]], up: &[[f64; 3]]) -> Vec<f64> {
    rates
        .iter()
        .zip(up)
        .map(|(w, u)| w[0] * u[0] + w[1] * u[1] + w[2] * u[2])
        .collect()
}
