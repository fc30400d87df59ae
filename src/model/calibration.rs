//! The calibration values of the 2-D model, as the daemon publishes and
//! stores them and `fieldcal check` reads them back: [`Calibration`] (the
//! paper's parameters and the live-correctable [`Terms`], with a 3-axis
//! sensor's [`Ellipsoid3Params`]), the corrector [`apply`], and the state
//! file's [`FORMAT_VERSION`]. Here in the model, below the daemon and the
//! reports, so that `check` needs neither.

use serde::{Deserialize, Serialize};

use super::calibration3::{Calibration3D, correct3};
use super::nonlinear::Param;
use super::paper::PaperCalibration;

/// The version of the daemon's state file layout (one JSON file a sensor),
/// which `fieldcal check` also reads.
pub const FORMAT_VERSION: u32 = 1;

/// An accepted calibration of one sensor: what is published in a
/// `CALIBRATION` message, what is stored, and what corrects readings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// The sensor's name, from the configuration.
    pub sensor: String,
    /// Increases by one with every accepted calibration of the sensor,
    /// across restarts; readings name the id that corrected them.
    pub id: u64,
    /// The model as effect names joined by `+` (the paper's: `offset+scale`).
    pub model: String,
    /// The model's parameters.
    pub params: PaperCalibration,
    /// Root mean square of |calibrated|/r - 1 over the fitted samples.
    pub rms: f64,
    /// Heading coverage of the rotation that was fitted, in degrees.
    pub coverage_deg: f64,
    /// Samples fitted.
    pub n: usize,
    /// When it was accepted, in seconds since the Unix epoch.
    pub time: f64,
    /// Terms of the effects beyond the paper's (zero when absent, and then
    /// left out of the JSON, so files of the paper's model stay as they were).
    #[serde(default, skip_serializing_if = "Terms::is_none")]
    pub terms: Terms,
    /// A 3-axis sensor's calibration (then `params` is the identity with
    /// the field's r, and `coverage_deg` 0); absent for a 2-axis one, so its
    /// files stay as they were.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ellipsoid: Option<Ellipsoid3Params>,
    /// Each parameter's standard error by name, widened for the fitted
    /// residuals' correlation in time ([`crate::model::watch`]); empty for
    /// a calibration stored without them.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub se: std::collections::BTreeMap<String, f64>,
    /// The calibration this one refined or replaced, by id.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<u64>,
    /// The calibrations before this one, oldest first, at most
    /// [`crate::model::watch::HISTORY`] (each with an empty history of its
    /// own): what `rollback` returns to.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub history: Vec<Calibration>,
    /// The gyro as the calibration's heading check found it, when it had
    /// one: kept so the trust monitor checks the heading against the gyro
    /// after a restart too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gyro: Option<GyroFit>,
    /// A 3-axis compass's dip over its calibration's sphere, against its
    /// tilt accelerometer's vertical, when it has one: kept so the trust
    /// monitor checks each reading's dip against it, after a restart too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dip: Option<DipFit>,
    /// A 2-axis sensor's field across its turn over the calibration's
    /// rotation, when its configuration names that axis: raw units, median
    /// and robust spread, kept so the trust monitor checks each reading's
    /// against it, after a restart too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub across: Option<AcrossFit>,
    /// A 2-axis compass's attitude over the calibration's rotation, when
    /// its configuration names a tilt accelerometer: kept so the trust
    /// monitor checks each reading's tilt against it, after a restart too.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level: Option<LevelFit>,
}

/// The attitude a 2-axis compass was calibrated in: its tilt
/// accelerometer's mean vertical over the rotation ([`crate::model::level::level_of`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelFit {
    /// The specific force's direction (up, a unit vector) in the
    /// accelerometer's raw axes.
    pub up: [f64; 3],
    /// The tilt's spread about `up` along one axis, degrees: the median
    /// tilt over the rotation / √(2 ln 2), a Rayleigh distribution's σ.
    pub tilt_sd_deg: f64,
    pub n: usize,
    /// The tilt accelerometer it was measured with (its sensor and axes or
    /// columns): a reading tilted against another is not compared with it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt: Option<String>,
}

/// The reading of the axis across a turn over a calibration's rotation:
/// median, robust spread (1.4826 × MAD), raw units, and samples.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AcrossFit {
    pub median: f64,
    pub spread: f64,
    pub n: usize,
}

/// The dip measured over a calibration's samples: median and robust
/// spread (1.4826 × MAD), degrees, how many samples had a dip, and the
/// tilt accelerometer's calibration that corrected its readings (none:
/// raw): a reading's dip is comparable only through the same correction,
/// whatever the accelerometer's calibration is by then.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DipFit {
    pub median_deg: f64,
    pub spread_deg: f64,
    pub n: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accel: Option<Ellipsoid3Params>,
    /// Why the configured `mag_axes` cannot be how the magnetometer lies on
    /// the accelerometer ([`crate::model::tilt::mounting_problem`]): then
    /// every tilt-compensated heading is distrusted with this reason.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mounting: Option<String>,
    /// The `mag_axes` the dip was measured with ("x,y,z" when absent): a
    /// reading mapped otherwise is not compared with it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mag_axes: Option<String>,
}

