//! The plane geometry of a 2-axis sensor (`axes = ["x", "y"]`): readings
//! are collected by the rotation buffer ([`crate::model::rotation`]) until
//! the sensor has turned once round, then fitted with the paper's model
//! (and the effects the configuration adds), checked against the
//! [`acceptance`] limits, and from then on every reading carries the
//! corrected x, y and heading. A gyro beside it checks each fit's heading.
//!
//! A plain state machine as [`super::sensor::Sensor`] (which holds one of
//! these, or a sphere, beside the sensor's [`Lifecycle`]): readings in,
//! lines to publish and calibrations to store out, no I/O, no clock.

mod gyro_track;
mod watching;

use super::beside::Beside;

use std::sync::Arc;
use std::time::Instant;

use super::acceptance::{self, Limits};
use super::config::{
    Axis, Field, GyroChoice, OnStale, OutOfPlane, PlaneConfig, SensorConfig, TiltSource,
};
use super::lifecycle::Lifecycle;
use super::messages::{
    CalibrationEvent, CalibrationMessage, ColumnValues, ReadingMessage, ReadingValues, to_line,
};
use super::publish::Lane;
use super::sensor::{Emitter, Geometry, Sample};
use super::sensor3::{MAX_TILT_AGE_S, finite3, pick};
use super::{Calibration, Terms};
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::model::calibration::GyroFit;
use crate::model::centred_split::fit_with_gyro;
use crate::model::diagnose::diagnose;
use crate::model::effects::{Effect, parse_list};
use crate::model::fit::{FitOptions, FitReport, Solver, fit_paper, fit_paper_turned};
use crate::model::gyro::HeadingCheck;
use crate::model::gyro::{GyroUnits, HeadingReference};
use crate::model::heading::{coverage, wrap_degrees};
use crate::model::level::angle_between_deg;
use crate::model::nonlinear::{cubic_scale, turn_frame};
use crate::model::rotation::{Progress, RotationBuffer, RotationEvent};
use crate::model::trust::{
    GyroModel, Observation, TrustCounts, TrustLimits, TrustMonitor, monitor_of,
};
use crate::model::turn::check_turn;
use crate::model::watch::{self, Refit};
use crate::sample::Dataset;
use crate::sample::Reading;

pub(super) use gyro_track::GyroTrack;

/// A 2-axis sensor's rotation buffer, model and gyro.
pub struct Plane {
    config: SensorConfig,
    /// The 2-axis settings of `config`.
    plane: PlaneConfig,
    effects: Vec<Effect>,
    limits: Limits,
    model: String,
    buffer: RotationBuffer,
    /// The gyro rate kept beside the rotation, for its heading check.
    pub(super) gyro: Option<GyroTrack>,
    /// A sensor of a csv source: its columns, resolved once against the
    /// file's header by [`Plane::bind_csv`].
    csv: Option<CsvBinding>,
    /// Trust at every reading, under the calibration of the id it holds.
    trust: Option<(u64, TrustMonitor)>,
    /// The raw x and y of the last rotation fitted (the one behind the
    /// calibration, or the last one watched against it): a refinement
    /// must not be worse than its parent over it and the next.
    last_rotation: Option<(Vec<f64>, Vec<f64>)>,
    /// A stale calibration's id while a clean rotation is collected to
    /// replace it (`on_stale = "replace"`, the rotation that showed the
    /// change having straddled it).
    replacing: Option<u64>,
    /// The field across the turn kept beside the rotation, when the
    /// configuration names its axis (`out_of_plane`).
    across: Option<Beside<f64>>,
    /// The tilt accelerometer's raw readings kept beside the rotation,
    /// when the configuration names one (`tilt`).
    level: Option<Beside<[f64; 3]>>,
    /// The tilt accelerometer's last raw reading, with its time.
    last_accel: Option<(f64, [f64; 3])>,
}

/// Where a csv sensor's values are in each row: indices into
/// [`CsvRow::values`], resolved once, never looked up by name per row.
#[derive(Debug, Clone)]
struct CsvBinding {
    /// The file of its source the columns are in ([`CsvRow::file`]).
    file: usize,
    layout: Arc<CsvLayout>,
    axes: [usize; 2],
    /// The gyro column: (file, index), in any file of the source.
    gyro: Option<(usize, usize)>,
    /// The column across the turn (`out_of_plane`), in `file`.
    across: Option<usize>,
    /// The tilt accelerometer's x, y, z columns: (file, indices), in any
    /// file of the source.
    tilt: Option<(usize, [usize; 3])>,
    /// The other columns, published with each reading.
    others: Vec<usize>,
}

