//! Residual diagnostics for any fit: where the magnitude error
//! `e_i = |s_i|/r - 1` still has structure (harmonics of heading, a trend or
//! slow wander in time, a link to a logged column, heavy tails), and how
//! large the noise is, estimated from the data itself.
//!
//! These are what [`super::diagnose`] reads to say which effect the data
//! supports and why, in words a person understands.

use nalgebra::{DMatrix, DVector, SMatrix, SVector, SymmetricEigen};

use super::heading::SVD_MAX_ITERATIONS;
use serde::Serialize;

use super::nonlinear::ModelFit;
use crate::sample::{Covariate, Dataset};

/// Highest harmonic of heading analysed: cross-axis coupling shows at 2,
/// cubic non-linearity at 2 and 4; 1 and 3 catch leftover offsets.
pub const MAX_HARMONIC: u32 = 4;
/// Samples further than this many robust SD from the median are tails.
pub const TAIL_SDS: f64 = 4.0;
/// P(|Z| > 4) for a standard normal: the tail fraction Gaussian noise gives.
pub const GAUSSIAN_TAIL_4SD: f64 = 6.334e-5;
/// MAD to SD for Gaussian data.
const MAD_TO_SD: f64 = super::tilt::MAD_TO_SIGMA;
/// The slow smooth of e vs time averages over this fraction of the run.
pub const SMOOTH_FRACTION: f64 = 0.1;

/// One harmonic of e vs heading: `e ≈ amplitude * cos(order*θ + phase)`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Harmonic {
    pub order: u32,
    /// As a fraction of the field.
    pub amplitude: f64,
    pub phase_deg: f64,
}

/// How the residual follows one logged column (least-squares line).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CovariateLink {
    pub column: String,
    /// Residual per unit of the column.
    pub slope: f64,
    pub correlation: f64,
    /// Fraction of the residual variance the line explains (correlation²).
    pub explained: f64,
}

/// The noise level of the residual, and how it was estimated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NoiseFloor {
    /// As a fraction of the field (comparable with a fit's rms).
    pub rms: f64,
    pub method: String,
}

/// Everything the residual says about what the model misses.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Residuals {
    /// Orders 1..=4, least squares of e on cos/sin(kθ) jointly.
    pub harmonics: Vec<Harmonic>,
    #[serde(flatten)]
    pub common: ResidualCommon,
}

/// What the residual of a fit of either geometry says beyond its
/// geometry: its trend and structure in time, its links to logged
/// columns, its tail and its noise.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResidualCommon {
    /// Slope of e vs time, per second (None without a time column).
    pub time_trend: Option<f64>,
    /// Fraction of the residual variance explained by a moving average over
    /// ~1/10 of the run, in time order (None with fewer than 20 samples).
    pub time_structure: Option<f64>,
    pub covariates: Vec<CovariateLink>,
    /// Samples with |e - median| > 4 robust SD, the SD taken at each
    /// sample's heading when the noise depends on heading (unequal gains).
    pub tail_count: usize,
    /// What Gaussian noise would give: n · P(|Z| > 4).
    pub tail_expected: f64,
    /// The largest |e - median|, in robust SD: one far spike shows here even
    /// when the tail count is small.
    pub tail_max_sd: f64,
    /// 1.4826 · MAD of e.
    pub robust_sd: f64,
    pub noise_floor: NoiseFloor,
}

/// Whether a column name looks like time (those are not covariates: time is
/// the `drift` effect's business).
pub fn is_time_like(name: &str) -> bool {
    let lower = name.trim().to_ascii_lowercase();
    matches!(
        lower.as_str(),
        "t" | "t_s" | "ts" | "time" | "time_s" | "timestamp" | "seconds" | "secs"
    ) || lower.starts_with("time")
}

/// A column whose variance the chosen axes explain beyond this R² is a
/// (nearly) linear copy of them, not a covariate. Fitted as one, it can
/// only recombine x and y linearly, which is the business of scale and
/// cross-axis, and its coefficients' standard errors are inflated by
/// 1/√(1 − R²) ≥ 10 (a variance inflation factor ≥ 100, ten times the
/// usual VIF 10 alarm of regression diagnostics, Marquardt 1970; Kutner et
/// al., Applied Linear Statistical Models, §10.5). An axis logged again in
/// other units (`mag_z_uT` beside `mag_z_lsb`) gives R² ≈ 1 less rounding;
/// the third axis of a sensor turned in a plane tilted from its own is the
/// other two plus noise, and lands here too.
pub const COPY_R2: f64 = 0.99;

/// A logged column that is not offered as a covariate, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SetAside {
    pub column: String,
    pub reason: String,
}

/// Sums of squares and products of three series about their means (the
/// moments of a least-squares fit on centred columns), each summed in
/// sample order.
#[derive(Debug, Clone, Copy)]
pub(crate) struct CentredSums {
    /// The means the series are centred on.
    pub means: [f64; 3],
    pub aa: f64,
    pub bb: f64,
    pub cc: f64,
    pub ab: f64,
    pub ac: f64,
    pub bc: f64,
}

