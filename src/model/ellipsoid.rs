//! The 3-D model: calibrated = W·(raw − o), |calibrated| = r.
//!
//! `o` is the hard-iron offset (or the accelerometer's zero-g bias), `W` a
//! symmetric positive definite matrix (gains, cross-axis coupling, soft
//! iron), `r` the field's magnitude. The restricted models carry the names
//! of the 2-D effects of docs/product.md: `offset` (W = I), `offset+scale`
//! (W diagonal: the per-axis gains of the `scale` effect) and
//! `offset+scale+cross-axis` (W full: the `cross-axis` effect's coupling;
//! `full` is accepted as its short name).
//!
//! Identifiability: (W, r) and (cW, cr) calibrate alike, so one scale must
//! be fixed. The fit estimates A = W / r (the map onto the unit sphere,
//! which the data determine uniquely) and reports W = A / det(A)^(1/3),
//! r = 1 / det(A)^(1/3): det W = 1, so W changes shape and not volume, and
//! r is the geometric mean of the ellipsoid's semi-axes, in raw units. For
//! `offset`, W = I and r is the sphere's radius.
//!
//! The fit: the data are centred on their mean and scaled by their rms
//! distance from it (so counts in the tens of thousands and gauss fit
//! alike), then
//! 1. a closed form: for `offset` the linear sphere fit; for
//!    `offset+scale` and the full model Li & Griffiths' ellipsoid-specific
//!    least squares ("Least squares ellipsoid specific fitting", GMP 2004)
//!    with the constraint 4J − I² > 0 (k = 4), on the axis-aligned quadric
//!    for `offset+scale`: the result is an ellipsoid even on a poorly
//!    covered sphere, never a hyperboloid;
//! 2. the coverage rule ([`supports`]): the directions of the points from
//!    the closed-form centre must determine the model's parameters;
//! 3. Levenberg–Marquardt ([`super::lm`]) on the magnitude residual
//!    |A(raw − o)| − 1 (the magnitude error as a fraction of r, as the 2-D
//!    rms), with an iteration cap, and standard errors σ²(JᵀJ)⁻¹ propagated
//!    to o, W, r.

use std::fmt;
use std::str::FromStr;
use std::sync::OnceLock;

use nalgebra::{DMatrix, Matrix3, SymmetricEigen, Vector3};
use serde::Serialize;

use super::calibration3::{Calibration3D, correct3};
use super::lm::{self, LeastSquares, Weighting};
use super::sphere::{self, SphereCoverage};
use crate::sample::{MAX_MAGNITUDE, too_large};

mod closed_form;

use closed_form::{closed_form_scaled, sphere_fit};

/// Cap on Levenberg–Marquardt iterations. From a closed-form start the
/// fit converges in well under 50 on every simulated and real tumble; the
/// cap only stops a pathological input from looping.
pub const MAX_ITERATIONS: usize = 200;

/// Stop when an accepted step lowers the cost by less than this fraction.
pub const RELATIVE_COST_TOLERANCE: f64 = 1e-12;

/// Li & Griffiths' k: the constraint k·J − I² > 0 with k = 4 admits every
/// ellipsoid whose shortest semi-axis is at least half its longest (their
/// section 3). Sensor gains differ by far less (ArduPilot accepts diagonal
/// scale factors only within 1/1.5..1.5: COMPASS_MAX_SCALE_FACTOR).
pub const LI_GRIFFITHS_K: f64 = 4.0;

/// The coverage rule's reference gap: PJRC MotionCal offers a calibration
/// only when its surface gap error is below 15 % of its 100 equal-area
/// regions (`gaps < 15.0f` in its gui.cpp). A model is supported when no
/// parameter is less well determined by the data's directions than by a
/// sphere missing one cap of this share of its area, in the worst of 14
/// orientations (see [`supports`]).
pub const MOTIONCAL_MAX_GAP: f64 = 0.15;

/// A singular value below this fraction of the largest marks a design
/// matrix (on centred, scaled data) as rank-deficient.
const RANK_TOLERANCE: f64 = 1e-10;

/// Which 3-D model to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Ellipsoid3Model {
    /// W = I: offsets and the field's magnitude.
    Offset,
    /// W diagonal: offsets and per-axis gains.
    OffsetScale,
    /// W symmetric: offsets, gains and cross-axis coupling (soft iron).
    Full,
}