impl Plane {
    /// The plane of a 2-axis sensor of `config`.
    pub fn new(config: SensorConfig, plane: PlaneConfig) -> Self {
        let limits = plane.limits.clone();
        let buffer = RotationBuffer::new(plane.rotation.clone());
        let gyro = GyroTrack::new(&plane.gyro, buffer.config().max_samples);
        let across = plane
            .out_of_plane
            .as_ref()
            .map(|_| Beside::new(buffer.config().max_samples));
        let level = plane
            .tilt
            .as_ref()
            .map(|_| Beside::new(buffer.config().max_samples));
        // The configuration checked the names; an unparsable list (not
        // possible from a checked file) falls back to the paper's model.
        let effects = parse_list(&plane.effects.join(","))
            .unwrap_or_else(|_| crate::model::effects::PAPER.to_vec());
        Plane {
            model: crate::model::effects::model_name(&effects),
            effects,
            config,
            plane,
            limits,
            buffer,
            gyro,
            csv: None,
            trust: None,
            last_rotation: None,
            replacing: None,
            across,
            level,
            last_accel: None,
        }
    }

    /// The two turning axes of a reading, if it carries the sensor's field.
    pub fn axes_of(&self, reading: &Reading) -> Option<(f64, f64)> {
        axes_of(self.config.field, self.plane.axes, reading)
    }

    /// Starts a new rotation (the [`Lifecycle`] restarts beside it).
    pub fn recalibrate(&mut self) {
        self.replacing = None;
        self.buffer.reset();
        if let Some(track) = &mut self.across {
            track.clear();
        }
        if let Some(track) = &mut self.level {
            track.clear();
        }
        if let Some(gyro) = &mut self.gyro {
            gyro.clear();
        }
    }

    /// The READING of a sample, calibrated and judged by the trust monitor
    /// when the sensor has a calibration.
    fn reading_values(
        &mut self,
        life: &Lifecycle,
        time: f64,
        [x, y, across]: [f64; 3],
    ) -> ReadingValues {
        let corrected = life.current.as_ref().map(|c| {
            let (sx, sy) = c.apply(x, y);
            (c.id, [sx, sy], wrap_degrees(sy.atan2(sx).to_degrees()))
        });
        let gyro_deg_s = self.gyro.as_ref().and_then(GyroTrack::latest_deg_s);
        let accel = self.fresh_accel(time);
        let verdict = life
            .current
            .as_ref()
            .zip(corrected)
            .map(|(c, (_, s, heading))| {
                let monitor = self.trust_of(c);
                monitor.check_under(
                    Observation {
                        time,
                        field_ratio: monitor.plane_field_ratio(s, c.params.r),
                        heading_deg: heading,
                        gyro_deg_s,
                        dip_deg: None,
                        across: c
                            .across
                            .filter(|_| across.is_finite())
                            .map(|_| across / c.params.r),
                        tilt_deg: c
                            .level
                            .as_ref()
                            .zip(accel)
                            .and_then(|(l, a)| angle_between_deg(l.up, a)),
                    },
                    life.stale.as_deref().as_slice(),
                )
            });
        ReadingValues {
            time,
            raw: [x, y],
            corrected: corrected.map(|c| c.1),
            heading_deg: corrected.map(|c| c.2),
            true_heading_deg: corrected
                .zip(self.config.north.as_ref())
                .map(|(c, n)| n.true_heading(c.2)),
            calibration: corrected.map(|c| c.0),
            calibrated: corrected.is_some(),
            trusted: verdict.as_ref().map(|v| v.trusted),
            distrust: verdict.map(|v| v.reasons).filter(|r| !r.is_empty()),
        }
    }

    /// A sample of the plane at `time`, with the accelerometer and the
    /// gyro's angle beside it now.
    fn sample(&self, time: f64, raw: [f64; 3]) -> Sample {
        Sample {
            turned: self.gyro.as_ref().and_then(GyroTrack::angle),
            ..Sample::beside(time, raw, self.last_accel)
        }
    }

