//! A 3-axis sensor of the daemon (`axes = ["x", "y", "z"]`): readings are
//! collected until their directions cover enough of the sphere for the
//! configured 3-D model ([`ellipsoid::supports`]), then fitted
//! ([`ellipsoid::fit`]), checked against ArduPilot's acceptance limits
//! ([`Limits3`]), and from then on every reading carries the corrected x,
//! y, z. A magnetometer may name the accelerometer sensor of its source
//! (`tilt`): its readings then carry the tilt-compensated heading
//! ([`crate::model::tilt::tilt_heading`]).
//!
//! A plain state machine as [`super::sensor::Sensor`] (which holds one of
//! these for a 3-axis section and hands it every call): readings in, lines
//! to publish and calibrations to store out, no I/O, no clock.

use std::time::Instant;

use serde::Serialize;

use super::config::{Axis, Field, SensorConfig};
use super::lifecycle::Lifecycle;
use super::messages::{CalibrationEvent, as_published, to_line};
use super::north::{Earth, MeasuredDip, North, earth};
use super::sensor::{Emitter, Geometry, Sample};
use super::{Calibration, Ellipsoid3Params};
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::model::ellipsoid::{self, Ellipsoid3Fit, Ellipsoid3Se};
use crate::model::paper::PaperCalibration;
use crate::model::sphere::SphereCoverage;
use crate::model::sphere_buffer::SphereBuffer;
use crate::model::tilt::{inclination_deg, robust_spread, tilt_heading_or_why};
use crate::sample::Reading;
use std::sync::Arc;

// The sphere buffer's settings and progress, at the paths they had before
// the buffer moved to [`crate::model::sphere_buffer`].
pub use crate::model::sphere_buffer::{
    CHECK_EVERY, DEFAULT_MAX_SAMPLES, DEFAULT_MIN_SAMPLES, SAMPLES_RANGE, SphereProgress,
    SphereSettings, StillProgress,
};

/// ArduPilot's field radius bounds, milligauss: `FIELD_RADIUS_MIN` 150 and
/// `FIELD_RADIUS_MAX` 950 (CompassCalibrator.cpp, "Earth's magnetic field
/// strength range: 250-850mG").
pub const FIELD_RADIUS_MGAUSS: (f64, f64) = (150.0, 950.0);
/// ArduPilot's largest offset per axis, milligauss: `COMPASS_OFFS_MAX`,
/// default 1800 (AP_Compass.cpp).
pub const MAX_OFFSET_MGAUSS: f64 = 1800.0;
/// ArduPilot's fitness tolerance: the rms residual in milligauss,
/// `COMPASS_CAL_FIT` default 16 (`AP_COMPASS_CALIBRATION_FITNESS_DEFAULT`).
pub const MAX_FITNESS_MGAUSS: f64 = 16.0;
/// ArduPilot's bounds of the soft-iron matrix's diagonal, 0.2 to 5, and of
/// its off-diagonal entries, |·| < 1 (CompassCalibrator::fit_acceptable).
pub const MAG_DIAGONAL: (f64, f64) = (0.2, 5.0);
pub const MAG_MAX_OFF_DIAGONAL: f64 = 1.0;
/// ArduPilot's accelerometer bounds (AccelCalibrator::accept_result): each
/// offset at most 1 g (`GRAVITY_MSS`), each diagonal scale 0.8 to 1.2.
pub const ACCEL_MAX_OFFSET_G: f64 = 1.0;
pub const ACCEL_DIAGONAL: (f64, f64) = (0.8, 1.2);
/// When the sensor's units are not configured, the limits are relative to
/// the fitted radius: offsets at most 5 radii (the 2-D daemon's
/// `max_offset_ratio`, from the same COMPASS_OFFS_MAX beside the Earth's
/// 250-850 mG) and an rms of at most 5 % of the field (the 2-D `max_rms`;
/// ArduPilot's 16 mG is 2-6 % of the Earth's field).
pub const RELATIVE_MAX_OFFSET: f64 = 5.0;
pub const RELATIVE_MAX_RMS: f64 = 0.05;

/// The oldest accelerometer reading a heading is tilt-compensated with,
/// seconds before the magnetometer's reading: 0.1 s. A hand turns a board
/// at up to about 90°/s while calibrating (the sphere is covered in tens
/// of seconds), so in 0.1 s the vertical moves up to some 9°, and the
/// tilt-compensated heading errs by as much (a heading error is of the
/// order of the tilt error times tan(inclination), ≈ 1-2.5 at mid
/// latitudes). Ten periods of the MPU-6050's usual 100 Hz, three of the
/// usb-iss default 30 ms poll: readings of one board sampled together are
/// always well within it. With a staler accelerometer (a gap in its file,
/// a file that has ended) the heading is left out and the reason said
/// (`heading_omitted`) and counted (`headings_stale` in STATUS).
pub const MAX_TILT_AGE_S: f64 = 0.1;

pub use super::config::{Sensor3Config, TiltSource};

/// The unit of a field's calibrated magnitude.
fn unit_of(field: Field) -> &'static str {
    match field {
        Field::Mag => "gauss",
        Field::Accel => "g",
        Field::Gyro => "deg/s",
    }
}