impl Ellipsoid3Model {
    /// From the richest to the simplest.
    pub const ALL: [Ellipsoid3Model; 3] = [
        Ellipsoid3Model::Full,
        Ellipsoid3Model::OffsetScale,
        Ellipsoid3Model::Offset,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Ellipsoid3Model::Offset => "offset",
            Ellipsoid3Model::OffsetScale => "offset+scale",
            Ellipsoid3Model::Full => "offset+scale+cross-axis",
        }
    }

    /// Parameters the fit estimates: 3 offsets and 1, 3 or 6 entries of A.
    pub fn unknowns(self) -> usize {
        match self {
            Ellipsoid3Model::Offset => 4,
            Ellipsoid3Model::OffsetScale => 6,
            Ellipsoid3Model::Full => 9,
        }
    }
}

impl fmt::Display for Ellipsoid3Model {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Ellipsoid3Model {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "offset" => Ok(Ellipsoid3Model::Offset),
            "offset+scale" | "paper" => Ok(Ellipsoid3Model::OffsetScale),
            "offset+scale+cross-axis" | "full" => Ok(Ellipsoid3Model::Full),
            other => Err(format!(
                "unknown 3-D model '{other}': choose offset, offset+scale or offset+scale+cross-axis (full)"
            )),
        }
    }
}

/// Standard errors of the reported parameters, in their units. Entries a
/// model fixes (W = I, off-diagonals of a diagonal W) are 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Ellipsoid3Se {
    pub offset: [f64; 3],
    pub matrix: [[f64; 3]; 3],
    pub r: f64,
}

/// A fitted 3-D calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ellipsoid3Fit {
    pub model: Ellipsoid3Model,
    /// o, raw units.
    pub offset: [f64; 3],
    /// W, row-major, symmetric, det W = 1 (W = I for `offset`).
    pub matrix: [[f64; 3]; 3],
    /// The field's magnitude, raw units.
    pub r: f64,
    /// Root mean square of |W(raw − o)|/r − 1.
    pub rms: f64,
    /// Samples fitted.
    pub n: usize,
    pub se: Ellipsoid3Se,
    /// Directions of the calibrated samples on the sphere.
    pub coverage: SphereCoverage,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
}

impl Ellipsoid3Fit {
    /// W·(raw − o).
    pub fn apply(&self, raw: [f64; 3]) -> [f64; 3] {
        correct3(&self.offset, &self.matrix, raw)
    }

    /// The calibration the fit found (o, W, r), without the fit's report.
    pub fn calibration(&self) -> Calibration3D {
        Calibration3D {
            offset: self.offset,
            matrix: self.matrix,
            r: self.r,
        }
    }

    /// |W(raw − o)|/r − 1.
    pub fn magnitude_error(&self, raw: [f64; 3]) -> f64 {
        let c = self.apply(raw);
        (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() / self.r - 1.0
    }
}

/// Why a 3-D fit gave no calibration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Ellipsoid3Error {
    #[error(
        "{} too few for the {model} model: it has {unknowns} unknowns and needs at least {needed} samples; record a longer tumble",
        crate::sample::count_is(*found as u64, "sample")
    )]
    TooFewSamples {
        model: Ellipsoid3Model,
        found: usize,
        unknowns: usize,
        needed: usize,
    },
    #[error(
        "reading {index} of axis {axis} is not a finite number ({value}); remove it from the recording"
    )]
    NonFinite {
        index: usize,
        axis: &'static str,
        value: f64,
    },
    #[error(
        "reading {index} of axis {axis} is {value:e}: too large to square in f64 (readings must stay within ±{max:e}); give counts or physical units",
        max = MAX_MAGNITUDE
    )]
    TooLarge {
        index: usize,
        axis: &'static str,
        value: f64,
    },
    #[error(
        "the readings are degenerate: they lie on a point, a line or a plane, or fit no ellipsoid; tumble the sensor through every direction in a constant field"
    )]
    Degenerate,
    #[error(
        "the readings spread over {spread:.1e} (their rms distance from their mean), outside the {min:.0e} to {max:.0e} the 3-D fit computes in; the farthest, ({:.3e}, {:.3e}, {:.3e}), lies {distance:.1e} from their mean: if it alone is off, it is a spike to remove, else give the readings in the sensor's counts or in physical units",
        farthest[0],
        farthest[1],
        farthest[2],
        min = MIN_SPREAD,
        max = MAX_SPREAD
    )]
    OutOfRange {
        spread: f64,
        farthest: [f64; 3],
        distance: f64,
    },
    #[error(
        "the readings cover {percent:.0} % of the sphere of directions, too little to determine the {model} model; {missing}; {}{}",
        match supported {
            Some(m) => format!("the data still support the {m} model (choose it, or tumble the sensor through the missing directions)"),
            None => "the data support no 3-D model: tumble the sensor through the missing directions".to_string(),
        },
        match plane {
            Some(p) => format!(" ({p})"),
            None => String::new(),
        }
    )]
    NotCovered {
        model: Ellipsoid3Model,
        percent: f64,
        missing: String,
        supported: Option<Ellipsoid3Model>,
        /// When the directions lie near one plane (a turn, not a tumble):
        /// which, and what to do.
        plane: Option<String>,
    },
    #[error(
        "the fit did not converge within {iterations} iterations; the readings may not be a sensor turning in a constant field"
    )]
    NoConvergence { iterations: usize },
}