    /// The tilt accelerometer's last raw reading, when it is at most
    /// [`MAX_TILT_AGE_S`] older than `time`.
    fn fresh_accel(&self, time: f64) -> Option<[f64; 3]> {
        self.last_accel
            .filter(|(t, _)| (time - t).abs() <= MAX_TILT_AGE_S)
            .map(|(_, a)| a)
    }

    /// The trust monitor of calibration `c`: its limits from the
    /// calibration's rms and, when it was accepted with a heading check,
    /// the gyro that check found (kept with it, across restarts); the
    /// field across the turn and the attitude it measured, when it did.
    fn trust_of(&mut self, c: &Calibration) -> &mut TrustMonitor {
        let dip = self
            .config
            .north
            .as_ref()
            .and_then(|n| n.model.as_ref())
            .map(|m| m.inclination_deg);
        monitor_of(&mut self.trust, c.id, || {
            let gyro = c.gyro.as_ref().map(|g| GyroModel {
                scale: g.scale,
                bias_deg_s: g.bias_deg_s,
            });
            let limits =
                TrustLimits::from_rms(c.rms, c.gyro.as_ref().map(|g| g.heading_rms_deg), gyro);
            let limits = match c.across {
                Some(a) => limits.with_across(a.median / c.params.r, a.spread / c.params.r),
                None => limits,
            };
            // An attitude measured with another accelerometer (the
            // configuration changed since) says nothing of this one's.
            let tilt = self.plane.tilt.as_ref().map(TiltSource::describe);
            match c.level.as_ref().filter(|l| l.tilt == tilt) {
                Some(l) => limits.with_tilt(l.tilt_sd_deg, dip),
                None => limits,
            }
        })
    }

    fn fit(
        &mut self,
        life: &mut Lifecycle,
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let (t, x, y) = self.buffer.take();
        let started = Instant::now();
        let fitted = self.fit_rotation(t, x, y, true);
        let fit_ms = started.elapsed().as_secs_f64() * 1e3;
        let (report, terms, rotation, refit) = match fitted {
            Ok(found) => found,
            Err((reason, n)) => {
                self.reject(life, time, format!("no fit: {reason}"), (n, fit_ms), emit);
                return None;
            }
        };
        // What the rotation's residual says beyond the fit: its noise floor,
        // and an effect the model lacks, so the user beside the robot learns
        // that the configuration should add it; with the gyro beside the
        // rotation, each candidate's heading is checked against it (and a
        // cubic held to the limit a checked heading allows) as `fieldcal
        // diagnose --gyro` does.
        let reference = self
            .gyro
            .as_ref()
            .zip(rotation.t.as_deref())
            .and_then(|(g, t)| g.reference(t).ok());
        let insight = diagnose(&rotation, &self.effects, reference.as_ref()).ok();
        let noise_floor = insight.as_ref().map(|d| d.noise_floor.rms);
        let (suggested, close_second) = match insight {
            Some(d) => (
                d.suggested.map(|e| e.to_string()),
                d.close_second.map(|e| e.to_string()),
            ),
            None => (None, None),
        };
        let heading = self.heading_check(&rotation, &report, &terms);
        let (heading_vs_gyro, heading_check) = match heading {
            Ok(check) => (Some(check), None),
            Err(why) => (None, Some(why)),
        };
        // The acceptance limits, then what every calibration that enters
        // must be (model/validity.rs: its terms too), so none is accepted
        // and stored that the next start would refuse.
        let valid = || match crate::model::validity::plane_problem(
            &report.calibration,
            &terms,
            self.limits.max_scale_ratio,
            self.limits.max_offset_ratio,
        ) {
            Some(problem) => Err(format!("not a calibration: {problem}")),
            None => Ok(()),
        };
        if let Err(reason) = acceptance::check(&report, &self.limits).and_then(|()| valid()) {
            // A fit outside the limits is published with its numbers, so the
            // user sees how far off it was.
            let message = CalibrationMessage {
                params: Some(report.calibration),
                rms: Some(report.rms),
                terms: (!terms.is_none()).then_some(terms),
                noise_floor,
                suggested,
                close_second,
                heading_vs_gyro,
                heading_check,
                ..self.rejection(time, &reason, report.n, report.coverage.covered_deg, fit_ms)
            };
            emit.calibration(|| message.event(), to_line(&message));
            self.note_rejection(life, reason);
            return None;
        }
        let mut calibration = self.calibration_of(life, (&report, terms, &refit, &rotation), time);
        calibration.gyro = heading_vs_gyro.as_ref().map(gyro_fit);
        // The clean rotation collected to replace a stale calibration.
        calibration.parent = self.replacing.take();
        self.last_rotation = Some((rotation.x.clone(), rotation.y.clone()));
        let message = CalibrationMessage {
            fit_ms,
            origin: if calibration.parent.is_some() {
                "replaced"
            } else {
                "rotation"
            },
            noise_floor,
            suggested,
            close_second,
            heading_vs_gyro,
            heading_check,
            ..CalibrationMessage::loaded(&calibration).with_north(self.config.north.as_ref())
        };
        emit.calibration(|| message.event(), to_line(&message));
        match (&message.heading_vs_gyro, &message.heading_check) {
            (Some(h), _) => tracing::info!(
                sensor = %self.config.name,
                id = calibration.id,
                rms = calibration.rms,
                heading_rms_deg = h.rms_deg,
                heading_peak_to_peak_deg = h.peak_to_peak_deg,
                "calibration accepted; heading against {}: {:.2}° rms",
                h.gyro_column,
                h.rms_deg
            ),
            (None, why) => tracing::info!(
                sensor = %self.config.name,
                id = calibration.id,
                rms = calibration.rms,
                "calibration accepted; heading not checked: {}",
                why.as_deref().unwrap_or("no gyro")
            ),
        }
        life.accept(calibration);
        life.current.clone()
    }

