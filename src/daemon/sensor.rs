//! One sensor of the daemon, as a plain state machine: readings in, lines to
//! publish and calibrations to store out. No I/O, no clock: the time of a
//! reading is the time the source stamped on it, so a replay publishes
//! exactly what the live daemon would have.
//!
//! A sensor is its [`Lifecycle`] (state, current calibration, ids,
//! counts), held once, and its [`Geometry`]: the plane of a 2-axis sensor
//! ([`Plane`]: a rotation, the paper's model) or the sphere of a 3-axis one
//! ([`Sensor3`]: sphere coverage, an ellipsoid, still poses).

use std::sync::Arc;

use super::Calibration;
use super::config::{SensorConfig, SensorGeometry};
use super::lifecycle::Lifecycle;
use super::messages::{CalibrationEvent, ReadingValues, SensorState, SensorStatus};
use super::north::North;
use super::plane::Plane;
use super::publish::Lane;
use super::sensor3::Sensor3;
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::model::rotation::Progress;
use crate::model::spike::Gated;
use crate::sample::Reading;

/// A line to publish, on its lane.
pub type Emit<'a> = dyn FnMut(Lane, String) + 'a;

/// Where a sensor's output goes: every line to publish, on its lane, and,
/// to whoever watches the fits (the progress board), each `CALIBRATION`'s
/// outcome as a typed [`CalibrationEvent`], just before its line.
pub struct Emitter<'a> {
    lines: &'a mut Emit<'a>,
    fits: Option<&'a mut dyn FnMut(CalibrationEvent)>,
    readings: Option<&'a mut EmitReading<'a>>,
}

/// A 2-axis sensor's READING, as its values, with the sensor's name: its
/// line is written later ([`ReadingValues::message`]).
pub type EmitReading<'a> = dyn FnMut(&str, ReadingValues) + 'a;

impl<'a> Emitter<'a> {
    /// Lines only: nobody watches the fits.
    pub fn new(lines: &'a mut Emit<'a>) -> Self {
        Emitter {
            lines,
            fits: None,
            readings: None,
        }
    }

    /// Lines to `lines`, each fit's outcome to `fits` as well.
    pub fn watched(lines: &'a mut Emit<'a>, fits: &'a mut dyn FnMut(CalibrationEvent)) -> Self {
        Emitter {
            lines,
            fits: Some(fits),
            readings: None,
        }
    }

    /// Lines to `lines`, but a 2-axis sensor's READINGs (without a csv
    /// row's columns) to `readings` as their values, in the same order
    /// with the lines: whoever takes them writes their lines.
    pub fn deferred(lines: &'a mut Emit<'a>, readings: &'a mut EmitReading<'a>) -> Self {
        Emitter {
            lines,
            fits: None,
            readings: Some(readings),
        }
    }

    /// Publishes a line on its lane.
    pub fn line(&mut self, lane: Lane, line: String) {
        (self.lines)(lane, line);
    }

    /// Publishes the READING of sensor `sensor` with `values` on the
    /// reading lane: its line, or its values where they are deferred.
    pub fn reading(&mut self, sensor: &str, values: ReadingValues) {
        match &mut self.readings {
            Some(readings) => readings(sensor, values),
            None => (self.lines)(Lane::Reading, values.message(sensor).to_line()),
        }
    }

    /// Publishes a `CALIBRATION` line on the control lane, after handing
    /// its outcome (made by `event` only when the fits are watched) to the
    /// watcher.
    pub fn calibration(&mut self, event: impl FnOnce() -> Option<CalibrationEvent>, line: String) {
        if let Some(fits) = &mut self.fits
            && let Some(event) = event()
        {
            fits(event);
        }
        (self.lines)(Lane::Control, line);
    }
}

