//! What the daemon publishes: one JSON object per line, each with a
//! `class`, in the manner of gpsd. Absent values are omitted, never null
//! (a number that is not finite is written `null`, as serde_json writes
//! it).
//!
//! One clock for every message of a run (`time`, in seconds):
//! - under `fieldcal run`, the host's Unix clock (seconds since the epoch),
//!   never going back ([`crate::source::clock`]).
//!   A live source stamps a reading when it arrives; a replay or csv source
//!   stamps it with the Unix time the source started plus the reading's
//!   offset in the recording (not divided by the speed, so the time between
//!   readings, which the rotation's timeouts and the gyro's integration
//!   use, is what the sensor saw). STATUS is stamped when it is made.
//! - under `fieldcal replay --config`, the recording's clock (a capture's
//!   seconds from its start, a CSV's time column or row * period_s), for
//!   READING, CALIBRATION and STATUS alike, so the output is the same on
//!   every run.

use serde::Serialize;

use super::Calibration;
use crate::model::gyro::HeadingCheck;
use crate::model::paper::PaperCalibration;
use crate::model::rotation::Progress;
use crate::source::CountersSnapshot;

/// `,"name":`, the fixed text before a field's value in a line written
/// directly.
macro_rules! key {
    ($name:literal) => {
        concat!(",\"", $name, "\":")
    };
}

/// A sample of one sensor, raw and (once calibrated) corrected.
#[derive(Debug, Clone, Serialize)]
pub struct ReadingMessage<'a> {
    pub class: &'static str,
    pub sensor: &'a str,
    /// When the sample was taken: on the host's Unix clock under `run`, on
    /// the recording's clock under `replay --config` (see the module).
    pub time: f64,
    /// The two turning axes, in counts.
    pub raw: [f64; 2],
    /// The calibrated axes (in the y axis' units), once a calibration exists.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub corrected: Option<[f64; 2]>,
    /// Heading of the corrected reading, degrees counter-clockwise from +x in [0, 360).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_deg: Option<f64>,
    /// The heading from true north (`heading_deg` plus the sensor's
    /// declination, in [0, 360)), when the sensor has a declination.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_heading_deg: Option<f64>,
    /// The id of the calibration that corrected it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<u64>,
    /// False until the sensor has a calibration: the reading is raw only.
    pub calibrated: bool,
    /// Whether the calibrated reading can be believed (see
    /// [`crate::model::trust`]); absent while uncalibrated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trusted: Option<bool>,
    /// Why not, with the deciding numbers; absent when trusted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distrust: Option<&'a [String]>,
    /// A csv source's other columns (all but the time and the two axes),
    /// by header name, where the row holds a number: `{"temp_c": 21.3}`.
    /// Omitted when there are none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub columns: Option<ColumnValues<'a>>,
}

impl ReadingMessage<'_> {
    /// The line [`to_line`] writes for this message, byte for byte, written
    /// directly: the keys are fixed text and each value is serde_json's
    /// own (the same digits, the same escapes, `null` for a value that is
    /// not finite), without the serializer's work for each key. A READING
    /// goes out for every sample, so this is the reading path's line (and,
    /// through [`Self::write_line`], the replay's).
    pub fn to_line(&self) -> String {
        let mut line = String::with_capacity(LINE_CAPACITY);
        self.write_line(&mut line);
        line
    }

    /// [`Self::to_line`], appended to `out` (a buffer used again for each
    /// line).
    pub fn write_line(&self, out: &mut String) {
        let mut line = JsonLine::reading(out, self.class, self.sensor, self.time);
        line.field(key!("raw"), &self.raw);
        line.optional(key!("corrected"), self.corrected.as_ref());
        line.optional(key!("heading_deg"), self.heading_deg.as_ref());
        line.optional(key!("true_heading_deg"), self.true_heading_deg.as_ref());
        line.optional(key!("calibration"), self.calibration.as_ref());
        line.field(key!("calibrated"), &self.calibrated);
        line.optional(key!("trusted"), self.trusted.as_ref());
        line.optional(key!("distrust"), self.distrust);
        line.optional(key!("columns"), self.columns.as_ref());
        line.end();
    }
}

