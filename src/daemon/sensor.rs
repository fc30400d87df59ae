//! One sensor of the daemon, as a plain state machine: readings in, lines to
//! publish and calibrations to store out. No I/O, no clock: the time of a
//! reading is the time the source stamped on it, so a replay publishes
//! exactly what the live daemon would have.

use std::time::Instant;

use super::acceptance::{self, Limits};
use super::config::{Axis, Field, SensorConfig};
use super::messages::{CalibrationMessage, ReadingMessage, SensorState, SensorStatus, to_line};
use super::publish::Lane;
use super::rotation::{RotationBuffer, RotationEvent};
use super::{Calibration, Terms};
use crate::model::diagnose::diagnose;
use crate::model::effects::{Effect, parse_list};
use crate::model::fit::{FitOptions, FitReport, Solver, fit_paper};
use crate::model::heading::coverage;
use crate::model::nonlinear::{cubic_scale, fit_model};
use crate::sample::Dataset;
use crate::sample::Reading;

/// A line to publish, on its lane.
pub type Emit<'a> = dyn FnMut(Lane, String) + 'a;

pub struct Sensor {
    config: SensorConfig,
    effects: Vec<Effect>,
    limits: Limits,
    model: String,
    buffer: RotationBuffer,
    state: SensorState,
    current: Option<Calibration>,
    next_id: u64,
    readings: u64,
    fits_accepted: u64,
    fits_rejected: u64,
    last_rejection: Option<String>,
}

impl Sensor {
    /// A sensor starting from the calibration stored for it, if any: it
    /// corrects at once and collects no rotation until asked to.
    pub fn new(config: SensorConfig, stored: Option<Calibration>) -> Self {
        let limits = config.limits.clone();
        let buffer = RotationBuffer::new(config.rotation.clone());
        // The configuration checked the names; an unparsable list (not
        // possible from a checked file) falls back to the paper's model.
        let effects = parse_list(&config.effects.join(","))
            .unwrap_or_else(|_| crate::model::effects::PAPER.to_vec());
        Sensor {
            model: crate::model::effects::model_name(&effects),
            effects,
            state: if stored.is_some() {
                SensorState::Calibrated
            } else {
                SensorState::Collecting
            },
            next_id: stored.as_ref().map_or(1, |c| c.id + 1),
            current: stored,
            config,
            limits,
            buffer,
            readings: 0,
            fits_accepted: 0,
            fits_rejected: 0,
            last_rejection: None,
        }
    }

    pub fn name(&self) -> &str {
        &self.config.name
    }

    pub fn config(&self) -> &SensorConfig {
        &self.config
    }

    pub fn calibration(&self) -> Option<&Calibration> {
        self.current.as_ref()
    }

    /// Whether a reading from `stream` of the sensor's source belongs to it.
    pub fn wants(&self, stream: u8) -> bool {
        self.config.stream == stream
    }