/// Why a 3-D fit is refused: every failed limit, named with its value and
/// its source, joined by "; ". `field` and `lsb_per_unit` give the units.
pub fn check_limits(
    fit: &Ellipsoid3Fit,
    field: Field,
    lsb_per_unit: Option<f64>,
    max_rms: Option<f64>,
) -> Result<(), String> {
    let extra = [fit.r, fit.rms];
    let mut numbers = fit
        .offset
        .iter()
        .chain(fit.matrix.iter().flatten())
        .chain(extra.iter());
    if numbers.any(|v| !v.is_finite()) || !(fit.r > 0.0) {
        return Err("the fit produced a non-finite or non-positive parameter".into());
    }
    let mut failures = Vec::new();
    let w = &fit.matrix;
    let diagonal = [w[0][0], w[1][1], w[2][2]];
    let off_diagonal = [w[0][1], w[0][2], w[1][2]];
    match (field, lsb_per_unit) {
        (Field::Mag, Some(u)) => {
            let to_mg = |counts: f64| counts / u * 1000.0;
            let r_mg = to_mg(fit.r);
            let (lo, hi) = FIELD_RADIUS_MGAUSS;
            if !(r_mg > lo && r_mg < hi) {
                failures.push(format!(
                    "field radius {r_mg:.0} mG is outside ArduPilot's {lo:.0}-{hi:.0} mG (FIELD_RADIUS_MIN/MAX; {:.1} counts at lsb_per_gauss {u})",
                    fit.r
                ));
            }
            for (axis, o) in ["x", "y", "z"].iter().zip(fit.offset) {
                if to_mg(o).abs() >= MAX_OFFSET_MGAUSS {
                    failures.push(format!(
                        "offset {axis} {:.0} mG exceeds ArduPilot's {MAX_OFFSET_MGAUSS:.0} mG (COMPASS_OFFS_MAX)",
                        to_mg(o)
                    ));
                }
            }
            let fitness = to_mg(fit.rms * fit.r);
            let limit_mg = max_rms.map_or(MAX_FITNESS_MGAUSS, |f| to_mg(f * fit.r));
            if fitness > limit_mg {
                failures.push(format!(
                    "rms {fitness:.1} mG ({:.2} % of the field) exceeds {limit_mg:.1} mG ({})",
                    fit.rms * 100.0,
                    if max_rms.is_some() {
                        "sphere.max_rms"
                    } else {
                        "ArduPilot's COMPASS_CAL_FIT"
                    }
                ));
            }
        }
        (Field::Accel, Some(u)) => {
            for (axis, o) in ["x", "y", "z"].iter().zip(fit.offset) {
                if (o / u).abs() > ACCEL_MAX_OFFSET_G {
                    failures.push(format!(
                        "offset {axis} {:.3} g exceeds ArduPilot's {ACCEL_MAX_OFFSET_G} g (AccelCalibrator)",
                        o / u
                    ));
                }
            }
            let (lo, hi) = ACCEL_DIAGONAL;
            let g = fit.r / u;
            if !(lo..=hi).contains(&g) {
                failures.push(format!(
                    "gravity reads {g:.3} g at lsb_per_g {u}: the overall scale is outside ArduPilot's {lo}-{hi} (AccelCalibrator)"
                ));
            }
        }
        _ => {
            for (axis, o) in ["x", "y", "z"].iter().zip(fit.offset) {
                if o.abs() > RELATIVE_MAX_OFFSET * fit.r {
                    failures.push(format!(
                        "offset {axis} {o:.1} counts is more than {RELATIVE_MAX_OFFSET} field radii ({:.1} counts)",
                        fit.r
                    ));
                }
            }
        }
    }
    if !(field == Field::Mag && lsb_per_unit.is_some()) {
        let limit = max_rms.unwrap_or(RELATIVE_MAX_RMS);
        if fit.rms > limit {
            failures.push(format!(
                "rms {:.2} % of the field exceeds {:.2} % ({})",
                fit.rms * 100.0,
                limit * 100.0,
                if max_rms.is_some() {
                    "sphere.max_rms"
                } else {
                    "the default"
                }
            ));
        }
    }
    let (lo, hi, off) = match field {
        Field::Accel => (ACCEL_DIAGONAL.0, ACCEL_DIAGONAL.1, MAG_MAX_OFF_DIAGONAL),
        _ => (MAG_DIAGONAL.0, MAG_DIAGONAL.1, MAG_MAX_OFF_DIAGONAL),
    };
    for (axis, d) in ["xx", "yy", "zz"].iter().zip(diagonal) {
        if !(d > lo && d < hi) {
            failures.push(format!(
                "matrix {axis} {d:.3} is outside ArduPilot's {lo}-{hi} (diagonal bound)"
            ));
        }
    }
    for (axis, d) in ["xy", "xz", "yz"].iter().zip(off_diagonal) {
        if d.abs() >= off {
            failures.push(format!(
                "matrix {axis} {d:.3} is beyond ArduPilot's ±{off} (off-diagonal bound)"
            ));
        }
    }
    if failures.is_empty() {
        Ok(())
    } else {
        Err(failures.join("; "))
    }
}

#[derive(Serialize)]
struct TiltFields<'a> {
    /// The accelerometer sensor.
    sensor: &'a str,
    /// Its calibration that corrected the accelerometer, or none: the
    /// accelerometer's raw readings were used.
    calibration: Option<u64>,
    calibrated: bool,
    tilt_deg: f64,
    pitch_deg: f64,
    inclination_deg: f64,
}

#[derive(Serialize)]
struct Reading3Message<'a> {
    class: &'static str,
    sensor: &'a str,
    time: f64,
    axes: u8,
    raw: [f64; 3],
    #[serde(skip_serializing_if = "Option::is_none")]
    corrected: Option<[f64; 3]>,
    /// |corrected|: the field's magnitude, ≈ r.
    #[serde(skip_serializing_if = "Option::is_none")]
    magnitude: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    calibration: Option<u64>,
    calibrated: bool,
    /// Tilt-compensated, clockwise from magnetic north to the sensor's +x.
    #[serde(skip_serializing_if = "Option::is_none")]
    heading_deg: Option<f64>,
    /// `heading_deg` from true north, when the sensor has a declination.
    #[serde(skip_serializing_if = "Option::is_none")]
    true_heading_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    tilt: Option<TiltFields<'a>>,
    /// Why a calibrated magnetometer with a tilt source has no heading.
    #[serde(skip_serializing_if = "Option::is_none")]
    heading_omitted: Option<String>,
}

#[derive(Serialize)]
struct Calibration3Message<'a> {
    class: &'static str,
    sensor: &'a str,
    accepted: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    id: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    reason: Option<String>,
    axes: u8,
    model: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    offset: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    matrix: Option<[[f64; 3]; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    r: Option<f64>,
    /// r in gauss or g, when the units are configured.
    #[serde(skip_serializing_if = "Option::is_none")]
    r_units: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    units: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    se: Option<Ellipsoid3Se>,
    #[serde(skip_serializing_if = "Option::is_none")]
    rms: Option<f64>,
    n: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    coverage: Option<SphereCoverage>,
    fit_ms: f64,
    time: f64,
    origin: &'static str,
    /// The declination, its source and 1σ (as a 2-axis CALIBRATION's).
    #[serde(skip_serializing_if = "Option::is_none")]
    declination_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    declination_source: Option<&'a str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    declination_uncertainty_deg: Option<f64>,
    /// The fitted field beside the World Magnetic Model's (a location).
    #[serde(skip_serializing_if = "Option::is_none")]
    earth: Option<Earth>,
    /// With `still`: the poses the fit was made on.
    #[serde(skip_serializing_if = "Option::is_none")]
    poses: Option<usize>,
}