/// A 2-axis READING's values, owned (all but the sensor's name and a csv
/// row's columns), so that its line can be written later and elsewhere:
/// a replay at full speed writes its lines on a thread of its own.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadingValues {
    pub time: f64,
    pub raw: [f64; 2],
    pub corrected: Option<[f64; 2]>,
    pub heading_deg: Option<f64>,
    pub true_heading_deg: Option<f64>,
    pub calibration: Option<u64>,
    pub calibrated: bool,
    pub trusted: Option<bool>,
    /// Why not trusted; none when there is no reason.
    pub distrust: Option<Vec<String>>,
}

impl ReadingValues {
    /// The READING of sensor `sensor` with these values.
    pub fn message<'a>(&'a self, sensor: &'a str) -> ReadingMessage<'a> {
        ReadingMessage {
            class: "READING",
            sensor,
            time: self.time,
            raw: self.raw,
            corrected: self.corrected,
            heading_deg: self.heading_deg,
            true_heading_deg: self.true_heading_deg,
            calibration: self.calibration,
            calibrated: self.calibrated,
            trusted: self.trusted,
            distrust: self.distrust.as_deref(),
            columns: None,
        }
    }
}

/// The accelerometer beside a 3-axis magnetometer's READING.
#[derive(Debug, Clone, Serialize)]
pub struct TiltFields<'a> {
    /// The accelerometer sensor.
    pub sensor: &'a str,
    /// Its calibration that corrected the accelerometer, or none: the
    /// accelerometer's raw readings were used.
    pub calibration: Option<u64>,
    pub calibrated: bool,
    pub tilt_deg: f64,
    pub pitch_deg: f64,
    pub inclination_deg: f64,
}

/// A sample of one 3-axis sensor, raw and (once calibrated) corrected.
#[derive(Debug, Clone, Serialize)]
pub struct Reading3Message<'a> {
    pub class: &'static str,
    pub sensor: &'a str,
    pub time: f64,
    pub axes: u8,
    pub raw: [f64; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    pub corrected: Option<[f64; 3]>,
    /// |corrected|: the field's magnitude, ≈ r.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub magnitude: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<u64>,
    pub calibrated: bool,
    /// Tilt-compensated, clockwise from magnetic north to the sensor's +x.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_deg: Option<f64>,
    /// `heading_deg` from true north, when the sensor has a declination.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub true_heading_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tilt: Option<TiltFields<'a>>,
    /// Why a calibrated magnetometer with a tilt source has no heading.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_omitted: Option<String>,
    /// Whether the calibrated reading can be believed; absent while
    /// uncalibrated ([`crate::model::trust`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trusted: Option<bool>,
    /// Why not, with the deciding numbers; absent when trusted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distrust: Option<&'a [String]>,
}

impl Reading3Message<'_> {
    /// The line [`to_line`] writes for this message, byte for byte, written
    /// directly (as [`ReadingMessage::to_line`]).
    pub fn to_line(&self) -> String {
        let mut out = String::with_capacity(LINE_CAPACITY);
        let mut line = JsonLine::reading(&mut out, self.class, self.sensor, self.time);
        line.field(key!("axes"), &self.axes);
        line.field(key!("raw"), &self.raw);
        line.optional(key!("corrected"), self.corrected.as_ref());
        line.optional(key!("magnitude"), self.magnitude.as_ref());
        line.optional(key!("calibration"), self.calibration.as_ref());
        line.field(key!("calibrated"), &self.calibrated);
        line.optional(key!("heading_deg"), self.heading_deg.as_ref());
        line.optional(key!("true_heading_deg"), self.true_heading_deg.as_ref());
        line.optional(key!("tilt"), self.tilt.as_ref());
        line.optional(key!("heading_omitted"), self.heading_omitted.as_ref());
        line.optional(key!("trusted"), self.trusted.as_ref());
        line.optional(key!("distrust"), self.distrust);
        line.end();
        out
    }
}

/// A message's line written field by field: keys are fixed text (they
/// need no escapes), each value is written as serde_json writes it.
/// It is appended to the buffer it holds.
struct JsonLine<'a>(&'a mut String);

impl<'a> JsonLine<'a> {
    /// `{"class":…,"sensor":…,"time":…`, the start of every READING.
    fn reading(out: &'a mut String, class: &str, sensor: &str, time: f64) -> Self {
        let mut line = JsonLine(out);
        line.0.push_str("{\"class\":");
        class.write_json(line.0);
        line.field(key!("sensor"), sensor);
        line.field(key!("time"), &time);
        line
    }

