//! A 3-axis compass's tilt-compensated heading against a 3-axis gyro: the
//! rate at which that heading turns, from the gyro and the accelerometer's
//! vertical, and the gyro's scale and bias fitted over a calibration's
//! samples, so that the trust monitor can check each later heading's
//! change against the gyro's ([`crate::model::trust`]).
//!
//! The heading ψ of the body's forward axis x̂ ([`super::tilt::tilt_heading`]
//! with forward +x) turns, for a body rate ω and a vertical û (unit), at
//!
//! ```text
//! ψ̇ = ω · v / |v|²,   v = û − (û · x̂) x̂,
//! ```
//!
//! up to a sign the frames' handedness sets. In Euler angles (yaw ψ,
//! pitch θ, roll φ) that is the familiar ψ̇ = (q sin φ + r cos φ) / cos θ,
//! with |v| = cos θ: exact at any roll, and ill-conditioned as the forward
//! axis nears the vertical, so readings pitched beyond [`MAX_PITCH_DEG`]
//! are not checked. v has no component along x̂: a roll about the forward
//! axis turns no heading, so the gyro's x bias is neither needed nor
//! determined (it is reported as 0).
//!
//! Pure functions on plain data.

use nalgebra::{Matrix3, Vector3};

use super::tilt::{MAD_TO_SIGMA, median_of as median};

/// Readings pitched beyond this are not checked against the gyro: at 60°
/// the heading's rate weighs the gyro's components by up to 1 / cos²θ = 4,
/// and every error of the vertical's direction by as much.
pub const MAX_PITCH_DEG: f64 = 60.0;
/// Two readings further apart than this, seconds, are no step of the fit:
/// a gap in the recording, over which the rate is not known.
pub const MAX_STEP_S: f64 = 0.5;
/// How far the fitted scale may be from ±1 beyond three standard errors:
/// the MPU-6050's sensitivity is ±3 % from the factory and moves ±2 % over
/// its temperature range; a gyro whose axes are not the accelerometer's
/// (a column left out, swapped or of the wrong sign) is far beyond it.
pub const SCALE_TOLERANCE: f64 = 0.05;
/// The span of one row of the fit, seconds: the heading's change over it
/// against the gyro's, summed over the steps between readings. Long
/// against the 0.1 s by which a board's magnetometer, accelerometer and
/// gyro readings may be apart ([`crate::daemon::sensor3::MAX_TILT_AGE_S`]),
/// so that its ends' misalignment does not swamp its turn; a quarter of
/// the monitor's window ([`super::trust::WINDOW_S`]), so that a sphere of a
/// minute gives tens of them.
pub const SEGMENT_S: f64 = 0.5;
/// Fewest segments the fit needs: one per batch of the heading checks'
/// comparisons ([`super::gyro::COMPARISON_BATCHES`]).
pub const MIN_SEGMENTS: usize = super::gyro::COMPARISON_BATCHES;
/// Steps whose residual is beyond this many robust σ are left out of the
/// second pass (a hand's jerk, a heading glitch near the vertical field).
const OUTLIER_SIGMAS: f64 = 5.0;

/// One reading of a 3-axis compass with its accelerometer and gyro.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroSample {
    /// Seconds.
    pub time: f64,
    /// The tilt-compensated heading, degrees.
    pub heading_deg: f64,
    /// The specific force (up) in the accelerometer's axes; any size.
    pub up: [f64; 3],
    /// The gyro in the accelerometer's axes, deg/s.
    pub gyro_deg_s: [f64; 3],
}

/// The gyro as a calibration's samples show it: heading rate ≈ `scale` ·
/// (ω − `bias_deg_s`) · v / |v|².
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Gyro3Fit {
    /// ±1 within the gyro's tolerance; the sign is the frames' handedness.
    pub scale: f64,
    pub scale_se: f64,
    /// The gyro's bias on each axis, deg/s; x (the forward axis, whose
    /// rate turns no heading) is 0.
    pub bias_deg_s: [f64; 3],
    /// One heading's noise, degrees: the segments' robust spread / √2
    /// (each holds the errors of its two ends).
    pub heading_sd_deg: f64,
    /// Segments fitted (after outliers were left out).
    pub segments: usize,
}

/// v / |v|² of a vertical `up` (any size, in the accelerometer's axes), or
/// none when it is zero, not finite, or the forward axis is pitched beyond
/// [`MAX_PITCH_DEG`].
pub fn vertical_weight(up: [f64; 3]) -> Option<[f64; 3]> {
    let u = Vector3::from(up);
    let n = u.norm();
    if !(n.is_finite() && n > 0.0) {
        return None;
    }
    let u = u / n;
    // v = û − (û · x̂) x̂: û without its x component; |v| = cos(pitch).
    let v = Vector3::new(0.0, u.y, u.z);
    let cos2 = v.norm_squared();
    if cos2 < MAX_PITCH_DEG.to_radians().cos().powi(2) {
        return None;
    }
    Some((v / cos2).into())
}

/// The heading's rate (deg/s, before the fitted scale) that a gyro reading
/// (deg/s) with `bias` gives at vertical `up`; none as [`vertical_weight`].
pub fn heading_rate(gyro_deg_s: [f64; 3], bias_deg_s: [f64; 3], up: [f64; 3]) -> Option<f64> {
    let w = Vector3::from(vertical_weight(up)?);
    let rate = (Vector3::from(gyro_deg_s) - Vector3::from(bias_deg_s)).dot(&w);
    rate.is_finite().then_some(rate)
}

/// Wraps degrees to (-180, 180].
fn wrap180(d: f64) -> f64 {
    let w = (d + 180.0).rem_euclid(360.0) - 180.0;
    if w == -180.0 { 180.0 } else { w }
}

