//! The tilt-compensated heading: a calibrated magnetometer and a
//! calibrated accelerometer on one board give the heading of the board in
//! the horizontal plane, whatever its tilt.
//!
//! Conventions (one for the whole crate):
//! - Both vectors are in the same body frame (map the magnetometer's axes
//!   onto the accelerometer's first when the chips are mounted differently).
//! - The accelerometer reads the specific force: at rest it points **up**
//!   (a board lying flat, z up, reads +1 g on z).
//! - The heading is the angle from (magnetic) north to the body's `forward`
//!   axis (by default +x), measured clockwise seen from above, as a compass
//!   reads it: 0° north, 90° east, in [0, 360).
//! - The inclination (dip) is the angle of the field below the horizontal:
//!   positive in the northern hemisphere, where the field points down.

use nalgebra::Vector3;

/// Fewest of the field's magnitude that its horizontal component must keep
/// for a heading to mean anything: near the magnetic poles (or when the
/// accelerometer sees motion along the field) the horizontal part vanishes
/// and its direction is noise. sin(5°): a field within 5° of the vertical
/// gives no heading. At Earth's steepest inclinations outside the polar
/// regions (about 80°) the horizontal part is still sin(10°) of the field.
pub const MIN_HORIZONTAL_FRACTION: f64 = 0.087_155_742_747_658_17;

/// The heading and the field's geometry at one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiltHeading {
    /// Clockwise from north to the forward axis, degrees in [0, 360).
    pub heading_deg: f64,
    /// The field's angle below the horizontal, degrees in [-90, 90].
    pub inclination_deg: f64,
    /// The forward axis's angle above the horizontal (pitch), degrees.
    pub pitch_deg: f64,
    /// The angle between the board's up axis and the vertical, degrees.
    pub tilt_deg: f64,
}

/// The tilt-compensated heading of the body's `forward` and `up` axes
/// (unit vectors of the body frame; the usual board: forward +x, up +z),
/// from a calibrated field `mag` and a calibrated specific force `accel` in
/// that frame. `None` when a vector is zero or not finite, when the forward
/// axis is within a degree of the vertical (it has no heading), or when the
/// field is too near the vertical ([`MIN_HORIZONTAL_FRACTION`]).
pub fn tilt_heading(
    mag: [f64; 3],
    accel: [f64; 3],
    forward: [f64; 3],
    up_axis: [f64; 3],
) -> Option<TiltHeading> {
    let m = Vector3::from(mag);
    let a = Vector3::from(accel);
    let f = Vector3::from(forward);
    let b_up = Vector3::from(up_axis);
    if !(m.iter().chain(a.iter()).all(|v| v.is_finite())) {
        return None;
    }
    let (m_norm, a_norm, f_norm) = (m.norm(), a.norm(), f.norm());
    if m_norm == 0.0 || a_norm == 0.0 || f_norm == 0.0 || !f_norm.is_finite() {
        return None;
    }
    let up = a / a_norm;
    let f = f / f_norm;
    // East is horizontal, perpendicular to the field's horizontal part:
    // the field's vertical part does not change m × up.
    let east = m.cross(&up);
    let horizontal = east.norm() / m_norm;
    if horizontal < MIN_HORIZONTAL_FRACTION {
        return None;
    }
    let east = east / east.norm();
    let north = up.cross(&east);
    let (fe, fn_) = (f.dot(&east), f.dot(&north));
    // The forward axis within a degree of the vertical has no heading.
    if fe.hypot(fn_) < 1.0_f64.to_radians().sin() {
        return None;
    }
    let heading_deg = fe.atan2(fn_).to_degrees().rem_euclid(360.0);
    let inclination_deg = (-(m.dot(&up)) / m_norm)
        .clamp(-1.0, 1.0)
        .asin()
        .to_degrees();
    let pitch_deg = f.dot(&up).clamp(-1.0, 1.0).asin().to_degrees();
    let b_up_norm = b_up.norm();
    let tilt_deg = if b_up_norm > 0.0 && b_up_norm.is_finite() {
        (b_up.dot(&up) / b_up_norm)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
    } else {
        f64::NAN
    };
    Some(TiltHeading {
        heading_deg: if heading_deg >= 360.0 {
            0.0
        } else {
            heading_deg
        },
        inclination_deg,
        pitch_deg,
        tilt_deg,
    })
}

