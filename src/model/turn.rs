//! Whether the readings show a turn at all: the gate every fit, diagnosis
//! and acceptance passes before any solver runs.
//!
//! A model of a turning sensor fits anything: noise around one point is an
//! ellipse too, and its "headings" cover every direction. So the physics is
//! checked on the readings themselves, in four gates:
//!
//! - A, enough samples to judge ([`MIN_TURN_SAMPLES`]);
//! - B, a ring, not a cloud: the spread of the readings stands at least
//!   [`RADIUS_OVER_NOISE`] times above their noise;
//! - C, a ring, not a disc: almost no readings near the centre
//!   ([`MAX_HOLE_FRACTION`] within [`HOLE_RADIUS`] of the median radius), as a
//!   tumble or two axes that are not the turning plane give;
//! - D, round the centre: the readings near the ring (radius within
//!   [`RING_BAND`] of the median) cover the required heading.
//!
//! Everything is linear in the samples (medians by selection, one
//! least-squares fit of four unknowns, the coverage's largest gap by
//! buckets) but the quantum, which sorts an axis only when it could matter,
//! so the daemon runs it on every rotation.

use serde::Serialize;

use super::FitError;
use super::heading::{Coverage, circle_centre, coverage};
use super::paper::closed_form;
use super::residuals::{mad, median_mut as median};
use crate::sample::Dataset;

/// Fewest samples from which the gates can tell a turn. A coverage of 300°
/// needs at least 6 samples even when evenly spread (360° less one gap of
/// 360°/n); and the noise (gate B) is a robust SD of n - 2 second
/// differences, whose relative standard error, 1.17/sqrt(n - 2) for the
/// 1.4826·MAD (its efficiency is 37 %), must stay well below the factor
/// between a turn at the threshold (10×) and a still cloud (1.4×): at 12
/// samples it is 37 %, so a cloud cannot reach 10× by chance of the estimate.
pub const MIN_TURN_SAMPLES: usize = 12;

/// Smallest spread of the readings (rms distance from their mean: the radius,
/// for a full ring) over their noise (per axis). ArduPilot's
/// CompassCalibrator accepts a fit whose rms residual ("fitness") is at most
/// 16 mGauss (AP_COMPASS_CALIBRATION_FITNESS_DEFAULT) and a field radius of
/// at least 150 mGauss (FIELD_RADIUS_MIN): a radius 9.4 times the residual
/// at the edge of acceptance. Below 10×, one sample's heading scatters by
/// more than atan(1/10) ≈ 6°, more than a compass calibration is for.
pub const RADIUS_OVER_NOISE: f64 = 10.0;

/// Radius, as a fraction of the median distance from the centre, inside
/// which a reading lies in the "hole" of a ring.
pub const HOLE_RADIUS: f64 = 0.5;

/// Largest fraction of readings allowed in the hole. A ring whose noise is at
/// most r/10 (gate B) reaches half the radius only at 5 SD (a fraction below
/// 1e-6); a uniformly filled disc puts (1/2)² · (median radius)²/R² ≈ 12 %
/// there, and two axes of a sphere tumbled evenly (the projection of a
/// uniform sphere is uniform in the third coordinate) about 10 %. 5 % sits
/// between them and leaves a ring room for a few percent of spikes.
pub const MAX_HOLE_FRACTION: f64 = 0.05;

/// Distances from the centre, as fractions of the median, of the readings
/// whose headings count toward coverage: a spike or a stray point far inside
/// or outside the ring would otherwise open headings the turn never reached.
pub const RING_BAND: [f64; 2] = [0.5, 1.5];

/// Least noise, in units of the largest reading: four decades above the
/// rounding of f64 (1.1e-16), so that readings equal but for rounding count
/// as a point, while noiseless simulated turns still pass by far.
const ROUNDING_FLOOR: f64 = 1e-12;

/// 1.4826 · MAD is the SD of Gaussian values.
const MAD_TO_SD: f64 = 1.4826;

/// Where the centre of the turn came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CentreFrom {
    /// The paper's closed form (eq. 6): distances in calibrated units.
    Paper,
    /// Kåsa's circle, when no ellipse of the paper's family fits.
    Circle,
    /// The mean of the readings, when neither fits.
    Mean,
}

/// What the gates measured, in the data's own units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TurnCheck {
    pub n: usize,
    /// Centre of the turn, raw x and y.
    pub centre: [f64; 2],
    pub centre_from: CentreFrom,
    /// Median distance of the readings from the centre (raw units, along
    /// each reading's own direction).
    pub radius: f64,
    /// Rms distance of the readings from their mean.
    pub spread: f64,
    /// Noise per axis: the smaller of the second-difference and the radial
    /// estimate, floored at the quantisation.
    pub noise: f64,
    pub spread_over_noise: f64,
    /// Fraction of readings within [`HOLE_RADIUS`] of the median radius.
    pub hole_fraction: f64,
    /// Readings in the [`RING_BAND`], whose headings make the coverage.
    pub ring_samples: usize,
    pub coverage: Coverage,
}