/// The [`CentredSums`] of `a`, `b` and `c` (of equal length, not empty).
pub(crate) fn centred_sums(a: &[f64], b: &[f64], c: &[f64]) -> CentredSums {
    let n = a.len();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n as f64;
    let (ma, mb, mc) = (mean(a), mean(b), mean(c));
    let mut s = CentredSums {
        means: [ma, mb, mc],
        aa: 0.0,
        bb: 0.0,
        cc: 0.0,
        ab: 0.0,
        ac: 0.0,
        bc: 0.0,
    };
    for i in 0..n {
        let (da, db, dc) = (a[i] - ma, b[i] - mb, c[i] - mc);
        s.aa += da * da;
        s.bb += db * db;
        s.cc += dc * dc;
        s.ab += da * db;
        s.ac += da * dc;
        s.bc += db * dc;
    }
    s
}

/// R² of `u` regressed on `[1, x, y]`, and on `[1, x]` and `[1, y]` alone;
/// None when `u` is constant.
fn r2_on_axes(u: &[f64], x: &[f64], y: &[f64]) -> Option<(f64, f64, f64)> {
    let n = u.len().min(x.len()).min(y.len());
    if n < 3 {
        return None;
    }
    let CentredSums {
        aa: suu,
        bb: sxx,
        cc: syy,
        ab: sux,
        ac: suy,
        bc: sxy,
        ..
    } = centred_sums(&u[..n], &x[..n], &y[..n]);
    if !(suu > 0.0) || !suu.is_finite() {
        return None;
    }
    let single = |s: f64, ss: f64| if ss > 0.0 { s * s / (ss * suu) } else { 0.0 };
    let r2x = single(sux, sxx);
    let r2y = single(suy, syy);
    let det = sxx * syy - sxy * sxy;
    let r2 = if det > 0.0 {
        let bx = (sux * syy - suy * sxy) / det;
        let by = (suy * sxx - sux * sxy) / det;
        (bx * sux + by * suy) / suu
    } else {
        r2x.max(r2y)
    };
    let clamp = |v: f64| {
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    Some((clamp(r2), clamp(r2x), clamp(r2y)))
}

/// The logged columns that are not covariate candidates, with the reason:
/// time (the `drift` effect's business), a constant, or a (nearly) linear
/// copy of the chosen axes (R² above [`COPY_R2`]).
pub fn set_aside(data: &Dataset) -> Vec<SetAside> {
    data.covariates
        .iter()
        .filter_map(|c| {
            let reason = if is_time_like(&c.name) {
                "time, which the drift effect covers".to_string()
            } else {
                match r2_on_axes(&c.values, &data.x, &data.y) {
                    None => "constant: the residual cannot follow it".to_string(),
                    Some((r2, r2x, r2y)) if r2 > COPY_R2 => {
                        if r2x.max(r2y) > COPY_R2 {
                            let (axis, single) = if r2x >= r2y {
                                (&data.x_name, r2x)
                            } else {
                                (&data.y_name, r2y)
                            };
                            format!("a copy of {axis} in other units (R² {single:.4})")
                        } else {
                            format!(
                                "a linear combination of {} and {} (R² {r2:.4}): the axes in the plane of the turn already carry it",
                                data.x_name, data.y_name
                            )
                        }
                    }
                    Some(_) => return None,
                }
            };
            Some(SetAside {
                column: c.name.clone(),
                reason,
            })
        })
        .collect()
}

/// Indices of the samples the fit used (all but the flagged ones), in time
/// order when the data has times (input order otherwise).
fn used_in_time_order(data: &Dataset, fit: &ModelFit) -> Vec<usize> {
    let n = fit.residuals.len();
    let mut flagged = vec![false; n];
    for &i in &fit.flagged {
        if let Some(f) = flagged.get_mut(i) {
            *f = true;
        }
    }
    let mut used: Vec<usize> = (0..n)
        .filter(|&i| {
            !flagged[i]
                && fit.residuals[i].is_finite()
                && fit.headings.get(i).is_some_and(|h| h.is_finite())
        })
        .collect();
    if let Some(t) = data.t.as_deref().filter(|t| t.len() == n) {
        used.sort_by(|&a, &b| t[a].total_cmp(&t[b]));
    }
    used
}

/// Median of the values (0 for none), selected in a copy.
pub fn median(values: &[f64]) -> f64 {
    median_mut(&mut values.to_vec())
}

/// The median of `values` (which may be reordered), in linear time: the
/// same value a sort would give (the middle one, or the mean of the two
/// middle ones).
pub(crate) fn median_mut(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let n = values.len();
    let (below, upper) = if n >= SAMPLED_FROM {
        middle_by_sample(values, middle_sample(n)).unwrap_or_else(|| middle_by_selection(values))
    } else {
        middle_by_selection(values)
    };
    if n % 2 == 1 {
        upper
    } else {
        0.5 * (below + upper)
    }
}

/// The sorted values' `[n/2 - 1]` and `[n/2]` (the same one for a single
/// value), by `total_cmp`: by selection.
fn middle_by_selection(values: &mut [f64]) -> (f64, f64) {
    let n = values.len();
    ranks_up_to(values, n / 2)
}

/// The sorted values' `[rank - 1]` and `[rank]` (the same one at rank 0),
/// by `total_cmp`: `values` partitioned about `[rank]`, and the largest of
/// those before it.
fn ranks_up_to(values: &mut [f64], rank: usize) -> (f64, f64) {
    let (lower, &mut upper, _) = values.select_nth_unstable_by(rank, f64::total_cmp);
    let below = lower
        .iter()
        .copied()
        .max_by(f64::total_cmp)
        .unwrap_or(upper);
    (below, upper)
}

/// Values from which the middle is looked for about a sample first.
const SAMPLED_FROM: usize = 1 << 15;

/// Values [`middle_by_sample`] samples of `n`: about n^(2/3) (Floyd and
/// Rivest's choice, which balances the sample's sort against the copies
/// between its bounds, about 4/√sample of the values), from 4,096 (6 %
/// copied) to 16,384 (3 %), each sorted within a millisecond.
fn middle_sample(n: usize) -> usize {
    ((n as f64).cbrt().powi(2) as usize).clamp(1 << 12, 1 << 14)
}

/// A value's place in the order of `total_cmp`, as an unsigned integer:
/// a negative value's bits all flipped, a positive one's sign bit set.
fn ordered_key(v: f64) -> u64 {
    let bits = v.to_bits();
    // All ones for a negative value, none for a positive one: no branch.
    let negative = ((bits as i64) >> 63) as u64;
    bits ^ (negative | (1 << 63))
}

/// [`middle_by_selection`]'s two values, the same to the bit, in about one
/// pass (Floyd and Rivest's selection): `sample` values spread evenly over
/// `values` are sorted, two of them bound the middle ranks with a margin of
/// four standard deviations of a rank's place in a sample, one pass counts
/// the values below the lower bound and copies those between the bounds,
/// and the selection is done among the copies. `None` when the bounds miss
/// the middle or leave too many values between them (a sample that
/// misleads; many values equal to a bound): the caller selects among all.
fn middle_by_sample(values: &[f64], sample: usize) -> Option<(f64, f64)> {
    let n = values.len();
    let sample = sample.min(n);
    if n < 2 || sample < 2 {
        return None;
    }
    let stride = n / sample;
    let mut keys: Vec<u64> = (0..sample)
        .map(|i| ordered_key(values[i * stride]))
        .collect();
    keys.sort_unstable();
    // The ranks n/2 - 1 and n/2 sit about the sample's middle, give or take
    // √(sample)/2 places (a binomial's spread): four of those either side.
    let margin = 2 * sample.isqrt() + 1;
    let middle = sample / 2;
    let low = keys[middle.saturating_sub(margin)];
    let high = keys[(middle + margin).min(sample - 1)];
    let most = n / 8 + 1;
    // Counted and copied without a branch on the value (which way it goes
    // is a coin toss for half of them): each is written at the end of the
    // copies, and kept there when it lies between the bounds.
    let mut below = 0usize;
    let mut between = vec![0.0; most + 1];
    let mut kept = 0;
    for &v in values {
        let key = ordered_key(v);
        below += usize::from(key < low);
        between[kept] = v;
        kept += usize::from(low <= key && key <= high);
        if kept == most {
            return None;
        }
    }
    between.truncate(kept);
    let rank = n / 2;
    // Both middle ranks must lie among the values between the bounds.
    if below + 1 > rank || rank >= below + between.len() {
        return None;
    }
    Some(ranks_up_to(&mut between, rank - below))
}

/// 1.4826 · median absolute deviation: the SD for Gaussian data, barely
/// moved by a few spikes.
pub fn robust_sd(values: &[f64]) -> f64 {
    MAD_TO_SD * mad(&mut values.to_vec())
}

/// The median absolute deviation from the median of `values` (0 for
/// none), in place: they are left as the deviations (perhaps reordered).
pub(crate) fn mad(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let m = median_mut(values);
    for v in values.iter_mut() {
        *v = (*v - m).abs();
    }
    median_mut(values)
}

/// Each group of headings needs this many samples for its own scale.
const MIN_GROUP: usize = 10;
/// The two halves' scales must differ by this many standard errors of
/// ln(MAD) before the noise is taken to depend on heading.
const SCALE_SPLIT_SES: f64 = 3.0;
/// Standard error of ln(MAD) per 1/√n for Gaussian data (the MAD's
/// asymptotic variance is 1.36 σ²/n).
const LN_MAD_SE: f64 = 1.166;

/// The noise of e as it varies with heading. Each calibrated axis carries
/// its raw noise times its own gain, so where the noisier axis lies along
/// the field the radial residual is noisier: σ(θ)² = α·cos²θ + β·sin²θ.
/// With gains 2:1 apart, one scale for all headings would see the noisier
/// half's ordinary samples as 4-SD tails. The model is used only when the
/// two halves (|cos θ| above or below |sin θ|) differ by more than their
/// estimation noise; otherwise every heading has the same scale.
#[derive(Debug, Clone, Copy, PartialEq)]
struct HeadingScale {
    alpha: f64,
    beta: f64,
}

impl HeadingScale {
    const UNIFORM: HeadingScale = HeadingScale {
        alpha: 1.0,
        beta: 1.0,
    };

    fn estimate(deviations: &[f64], theta: &[f64]) -> HeadingScale {
        let (mut along_x, mut along_y) = (Vec::new(), Vec::new());
        let (mut cos2_x, mut cos2_y) = (0.0, 0.0);
        for (&d, &t) in deviations.iter().zip(theta) {
            let c2 = t.cos().powi(2);
            if c2 >= 0.5 {
                along_x.push(d);
                cos2_x += c2;
            } else {
                along_y.push(d);
                cos2_y += c2;
            }
        }
        let (nx, ny) = (along_x.len(), along_y.len());
        if nx < MIN_GROUP || ny < MIN_GROUP {
            return HeadingScale::UNIFORM;
        }
        let (sx, sy) = (robust_sd(&along_x), robust_sd(&along_y));
        let se = LN_MAD_SE * (1.0 / nx as f64 + 1.0 / ny as f64).sqrt();
        if !(sx > 0.0 && sy > 0.0) || (sx / sy).ln().abs() <= SCALE_SPLIT_SES * se {
            return HeadingScale::UNIFORM;
        }
        // Each half's variance is the model's at its mean cos²θ.
        let (cx, cy) = (cos2_x / nx as f64, cos2_y / ny as f64);
        let (vx, vy) = (sx * sx, sy * sy);
        let det = cx - cy;
        if det <= 1e-6 {
            return HeadingScale::UNIFORM;
        }
        let floor = 0.05 * vx.max(vy);
        HeadingScale {
            alpha: ((vx * (1.0 - cy) - vy * (1.0 - cx)) / det).max(floor),
            beta: ((vy * cx - vx * cy) / det).max(floor),
        }
    }

    /// The relative noise SD at heading `theta` (any common factor).
    fn at(&self, theta: f64) -> f64 {
        let c2 = theta.cos().powi(2);
        (self.alpha * c2 + self.beta * (1.0 - c2)).sqrt()
    }
}

/// Deviations from the median in units of the noise at their heading,
/// scaled so their robust SD is 1: what the tail count compares with 4.
fn standardized(e: &[f64], theta: &[f64]) -> Vec<f64> {
    let m = median(e);
    let deviations: Vec<f64> = e.iter().map(|v| v - m).collect();
    let scale = HeadingScale::estimate(&deviations, theta);
    let z: Vec<f64> = deviations
        .iter()
        .zip(theta)
        .map(|(d, &t)| d / scale.at(t))
        .collect();
    let sd = robust_sd(&z);
    if sd > 0.0 && sd.is_finite() {
        z.iter().map(|v| v / sd).collect()
    } else {
        vec![0.0; z.len()]
    }
}

/// Columns of the harmonic fit: 1, then cos kθ and sin kθ for each order.
const HARMONIC_COLUMNS: usize = 1 + 2 * MAX_HARMONIC as usize;

/// The normal equations are solved directly when their matrix's smallest
/// eigenvalue is at least this fraction of its largest: a condition of the
/// design under 10⁵, so squaring it loses at most 10⁻⁶ of a result that
/// matters to three figures. Below it (a turn that covers only a few
/// headings) the design is solved by its SVD, as accurately as it allows.
const NORMAL_EQUATIONS_MIN_RCOND: f64 = 1e-10;

/// Least squares of e on `[1, cos kθ, sin kθ]`, k = 1..=4, jointly (the
/// columns are not orthogonal on an uneven turn). One pass forms the 9 × 9
/// normal equations, with cos kθ and sin kθ from cos θ and sin θ by the
/// angle-addition formulas; no design matrix is kept, so memory does not
/// grow with the samples.
pub fn harmonics(e: &[f64], theta: &[f64]) -> Vec<Harmonic> {
    let n = e.len().min(theta.len());
    if n <= HARMONIC_COLUMNS {
        return Vec::new();
    }
    let mut ata = SMatrix::<f64, HARMONIC_COLUMNS, HARMONIC_COLUMNS>::zeros();
    let mut atb = SVector::<f64, HARMONIC_COLUMNS>::zeros();
    for (&t, &value) in theta[..n].iter().zip(&e[..n]) {
        let row = harmonic_row(t);
        for j in 0..HARMONIC_COLUMNS {
            atb[j] += row[j] * value;
            for k in j..HARMONIC_COLUMNS {
                ata[(j, k)] += row[j] * row[k];
            }
        }
    }
    ata.fill_lower_triangle_with_upper_triangle();
    // Bounded iterations, as the SVD's: a solve that cannot converge must
    // not hang the tool; a value that is not finite goes to the SVD.
    let conditioned = ata.iter().all(|v| v.is_finite())
        && SymmetricEigen::try_new(ata, f64::EPSILON, SVD_MAX_ITERATIONS).is_some_and(|eigen| {
            let (low, high) = (eigen.eigenvalues.min(), eigen.eigenvalues.max());
            high > 0.0 && low >= NORMAL_EQUATIONS_MIN_RCOND * high
        });
    match ata.cholesky().filter(|_| conditioned) {
        Some(c) => amplitudes(c.solve(&atb).as_slice()),
        None => harmonics_by_svd(&e[..n], &theta[..n]),
    }
}

/// One row of the harmonic design at heading `t`.
fn harmonic_row(t: f64) -> [f64; HARMONIC_COLUMNS] {
    let mut row = [0.0; HARMONIC_COLUMNS];
    row[0] = 1.0;
    let (s1, c1) = t.sin_cos();
    let (mut c, mut s) = (c1, s1);
    for k in 0..MAX_HARMONIC as usize {
        row[2 * k + 1] = c;
        row[2 * k + 2] = s;
        (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
    }
    row
}

/// [`harmonics`] by the SVD of the whole design, for a turn whose columns
/// are too close to dependent for the normal equations.
fn harmonics_by_svd(e: &[f64], theta: &[f64]) -> Vec<Harmonic> {
    let design = DMatrix::from_fn(e.len(), HARMONIC_COLUMNS, |i, j| {
        if j == 0 {
            return 1.0;
        }
        let k = j.div_ceil(2) as f64;
        if j % 2 == 1 {
            (k * theta[i]).cos()
        } else {
            (k * theta[i]).sin()
        }
    });
    let target = DVector::from_column_slice(e);
    // Bounded iterations: an SVD that cannot converge must not hang the tool.
    let Some(svd) = design.try_svd(true, true, f64::EPSILON, SVD_MAX_ITERATIONS) else {
        return Vec::new();
    };
    let Ok(coef) = svd.solve(&target, 1e-12) else {
        return Vec::new();
    };
    amplitudes(coef.as_slice())
}

/// Each order's amplitude and phase from the coefficients of
/// `[1, cos kθ, sin kθ]`.
fn amplitudes(coef: &[f64]) -> Vec<Harmonic> {
    (1..=MAX_HARMONIC)
        .map(|k| {
            let a = coef[2 * k as usize - 1];
            let b = coef[2 * k as usize];
            // a cos + b sin = A cos(kθ + φ) with a = A cos φ, b = -A sin φ.
            let amplitude = a.hypot(b);
            let phase_deg = if amplitude > 0.0 {
                (-b).atan2(a).to_degrees()
            } else {
                0.0
            };
            Harmonic {
                order: k,
                amplitude: finite_or_zero(amplitude),
                phase_deg: finite_or_zero(phase_deg),
            }
        })
        .collect()
}

fn finite_or_zero(v: f64) -> f64 {
    if v.is_finite() { v } else { 0.0 }
}

/// Least-squares line of `e` on `u`: (slope, correlation). None when `u` is
/// constant or there are too few points.
pub fn line(u: &[f64], e: &[f64]) -> Option<(f64, f64)> {
    let n = u.len().min(e.len());
    if n < 3 {
        return None;
    }
    let mu = u[..n].iter().sum::<f64>() / n as f64;
    let me = e[..n].iter().sum::<f64>() / n as f64;
    let (mut suu, mut see, mut sue) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let (du, de) = (u[i] - mu, e[i] - me);
        suu += du * du;
        see += de * de;
        sue += du * de;
    }
    if !(suu > 0.0) {
        return None;
    }
    let slope = sue / suu;
    let correlation = if see > 0.0 {
        sue / (suu * see).sqrt()
    } else {
        0.0
    };
    (slope.is_finite() && correlation.is_finite()).then_some((slope, correlation))
}

/// Fraction of the variance of `e` (already in time order) explained by a
/// centred moving average over ~1/10 of the run.
pub fn slow_structure(e: &[f64]) -> Option<f64> {
    let n = e.len();
    if n < 20 {
        return None;
    }
    let half = ((n as f64 * SMOOTH_FRACTION) as usize / 2).max(1);
    let mut prefix = vec![0.0; n + 1];
    for i in 0..n {
        prefix[i + 1] = prefix[i] + e[i];
    }
    let mean = prefix[n] / n as f64;
    let total: f64 = e.iter().map(|v| (v - mean).powi(2)).sum();
    if !(total > 0.0) {
        return Some(0.0);
    }
    let left: f64 = (0..n)
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(half), (i + half + 1).min(n));
            let smooth = (prefix[hi] - prefix[lo]) / (hi - lo) as f64;
            (e[i] - smooth).powi(2)
        })
        .sum();
    Some((1.0 - left / total).clamp(0.0, 1.0))
}