/// The heading a level compass would read from the same field, ignoring
/// tilt: the field's direction in the plane of `forward` and `right`
/// (right = forward × up of a level board: −y for a board with x forward,
/// z up). The uncompensated heading that [`tilt_heading`] improves on.
pub fn level_heading(mag: [f64; 3], forward: [f64; 3], right: [f64; 3]) -> Option<f64> {
    let m = Vector3::from(mag);
    let (mf, mr) = (m.dot(&Vector3::from(forward)), m.dot(&Vector3::from(right)));
    if !(mf.is_finite() && mr.is_finite()) || (mf == 0.0 && mr == 0.0) {
        return None;
    }
    // The field points north: seen from the board, north is at −heading,
    // so the forward axis is `heading` clockwise from north.
    let h = (-mr).atan2(mf).to_degrees().rem_euclid(360.0);
    Some(if h >= 360.0 { 0.0 } else { h })
}

/// The smallest signed difference `a − b` between two headings, degrees in
/// (−180, 180].
pub fn heading_difference(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    const FORWARD: [f64; 3] = [1.0, 0.0, 0.0];
    const UP: [f64; 3] = [0.0, 0.0, 1.0];
    const RIGHT: [f64; 3] = [0.0, -1.0, 0.0];

    /// The Earth's field and gravity's specific force in a world frame of
    /// east, north, up, seen from a board at `heading` (clockwise from
    /// north), pitched up by `pitch` and rolled right by `roll` (degrees).
    fn seen(heading: f64, pitch: f64, roll: f64, dip: f64) -> ([f64; 3], [f64; 3]) {
        let d = dip.to_radians();
        let field_enu = Vector3::new(0.0, d.cos(), -d.sin()) * 0.5;
        let up_enu = Vector3::new(0.0, 0.0, 9.81);
        // Body axes in the world: yaw (clockwise from north about −up),
        // then pitch about the body's right axis, then roll about forward.
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), -heading.to_radians());
        // A body at heading 0 has x north, y west, z up.
        let base = nalgebra::Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let pitch_r = Rotation3::from_axis_angle(&Vector3::y_axis(), -pitch.to_radians());
        let roll_r = Rotation3::from_axis_angle(&Vector3::x_axis(), roll.to_radians());
        // body->world = yaw * base * pitch * roll
        let body_to_world = yaw.matrix() * base * pitch_r.matrix() * roll_r.matrix();
        let w2b = body_to_world.transpose();
        let m = w2b * field_enu;
        let a = w2b * up_enu;
        ([m.x, m.y, m.z], [a.x, a.y, a.z])
    }

    #[test]
    fn level_board_reads_its_heading_both_ways() {
        for h in [0.0, 30.0, 90.0, 181.0, 270.0, 359.0] {
            let (m, a) = seen(h, 0.0, 0.0, 60.0);
            let t = tilt_heading(m, a, FORWARD, UP).unwrap();
            assert!(
                heading_difference(t.heading_deg, h).abs() < 1e-9,
                "{h}: {t:?}"
            );
            assert!((t.inclination_deg - 60.0).abs() < 1e-9);
            assert!(t.tilt_deg.abs() < 1e-6);
            let l = level_heading(m, FORWARD, RIGHT).unwrap();
            assert!(heading_difference(l, h).abs() < 1e-9, "{h}: level {l}");
        }
    }

    #[test]
    fn tilt_is_compensated_and_the_level_compass_is_not() {
        for (h, p, r) in [(40.0, 20.0, 0.0), (200.0, -15.0, 25.0), (300.0, 0.0, -30.0)] {
            let (m, a) = seen(h, p, r, 65.0);
            let t = tilt_heading(m, a, FORWARD, UP).unwrap();
            assert!(heading_difference(t.heading_deg, h).abs() < 1e-9, "{t:?}");
            assert!((t.pitch_deg - p).abs() < 1e-9, "{t:?}");
            assert!((t.inclination_deg - 65.0).abs() < 1e-9);
            let l = level_heading(m, FORWARD, RIGHT).unwrap();
            assert!(heading_difference(l, h).abs() > 5.0, "level {l} vs {h}");
        }
    }

    #[test]
    fn no_heading_without_a_horizontal_field_or_with_bad_input() {
        let (m, a) = seen(10.0, 0.0, 0.0, 89.0);
        assert!(tilt_heading(m, a, FORWARD, UP).is_none());
        assert!(tilt_heading([0.0; 3], a, FORWARD, UP).is_none());
        assert!(tilt_heading(m, [f64::NAN, 0.0, 1.0], FORWARD, UP).is_none());
        // The forward axis pointing straight up.
        let (m, a) = seen(10.0, 90.0, 0.0, 60.0);
        assert!(tilt_heading(m, a, FORWARD, UP).is_none());
    }

    #[test]
    fn differences_wrap() {
        assert_eq!(heading_difference(1.0, 359.0), 2.0);
        assert_eq!(heading_difference(359.0, 1.0), -2.0);
        assert_eq!(heading_difference(180.0, 0.0), 180.0);
    }
}