/// Checks that `(x, y)` trace a turn; `x` and `y` are named "x" and "y" in
/// the messages. See [`check_turn_of`] for a recording's own column names.
pub fn check_turn(x: &[f64], y: &[f64], min_coverage_deg: f64) -> Result<TurnCheck, FitError> {
    check_named(x, y, ["x", "y"], min_coverage_deg, || {
        second_difference_noise(x, y)
    })
}

/// [`check_turn`] on a recording, naming its columns in the messages.
pub fn check_turn_of(data: &Dataset, min_coverage_deg: f64) -> Result<TurnCheck, FitError> {
    check_turn_of_with(data, min_coverage_deg, || {
        second_difference_noise(&data.x, &data.y)
    })
}

/// [`check_turn_of`], the noise of the readings' second differences
/// ([`second_difference_noise`]) given by `noise` when it is needed
/// (worked out on another core meanwhile, say): called once, after the
/// readings' count and values are checked, and not at all when those
/// checks refuse them.
pub fn check_turn_of_with(
    data: &Dataset,
    min_coverage_deg: f64,
    noise: impl FnOnce() -> f64,
) -> Result<TurnCheck, FitError> {
    check_named(
        &data.x,
        &data.y,
        [&data.x_name, &data.y_name],
        min_coverage_deg,
        noise,
    )
}

/// The one scale that brings every value of `x` and `y` into [-1, 1].
fn common_scale(x: &[f64], y: &[f64]) -> f64 {
    x.iter()
        .chain(y)
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE)
}

/// The readings' noise per axis from their second differences (in the
/// turn check's scaled units: `x` and `y` over [`common_scale`]): a steady
/// turn cancels out of them.
pub fn second_difference_noise(x: &[f64], y: &[f64]) -> f64 {
    let scale = common_scale(x, y);
    (0.5 * (second_difference_sd(x, scale).powi(2) + second_difference_sd(y, scale).powi(2))).sqrt()
}

fn check_named(
    x: &[f64],
    y: &[f64],
    names: [&str; 2],
    min_coverage_deg: f64,
    noise_diff: impl FnOnce() -> f64,
) -> Result<TurnCheck, FitError> {
    let n = x.len().min(y.len());
    // Gate A.
    if n < MIN_TURN_SAMPLES || x.len() != y.len() {
        return Err(FitError::TooFewToTurn {
            found: n,
            needed: MIN_TURN_SAMPLES,
        });
    }
    if let Some(i) = (0..n).find(|&i| !(x[i].is_finite() && y[i].is_finite())) {
        return Err(FitError::NonFiniteReading {
            index: i,
            x: x[i],
            y: y[i],
        });
    }
    if let Some((column, index, value)) =
        [(names[0], x), (names[1], y)]
            .into_iter()
            .find_map(|(name, v)| {
                let i = v.iter().position(|&a| crate::sample::too_large(a))?;
                Some((name, i, v[i]))
            })
    {
        return Err(FitError::TooLarge {
            column: column.to_string(),
            index,
            value,
        });
    }
    // One common scale brings every value into [-1, 1]: nothing below can
    // overflow (a difference of two values near f64::MAX would), the solvers
    // see well-conditioned inputs, and the aspect ratio is kept.
    let scale = common_scale(x, y);
    let u: Vec<f64> = x.iter().map(|v| v / scale).collect();
    let v: Vec<f64> = y.iter().map(|v| v / scale).collect();

    let nf = n as f64;
    let (mu, mv) = (u.iter().sum::<f64>() / nf, v.iter().sum::<f64>() / nf);
    let spread = (u
        .iter()
        .zip(&v)
        .map(|(a, b)| (a - mu).powi(2) + (b - mv).powi(2))
        .sum::<f64>()
        / nf)
        .sqrt();

    let ring = Ring::about_centre(&u, &v, (mu, mv));
    let noise_diff = noise_diff();
    let noise =
        at_least_quantisation(noise_diff.min(ring.radial_noise), &u, &v).max(ROUNDING_FLOOR);
    let ratio = if noise > 0.0 {
        spread / noise
    } else if spread > 0.0 {
        f64::INFINITY
    } else {
        0.0
    };

    let check = TurnCheck {
        n,
        centre: [ring.centre.0 * scale, ring.centre.1 * scale],
        centre_from: ring.from,
        radius: ring.raw_radius * scale,
        spread: spread * scale,
        noise: noise * scale,
        spread_over_noise: ratio,
        hole_fraction: ring.hole_fraction,
        ring_samples: ring.ring_samples,
        coverage: ring.coverage,
    };
    // Gate B.
    if !(ratio >= RADIUS_OVER_NOISE) {
        return Err(FitError::NotTurning {
            across: 2.0 * check.spread,
            centre_x: mu * scale,
            centre_y: mv * scale,
            ratio,
            noise: check.noise,
            needed: RADIUS_OVER_NOISE,
        });
    }
    // Gate C.
    if check.hole_fraction > MAX_HOLE_FRACTION {
        return Err(FitError::DiscNotRing {
            percent: 100.0 * check.hole_fraction,
            x: names[0].to_string(),
            y: names[1].to_string(),
        });
    }
    // Gate D.
    if check.coverage.covered_deg + 1e-9 < min_coverage_deg {
        return Err(FitError::NoFullTurn {
            covered_deg: check.coverage.covered_deg,
            gap_deg: check.coverage.largest_gap_deg,
            gap_start_deg: check.coverage.gap_start_deg,
            needed_deg: min_coverage_deg,
            x: names[0].to_string(),
            y: names[1].to_string(),
        });
    }
    Ok(check)
}

