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

use std::sync::Arc;
use std::time::Instant;

use super::acceptance::{self, Limits};
use super::config::{Axis, Field, GyroChoice, PlaneConfig, SensorConfig};
use super::lifecycle::Lifecycle;
use super::messages::{
    CalibrationEvent, CalibrationMessage, ColumnValues, ReadingMessage, to_line,
};
use super::sensor::{Emitter, Geometry, Sample};
use super::{Calibration, Terms};
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::model::diagnose::diagnose;
use crate::model::effects::{Effect, parse_list};
use crate::model::fit::{FitOptions, FitReport, Solver, fit_paper};
use crate::model::gyro::HeadingCheck;
use crate::model::gyro::{GyroUnits, HeadingReference};
use crate::model::heading::coverage;
use crate::model::nonlinear::{cubic_scale, fit_model, turn_frame};
use crate::model::rotation::{Progress, RotationBuffer, RotationEvent};
use crate::model::trust::{
    GyroModel, Observation, TrustCounts, TrustLimits, TrustMonitor, monitor_of,
};
use crate::model::turn::check_turn;
use crate::sample::Dataset;
use crate::sample::Reading;

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
    /// The gyro as the accepted calibration's heading check found it, by
    /// the calibration's id, for the trust monitor.
    gyro_model: Option<(u64, GyroModel, f64)>,
    /// Trust at every reading, under the calibration of the id it holds.
    trust: Option<(u64, TrustMonitor)>,
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
    /// The other columns, published with each reading.
    others: Vec<usize>,
}

/// The angular rate about the turn's axis, in degrees/second, with its
/// times, kept while the sensor collects a rotation: one push per reading;
/// integrated and compared once per rotation.
#[derive(Debug, Clone)]
pub(super) struct GyroTrack {
    stream: u8,
    /// Index of the axis in the reading's gyro triad.
    axis: usize,
    lsb_per_deg_s: f64,
    /// `gyro_x`, `gyro_y` or `gyro_z`, as the messages name it.
    column: String,
    pub(super) t: Vec<f64>,
    pub(super) rate: Vec<f64>,
    /// Most entries held: the older half is dropped when full, so memory
    /// stays bounded however long the sensor collects.
    cap: usize,
    /// The rate integrated (trapezoids) over every reading kept, in
    /// degrees from an arbitrary origin: the rotation buffer takes its
    /// change since a rotation's first sample.
    angle_deg: f64,
    /// The latest rate seen, deg/s, for the trust monitor.
    latest: Option<f64>,
}

impl GyroTrack {
    fn new(choice: &GyroChoice, max_samples: usize) -> Option<Self> {
        let (stream, axis, lsb_per_deg_s, column) = match choice {
            GyroChoice::Rate {
                stream,
                axis,
                lsb_per_deg_s,
            } => (
                *stream,
                axis.index(),
                *lsb_per_deg_s,
                format!("gyro_{}", axis.name()),
            ),
            // A column's value in its units: one deg/s is 1 deg/s, or
            // pi/180 rad/s.
            GyroChoice::Column { name, units } => (
                0,
                0,
                match units {
                    GyroUnits::DegPerSecond => 1.0,
                    GyroUnits::RadPerSecond => std::f64::consts::PI / 180.0,
                },
                name.clone(),
            ),
            GyroChoice::Off(_) => return None,
        };
        Some(GyroTrack {
            stream,
            axis,
            lsb_per_deg_s,
            column,
            t: Vec::new(),
            rate: Vec::new(),
            // A rotation holds at most max_samples readings of the sensor;
            // a gyro polled beside it adds as many.
            cap: 2 * max_samples.max(1),
            angle_deg: 0.0,
            latest: None,
        })
    }

    /// The latest rate seen, deg/s, kept or not.
    fn latest_deg_s(&self) -> Option<f64> {
        self.latest
    }

    /// Notes the rate of a reading that carries this gyro, for the trust
    /// monitor, collecting or not.
    fn observe(&mut self, reading: &Reading) {
        if let Some(triad) = reading.gyro.filter(|_| reading.stream == self.stream) {
            self.observe_value(f64::from(triad[self.axis]));
        }
    }