/// A quadric's ellipsoid in the scaled frame: centre `o`, map `a` onto the
/// unit sphere.
#[derive(Debug, Clone, Copy)]
pub(super) struct Ellipsoid {
    pub(super) o: Vector3<f64>,
    pub(super) a: Matrix3<f64>,
}

/// The spread of readings the 3-D fit computes in. It works in the scaled
/// frame, but its report goes back to raw units through powers of the
/// scale, which leave f64 beyond about 1e±100 (a tumble of radius 1e120 or
/// 1e-120 fails there; 1e±100 is fitted). These bounds keep a factor of
/// 1e50 from that, and every sensor's counts or physical units (a
/// nanotesla is 1e-9, a count of a 32-bit ADC at most 2e9) lie far inside.
pub const MIN_SPREAD: f64 = 1e-50;
pub const MAX_SPREAD: f64 = 1e50;

/// Points centred and scaled, with the mean m and the scale s.
type Normalised = (Vec<Vector3<f64>>, Vector3<f64>, f64);

/// Checks the points and returns them centred and scaled: p = (raw − m)/s.
fn normalise(points: &[[f64; 3]], model: Ellipsoid3Model) -> Result<Normalised, Ellipsoid3Error> {
    for (index, p) in points.iter().enumerate() {
        for (value, axis) in p.iter().zip(["x", "y", "z"]) {
            if !value.is_finite() {
                return Err(Ellipsoid3Error::NonFinite {
                    index,
                    axis,
                    value: *value,
                });
            }
            if too_large(*value) {
                return Err(Ellipsoid3Error::TooLarge {
                    index,
                    axis,
                    value: *value,
                });
            }
        }
    }
    // One sample more than unknowns, so the residual has a variance.
    let needed = model.unknowns() + 1;
    if points.len() < needed {
        return Err(Ellipsoid3Error::TooFewSamples {
            model,
            found: points.len(),
            unknowns: model.unknowns(),
            needed,
        });
    }
    if points.iter().all(|p| p == &points[0]) {
        return Err(Ellipsoid3Error::Degenerate);
    }
    let (mean, spread) = mean_and_spread(points)?;
    if !(MIN_SPREAD..=MAX_SPREAD).contains(&spread) {
        let (farthest, distance) = points
            .iter()
            .map(|p| (*p, (Vector3::from(*p) - mean).norm()))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or(([f64::NAN; 3], spread));
        return Err(Ellipsoid3Error::OutOfRange {
            spread,
            farthest,
            distance,
        });
    }
    let scaled = points
        .iter()
        .map(|p| (Vector3::from(*p) - mean) / spread)
        .collect();
    Ok((scaled, mean, spread))
}

/// The points' mean m and their rms distance s from it: the frame the fit
/// works in, p = (raw − m)/s. Degenerate when s is zero or not finite.
pub(super) fn mean_and_spread(points: &[[f64; 3]]) -> Result<(Vector3<f64>, f64), Ellipsoid3Error> {
    let n = points.len() as f64;
    let mut mean = Vector3::zeros();
    for p in points {
        mean += Vector3::from(*p) / n;
    }
    let spread = (points
        .iter()
        .map(|p| (Vector3::from(*p) - mean).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    if !(spread > 0.0) || !spread.is_finite() {
        return Err(Ellipsoid3Error::Degenerate);
    }
    Ok((mean, spread))
}

/// The closed-form (algebraic) fit alone, in raw units: (o, A) with
/// A(raw − o) on the unit sphere. For tests and as a start.
pub fn closed_form(
    points: &[[f64; 3]],
    model: Ellipsoid3Model,
) -> Result<([f64; 3], [[f64; 3]; 3]), Ellipsoid3Error> {
    let (p, mean, spread) = normalise(points, model)?;
    let e = closed_form_scaled(&p, model)?;
    let o = mean + e.o * spread;
    let a = e.a / spread;
    Ok((o.into(), to_rows(&a)))
}

fn to_rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [m[(i, 0)], m[(i, 1)], m[(i, 2)]])
}