    /// `key` (a [`key!`]: `,"name":`), then the value.
    fn field<T: JsonValue + ?Sized>(&mut self, key: &str, value: &T) {
        self.0.push_str(key);
        value.write_json(self.0);
    }

    /// [`Self::field`], when there is a value.
    fn optional<T: JsonValue + ?Sized>(&mut self, key: &str, value: Option<&T>) {
        if let Some(value) = value {
            self.field(key, value);
        }
    }

    fn end(self) {
        self.0.push('}');
    }
}

/// A value of a READING line, written as serde_json writes it, byte for
/// byte: the plain values (strings, numbers, booleans, arrays of numbers)
/// directly, with serde_json's own float formatter (`zmij`) and integer
/// formatter (`itoa`) and its escapes; the rest through serde_json.
trait JsonValue {
    fn write_json(&self, out: &mut String);
}

impl JsonValue for str {
    /// A string: quoted, with serde_json's escapes when it needs any
    /// (control characters, `"` and `\`; everything else is written as
    /// it is).
    fn write_json(&self, out: &mut String) {
        if self.bytes().any(|b| b < 0x20 || b == b'"' || b == b'\\') {
            serialized(self, out);
        } else {
            out.push('"');
            out.push_str(self);
            out.push('"');
        }
    }
}

impl JsonValue for f64 {
    /// The shortest digits that read back to the same number; `null` for
    /// a value that is not finite.
    fn write_json(&self, out: &mut String) {
        if self.is_finite() {
            out.push_str(zmij::Buffer::new().format_finite(*self));
        } else {
            out.push_str("null");
        }
    }
}

impl<const N: usize> JsonValue for [f64; N] {
    fn write_json(&self, out: &mut String) {
        out.push('[');
        for (k, value) in self.iter().enumerate() {
            if k > 0 {
                out.push(',');
            }
            value.write_json(out);
        }
        out.push(']');
    }
}

impl JsonValue for u64 {
    fn write_json(&self, out: &mut String) {
        out.push_str(itoa::Buffer::new().format(*self));
    }
}

impl JsonValue for u8 {
    fn write_json(&self, out: &mut String) {
        out.push_str(itoa::Buffer::new().format(*self));
    }
}

impl JsonValue for bool {
    fn write_json(&self, out: &mut String) {
        out.push_str(if *self { "true" } else { "false" });
    }
}

impl JsonValue for String {
    fn write_json(&self, out: &mut String) {
        self.as_str().write_json(out);
    }
}

/// The values written through serde_json.
macro_rules! json_value_by_serde {
    ($($t:ty),*) => {$(
        impl JsonValue for $t {
            fn write_json(&self, out: &mut String) {
                serialized(self, out);
            }
        }
    )*};
}
json_value_by_serde!([String], ColumnValues<'_>, TiltFields<'_>);

/// `value` as serde_json writes it. Serialising the plain values of a
/// message cannot fail; nothing is written if it did.
fn serialized<T: Serialize + ?Sized>(value: &T, out: &mut String) {
    let written = serde_json::to_string(value);
    debug_assert!(written.is_ok(), "a message's value did not serialise");
    if let Ok(text) = written {
        out.push_str(&text);
    }
}

/// Some columns of a CSV row, serialised as a map from the header's names
/// to the row's values; cells that are not numbers are left out. Borrows
/// the header (resolved once) and the row: nothing is copied per reading.
#[derive(Debug, Clone, Copy)]
pub struct ColumnValues<'a> {
    /// The header, in file order.
    pub names: &'a [String],
    /// Which columns, as indices into `names` and `values`.
    pub indices: &'a [usize],
    /// The row, in file order.
    pub values: &'a [f64],
}

impl ColumnValues<'_> {
    fn entries(&self) -> impl Iterator<Item = (&str, f64)> {
        self.indices.iter().filter_map(|&i| {
            let value = *self.values.get(i)?;
            let name = self.names.get(i)?;
            value.is_finite().then_some((name.as_str(), value))
        })
    }

    /// No column holds a number.
    pub fn is_empty(&self) -> bool {
        self.entries().next().is_none()
    }
}

impl Serialize for ColumnValues<'_> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(None)?;
        for (name, value) in self.entries() {
            map.serialize_entry(name, &value)?;
        }
        map.end()
    }
}

