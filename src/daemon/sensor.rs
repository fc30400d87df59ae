//! One sensor of the daemon, as a plain state machine: readings in, lines to
//! publish and calibrations to store out. No I/O, no clock: the time of a
//! reading is the time the source stamped on it, so a replay publishes
//! exactly what the live daemon would have.

use std::sync::Arc;
use std::time::Instant;

use super::acceptance::{self, Limits};
use super::config::{Axis, Field, GyroChoice, SensorConfig};
use super::messages::{
    CalibrationMessage, ColumnValues, HeadingVsGyro, ReadingMessage, SensorState, SensorStatus,
    to_line,
};
use super::publish::Lane;
use super::{Calibration, Terms};
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::model::diagnose::diagnose;
use crate::model::effects::{Effect, parse_list};
use crate::model::fit::{FitOptions, FitReport, Solver, fit_paper};
use crate::model::gyro::{GyroUnits, HeadingReference};
use crate::model::heading::coverage;
use crate::model::nonlinear::{cubic_scale, fit_model, turn_frame};
use crate::model::rotation::{RotationBuffer, RotationEvent};
use crate::model::turn::check_turn;
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
    /// The gyro rate kept beside the rotation, for its heading check.
    gyro: Option<GyroTrack>,
    /// A sensor of a csv source: its columns, resolved once against the
    /// file's header by [`Sensor::bind_csv`].
    csv: Option<CsvBinding>,
    /// A 3-axis sensor (`axes = ["x", "y", "z"]`): every call goes to it.
    three: Option<Box<super::sensor3::Sensor3>>,
}

/// Where a csv sensor's values are in each row: indices into
/// [`CsvRow::values`], resolved once, never looked up by name per row.
#[derive(Debug, Clone)]
struct CsvBinding {
    /// The file of its source the columns are in ([`CsvRow::file`]).
    file: usize,
    layout: Arc<CsvLayout>,
    axes: [usize; 2],
    gyro: Option<usize>,
    /// The other columns, published with each reading.
    others: Vec<usize>,
}

/// The angular rate about the turn's axis, in degrees/second, with its
/// times, kept while the sensor collects a rotation: one push per reading;
/// integrated and compared once per rotation.
#[derive(Debug, Clone)]
struct GyroTrack {
    stream: u8,
    /// Index of the axis in the reading's gyro triad.
    axis: usize,
    lsb_per_deg_s: f64,
    /// `gyro_x`, `gyro_y` or `gyro_z`, as the messages name it.
    column: String,
    t: Vec<f64>,
    rate: Vec<f64>,
    /// Most entries held: the older half is dropped when full, so memory
    /// stays bounded however long the sensor collects.
    cap: usize,
    /// The rate integrated (trapezoids) over every reading kept, in
    /// degrees from an arbitrary origin: the rotation buffer takes its
    /// change since a rotation's first sample.
    angle_deg: f64,
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
        })
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
    fn check(&self, t: &[f64], headings_rad: &[f64]) -> Result<HeadingVsGyro, String> {
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
        Ok(HeadingVsGyro::from(&check))
    }
}