/// The parameter vector of a model: o (3), then A's free entries.
pub(super) fn pack(model: Ellipsoid3Model, e: &Ellipsoid) -> Vec<f64> {
    let mut v = vec![e.o[0], e.o[1], e.o[2]];
    match model {
        Ellipsoid3Model::Offset => v.push(e.a.trace() / 3.0),
        Ellipsoid3Model::OffsetScale => v.extend([e.a[(0, 0)], e.a[(1, 1)], e.a[(2, 2)]]),
        Ellipsoid3Model::Full => v.extend([
            e.a[(0, 0)],
            e.a[(1, 1)],
            e.a[(2, 2)],
            e.a[(1, 2)],
            e.a[(0, 2)],
            e.a[(0, 1)],
        ]),
    }
    v
}

fn unpack(model: Ellipsoid3Model, v: &[f64]) -> Ellipsoid {
    let o = Vector3::new(v[0], v[1], v[2]);
    Ellipsoid {
        o,
        a: packed_matrix(model, v),
    }
}

/// A of a packed parameter vector (its entries after the 3 offsets; any
/// parameters past the model's are ignored).
pub(super) fn packed_matrix(model: Ellipsoid3Model, v: &[f64]) -> Matrix3<f64> {
    match model {
        Ellipsoid3Model::Offset => Matrix3::identity() * v[3],
        Ellipsoid3Model::OffsetScale => Matrix3::from_diagonal(&Vector3::new(v[3], v[4], v[5])),
        Ellipsoid3Model::Full => Matrix3::new(v[3], v[8], v[7], v[8], v[4], v[6], v[7], v[6], v[5]),
    }
}

/// Residual |A(p − o)| − 1 and, when asked, its gradient in the packed
/// parameters.
fn residual(
    model: Ellipsoid3Model,
    e: &Ellipsoid,
    p: &Vector3<f64>,
    row: Option<&mut [f64]>,
) -> f64 {
    let d = p - e.o;
    let v = e.a * d;
    let norm = v.norm();
    if let Some(row) = row {
        let safe = norm.max(f64::MIN_POSITIVE);
        let g_o = -(e.a * v) / safe;
        row[..3].copy_from_slice(g_o.as_slice());
        gradient_in_matrix(model, &v, &d, safe, &mut row[3..]);
    }
    norm - 1.0
}

/// The derivatives of |A d| in A's free entries (in packed order), into
/// `row`: `v` = A d, `safe` = |A d| kept off zero.
pub(super) fn gradient_in_matrix(
    model: Ellipsoid3Model,
    v: &Vector3<f64>,
    d: &Vector3<f64>,
    safe: f64,
    row: &mut [f64],
) {
    match model {
        Ellipsoid3Model::Offset => row[0] = d.norm(),
        Ellipsoid3Model::OffsetScale => {
            for j in 0..3 {
                row[j] = v[j] * d[j] / safe;
            }
        }
        Ellipsoid3Model::Full => {
            for j in 0..3 {
                row[j] = v[j] * d[j] / safe;
            }
            // (1,2), (0,2), (0,1)
            for (slot, (j, k)) in [(1, 2), (0, 2), (0, 1)].into_iter().enumerate() {
                row[3 + slot] = (v[j] * d[k] + v[k] * d[j]) / safe;
            }
        }
    }
}

/// The fit of one model to scaled points, as a least-squares problem.
struct Refinement<'a> {
    model: Ellipsoid3Model,
    points: &'a [Vector3<f64>],
}

impl LeastSquares for Refinement<'_> {
    type Shared = Ellipsoid;

    fn shared(&self, v: &[f64]) -> Ellipsoid {
        unpack(self.model, v)
    }

    fn residual(&self, e: &Ellipsoid, _: &[f64], i: usize, row: Option<&mut [f64]>) -> f64 {
        residual(self.model, e, &self.points[i], row)
    }
}