/// Why a stored calibration cannot correct this sensor's readings: the
/// other geometry (its axes changed since), or numbers beyond its
/// acceptance limits ([`crate::model::validity::plane_problem`]; a 3-D
/// one's are checked wherever it is read,
/// [`crate::model::calibration3::Calibration3D::validate`]).
pub(crate) fn stored_problem(config: &SensorConfig, c: &Calibration) -> Option<String> {
    match (&config.geometry, &c.ellipsoid) {
        (SensorGeometry::Plane(_), Some(_)) => Some(format!(
            "it is a 3-axis calibration and sensor '{}' now has 2 axes: calibrate it again by turning it",
            config.name
        )),
        (SensorGeometry::Sphere(_), None) => Some(format!(
            "it is a 2-axis calibration and sensor '{}' now has 3 axes: calibrate it again by tumbling it",
            config.name
        )),
        (SensorGeometry::Plane(plane), None) => crate::model::validity::plane_problem(
            &c.params,
            &c.terms,
            plane.limits.max_scale_ratio,
            plane.limits.max_offset_ratio,
        ),
        (SensorGeometry::Sphere(_), Some(_)) => None,
    }
}

/// One sample of a sensor's own field: the time its source stamped, and
/// its raw axes (x, y, z; a plane's third is its reading across the turn
/// when `out_of_plane` names it, else NaN: it turns in x, y).
///
/// It carries what was beside it when it came, so that a sample the
/// spike gate holds for a few samples is collected with its own context,
/// not a later one's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub time: f64,
    pub raw: [f64; 3],
    /// The tilt accelerometer's latest reading, when it was fresh.
    pub accel: Option<[f64; 3]>,
    /// The gyro's integrated angle, degrees (a plane checked by a gyro).
    pub turned: Option<f64>,
    /// The 3-axis gyro's latest rate, deg/s, when it was fresh (a sphere
    /// with a gyro).
    pub gyro: Option<[f64; 3]>,
}

impl Sample {
    /// A sample at `time` with the accelerometer's `last` reading beside
    /// it, when that is at most
    /// [`MAX_TILT_AGE_S`](super::sensor3::MAX_TILT_AGE_S) from it.
    pub fn beside(time: f64, raw: [f64; 3], last: Option<(f64, [f64; 3])>) -> Self {
        Sample {
            time,
            raw,
            accel: last
                .filter(|(t, _)| (time - t).abs() <= super::sensor3::MAX_TILT_AGE_S)
                .map(|(_, a)| a),
            turned: None,
            gyro: None,
        }
    }
}

