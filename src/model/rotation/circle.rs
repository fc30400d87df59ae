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

    /// `self.distance(other) <= limit`, the same decision, without
    /// `hypot` where the squares decide the centres' shift
    /// ([`Frame::shift_by_squares`]).
    pub(super) fn within(&self, other: &Frame, limit: f64) -> bool {
        let scale = (other.radius / self.radius - 1.0).abs();
        match self.shift_by_squares(other, limit) {
            // The shift is within: the scale decides.
            Some(true) if scale.is_finite() => scale <= limit,
            Some(false) if scale.is_finite() => false,
            _ => self.distance(other) <= limit,
        }
    }

    /// Whether the centres' shift is within `limit` radii, when their
    /// squared distance decides it whatever the last bits of the distance
    /// (by a margin of 1e-9, far beyond the few ulp between √s² and
    /// `hypot`'s); `None` near the limit, at sizes where squares leave the
    /// range of f64, and for values that are not finite.
    fn shift_by_squares(&self, other: &Frame, limit: f64) -> Option<bool> {
        const MARGIN: f64 = 1e-9;
        if !((1e-100..1e100).contains(&self.radius) && (1e-3..1e3).contains(&limit)) {
            return None;
        }
        let (dx, dy) = (self.cx - other.cx, self.cy - other.cy);
        let s2 = dx * dx + dy * dy;
        let bound = limit * self.radius;
        if s2 < bound * bound * (1.0 - MARGIN) {
            Some(true)
        } else if s2 > bound * bound * (1.0 + MARGIN) && s2.is_finite() {
            Some(false)
        } else {
            None
        }
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
        if !self.surely_on_ring(du * du + dv * dv) {
            let rho = du.hypot(dv) / self.radius;
            if !(RING_BAND.0..=RING_BAND.1).contains(&rho) {
                return None;
            }
        }
        let h = wrap_degrees(dv.atan2(du).to_degrees());
        h.is_finite().then_some(h)
    }

    /// Whether a sample `d2` (its squared distance from the centre) lies
    /// on the ring ([`RING_BAND`]) whatever the last bits of its distance:
    /// within the band by a margin (1e-9 of it) far beyond the few ulp
    /// between √d2 and `hypot`'s distance. Only near an edge of the band
    /// (or at sizes where squares leave the range of f64) is the exact
    /// test (`hypot`) needed; it decides the same as here everywhere else.
    fn surely_on_ring(&self, d2: f64) -> bool {
        const MARGIN: f64 = 1e-9;
        let r = self.radius;
        if !(1e-100..1e100).contains(&r) {
            return false;
        }
        let (inner, outer) = (RING_BAND.0 * r, RING_BAND.1 * r);
        d2 > inner * inner * (1.0 + MARGIN) && d2 < outer * outer * (1.0 - MARGIN)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift's uniform numbers in [0, 1).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// `x` moved by `k` units in the last place of 1 (relative).
    fn ulps(x: f64, k: i32) -> f64 {
        x * (1.0 + f64::from(k) * f64::EPSILON)
    }

    /// Where the squares put a sample on the ring, `hypot`'s distance
    /// does too: on samples at every scale, half of them within 16 ulp of
    /// an edge of the band (where a test without its margin errs).
    #[test]
    fn the_squares_put_on_the_ring_only_what_hypot_puts_there() {
        let mut unit = uniform(0x2545_f491_4f6c_dd1d);
        let (mut on, mut near_edges) = (0, 0);
        for _ in 0..200_000 {
            let radius = 10f64.powf(unit() * 240.0 - 120.0);
            let frame = Frame {
                cx: (unit() - 0.5) * radius * 3.0,
                cy: (unit() - 0.5) * radius * 3.0,
                radius,
            };
            let edge = if unit() < 0.5 {
                RING_BAND.0
            } else {
                RING_BAND.1
            };
            let distance = if unit() < 0.5 {
                ulps(edge * radius, (unit() * 33.0) as i32 - 16)
            } else {
                unit() * 2.0 * radius
            };
            let angle = unit() * std::f64::consts::TAU;
            let (du, dv) = (distance * angle.cos(), distance * angle.sin());
            let exact = (RING_BAND.0..=RING_BAND.1).contains(&(du.hypot(dv) / radius));
            if frame.surely_on_ring(du * du + dv * dv) {
                assert!(exact, "{du:e} {dv:e} r {radius:e}");
                on += 1;
            } else if exact {
                near_edges += 1;
            }
        }
        // The quick test decides most of the samples on the ring away from
        // its edges (about 42,000 of the 100,000 spread anywhere, the
        // others at sizes beyond its range or off the ring).
        assert!(on > 35_000 && near_edges > 0, "{on} {near_edges}");
    }

    /// `within` decides as `distance` does, and the squares as the
    /// distance's shift, on frames at every scale whose centres moved by
    /// about the limit (half of them within 16 ulp of it), and on frames
    /// that are not finite; the squares decide most of them.
    #[test]
    fn within_decides_as_the_distance_does() {
        let mut unit = uniform(0x853c_49e6_748f_ea9b);
        let mut by_squares = 0;
        for i in 0..200_000 {
            let radius = 10f64.powf(unit() * 240.0 - 120.0);
            let limit = if unit() < 0.5 {
                RECOUNT_MOVE_FOR_TEST
            } else {
                0.01
            };
            let a = Frame {
                cx: (unit() - 0.5) * radius,
                cy: (unit() - 0.5) * radius,
                radius,
            };
            let shift = if unit() < 0.5 {
                ulps(limit * radius, (unit() * 33.0) as i32 - 16)
            } else {
                unit() * 2.0 * limit * radius
            };
            let angle = unit() * std::f64::consts::TAU;
            let mut b = Frame {
                cx: a.cx + shift * angle.cos(),
                cy: a.cy + shift * angle.sin(),
                radius: radius * (1.0 + (unit() - 0.5) * 4.0 * limit),
            };
            match i % 50 {
                0 => b.cx = f64::NAN,
                1 => b.radius = f64::INFINITY,
                2 => b.cy = f64::INFINITY,
                _ => {}
            }
            assert_eq!(
                a.within(&b, limit),
                a.distance(&b) <= limit,
                "{a:?} {b:?} {limit}"
            );
            if let Some(within) = a.shift_by_squares(&b, limit) {
                let exact = (a.cx - b.cx).hypot(a.cy - b.cy) / a.radius <= limit;
                assert_eq!(within, exact, "{a:?} {b:?} {limit}");
                by_squares += 1;
            }
        }
        // (About 80,000: most of the frames moved by anything but the
        // limit itself, at sizes within the squares' range.)
        assert!(by_squares > 60_000, "{by_squares}");
    }

    const RECOUNT_MOVE_FOR_TEST: f64 = super::super::RECOUNT_MOVE;
}