    /// Notes a rate in the gyro's units (counts, or a column's deg/s or
    /// rad/s).
    fn observe_value(&mut self, value: f64) {
        let rate = value / self.lsb_per_deg_s;
        self.latest = rate.is_finite().then_some(rate);
    }

    /// Keeps the rate of a reading that carries this gyro. O(1) amortised.
    fn keep(&mut self, reading: &Reading) {
        let Some(triad) = reading.gyro.filter(|_| reading.stream == self.stream) else {
            return;
        };
        self.keep_value(reading.time, f64::from(triad[self.axis]));
    }

    /// Keeps a rate at `time` in the gyro's units (counts, or a column's
    /// deg/s or rad/s). O(1) amortised.
    fn keep_value(&mut self, time: f64, value: f64) {
        if !value.is_finite() {
            return;
        }
        // The integration needs increasing times; a repeated or earlier
        // time (as the rotation buffer also ignores) is left out.
        if !time.is_finite() || self.t.last().is_some_and(|&last| time <= last) {
            return;
        }
        if self.t.len() >= self.cap {
            let half = self.cap / 2;
            self.t.drain(..half);
            self.rate.drain(..half);
        }
        let rate = value / self.lsb_per_deg_s;
        if let (Some(&t0), Some(&r0)) = (self.t.last(), self.rate.last()) {
            self.angle_deg += (time - t0) * (rate + r0) / 2.0;
        }
        self.t.push(time);
        self.rate.push(rate);
    }

    /// The integrated angle, once a rate has been kept.
    fn angle(&self) -> Option<f64> {
        (!self.t.is_empty()).then_some(self.angle_deg)
    }

    fn clear(&mut self) {
        self.t.clear();
        self.rate.clear();
    }

    /// Drops the rates of a rotation that was given up, keeping the last
    /// one at or before `time` (where the new rotation starts) and after.
    fn forget_before(&mut self, time: f64) {
        let keep_from = self.t.partition_point(|&g| g < time).saturating_sub(1);
        self.t.drain(..keep_from);
        self.rate.drain(..keep_from);
    }

    /// The heading check of a rotation: samples at times `t` whose model
    /// headings are `headings_rad`. Uses the rates from the last one at or
    /// before the rotation's first sample to the first at or after its last.
    fn check(&self, t: &[f64], headings_rad: &[f64]) -> Result<HeadingCheck, String> {
        let (Some(&first), Some(&last)) = (t.first(), t.last()) else {
            return Err("no samples to check".into());
        };
        let lo = self.t.partition_point(|&g| g <= first).saturating_sub(1);
        let hi = (self.t.partition_point(|&g| g < last) + 1).min(self.t.len());
        let (gyro_t, rate) = match (self.t.get(lo..hi), self.rate.get(lo..hi)) {
            (Some(gt), Some(r)) if !gt.is_empty() => (gt, r),
            _ => {
                return Err(format!("no {} readings during the rotation", self.column));
            }
        };
        let reference =
            HeadingReference::from_rates(&self.column, t, gyro_t, rate, GyroUnits::DegPerSecond)
                .map_err(|e| e.to_string())?;
        let check = reference
            .check(headings_rad, &[])
            .map_err(|e| e.to_string())?;
        Ok(check)
    }
}

