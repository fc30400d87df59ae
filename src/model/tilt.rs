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

use super::calibration3::{Calibration3D, Calibration3Invalid, Calibration3JsonError};

mod series;
pub use series::{BoardAxesError, HeadingSeries, heading_series};

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

/// Why a sample has no tilt-compensated heading.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum NoHeading {
    /// A component of the field or the specific force is NaN or infinite.
    #[error("the field or the tilt reading is not finite")]
    NotFinite,
    /// The field, the specific force or the forward axis is zero.
    #[error("the field, the tilt reading or the forward axis is zero")]
    Zero,
    /// The field is within 5° of the vertical: its horizontal part, which
    /// gives north, is noise (near a magnetic pole, or motion along it).
    #[error(
        "the field is {angle_deg:.1}° from the vertical, within 5°: it has no horizontal part to \
         give north"
    )]
    FieldVertical {
        /// The field's angle from the vertical, degrees.
        angle_deg: f64,
    },
    /// The forward axis is within a degree of the vertical: it points at no
    /// heading (a board stood on its end).
    #[error(
        "the forward axis is {angle_deg:.1}° from the vertical, within 1°: it points at no \
         heading"
    )]
    ForwardVertical {
        /// The forward axis's angle from the vertical, degrees.
        angle_deg: f64,
    },
}

/// The tilt-compensated heading of the body's `forward` and `up` axes
/// (unit vectors of the body frame; the usual board: forward +x, up +z),
/// from a calibrated field `mag` and a calibrated specific force `accel` in
/// that frame. `None` when a vector is zero or not finite, when the forward
/// axis is within a degree of the vertical (it has no heading), or when the
/// field is too near the vertical ([`MIN_HORIZONTAL_FRACTION`]);
/// [`tilt_heading_or_why`] says which.
pub fn tilt_heading(
    mag: [f64; 3],
    accel: [f64; 3],
    forward: [f64; 3],
    up_axis: [f64; 3],
) -> Option<TiltHeading> {
    tilt_heading_or_why(mag, accel, forward, up_axis).ok()
}