/// One step between two readings: its design row and the heading's change.
fn step(a: &GyroSample, b: &GyroSample) -> Option<([f64; 3], f64)> {
    let dt = b.time - a.time;
    if !(dt > 0.0 && dt <= MAX_STEP_S) {
        return None;
    }
    let (wa, wb) = (vertical_weight(a.up)?, vertical_weight(b.up)?);
    let w = (Vector3::from(wa) + Vector3::from(wb)) * (0.5 * dt);
    let omega = (Vector3::from(a.gyro_deg_s) + Vector3::from(b.gyro_deg_s)) * 0.5;
    let y = wrap180(b.heading_deg - a.heading_deg);
    let row = [omega.dot(&w), w.y, w.z];
    (y.is_finite() && row.iter().all(|v| v.is_finite())).then_some((row, y))
}

/// Least squares of `rows` · θ = `y` on the rows `keep` allows: θ, the
/// residuals of every row, and the normal matrix's inverse.
fn solve(
    rows: &[([f64; 3], f64)],
    keep: impl Fn(usize) -> bool,
) -> Option<(Vector3<f64>, Matrix3<f64>, usize)> {
    let mut n = Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    let mut used = 0;
    for (i, (row, y)) in rows.iter().enumerate() {
        if !keep(i) {
            continue;
        }
        let x = Vector3::from(*row);
        n += x * x.transpose();
        rhs += x * *y;
        used += 1;
    }
    let inverse = n.try_inverse()?;
    let theta = inverse * rhs;
    theta
        .iter()
        .all(|v| v.is_finite())
        .then_some((theta, inverse, used))
}

/// The steps between consecutive `samples` summed into segments of at
/// least [`SEGMENT_S`]; a step that cannot be one (a gap, a pitch beyond
/// the limit) ends the segment it was in, which is let go.
fn segments(samples: &[GyroSample]) -> Vec<([f64; 3], f64)> {
    let mut out = Vec::new();
    let mut open: Option<(f64, [f64; 3], f64)> = None;
    for pair in samples.windows(2) {
        let Some((row, y)) = step(&pair[0], &pair[1]) else {
            open = None;
            continue;
        };
        let (start, sum, turned) = open.get_or_insert((pair[0].time, [0.0; 3], 0.0));
        for (s, r) in sum.iter_mut().zip(row) {
            *s += r;
        }
        *turned += y;
        if pair[1].time - *start >= SEGMENT_S {
            out.push((*sum, *turned));
            open = None;
        }
    }
    out
}

/// Fits the gyro's scale and bias to the heading's changes over segments
/// of consecutive `samples` (time order), by least squares in two passes
/// (the second without the segments beyond [`OUTLIER_SIGMAS`] robust σ of
/// the first). Err says why there is no fit, or why the gyro does not
/// follow the heading. O(n).
pub fn fit_gyro3(samples: &[GyroSample]) -> Result<Gyro3Fit, String> {
    let rows = segments(samples);
    if rows.len() < MIN_SEGMENTS {
        return Err(format!(
            "{} spans of {SEGMENT_S} s with every reading pitched within {MAX_PITCH_DEG}° and \
             none more than {MAX_STEP_S} s from the last, of {MIN_SEGMENTS} needed",
            rows.len()
        ));
    }
    let unresolved = || {
        "the samples do not tell the gyro's bias from its scale: the vertical did not move \
         enough among them"
            .to_string()
    };
    let residual =
        |theta: &Vector3<f64>, (row, y): &([f64; 3], f64)| y - Vector3::from(*row).dot(theta);
    let (first, _, _) = solve(&rows, |_| true).ok_or_else(unresolved)?;
    let mut spread: Vec<f64> = rows.iter().map(|r| residual(&first, r).abs()).collect();
    let cut = OUTLIER_SIGMAS * MAD_TO_SIGMA * median(&mut spread);
    let inside = |i: usize| residual(&first, &rows[i]).abs() <= cut;
    let (theta, inverse, used) = solve(&rows, inside).ok_or_else(unresolved)?;
    let mut kept: Vec<f64> = (0..rows.len())
        .filter(|&i| inside(i))
        .map(|i| residual(&theta, &rows[i]))
        .collect();
    let sum2: f64 = kept.iter().map(|r| r * r).sum();
    let dof = used.saturating_sub(3).max(1) as f64;
    let scale = theta[0];
    let scale_se = (sum2 / dof * inverse[(0, 0)]).max(0.0).sqrt();
    let centre = median(&mut kept);
    let mut deviations: Vec<f64> = kept.iter().map(|r| (r - centre).abs()).collect();
    let heading_sd_deg = MAD_TO_SIGMA * median(&mut deviations) / std::f64::consts::SQRT_2;
    if !(scale.is_finite() && scale != 0.0) {
        return Err(unresolved());
    }
    if (scale.abs() - 1.0).abs() > SCALE_TOLERANCE + 3.0 * scale_se {
        return Err(format!(
            "the gyro's rate about the vertical does not follow the heading: scale {scale:.3} \
             ± {scale_se:.3}, where a gyro in the accelerometer's axes gives ±1 within {:.0} %: \
             check that its axes are the accelerometer's x, y, z in that order (a csv source's \
             `gyro` columns), and its scale (`gyro_units`, or the chip's full-scale range)",
            SCALE_TOLERANCE * 100.0
        ));
    }
    // θ = (s, −s·b_y, −s·b_z).
    let bias_deg_s = [0.0, -theta[1] / scale, -theta[2] / scale];
    Ok(Gyro3Fit {
        scale,
        scale_se,
        bias_deg_s,
        heading_sd_deg,
        segments: used,
    })
}