/// Levenberg–Marquardt as the 3-D base fit runs it: unweighted, from the
/// closed form, every curvature damped by at least λ·[`f64::MIN_POSITIVE`].
const LM_OPTIONS: lm::Options = lm::Options {
    max_iterations: MAX_ITERATIONS,
    tolerance: RELATIVE_COST_TOLERANCE,
    weighting: Weighting::EverySample,
    require_curvature: false,
    damping_floor: Some(f64::MIN_POSITIVE),
    step_tolerance: None,
    positive: None,
    lower_damping_on_stop: true,
    // From the closed form nearly every trial is accepted: each is judged
    // by its normal equations (the same cost to the bit), which the next
    // step and the covariance need anyway.
    trials_by_equations: true,
};

/// The reported parameters (o[3], W row-major[9], r) of packed scaled ones.
pub(super) fn report(
    model: Ellipsoid3Model,
    v: &[f64],
    mean: &Vector3<f64>,
    spread: f64,
) -> Option<Vec<f64>> {
    let e = unpack(model, v);
    let a = e.a / spread;
    let det = a.determinant();
    if !(det > 0.0) {
        return None;
    }
    let c = det.cbrt();
    let w = a / c;
    let o = mean + e.o * spread;
    let mut out = vec![o[0], o[1], o[2]];
    for i in 0..3 {
        for j in 0..3 {
            out.push(w[(i, j)]);
        }
    }
    out.push(1.0 / c);
    Some(out)
}

/// Rows of the residual's gradient for unit directions u on the unit sphere
/// (A = I, o = 0): the information a direction carries about each packed
/// parameter.
fn direction_row(model: Ellipsoid3Model, u: &Vector3<f64>, row: &mut [f64]) {
    let e = Ellipsoid {
        o: Vector3::zeros(),
        a: Matrix3::identity(),
    };
    residual(model, &e, u, Some(row));
}

/// Per-parameter variance (times n, at unit noise) that directions give
/// the model's parameters: diag((Σ rowsᵀrows / n)⁻¹). `None` when the
/// directions do not determine them.
fn variances(model: Ellipsoid3Model, directions: &[Vector3<f64>]) -> Option<Vec<f64>> {
    let k = model.unknowns();
    if directions.len() < k {
        return None;
    }
    let mut info = DMatrix::<f64>::zeros(k, k);
    let mut row = vec![0.0; k];
    for u in directions {
        direction_row(model, u, &mut row);
        for a in 0..k {
            for b in 0..k {
                info[(a, b)] += row[a] * row[b];
            }
        }
    }
    info /= directions.len() as f64;
    let scale = (0..k).map(|j| info[(j, j)]).fold(0.0, f64::max);
    let eig = SymmetricEigen::new(info.clone());
    if eig.eigenvalues.min() <= scale * RANK_TOLERANCE {
        return None;
    }
    let inv = info.try_inverse()?;
    Some((0..k).map(|j| inv[(j, j)]).collect())
}

/// The worst per-parameter variance over a sphere missing a cap of
/// [`MOTIONCAL_MAX_GAP`] of its area about each of 14 directions (the 6
/// axes and 8 octant diagonals), computed once per model.
fn reference_variances(model: Ellipsoid3Model) -> &'static [f64] {
    static CACHE: [OnceLock<Vec<f64>>; 3] = [OnceLock::new(), OnceLock::new(), OnceLock::new()];
    let slot = match model {
        Ellipsoid3Model::Offset => 0,
        Ellipsoid3Model::OffsetScale => 1,
        Ellipsoid3Model::Full => 2,
    };
    CACHE[slot].get_or_init(|| compute_reference_variances(model))
}

fn compute_reference_variances(model: Ellipsoid3Model) -> Vec<f64> {
    let lattice: Vec<Vector3<f64>> = (0..sphere::REGIONS)
        .map(|k| Vector3::from(sphere::region(k).centre))
        .collect();
    // A cap of area fraction g about axis c: cos(angle) > 1 − 2g.
    let limit = 1.0 - 2.0 * MOTIONCAL_MAX_GAP;
    let mut axes: Vec<Vector3<f64>> = Vec::new();
    for i in 0..3 {
        for s in [1.0, -1.0] {
            let mut v = Vector3::zeros();
            v[i] = s;
            axes.push(v);
        }
    }
    for sx in [1.0, -1.0] {
        for sy in [1.0, -1.0] {
            for sz in [1.0, -1.0] {
                axes.push(Vector3::new(sx, sy, sz).normalize());
            }
        }
    }
    let mut worst = vec![0.0; model.unknowns()];
    for c in &axes {
        let kept: Vec<Vector3<f64>> = lattice
            .iter()
            .filter(|u| u.dot(c) <= limit)
            .copied()
            .collect();
        if let Some(v) = variances(model, &kept) {
            for (w, x) in worst.iter_mut().zip(v) {
                *w = f64::max(*w, x);
            }
        }
    }
    worst
}