/// [`tilt_heading`], or why the sample has none.
pub fn tilt_heading_or_why(
    mag: [f64; 3],
    accel: [f64; 3],
    forward: [f64; 3],
    up_axis: [f64; 3],
) -> Result<TiltHeading, NoHeading> {
    let m = Vector3::from(mag);
    let a = Vector3::from(accel);
    let f = Vector3::from(forward);
    let b_up = Vector3::from(up_axis);
    if !(m.iter().chain(a.iter()).all(|v| v.is_finite())) {
        return Err(NoHeading::NotFinite);
    }
    let (m_norm, a_norm, f_norm) = (m.norm(), a.norm(), f.norm());
    if !f_norm.is_finite() {
        return Err(NoHeading::NotFinite);
    }
    if m_norm == 0.0 || a_norm == 0.0 || f_norm == 0.0 {
        return Err(NoHeading::Zero);
    }
    let up = a / a_norm;
    let f = f / f_norm;
    // East is horizontal, perpendicular to the field's horizontal part:
    // the field's vertical part does not change m × up.
    let east = m.cross(&up);
    let horizontal = east.norm() / m_norm;
    if horizontal < MIN_HORIZONTAL_FRACTION {
        return Err(NoHeading::FieldVertical {
            angle_deg: horizontal.clamp(0.0, 1.0).asin().to_degrees(),
        });
    }
    let east = east / east.norm();
    let north = up.cross(&east);
    let (fe, fn_) = (f.dot(&east), f.dot(&north));
    // The forward axis within a degree of the vertical has no heading.
    if fe.hypot(fn_) < 1.0_f64.to_radians().sin() {
        return Err(NoHeading::ForwardVertical {
            angle_deg: fe.hypot(fn_).clamp(0.0, 1.0).asin().to_degrees(),
        });
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
    Ok(TiltHeading {
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

/// The axis of a frame a name stands for: `x`, `-y`, `+z`. `None` for
/// anything else.
pub fn parse_axis(text: &str) -> Option<[f64; 3]> {
    let (sign, name) = match text.trim() {
        t if t.starts_with('-') => (-1.0, &t[1..]),
        t if t.starts_with('+') => (1.0, &t[1..]),
        t => (1.0, t),
    };
    let i = match name {
        "x" => 0,
        "y" => 1,
        "z" => 2,
        _ => return None,
    };
    let mut v = [0.0; 3];
    v[i] = sign;
    Some(v)
}

/// How a magnetometer's axes lie on the board (the accelerometer's frame,
/// the body frame): body axis `i` reads `sign[i]` times magnetometer axis
/// `from[i]`. Written as in `--mag-axes`: `x,-z,y` says body x is the
/// magnetometer's x, body y its −z, body z its y.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct AxisMap {
    from: [usize; 3],
    negate: [bool; 3],
}

/// Why an axis mapping was not understood.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "'{text}' is not an axis mapping: give three signed magnetometer axes, one per body axis x, y, z, each of x, y, z once (for example x,-z,y), or auto"
)]
pub struct AxisMapParseError {
    pub text: String,
}

impl AxisMap {
    /// Body axis i is the magnetometer's axis i.
    pub const IDENTITY: AxisMap = AxisMap {
        from: [0, 1, 2],
        negate: [false; 3],
    };

    /// All 48 signed permutations of the axes (24 rotations, 24 mirrors).
    pub fn all() -> Vec<AxisMap> {
        const PERMUTATIONS: [[usize; 3]; 6] = [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ];
        let mut all = Vec::with_capacity(48);
        for from in PERMUTATIONS {
            for bits in 0..8u8 {
                all.push(AxisMap {
                    from,
                    negate: [bits & 1 != 0, bits & 2 != 0, bits & 4 != 0],
                });
            }
        }
        all
    }

    /// The magnetometer's reading in the body frame.
    pub fn apply(&self, mag: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|i| {
            let v = mag[self.from[i]];
            if self.negate[i] { -v } else { v }
        })
    }

    /// The same mapping with every axis negated: the field read backwards.
    pub fn mirrored(&self) -> AxisMap {
        AxisMap {
            from: self.from,
            negate: self.negate.map(|n| !n),
        }
    }

    /// +1 for a rotation (a right-handed magnetometer on a right-handed
    /// board), −1 for a mirror.
    pub fn determinant(&self) -> f64 {
        let mut m = [[0.0; 3]; 3];
        for i in 0..3 {
            m[i][self.from[i]] = if self.negate[i] { -1.0 } else { 1.0 };
        }
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    }
}

impl std::fmt::Display for AxisMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names = ["x", "y", "z"];
        let parts: Vec<String> = (0..3)
            .map(|i| {
                format!(
                    "{}{}",
                    if self.negate[i] { "-" } else { "" },
                    names[self.from[i]]
                )
            })
            .collect();
        f.write_str(&parts.join(","))
    }
}

impl std::str::FromStr for AxisMap {
    type Err = AxisMapParseError;
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let err = || AxisMapParseError {
            text: crate::io::excerpt(text).to_string(),
        };
        let parts: Vec<&str> = text.split(',').collect();
        if parts.len() != 3 {
            return Err(err());
        }
        let mut from = [0; 3];
        let mut negate = [false; 3];
        let mut seen = [false; 3];
        for (i, part) in parts.iter().enumerate() {
            let v = parse_axis(part).ok_or_else(err)?;
            let k = v.iter().position(|c| *c != 0.0).ok_or_else(err)?;
            if seen[k] {
                return Err(err());
            }
            seen[k] = true;
            from[i] = k;
            negate[i] = v[k] < 0.0;
        }
        Ok(AxisMap { from, negate })
    }
}

/// The field's angle below the horizontal (the dip, or inclination), in
/// degrees, from a field and a specific force (up) in one frame; `None`
/// when either is zero or not finite.
pub fn inclination_deg(mag: [f64; 3], accel: [f64; 3]) -> Option<f64> {
    let m = Vector3::from(mag);
    let a = Vector3::from(accel);
    let (mn, an) = (m.norm(), a.norm());
    if !(mn > 0.0 && an > 0.0 && mn.is_finite() && an.is_finite()) {
        return None;
    }
    Some(
        (-(m.dot(&a)) / (mn * an))
            .clamp(-1.0, 1.0)
            .asin()
            .to_degrees(),
    )
}

