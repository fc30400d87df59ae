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
use super::messages::{CalibrationEvent, Reading3Message, TiltFields, as_published, to_line};
use super::north::{Earth, MeasuredDip, North, earth};
use super::sensor::{Emitter, Geometry, Sample};
use super::{Calibration, Ellipsoid3Params};
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::model::calibration::{DipFit, GyroFit};
use crate::model::ellipsoid::{self, Ellipsoid3Fit, Ellipsoid3Se};
use crate::model::paper::PaperCalibration;
use crate::model::sphere::SphereCoverage;
use crate::model::sphere_buffer::SphereBuffer;
use crate::model::tilt::{
    AxisMap, inclination_deg, mounting_problem, robust_spread, tilt_heading_or_why,
};
use crate::model::trust::{
    GyroModel, Observation, TrustCounts, TrustLimits, TrustMonitor, Verdict, monitor_of,
};
use crate::model::watch;
use crate::sample::Reading;
use std::sync::Arc;

mod gyro;
mod watching;

use gyro::Gyro3Track;

// The sphere buffer's settings and progress, at the paths they had before
// the buffer moved to [`crate::model::sphere_buffer`].
pub use crate::model::sphere_buffer::{SphereProgress, SphereSettings};
// ArduPilot's acceptance limits, at the paths they had before they moved
// to [`super::sphere_limits`].
pub use super::sphere_limits::*;

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
    /// A magnetometer with a tilt accelerometer: the dip over the fit's
    /// samples, and whether `mag_axes` can be right.
    #[serde(skip_serializing_if = "Option::is_none")]
    dip: Option<&'a DipFit>,
    /// A compass with a gyro: the gyro against the tilt-compensated
    /// heading over the fit's samples (its scale, its bias on each axis,
    /// the heading's noise), which each later heading's change is checked
    /// against ([`crate::model::gyro3`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    gyro: Option<&'a GyroFit>,
    /// Why a compass with a gyro has no such fit.
    #[serde(skip_serializing_if = "Option::is_none")]
    heading_check: Option<&'a str>,
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
            stored: super::messages::is_stored(self.origin),
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
    /// Trust at every reading, under the calibration of the id it holds.
    trust: Option<(u64, TrustMonitor)>,
    /// The gyro its tilt-compensated heading is checked against (`gyro`).
    gyro: Option<Gyro3Track>,
    /// Why the last accepted calibration has no gyro fit, when it has none.
    gyro_check: Option<String>,
}

/// Where a 3-axis csv sensor's values are: (file, column indices of x, y,
/// z) of its own and of its tilt source.
#[derive(Debug, Clone)]
struct Csv3Binding {
    own: (usize, [usize; 3]),
    tilt: Option<(usize, [usize; 3])>,
}

/// The values at `at` of a row, when all three are there and finite.
pub(super) fn finite3(values: &[f64], at: [usize; 3]) -> Option<[f64; 3]> {
    let v = [
        *values.get(at[0])?,
        *values.get(at[1])?,
        *values.get(at[2])?,
    ];
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The `axes` of a chip's reading, in that order.
pub(super) fn pick(triad: [i16; 3], axes: [Axis; 3]) -> [f64; 3] {
    axes.map(|a| f64::from(triad[a.index()]))
}

fn field_of(reading: &Reading, field: Field) -> Option<[i16; 3]> {
    match field {
        Field::Mag => reading.mag,
        Field::Accel => reading.accel,
        Field::Gyro => reading.gyro,
    }
}

/// The trust monitor's verdict on a calibrated reading: `mag` corrected
/// by `c`, `accel_raw` the tilt accelerometer's raw reading beside it
/// when there is a fresh one. The field, and the dip
/// through the accelerometer correction the calibration's own dip was
/// measured with (so that a later accelerometer calibration does not
/// read as a change of the field); a mounting the calibration's samples
/// showed wrong distrusts every tilt-compensated heading; with a gyro
/// fitted at calibration, `gyro_deg_s` is the heading's rate it gives.
fn judge(
    trust: &mut Option<(u64, TrustMonitor)>,
    (mag_axes, stale): (AxisMap, Option<&str>),
    c: &Calibration,
    (time, mag, heading_deg, gyro_deg_s): (f64, [f64; 3], Option<f64>, Option<f64>),
    accel_raw: Option<[f64; 3]>,
) -> Verdict {
    let magnitude = (mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2]).sqrt();
    let ratio = magnitude / c.ellipsoid.as_ref().map_or(f64::NAN, |p| p.r);
    // A dip (and a mounting verdict) measured under another `mag_axes`
    // (the configuration changed since) says nothing of this mapping.
    let dip = c.dip.as_ref().filter(|d| {
        d.mag_axes
            .as_deref()
            .unwrap_or("x,y,z")
            .parse::<AxisMap>()
            .is_ok_and(|m| m == mag_axes)
    });
    let dip_deg = dip.zip(accel_raw).and_then(|(d, raw)| {
        let accel = d.accel.as_ref().map_or(raw, |p| apply3(p, raw));
        inclination_deg(mag_axes.apply(mag), accel)
    });
    let mounting = dip
        .and_then(|d| d.mounting.as_deref())
        .filter(|_| heading_deg.is_some());
    let standing: Vec<&str> = stale.into_iter().chain(mounting).collect();
    monitor_of(trust, c.id, || {
        let gyro = c.gyro.as_ref().filter(|g| g.bias_xyz_deg_s.is_some());
        let limits = TrustLimits::from_rms(
            c.rms,
            gyro.map(|g| g.heading_rms_deg),
            gyro.map(|g| GyroModel {
                scale: g.scale,
                bias_deg_s: g.bias_deg_s,
            }),
        );
        match dip {
            Some(d) => limits.with_dip(d.median_deg, d.spread_deg),
            None => limits,
        }
    })
    .check_under(
        Observation {
            time,
            field_ratio: ratio,
            heading_deg: heading_deg.unwrap_or(0.0),
            gyro_deg_s: gyro_deg_s.filter(|_| heading_deg.is_some()),
            dip_deg,
            across: None,
            tilt_deg: None,
        },
        &standing,
    )
}