/// Whether the directions `directions` (of the calibrated samples) cover
/// enough of the sphere to determine `model`.
///
/// The rule judges coverage, not density (a hand dwells on some
/// directions): each region of [`sphere`]'s equal-area partition that
/// holds a sample stands for one unit direction, its centre. The model is
/// supported when every one of its parameters is at least as well
/// determined by those directions (the diagonal of (Σ gᵀg / m)⁻¹, g the
/// residual's gradient at a unit sphere) as by the partition's centres
/// less a cap of [`MOTIONCAL_MAX_GAP`] of the sphere, the largest gap
/// MotionCal accepts, placed where it hurts that parameter most (about any
/// of the 6 axes and 8 octant diagonals). A ring in a plane supports no
/// model (the offset along its normal is free); a 40° cap or a half sphere
/// determine even a sphere's offset far worse than an 85 % sphere, so they
/// are refused too; scattered gaps of a few regions are not.
///
/// A restricted model is supported whenever a richer one is (its
/// parameters are a subset, fixed at values the richer fit could reach).
pub fn supports(model: Ellipsoid3Model, directions: &[[f64; 3]]) -> bool {
    supports_covered(model, &sphere::coverage(directions.iter().copied()))
}

/// [`supports`], given the directions' coverage of the sphere.
pub fn supports_covered(model: Ellipsoid3Model, covered: &sphere::SphereCoverage) -> bool {
    Ellipsoid3Model::ALL
        .into_iter()
        .filter(|m| m.unknowns() >= model.unknowns())
        .any(|m| determines(m, covered))
}

/// The rule of [`supports`] for one model alone.
fn determines(model: Ellipsoid3Model, covered: &sphere::SphereCoverage) -> bool {
    let centres: Vec<Vector3<f64>> = (0..sphere::REGIONS)
        .filter(|&k| covered.reached[k])
        .map(|k| Vector3::from(sphere::region(k).centre))
        .collect();
    let Some(v) = variances(model, &centres) else {
        return false;
    };
    let reference = reference_variances(model);
    v.iter().zip(reference).all(|(x, r)| x <= r)
}

/// The richest model the directions support, if any.
pub fn best_supported(directions: &[[f64; 3]]) -> Option<Ellipsoid3Model> {
    let covered = sphere::coverage(directions.iter().copied());
    let mut models = Ellipsoid3Model::ALL.into_iter();
    models.find(|&m| supports_covered(m, &covered))
}

fn directions_about(p: &[Vector3<f64>], e: &Ellipsoid) -> Vec<[f64; 3]> {
    p.iter().map(|pi| (e.a * (pi - e.o)).into()).collect()
}

/// The coverage of [`directions_about`], without keeping the directions.
fn coverage_about(p: &[Vector3<f64>], e: &Ellipsoid) -> SphereCoverage {
    sphere::coverage(p.iter().map(|pi| (e.a * (pi - e.o)).into()))
}

/// Fits the 3-D `model` to raw readings: closed form, coverage rule,
/// Levenberg–Marquardt, standard errors.
pub fn fit(points: &[[f64; 3]], model: Ellipsoid3Model) -> Result<Ellipsoid3Fit, Ellipsoid3Error> {
    let r = refine(points, model)?;
    // Standard errors: cov propagated to the reported parameters by
    // central differences of `report`.
    let cov_out = propagate(&r.v, r.cov, r.out.len(), |v| {
        report(model, v, &r.mean, r.spread)
    });
    let se = base_se(&cov_out);
    let coverage = coverage_about(&r.p, &unpack(model, &r.v));
    let n = points.len();
    Ok(Ellipsoid3Fit {
        model,
        offset: [r.out[0], r.out[1], r.out[2]],
        matrix: reported_matrix(&r.out),
        r: r.out[12],
        rms: (r.rss / n as f64).sqrt(),
        n,
        se,
        coverage,
        iterations: r.iterations,
    })
}