/// 1.4826: the median absolute deviation of a normal distribution times
/// this is its standard deviation.
pub const MAD_TO_SIGMA: f64 = 1.482_602_218_505_602;

/// A median and a robust spread (1.4826 × the median absolute deviation:
/// the standard deviation for normal values, and unmoved by the few
/// samples a hand's jerk throws off).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RobustSpread {
    pub median: f64,
    pub spread: f64,
    pub n: usize,
}

/// The median of `values` (found by selection: they are reordered); NaN
/// when there are none.
pub(crate) fn median_of(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    super::residuals::median_mut(values)
}

/// The median and robust spread of the finite values; `None` when there
/// are none.
pub fn robust_spread(values: &[f64]) -> Option<RobustSpread> {
    let mut v: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let median = median_of(&mut v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - median).abs()).collect();
    let mad = median_of(&mut dev);
    Some(RobustSpread {
        median,
        spread: MAD_TO_SIGMA * mad,
        n: v.len(),
    })
}

/// How much larger the dip's spread of every other mapping must be than
/// the chosen one's before `--mag-axes auto` trusts its choice: a ratio of
/// 2 in spread is 4 in variance, which over [`crate::model::gyro::
/// COMPARISON_BATCHES`] (20) independent batches of a recording is the
/// 99.9 % point of the F(19, 19) distribution (3.9): a chance ordering
/// of two equally good mappings reaches it once in a thousand recordings.
pub const AUTO_MIN_SPREAD_RATIO: f64 = 2.0;

/// Fewest samples `--mag-axes auto` needs: two per batch of
/// [`AUTO_MIN_SPREAD_RATIO`]'s test.
pub const AUTO_MIN_SAMPLES: usize = 2 * crate::model::gyro::COMPARISON_BATCHES;

/// One mapping's dip over the recording.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisCandidate {
    pub map: AxisMap,
    /// The dip's median and robust spread, degrees.
    pub inclination: RobustSpread,
}

/// The mapping `--mag-axes auto` chose, and how clearly.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisChoice {
    pub chosen: AxisCandidate,
    /// The best mapping other than the chosen one and its mirror.
    pub runner_up: AxisCandidate,
    /// How far the board's vertical moved: the largest angle between the
    /// accelerometer's direction and its mean, degrees.
    pub tilt_range_deg: f64,
    /// Why the chosen one and not its mirror (which has the same spread,
    /// the dip of opposite sign).
    pub mirror_rule: String,
}

/// Why `--mag-axes auto` could not choose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AxisChoiceError {
    #[error(
        "{found} samples with both a field and a gravity reading; choosing the magnetometer's axes needs at least {needed}"
    )]
    TooFew { found: usize, needed: usize },
    #[error(
        "the recording cannot tell the magnetometer's axes apart: the best mapping ({best}) keeps the dip within {best_spread:.2}° (robust SD) and another ({runner_up}) within {runner_up_spread:.2}°, and a choice needs the others at least {ratio}× worse. The board's vertical moved up to {tilt_range_deg:.1}°: a turn about one axis (a flat turn) keeps that axis vertical, and mappings that differ by a swap or a sign about it give the same dip; an uncalibrated magnetometer, or an accelerometer that sees the hand's motion, blurs the dip of every mapping alike. Calibrate both (--mag-calibration, --accel-calibration), tumble the board through many tilts, or give the mapping with --mag-axes (e.g. x,-z,y)"
    )]
    Ambiguous {
        best: AxisMap,
        best_spread: f64,
        runner_up: AxisMap,
        runner_up_spread: f64,
        ratio: f64,
        tilt_range_deg: f64,
    },
}