/// The readings seen from the centre of the turn (scaled units).
struct Ring {
    centre: (f64, f64),
    from: CentreFrom,
    raw_radius: f64,
    radial_noise: f64,
    hole_fraction: f64,
    ring_samples: usize,
    coverage: Coverage,
}

impl Ring {
    /// The centre from the paper's closed form, else Kåsa's circle, else
    /// `mean`; distances in calibrated units when the paper's fit exists.
    fn about_centre(u: &[f64], v: &[f64], mean: (f64, f64)) -> Ring {
        let n = u.len();
        let paper = closed_form(u, v)
            .and_then(|t| t.to_calibration())
            .ok()
            .filter(|c| [c.a, c.b, c.d, c.r].iter().all(|p| p.is_finite()) && c.a > 0.0);
        let (centre, from, paper_cal) = if let Some(c) = paper {
            ((-c.b / c.a, -c.d), CentreFrom::Paper, Some(c))
        } else {
            let (centre, from) = match circle_centre(u, v) {
                Ok(c) if c.0.is_finite() && c.1.is_finite() => (c, CentreFrom::Circle),
                _ => (mean, CentreFrom::Mean),
            };
            (centre, from, None)
        };
        // A reading's calibrated offset (sx, sy) from the centre, and its
        // raw one; worked out where they are used rather than kept.
        let calibrated = |x: f64, y: f64| match &paper_cal {
            Some(c) => c.apply(x, y),
            None => (x - centre.0, y - centre.1),
        };
        let (rho, rho_raw): (Vec<f64>, Vec<f64>) = u
            .iter()
            .zip(v)
            .map(|(&x, &y)| {
                let (sx, sy) = calibrated(x, y);
                let raw = match &paper_cal {
                    Some(c) => (sx / c.a, sy),
                    None => (sx, sy),
                };
                (sx.hypot(sy), raw.0.hypot(raw.1))
            })
            .unzip();
        // One scratch copy serves each median in turn (a fresh one each
        // would be faulted in anew).
        let mut scratch = rho.clone();
        let median_rho = median(&mut scratch);
        scratch.copy_from_slice(&rho_raw);
        let raw_radius = median(&mut scratch);

        // Radial residual, taken back to raw units along each reading's
        // direction (first order): comparable with the per-axis noise.
        let radial_noise = if centre_from_fit(from) && median_rho > 0.0 {
            for ((e, &c), &r) in scratch.iter_mut().zip(&rho).zip(&rho_raw) {
                *e = if c > 0.0 {
                    (c - median_rho) * r / c
                } else {
                    0.0
                };
            }
            mad_sd(&mut scratch)
        } else {
            f64::INFINITY
        };

        let hole = rho
            .iter()
            .filter(|&&r| r < HOLE_RADIUS * median_rho)
            .count();
        let hole_fraction = if median_rho > 0.0 {
            hole as f64 / n.max(1) as f64
        } else {
            1.0
        };
        let band = (RING_BAND[0] * median_rho, RING_BAND[1] * median_rho);
        let in_band: Vec<f64> = u
            .iter()
            .zip(v)
            .zip(&rho)
            .filter(|(_, r)| (band.0..=band.1).contains(*r) && **r > 0.0)
            .map(|((&x, &y), _)| {
                let (a, b) = calibrated(x, y);
                b.atan2(a)
            })
            .collect();
        Ring {
            centre,
            from,
            raw_radius,
            radial_noise,
            hole_fraction,
            ring_samples: in_band.len(),
            coverage: coverage(in_band),
        }
    }
}

fn centre_from_fit(from: CentreFrom) -> bool {
    from != CentreFrom::Mean
}