/// The noise floor of the residual, from the data itself: differences of
/// consecutive residuals in time order. Structure (harmonics of heading,
/// drift, a slowly changing covariate) changes little between neighbouring
/// samples of a turn, while independent noise does not cancel: Δe has SD
/// σ√2. The MAD keeps spikes from inflating it.
pub fn noise_floor(data: &Dataset, fit: &ModelFit) -> NoiseFloor {
    let order = used_in_time_order(data, fit);
    let e: Vec<f64> = order.iter().map(|&i| fit.residuals[i]).collect();
    noise_floor_of(&e, data.t.is_some())
}

/// [`noise_floor`] of residuals already in time order.
fn noise_floor_of(e: &[f64], timed: bool) -> NoiseFloor {
    let order = if timed { "time" } else { "input" };
    if e.len() < 3 {
        return NoiseFloor {
            rms: 0.0,
            method: "too few samples to estimate the noise".to_string(),
        };
    }
    let diffs: Vec<f64> = e.windows(2).map(|w| w[1] - w[0]).collect();
    // Differences are centred on zero by construction: MAD about zero.
    let abs: Vec<f64> = diffs.iter().map(|d| d.abs()).collect();
    let rms = finite_or_zero(MAD_TO_SD * median(&abs) / std::f64::consts::SQRT_2);
    NoiseFloor {
        rms,
        method: format!(
            "1.4826·MAD of the differences of consecutive residuals in {order} order, divided by √2 ({} differences): slow structure cancels between neighbours, noise does not, and the MAD ignores spikes",
            diffs.len()
        ),
    }
}