/// What a sensor does that depends on its geometry: which readings are
/// its, how a reading is corrected and published, how samples are
/// collected and fitted. The sensor's [`Lifecycle`] is lent to each call.
pub trait Geometry: Send {
    /// Whether a reading from `stream` of the sensor's source belongs to it.
    fn wants(&self, stream: u8) -> bool;
    /// The sensor's own sample in a reading, if it carries one; keeps what
    /// else the reading carries for the geometry (a gyro's rate, an
    /// accelerometer's vertical).
    fn reading_sample(&mut self, life: &Lifecycle, reading: &Reading) -> Option<Sample>;
    /// [`Geometry::reading_sample`] for a row of the sensor's csv source
    /// (unbound, another file's row or no numbers in its axes: none).
    fn row_sample(&mut self, life: &Lifecycle, row: &CsvRow) -> Option<Sample>;
    /// The `READING` line of a sample (corrected when a calibration
    /// exists), with the other columns of its csv row, if any.
    fn reading_line(&mut self, life: &Lifecycle, sample: Sample, row: Option<&CsvRow>) -> String;
    /// Publishes the `READING` of a sample: its line
    /// ([`Geometry::reading_line`]), or (a plane) its values, for the
    /// emitter to write.
    fn emit_reading(
        &mut self,
        life: &Lifecycle,
        sample: Sample,
        row: Option<&CsvRow>,
        emit: &mut Emitter<'_>,
    ) {
        let line = self.reading_line(life, sample, row);
        emit.line(Lane::Reading, line);
    }
    /// Collects a published sample while collecting, and fits when the
    /// samples are complete. Returns a newly accepted calibration, to store.
    fn push(
        &mut self,
        life: &mut Lifecycle,
        sample: Sample,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration>;
    /// Publishes a sample of the sensor's own field and collects it: the
    /// one path every reading and row takes (written once; each geometry's
    /// copy calls its own methods directly).
    ///
    /// A sample passes the spike gate ([`crate::model::spike`]) before it
    /// is collected: a spike is published (a calibrated one is judged by
    /// the trust monitor as any reading is) but never collected nor
    /// fitted. The gate may hold a sample until the few after it show
    /// whether it was one, so a call may collect none, or several.
    fn publish(
        &mut self,
        life: &mut Lifecycle,
        sample: Sample,
        row: Option<&CsvRow>,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        life.readings += 1;
        self.emit_reading(life, sample, row, emit);
        // Nearly every sample is kept at once, and then nothing waits
        // behind it (`SpikeGate::feed_at_once`): collected as it is.
        if let Some(kept) = life.gate.feed_at_once(sample, sample.raw) {
            return self.push(life, kept, emit);
        }
        let mut accepted = None;
        while let Some(gated) = life.gate.decided() {
            match gated {
                Gated::Kept(kept) => {
                    if let Some(c) = self.push(life, kept, emit) {
                        accepted = Some(c);
                    }
                }
                Gated::Refused(refused, spike) => {
                    life.refuse_spike(&refused, &spike, self.axis_name(spike.axis));
                }
            }
        }
        accepted
    }
    /// The name of the sensor's axis `axis` (0, 1, 2) in messages.
    fn axis_name(&self, axis: usize) -> &'static str {
        ["x", "y", "z"].get(axis).copied().unwrap_or("?")
    }
    /// Handles one reading: publishes the sensor's own sample, if it
    /// carries one, and collects it. Returns a newly accepted calibration.
    fn on_reading(
        &mut self,
        life: &mut Lifecycle,
        reading: &Reading,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let sample = self.reading_sample(life, reading)?;
        self.publish(life, sample, None, emit)
    }
    /// [`Geometry::on_reading`] for a row of the sensor's csv source.
    fn on_row(
        &mut self,
        life: &mut Lifecycle,
        row: &CsvRow,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let sample = self.row_sample(life, row)?;
        self.publish(life, sample, Some(row), emit)
    }
    /// Resolves a csv sensor's columns; see [`Sensor::bind_csv`].
    fn bind_csv(
        &mut self,
        layouts: &[Arc<CsvLayout>],
        files: &[std::path::PathBuf],
    ) -> Result<Vec<(usize, usize)>, CsvError>;
    /// Empties the samples collected, to collect anew.
    fn restart(&mut self);
    /// The `CALIBRATION` line of the current calibration as `origin` put
    /// it in place (`state`: loaded from the state directory at start;
    /// `rollback`), if any, with its outcome for the progress board.
    fn loaded_line(
        &self,
        life: &Lifecycle,
        origin: &'static str,
    ) -> Option<(String, Option<CalibrationEvent>)>;
    /// Takes a new true north.
    fn set_north(&mut self, north: Option<North>);
    /// The rotation being collected (a plane).
    fn rotation(&self) -> Option<Progress> {
        None
    }
    /// The sphere being collected (when `collecting`), and the headings
    /// left out for a stale tilt source when it has one (a sphere).
    fn sphere(&self, _collecting: bool) -> (Option<super::sensor3::SphereProgress>, Option<u64>) {
        (None, None)
    }
    /// Readings trusted and distrusted under the current calibration,
    /// where the geometry judges them.
    fn trust(&self) -> Option<crate::model::trust::TrustCounts> {
        None
    }
    /// Why the latest calibrated reading was distrusted, if it was.
    fn distrust_now(&self) -> Option<&str> {
        None
    }
    /// The sphere this is, if it is one.
    fn as_sphere(&self) -> Option<&Sensor3> {
        None
    }
    /// The sphere this is, if it is one.
    fn as_sphere_mut(&mut self) -> Option<&mut Sensor3> {
        None
    }
    /// The plane this is, if it is one.
    fn as_plane(&self) -> Option<&Plane> {
        None
    }
}

/// One sensor: its configuration, its lifecycle and its geometry.
pub struct Sensor {
    config: SensorConfig,
    life: Lifecycle,
    geometry: Box<dyn Geometry>,
}