impl Calibration3Message<'_> {
    /// The outcome this message publishes, for the progress board (a
    /// sphere has no headings covered, no heading check, no suggestion).
    fn event(&self) -> CalibrationEvent {
        CalibrationEvent {
            sensor: self.sensor.to_string(),
            accepted: self.accepted,
            id: self.id,
            reason: self.reason.clone(),
            rms: self.rms.and_then(as_published),
            coverage_deg: 0.0,
            n: self.n,
            stored: self.origin == "state",
            suggested: None,
            heading_rms_deg: None,
            heading_check: None,
            poses: self.poses,
            axes: self.axes,
        }
    }
}

/// The sphere geometry of a 3-axis sensor: its buffer, its tilt source and
/// its true north. Its state, calibration and counts are the
/// [`Lifecycle`] its [`super::sensor::Sensor`] lends it.
pub struct Sensor3 {
    name: String,
    stream: u8,
    field: Field,
    config: Sensor3Config,
    /// The samples collected, their coverage and (with `still`) poses.
    buffer: SphereBuffer,
    /// The tilt source's current calibration, as [`Sensor3::set_tilt`] gave it.
    tilt_calibration: Option<Calibration>,
    /// The tilt source's last raw reading, with its time.
    last_accel: Option<(f64, [f64; 3])>,
    /// True north (`declination_deg` or a location).
    north: Option<North>,
    /// Readings whose heading was left out for a stale accelerometer.
    headings_stale: u64,
    /// A sensor of a csv source: where its values (and its tilt source's)
    /// are in the rows, resolved by [`Sensor3::bind_csv`].
    csv: Option<Csv3Binding>,
}

/// Where a 3-axis csv sensor's values are: (file, column indices of x, y,
/// z) of its own and of its tilt source.
#[derive(Debug, Clone)]
struct Csv3Binding {
    own: (usize, [usize; 3]),
    tilt: Option<(usize, [usize; 3])>,
}

fn pick(triad: [i16; 3], axes: [Axis; 3]) -> [f64; 3] {
    axes.map(|a| f64::from(triad[a.index()]))
}

fn field_of(reading: &Reading, field: Field) -> Option<[i16; 3]> {
    match field {
        Field::Mag => reading.mag,
        Field::Accel => reading.accel,
        Field::Gyro => reading.gyro,
    }
}

/// W·(raw − o) of a stored 3-D calibration.
pub fn apply3(p: &Ellipsoid3Params, raw: [f64; 3]) -> [f64; 3] {
    p.correct(raw)
}

impl Sensor3 {
    /// The sphere of a 3-axis sensor of `config` (whose `three` is set).
    pub fn new(config: &SensorConfig, three: Sensor3Config) -> Self {
        Sensor3 {
            name: config.name.clone(),
            stream: config.stream,
            field: config.field,
            buffer: SphereBuffer::new(three.model, three.sphere.clone(), three.lsb_per_unit),
            tilt_calibration: None,
            last_accel: None,
            north: config.north.clone(),
            headings_stale: 0,
            csv: None,
            config: three,
        }
    }

    /// The samples held while collecting.
    pub fn points(&self) -> &[[f64; 3]] {
        self.buffer.points()
    }

    /// The name of the accelerometer sensor this one takes its tilt from.
    pub fn tilt_sensor(&self) -> Option<&str> {
        self.config.tilt.as_ref().map(|t| t.sensor.as_str())
    }

    /// The tilt source's current calibration (a 3-D one, or none).
    pub fn set_tilt(&mut self, calibration: Option<&Calibration>) {
        self.tilt_calibration = calibration.filter(|c| c.ellipsoid.is_some()).cloned();
    }

    /// Takes over what the same sensor earned under the settings before a
    /// reload beyond its [`Lifecycle`]: its tilt source's calibration and
    /// the count of stale headings.
    pub fn carry_over(&mut self, old: &Sensor3) {
        self.tilt_calibration = old.tilt_calibration.clone();
        self.headings_stale = old.headings_stale;
        self.recalibrate();
    }

    /// Starts a new buffer (the [`Lifecycle`] restarts beside it).
    pub fn recalibrate(&mut self) {
        self.buffer.reset();
    }

    /// Progress of the buffer being collected.
    pub fn progress(&self) -> SphereProgress {
        self.buffer.progress()
    }

    /// Readings whose tilt-compensated heading was left out because the
    /// accelerometer's latest reading was older than [`MAX_TILT_AGE_S`].
    pub fn headings_stale(&self) -> u64 {
        self.headings_stale
    }