impl Plane {
    /// The plane of a 2-axis sensor of `config`.
    pub fn new(config: SensorConfig, plane: PlaneConfig) -> Self {
        let limits = plane.limits.clone();
        let buffer = RotationBuffer::new(plane.rotation.clone());
        let gyro = GyroTrack::new(&plane.gyro, buffer.config().max_samples);
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
            gyro_model: None,
            trust: None,
        }
    }

    /// The two turning axes of a reading, if it carries the sensor's field.
    pub fn axes_of(&self, reading: &Reading) -> Option<(f64, f64)> {
        axes_of(self.config.field, self.plane.axes, reading)
    }

    /// Starts a new rotation (the [`Lifecycle`] restarts beside it).
    pub fn recalibrate(&mut self) {
        self.buffer.reset();
        if let Some(gyro) = &mut self.gyro {
            gyro.clear();
        }
    }

    /// The READING line of a sample, calibrated and judged by the trust
    /// monitor when the sensor has a calibration.
    fn line_xy(
        &mut self,
        life: &Lifecycle,
        time: f64,
        [x, y]: [f64; 2],
        row: Option<&CsvRow>,
    ) -> String {
        let corrected = life.current.as_ref().map(|c| {
            let (sx, sy) = c.apply(x, y);
            (c.id, [sx, sy], sy.atan2(sx).to_degrees().rem_euclid(360.0))
        });
        let gyro_deg_s = self.gyro.as_ref().and_then(GyroTrack::latest_deg_s);
        let verdict = life
            .current
            .as_ref()
            .zip(corrected)
            .map(|(c, (_, s, heading))| {
                self.trust_of(c).check(Observation {
                    time,
                    field_ratio: s[0].hypot(s[1]) / c.params.r,
                    heading_deg: heading,
                    gyro_deg_s,
                })
            });
        let columns = row
            .zip(self.csv.as_ref())
            .map(|(row, binding)| ColumnValues {
                names: &binding.layout.names,
                indices: &binding.others,
                values: &row.values,
            });
        to_line(&ReadingMessage {
            class: "READING",
            sensor: &self.config.name,
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
            distrust: verdict
                .as_ref()
                .map(|v| v.reasons.as_slice())
                .filter(|r| !r.is_empty()),
            columns: columns.filter(|c| !c.is_empty()),
        })
    }

    /// The trust monitor of calibration `c`: its limits from the
    /// calibration's rms and, when this run accepted it with a heading
    /// check, the gyro that check found.
    fn trust_of(&mut self, c: &Calibration) -> &mut TrustMonitor {
        let gyro_model = self.gyro_model;
        monitor_of(&mut self.trust, c.id, || {
            let (gyro, heading_rms) = match gyro_model {
                Some((id, gyro, rms)) if id == c.id => (Some(gyro), Some(rms)),
                _ => (None, None),
            };
            TrustLimits::from_rms(c.rms, heading_rms, gyro)
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
        let fitted = self.fit_rotation(t, x, y);
        let fit_ms = started.elapsed().as_secs_f64() * 1e3;
        let (report, terms, rotation) = match fitted {
            Ok(found) => found,
            Err((reason, n)) => {
                self.reject(life, time, format!("no fit: {reason}"), (n, fit_ms), emit);
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
        let heading = self.heading_check(&rotation, &report, &terms);
        let (heading_vs_gyro, heading_check) = match heading {
            Ok(check) => (Some(check), None),
            Err(why) => (None, Some(why)),
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
                heading_vs_gyro,
                heading_check,
                ..self.rejection(time, &reason, report.n, report.coverage.covered_deg, fit_ms)
            };
            emit.calibration(|| message.event(), to_line(&message));
            self.note_rejection(life, reason);
            return None;
        }
        let calibration = Calibration {
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
        };
        let message = CalibrationMessage {
            fit_ms,
            origin: "rotation",
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
        self.gyro_model = message.heading_vs_gyro.as_ref().map(|h| {
            let gyro = GyroModel {
                scale: h.gyro_scale,
                bias_deg_s: h.gyro_bias_deg_s,
            };
            (calibration.id, gyro, h.rms_deg)
        });
        life.accept(calibration.clone());
        Some(calibration)
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
                let (cx, cy) = super::apply(&report.calibration, terms, x, y);
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
        // fit_paper runs the turn gate itself; the general model must too.
        check_turn(&rotation.x, &rotation.y, options.min_coverage_deg)
            .map_err(|e| (e.to_string(), n))?;
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
            ..Terms::default()
        };
        let terms = if self.effects.contains(&Effect::CubicCentred) {
            // The frame the fit held fixed; the fit above succeeded, so the
            // same starting point does.
            let frame = turn_frame(&rotation).map_err(|e| (e.to_string(), n))?;
            Terms {
                kc: [fit.value("kc"); 2],
                centre: frame.centre,
                turn_radius: frame.radius,
                ..terms
            }
        } else {
            terms
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

impl Geometry for Plane {
    fn trust(&self) -> Option<TrustCounts> {
        self.trust.as_ref().map(|(_, m)| m.counts())
    }
    fn distrust_now(&self) -> Option<&str> {
        self.trust.as_ref().and_then(|(_, m)| m.distrust_now())
    }
    fn row_sample(&mut self, life: &Lifecycle, row: &CsvRow) -> Option<Sample> {
        let binding = self.csv.as_ref()?;
        if let (Some(gyro), Some((file, i))) = (&mut self.gyro, binding.gyro)
            && row.file == file
            && let Some(&rate) = row.values.get(i)
        {
            gyro.observe_value(rate);
            if life.collecting() {
                gyro.keep_value(row.time, rate);
            }
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
        Some(Sample {
            time: row.time,
            raw: [x, y, 0.0],
        })
    }
    fn reading_sample(&mut self, life: &Lifecycle, reading: &Reading) -> Option<Sample> {
        if let Some(gyro) = &mut self.gyro {
            gyro.observe(reading);
            if life.collecting() {
                gyro.keep(reading);
            }
        }
        if reading.stream != self.config.stream {
            // Only the gyro of another chip: kept above, nothing to publish.
            return None;
        }
        let (x, y) = self.axes_of(reading)?;
        Some(Sample {
            time: reading.time,
            raw: [x, y, 0.0],
        })
    }
    fn reading_line(&mut self, life: &Lifecycle, sample: Sample, row: Option<&CsvRow>) -> String {
        let [x, y, _] = sample.raw;
        self.line_xy(life, sample.time, [x, y], row)
    }
    fn push(
        &mut self,
        life: &mut Lifecycle,
        sample: Sample,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let (time, [x, y, _]) = (sample.time, sample.raw);
        if !life.collecting() {
            return None;
        }
        // The gyro's integrated angle lets the buffer check the turn.
        let turned = self.gyro.as_ref().and_then(GyroTrack::angle);
        match self.buffer.push_turned(time, x, y, turned) {
            RotationEvent::Collecting => None,
            RotationEvent::Rejected { reason } => {
                if let Some(gyro) = &mut self.gyro {
                    gyro.forget_before(time);
                }
                tracing::warn!(sensor = %self.config.name, "{reason}");
                self.reject(life, time, reason, (0, 0.0), emit);
                None
            }
            RotationEvent::Complete => self.fit(life, time, emit),
        }
    }
    fn loaded_line(&self, life: &Lifecycle) -> Option<(String, Option<CalibrationEvent>)> {
        life.current.as_ref().map(|c| {
            let message = CalibrationMessage::loaded(c).with_north(self.config.north.as_ref());
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
        let names = [
            (columns[0].as_str(), "the sensor's x axis"),
            (columns[1].as_str(), "the sensor's y axis"),
        ];
        let (file, found) = crate::source::csv::locate_columns(files, &refs, &names)?;
        let Some(layout) = layouts.get(file) else {
            return Ok(Vec::new());
        };
        let axes = [found[0], found[1]];
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
        let others = (0..layout.names.len())
            .filter(|i| !axes.contains(i) && Some(*i) != layout.time_index())
            .collect();
        let mut required: Vec<(usize, usize)> = axes.iter().map(|&i| (file, i)).collect();
        required.extend(gyro);
        self.csv = Some(CsvBinding {
            file,
            layout: layout.clone(),
            axes,
            gyro,
            others,
        });
        Ok(required)
    }
    fn set_north(&mut self, north: Option<super::north::North>) {
        self.config.north = north;
    }
    fn wants(&self, stream: u8) -> bool {
        self.config.stream == stream || self.gyro.as_ref().is_some_and(|g| g.stream == stream)
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