/// A fit's calibration as the state file keeps it.
fn params_of(fit: &Ellipsoid3Fit) -> Ellipsoid3Params {
    Ellipsoid3Params {
        offset: fit.offset,
        matrix: fit.matrix,
        r: fit.r,
        coverage: fit.coverage.fraction,
    }
}

/// A magnetometer's corrected readings, each with the tilt accelerometer's
/// beside it.
type DipPairs = Vec<([f64; 3], [f64; 3])>;

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
            trust: None,
            gyro: Gyro3Track::new(&three.gyro, three.mag_axes, three.sphere.max_samples),
            gyro_check: None,
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
        self.reset_sphere();
    }

    /// The sphere collected afresh: the buffer and the gyro kept beside it.
    fn reset_sphere(&mut self) {
        self.buffer.reset();
        if let Some(gyro) = &mut self.gyro {
            gyro.clear();
        }
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
        let (calibration, dip) = self.calibration_of(life, &fit, time);
        let earth = dip.and_then(|d| self.earth_of(fit.r, || d));
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
        life.accept(calibration);
        // Let the samples go; the next sphere, watched against this
        // calibration, is collected afresh.
        self.reset_sphere();
        life.current.clone()
    }

    /// The calibration a fit of the samples held makes, with its standard
    /// errors (widened for the samples' correlation in time), and its dip
    /// over them (beside the dip's measurement, for the Earth's model).
    fn calibration_of(
        &mut self,
        life: &Lifecycle,
        fit: &Ellipsoid3Fit,
        time: f64,
    ) -> (Calibration, Option<Result<MeasuredDip, String>>) {
        let residuals: Vec<f64> = self
            .buffer
            .points()
            .iter()
            .map(|p| fit.magnitude_error(*p))
            .collect();
        let refit = watch::sphere_refit(fit, &residuals);
        let dip = (self.field == Field::Mag).then(|| self.measured_inclination(&params_of(fit)));
        let mut calibration = Calibration {
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
            ellipsoid: Some(params_of(fit)),
            se: watch::se_map(&refit.params),
            parent: None,
            history: Vec::new(),
            gyro: None,
            across: None,
            level: None,
            dip: dip
                .as_ref()
                .and_then(|d| d.as_ref().ok())
                .map(|d| self.dip_fit(&params_of(fit), d)),
        };
        let accel = self
            .tilt_calibration
            .as_ref()
            .and_then(|c| c.ellipsoid.as_ref());
        let gyro = self
            .gyro
            .as_ref()
            .map(|g| g.fit(&params_of(fit), self.config.mag_axes, accel));
        self.gyro_check = match &gyro {
            Some(Err(why)) => {
                tracing::warn!(sensor = %self.name, "heading not checked against the gyro: {why}");
                Some(format!("no heading check against the gyro: {why}"))
            }
            _ => None,
        };
        calibration.gyro = gyro.and_then(Result::ok);
        (calibration, dip)
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
            dip: c.dip.as_ref(),
            gyro: c.gyro.as_ref(),
            heading_check: self
                .gyro_check
                .as_deref()
                .filter(|_| c.gyro.is_none() && !super::messages::is_stored(origin)),
        }
    }

    /// The fitted field beside the World Magnetic Model's, when the sensor
    /// is a magnetometer with a location.
    /// `dip`: the inclination over the fit's samples, measured only when
    /// there is a model to compare it with.
    fn earth_of(&self, r: f64, dip: impl FnOnce() -> Result<MeasuredDip, String>) -> Option<Earth> {
        let north = self.north.as_ref().filter(|_| self.field == Field::Mag)?;
        earth(north, r, self.config.lsb_per_unit, dip())
    }

    /// The inclination over the samples held, each corrected by `params`
    /// with the tilt accelerometer's reading beside it (corrected by its
    /// calibration, when it has one): median and robust spread, as
    /// `fieldcal heading` measures it.
    fn measured_inclination(&self, params: &Ellipsoid3Params) -> Result<MeasuredDip, String> {
        let (pairs, accelerometer_calibrated) = self.dip_pairs(params)?;
        let values: Vec<f64> = pairs
            .iter()
            .filter_map(|(mag, accel)| inclination_deg(self.config.mag_axes.apply(*mag), *accel))
            .collect();
        robust_spread(&values)
            .map(|spread| MeasuredDip {
                spread,
                accelerometer_calibrated,
            })
            .ok_or_else(|| "no fitted sample had a tilt accelerometer reading beside it".into())
    }

    /// The samples held, each corrected by `params` (in the magnetometer's
    /// own axes), with the tilt accelerometer's reading beside it
    /// (corrected by its calibration, when it has one: then `true`).
    fn dip_pairs(&self, params: &Ellipsoid3Params) -> Result<(DipPairs, bool), String> {
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
        let pairs = self
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
                Some((apply3(params, *raw), accel))
            })
            .collect();
        Ok((pairs, accel_cal.is_some()))
    }

    /// The calibration's dip, and whether `mag_axes` can be how the
    /// magnetometer lies on the accelerometer: what the trust monitor
    /// checks each reading against.
    fn dip_fit(&self, params: &Ellipsoid3Params, dip: &MeasuredDip) -> DipFit {
        let expected = self
            .north
            .as_ref()
            .and_then(|n| n.model.as_ref())
            .map(|m| m.inclination_deg);
        let mounting = self.dip_pairs(params).ok().and_then(|(pairs, _)| {
            let (mag, accel): (Vec<_>, Vec<_>) = pairs.into_iter().unzip();
            mounting_problem(&mag, &accel, self.config.mag_axes, expected)
        });
        if let Some(why) = &mounting {
            tracing::warn!(sensor = %self.name, "{why}");
        }
        DipFit {
            median_deg: dip.spread.median,
            spread_deg: dip.spread.spread,
            n: dip.spread.n,
            accel: self
                .tilt_calibration
                .as_ref()
                .filter(|_| dip.accelerometer_calibrated)
                .and_then(|c| c.ellipsoid),
            mounting,
            mag_axes: Some(self.config.mag_axes.to_string()),
        }
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
            earth: fit
                .and_then(|f| self.earth_of(f.r, || self.measured_inclination(&params_of(f)))),
            poses: self.buffer.still_poses(),
            dip: None,
            gyro: None,
            heading_check: None,
        };
        emit.calibration(|| Some(message.event()), to_line(&message));
        tracing::warn!(sensor = %self.name, "3-D calibration rejected: {reason}");
        life.reject(reason);
        // Collect anew; the previous calibration (if any) keeps correcting.
        self.buffer.rejected();
        if let Some(gyro) = &mut self.gyro {
            gyro.clear();
        }
    }
}