    fn fit(
        &mut self,
        life: &mut Lifecycle,
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let started = Instant::now();
        let fitted = ellipsoid::fit(self.buffer.points(), self.config.model);
        let fit_ms = started.elapsed().as_secs_f64() * 1e3;
        let fit = match fitted {
            Ok(fit) => fit,
            Err(e @ ellipsoid::Ellipsoid3Error::NotCovered { .. }) => {
                // The estimate's directions looked complete, the fit's did
                // not: collect on, and try again a quarter (at least
                // min_samples / 4) further on.
                tracing::info!(sensor = %self.name, "not yet: {e}");
                self.buffer.not_yet();
                return None;
            }
            Err(e) => {
                self.reject(life, (time, fit_ms), format!("no fit: {e}"), None, emit);
                return None;
            }
        };
        let max_rms = self.config.sphere.max_rms;
        if let Err(reason) = check_limits(&fit, self.field, self.config.lsb_per_unit, max_rms) {
            self.reject(life, (time, fit_ms), reason, Some(&fit), emit);
            return None;
        }
        let calibration = Calibration {
            sensor: self.name.clone(),
            id: life.next_id,
            model: fit.model.name().to_string(),
            // The 2-D parameters of a 3-D calibration: the identity, r.
            params: PaperCalibration {
                a: 1.0,
                b: 0.0,
                d: 0.0,
                r: fit.r,
            },
            rms: fit.rms,
            coverage_deg: 0.0,
            n: fit.n,
            time,
            terms: Default::default(),
            ellipsoid: Some(Ellipsoid3Params {
                offset: fit.offset,
                matrix: fit.matrix,
                r: fit.r,
                coverage: fit.coverage.fraction,
            }),
        };
        let earth = self.earth_of(&fit);
        if let Some(e) = &earth {
            tracing::info!(sensor = %self.name, "against the World Magnetic Model: {}", e.verdict);
        }
        let message = self.message(&calibration, Some(&fit), fit_ms, "sphere", earth);
        emit.calibration(|| Some(message.event()), to_line(&message));
        tracing::info!(
            sensor = %self.name,
            id = calibration.id,
            rms = calibration.rms,
            "3-D calibration accepted ({}, {} samples, {:.0} % of the sphere)",
            fit.model,
            fit.n,
            fit.coverage.fraction * 100.0
        );
        life.accept(calibration.clone());
        self.buffer.accepted();
        Some(calibration)
    }

    fn message<'a>(
        &'a self,
        c: &'a Calibration,
        fit: Option<&Ellipsoid3Fit>,
        fit_ms: f64,
        origin: &'static str,
        earth: Option<Earth>,
    ) -> Calibration3Message<'a> {
        let p = c.ellipsoid.as_ref();
        Calibration3Message {
            class: "CALIBRATION",
            sensor: &self.name,
            accepted: true,
            id: Some(c.id),
            reason: None,
            axes: 3,
            model: &c.model,
            offset: p.map(|p| p.offset),
            matrix: p.map(|p| p.matrix),
            r: p.map(|p| p.r),
            r_units: p.and_then(|p| self.config.lsb_per_unit.map(|u| p.r / u)),
            units: self.config.lsb_per_unit.map(|_| unit_of(self.field)),
            se: fit.map(|f| f.se),
            rms: Some(c.rms),
            n: c.n,
            coverage: fit.map(|f| f.coverage.clone()),
            fit_ms,
            time: c.time,
            origin,
            declination_deg: self.north.as_ref().map(|n| n.declination_deg),
            declination_source: self.north.as_ref().map(|n| n.source.as_str()),
            declination_uncertainty_deg: self.north.as_ref().and_then(North::uncertainty_deg),
            earth,
            poses: self.buffer.still_poses().filter(|_| origin == "sphere"),
        }
    }

    /// The fitted field beside the World Magnetic Model's, when the sensor
    /// is a magnetometer with a location.
    fn earth_of(&self, fit: &Ellipsoid3Fit) -> Option<Earth> {
        let north = self.north.as_ref().filter(|_| self.field == Field::Mag)?;
        let params = Ellipsoid3Params {
            offset: fit.offset,
            matrix: fit.matrix,
            r: fit.r,
            coverage: fit.coverage.fraction,
        };
        earth(
            north,
            fit.r,
            self.config.lsb_per_unit,
            self.measured_inclination(&params),
        )
    }

    /// The inclination over the samples held, each corrected by `params`
    /// with the tilt accelerometer's reading beside it (corrected by its
    /// calibration, when it has one): median and robust spread, as
    /// `fieldcal heading` measures it.
    fn measured_inclination(&self, params: &Ellipsoid3Params) -> Result<MeasuredDip, String> {
        if self.config.tilt.is_none() {
            return Err(
                "the sensor has no tilt accelerometer (tilt = the 3-axis accelerometer \
                        sensor of its source)"
                    .into(),
            );
        }
        let accel_cal = self
            .tilt_calibration
            .as_ref()
            .and_then(|c| c.ellipsoid.as_ref());
        let values: Vec<f64> = self
            .buffer
            .points()
            .iter()
            .zip(self.buffer.accel_at())
            .filter_map(|(raw, accel)| {
                let accel = (*accel)?;
                let accel = match accel_cal {
                    Some(p) => apply3(p, accel),
                    None => accel,
                };
                inclination_deg(apply3(params, *raw), accel)
            })
            .collect();
        robust_spread(&values)
            .map(|spread| MeasuredDip {
                spread,
                accelerometer_calibrated: accel_cal.is_some(),
            })
            .ok_or_else(|| "no fitted sample had a tilt accelerometer reading beside it".into())
    }

    /// The sphere's samples refused for `reason` (with the fit, when there
    /// was one): published, counted, and collected anew.
    fn reject(
        &mut self,
        life: &mut Lifecycle,
        (time, fit_ms): (f64, f64),
        reason: String,
        fit: Option<&Ellipsoid3Fit>,
        emit: &mut Emitter<'_>,
    ) {
        let n = self.buffer.points().len();
        let message = Calibration3Message {
            class: "CALIBRATION",
            sensor: &self.name,
            accepted: false,
            id: None,
            reason: Some(reason.clone()),
            axes: 3,
            model: self.config.model.name(),
            offset: fit.map(|f| f.offset),
            matrix: fit.map(|f| f.matrix),
            r: fit.map(|f| f.r),
            r_units: fit.and_then(|f| self.config.lsb_per_unit.map(|u| f.r / u)),
            units: self.config.lsb_per_unit.map(|_| unit_of(self.field)),
            se: fit.map(|f| f.se),
            rms: fit.map(|f| f.rms),
            n,
            coverage: fit.map(|f| f.coverage.clone()),
            fit_ms,
            time,
            origin: "sphere",
            declination_deg: self.north.as_ref().map(|n| n.declination_deg),
            declination_source: self.north.as_ref().map(|n| n.source.as_str()),
            declination_uncertainty_deg: self.north.as_ref().and_then(North::uncertainty_deg),
            earth: fit.and_then(|f| self.earth_of(f)),
            poses: self.buffer.still_poses(),
        };
        emit.calibration(|| Some(message.event()), to_line(&message));
        tracing::warn!(sensor = %self.name, "3-D calibration rejected: {reason}");
        life.reject(reason);
        // Collect anew; the previous calibration (if any) keeps correcting.
        self.buffer.rejected();
    }
}

