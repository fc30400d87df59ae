//! Whether numbers can be a 2-D calibration at all: what every calibration
//! that enters fieldcal from outside (a daemon state file, the CAL of
//! `check`) must be before it corrects a reading. A hand-edited file can hold
//! `a = 1e308`, `a = 5e-324` or an offset of 1.7e308; applied, they turn
//! every reading into `null` or a heading stuck at one value while saying
//! `"calibrated": true`. The 3-D rules are [`super::calibration3::Calibration3D::validate`].

use super::calibration::Terms;
use super::paper::PaperCalibration;

/// The daemon's default acceptance limits
/// ([`crate::daemon::acceptance::Limits`]), for a calibration read where no
/// sensor's configuration gives them (`check`): the largest gain ratio of
/// the two axes, and the largest offset in field radii.
pub const DEFAULT_MAX_SCALE_RATIO: f64 = 2.0;
pub const DEFAULT_MAX_OFFSET_RATIO: f64 = 5.0;

/// The bounds of a possible 2-D calibration where no sensor's limits apply
/// (`check` of a `fit --json`, which holds none): two axes of one chip
/// whose gains differ 100-fold, or an offset of 100 field radii, are a
/// wrong column or an edited number, never a sensor.
pub const POSSIBLE_SCALE_RATIO: f64 = 100.0;
pub const POSSIBLE_OFFSET_RATIO: f64 = 100.0;

/// The largest |k| or |kc| a calibration may hold: 1/3. Beyond −1/3 the
/// cubic correction `x + k x³/S²` turns back within its full scale (its
/// slope `1 + 3k` reaches zero) and folds two readings onto one; a cubic of
/// a third of the reading is far beyond what any sensor does (datasheets
/// give 0.1–0.5 %), so the bound is symmetric.
pub const MAX_CUBIC_TERM: f64 = 1.0 / 3.0;
/// The largest |c|: 1, a coupling of 45°, beyond which the two axes have
/// swapped roles (ArduPilot bounds a soft-iron off-diagonal by 1 too).
pub const MAX_COUPLING: f64 = 1.0;

/// Why `p` and `t` cannot be a calibration of a 2-axis sensor whose
/// acceptance limits are `max_scale_ratio` and `max_offset_ratio`
/// ([`crate::daemon::acceptance::Limits`]), naming the field; None when
/// they can.
pub fn plane_problem(
    p: &PaperCalibration,
    t: &Terms,
    max_scale_ratio: f64,
    max_offset_ratio: f64,
) -> Option<String> {
    let numbers = [
        ("params.a", p.a),
        ("params.b", p.b),
        ("params.d", p.d),
        ("params.r", p.r),
        ("terms.c", t.c),
        ("terms.k", t.k[0]),
        ("terms.k", t.k[1]),
        ("terms.cubic_scale", t.cubic_scale),
        ("terms.kc", t.kc[0]),
        ("terms.kc", t.kc[1]),
        ("terms.centre", t.centre[0]),
        ("terms.centre", t.centre[1]),
        ("terms.turn_radius", t.turn_radius[0]),
        ("terms.turn_radius", t.turn_radius[1]),
    ];
    if let Some((name, v)) = numbers.iter().find(|(_, v)| !v.is_finite()) {
        return Some(format!("{name} is {v}, not a finite number"));
    }
    for (name, v) in [("params.a", p.a), ("params.r", p.r)] {
        if !(v > 0.0) {
            return Some(format!("{name} is {v}, it must be above zero"));
        }
    }
    let ratio = p.a.max(1.0 / p.a);
    if !(ratio <= max_scale_ratio) {
        return Some(format!(
            "params.a = {} makes the axes' gains differ ×{ratio:.3e}, beyond the limit ×{max_scale_ratio} (max_scale_ratio)",
            p.a
        ));
    }
    let offset = p.b.hypot(p.d) / p.r;
    if !(offset <= max_offset_ratio) {
        return Some(format!(
            "params.b = {}, params.d = {}: the offset is {offset:.3e} field radii (r = {}), beyond the limit {max_offset_ratio} (max_offset_ratio)",
            p.b, p.d, p.r
        ));
    }
    if t.c.abs() > MAX_COUPLING {
        return Some(format!(
            "terms.c = {} couples the axes by more than 45° (|c| at most {MAX_COUPLING}): the axes would have swapped roles",
            t.c
        ));
    }
    for (name, pair) in [("terms.k", t.k), ("terms.kc", t.kc)] {
        if let Some(k) = pair.iter().find(|k| k.abs() > MAX_CUBIC_TERM) {
            return Some(format!(
                "{name} = {k} bends the reading by more than a third at full scale (at most {MAX_CUBIC_TERM:.3}): the correction would fold readings onto each other"
            ));
        }
    }
    if t.k != [0.0; 2] && !(t.cubic_scale > 0.0) {
        return Some(format!(
            "terms.cubic_scale is {}: a cubic k needs the full scale it refers to, above zero",
            t.cubic_scale
        ));
    }
    if t.kc != [0.0; 2] && !t.turn_radius.iter().all(|r| *r > 0.0) {
        return Some(format!(
            "terms.turn_radius is {:?}: a centred cubic kc needs the turn's radius it refers to, above zero on both axes",
            t.turn_radius
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper(a: f64, b: f64, d: f64, r: f64) -> PaperCalibration {
        PaperCalibration { a, b, d, r }
    }

    #[test]
    fn the_hand_edited_values_of_the_report_are_refused_by_field() {
        let t = Terms::default();
        let ok = paper(1.1, -120.0, 80.0, 1000.0);
        assert_eq!(plane_problem(&ok, &t, 2.0, 5.0), None);
        for (p, field) in [
            (paper(1e308, -120.0, 80.0, 1000.0), "max_scale_ratio"),
            (paper(5e-324, -120.0, 80.0, 1000.0), "max_scale_ratio"),
            (paper(1.1, 1.7e308, 80.0, 1000.0), "max_offset_ratio"),
            (paper(1.1, f64::NAN, 80.0, 1000.0), "params.b is NaN"),
            (paper(1.1, 0.0, 0.0, -1.0), "params.r is -1"),
            (paper(-1.0, 0.0, 0.0, 1.0), "params.a is -1"),
        ] {
            let problem = plane_problem(&p, &t, 2.0, 5.0).expect("refused");
            assert!(problem.contains(field), "{problem}");
        }
        let folding = Terms {
            k: [-0.5, 0.0],
            cubic_scale: 1000.0,
            ..Terms::default()
        };
        assert!(plane_problem(&ok, &folding, 2.0, 5.0).is_some());
        let no_radius = Terms {
            kc: [0.02, 0.02],
            ..Terms::default()
        };
        let problem = plane_problem(&ok, &no_radius, 2.0, 5.0).unwrap();
        assert!(problem.contains("turn_radius"), "{problem}");
    }
}