impl Sensor {
    /// A sensor starting from the calibration stored for it, if any: it
    /// corrects at once and collects no rotation until asked to.
    pub fn new(config: SensorConfig, stored: Option<Calibration>) -> Self {
        let three = config
            .three
            .clone()
            .map(|t| Box::new(super::sensor3::Sensor3::new(&config, t, stored.clone())));
        // A 2-axis sensor never starts from a 3-D calibration (its axes
        // were changed from three to two), nor a 3-axis one from a 2-D one.
        let stored = stored.filter(|c| c.ellipsoid.is_none() || three.is_some());
        let limits = config.limits.clone();
        let buffer = RotationBuffer::new(config.rotation.clone());
        let gyro = GyroTrack::new(&config.gyro, buffer.config().max_samples);
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
            gyro,
            csv: None,
            three,
        }
    }

    /// The 3-axis sensor this is, if it is one.
    pub fn three(&self) -> Option<&super::sensor3::Sensor3> {
        self.three.as_deref()
    }

    /// The 3-axis sensor this is, if it is one.
    pub fn three_mut(&mut self) -> Option<&mut super::sensor3::Sensor3> {
        self.three.as_deref_mut()
    }

    /// The `CALIBRATION` line of the calibration loaded from the state
    /// directory, if any.
    pub fn loaded_line(&self) -> Option<String> {
        match &self.three {
            Some(three) => three.loaded_line(),
            None => self.current.as_ref().map(|c| {
                to_line(&CalibrationMessage::loaded(c).with_north(self.config.north.as_ref()))
            }),
        }
    }

    /// Resolves a csv sensor's columns against the headers of the files
    /// its source plays (`files[k]` has `layouts[k]`; one file, or several
    /// on one clock), once before the first row: all its columns must be in
    /// one file. Returns the (file, column) pairs it needs a number in, for
    /// the source to skip rows without. A sensor of another source needs
    /// none.
    pub fn bind_csv(
        &mut self,
        layouts: &[Arc<CsvLayout>],
        files: &[std::path::PathBuf],
    ) -> Result<Vec<(usize, usize)>, CsvError> {
        let refs: Vec<&CsvLayout> = layouts.iter().map(Arc::as_ref).collect();
        if let Some(three) = &mut self.three {
            return three.bind_csv(files, &refs);
        }
        let Some(columns) = &self.config.columns else {
            return Ok(Vec::new());
        };
        let mut names = vec![
            (columns[0].as_str(), "the sensor's x axis"),
            (columns[1].as_str(), "the sensor's y axis"),
        ];
        if let GyroChoice::Column { name, .. } = &self.config.gyro {
            names.push((name.as_str(), "the sensor's gyro"));
        }
        let (file, found) = crate::source::csv::locate_columns(files, &refs, &names)?;
        let Some(layout) = layouts.get(file) else {
            return Ok(Vec::new());
        };
        let axes = [found[0], found[1]];
        let gyro = found.get(2).copied();
        let others = (0..layout.names.len())
            .filter(|i| !axes.contains(i) && Some(*i) != layout.time_index())
            .collect();
        let required = found.iter().map(|&i| (file, i)).collect();
        self.csv = Some(CsvBinding {
            file,
            layout: layout.clone(),
            axes,
            gyro,
            others,
        });
        Ok(required)
    }

    /// Handles one row of the sensor's csv source, as
    /// [`Sensor::on_reading`] a reading: the row's other columns travel
    /// with the published reading. A sensor not bound to a csv source, a
    /// row of another file of the source, or a row without numbers in its
    /// axes, is ignored.
    pub fn on_row(&mut self, row: &CsvRow, emit: &mut Emit<'_>) -> Option<Calibration> {
        if let Some(three) = &mut self.three {
            return three.on_row(row, emit);
        }
        let binding = self.csv.as_ref()?;
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
        if self.state != SensorState::Calibrated
            && let (Some(gyro), Some(i)) = (&mut self.gyro, binding.gyro)
            && let Some(&rate) = row.values.get(i)
        {
            gyro.keep_value(row.time, rate);
        }
        self.readings += 1;
        let columns = ColumnValues {
            names: &binding.layout.names,
            indices: &binding.others,
            values: &row.values,
        };
        let line = self.reading_line(row.time, x, y, Some(columns));
        emit(Lane::Reading, line);
        self.collect(row.time, x, y, emit)
    }

    /// Takes over what `old` (the same sensor under the settings before a
    /// reload) had earned: its calibration, which keeps correcting (and
    /// keeps naming its own model) until one under the new settings is
    /// accepted, the next id, and its counts. The rotation starts afresh
    /// under the new settings, so a sensor built by [`Sensor::new`] with
    /// the new section (and bound to its csv file) collects at once.
    pub fn carry_over(&mut self, old: Sensor) {
        if let (Some(three), Some(old_three)) = (&mut self.three, old.three) {
            three.carry_over(*old_three);
            return;
        }
        self.current = old.current;
        self.next_id = self.next_id.max(old.next_id);
        self.readings = old.readings;
        self.fits_accepted = old.fits_accepted;
        self.fits_rejected = old.fits_rejected;
        self.last_rejection = old.last_rejection;
        self.recalibrate();
    }

    pub fn name(&self) -> &str {
        &self.config.name
    }

    /// Takes a new true north (a reload that changed only
    /// `declination_deg` or the location): the calibration and the
    /// rotation being collected are kept.
    pub fn set_north(&mut self, north: Option<super::north::North>) {
        if let Some(three) = &mut self.three {
            three.set_north(north.clone());
        }
        self.config.north = north;
    }

    pub fn config(&self) -> &SensorConfig {
        &self.config
    }

    pub fn calibration(&self) -> Option<&Calibration> {
        if let Some(three) = &self.three {
            return three.calibration();
        }
        self.current.as_ref()
    }

    /// Whether a reading from `stream` of the sensor's source belongs to it
    /// (its own stream, or the stream of the gyro its heading is checked by).
    pub fn wants(&self, stream: u8) -> bool {
        if let Some(three) = &self.three {
            return three.wants(stream);
        }
        self.config.stream == stream || self.gyro.as_ref().is_some_and(|g| g.stream == stream)
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
        if let Some(three) = &mut self.three {
            three.recalibrate();
            return;
        }
        self.buffer.reset();
        if let Some(gyro) = &mut self.gyro {
            gyro.clear();
        }
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
        if let Some(three) = &mut self.three {
            return three.on_reading(reading, emit);
        }
        if self.state != SensorState::Calibrated
            && let Some(gyro) = &mut self.gyro
        {
            gyro.keep(reading);
        }
        if reading.stream != self.config.stream {
            // Only the gyro of another chip: kept above, nothing to publish.
            return None;
        }
        let (x, y) = self.axes_of(reading)?;
        self.readings += 1;
        emit(Lane::Reading, self.reading_line(reading.time, x, y, None));
        self.collect(reading.time, x, y, emit)
    }

    /// Feeds a published sample to the rotation buffer while collecting,
    /// and fits when the rotation is complete.
    fn collect(&mut self, time: f64, x: f64, y: f64, emit: &mut Emit<'_>) -> Option<Calibration> {
        if self.state == SensorState::Calibrated {
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
                self.reject(time, reason, 0, 0.0, 0.0, emit);
                None
            }
            RotationEvent::Complete => self.fit(time, emit),
        }
    }

    fn reading_line(&self, time: f64, x: f64, y: f64, columns: Option<ColumnValues<'_>>) -> String {
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
            true_heading_deg: corrected
                .zip(self.config.north.as_ref())
                .map(|(c, n)| n.true_heading(c.2)),
            calibration: corrected.map(|c| c.0),
            calibrated: corrected.is_some(),
            columns: columns.filter(|c| !c.is_empty()),
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
        emit(Lane::Control, to_line(&message));
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
        self.next_id += 1;
        self.fits_accepted += 1;
        self.state = SensorState::Calibrated;
        self.current = Some(calibration.clone());
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
    ) -> Result<HeadingVsGyro, String> {
        let Some(gyro) = &mut self.gyro else {
            return Err(match &self.config.gyro {
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
            heading_vs_gyro: None,
            heading_check: None,
            declination_deg: None,
            declination_source: None,
            declination_uncertainty_deg: None,
        }
        .with_north(self.config.north.as_ref())
    }

    fn note_rejection(&mut self, reason: String) {
        tracing::warn!(sensor = %self.config.name, "calibration rejected: {reason}");
        self.fits_rejected += 1;
        self.last_rejection = Some(reason);
        // Collect again; the previous calibration (if any) keeps correcting.
    }

    pub fn status(&self) -> SensorStatus<'_> {
        if let Some(three) = &self.three {
            let (readings, fits_accepted, fits_rejected, last_rejection) = three.counts();
            return SensorStatus {
                sensor: &self.config.name,
                source: &self.config.source,
                state: three.state(),
                rotation: None,
                sphere: three.progress(),
                calibration: three.calibration().map(|c| c.id),
                headings_stale: (three.tilt_sensor().is_some()).then(|| three.headings_stale()),
                readings,
                fits_accepted,
                fits_rejected,
                last_rejection,
            };
        }
        SensorStatus {
            sensor: &self.config.name,
            source: &self.config.source,
            state: self.state,
            rotation: (self.state != SensorState::Calibrated).then(|| self.buffer.progress()),
            sphere: None,
            calibration: self.current.as_ref().map(|c| c.id),
            headings_stale: None,
            readings: self.readings,
            fits_accepted: self.fits_accepted,
            fits_rejected: self.fits_rejected,
            last_rejection: self.last_rejection.as_deref(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn falcon_sensor(extra: &str) -> Sensor {
        let text = format!(
            "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
             [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n{extra}"
        );
        let config = crate::daemon::config::parse(&text, std::path::Path::new("t.toml")).unwrap();
        Sensor::new(config.sensors[0].clone(), None)
    }

    fn reading(time: f64, mag: [i16; 2], rate_z: i16) -> Reading {
        Reading {
            time,
            mag: Some([mag[0], mag[1], 0]),
            gyro: Some([7, -7, rate_z]),
            ..Reading::default()
        }
    }

    #[test]
    fn the_gyro_track_stays_bounded_and_keeps_the_rate_in_deg_per_s() {
        let mut sensor = falcon_sensor("[sensor.rotation]\nmax_samples = 200\n");
        // A sensor that never turns, for far longer than a rotation may take.
        for i in 0..20_000 {
            let r = reading(f64::from(i) * 0.05, [100 + (i % 3) as i16, 50], 360);
            sensor.on_reading(&r, &mut |_, _| {});
            let track = sensor.gyro.as_ref().unwrap();
            assert!(track.t.len() <= 400, "{} held at {i}", track.t.len());
            assert_eq!(track.t.len(), track.rate.len());
        }
        let track = sensor.gyro.as_ref().unwrap();
        // The last rejection (not turning, every 10 s = 200 readings) let go
        // of the rates before it: the track holds the current try's.
        assert!(track.t.len() <= 201, "{}", track.t.len());
        // 360 counts at the frame's 10 counts per deg/s, about z.
        assert!(track.rate.iter().all(|&r| r == 36.0));
        // A repeated or earlier time is left out; another stream's too.
        let last = *track.t.last().unwrap();
        let n = track.t.len();
        sensor.on_reading(&reading(last, [0, 0], 1), &mut |_, _| {});
        sensor.on_reading(&reading(last - 1.0, [0, 0], 1), &mut |_, _| {});
        let other = Reading {
            stream: 1,
            ..reading(last + 1.0, [0, 0], 1)
        };
        sensor.on_reading(&other, &mut |_, _| {});
        assert_eq!(sensor.gyro.as_ref().unwrap().t.len(), n);
        // Recalibrating starts afresh.
        sensor.recalibrate();
        assert!(sensor.gyro.as_ref().unwrap().t.is_empty());
    }

    /// One turn of the magnetometer in 10 s at 20 Hz, with the frame's gyro
    /// reading `rate_z` counts (10 per deg/s); whether a CALIBRATION came.
    fn turn_with_gyro(sensor: &mut Sensor, rate_z: i16) -> Vec<String> {
        let mut lines = Vec::new();
        for i in 0..=200 {
            let t = f64::from(i) * 0.05;
            let h = (36.0 * t).to_radians();
            let mag = [
                (300.0 + 1000.0 * h.cos()).round() as i16,
                (-200.0 + 1000.0 * h.sin()).round() as i16,
            ];
            sensor.on_reading(&reading(t, mag, rate_z), &mut |_, line| {
                if line.contains("\"CALIBRATION\"") {
                    lines.push(line);
                }
            });
        }
        lines
    }

    #[test]
    fn the_gyro_angle_reaches_the_rotation_buffer() {
        let used = "[sensor.rotation]\nuse_gyro = true\n";
        // A gyro that agrees (36 deg/s): the turn completes and is fitted.
        let mut sensor = falcon_sensor(used);
        let lines = turn_with_gyro(&mut sensor, 360);
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(lines[0].contains("\"accepted\":true"), "{lines:?}");
        // A gyro that saw no turn (a magnet carried round a still sensor):
        // the readings alone would complete, the gyro holds it back.
        let mut sensor = falcon_sensor(used);
        assert!(turn_with_gyro(&mut sensor, 0).is_empty());
        let progress = sensor.status().rotation.unwrap();
        assert!(progress.turned_deg > 350.0, "{progress:?}");
        assert_eq!(progress.gyro_turned_deg, Some(0.0));
        // Unless the configuration leaves it out, as by default.
        let mut sensor = falcon_sensor("");
        assert_eq!(turn_with_gyro(&mut sensor, 0).len(), 1);
    }

    #[test]
    fn without_a_gyro_nothing_is_kept() {
        let sensor = falcon_sensor("gyro = \"none\"\n");
        assert!(sensor.gyro.is_none());
        assert!(!sensor.wants(1));
        assert!(sensor.wants(0));
    }
}
