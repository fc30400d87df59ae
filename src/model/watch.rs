//! Watching a calibration after it is accepted: each later rotation of a
//! 2-axis sensor is fitted with the same model and compared with the
//! calibration by `check`'s statistics ([`super::check`]), and either
//! agrees (and may refine it), or shows it stale.
//!
//! Pure functions on plain data: the daemon's plane fits the rotation,
//! calls [`compare`], and acts on the [`Comparison`].
//!
//! - **z per parameter.** z = Δ / sqrt(se_stored² + se_now²), both
//!   standard errors widened for residuals correlated in time
//!   ([`se_inflation`] of each fit's own residuals), against the
//!   Bonferroni threshold that keeps the family-wise false alarm at
//!   [`FAMILY_FALSE_ALARM`] per comparison ([`moved_threshold`]).
//! - **What matters physically.** A parameter can move beyond its SE and
//!   still change the heading by less than one reading's own noise (a
//!   temperature drift within the noise): the calibration is then not
//!   stale, since correcting it would change no heading by more than the
//!   sensor's scatter. Stale needs both: a move beyond the threshold, and a
//!   heading error from it (the largest over the rotation, old calibration
//!   against the new fit) beyond [`NOISE_SIGMAS`] times the heading noise
//!   of one reading, the band its own scatter fills. The
//!   heading noise of a reading whose magnitude scatters by a fraction σ
//!   (the smaller rms of the two fits) is σ radians: isotropic noise of that size moves the
//!   point as much across the radius as along it.
//! - **3-D.** A 3-axis sensor's later covered sphere is compared the same
//!   way, parameter by parameter (o, the six entries of the symmetric W,
//!   r: [`sphere_refit`]); the physical gate is the largest angle between
//!   the two corrections of one of the sphere's samples
//!   ([`direction_error_deg`]), which bounds the heading error the move
//!   causes, against the same 3 σ of one reading's noise.
//! - **Refining.** Two fits that agree are combined per parameter by
//!   inverse variance: value = Σ wᵢvᵢ / Σ wᵢ with wᵢ = 1/seᵢ², se =
//!   1/sqrt(Σ wᵢ). Ten agreeing rotations shrink each SE by about √11.

use std::collections::BTreeMap;

use serde::Serialize;

use super::calibration::{Calibration, Ellipsoid3Params, paper_parameters};
use super::check::{FAMILY_FALSE_ALARM, ParamShift, moved_threshold};
use super::ellipsoid::Ellipsoid3Fit;
use super::fit::FitReport;
use super::nonlinear::Param;
use super::paper::closed_form_se;

pub use super::check::{lag1_autocorrelation, se_inflation};

/// A move is stale when its heading error leaves the ±3σ band of one
/// reading's heading noise.
pub const NOISE_SIGMAS: f64 = 3.0;

/// A refit whose rms is at most this many times the stale calibration's
/// is clean (the same sensor's noise, within what two turns' or spheres'
/// rms differ by); beyond, it straddled the change and calibrates nothing.
pub const CLEAN_RMS_FACTOR: f64 = 2.0;

/// Calibrations kept behind the current one (for `rollback`), oldest
/// dropped first.
pub const HISTORY: usize = 10;

/// A later rotation's fit of a calibration's model.
#[derive(Debug, Clone, PartialEq)]
pub struct Refit {
    /// Its parameters, with standard errors already widened for its
    /// residuals' correlation in time.
    pub params: Vec<Param>,
    /// Its magnitude rms (fraction of r).
    pub rms: f64,
}

/// A calibration against a later rotation's fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    /// Each parameter both have: stored, now, and z.
    pub parameters: Vec<ParamShift>,
    pub z_threshold: f64,
    pub family_false_alarm: f64,
    /// The largest heading difference over the rotation between the stored
    /// calibration and the new fit, degrees.
    pub heading_error_deg: f64,
    /// The heading noise of one reading, degrees: the smaller rms of the
    /// two fits as an angle (a rotation that a disturbance crossed
    /// scatters more than the sensor does).
    pub heading_noise_deg: f64,
    /// The heading error beyond which a move is stale:
    /// [`NOISE_SIGMAS`] × `heading_noise_deg`.
    pub heading_limit_deg: f64,
    /// Whether the stored calibration gave no standard errors of its own
    /// (one loaded from an older state file): the new fit's were used for
    /// both, as the same sensor turned the same way.
    pub stored_se_assumed: bool,
}

impl Comparison {
    /// No parameter moved beyond the threshold.
    pub fn agrees(&self) -> bool {
        !self.parameters.iter().any(|p| p.moved)
    }

    /// A parameter moved, and the move turns the heading beyond the band a
    /// reading's noise fills.
    pub fn stale(&self) -> bool {
        !self.agrees() && self.heading_error_deg > self.heading_limit_deg
    }

