//! The circle a rotation's samples are counted around: Kåsa's algebraic
//! circle fit kept as running sums ([`Moments`], O(1) per sample), the
//! centre and radius it gives ([`Frame`]), and a sample's heading about it.
//! Used by the rotation buffer ([`super::RotationBuffer`]).

use super::RING_BAND;
use crate::model::heading::wrap_degrees;

/// The running centre and radius samples are counted around.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Frame {
    pub(super) cx: f64,
    pub(super) cy: f64,
    /// Root mean square distance of the samples from the centre.
    pub(super) radius: f64,
}

impl Frame {
    /// How far `other` is from `self`, as a fraction of the radius.
    pub(super) fn distance(&self, other: &Frame) -> f64 {
        let shift = (self.cx - other.cx).hypot(self.cy - other.cy) / self.radius;
        let scale = (other.radius / self.radius - 1.0).abs();
        let d = shift.max(scale);
        if d.is_nan() { f64::INFINITY } else { d }
    }

    /// How far the centre lies from the zero reading, in radii.
    pub(super) fn offset_ratio(&self) -> f64 {
        let r = self.cx.hypot(self.cy) / self.radius;
        if r.is_nan() { f64::INFINITY } else { r }
    }

    /// Heading in degrees [0, 360) of a sample on the circle, or None when
    /// it lies too far inside or outside it to have a meaningful heading.
    pub(super) fn heading_deg(&self, x: f64, y: f64) -> Option<f64> {
        let (du, dv) = (x - self.cx, y - self.cy);
        let rho = du.hypot(dv) / self.radius;
        if !(RING_BAND.0..=RING_BAND.1).contains(&rho) {
            return None;
        }
        let h = wrap_degrees(dv.atan2(du).to_degrees());
        h.is_finite().then_some(h)
    }
}

/// `d` degrees wrapped to [-180, 180).
pub(super) fn wrap_deg(d: f64) -> f64 {
    wrap_degrees(d + 540.0) - 180.0
}

/// Running sums for Kåsa's circle fit, in coordinates relative to the
/// first sample (so the sums of cubes do not lose their digits to large
/// offsets).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Moments {
    n: f64,
    su: f64,
    sv: f64,
    suu: f64,
    svv: f64,
    suv: f64,
    suuu: f64,
    suvv: f64,
    suuv: f64,
    svvv: f64,
}

impl Moments {
    pub(super) fn add(&mut self, u: f64, v: f64) {
        self.n += 1.0;
        self.su += u;
        self.sv += v;
        self.suu += u * u;
        self.svv += v * v;
        self.suv += u * v;
        self.suuu += u * u * u;
        self.suvv += u * v * v;
        self.suuv += u * u * v;
        self.svvv += v * v * v;
    }

    /// The circle minimising sum (u^2 + v^2 - A u - B v - C)^2, relative to
    /// the anchor; None for fewer than 3 samples or points on a line.
    pub(super) fn circle(&self) -> Option<(f64, f64, f64)> {
        let n = self.n;
        if n < 3.0 {
            return None;
        }
        let (mu, mv) = (self.su / n, self.sv / n);
        let mz = (self.suu + self.svv) / n;
        let s_uu = self.suu - n * mu * mu;
        let s_vv = self.svv - n * mv * mv;
        let s_uv = self.suv - n * mu * mv;
        let s_uz = self.suuu + self.suvv - n * mu * mz;
        let s_vz = self.suuv + self.svvv - n * mv * mz;
        let det = s_uu * s_vv - s_uv * s_uv;
        if !(s_uu > 0.0 && s_vv > 0.0 && det > 1e-9 * s_uu * s_vv) {
            return None;
        }
        let a = (s_uz * s_vv - s_vz * s_uv) / det;
        let b = (s_vz * s_uu - s_uz * s_uv) / det;
        let (cu, cv) = (a / 2.0, b / 2.0);
        let r2 = (s_uu + s_vv) / n + (mu - cu).powi(2) + (mv - cv).powi(2);
        let radius = r2.sqrt();
        (cu.is_finite() && cv.is_finite() && radius.is_finite() && radius > 0.0)
            .then_some((cu, cv, radius))
    }
}