/// Chooses how the magnetometer's axes lie on the board: among the 48
/// signed permutations, the one that keeps the dip (the angle between the
/// field and gravity) most constant over the recording. In a uniform field
/// the dip is the same whatever the board's orientation, so only the right
/// mapping (and its mirror, which reads the dip with the opposite sign)
/// keeps it constant while the board tilts. The mirror is told apart by
/// `expected_inclination_deg`'s sign (the World Magnetic Model's, when the
/// place is known), else by handedness: both chips of a board are
/// right-handed, so the rotation is chosen. `mag` and `accel` are
/// calibrated and paired sample by sample (NaN: no reading).
pub fn choose_axis_map(
    mag: &[[f64; 3]],
    accel: &[[f64; 3]],
    expected_inclination_deg: Option<f64>,
) -> Result<AxisChoice, AxisChoiceError> {
    let pairs: Vec<([f64; 3], [f64; 3])> = mag
        .iter()
        .zip(accel)
        .filter(|(m, a)| inclination_deg(**m, **a).is_some())
        .map(|(m, a)| (*m, *a))
        .collect();
    if pairs.len() < AUTO_MIN_SAMPLES {
        return Err(AxisChoiceError::TooFew {
            found: pairs.len(),
            needed: AUTO_MIN_SAMPLES,
        });
    }
    let mut candidates: Vec<AxisCandidate> = AxisMap::all()
        .into_iter()
        .filter_map(|map| {
            let dips: Vec<f64> = pairs
                .iter()
                .filter_map(|(m, a)| inclination_deg(map.apply(*m), *a))
                .collect();
            robust_spread(&dips).map(|inclination| AxisCandidate { map, inclination })
        })
        .collect();
    candidates.sort_by(|a, b| a.inclination.spread.total_cmp(&b.inclination.spread));
    let Some(best) = candidates.first().copied() else {
        return Err(AxisChoiceError::TooFew {
            found: 0,
            needed: AUTO_MIN_SAMPLES,
        });
    };
    let mirror = best.map.mirrored();
    let runner_up = candidates
        .iter()
        .find(|c| c.map != best.map && c.map != mirror)
        .copied()
        .unwrap_or(best);
    // The tilt range: angles of the accelerometer from its mean direction.
    let mut mean = Vector3::zeros();
    for (_, a) in &pairs {
        let v = Vector3::from(*a);
        mean += v / v.norm();
    }
    let tilt_range_deg = if mean.norm() > 0.0 {
        let mean = mean / mean.norm();
        pairs
            .iter()
            .map(|(_, a)| {
                let v = Vector3::from(*a);
                (v.dot(&mean) / v.norm())
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees()
            })
            .fold(0.0, f64::max)
    } else {
        180.0
    };
    let (b, r) = (best.inclination.spread, runner_up.inclination.spread);
    if !(r >= AUTO_MIN_SPREAD_RATIO * b && r > 0.0) {
        return Err(AxisChoiceError::Ambiguous {
            best: best.map,
            best_spread: b,
            runner_up: runner_up.map,
            runner_up_spread: r,
            ratio: AUTO_MIN_SPREAD_RATIO,
            tilt_range_deg,
        });
    }
    let mirrored = AxisCandidate {
        map: mirror,
        inclination: RobustSpread {
            median: -best.inclination.median,
            ..best.inclination
        },
    };
    let (chosen, mirror_rule) = match expected_inclination_deg {
        Some(expected) if expected != 0.0 && expected.is_finite() => {
            let rule = format!(
                "of the mapping and its mirror, the one whose dip has the sign of the model's ({expected:+.1}°)"
            );
            if best.inclination.median * expected > 0.0 {
                (best, rule)
            } else {
                (mirrored, rule)
            }
        }
        _ => {
            let rule = "of the mapping and its mirror (the same dip, of opposite sign), the rotation: both chips of a board are right-handed (give --mag-axes if a flipped axis makes one left-handed, or --latitude/--longitude to decide by the dip's sign)".to_string();
            if best.map.determinant() > 0.0 {
                (best, rule)
            } else {
                (mirrored, rule)
            }
        }
    };
    Ok(AxisChoice {
        chosen,
        runner_up,
        tilt_range_deg,
        mirror_rule,
    })
}