/// A fit, accepted or rejected.
#[derive(Debug, Clone, Serialize)]
pub struct CalibrationMessage<'a> {
    pub class: &'static str,
    pub sensor: &'a str,
    pub accepted: bool,
    /// The new calibration's id (accepted fits only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u64>,
    /// Why the fit was rejected, or why no fit was possible.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    pub model: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub params: Option<PaperCalibration>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rms: Option<f64>,
    pub coverage_deg: f64,
    pub n: usize,
    /// Milliseconds the fit took.
    pub fit_ms: f64,
    /// The time of the rotation's last sample (the clock of the readings;
    /// see the module), or when a loaded calibration was accepted.
    pub time: f64,
    /// Where the calibration came from: `rotation` (fitted now) or `state`
    /// (loaded from the state directory at start).
    pub origin: &'static str,
    /// The calibration this one refined or replaced (`origin` `refined`
    /// or `replaced`), by id.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub parent: Option<u64>,
    /// Terms of the effects beyond the paper's, when the model has them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub terms: Option<super::Terms>,
    /// Each parameter's standard error, widened for residuals correlated
    /// in time.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub se: Option<&'a std::collections::BTreeMap<String, f64>>,
    /// The noise floor estimated from the rotation itself (rms, fraction of the field).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise_floor: Option<f64>,
    /// The effect the rotation's residual supports adding to the model, if any:
    /// add it to the sensor's `model` in the configuration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub suggested: Option<String>,
    /// An effect that explains the rotation's residual about as well as the
    /// suggested one (one turn cannot tell them apart; see `diagnose`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub close_second: Option<String>,
    /// The fitted model's heading against the integrated gyro of the
    /// sensor's source, when a check was possible.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_vs_gyro: Option<HeadingCheck>,
    /// Why the heading could not be checked against a gyro, when a model
    /// was fitted but no check was possible.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heading_check: Option<String>,
    /// The sensor's declination (degrees east of true north), its source
    /// (`config`, or `WMM2025 at LAT,LON,DATE`) and, from the model, its
    /// 1σ: when the sensor has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub declination_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub declination_source: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub declination_uncertainty_deg: Option<f64>,
    /// The field across the turn over the rotation (`out_of_plane`): its
    /// median and spread, raw units, which each reading is checked against.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub across: Option<crate::model::calibration::AcrossFit>,
    /// The attitude over the rotation (`tilt`): the tilt accelerometer's
    /// vertical and the tilt's spread about it, which each reading's tilt
    /// is checked against.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub level: Option<&'a crate::model::calibration::LevelFit>,
}

/// A `STALE` line: a later rotation moved the calibration further than
/// its standard errors allow, by enough to turn the heading beyond a
/// reading's noise ([`crate::model::watch`]).
#[derive(Debug, Serialize)]
pub struct StaleMessage<'a> {
    pub class: &'static str,
    pub sensor: &'a str,
    /// The rotation's last sample, on the clock of the READINGs.
    pub time: f64,
    /// The id of the calibration that no longer holds.
    pub calibration: u64,
    /// Each parameter compared: stored, now (`refitted`), z, moved.
    pub parameters: &'a [crate::model::check::ParamShift],
    pub z_threshold: f64,
    /// The largest heading error the move causes over the rotation.
    pub heading_error_deg: f64,
    /// One reading's heading noise, for scale.
    pub heading_noise_deg: f64,
    /// The heading error beyond which a move is stale (3 × the noise).
    pub heading_limit_deg: f64,
    /// `warn` (readings distrusted until recalibrated) or `replace` (the
    /// new fit is the calibration now).
    pub action: &'static str,
    /// What happened and what to do, in words.
    pub message: &'a str,
}

/// Whether a CALIBRATION of `origin` is one kept before (loaded from the
/// state file at start, or returned to by `rollback`), not a fit of
/// samples just collected: the progress board then logs no rotation.
pub fn is_stored(origin: &str) -> bool {
    matches!(origin, "state" | "rollback")
}