/// What a model's fit leaves to compare it with others: its rms and its r.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitSummary {
    pub rms: f64,
    pub r: f64,
}

/// [`fit`]'s rms and r alone (the same figures, and the same refusals),
/// without the standard errors and the fitted directions' coverage.
pub fn fit_summary(
    points: &[[f64; 3]],
    model: Ellipsoid3Model,
) -> Result<FitSummary, Ellipsoid3Error> {
    let refined = refine(points, model)?;
    Ok(FitSummary {
        rms: (refined.rss / points.len() as f64).sqrt(),
        r: refined.out[12],
    })
}

/// A fit refined by Levenberg–Marquardt, in the scaled frame.
struct Refined {
    /// The scaled points, their mean and their scale.
    p: Vec<Vector3<f64>>,
    mean: Vector3<f64>,
    spread: f64,
    /// The packed parameters, and the reported ones (o, W row-major, r).
    v: Vec<f64>,
    out: Vec<f64>,
    /// The sum of squared residuals, and σ²(JᵀJ)⁻¹ of the packed ones.
    rss: f64,
    cov: DMatrix<f64>,
    iterations: usize,
}

/// The fit up to its parameters: closed form, coverage rule,
/// Levenberg–Marquardt, the parameters' covariance.
fn refine(points: &[[f64; 3]], model: Ellipsoid3Model) -> Result<Refined, Ellipsoid3Error> {
    let (p, mean, spread) = normalise(points, model)?;
    let start = match closed_form_scaled(&p, model) {
        Ok(e) => e,
        Err(error) => {
            // No ellipsoid of this model: say which directions are missing
            // about the sphere fit's centre, or the cloud's mean.
            let about = sphere_fit(&p).unwrap_or(Ellipsoid {
                o: Vector3::zeros(),
                a: Matrix3::identity(),
            });
            let dirs = directions_about(&p, &about);
            if !supports(model, &dirs) {
                return Err(not_covered(model, &dirs, &p));
            }
            return Err(error);
        }
    };
    if !supports_covered(model, &coverage_about(&p, &start)) {
        return Err(not_covered(model, &directions_about(&p, &start), &p));
    }
    let mut v = pack(model, &start);
    let refinement = Refinement { model, points: &p };
    let weights = vec![1.0; p.len()];
    let solved =
        lm::solve(&refinement, &mut v, &weights, &mut 1e-3, 0, &LM_OPTIONS).map_err(|failure| {
            match failure {
                lm::Failure::NoConvergence { iterations } => {
                    Ellipsoid3Error::NoConvergence { iterations }
                }
                // Not asked for: LM_OPTIONS.require_curvature is false.
                lm::Failure::Undetermined { .. } => Ellipsoid3Error::Degenerate,
            }
        })?;
    let iterations = solved.iterations;
    // The equations at the end, as computed again here they would be.
    let lm::NormalEquations { jtj, cost: rss, .. } = solved
        .equations
        .unwrap_or_else(|| lm::normal_equations(&refinement, &v, &weights, Weighting::EverySample));
    let n = points.len();
    let k = model.unknowns();
    let out = report(model, &v, &mean, spread).ok_or(Ellipsoid3Error::Degenerate)?;
    if out.iter().any(|x| !x.is_finite()) {
        return Err(Ellipsoid3Error::Degenerate);
    }
    // cov = σ²(JᵀJ)⁻¹ in the packed scaled parameters.
    let sigma2 = rss / (n - k) as f64;
    let cov = jtj.try_inverse().ok_or(Ellipsoid3Error::Degenerate)? * sigma2;
    Ok(Refined {
        p,
        mean,
        spread,
        v,
        out,
        rss,
        cov,
        iterations,
    })
}

/// The covariance `cov` of the packed parameters `v` propagated to the
/// `m` reported ones, by central differences of `report`.
pub(super) fn propagate(
    v: &[f64],
    cov: DMatrix<f64>,
    m: usize,
    report: impl Fn(&[f64]) -> Option<Vec<f64>>,
) -> DMatrix<f64> {
    let k = v.len();
    let mut g = DMatrix::<f64>::zeros(m, k);
    for j in 0..k {
        let h = 1e-6 * v[j].abs().max(1e-3);
        let mut plus = v.to_vec();
        let mut minus = v.to_vec();
        plus[j] += h;
        minus[j] -= h;
        if let (Some(a), Some(b)) = (report(&plus), report(&minus)) {
            for i in 0..m {
                g[(i, j)] = (a[i] - b[i]) / (2.0 * h);
            }
        }
    }
    &g * cov * g.transpose()
}