/// Whether `configured`, the mapping of the magnetometer's axes onto the
/// accelerometer's that a configuration gives, keeps the dip as constant
/// as the data allow: `None` when it does, or when the data cannot tell
/// (too few pairs, or a choice [`choose_axis_map`] calls ambiguous, as on
/// a flat turn); else why not and what to set, in a sentence. A mapping
/// is wrong when the dip's robust spread with it is at least
/// [`AUTO_MIN_SPREAD_RATIO`] times the best mapping's (which is neither it
/// nor its mirror), or, with the model's inclination, when it is the best
/// one's mirror and reads the dip with the opposite sign (its headings
/// are then 180° off).
pub fn mounting_problem(
    mag: &[[f64; 3]],
    accel: &[[f64; 3]],
    configured: AxisMap,
    expected_inclination_deg: Option<f64>,
) -> Option<String> {
    let choice = choose_axis_map(mag, accel, expected_inclination_deg).ok()?;
    let best = choice.chosen;
    if configured == best.map {
        return None;
    }
    if configured == best.map.mirrored() {
        let expected = expected_inclination_deg.filter(|e| e.is_finite() && *e != 0.0)?;
        return Some(format!(
            "with mag_axes = \"{configured}\" the dip reads {:+.1}° where the World Magnetic \
             Model gives {expected:+.1}°: the mapping is mirrored, so every heading is 180° off; \
             set mag_axes = \"{}\"",
            -best.inclination.median, best.map
        ));
    }
    let dips: Vec<f64> = mag
        .iter()
        .zip(accel)
        .filter_map(|(m, a)| inclination_deg(configured.apply(*m), *a))
        .collect();
    let spread = robust_spread(&dips)?.spread;
    let b = best.inclination.spread;
    (spread >= AUTO_MIN_SPREAD_RATIO * b).then(|| {
        format!(
            "the dip wanders {spread:.1}° (robust SD) with mag_axes = \"{configured}\" and \
             {b:.1}° with \"{}\": the magnetometer's axes do not lie on the accelerometer's as \
             configured, so tilt-compensated headings are wrong; set mag_axes = \"{}\"",
            best.map, best.map
        )
    })
}

/// A gap in a time column longer than this many of its sample periods is
/// not bridged by interpolation: up to two dropped samples in a row (a
/// host's or a bus's hiccup) are; a longer gap (the ~0.25 s stalls of a
/// USB host) can hold a turn of the board that a straight line between
/// its ends would not follow. The period is the 90th percentile of the
/// intervals between time stamps: on a regular clock the sample period;
/// on host receive times, which come in bursts (a USB serial adapter
/// hands over its buffer in packets, so stamps bunch a few milliseconds
/// apart and then pause), the interval between bursts, the resolution the
/// stamps actually have (the median would be the spacing within a burst,
/// and every pause would count as a gap).
pub const MAX_GAP_PERIODS: f64 = 3.0;

/// A second sensor's readings, interpolated at the first's sample times.
#[derive(Debug, Clone, PartialEq)]
pub struct Resampled {
    /// One per target time; NaN where not interpolated.
    pub values: Vec<[f64; 3]>,
    /// Target times outside the source's time span.
    pub outside: usize,
    /// Target times inside a gap longer than [`MAX_GAP_PERIODS`].
    pub in_gaps: usize,
    /// The source's sample period (90th percentile of its intervals), s.
    pub period: f64,
}

/// Why one sensor's readings cannot be put on another's times.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResampleError {
    #[error("{what} has {values} readings and {times} times: each reading needs its time")]
    LengthMismatch {
        what: String,
        values: usize,
        times: usize,
    },
    #[error(
        "the times of {what} are not finite and increasing at row {row}: the times must be in increasing order, on one clock"
    )]
    BadTimes { what: String, row: usize },
    #[error(
        "the clocks do not overlap: {what} runs from {source_start} s to {source_end} s, the samples it is joined to from {target_start} s to {target_end} s; the two files must be recorded together, on the same clock"
    )]
    NoOverlap {
        what: String,
        source_start: f64,
        source_end: f64,
        target_start: f64,
        target_end: f64,
    },
}