/// The residual `e`'s links to time and to the logged columns not set
/// aside: its slope against time, and each column's line. `column` puts a
/// column of every sample into `e`'s order (None when its length differs).
pub fn links(
    t: Option<&[f64]>,
    covariates: &[Covariate],
    aside: &[SetAside],
    column: impl Fn(&[f64]) -> Option<Vec<f64>>,
    e: &[f64],
) -> (Option<f64>, Vec<CovariateLink>) {
    let time_trend = t
        .and_then(&column)
        .and_then(|t| line(&t, e))
        .map(|(slope, _)| slope);
    let covariates = covariates
        .iter()
        .filter(|c| !aside.iter().any(|a| a.column == c.name))
        .filter_map(|c| {
            let u = column(&c.values)?;
            let (slope, correlation) = line(&u, e)?;
            Some(CovariateLink {
                column: c.name.clone(),
                slope,
                correlation,
                explained: correlation * correlation,
            })
        })
        .collect();
    (time_trend, covariates)
}

/// All the residual diagnostics of a fit. Flagged samples (the `outliers`
/// effect) are left out of every statistic, the tail count included: they
/// are already explained.
pub fn analyse(data: &Dataset, fit: &ModelFit) -> Residuals {
    let order = used_in_time_order(data, fit);
    let e: Vec<f64> = order.iter().map(|&i| fit.residuals[i]).collect();
    let theta: Vec<f64> = order
        .iter()
        .map(|&i| fit.headings.get(i).copied().unwrap_or(0.0))
        .collect();
    let n_all = fit.residuals.len();
    let column = |values: &[f64]| -> Option<Vec<f64>> {
        (values.len() == n_all).then(|| order.iter().map(|&i| values[i]).collect())
    };

    let aside = set_aside(data);
    let timed = data.t.is_some();
    let links = links(data.t.as_deref(), &data.covariates, &aside, column, &e);

    let sd = robust_sd(&e);
    let z = standardized(&e, &theta);
    let tail_max_sd = z.iter().map(|v| v.abs()).fold(0.0, f64::max);

    Residuals {
        harmonics: harmonics(&e, &theta),
        common: ResidualCommon {
            tail_max_sd: finite_or_zero(tail_max_sd),
            ..ResidualCommon::of(&e, &z, sd, links, noise_floor_of(&e, timed))
        },
    }
}