/// A heading check's gyro: heading ≈ scale · ∫(rate − bias), and the
/// heading's rms error against it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GyroFit {
    pub scale: f64,
    pub bias_deg_s: f64,
    pub heading_rms_deg: f64,
    /// A 3-axis gyro's bias on each of its axes (the tilt accelerometer's),
    /// deg/s: a 3-axis compass's ([`crate::model::gyro3`]), whose heading
    /// rate is `scale` · (ω − this) · v / |v|², and `bias_deg_s` 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bias_xyz_deg_s: Option<[f64; 3]>,
    /// A 3-axis compass's: the gyro, its units and the `mag_axes` it was
    /// fitted with; a heading read otherwise is not checked against it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
}

/// The 3-D model of a 3-axis sensor: calibrated = W·(raw − o), with
/// |calibrated| = r (see [`crate::model::ellipsoid`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Ellipsoid3Params {
    /// o, raw units.
    pub offset: [f64; 3],
    /// W, row-major, symmetric, det W = 1.
    pub matrix: [[f64; 3]; 3],
    /// The field's magnitude, raw units.
    pub r: f64,
    /// The share of the sphere's regions the fitted samples reached.
    pub coverage: f64,
}

impl Ellipsoid3Params {
    /// The calibration itself (o, W, r), without the coverage.
    pub fn calibration(&self) -> Calibration3D {
        Calibration3D {
            offset: self.offset,
            matrix: self.matrix,
            r: self.r,
        }
    }

    /// W·(raw − o).
    pub fn correct(&self, raw: [f64; 3]) -> [f64; 3] {
        correct3(&self.offset, &self.matrix, raw)
    }
}

/// The live-correctable effects' terms: cross-axis coupling `c`, the odd
/// cubic per axis `k` relative to the full scale `cubic_scale`, and the odd
/// cubic about the turn's centre `kc` relative to the turn's radius per
/// axis `turn_radius` (raw units, as `centre`). The centred terms are left
/// out of the JSON when absent, and default to absent, so state files
/// written before them still load and read the same.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Terms {
    #[serde(default)]
    pub c: f64,
    #[serde(default)]
    pub k: [f64; 2],
    #[serde(default)]
    pub cubic_scale: f64,
    #[serde(default, skip_serializing_if = "is_zero_pair")]
    pub kc: [f64; 2],
    #[serde(default, skip_serializing_if = "is_zero_pair")]
    pub centre: [f64; 2],
    #[serde(default, skip_serializing_if = "is_zero_pair")]
    pub turn_radius: [f64; 2],
}

fn is_zero_pair(pair: &[f64; 2]) -> bool {
    *pair == [0.0; 2]
}

impl Terms {
    pub fn is_none(&self) -> bool {
        *self == Terms::default()
    }
}

impl Calibration {
    /// The corrected reading of a raw sample: the cubic terms removed (about
    /// the sensor's zero and about the turn's centre), then the paper's
    /// gains and offsets with the cross-axis coupling.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        apply(&self.params, &self.terms, x, y)
    }
}

/// The corrected reading of a raw sample under a model's parameters and
/// terms (see [`Calibration::apply`]); also for fits not (yet) accepted.
pub fn apply(p: &PaperCalibration, t: &Terms, x: f64, y: f64) -> (f64, f64) {
    let (mut x2, mut y2) = if t.cubic_scale > 0.0 {
        let s2 = t.cubic_scale * t.cubic_scale;
        (x + t.k[0] * x * x * x / s2, y + t.k[1] * y * y * y / s2)
    } else {
        (x, y)
    };
    if t.turn_radius.iter().all(|s| *s > 0.0) {
        let (vx, vy) = (x - t.centre[0], y - t.centre[1]);
        x2 += t.kc[0] * vx * vx * vx / (t.turn_radius[0] * t.turn_radius[0]);
        y2 += t.kc[1] * vy * vy * vy / (t.turn_radius[1] * t.turn_radius[1]);
    }
    (p.a * x2 + p.b + t.c * (y2 + p.d), y2 + p.d)
}

/// The paper's parameters with their standard errors, by name.
pub fn paper_parameters(c: &PaperCalibration, se: Option<&PaperCalibration>) -> Vec<Param> {
    let se = se.copied().unwrap_or(PaperCalibration {
        a: f64::NAN,
        b: f64::NAN,
        d: f64::NAN,
        r: f64::NAN,
    });
    [
        ("a", c.a, se.a),
        ("b", c.b, se.b),
        ("d", c.d, se.d),
        ("r", c.r, se.r),
    ]
    .into_iter()
    .map(|(name, value, se)| Param {
        name: name.into(),
        value,
        se,
    })
    .collect()
}