/// The standard error of reported parameter i (o, W row-major, r, ...) of
/// the reported covariance.
pub(super) fn reported_se(cov_out: &DMatrix<f64>, i: usize) -> f64 {
    cov_out[(i, i)].max(0.0).sqrt()
}

/// The standard errors of o, W and r of the reported covariance.
pub(super) fn base_se(cov_out: &DMatrix<f64>) -> Ellipsoid3Se {
    let se_of = |i: usize| reported_se(cov_out, i);
    Ellipsoid3Se {
        offset: [se_of(0), se_of(1), se_of(2)],
        matrix: [0, 1, 2].map(|i| [0, 1, 2].map(|j| se_of(3 + 3 * i + j))),
        r: se_of(12),
    }
}

/// W, row-major, of the reported parameters (o, W row-major, r, ...).
pub(super) fn reported_matrix(out: &[f64]) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| out[3 + 3 * i + j]))
}

fn not_covered(model: Ellipsoid3Model, dirs: &[[f64; 3]], p: &[Vector3<f64>]) -> Ellipsoid3Error {
    let coverage = sphere::coverage(dirs.iter().copied());
    Ellipsoid3Error::NotCovered {
        model,
        percent: coverage.fraction * 100.0,
        missing: coverage.missing_text(),
        supported: best_supported(dirs),
        plane: plane_of(p),
    }
}

/// Points within this rms fraction of their spread from one plane are a
/// turn: sin²(13°) of the field, as a hand-held turn wobbles by about ±10°
/// (the sunsided set's turns); a tumble spreads its points evenly (1/3 of
/// the spread along every axis).
const PLANE_MAX_OUT: f64 = 0.05;
/// ... spread within the plane (an ellipse, not a line): at least half of
/// an even ring's 1/2 along each in-plane axis.
const PLANE_MIN_IN: f64 = 0.25;
/// ... and round it, not filling it: at most this fraction of the points
/// within half the rms radius of their centre. A ring has none there (an
/// ellipse whose axes differ by up to 2×, a gain error far beyond any
/// sensor's, keeps every point beyond 0.63 of its rms radius); a cap of
/// directions seen flat is a disc, with 12.5 % there if evenly filled.
const PLANE_MAX_INSIDE: f64 = 0.05;

/// When the points (centred on their mean) lie near one plane round its
/// centre, as a turn does: the plane's normal axis and the advice (fit the
/// two axes of the plane in 2-D, or tumble).
fn plane_of(p: &[Vector3<f64>]) -> Option<String> {
    if p.is_empty() {
        return None;
    }
    let mean = p.iter().sum::<Vector3<f64>>() / p.len() as f64;
    let mut s = Matrix3::<f64>::zeros();
    for v in p {
        let d = v - mean;
        s += d * d.transpose();
    }
    let trace = s.trace();
    if !(trace > 0.0 && trace.is_finite()) {
        return None;
    }
    s /= trace;
    let eig = nalgebra::SymmetricEigen::new(s);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let (low, mid) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
    if !(low < PLANE_MAX_OUT && mid > PLANE_MIN_IN) {
        return None;
    }
    let normal = eig.eigenvectors.column(order[0]).into_owned();
    let radius2: Vec<f64> = p
        .iter()
        .map(|v| {
            let d = v - mean;
            (d - normal * normal.dot(&d)).norm_squared()
        })
        .collect();
    let rms2 = radius2.iter().sum::<f64>() / radius2.len() as f64;
    let inside = radius2.iter().filter(|&&r2| r2 < 0.25 * rms2).count();
    if inside as f64 > PLANE_MAX_INSIDE * radius2.len() as f64 {
        return None;
    }
    let k = normal.iamax();
    let names = ["x", "y", "z"];
    let others: Vec<&str> = (0..3).filter(|&i| i != k).map(|i| names[i]).collect();
    let out_deg = low.sqrt().asin().to_degrees();
    Some(format!(
        "the readings lie within {out_deg:.0}° rms of one plane, about the {} axis: a turn, not a tumble; to calibrate a turn fit the two axes that turned in 2-D (--x and --y, e.g. the {} and {} columns), or tumble the sensor",
        names[k], others[0], others[1]
    ))
}