impl ResidualCommon {
    /// From the residual `e` in time order, standardised as `z` (robust SD
    /// `sd`), with its trend in time and links to the logged columns
    /// ([`links`]) and its noise floor.
    pub fn of(
        e: &[f64],
        z: &[f64],
        sd: f64,
        (time_trend, covariates): (Option<f64>, Vec<CovariateLink>),
        noise_floor: NoiseFloor,
    ) -> Self {
        ResidualCommon {
            time_trend,
            time_structure: slow_structure(e),
            covariates,
            tail_count: z.iter().filter(|v| v.abs() > TAIL_SDS).count(),
            tail_expected: e.len() as f64 * GAUSSIAN_TAIL_4SD,
            tail_max_sd: z.iter().map(|v| v.abs()).fold(0.0, f64::max),
            robust_sd: sd,
            noise_floor,
        }
    }
}

/// The median by a sort: what every median found by selection must give
/// (for the tests).
#[cfg(test)]
pub(crate) fn sorted_median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_unstable_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn value() -> impl proptest::strategy::Strategy<Value = f64> {
        use proptest::prelude::*;
        prop_oneof![
            -1e3f64..1e3,
            0.999_999f64..1.000_001,
            (0u8..7).prop_map(f64::from),
            (-3i8..3).prop_map(|k| f64::from(k) * 0.25),
            Just(0.0),
            Just(-0.0),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(f64::NAN),
            Just(-f64::NAN),
            any::<f64>(),
        ]
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 512, ..Default::default() })]

        /// The bounds from a sample find the selection's two middle values,
        /// to the bit, or leave them to it: any values, signed zeros, NaN,
        /// repeats and near ties, samples of every size.
        #[test]
        fn the_middle_about_a_sample_is_the_middle_by_selection(
            values in proptest::prop_oneof![
                proptest::collection::vec(-1e3f64..1e3, 2..12_000),
                proptest::collection::vec(value(), 2..12_000),
            ],
            share in 0.0f64..1.0,
        ) {
            // Samples of every size up to all the values (a large share
            // leaves few between the bounds: the copies are selected among).
            let sample = 2 + (share * (values.len() - 2) as f64) as usize;
            let by_selection = middle_by_selection(&mut values.clone());
            if let Some(found) = middle_by_sample(&values, sample) {
                proptest::prop_assert_eq!(found.0.to_bits(), by_selection.0.to_bits());
                proptest::prop_assert_eq!(found.1.to_bits(), by_selection.1.to_bits());
            }
        }
    }

    /// Past [`SAMPLED_FROM`] values the median is found about a sample,
    /// and is the sort's: an even and an odd count, radii packed about 1,
    /// a quantised axis with many repeats (left to the selection).
    #[test]
    fn a_long_median_is_the_sorted_one() {
        let noise = gaussian(3 * SAMPLED_FROM + 1, 1e-6, 7);
        let radii: Vec<f64> = noise.iter().map(|e| 1.0 + e).collect();
        assert!(middle_by_sample(&radii, middle_sample(radii.len())).is_some());
        let counts: Vec<f64> = noise.iter().map(|e| (e * 2e6).round()).collect();
        assert!(middle_by_sample(&counts, middle_sample(counts.len())).is_none());
        for values in [&radii[..], &radii[1..], &counts[..], &counts[1..]] {
            let m = median_mut(&mut values.to_vec());
            assert_eq!(m.to_bits(), sorted_median(values).to_bits());
        }
    }

    fn gaussian(n: usize, sd: f64, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::new(0.0, sd).unwrap();
        (0..n).map(|_| normal.sample(&mut rng)).collect()
    }

    /// Headings of an uneven turn over `span` radians, and a residual of
    /// harmonics and noise on them.
    fn uneven_turn(seed: u64, n: usize, span: f64) -> (Vec<f64>, Vec<f64>) {
        use rand::RngExt;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = gaussian(n, 1e-3, seed + 100);
        let amp: Vec<f64> = (0..8).map(|_| rng.random_range(-0.02..0.02)).collect();
        let start: f64 = rng.random_range(-3.0..3.0);
        let theta: Vec<f64> = (0..n)
            .map(|i| {
                let u = i as f64 / n as f64;
                // Slower at some headings than others.
                start + span * (u + 0.1 * (u * 7.0).sin() / 7.0)
            })
            .collect();
        let e = theta
            .iter()
            .zip(&noise)
            .map(|(t, w)| {
                (1..=4)
                    .map(|k| {
                        let kt = k as f64 * t;
                        amp[2 * k - 2] * kt.cos() + amp[2 * k - 1] * kt.sin()
                    })
                    .sum::<f64>()
                    + w
            })
            .collect();
        (theta, e)
    }

    #[test]
    fn harmonics_by_normal_equations_match_the_svd_of_the_design() {
        for seed in 0..20 {
            let span = [std::f64::consts::TAU, 5.5, 4.0][seed as usize % 3];
            let (theta, e) = uneven_turn(seed, 3000 + 500 * seed as usize, span);
            let fast = harmonics(&e, &theta);
            let svd = harmonics_by_svd(&e, &theta);
            assert_eq!(fast.len(), 4);
            for (f, s) in fast.iter().zip(&svd) {
                assert!(
                    (f.amplitude - s.amplitude).abs() < 1e-12,
                    "seed {seed}: {fast:?} against {svd:?}"
                );
                if s.amplitude > 1e-4 {
                    assert!((f.phase_deg - s.phase_deg).abs() < 1e-7, "seed {seed}");
                }
            }
        }
    }

    #[test]
    fn a_turn_over_few_headings_is_solved_by_the_svd() {
        // 20° of heading: cos kθ and sin kθ are nearly dependent, and the
        // normal equations would square their condition.
        for seed in 0..5 {
            let (theta, e) = uneven_turn(seed, 2000, 20f64.to_radians());
            assert_eq!(harmonics(&e, &theta), harmonics_by_svd(&e, &theta));
        }
    }

    #[test]
    fn second_harmonic_is_recovered() {
        let n = 360;
        let theta: Vec<f64> = (0..n)
            .map(|i| i as f64 / n as f64 * std::f64::consts::TAU - 3.0)
            .collect();
        let e: Vec<f64> = theta
            .iter()
            .map(|t| 0.02 * (2.0 * t + 30f64.to_radians()).cos())
            .collect();
        let h = harmonics(&e, &theta);
        assert_eq!(h.len(), 4);
        assert!((h[1].amplitude - 0.02).abs() < 1e-9, "{h:?}");
        assert!((h[1].phase_deg - 30.0).abs() < 1e-6, "{h:?}");
        for k in [0, 2, 3] {
            assert!(h[k].amplitude < 1e-9, "{h:?}");
        }
    }

    #[test]
    fn noise_floor_ignores_slow_structure() {
        let n = 400;
        let noise = gaussian(n, 0.003, 7);
        let e: Vec<f64> = noise
            .iter()
            .enumerate()
            .map(|(i, v)| v + 0.02 * (i as f64 / n as f64 * std::f64::consts::TAU * 2.0).sin())
            .collect();
        let floor = noise_floor_of(&e, true);
        assert!((floor.rms / 0.003 - 1.0).abs() < 0.15, "{floor:?}");
        assert!(floor.method.contains("MAD"));
    }

    #[test]
    fn tails_are_counted() {
        let mut e = gaussian(1000, 0.003, 3);
        for i in [10, 200, 555] {
            e[i] += 0.1;
        }
        let m = median(&e);
        let sd = robust_sd(&e);
        assert!((sd / 0.003 - 1.0).abs() < 0.1, "{sd}");
        let tails = e.iter().filter(|v| (*v - m).abs() > TAIL_SDS * sd).count();
        assert!((3..=4).contains(&tails), "{tails}");
    }

    #[test]
    fn covariate_correlation() {
        let n = 200;
        let temp: Vec<f64> = (0..n).map(|i| 20.0 + i as f64 * 0.05).collect();
        let noise = gaussian(n, 0.001, 5);
        let e: Vec<f64> = temp
            .iter()
            .zip(&noise)
            .map(|(t, v)| 0.002 * (t - 25.0) + v)
            .collect();
        let (slope, corr) = line(&temp, &e).unwrap();
        assert!((slope - 0.002).abs() < 2e-4, "{slope}");
        assert!(corr > 0.9, "{corr}");
        assert!(line(&vec![1.0; n], &e).is_none());
    }

    #[test]
    fn copies_constants_and_time_are_set_aside() {
        use crate::sample::Covariate;
        let n = 300;
        let theta: Vec<f64> = (0..n).map(|i| i as f64 * 0.03).collect();
        let noise = gaussian(n, 0.01, 11);
        let x: Vec<f64> = theta.iter().map(|t| 400.0 * t.cos() + 30.0).collect();
        let y: Vec<f64> = theta.iter().map(|t| 380.0 * t.sin() - 10.0).collect();
        let column = |name: &str, values: Vec<f64>| Covariate {
            name: name.into(),
            values,
        };
        let covariates = vec![
            // y again, in µT rounded to 0.1.
            column(
                "y_uT",
                y.iter()
                    .map(|v| (v * 0.092 * 10.0).round() / 10.0)
                    .collect(),
            ),
            // A third axis of a plane tilted by 20°: x and y plus noise.
            column(
                "z",
                x.iter()
                    .zip(&y)
                    .zip(&noise)
                    .map(|((x, y), e)| 0.3 * x - 0.2 * y + 50.0 + e)
                    .collect(),
            ),
            column("supply", vec![5.0; n]),
            column("timestamp", (0..n).map(|i| i as f64).collect()),
            // A real covariate: warms through the run, independent of x, y.
            column("temp", (0..n).map(|i| 20.0 + i as f64 * 0.01).collect()),
        ];
        let data = Dataset::new("x", "y", None, x, y, covariates).unwrap();
        let aside = set_aside(&data);
        let reason = |name: &str| {
            aside
                .iter()
                .find(|a| a.column == name)
                .map(|a| a.reason.clone())
        };
        assert!(
            reason("y_uT")
                .unwrap()
                .starts_with("a copy of y in other units (R² 1.0000)"),
            "{aside:?}"
        );
        assert!(
            reason("z")
                .unwrap()
                .starts_with("a linear combination of x and y"),
            "{aside:?}"
        );
        assert!(
            reason("supply").unwrap().starts_with("constant"),
            "{aside:?}"
        );
        assert!(
            reason("timestamp").unwrap().starts_with("time"),
            "{aside:?}"
        );
        assert_eq!(reason("temp"), None, "{aside:?}");
    }

    #[test]
    fn time_like_names() {
        assert!(is_time_like("time_s") && is_time_like("T") && is_time_like("timestamp"));
        assert!(!is_time_like("temp_c"));
    }
}