    /// "b 12.0 → 31.5 (z 14.2), d …" for the moved parameters.
    pub fn moved_text(&self) -> String {
        let sig = |v: f64| crate::numfmt::significant(v, 4);
        self.parameters
            .iter()
            .filter(|p| p.moved)
            .map(|p| {
                format!(
                    "{} {} → {} (z {:.1})",
                    p.name,
                    sig(p.stored),
                    sig(p.refitted),
                    p.z
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// A fit's parameters with their standard errors widened for its
/// `residuals`' correlation in time (in time order), as kept with a
/// calibration and compared by [`compare`].
pub fn widened(mut params: Vec<Param>, residuals: &[f64], rms: f64) -> Refit {
    let inflation = se_inflation(lag1_autocorrelation(residuals));
    for p in &mut params {
        p.se *= inflation;
    }
    Refit { params, rms }
}

/// The paper's closed-form fit `report` of the samples `x`, `y` (in time
/// order) as a [`Refit`]: its parameters with their least-squares standard
/// errors, widened. O(n).
pub fn paper_refit(x: &[f64], y: &[f64], report: &FitReport) -> Refit {
    let c = report.calibration;
    let se = closed_form_se(x, y, &report.theta);
    let residuals: Vec<f64> = x
        .iter()
        .zip(y)
        .map(|(&x, &y)| c.magnitude_error(x, y))
        .collect();
    widened(paper_parameters(&c, se.as_ref()), &residuals, report.rms)
}

/// A 3-axis calibration's parameters by name: the offset o, the entries
/// of the symmetric W on and above its diagonal, r.
pub const NAMES3: [&str; 10] = [
    "o_x", "o_y", "o_z", "w_xx", "w_xy", "w_xz", "w_yy", "w_yz", "w_zz", "r",
];

/// The values of [`NAMES3`] of `o`, `w`, `r`.
fn values3(o: &[f64; 3], w: &[[f64; 3]; 3], r: f64) -> [f64; 10] {
    [
        o[0], o[1], o[2], w[0][0], w[0][1], w[0][2], w[1][1], w[1][2], w[2][2], r,
    ]
}

/// A later sphere's 3-D fit as a [`Refit`]: the parameters its model fits
/// (those with a standard error; W = I of `offset` has none), their
/// standard errors widened for its `residuals`' correlation (the sphere's
/// samples in time order).
pub fn sphere_refit(fit: &Ellipsoid3Fit, residuals: &[f64]) -> Refit {
    let values = values3(&fit.offset, &fit.matrix, fit.r);
    let ses = values3(&fit.se.offset, &fit.se.matrix, fit.se.r);
    let params = NAMES3
        .iter()
        .zip(values.iter().zip(ses))
        .filter(|(_, (_, se))| se.is_finite() && *se > 0.0)
        .map(|(name, (&value, se))| Param {
            name: (*name).to_string(),
            value,
            se,
        })
        .collect();
    widened(params, residuals, fit.rms)
}

/// The largest angle between two 3-D corrections of the same samples,
/// degrees: a bound on the heading error between them (a reading's
/// direction turned by α turns its heading by about α / cos(dip) at most
/// in the horizontal, and by α when level).
pub fn direction_error_deg(a: &Ellipsoid3Params, b: &Ellipsoid3Params, points: &[[f64; 3]]) -> f64 {
    points.iter().fold(0.0f64, |worst, p| {
        let (u, v) = (a.correct(*p), b.correct(*p));
        let dot = u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
        let norms = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
            * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let angle = (dot / norms).clamp(-1.0, 1.0).acos().to_degrees();
        if angle.is_finite() {
            worst.max(angle)
        } else {
            worst
        }
    })
}

/// The value of a parameter of `c` by its name in a fit's parameter list.
pub fn value_of(c: &Calibration, name: &str) -> Option<f64> {
    if let Some(e) = &c.ellipsoid {
        let i = NAMES3.iter().position(|n| *n == name)?;
        return Some(values3(&e.offset, &e.matrix, e.r)[i]);
    }
    let (p, t) = (&c.params, &c.terms);
    Some(match name {
        "a" => p.a,
        "b" => p.b,
        "d" => p.d,
        "r" => p.r,
        "c" => t.c,
        "k_x" => t.k[0],
        "k_y" => t.k[1],
        // One kc, or the mean of the two a gyro split
        // (model/centred_split.rs).
        "kc" => 0.5 * (t.kc[0] + t.kc[1]),
        "kc_x" => t.kc[0],
        "kc_y" => t.kc[1],
        _ => return None,
    })
}

/// Sets a parameter of `c` by name; false for a name it does not hold.
fn set_value(c: &mut Calibration, name: &str, value: f64) -> bool {
    let (p, t) = (&mut c.params, &mut c.terms);
    match name {
        "a" => p.a = value,
        "b" => p.b = value,
        "d" => p.d = value,
        "r" => p.r = value,
        "c" => t.c = value,
        "k_x" => t.k[0] = value,
        "k_y" => t.k[1] = value,
        "kc" => {
            // The mean moves; a split kept from the gyro stays.
            let half = 0.5 * (t.kc[0] - t.kc[1]);
            t.kc = [value + half, value - half];
        }
        "kc_x" => t.kc[0] = value,
        "kc_y" => t.kc[1] = value,
        _ => return false,
    }
    true
}

/// The standard errors to keep with a calibration: each parameter's,
/// finite and positive ones only.
pub fn se_map(params: &[Param]) -> BTreeMap<String, f64> {
    params
        .iter()
        .filter(|p| p.se.is_finite() && p.se > 0.0)
        .map(|p| (p.name.clone(), p.se))
        .collect()
}

/// Compares `stored` with a later rotation's `refit`, given the heading
/// error the difference makes over that rotation (degrees). O(parameters).
pub fn compare(stored: &Calibration, refit: &Refit, heading_error_deg: f64) -> Comparison {
    let stored_se_assumed = stored.se.is_empty();
    let comparable: Vec<(&Param, f64)> = refit
        .params
        .iter()
        .filter_map(|p| value_of(stored, &p.name).map(|v| (p, v)))
        .collect();
    let z_threshold = moved_threshold(comparable.len());
    let parameters = comparable
        .into_iter()
        .map(|(now, value)| {
            let se = stored.se.get(&now.name).copied().unwrap_or(now.se);
            ParamShift::compare(
                now.name.clone(),
                (value, se),
                (now.value, now.se),
                true,
                z_threshold,
            )
        })
        .collect();
    let heading_noise_deg = refit.rms.min(stored.rms).to_degrees();
    Comparison {
        parameters,
        z_threshold,
        family_false_alarm: FAMILY_FALSE_ALARM,
        heading_error_deg,
        heading_noise_deg,
        heading_limit_deg: NOISE_SIGMAS * heading_noise_deg,
        stored_se_assumed,
    }
}

/// The parent refined by an agreeing refit: each parameter with a standard
/// error in both combined by inverse variance; None when the parent has no
/// standard errors to weigh its values by.
pub fn refine(parent: &Calibration, refit: &Refit) -> Option<Calibration> {
    if parent.se.is_empty() {
        return None;
    }
    let mut refined = parent.clone();
    refined.history = Vec::new();
    let mut se = BTreeMap::new();
    for now in &refit.params {
        let (Some(old), Some(&old_se)) = (value_of(parent, &now.name), parent.se.get(&now.name))
        else {
            continue;
        };
        if !(now.se.is_finite() && now.se > 0.0) {
            continue;
        }
        let (w_old, w_now) = (1.0 / (old_se * old_se), 1.0 / (now.se * now.se));
        let value = (w_old * old + w_now * now.value) / (w_old + w_now);
        if value.is_finite() && set_value(&mut refined, &now.name, value) {
            se.insert(now.name.clone(), 1.0 / (w_old + w_now).sqrt());
        }
    }
    if se.is_empty() {
        return None;
    }
    refined.se = se;
    refined.parent = Some(parent.id);
    Some(refined)
}

/// Magnitude rms (|corrected|/r − 1) of `c` over the samples.
pub fn rms_on(c: &Calibration, x: &[f64], y: &[f64]) -> f64 {
    let (ss, n) = x.iter().zip(y).fold((0.0, 0usize), |(ss, n), (&x, &y)| {
        let (sx, sy) = c.apply(x, y);
        let e = sx.hypot(sy) / c.params.r - 1.0;
        (ss + e * e, n + 1)
    });
    if n == 0 {
        f64::NAN
    } else {
        (ss / n as f64).sqrt()
    }
}

/// The largest heading difference (degrees, wrapped to ±180) between
/// corrections `a` and `b` of the same samples. A sample whose angle
/// between the two is surely no larger than the largest so far is passed
/// over without its two `atan2`s (most of a rotation, past its first
/// peak): the angle is at most |a × b| / (a · b) radians while a · b > 0
/// (atan t ≤ t), and that bound is taken with a margin of 1e-9 of it and
/// 1e-9°, far beyond the few ulp the `atan2`s and the bound are off by
/// (a · b far from the ends of f64's range). The result is the same to
/// the bit.
pub fn heading_error_deg(
    a: impl Fn(f64, f64) -> (f64, f64),
    b: impl Fn(f64, f64) -> (f64, f64),
    x: &[f64],
    y: &[f64],
) -> f64 {
    const MARGIN: f64 = 1e-9;
    x.iter().zip(y).fold(0.0f64, |worst, (&x, &y)| {
        let (ax, ay) = a(x, y);
        let (bx, by) = b(x, y);
        let dot = ax * bx + ay * by;
        if (1e-200..1e200).contains(&dot) {
            let at_most = ((ax * by - ay * bx).abs() / dot).to_degrees();
            if at_most * (1.0 + MARGIN) + MARGIN < worst {
                return worst;
            }
        }
        let d = (ay.atan2(ax) - by.atan2(bx)).to_degrees();
        let d = (d + 180.0).rem_euclid(360.0) - 180.0;
        if d.is_finite() {
            worst.max(d.abs())
        } else {
            worst
        }
    })
}