impl<'a> CalibrationMessage<'a> {
    /// A rejected fit of `model` for `sensor` with nothing else known: the
    /// start of every message.
    pub fn rejected(sensor: &'a str, model: &'a str, reason: Option<String>) -> Self {
        CalibrationMessage {
            class: "CALIBRATION",
            sensor,
            accepted: false,
            id: None,
            reason,
            model,
            params: None,
            rms: None,
            coverage_deg: 0.0,
            n: 0,
            fit_ms: 0.0,
            time: 0.0,
            origin: "rotation",
            parent: None,
            terms: None,
            se: None,
            noise_floor: None,
            suggested: None,
            close_second: None,
            heading_vs_gyro: None,
            heading_check: None,
            declination_deg: None,
            declination_source: None,
            declination_uncertainty_deg: None,
            across: None,
            level: None,
        }
    }

    pub fn loaded(calibration: &'a Calibration) -> Self {
        CalibrationMessage {
            accepted: true,
            id: Some(calibration.id),
            params: Some(calibration.params),
            rms: Some(calibration.rms),
            coverage_deg: calibration.coverage_deg,
            n: calibration.n,
            time: calibration.time,
            origin: "state",
            parent: calibration.parent,
            terms: (!calibration.terms.is_none()).then_some(calibration.terms),
            se: (!calibration.se.is_empty()).then_some(&calibration.se),
            across: calibration.across,
            level: calibration.level.as_ref(),
            ..Self::rejected(&calibration.sensor, &calibration.model, None)
        }
    }

    /// With the declination of `north`, when there is one.
    pub fn with_north(self, north: Option<&'a super::north::North>) -> Self {
        CalibrationMessage {
            declination_deg: north.map(|n| n.declination_deg),
            declination_source: north.map(|n| n.source.as_str()),
            declination_uncertainty_deg: north.and_then(|n| n.uncertainty_deg()),
            ..self
        }
    }
}

/// A `CALIBRATION` as the progress board takes it: what the published
/// line says about the fit's outcome, as a plain value, so the board never
/// reads the line back. Built from the message just before it is
/// serialised ([`CalibrationMessage::event`], and the 3-axis message's).
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationEvent {
    pub sensor: String,
    pub accepted: bool,
    /// The new calibration's id (accepted fits only).
    pub id: Option<u64>,
    /// Why the fit was rejected, or why no fit was possible.
    pub reason: Option<String>,
    /// Fraction of the field.
    pub rms: Option<f64>,
    /// Headings covered, degrees (0 for a 3-axis sensor's sphere).
    pub coverage_deg: f64,
    /// Samples fitted.
    pub n: usize,
    /// Kept before rather than fitted now: loaded from the state directory
    /// (`origin` `state`) or returned to by `rollback` ([`is_stored`]).
    pub stored: bool,
    /// The effect the residual suggests adding, if any.
    pub suggested: Option<String>,
    /// The heading's rms error against the integrated gyro, degrees, when
    /// it was checked.
    pub heading_rms_deg: Option<f64>,
    /// Why the heading could not be checked against a gyro.
    pub heading_check: Option<String>,
    /// A still-pose sensor's fit: its poses.
    pub poses: Option<usize>,
    /// 2 for a plane's rotation, 3 for a sphere.
    pub axes: u8,
}

/// A number as a published line carries it: JSON has no NaN or infinity,
/// so such a number goes out as `null`. The board shows what the line
/// says: an optional number that is not finite is absent, and a line whose
/// required number is not finite says nothing it can read (`None`).
pub(crate) fn as_published(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

impl CalibrationMessage<'_> {
    /// The outcome this message publishes, for the progress board; `None`
    /// when a number it needs cannot be published (see [`as_published`]).
    pub fn event(&self) -> Option<CalibrationEvent> {
        let heading_rms_deg = match &self.heading_vs_gyro {
            Some(h) => Some(as_published(h.rms_deg)?),
            None => None,
        };
        Some(CalibrationEvent {
            sensor: self.sensor.to_string(),
            accepted: self.accepted,
            id: self.id,
            reason: self.reason.clone(),
            rms: self.rms.and_then(as_published),
            coverage_deg: as_published(self.coverage_deg)?,
            n: self.n,
            stored: is_stored(self.origin),
            suggested: self.suggested.clone(),
            heading_rms_deg,
            heading_check: self.heading_check.clone(),
            poses: None,
            axes: 2,
        })
    }
}

/// Where a sensor is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorState {
    /// No calibration yet: collecting the first rotation.
    Collecting,
    /// Calibrated, correcting every reading.
    Calibrated,
    /// Calibrated and collecting a new rotation (after `recalibrate`).
    Recalibrating,
}