    /// The calibration a fit gives, as the sensor's next id.
    fn calibration_of(
        &self,
        life: &Lifecycle,
        (report, terms, refit, rotation): (&FitReport, Terms, &Refit, &Dataset),
        time: f64,
    ) -> Calibration {
        // The field across the turn over the rotation's own span.
        let span = rotation
            .t
            .as_ref()
            .and_then(|t| Some((*t.first()?, *t.last()?)));
        let across = self
            .across
            .as_ref()
            .zip(span)
            .and_then(|(track, (from, to))| track.across_over(from, to));
        let level = self
            .level
            .as_ref()
            .zip(span)
            .and_then(|(track, (from, to))| track.level_over(from, to))
            .map(|l| crate::model::calibration::LevelFit {
                tilt: self.plane.tilt.as_ref().map(TiltSource::describe),
                ..l
            });
        Calibration {
            sensor: self.config.name.clone(),
            id: life.next_id,
            model: self.model.clone(),
            params: report.calibration,
            rms: report.rms,
            coverage_deg: report.coverage.covered_deg,
            n: report.n,
            time,
            terms,
            ellipsoid: None,
            se: watch::se_map(&refit.params),
            parent: None,
            history: Vec::new(),
            gyro: None,
            dip: None,
            across,
            level,
        }
    }

    /// The fitted model's heading against the gyro kept beside the
    /// rotation, or why there is none. Information only: it never rejects a
    /// fit. O(n) in the rotation's samples; empties the gyro track.
    fn heading_check(
        &mut self,
        rotation: &Dataset,
        report: &FitReport,
        terms: &Terms,
    ) -> Result<HeadingCheck, String> {
        let Some(gyro) = &mut self.gyro else {
            return Err(match &self.plane.gyro {
                GyroChoice::Off(why) => why.clone(),
                GyroChoice::Rate { .. } | GyroChoice::Column { .. } => {
                    "no heading check: no gyro".into()
                }
            });
        };
        let t = rotation.t.as_deref().unwrap_or(&[]);
        let headings: Vec<f64> = rotation
            .x
            .iter()
            .zip(&rotation.y)
            .map(|(&x, &y)| {
                let (cx, cy) = crate::daemon::apply(&report.calibration, terms, x, y);
                cy.atan2(cx)
            })
            .collect();
        let checked = gyro
            .check(t, &headings)
            .map_err(|e| format!("no heading check against {}: {e}", gyro.column));
        gyro.clear();
        checked
    }