impl Geometry for Sensor3 {
    fn reading_line(&mut self, life: &Lifecycle, sample: Sample, _row: Option<&CsvRow>) -> String {
        let Sample { time, raw, .. } = sample;
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
                let mag = self.config.mag_axes.apply(mag);
                match tilt_heading_or_why(mag, accel, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]) {
                    Ok(h) => Some((
                        (h.heading_deg, accel),
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
        let (heading_deg, up, tilt) = match tilt {
            Some(((h, up), t)) => (Some(h), Some(up), Some(t)),
            None => (None, None, None),
        };
        // The heading's rate the gyro gives, under the calibration's fit.
        let gyro_deg_s = self
            .gyro
            .as_ref()
            .zip(life.current.as_ref().and_then(|c| c.gyro.as_ref()))
            .zip(up)
            .and_then(|((g, fit), up)| g.rate(time, fit, up));
        let true_heading_deg = heading_deg
            .zip(self.north.as_ref())
            .map(|(h, n)| n.true_heading(h));
        let magnitude = corrected.map(|(_, c)| (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt());
        let verdict = life.current.as_ref().zip(corrected).map(|(c, (_, mag))| {
            judge(
                &mut self.trust,
                (self.config.mag_axes, life.stale.as_deref()),
                c,
                (time, mag, heading_deg, gyro_deg_s),
                accel,
            )
        });
        Reading3Message {
            class: "READING",
            sensor: &self.name,
            time,
            axes: 3,
            raw,
            corrected: corrected.map(|c| c.1),
            magnitude,
            calibration: corrected.map(|c| c.0),
            calibrated: corrected.is_some(),
            heading_deg,
            true_heading_deg,
            tilt,
            heading_omitted,
            trusted: verdict.as_ref().map(|v| v.trusted),
            distrust: verdict
                .as_ref()
                .map(|v| v.reasons.as_slice())
                .filter(|r| !r.is_empty()),
        }
        .to_line()
    }
    fn trust(&self) -> Option<TrustCounts> {
        self.trust.as_ref().map(|(_, m)| m.counts())
    }
    fn distrust_now(&self) -> Option<&str> {
        self.trust.as_ref().and_then(|(_, m)| m.distrust_now())
    }
    fn push(
        &mut self,
        life: &mut Lifecycle,
        sample: Sample,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let Sample { time, raw, .. } = sample;
        // Calibrated: each later sphere is watched against the calibration,
        // until it is found stale.
        let watching = !life.collecting();
        if (watching && life.stale.is_some()) || raw.iter().any(|v| !v.is_finite()) {
            return None;
        }
        // The accelerometer beside this sample, unless it was stale.
        let accel = self.config.tilt.is_some().then_some(sample.accel);
        if let (Some(gyro), Some(Some(a))) = (&mut self.gyro, accel) {
            gyro.keep(time, [raw, a], sample.gyro, self.buffer.points().is_empty());
        }
        if !self.buffer.push(time, raw, accel) {
            return None;
        }
        let fitted = if watching {
            self.watch(life, time, emit)
        } else {
            self.fit(life, time, emit)
        };
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
            || self.gyro.as_ref().and_then(Gyro3Track::stream) == Some(stream)
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
        let mut required: Vec<(usize, usize)> = [Some(own), tilt]
            .into_iter()
            .flatten()
            .flat_map(|(file, at)| at.map(|i| (file, i)))
            .collect();
        if let Some(gyro) = &mut self.gyro {
            required.extend(gyro.bind_csv(files, &layouts)?);
        }
        self.csv = Some(Csv3Binding { own, tilt });
        Ok(required)
    }
    fn row_sample(&mut self, _life: &Lifecycle, row: &CsvRow) -> Option<Sample> {
        if let Some(gyro) = &mut self.gyro {
            gyro.observe_row(row);
        }
        let binding = self.csv.as_ref()?;
        let values = |at: [usize; 3]| finite3(&row.values, at);
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
        let raw = values(at)?;
        Some(self.sample_at(row.time, raw))
    }
    fn reading_sample(&mut self, _life: &Lifecycle, reading: &Reading) -> Option<Sample> {
        if let Some(gyro) = &mut self.gyro {
            gyro.observe_reading(reading);
        }
        if let Some(tilt) = &self.config.tilt
            && reading.stream == tilt.stream
            && let Some(triad) = reading.accel
        {
            self.last_accel = Some((reading.time, pick(triad, tilt.axes)));
        }
        if reading.stream != self.stream {
            return None;
        }
        let raw = pick(field_of(reading, self.field)?, self.config.axes);
        Some(self.sample_at(reading.time, raw))
    }
    fn loaded_line(
        &self,
        life: &Lifecycle,
        origin: &'static str,
    ) -> Option<(String, Option<CalibrationEvent>)> {
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
        let message = self.message(c, None, 0.0, origin, earth);
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
pub(super) const TILT_ROLES: [&str; 3] = [
    "the tilt source's x axis",
    "the tilt source's y axis",
    "the tilt source's z axis",
];

/// Finds the three columns named in `columns` (x, y, z, with their `roles`
/// for messages) among the files' headers: the file and the three indices.
pub(super) fn locate3(
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