/// Robust SD of white noise from second differences: the difference
/// x[i+1] - 2 x[i] + x[i-1] cancels a steady motion (a turn sampled densely
/// moves almost linearly between neighbours) and has variance 6σ². Of
/// `values / scale`, each divided as the turn check divides it.
fn second_difference_sd(values: &[f64], scale: f64) -> f64 {
    let mut d: Vec<f64> = values
        .windows(3)
        .map(|w| w[2] / scale - 2.0 * (w[1] / scale) + w[0] / scale)
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    mad_sd(&mut d) / 6f64.sqrt()
}

/// 1.4826 · median absolute deviation from the median.
fn mad_sd(values: &mut [f64]) -> f64 {
    MAD_TO_SD * mad(values)
}

/// Samples of each axis whose quantum is looked at before the whole axis's.
const QUANTUM_PROBE: usize = 4096;

/// `noise`, or the SD of the quantisation (quantum/√12) when that is
/// larger. The smallest step between the values of a part of an axis is at
/// least that of the whole axis: when the first [`QUANTUM_PROBE`] samples'
/// quantum cannot lift `noise`, neither can the whole's, and the sort of
/// every value is skipped (the result is the same).
fn at_least_quantisation(noise: f64, u: &[f64], v: &[f64]) -> f64 {
    let sd = |q: f64| q / 12f64.sqrt();
    if u.len() > QUANTUM_PROBE {
        let probe = [u, v].map(|axis| quantum(&axis[..QUANTUM_PROBE.min(axis.len())]));
        // A probe with no step at all (one value) bounds nothing.
        if probe.iter().all(|&q| q > 0.0 && sd(q) <= noise) {
            return noise;
        }
    }
    noise.max(sd(quantum(u).max(quantum(v))))
}

/// The smallest step between distinct values of an axis: the quantum of an
/// ADC (0 when the axis holds a single value). A uniform quantisation error
/// has SD quantum/√12, the least noise any reading carries.
fn quantum(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_unstable_by(f64::total_cmp);
    let step = sorted
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    if step.is_finite() { step } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::super::residuals::sorted_median;
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

        /// Selection gives the sort's median to the bit.
        #[test]
        fn the_median_by_selection_is_the_sorted_one(
            values in proptest::collection::vec(prop_oneof![-1e3f64..1e3, (0u8..5).prop_map(f64::from)], 1..300)
        ) {
            let mut v = values.clone();
            prop_assert_eq!(median(&mut v).to_bits(), sorted_median(&values).to_bits());
        }

        /// The probe of the quantum never changes the noise: the same value
        /// as the quantum of every sample, whether the steps are fine,
        /// coarse, or only start after the probe.
        #[test]
        fn the_quantum_probe_gives_the_whole_axis_result(
            step in prop_oneof![Just(1e-6f64), Just(1.0), Just(16.0)],
            noise in 0.0f64..20.0,
            still in 0usize..(2 * QUANTUM_PROBE),
            n in (QUANTUM_PROBE + 1)..(3 * QUANTUM_PROBE),
        ) {
            let axis = |phase: f64| -> Vec<f64> {
                (0..n)
                    .map(|i| if i < still { 0.0 } else { ((i as f64 * 0.01 + phase).sin() * 500.0 / step).round() * step })
                    .collect()
            };
            let (u, v) = (axis(0.0), axis(1.0));
            let whole = noise.max(quantum(&u).max(quantum(&v)) / 12f64.sqrt());
            prop_assert_eq!(at_least_quantisation(noise, &u, &v).to_bits(), whole.to_bits());
        }

        /// The noise of the second differences, worked out from the raw
        /// readings (on the fit's core), is that of the check's scaled
        /// copies to the bit.
        #[test]
        fn the_second_difference_noise_is_that_of_the_scaled_readings(
            xy in proptest::collection::vec((-1e6f64..1e6, -1e6f64..1e6), 0..300),
            exponent in -200i32..200,
        ) {
            let magnitude = 2f64.powi(exponent) / 3.0;
            let x: Vec<f64> = xy.iter().map(|p| p.0 * magnitude).collect();
            let y: Vec<f64> = xy.iter().map(|p| p.1 * magnitude).collect();
            let scale = common_scale(&x, &y);
            let sd = |values: &[f64]| {
                let u: Vec<f64> = values.iter().map(|v| v / scale).collect();
                let mut d: Vec<f64> = u.windows(3).map(|w| w[2] - 2.0 * w[1] + w[0]).collect();
                if d.is_empty() { 0.0 } else { mad_sd(&mut d) / 6f64.sqrt() }
            };
            let want = (0.5 * (sd(&x).powi(2) + sd(&y).powi(2))).sqrt();
            prop_assert_eq!(second_difference_noise(&x, &y).to_bits(), want.to_bits());
        }
    }
}