    /// Fits the rotation with the sensor's model: the paper's closed form,
    /// or the general model when the configuration adds effects. Returns
    /// the report the acceptance limits judge, the extra terms, and the
    /// rotation as a recording (for the diagnosis).
    /// `gate`: run the turn gate (the first fit of a calibration); a later
    /// rotation's fit, only compared with the calibration, skips it.
    fn fit_rotation(
        &self,
        t: Vec<f64>,
        x: Vec<f64>,
        y: Vec<f64>,
        gate: bool,
    ) -> Result<(FitReport, Terms, Dataset, Refit), (String, usize)> {
        let n = x.len();
        let rotation =
            Dataset::new("x", "y", Some(t), x, y, Vec::new()).map_err(|e| (e.to_string(), n))?;
        let options = FitOptions {
            min_coverage_deg: self.limits.min_coverage_deg,
            ..FitOptions::default()
        };
        if self.effects.iter().all(Effect::is_paper) {
            let fit = if gate { fit_paper } else { fit_paper_turned };
            let report = fit(&rotation.x, &rotation.y, &options, &mut |_| {})
                .map_err(|e| (e.to_string(), n))?;
            let refit = watch::paper_refit(&rotation.x, &rotation.y, &report);
            return Ok((report, Terms::default(), rotation, refit));
        }
        // fit_paper runs the turn gate itself; the general model must too.
        if gate {
            check_turn(&rotation.x, &rotation.y, options.min_coverage_deg)
                .map_err(|e| (e.to_string(), n))?;
        }
        let started = Instant::now();
        // With a gyro beside the rotation, a centred cubic is split per
        // axis where the gyro pins the difference (model/centred_split.rs).
        let reference = self
            .gyro
            .as_ref()
            .filter(|_| self.effects.contains(&Effect::CubicCentred))
            .zip(rotation.t.as_deref())
            .and_then(|(g, t)| g.reference(t).ok());
        let fit = fit_with_gyro(&rotation, &self.effects, reference.as_ref())
            .map_err(|e| (e.to_string(), n))?;
        let covered = coverage(fit.headings.iter().copied());
        covered
            .require(options.min_coverage_deg)
            .map_err(|e| (e.to_string(), n))?;
        let calibration = fit.paper();
        let terms = Terms {
            c: fit.value("c"),
            k: [fit.value("k_x"), fit.value("k_y")],
            cubic_scale: if self.effects.contains(&Effect::Cubic) {
                cubic_scale(&rotation)
            } else {
                0.0
            },
            ..Terms::default()
        };
        let terms = if self.effects.contains(&Effect::CubicCentred) {
            // The frame the fit held fixed; the fit above succeeded, so the
            // same starting point does.
            let frame = turn_frame(&rotation).map_err(|e| (e.to_string(), n))?;
            Terms {
                kc: fit.kc(),
                centre: frame.centre,
                turn_radius: frame.radius,
                ..terms
            }
        } else {
            terms
        };
        let refit = watch::widened(fit.params.clone(), &fit.used_residuals(), fit.rms);
        let report = FitReport {
            solver: Solver::Lsq,
            calibration,
            theta: calibration.to_theta(),
            rms: fit.rms,
            n: fit.n,
            iterations: None,
            coverage: covered,
            elapsed: started.elapsed(),
        };
        Ok((report, terms, rotation, refit))
    }

    /// A rotation of `n` samples refused for `reason`: published with no
    /// coverage, and counted.
    fn reject(
        &mut self,
        life: &mut Lifecycle,
        time: f64,
        reason: String,
        (n, fit_ms): (usize, f64),
        emit: &mut Emitter<'_>,
    ) {
        let message = self.rejection(time, &reason, n, 0.0, fit_ms);
        emit.calibration(|| message.event(), to_line(&message));
        self.note_rejection(life, reason);
    }

    /// A `CALIBRATION` line for a rotation that produced no accepted fit.
    fn rejection(
        &self,
        time: f64,
        reason: &str,
        n: usize,
        coverage_deg: f64,
        fit_ms: f64,
    ) -> CalibrationMessage<'_> {
        CalibrationMessage {
            coverage_deg,
            n,
            fit_ms,
            time,
            ..CalibrationMessage::rejected(&self.config.name, &self.model, Some(reason.to_string()))
        }
        .with_north(self.config.north.as_ref())
    }

    fn note_rejection(&self, life: &mut Lifecycle, reason: String) {
        tracing::warn!(sensor = %self.config.name, "calibration rejected: {reason}");
        life.reject(reason);
        // Collect again; the previous calibration (if any) keeps correcting.
    }

    /// Progress of the rotation being collected.
    pub fn progress(&self) -> Progress {
        self.buffer.progress()
    }
}

/// What a heading check found of the gyro, kept with the calibration.
fn gyro_fit(h: &HeadingCheck) -> GyroFit {
    GyroFit {
        scale: h.gyro_scale,
        bias_deg_s: h.gyro_bias_deg_s,
        heading_rms_deg: h.rms_deg,
        bias_xyz_deg_s: None,
        source: None,
    }
}