/// Interpolates `values` (at `times`, increasing) linearly at each of
/// `at`, never across a gap longer than [`MAX_GAP_PERIODS`] periods nor
/// outside the span. `what` names the source in messages.
pub fn resample(
    what: &str,
    times: &[f64],
    values: &[[f64; 3]],
    at: &[f64],
) -> Result<Resampled, ResampleError> {
    if times.len() != values.len() {
        return Err(ResampleError::LengthMismatch {
            what: what.to_string(),
            values: values.len(),
            times: times.len(),
        });
    }
    for (i, t) in times.iter().enumerate() {
        if !t.is_finite() || (i > 0 && *t <= times[i - 1]) {
            return Err(ResampleError::BadTimes {
                what: what.to_string(),
                row: i + 1,
            });
        }
    }
    let span = |t: &[f64]| {
        (
            t.first().copied().unwrap_or(f64::NAN),
            t.last().copied().unwrap_or(f64::NAN),
        )
    };
    let (s0, s1) = span(times);
    let (t0, t1) = span(at);
    let no_overlap = || ResampleError::NoOverlap {
        what: what.to_string(),
        source_start: s0,
        source_end: s1,
        target_start: t0,
        target_end: t1,
    };
    if times.len() < 2 || !(t1 >= s0 && t0 <= s1) {
        return Err(no_overlap());
    }
    let mut dt: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    dt.sort_by(|a, b| a.total_cmp(b));
    let period = dt[(dt.len() - 1) * 9 / 10];
    let max_gap = MAX_GAP_PERIODS * period;
    let (mut outside, mut in_gaps) = (0, 0);
    let values = at
        .iter()
        .map(|&t| {
            if !(t >= s0 && t <= s1) {
                outside += 1;
                return [f64::NAN; 3];
            }
            let k = times.partition_point(|&v| v <= t);
            if k >= times.len() {
                return values[times.len() - 1];
            }
            let (ta, tb) = (times[k - 1], times[k]);
            if tb - ta > max_gap {
                in_gaps += 1;
                return [f64::NAN; 3];
            }
            let w = (t - ta) / (tb - ta);
            [0, 1, 2].map(|i| values[k - 1][i] + w * (values[k][i] - values[k - 1][i]))
        })
        .collect();
    if outside == at.len() {
        return Err(no_overlap());
    }
    Ok(Resampled {
        values,
        outside,
        in_gaps,
        period,
    })
}

/// What a board reads (unit field, unit specific force) at `heading`
/// (clockwise from north to its +x axis), pitched up by `pitch_deg` about
/// its right axis and rolled right by `roll_deg` about its forward axis,
/// in a field of inclination `inclination_deg`: the inverse of
/// [`tilt_heading`] for a board with x forward, z up (at rest it reads
/// +1 on z). For simulations and tests.
pub fn board_reading(
    heading_deg: f64,
    pitch_deg: f64,
    roll_deg: f64,
    inclination_deg: f64,
) -> ([f64; 3], [f64; 3]) {
    use nalgebra::{Matrix3, Rotation3};
    let d = inclination_deg.to_radians();
    // World frame: east, north, up.
    let field = Vector3::new(0.0, d.cos(), -d.sin());
    let up = Vector3::new(0.0, 0.0, 1.0);
    let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), -heading_deg.to_radians());
    // A body at heading 0 has x north, y west, z up.
    let base = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let pitch = Rotation3::from_axis_angle(&Vector3::y_axis(), -pitch_deg.to_radians());
    let roll = Rotation3::from_axis_angle(&Vector3::x_axis(), roll_deg.to_radians());
    let body_to_world = yaw.matrix() * base * pitch.matrix() * roll.matrix();
    let w2b = body_to_world.transpose();
    let (m, a) = (w2b * field, w2b * up);
    ([m.x, m.y, m.z], [a.x, a.y, a.z])
}

/// A stored 3-D calibration, as `fieldcal fit --json` writes it for
/// three axes: calibrated = W·(raw − o), |calibrated| = r.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration3 {
    /// The columns it was fitted to: x, y, z.
    pub columns: [String; 3],
    /// o, W (row-major) and r.
    pub calibration: Calibration3D,
    /// The raw readings' units, when known.
    pub units: Option<String>,
}

/// Why a stored calibration was not understood.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Calibration3Error {
    #[error("not JSON ({message}): give the output of `fieldcal fit --json` on a 3-axis recording")]
    NotJson { message: String },
    #[error(
        "a calibration of {axes} axes: the heading needs a 3-D one; fit the three axes (`fieldcal fit FILE --x X --y Y --z Z --json`)"
    )]
    NotThreeAxes { axes: String },
    #[error(
        "no {field} (a {what}): give the output of `fieldcal fit --json` on a 3-axis recording"
    )]
    Missing {
        field: &'static str,
        what: &'static str,
    },
    #[error(
        "the numbers cannot be a calibration: {problem}; fit the recording again (`fieldcal fit FILE --x X --y Y --z Z --json`)"
    )]
    Impossible { problem: String },
    #[error(
        "the calibration's model has effects the heading cannot apply ({model}: {parameters}; the heading applies the offset and W alone): give the calibration of the model without them (`fieldcal fit FILE --x X --y Y --z Z --effects {base} --json`)"
    )]
    WithEffects {
        model: String,
        parameters: String,
        base: String,
    },
}