impl Geometry for Sensor3 {
    fn reading_line(&mut self, life: &Lifecycle, sample: Sample, _row: Option<&CsvRow>) -> String {
        let Sample { time, raw } = sample;
        let corrected = life
            .current
            .as_ref()
            .and_then(|c| Some((c.id, apply3(c.ellipsoid.as_ref()?, raw))));
        let mut heading_omitted = None;
        let accel = match (&self.config.tilt, corrected, self.last_accel) {
            (Some(source), Some(_), None) => {
                heading_omitted = Some(format!(
                    "no reading of the tilt source '{}' yet",
                    source.sensor
                ));
                None
            }
            (Some(source), Some(_), Some((t, _))) if time - t > MAX_TILT_AGE_S => {
                self.headings_stale += 1;
                heading_omitted = Some(format!(
                    "the latest reading of the tilt source '{}' is {:.3} s old, more than \
                     {MAX_TILT_AGE_S} s: its tilt is stale",
                    source.sensor,
                    time - t
                ));
                None
            }
            (_, _, last) => last.map(|(_, a)| a),
        };
        let tilt = match (&self.config.tilt, corrected, accel) {
            (Some(source), Some((_, mag)), Some(accel_raw)) => {
                let cal = self.tilt_calibration.as_ref();
                let accel = match cal.and_then(|c| c.ellipsoid.as_ref()) {
                    Some(p) => apply3(p, accel_raw),
                    None => accel_raw,
                };
                match tilt_heading_or_why(mag, accel, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]) {
                    Ok(h) => Some((
                        h.heading_deg,
                        TiltFields {
                            sensor: &source.sensor,
                            calibration: cal.map(|c| c.id),
                            calibrated: cal.is_some(),
                            tilt_deg: h.tilt_deg,
                            pitch_deg: h.pitch_deg,
                            inclination_deg: h.inclination_deg,
                        },
                    )),
                    Err(why) => {
                        heading_omitted = Some(why.to_string());
                        None
                    }
                }
            }
            _ => None,
        };
        let (heading_deg, tilt) = match tilt {
            Some((h, t)) => (Some(h), Some(t)),
            None => (None, None),
        };
        let true_heading_deg = heading_deg
            .zip(self.north.as_ref())
            .map(|(h, n)| n.true_heading(h));
        to_line(&Reading3Message {
            class: "READING",
            sensor: &self.name,
            time,
            axes: 3,
            raw,
            corrected: corrected.map(|c| c.1),
            magnitude: corrected.map(|(_, c)| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()),
            calibration: corrected.map(|c| c.0),
            calibrated: corrected.is_some(),
            heading_deg,
            true_heading_deg,
            tilt,
            heading_omitted,
        })
    }
    fn push(
        &mut self,
        life: &mut Lifecycle,
        sample: Sample,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let Sample { time, raw } = sample;
        if !life.collecting() || raw.iter().any(|v| !v.is_finite()) {
            return None;
        }
        // The accelerometer beside this sample, unless it is stale.
        let accel = self.config.tilt.is_some().then(|| {
            self.last_accel
                .filter(|(t, _)| (time - t).abs() <= MAX_TILT_AGE_S)
                .map(|(_, a)| a)
        });
        if !self.buffer.push(time, raw, accel) {
            return None;
        }
        let fitted = self.fit(life, time, emit);
        self.buffer.after_fit();
        fitted
    }
    fn wants(&self, stream: u8) -> bool {
        self.stream == stream
            || self
                .config
                .tilt
                .as_ref()
                .is_some_and(|t| t.stream == stream)
    }
    fn set_north(&mut self, north: Option<North>) {
        self.north = north;
    }
    fn bind_csv(
        &mut self,
        layouts: &[Arc<CsvLayout>],
        files: &[std::path::PathBuf],
    ) -> Result<Vec<(usize, usize)>, CsvError> {
        let Some(columns) = &self.config.columns else {
            return Ok(Vec::new());
        };
        let layouts: Vec<&CsvLayout> = layouts.iter().map(Arc::as_ref).collect();
        let own = locate3(files, &layouts, columns, OWN_ROLES)?;
        let tilt = match self.config.tilt.as_ref().and_then(|t| t.columns.as_ref()) {
            None => None,
            Some(columns) => Some(locate3(files, &layouts, columns, TILT_ROLES)?),
        };
        let required = [Some(own), tilt]
            .into_iter()
            .flatten()
            .flat_map(|(file, at)| at.map(|i| (file, i)))
            .collect();
        self.csv = Some(Csv3Binding { own, tilt });
        Ok(required)
    }
    fn row_sample(&mut self, _life: &Lifecycle, row: &CsvRow) -> Option<Sample> {
        let binding = self.csv.as_ref()?;
        let values = |at: [usize; 3]| -> Option<[f64; 3]> {
            let v = [
                *row.values.get(at[0])?,
                *row.values.get(at[1])?,
                *row.values.get(at[2])?,
            ];
            v.iter().all(|x| x.is_finite()).then_some(v)
        };
        if let Some((file, at)) = binding.tilt
            && row.file == file
            && let Some(accel) = values(at)
        {
            self.last_accel = Some((row.time, accel));
        }
        let (file, at) = binding.own;
        if row.file != file {
            return None;
        }
        Some(Sample {
            time: row.time,
            raw: values(at)?,
        })
    }
    fn reading_sample(&mut self, _life: &Lifecycle, reading: &Reading) -> Option<Sample> {
        if let Some(tilt) = &self.config.tilt
            && reading.stream == tilt.stream
            && let Some(triad) = reading.accel
        {
            self.last_accel = Some((reading.time, pick(triad, tilt.axes)));
        }
        if reading.stream != self.stream {
            return None;
        }
        Some(Sample {
            time: reading.time,
            raw: pick(field_of(reading, self.field)?, self.config.axes),
        })
    }
    fn loaded_line(&self, life: &Lifecycle) -> Option<(String, Option<CalibrationEvent>)> {
        let c = life.current.as_ref()?;
        let earth = match (&self.north, &c.ellipsoid) {
            (Some(north), Some(p)) if self.field == Field::Mag => earth(
                north,
                p.r,
                self.config.lsb_per_unit,
                Err(if self.config.tilt.is_some() {
                    "it is measured over a fit's samples, and a calibration loaded from the \
                     state directory has none"
                        .into()
                } else {
                    "the sensor has no tilt accelerometer".into()
                }),
            ),
            _ => None,
        };
        let message = self.message(c, None, 0.0, "state", earth);
        Some((to_line(&message), Some(message.event())))
    }
    fn restart(&mut self) {
        self.recalibrate();
    }
    fn sphere(&self, collecting: bool) -> (Option<SphereProgress>, Option<u64>) {
        (
            collecting.then(|| self.progress()),
            self.tilt_sensor().is_some().then(|| self.headings_stale()),
        )
    }
    fn as_sphere(&self) -> Option<&Sensor3> {
        Some(self)
    }
    fn as_sphere_mut(&mut self) -> Option<&mut Sensor3> {
        Some(self)
    }
}