impl Sensor {
    /// A sensor starting from the calibration stored for it, if any: it
    /// corrects at once and collects no rotation until asked to.
    pub fn new(config: SensorConfig, stored: Option<Calibration>) -> Self {
        // A 2-axis sensor never starts from a 3-D calibration (its axes
        // were changed from three to two), nor a 3-axis one from a 2-D one.
        let (geometry, stored): (Box<dyn Geometry>, _) = match &config.geometry {
            SensorGeometry::Sphere(three) => (
                Box::new(Sensor3::new(&config, three.clone())),
                stored.filter(|c| c.ellipsoid.is_some()),
            ),
            SensorGeometry::Plane(plane) => (
                Box::new(Plane::new(config.clone(), plane.clone())),
                stored.filter(|c| c.ellipsoid.is_none()),
            ),
        };
        Sensor {
            config,
            life: Lifecycle::new(stored),
            geometry,
        }
    }

    /// The 3-axis sensor this is, if it is one.
    pub fn three(&self) -> Option<&Sensor3> {
        self.geometry.as_sphere()
    }

    /// The 3-axis sensor this is, if it is one.
    pub fn three_mut(&mut self) -> Option<&mut Sensor3> {
        self.geometry.as_sphere_mut()
    }

    /// The `CALIBRATION` line of the calibration loaded from the state
    /// directory, if any.
    pub fn loaded_line(&self) -> Option<String> {
        self.loaded_calibration().map(|(line, _)| line)
    }

    /// [`Sensor::loaded_line`], with its outcome for the progress board.
    pub fn loaded_calibration(&self) -> Option<(String, Option<CalibrationEvent>)> {
        self.geometry.loaded_line(&self.life, "state")
    }

    /// Returns to the calibration before the current one: its `CALIBRATION`
    /// line (`origin` `rollback`) with its outcome for the progress board,
    /// and the calibration to store; Err says why there is none.
    pub fn rollback(&mut self) -> Result<(String, Option<CalibrationEvent>, Calibration), String> {
        self.life
            .rollback()
            .map_err(|why| format!("sensor '{}' cannot roll back: {why}", self.config.name))?;
        // What was collected under the calibration rolled back from is
        // not watched against the one rolled back to.
        self.geometry.restart();
        let (line, event) = self
            .geometry
            .loaded_line(&self.life, "rollback")
            .ok_or_else(|| format!("sensor '{}' has no calibration", self.config.name))?;
        let calibration = self
            .life
            .current
            .clone()
            .ok_or_else(|| format!("sensor '{}' has no calibration", self.config.name))?;
        Ok((line, event, calibration))
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
        self.geometry.bind_csv(layouts, files)
    }

    /// Handles one row of the sensor's csv source, as
    /// [`Sensor::on_reading`] a reading: the row's other columns travel
    /// with the published reading. A sensor not bound to a csv source, a
    /// row of another file of the source, or a row without numbers in its
    /// axes, is ignored.
    pub fn on_row(&mut self, row: &CsvRow, emit: &mut Emit<'_>) -> Option<Calibration> {
        self.on_row_to(row, &mut Emitter::new(emit)).map(|c| *c)
    }

    /// [`Sensor::on_row`], its output to an [`Emitter`]; the calibration
    /// accepted comes boxed (see [`Sensor::on_reading_to`]).
    pub fn on_row_to(&mut self, row: &CsvRow, out: &mut Emitter<'_>) -> Option<Box<Calibration>> {
        let accepted = self.geometry.on_row(&mut self.life, row, out).map(Box::new);
        self.log_spike();
        accepted
    }

    /// Logs the spike the gate just refused, when one is due.
    fn log_spike(&mut self) {
        if let Some(sentence) = self.life.take_spike_log() {
            tracing::warn!(sensor = %self.config.name, "{}: {sentence}", self.config.name);
        }
    }

    /// Takes over what `old` (the same sensor under the settings before a
    /// reload) had earned: its calibration, which keeps correcting (and
    /// keeps naming its own model) until one under the new settings is
    /// accepted, the next id, and its counts. The rotation starts afresh
    /// under the new settings, so a sensor built by [`Sensor::new`] with
    /// the new section (and bound to its csv file) collects at once. A
    /// sensor whose axes went from two to three, or back, takes over its
    /// next id and counts alone: a calibration of one geometry never
    /// corrects the other.
    pub fn carry_over(&mut self, old: Sensor) {
        match (self.geometry.as_sphere_mut(), old.geometry.as_sphere()) {
            (Some(three), Some(old_three)) => three.carry_over(old_three),
            (None, None) => {}
            _ => {
                self.life.carry_counts(&old.life);
                self.recalibrate();
                return;
            }
        }
        self.life.carry_over(old.life);
        self.geometry.restart();
    }