impl Calibration3 {
    /// Parses the JSON of `fieldcal fit --json` in 3-D (`"axes": 3`,
    /// `"x_column"`, `"y_column"`, `"z_column"`, `"params": {"offset":
    /// [3], "matrix": [[3]; 3], "r"}`, `"units"`).
    pub fn from_json(text: &str) -> Result<Calibration3, Calibration3Error> {
        let v: serde_json::Value =
            serde_json::from_str(text).map_err(|e| Calibration3Error::NotJson {
                message: e.to_string(),
            })?;
        match v.get("axes").and_then(|a| a.as_u64()) {
            Some(3) => {}
            Some(n) => {
                return Err(Calibration3Error::NotThreeAxes {
                    axes: n.to_string(),
                });
            }
            None => {
                return Err(Calibration3Error::NotThreeAxes {
                    axes: "two (no \"axes\": 3)".to_string(),
                });
            }
        }
        let column = |field: &'static str| {
            v.get(field)
                .and_then(|c| c.as_str())
                .map(str::to_string)
                .ok_or(Calibration3Error::Missing {
                    field,
                    what: "column name",
                })
        };
        let columns = [
            column("x_column")?,
            column("y_column")?,
            column("z_column")?,
        ];
        let params = v.get("params").ok_or(Calibration3Error::Missing {
            field: "params",
            what: "object of offset, matrix and r",
        })?;
        let calibration = Calibration3D::from_json(params, ["params.offset", "params.matrix"])
            .map_err(|e| match e {
                Calibration3JsonError::NotTriple { field } => Calibration3Error::Missing {
                    field,
                    what: "list of three finite numbers",
                },
                Calibration3JsonError::NotRows { field } => Calibration3Error::Missing {
                    field,
                    what: "3 × 3 list of rows",
                },
            })?;
        match calibration.validate() {
            Err(Calibration3Invalid::NotFinite { field: "r" })
            | Err(Calibration3Invalid::RadiusNotPositive { .. }) => {
                return Err(Calibration3Error::Missing {
                    field: "params.r",
                    what: "positive number",
                });
            }
            Err(Calibration3Invalid::NotFinite { field }) => {
                return Err(Calibration3Error::Missing {
                    field: if field == "offset" {
                        "params.offset"
                    } else {
                        "params.matrix"
                    },
                    what: "list of three finite numbers",
                });
            }
            // A mirror, a collapse, a matrix or offset no sensor has:
            // applied, it would give headings off by up to 180°.
            Err(
                e @ (Calibration3Invalid::NotSymmetric
                | Calibration3Invalid::NotPositiveDefinite
                | Calibration3Invalid::Stretched { .. }
                | Calibration3Invalid::OffsetTooLarge { .. }),
            ) => {
                return Err(Calibration3Error::Impossible {
                    problem: e.to_string(),
                });
            }
            Ok(()) => {}
        }
        // `fit --effects full+drift` (covariate, cubic) adds the extras'
        // parameters: applying o and W alone would drop them silently.
        if let Some(extra) = params
            .get("extra")
            .and_then(|e| e.as_object())
            .filter(|e| !e.is_empty())
        {
            let text = |field: &str, default: &str| {
                v.get(field)
                    .and_then(|m| m.as_str())
                    .unwrap_or(default)
                    .to_string()
            };
            return Err(Calibration3Error::WithEffects {
                model: text("model", "a model with effects"),
                parameters: extra.keys().cloned().collect::<Vec<_>>().join(", "),
                base: text("base_model", "full"),
            });
        }
        let units = v.get("units").and_then(|u| u.as_str()).map(str::to_string);
        Ok(Calibration3 {
            columns,
            calibration,
            units,
        })
    }

    /// W·(raw − o).
    pub fn apply(&self, raw: [f64; 3]) -> [f64; 3] {
        self.calibration.correct(raw)
    }
}