impl Geometry for Plane {
    fn trust(&self) -> Option<TrustCounts> {
        self.trust.as_ref().map(|(_, m)| m.counts())
    }
    fn distrust_now(&self) -> Option<&str> {
        self.trust.as_ref().and_then(|(_, m)| m.distrust_now())
    }
    fn row_sample(&mut self, _life: &Lifecycle, row: &CsvRow) -> Option<Sample> {
        let binding = self.csv.as_ref()?;
        if let (Some(gyro), Some((file, i))) = (&mut self.gyro, binding.gyro)
            && row.file == file
            && let Some(&rate) = row.values.get(i)
        {
            gyro.observe_value(rate);
            gyro.keep_value(row.time, rate);
        }
        if let Some((file, at)) = binding.tilt
            && row.file == file
            && let Some(accel) = finite3(&row.values, at)
        {
            self.last_accel = Some((row.time, accel));
        }
        if row.file != binding.file {
            return None;
        }
        let (x, y) = (
            *row.values.get(binding.axes[0])?,
            *row.values.get(binding.axes[1])?,
        );
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        let across = binding
            .across
            .and_then(|i| row.values.get(i).copied())
            .unwrap_or(f64::NAN);
        Some(self.sample(row.time, [x, y, across]))
    }
    fn reading_sample(&mut self, _life: &Lifecycle, reading: &Reading) -> Option<Sample> {
        if let Some(gyro) = &mut self.gyro {
            gyro.observe(reading);
            gyro.keep(reading);
        }
        if let Some(tilt) = &self.plane.tilt
            && reading.stream == tilt.stream
            && let Some(triad) = reading.accel
        {
            self.last_accel = Some((reading.time, pick(triad, tilt.axes)));
        }
        if reading.stream != self.config.stream {
            // Only the gyro or the accelerometer of another chip: kept
            // above, nothing to publish.
            return None;
        }
        let (x, y) = self.axes_of(reading)?;
        let across = match &self.plane.out_of_plane {
            Some(OutOfPlane::Axis(axis)) => {
                axes_of(self.config.field, [*axis, *axis], reading).map_or(f64::NAN, |(v, _)| v)
            }
            _ => f64::NAN,
        };
        Some(self.sample(reading.time, [x, y, across]))
    }
    fn reading_line(&mut self, life: &Lifecycle, sample: Sample, row: Option<&CsvRow>) -> String {
        let values = self.reading_values(life, sample.time, sample.raw);
        let columns = row
            .zip(self.csv.as_ref())
            .map(|(row, binding)| ColumnValues {
                names: &binding.layout.names,
                indices: &binding.others,
                values: &row.values,
            })
            .filter(|c| !c.is_empty());
        ReadingMessage {
            columns,
            ..values.message(&self.config.name)
        }
        .to_line()
    }
    fn emit_reading(
        &mut self,
        life: &Lifecycle,
        sample: Sample,
        row: Option<&CsvRow>,
        emit: &mut Emitter<'_>,
    ) {
        if row.is_some() {
            let line = self.reading_line(life, sample, row);
            emit.line(Lane::Reading, line);
        } else {
            let values = self.reading_values(life, sample.time, sample.raw);
            emit.reading(&self.config.name, values);
        }
    }
    fn axis_name(&self, axis: usize) -> &'static str {
        ["x", "y", "the field across the turn"]
            .get(axis)
            .copied()
            .unwrap_or("?")
    }
    fn push(
        &mut self,
        life: &mut Lifecycle,
        sample: Sample,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let (time, [x, y, across]) = (sample.time, sample.raw);
        let (accel, turned) = (sample.accel, sample.turned);
        // Calibrated: each later rotation is watched against the
        // calibration, until it is found stale.
        let watching = !life.collecting();
        if watching && life.stale.is_some() {
            return None;
        }
        if let Some(track) = &mut self.across
            && across.is_finite()
        {
            track.push(time, across);
        }
        if let (Some(track), Some(accel)) = (&mut self.level, accel) {
            track.push(time, accel);
        }
        // The gyro's integrated angle lets the buffer check the turn.
        match self.buffer.push_turned(time, x, y, turned) {
            RotationEvent::Collecting => None,
            RotationEvent::Rejected { reason } => {
                if let Some(gyro) = &mut self.gyro {
                    gyro.forget_before(time);
                }
                if watching {
                    tracing::debug!(sensor = %self.config.name, "later rotation: {reason}");
                    return None;
                }
                tracing::warn!(sensor = %self.config.name, "{reason}");
                self.reject(life, time, reason, (0, 0.0), emit);
                None
            }
            RotationEvent::Complete if watching => self.watch(life, time, emit),
            RotationEvent::Complete => self.fit(life, time, emit),
        }
    }
    fn loaded_line(
        &self,
        life: &Lifecycle,
        origin: &'static str,
    ) -> Option<(String, Option<CalibrationEvent>)> {
        life.current.as_ref().map(|c| {
            let message = CalibrationMessage {
                origin,
                ..CalibrationMessage::loaded(c).with_north(self.config.north.as_ref())
            };
            (to_line(&message), message.event())
        })
    }
    fn bind_csv(
        &mut self,
        layouts: &[Arc<CsvLayout>],
        files: &[std::path::PathBuf],
    ) -> Result<Vec<(usize, usize)>, CsvError> {
        let refs: Vec<&CsvLayout> = layouts.iter().map(Arc::as_ref).collect();
        let Some(columns) = &self.plane.columns else {
            return Ok(Vec::new());
        };
        let mut names = vec![
            (columns[0].as_str(), "the sensor's x axis"),
            (columns[1].as_str(), "the sensor's y axis"),
        ];
        if let Some(OutOfPlane::Column(name)) = &self.plane.out_of_plane {
            names.push((name.as_str(), "the axis across the turn"));
        }
        let (file, found) = crate::source::csv::locate_columns(files, &refs, &names)?;
        let Some(layout) = layouts.get(file) else {
            return Ok(Vec::new());
        };
        let axes = [found[0], found[1]];
        let across = found.get(2).copied();
        // The gyro may be in another file of the source: its rows come on
        // the same clock, merged in time order.
        let gyro = match &self.plane.gyro {
            GyroChoice::Column { name, .. } => {
                let wanted = [(name.as_str(), "the sensor's gyro")];
                let (gyro_file, at) = crate::source::csv::locate_columns(files, &refs, &wanted)?;
                at.first().map(|&i| (gyro_file, i))
            }
            _ => None,
        };
        let tilt = match self.plane.tilt.as_ref().and_then(|t| t.columns.as_ref()) {
            Some(columns) => Some(super::sensor3::locate3(
                files,
                &refs,
                columns,
                super::sensor3::TILT_ROLES,
            )?),
            None => None,
        };
        let others = (0..layout.names.len())
            .filter(|i| !axes.contains(i) && Some(*i) != layout.time_index())
            .collect();
        let mut required: Vec<(usize, usize)> = axes.iter().map(|&i| (file, i)).collect();
        required.extend(gyro);
        required.extend(tilt.iter().flat_map(|(file, at)| at.map(|i| (*file, i))));
        self.csv = Some(CsvBinding {
            file,
            layout: layout.clone(),
            axes,
            gyro,
            across,
            tilt,
            others,
        });
        Ok(required)
    }
    fn set_north(&mut self, north: Option<super::north::North>) {
        self.config.north = north;
        // The tilt limit reads the WMM's dip there: built anew.
        self.trust = None;
    }
    fn wants(&self, stream: u8) -> bool {
        self.config.stream == stream
            || self.gyro.as_ref().is_some_and(|g| g.stream == stream)
            || self.plane.tilt.as_ref().is_some_and(|t| t.stream == stream)
    }
    fn restart(&mut self) {
        self.recalibrate();
    }
    fn rotation(&self) -> Option<Progress> {
        Some(self.progress())
    }
    fn as_plane(&self) -> Option<&Plane> {
        Some(self)
    }
}

/// The two turning axes (`axes`) of a reading, if it carries the
/// sensor's field.
pub fn axes_of(field: Field, axes: [Axis; 2], reading: &Reading) -> Option<(f64, f64)> {
    let triad = match field {
        Field::Mag => reading.mag,
        Field::Accel => reading.accel,
        Field::Gyro => reading.gyro,
    }?;
    let pick = |axis: Axis| {
        f64::from(match axis {
            Axis::X => triad[0],
            Axis::Y => triad[1],
            Axis::Z => triad[2],
        })
    };
    Some((pick(axes[0]), pick(axes[1])))
}