    pub fn name(&self) -> &str {
        &self.config.name
    }

    /// Takes a new true north (a reload that changed only
    /// `declination_deg` or the location): the calibration and the
    /// rotation being collected are kept.
    pub fn set_north(&mut self, north: Option<North>) {
        self.geometry.set_north(north.clone());
        self.config.north = north;
    }

    pub fn config(&self) -> &SensorConfig {
        &self.config
    }

    pub fn calibration(&self) -> Option<&Calibration> {
        self.life.current.as_ref()
    }

    /// Whether a reading from `stream` of the sensor's source belongs to it
    /// (its own stream, or the stream of the gyro its heading is checked by,
    /// or of the accelerometer its heading is tilt-compensated with).
    pub fn wants(&self, stream: u8) -> bool {
        self.geometry.wants(stream)
    }

    /// Starts a new rotation; the current calibration keeps correcting
    /// until a new one is accepted.
    pub fn recalibrate(&mut self) {
        self.geometry.restart();
        self.life.restart();
    }

    /// Handles one reading: publishes it (corrected when a calibration
    /// exists), feeds the rotation buffer while collecting, and fits when the
    /// rotation is complete. Returns a newly accepted calibration, to store.
    pub fn on_reading(&mut self, reading: &Reading, emit: &mut Emit<'_>) -> Option<Calibration> {
        self.on_reading_to(reading, &mut Emitter::new(emit))
            .map(|c| *c)
    }

    /// [`Sensor::on_reading`], its output to an [`Emitter`]. The
    /// calibration accepted (at most once a rotation) comes boxed: an
    /// `Option<Calibration>` of some 750 bytes was copied twice on its
    /// way out for every reading, empty or not.
    pub fn on_reading_to(
        &mut self,
        reading: &Reading,
        out: &mut Emitter<'_>,
    ) -> Option<Box<Calibration>> {
        let accepted = self
            .geometry
            .on_reading(&mut self.life, reading, out)
            .map(Box::new);
        self.log_spike();
        accepted
    }

    /// Why the latest calibrated reading was distrusted, if it was.
    pub fn distrust_now(&self) -> Option<&str> {
        self.geometry.distrust_now()
    }

    pub fn status(&self) -> SensorStatus<&str> {
        let collecting = self.life.state != SensorState::Calibrated;
        let (sphere, headings_stale) = self.geometry.sphere(collecting);
        SensorStatus {
            sensor: &self.config.name,
            source: &self.config.source,
            state: self.life.state,
            rotation: collecting.then(|| self.geometry.rotation()).flatten(),
            sphere: collecting.then_some(sphere).flatten(),
            calibration: self.life.current.as_ref().map(|c| c.id),
            headings_stale,
            trust: self.geometry.trust(),
            stale: self.life.stale.as_deref(),
            readings: self.life.readings,
            spikes: self.life.spikes,
            last_spike: self.life.last_spike.as_deref(),
            fits_accepted: self.life.fits_accepted,
            fits_rejected: self.life.fits_rejected,
            last_rejection: self.life.last_rejection.as_deref(),
        }
    }

    /// The gyro track of a 2-axis sensor.
    #[cfg(test)]
    fn gyro(&self) -> Option<&super::plane::GyroTrack> {
        self.geometry.as_plane()?.gyro.as_ref()
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
            let track = sensor.gyro().unwrap();
            assert!(track.t.len() <= 400, "{} held at {i}", track.t.len());
            assert_eq!(track.t.len(), track.rate.len());
        }
        let track = sensor.gyro().unwrap();
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
        assert_eq!(sensor.gyro().unwrap().t.len(), n);
        // Recalibrating starts afresh.
        sensor.recalibrate();
        assert!(sensor.gyro().unwrap().t.is_empty());
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
        assert!(sensor.gyro().is_none());
        assert!(!sensor.wants(1));
        assert!(sensor.wants(0));
    }
}