/// One sensor in a `STATUS` message; its texts `S`: borrowed from the
/// sensor (`&str`), or owned ([`SensorStatus::map`]) to be written on
/// another thread.
#[derive(Debug, Clone, Serialize)]
pub struct SensorStatus<S> {
    pub sensor: S,
    pub source: S,
    pub state: SensorState,
    /// Rotation progress, while collecting.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation: Option<Progress>,
    /// A 3-axis sensor's sphere coverage, while collecting.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sphere: Option<super::sensor3::SphereProgress>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<u64>,
    /// A 3-axis magnetometer with a tilt source: readings whose heading was
    /// left out because the accelerometer's latest reading was stale
    /// ([`super::sensor3::MAX_TILT_AGE_S`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub headings_stale: Option<u64>,
    /// Readings trusted and distrusted under the current calibration, and
    /// the longest distrusted stretch ([`crate::model::trust`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trust: Option<crate::model::trust::TrustCounts>,
    /// Why the current calibration is stale, while it is (a `STALE` line
    /// said so; `on_stale = "warn"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stale: Option<S>,
    pub readings: u64,
    /// Samples refused as spikes ([`crate::model::spike`]): published,
    /// never collected nor fitted; and the last one's sentence.
    #[serde(skip_serializing_if = "is_zero")]
    pub spikes: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_spike: Option<S>,
    pub fits_accepted: u64,
    pub fits_rejected: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_rejection: Option<S>,
}

impl<S> SensorStatus<S> {
    /// The same status with each text `text(…)`.
    pub fn map<T>(self, text: impl Fn(S) -> T) -> SensorStatus<T> {
        SensorStatus {
            sensor: text(self.sensor),
            source: text(self.source),
            state: self.state,
            rotation: self.rotation,
            sphere: self.sphere,
            calibration: self.calibration,
            headings_stale: self.headings_stale,
            trust: self.trust,
            stale: self.stale.map(&text),
            readings: self.readings,
            spikes: self.spikes,
            last_spike: self.last_spike.map(&text),
            fits_accepted: self.fits_accepted,
            fits_rejected: self.fits_rejected,
            last_rejection: self.last_rejection.map(&text),
        }
    }
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

/// A source in a `STATUS` message: its decoder and connection counters;
/// its name `S` as in [`SensorStatus`].
#[derive(Debug, Clone, Serialize)]
pub struct SourceStatus<S> {
    pub source: S,
    pub connected: bool,
    #[serde(flatten)]
    pub counters: CountersSnapshot,
}

/// The periodic `STATUS` message.
#[derive(Debug, Clone, Serialize)]
pub struct StatusMessage<S> {
    pub class: &'static str,
    /// When it was made: the host's Unix clock under `run`, the recording's
    /// clock under `replay --config` (see the module).
    pub time: f64,
    pub sensors: Vec<SensorStatus<S>>,
    pub sources: Vec<SourceStatus<S>>,
    pub subscribers: usize,
    /// Readings dropped for slow subscribers, in all.
    pub dropped: u64,
}

/// Serialises a message to one line (without the newline). Serialising
/// these plain structs cannot fail; an empty object is the fallback.
pub fn to_line<T: Serialize>(message: &T) -> String {
    // Room for a calibrated READING (about 150 to 250 bytes) at once:
    // serde_json's own start of 128 bytes would grow, and copy, for most.
    to_line_in(message, LINE_CAPACITY)
}

/// [`to_line`] into a line with room for `capacity` bytes at once (a
/// STATUS line, some hundreds of bytes a sensor and a source, grows
/// and is copied three or four times from the room of a READING's).
pub fn to_line_in<T: Serialize>(message: &T, capacity: usize) -> String {
    let mut line = Vec::with_capacity(capacity);
    write_line_to(message, &mut line);
    String::from_utf8(line).unwrap_or_else(|_| "{}".to_string())
}

/// [`to_line`] appended to `line`, a buffer used again for each.
pub fn write_line_to<T: Serialize>(message: &T, line: &mut Vec<u8>) {
    let start = line.len();
    if serde_json::to_writer(&mut *line, message).is_err() {
        line.truncate(start);
        line.extend_from_slice(b"{}");
    }
}

/// Bytes reserved for a line before it is written.
const LINE_CAPACITY: usize = 256;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::collection::vec;
    use proptest::option::of;
    use proptest::prelude::*;