const OWN_ROLES: [&str; 3] = [
    "the sensor's x axis",
    "the sensor's y axis",
    "the sensor's z axis",
];
const TILT_ROLES: [&str; 3] = [
    "the tilt source's x axis",
    "the tilt source's y axis",
    "the tilt source's z axis",
];

/// Finds the three columns named in `columns` (x, y, z, with their `roles`
/// for messages) among the files' headers: the file and the three indices.
fn locate3(
    files: &[std::path::PathBuf],
    layouts: &[&CsvLayout],
    columns: &[String],
    roles: [&'static str; 3],
) -> Result<(usize, [usize; 3]), CsvError> {
    let names: Vec<(&str, &'static str)> = columns
        .iter()
        .zip(roles)
        .map(|(c, r)| (c.as_str(), r))
        .collect();
    let (file, at) = crate::source::csv::locate_columns(files, layouts, &names)?;
    Ok((file, [at[0], at[1], at[2]]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::config::parse;
    use crate::daemon::messages::SensorState;
    use crate::daemon::reload::{RunningSource, apply};
    use crate::daemon::sensor::Sensor;
    use crate::sim3::{ImuMotion, Motion3, SimAxes3, SimImu3, SimSensor3};

    const TEXT: &str = "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
        [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"level\"\n\
        [[sensor]]\nname = \"level\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n";

    const SOURCES: [RunningSource<'static>; 1] = [RunningSource {
        name: "imu",
        csv: None,
    }];

    fn config(text: &str) -> crate::daemon::config::Config {
        parse(text, std::path::Path::new("t.toml")).unwrap()
    }

    /// The shipped capture's IMU (tests/data/README.md), as readings.
    fn tumble() -> Vec<Reading> {
        let imu = SimImu3 {
            field: 1000.0,
            inclination_deg: 60.0,
            gravity: 4096.0,
            mag: SimAxes3 {
                matrix: [[1.08, 0.04, -0.02], [0.04, 0.95, 0.03], [-0.02, 0.03, 1.0]],
                offset: [150.0, -80.0, 60.0],
                noise: 3.0,
            },
            accel: SimAxes3 {
                matrix: [[1.01, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.0]],
                offset: [40.0, -25.0, 60.0],
                noise: 8.0,
            },
            gyro_noise: 0.0,
            period: 0.05,
            n: 2880,
            motion: ImuMotion::Tumble {
                turns: 24.0,
                axis_path_rad: 12.0,
            },
            seed: 7,
        };
        let round = |v: [f64; 3]| v.map(|x| x.round() as i16);
        imu.simulate()
            .unwrap()
            .into_iter()
            .map(|s| Reading {
                time: s.t,
                mag: Some(round(s.mag)),
                accel: Some(round(s.accel)),
                ..Reading::default()
            })
            .collect()
    }

    fn feed(sensors: &mut [(usize, Sensor)], readings: &[Reading]) -> Vec<String> {
        let mut lines = Vec::new();
        for r in readings {
            for (_, s) in sensors.iter_mut() {
                if s.wants(r.stream) {
                    s.on_reading(r, &mut |_, l| lines.push(l));
                }
            }
            // As the daemon's Sensors::link_tilts does on an acceptance.
            let level = sensors[1].1.calibration().cloned();
            if let Some(three) = sensors[0].1.three_mut() {
                three.set_tilt(level.as_ref());
            }
        }
        lines
    }

    #[test]
    fn a_reload_keeps_an_unchanged_3_axis_sensor_and_carries_a_changed_ones_calibration() {
        let mut running = config(TEXT);
        let mut sensors: Vec<(usize, Sensor)> = running
            .sensors
            .iter()
            .map(|s| (0, Sensor::new(s.clone(), None)))
            .collect();
        let readings = tumble();
        let lines = feed(&mut sensors, &readings);
        assert_eq!(
            lines
                .iter()
                .filter(|l| l.contains("\"CALIBRATION\"") && l.contains("\"accepted\":true"))
                .count(),
            2
        );
        assert!(lines.iter().any(|l| l.contains("\"heading_deg\"")));
        sensors[0].1.recalibrate();
        feed(&mut sensors, &readings[..100]);
        let sphere = |s: &Sensor| s.status().sphere.map(|p| p.samples);
        assert_eq!(sphere(&sensors[0].1), Some(100));

        // The same file: both sensors as they were.
        let out = apply(Ok(config(TEXT)), &mut running, &mut sensors, &SOURCES, None);
        assert!(out.lines[0].contains("no change"), "{:?}", out.lines);
        assert_eq!(sphere(&sensors[0].1), Some(100));
        assert_eq!(sensors[0].1.status().state, SensorState::Recalibrating);
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        assert_eq!(sensors[1].1.calibration().map(|c| c.id), Some(1));

        // compass's model changes: it keeps correcting with #1, collects
        // afresh, and its next calibration is #2.
        let new = TEXT.replace(
            "tilt = \"level\"\n",
            "tilt = \"level\"\nmodel = \"offset+scale\"\n",
        );
        let out = apply(Ok(config(&new)), &mut running, &mut sensors, &SOURCES, None);
        assert!(
            out.lines.iter().any(|l| l.contains("compass")),
            "{:?}",
            out.lines
        );
        assert_eq!(sphere(&sensors[0].1), Some(0));
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        assert_eq!(sensors[1].1.calibration().map(|c| c.id), Some(1));
        let lines = feed(&mut sensors, &readings);
        let accepted: Vec<&String> = lines
            .iter()
            .filter(|l| l.contains("\"CALIBRATION\"") && l.contains("\"sensor\":\"compass\""))
            .collect();
        assert!(
            accepted[0].contains("\"id\":2") && accepted[0].contains("\"model\":\"offset+scale\"")
        );

        // Back to two axes: a 2-axis sensor never corrects with a 3-D
        // calibration; it collects a rotation.
        let two = new.replace(
            "axes = [\"x\", \"y\", \"z\"]\ntilt = \"level\"\nmodel = \"offset+scale\"\n",
            "axes = [\"x\", \"y\"]\n",
        );
        apply(Ok(config(&two)), &mut running, &mut sensors, &SOURCES, None);
        assert!(sensors[0].1.three().is_none());
        assert!(sensors[0].1.calibration().is_none());
        assert!(sensors[0].1.status().rotation.is_some());
    }

    /// ArduPilot's limits in its units: an offset beyond COMPASS_OFFS_MAX
    /// (1800 mG) or a field outside 150-950 mG is refused, naming it.
    #[test]
    fn the_limits_are_ardupilots_in_milligauss() {
        let fit_of = |offset: [f64; 3], r: f64| {
            let sim = SimSensor3 {
                matrix: [[1.05, 0.02, 0.0], [0.02, 0.97, 0.0], [0.0, 0.0, 1.0]],
                offset,
                r,
                noise: 1.0,
                n: 1500,
                motion: Motion3::Tumble {
                    turns: 12.0,
                    axis_path_rad: 6.0,
                },
                seed: 5,
            };
            ellipsoid::fit(&sim.simulate().unwrap(), ellipsoid::Ellipsoid3Model::Full).unwrap()
        };
        // 2000 counts per gauss: 1000 counts = 500 mG.
        let good = fit_of([1000.0, -500.0, 200.0], 1000.0);
        assert_eq!(check_limits(&good, Field::Mag, Some(2000.0), None), Ok(()));
        let far = fit_of([3700.0, 0.0, 0.0], 1000.0);
        let e = check_limits(&far, Field::Mag, Some(2000.0), None).unwrap_err();
        assert!(
            e.contains("offset x 18") && e.contains("COMPASS_OFFS_MAX"),
            "{e}"
        );
        // Without units the offset is judged against the field: 3.7 r is fine.
        assert_eq!(check_limits(&far, Field::Mag, None, None), Ok(()));
        let strong = fit_of([0.0; 3], 2000.0);
        let e = check_limits(&strong, Field::Mag, Some(2000.0), None).unwrap_err();
        assert!(e.contains("FIELD_RADIUS"), "{e}");
        // The fitness: 1 count of noise on 1000 is 0.5 mG; a tighter max_rms
        // than the fit's rms refuses it.
        let e = check_limits(&good, Field::Mag, Some(2000.0), Some(good.rms / 2.0)).unwrap_err();
        assert!(e.contains("sphere.max_rms"), "{e}");
        // An accelerometer: gravity must read 0.8-1.2 g.
        let e = check_limits(&good, Field::Accel, Some(4096.0), None).unwrap_err();
        assert!(e.contains("gravity reads 0.24"), "{e}");
    }

    /// A sensor that never moves fills no more than max_samples, however
    /// long it collects.
    #[test]
    fn the_buffer_stays_bounded() {
        let text = "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
            [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\n\
            [sensor.sphere]\nmin_samples = 100\nmax_samples = 400\n";
        let c = config(text);
        let mut sensor = Sensor::new(c.sensors[0].clone(), None);
        let readings = tumble();
        for i in 0..20_000usize {
            // A still sensor, then the first 500 samples of the tumble.
            let r = if i < 19_500 {
                Reading {
                    time: i as f64 * 0.05,
                    mag: Some([500 + (i % 7) as i16, -300, 200]),
                    ..Reading::default()
                }
            } else {
                Reading {
                    time: i as f64 * 0.05,
                    ..readings[i - 19_500]
                }
            };
            sensor.on_reading(&r, &mut |_, _| {});
            let held = sensor.three().unwrap().points().len();
            assert!(held <= 400, "{held} at {i}");
        }
    }

    /// The real tumble of sunsided-set-1 (HMC5883L in gauss = counts/1090,
    /// MPU-6050 in g = counts/16384 at ±2 g, one clock), as the chips'
    /// counts on two streams of one bridge: the compass calibrates with
    /// the field within the Earth's 250-650 mG; the accelerometer, moved by
    /// hand, reads the hand's acceleration besides gravity and is refused
    /// for its rms (a still-pose calibration is what ArduPilot asks of an
    /// accelerometer), so the headings use its raw readings and say so.
    #[test]
    fn the_real_tilt_sphere_calibrates_the_compass_and_refuses_a_moving_accelerometer() {
        let dir = std::path::Path::new("../shared/data/real/sunsided-set-1/tilt-sphere");
        let read = |name: &str, scale: f64| -> Vec<(f64, [i16; 3])> {
            let text = std::fs::read_to_string(dir.join(name)).unwrap();
            text.lines()
                .skip(1)
                .map(|l| {
                    let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
                    (v[0], [1, 2, 3].map(|i| (v[i] * scale).round() as i16))
                })
                .collect()
        };
        let mut readings: Vec<Reading> = read("hmc5883l_mag.csv", 1090.0)
            .into_iter()
            .map(|(t, m)| Reading {
                time: t,
                stream: 0,
                mag: Some(m),
                ..Reading::default()
            })
            .chain(
                read("mpu6050.csv", 16384.0)
                    .into_iter()
                    .map(|(t, a)| Reading {
                        time: t,
                        stream: 1,
                        accel: Some(a),
                        ..Reading::default()
                    }),
            )
            .collect();
        readings.sort_by(|a, b| a.time.total_cmp(&b.time));
        let text = "[[source]]\nname = \"imu\"\nkind = \"usb-iss\"\nport = \"/dev/null\"\nchips = [\"lsm303dlhc-mag\", \"mpu6050\"]\n\
            [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\nlsb_per_gauss = 1090\ntilt = \"level\"\n\
            [[sensor]]\nname = \"level\"\nsource = \"imu\"\nchip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\nlsb_per_g = 16384\n";
        let c = config(text);
        let mut sensors: Vec<(usize, Sensor)> = c
            .sensors
            .iter()
            .map(|s| (0, Sensor::new(s.clone(), None)))
            .collect();
        let lines = feed(&mut sensors, &readings);
        for l in lines.iter().filter(|l| l.contains("\"CALIBRATION\"")) {
            println!("{l}");
        }
        let compass = sensors[0].1.calibration().expect("the compass calibrates");
        let gauss = compass.ellipsoid.unwrap().r / 1090.0;
        assert!((0.25..0.65).contains(&gauss), "field {gauss} G");
        assert!(sensors[1].1.calibration().is_none());
        let refusals: Vec<&String> = lines
            .iter()
            .filter(|l| l.contains("\"sensor\":\"level\"") && l.contains("\"accepted\":false"))
            .collect();
        assert!(!refusals.is_empty());
        assert!(
            refusals
                .iter()
                .all(|l| l.contains("% of the field exceeds")),
            "{refusals:?}"
        );
        let headings = lines
            .iter()
            .filter(|l| {
                l.contains("\"heading_deg\"") && l.contains("\"calibrated\":false,\"tilt_deg\"")
            })
            .count();
        println!(
            "compass rms {:.3} %, {headings} headings from the raw accelerometer",
            compass.rms * 100.0
        );
        assert!(headings > 100, "{headings}");
    }

    /// An accelerometer (4096 counts per g, 8 counts of noise) rested on
    /// its six faces for `hold_s` each, turned between them at 90 °/s, at
    /// 50 Hz.
    fn six_faces(hold_s: f64, seed: u64) -> (Vec<Reading>, [f64; 3], [[f64; 3]; 3]) {
        let w = [[1.03, 0.0, 0.0], [0.0, 0.97, 0.0], [0.0, 0.0, 1.01]];
        let offset = [60.0, -45.0, 90.0];
        let (samples, _) = crate::model::still_stream::tests::six_faces(
            hold_s,
            50.0,
            (w, offset, 4096.0, 8.0),
            seed,
        );
        let readings = samples
            .into_iter()
            .map(|(time, p)| Reading {
                time,
                accel: Some(p.map(|v| v.round() as i16)),
                ..Reading::default()
            })
            .collect();
        (readings, offset, w)
    }

    const STILL: &str = "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
        [[sensor]]\nname = \"level\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n\
        lsb_per_g = 4096\nmodel = \"offset+scale\"\n[sensor.sphere]\nstill = true\n";

    #[test]
    fn an_accelerometer_rested_on_its_six_faces_is_calibrated_from_the_poses() {
        for seed in 0..5 {
            let (readings, offset, w) = six_faces(2.0, seed);
            let c = config(STILL);
            let mut sensor = Sensor::new(c.sensors[0].clone(), None);
            let mut lines = Vec::new();
            let mut poses_seen = Vec::new();
            for r in &readings {
                sensor.on_reading(r, &mut |_, l| lines.push(l));
                if let Some(p) = sensor.status().sphere.and_then(|p| p.still) {
                    poses_seen.push(p.poses);
                }
            }
            let cals: Vec<&String> = lines
                .iter()
                .filter(|l| l.contains("\"CALIBRATION\""))
                .collect();
            assert_eq!(cals.len(), 1, "seed {seed}: {cals:?}");
            assert!(cals[0].contains("\"accepted\":true"), "{}", cals[0]);
            let cal = sensor.calibration().unwrap();
            let p = cal.ellipsoid.as_ref().unwrap();
            // 8 counts of noise over 6 poses of ~80 samples: the offsets
            // within a few counts, the gains within 0.2 %.
            for k in 0..3 {
                assert!(
                    (p.offset[k] - offset[k]).abs() < 4.0,
                    "seed {seed}: {:?}",
                    p.offset
                );
                // det W = 1: W·(raw − o) has magnitude r, 4096 counts per g.
                let gain = p.matrix[k][k] * 4096.0 / p.r;
                assert!(
                    (gain - w[k][k]).abs() < 2e-3,
                    "seed {seed}: {:?} r {}",
                    p.matrix,
                    p.r
                );
            }
            assert!((p.r / 4096.0 - 1.0).abs() < 0.01, "r {}", p.r);
            // STATUS counted the poses up to 5; the sixth, once it spans
            // a window, completes the model's six unknowns and is fitted.
            assert_eq!(poses_seen.iter().max(), Some(&5));
            assert!(poses_seen.windows(2).all(|w| w[0] <= w[1]));
            assert!(cals[0].contains("\"n\":"), "{}", cals[0]);
        }
    }

    #[test]
    fn a_still_pose_accelerometer_that_never_rests_is_not_calibrated_and_says_so() {
        let c = config(&STILL.replace("model = \"offset+scale\"\n", ""));
        let mut sensor = Sensor::new(c.sensors[0].clone(), None);
        let mut lines = Vec::new();
        for r in tumble() {
            sensor.on_reading(&r, &mut |_, l| lines.push(l));
        }
        assert!(!lines.iter().any(|l| l.contains("\"CALIBRATION\"")));
        let still = sensor.status().sphere.and_then(|p| p.still).unwrap();
        assert_eq!(still.poses, 0);
        assert!(still.state.never_still, "{still:?}");
        let status = serde_json::to_value(sensor.status().sphere.unwrap()).unwrap();
        assert_eq!(status["still"]["never_still"], true, "{status}");
        assert_eq!(status["still"]["poses_needed"], 9, "{status}");
    }

    #[test]
    fn still_poses_are_refused_for_a_magnetometer() {
        let text = STILL
            .replace("field = \"accel\"", "field = \"mag\"")
            .replace("lsb_per_g", "lsb_per_gauss");
        let e = parse(&text, std::path::Path::new("t.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("sphere.still") && e.contains("accelerometer"),
            "{e}"
        );
    }
}
