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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Unit};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Uniform};

    /// A hand-held board turning about the vertical while it wobbles by
    /// up to `wobble_deg`, its accelerometer reading gravity (1 g up) plus
    /// the hand's accelerations (`hand_g` at 1.5 Hz and 4 Hz) and noise,
    /// its gyro the true body rates plus `bias_deg_s` and noise. Returns
    /// the times, accel, rates (rad/s) and the true vertical in the body.
    #[allow(clippy::type_complexity)]
    fn hand_turn(
        seed: u64,
        wobble_deg: f64,
        hand_g: f64,
        bias_deg_s: [f64; 3],
    ) -> (Vec<f64>, Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (dt, n) = (0.01, 2000);
        let phase: Vec<f64> = (0..6)
            .map(|_| uniform(&mut rng, std::f64::consts::TAU))
            .collect();
        let attitude = |t: f64| {
            let yaw = 0.6 * t; // rad/s: a turn in ~10 s
            let roll = wobble_deg.to_radians() * (0.7 * t + phase[0]).sin();
            let pitch = wobble_deg.to_radians() * (0.45 * t + phase[1]).cos();
            Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
                * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch)
                * Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
        };
        let (mut ts, mut acc, mut rates, mut truth) = (vec![], vec![], vec![], vec![]);
        for k in 0..n {
            let t = k as f64 * dt;
            let r = attitude(t);
            // Body rates from the attitude's change over a small step.
            let h = 1e-5;
            let dr = r.inverse() * attitude(t + h);
            let w = dr.scaled_axis() / h;
            let up_body = r.inverse() * Vector3::z();
            let hand_world = Vector3::new(
                (2.0 * std::f64::consts::PI * 1.5 * t + phase[2]).sin(),
                (2.0 * std::f64::consts::PI * 4.0 * t + phase[3]).sin(),
                0.5 * (2.0 * std::f64::consts::PI * 1.5 * t + phase[4]).cos(),
            ) * hand_g;
            let f = up_body + r.inverse() * hand_world;
            let noise = |rng: &mut ChaCha8Rng, s: f64| {
                Vector3::new(
                    uniform(rng, s) * 2.0 - s,
                    uniform(rng, s) * 2.0 - s,
                    uniform(rng, s) * 2.0 - s,
                )
            };
            let f = f + noise(&mut rng, 0.005);
            let w = w + Vector3::from(bias_deg_s).map(f64::to_radians) + noise(&mut rng, 0.002);
            ts.push(t);
            acc.push([f.x, f.y, f.z]);
            rates.push([w.x, w.y, w.z]);
            truth.push([up_body.x, up_body.y, up_body.z]);
        }
        (ts, acc, rates, truth)
    }

    /// Uniform on [0, top).
    fn uniform(rng: &mut ChaCha8Rng, top: f64) -> f64 {
        Uniform::new(0.0, top).unwrap().sample(rng)
    }

    fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
        let (a, b) = (Vector3::from(a), Vector3::from(b));
        a.angle(&b).to_degrees()
    }

    fn rms(v: &[f64]) -> f64 {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }

    /// After the first 3 τ (the filter's start-up), the fused vertical's
    /// rms error and the accelerometer's own.
    fn errors(seed: u64, hand_g: f64, bias: [f64; 3], tau: f64) -> (f64, f64) {
        let (t, acc, rates, truth) = hand_turn(seed, 15.0, hand_g, bias);
        let up = fuse_vertical(&t, &acc, &rates, tau).unwrap();
        let skip = (3.0 * tau / 0.01) as usize;
        let fused: Vec<f64> = (skip..t.len())
            .map(|i| angle_deg(up[i], truth[i]))
            .collect();
        let alone: Vec<f64> = (skip..t.len())
            .map(|i| angle_deg(acc[i], truth[i]))
            .collect();
        (rms(&fused), rms(&alone))
    }

    #[test]
    fn the_gyro_removes_the_hands_accelerations_from_the_vertical() {
        // A hand's 0.1 g tilts the accelerometer's vertical by several
        // degrees; the fused one stays within a degree, over many seeds.
        for seed in 0..30 {
            let (fused, alone) = errors(seed, 0.1, [0.0; 3], DEFAULT_TAU_S);
            assert!(alone > 3.0, "seed {seed}: accelerometer alone {alone:.2}°");
            assert!(
                fused < 1.0,
                "seed {seed}: fused {fused:.2}° (alone {alone:.2}°)"
            );
        }
    }

    #[test]
    fn a_gyro_bias_tilts_the_vertical_by_about_bias_times_tau() {
        // 1 °/s on x and y: the vertical's error stays within b·τ·√2 and
        // the bound grows with τ, as the module's text says.
        for seed in 0..20 {
            for tau in [0.5, 1.0, 2.0] {
                let (fused, _) = errors(seed, 0.0, [1.0, 1.0, 0.0], tau);
                let bound = 1.0 * tau * 2f64.sqrt();
                assert!(
                    fused <= bound * 1.1 + 0.3,
                    "seed {seed} τ {tau}: {fused:.2}° > {bound:.2}°"
                );
            }
        }
    }

    #[test]
    fn a_still_board_gives_the_accelerometers_vertical() {
        let n = 500;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.02).collect();
        let g = [0.1, -0.2, 0.97];
        let up = fuse_vertical(&t, &vec![g; n], &vec![[0.0; 3]; n], 1.0).unwrap();
        let expect = Vector3::from(g).normalize();
        for u in &up {
            assert!((Vector3::from(*u) - expect).norm() < 1e-12);
        }
    }

    #[test]
    fn missing_readings_gaps_and_bad_time_restart_or_carry() {
        let n = 100;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.01).collect();
        let mut acc = vec![[0.0, 0.0, 1.0]; n];
        let mut rates = vec![[0.0; 3]; n];
        acc[0] = [f64::NAN; 3]; // no vertical yet
        acc[10] = [0.0; 3]; // carried by the gyro
        rates[20] = [f64::NAN, 0.0, 0.0]; // restart from the accelerometer
        let up = fuse_vertical(&t, &acc, &rates, 1.0).unwrap();
        assert!(up[0].iter().all(|v| v.is_nan()));
        for u in &up[1..] {
            assert!((Vector3::from(*u) - Vector3::z()).norm() < 1e-12);
        }
        // A gap longer than τ: the gyro's angle is unknown, the vertical
        // restarts from the accelerometer.
        let t = vec![0.0, 0.01, 5.0];
        let acc = vec![[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
        let up = fuse_vertical(&t, &acc, &[[0.0, 3.0, 0.0]; 3], 1.0).unwrap();
        assert_eq!(up[2], [1.0, 0.0, 0.0]);
        // Time that goes back restarts too.
        let t = vec![0.0, 0.01, 0.005];
        let up = fuse_vertical(&t, &acc, &[[0.0, 0.0, 0.0]; 3], 1.0).unwrap();
        assert_eq!(up[2], [1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_gyro_turns_the_vertical_between_readings() {
        // A board rolling at 90 °/s about x with its accelerometer silent
        // (zero): after one second the vertical has turned by 90°.
        let n = 1001;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.001).collect();
        let mut acc = vec![[0.0; 3]; n];
        acc[0] = [0.0, 0.0, 1.0];
        let w = [std::f64::consts::FRAC_PI_2, 0.0, 0.0];
        let up = fuse_vertical(&t, &acc, &vec![w; n], 1.0).unwrap();
        let expect = Rotation3::from_axis_angle(
            &Unit::new_normalize(Vector3::x()),
            -std::f64::consts::FRAC_PI_2,
        ) * Vector3::z();
        assert!(
            (Vector3::from(up[n - 1]) - expect).norm() < 1e-3,
            "{:?} vs {expect:?}",
            up[n - 1]
        );
    }

    #[test]
    fn bad_arguments_are_refused() {
        assert!(matches!(
            fuse_vertical(&[0.0], &[[0.0, 0.0, 1.0]], &[[0.0; 3]], 0.0),
            Err(VerticalError::Tau { .. })
        ));
        assert!(matches!(
            fuse_vertical(&[0.0], &[[0.0, 0.0, 1.0]], &[[0.0; 3]], f64::NAN),
            Err(VerticalError::Tau { .. })
        ));
        assert!(matches!(
            fuse_vertical(&[0.0, 1.0], &[[0.0, 0.0, 1.0]], &[[0.0; 3]], 1.0),
            Err(VerticalError::Lengths { .. })
        ));
    }

    #[test]
    fn the_rate_about_the_vertical_is_the_dot_product() {
        let r = rate_about_vertical(
            &[[1.0, 2.0, 3.0], [1.0, 0.0, 0.0]],
            &[[0.0, 0.0, 1.0], [f64::NAN; 3]],
        );
        assert_eq!(r[0], 3.0);
        assert!(r[1].is_nan());
    }
}