    fn number() -> impl Strategy<Value = f64> {
        prop_oneof![any::<f64>(), -1e4..1e4f64, Just(f64::NAN), Just(-0.0)]
    }

    proptest! {
        /// The READING line written directly is the line serde_json
        /// writes for the message, byte for byte, whatever it holds:
        /// names that need escapes, values that are not finite, every
        /// optional field present or not.
        #[test]
        fn a_reading_line_is_the_serialised_message(
            sensor in ".{0,12}",
            time in number(),
            raw in [number(), number()],
            corrected in of([number(), number()]),
            heading_deg in of(number()),
            true_heading_deg in of(number()),
            calibration in of(any::<u64>()),
            calibrated in any::<bool>(),
            trusted in of(any::<bool>()),
            distrust in of(vec(".{0,20}", 0..3)),
            columns in of(vec((".{0,8}", number()), 0..4)),
        ) {
            let (names, values): (Vec<String>, Vec<f64>) =
                columns.clone().unwrap_or_default().into_iter().unzip();
            // One index past the row: left out, as a short row's is.
            let indices: Vec<usize> = (0..=names.len()).collect();
            let message = ReadingMessage {
                class: "READING",
                sensor: &sensor,
                time,
                raw,
                corrected,
                heading_deg,
                true_heading_deg,
                calibration,
                calibrated,
                trusted,
                distrust: distrust.as_deref(),
                columns: columns.as_ref().map(|_| ColumnValues {
                    names: &names,
                    indices: &indices,
                    values: &values,
                }),
            };
            prop_assert_eq!(message.to_line(), to_line(&message));
        }

        /// Each value written directly is serde_json's: any float (every
        /// bit pattern: subnormals, extremes, not finite), and strings
        /// with the characters it escapes.
        #[test]
        fn a_value_is_written_as_serde_json_writes_it(
            bits in any::<u64>(),
            number in number(),
            text in prop_oneof![".{0,12}", "[\\x00-\\x21\"\\\\a-é\\u{7f}\\u{2028}]{0,12}"],
            count in any::<u64>(),
            small in any::<u8>(),
        ) {
            let mut out = String::new();
            for value in [f64::from_bits(bits), number] {
                out.clear();
                value.write_json(&mut out);
                prop_assert_eq!(&out, &serde_json::to_string(&value).unwrap_or_default());
            }
            out.clear();
            text.as_str().write_json(&mut out);
            prop_assert_eq!(&out, &serde_json::to_string(&text).unwrap_or_default());
            out.clear();
            count.write_json(&mut out);
            prop_assert_eq!(&out, &count.to_string());
            out.clear();
            small.write_json(&mut out);
            prop_assert_eq!(&out, &small.to_string());
        }

        /// The same for a 3-axis sensor's READING.
        #[test]
        fn a_3d_reading_line_is_the_serialised_message(
            sensor in ".{0,12}",
            time in number(),
            raw in [number(), number(), number()],
            corrected in of([number(), number(), number()]),
            magnitude in of(number()),
            calibration in of(any::<u64>()),
            calibrated in any::<bool>(),
            heading_deg in of(number()),
            true_heading_deg in of(number()),
            tilt in of((".{0,8}", of(any::<u64>()), any::<bool>(), [number(), number(), number()])),
            heading_omitted in of(".{0,20}"),
            trusted in of(any::<bool>()),
            distrust in of(vec(".{0,20}", 0..3)),
        ) {
            let message = Reading3Message {
                class: "READING",
                sensor: &sensor,
                time,
                axes: 3,
                raw,
                corrected,
                magnitude,
                calibration,
                calibrated,
                heading_deg,
                true_heading_deg,
                tilt: tilt.as_ref().map(|(sensor, calibration, calibrated, [t, p, i])| TiltFields {
                    sensor,
                    calibration: *calibration,
                    calibrated: *calibrated,
                    tilt_deg: *t,
                    pitch_deg: *p,
                    inclination_deg: *i,
                }),
                heading_omitted,
                trusted,
                distrust: distrust.as_deref(),
            };
            prop_assert_eq!(message.to_line(), to_line(&message));
        }
    }
}