    /// The two turning axes of a reading, if it carries the sensor's field.
    pub fn axes_of(&self, reading: &Reading) -> Option<(f64, f64)> {
        let triad = match self.config.field {
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
        Some((pick(self.config.axes[0]), pick(self.config.axes[1])))
    }

    /// Starts a new rotation; the current calibration keeps correcting
    /// until a new one is accepted.
    pub fn recalibrate(&mut self) {
        self.buffer.reset();
        self.state = if self.current.is_some() {
            SensorState::Recalibrating
        } else {
            SensorState::Collecting
        };
    }

    /// Handles one reading: publishes it (corrected when a calibration
    /// exists), feeds the rotation buffer while collecting, and fits when the
    /// rotation is complete. Returns a newly accepted calibration, to store.
    pub fn on_reading(&mut self, reading: &Reading, emit: &mut Emit<'_>) -> Option<Calibration> {
        let (x, y) = self.axes_of(reading)?;
        self.readings += 1;
        emit(Lane::Reading, self.reading_line(reading.time, x, y));
        if self.state == SensorState::Calibrated {
            return None;
        }
        match self.buffer.push(reading.time, x, y) {
            RotationEvent::Collecting => None,
            RotationEvent::Rejected { reason } => {
                tracing::warn!(sensor = %self.config.name, "{reason}");
                self.reject(reading.time, reason, 0, 0.0, 0.0, emit);
                None
            }
            RotationEvent::Complete => self.fit(reading.time, emit),
        }
    }

    fn reading_line(&self, time: f64, x: f64, y: f64) -> String {
        let corrected = self.current.as_ref().map(|c| {
            let (sx, sy) = c.apply(x, y);
            (c.id, [sx, sy], sy.atan2(sx).to_degrees().rem_euclid(360.0))
        });
        to_line(&ReadingMessage {
            class: "READING",
            sensor: &self.config.name,
            time,
            raw: [x, y],
            corrected: corrected.map(|c| c.1),
            heading_deg: corrected.map(|c| c.2),
            calibration: corrected.map(|c| c.0),
            calibrated: corrected.is_some(),
        })
    }

    fn fit(&mut self, time: f64, emit: &mut Emit<'_>) -> Option<Calibration> {
        let (t, x, y) = self.buffer.take();
        let started = Instant::now();
        let fitted = self.fit_rotation(t, x, y);
        let fit_ms = started.elapsed().as_secs_f64() * 1e3;
        let (report, terms, rotation) = match fitted {
            Ok(found) => found,
            Err((reason, n)) => {
                self.reject(time, format!("no fit: {reason}"), n, 0.0, fit_ms, emit);
                return None;
            }
        };
        // What the rotation's residual says beyond the fit: its noise floor,
        // and an effect the model lacks, so the user beside the robot learns
        // that the configuration should add it.
        let insight = diagnose(&rotation, &self.effects, None).ok();
        let noise_floor = insight.as_ref().map(|d| d.noise_floor.rms);
        let (suggested, close_second) = match insight {
            Some(d) => (
                d.suggested.map(|e| e.to_string()),
                d.close_second.map(|e| e.to_string()),
            ),
            None => (None, None),
        };
        if let Err(reason) = acceptance::check(&report, &self.limits) {
            // A fit outside the limits is published with its numbers, so the
            // user sees how far off it was.
            let message = CalibrationMessage {
                params: Some(report.calibration),
                rms: Some(report.rms),
                terms: (!terms.is_none()).then_some(terms),
                noise_floor,
                suggested,
                close_second,
                ..self.rejection(time, &reason, report.n, report.coverage.covered_deg, fit_ms)
            };
            emit(Lane::Control, to_line(&message));
            self.note_rejection(reason);
            return None;
        }
        let calibration = Calibration {
            sensor: self.config.name.clone(),
            id: self.next_id,
            model: self.model.clone(),
            params: report.calibration,
            rms: report.rms,
            coverage_deg: report.coverage.covered_deg,
            n: report.n,
            time,
            terms,
        };
        let message = CalibrationMessage {
            fit_ms,
            origin: "rotation",
            noise_floor,
            suggested,
            close_second,
            ..CalibrationMessage::loaded(&calibration)
        };
        emit(Lane::Control, to_line(&message));
        tracing::info!(
            sensor = %self.config.name,
            id = calibration.id,
            rms = calibration.rms,
            "calibration accepted"
        );
        self.next_id += 1;
        self.fits_accepted += 1;
        self.state = SensorState::Calibrated;
        self.current = Some(calibration.clone());
        Some(calibration)
    }

    /// Fits the rotation with the sensor's model: the paper's closed form,
    /// or the general model when the configuration adds effects. Returns
    /// the report the acceptance limits judge, the extra terms, and the
    /// rotation as a recording (for the diagnosis).
    fn fit_rotation(
        &self,
        t: Vec<f64>,
        x: Vec<f64>,
        y: Vec<f64>,
    ) -> Result<(FitReport, Terms, Dataset), (String, usize)> {
        let n = x.len();
        let rotation =
            Dataset::new("x", "y", Some(t), x, y, Vec::new()).map_err(|e| (e.to_string(), n))?;
        let options = FitOptions {
            min_coverage_deg: self.limits.min_coverage_deg,
            ..FitOptions::default()
        };
        if self.effects.iter().all(Effect::is_paper) {
            let report = fit_paper(&rotation.x, &rotation.y, &options, &mut |_| {})
                .map_err(|e| (e.to_string(), n))?;
            return Ok((report, Terms::default(), rotation));
        }
        let started = Instant::now();
        let fit = fit_model(&rotation, &self.effects).map_err(|e| (e.to_string(), n))?;
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
        };
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
        Ok((report, terms, rotation))
    }

    fn reject(
        &mut self,
        time: f64,
        reason: String,
        n: usize,
        coverage_deg: f64,
        fit_ms: f64,
        emit: &mut Emit<'_>,
    ) {
        let message = self.rejection(time, &reason, n, coverage_deg, fit_ms);
        emit(Lane::Control, to_line(&message));
        self.note_rejection(reason);
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
            class: "CALIBRATION",
            sensor: &self.config.name,
            accepted: false,
            id: None,
            reason: Some(reason.to_string()),
            model: &self.model,
            params: None,
            rms: None,
            coverage_deg,
            n,
            fit_ms,
            time,
            origin: "rotation",
            terms: None,
            noise_floor: None,
            suggested: None,
            close_second: None,
        }
    }

    fn note_rejection(&mut self, reason: String) {
        tracing::warn!(sensor = %self.config.name, "calibration rejected: {reason}");
        self.fits_rejected += 1;
        self.last_rejection = Some(reason);
        // Collect again; the previous calibration (if any) keeps correcting.
    }

    pub fn status(&self) -> SensorStatus<'_> {
        SensorStatus {
            sensor: &self.config.name,
            source: &self.config.source,
            state: self.state,
            rotation: (self.state != SensorState::Calibrated).then(|| self.buffer.progress()),
            calibration: self.current.as_ref().map(|c| c.id),
            readings: self.readings,
            fits_accepted: self.fits_accepted,
            fits_rejected: self.fits_rejected,
            last_rejection: self.last_rejection.as_deref(),
        }
    }
}
