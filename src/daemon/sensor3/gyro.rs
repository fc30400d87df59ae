//! A 3-axis compass's gyro (`gyro`: its tilt accelerometer's chip's, or
//! three columns of a csv source): its latest rate, and its readings kept
//! beside the sphere being collected, so that an accepted calibration fits
//! the gyro's scale and bias against the tilt-compensated heading over the
//! same samples ([`crate::model::gyro3`]) and the trust monitor checks each
//! later heading's change against it.

use super::*;
use crate::daemon::beside::Beside;
use crate::daemon::config::Gyro3Choice;
use crate::model::calibration::GyroFit;
use crate::model::gyro3::{GyroSample, fit_gyro3, heading_rate};

impl Sensor3 {
    /// A sample of the sphere at `time`, with the accelerometer and the
    /// gyro's rate beside it now.
    pub(super) fn sample_at(&self, time: f64, raw: [f64; 3]) -> Sample {
        Sample {
            gyro: self.gyro.as_ref().and_then(|g| g.fresh(time)),
            ..Sample::beside(time, raw, self.last_accel)
        }
    }
}

/// The gyro of a 3-axis compass.
#[derive(Debug, Clone)]
pub(super) struct Gyro3Track {
    choice: Gyro3Choice,
    /// A csv compass's columns: (file, indices), once bound.
    csv: Option<(usize, [usize; 3])>,
    /// The latest rate, deg/s, in the accelerometer's axes, with its time.
    last: Option<(f64, [f64; 3])>,
    /// Each sample of the sphere: the raw field, the raw accelerometer
    /// reading and the gyro beside it.
    kept: Beside<[[f64; 3]; 3]>,
    /// The gyro and the `mag_axes` in words ([`Gyro3Choice::describe`]):
    /// a fit made under others is not used.
    source: String,
}

/// The roles of a csv compass's gyro columns, for messages.
const GYRO_ROLES: [&str; 3] = [
    "the gyro's rate about the accelerometer's x",
    "the gyro's rate about the accelerometer's y",
    "the gyro's rate about the accelerometer's z",
];

impl Gyro3Track {
    /// The track of a configured gyro (none for [`Gyro3Choice::Off`] or
    /// one left unresolved) of a compass read under `mag_axes`, holding at
    /// most `cap` samples.
    pub(super) fn new(choice: &Gyro3Choice, mag_axes: AxisMap, cap: usize) -> Option<Self> {
        matches!(
            choice,
            Gyro3Choice::Chip { .. } | Gyro3Choice::Columns { .. }
        )
        .then(|| Gyro3Track {
            choice: choice.clone(),
            csv: None,
            last: None,
            kept: Beside::new(cap),
            source: choice.describe(&mag_axes),
        })
    }

    /// The chip's stream, for a device's gyro.
    pub(super) fn stream(&self) -> Option<u8> {
        match self.choice {
            Gyro3Choice::Chip { stream, .. } => Some(stream),
            _ => None,
        }
    }

    /// Binds a csv compass's columns; the (file, column) pairs its rows need.
    pub(super) fn bind_csv(
        &mut self,
        files: &[std::path::PathBuf],
        layouts: &[&CsvLayout],
    ) -> Result<Vec<(usize, usize)>, CsvError> {
        let Gyro3Choice::Columns { names, .. } = &self.choice else {
            return Ok(Vec::new());
        };
        let (file, at) = locate3(files, layouts, names, GYRO_ROLES)?;
        self.csv = Some((file, at));
        Ok(at.iter().map(|&i| (file, i)).collect())
    }

    /// A row of a csv source: the gyro's rate when it is in this row's file.
    pub(super) fn observe_row(&mut self, row: &CsvRow) {
        let (Gyro3Choice::Columns { units, .. }, Some((file, at))) = (&self.choice, self.csv)
        else {
            return;
        };
        if row.file != file {
            return;
        }
        let k = units.to_deg_per_second();
        let value = |i: usize| row.values.get(at[i]).map(|v| v * k);
        if let (Some(x), Some(y), Some(z)) = (value(0), value(1), value(2))
            && [x, y, z].iter().all(|v| v.is_finite())
        {
            self.last = Some((row.time, [x, y, z]));
        }
    }

    /// A device's reading: the gyro's rate when it is of the chip's stream.
    pub(super) fn observe_reading(&mut self, reading: &Reading) {
        let Gyro3Choice::Chip {
            stream,
            axes,
            lsb_per_deg_s,
        } = self.choice
        else {
            return;
        };
        if reading.stream == stream
            && let Some(triad) = reading.gyro
        {
            self.last = Some((reading.time, pick(triad, axes).map(|v| v / lsb_per_deg_s)));
        }
    }

    /// Lets the samples kept go (a sphere collected afresh).
    pub(super) fn clear(&mut self) {
        self.kept.clear();
    }

    /// The latest rate when it is at most [`MAX_TILT_AGE_S`] from `time`.
    pub(super) fn fresh(&self, time: f64) -> Option<[f64; 3]> {
        self.last
            .filter(|(t, _)| (time - t).abs() <= MAX_TILT_AGE_S)
            .map(|(_, g)| g)
    }

    /// Keeps a sample of the sphere with the accelerometer beside it (raw)
    /// and the gyro's rate fresh when it came, if there was one;
    /// `fresh_sphere` (the buffer held nothing before it) lets the last
    /// sphere's go first.
    pub(super) fn keep(
        &mut self,
        time: f64,
        [raw, accel]: [[f64; 3]; 2],
        gyro: Option<[f64; 3]>,
        fresh_sphere: bool,
    ) {
        if fresh_sphere {
            self.kept.clear();
        }
        if let Some(gyro) = gyro {
            self.kept.push(time, [raw, accel, gyro]);
        }
    }

    /// The gyro against the heading over the samples kept: the field
    /// corrected by `params` and laid on the accelerometer by `mag_axes`,
    /// the accelerometer corrected by `accel` (its calibration, if any).
    pub(super) fn fit(
        &self,
        params: &Ellipsoid3Params,
        mag_axes: AxisMap,
        accel: Option<&Ellipsoid3Params>,
    ) -> Result<GyroFit, String> {
        let samples: Vec<GyroSample> = self
            .kept
            .entries()
            .filter_map(|(time, [raw, accel_raw, gyro])| {
                let up = accel.map_or(accel_raw, |p| apply3(p, accel_raw));
                let mag = mag_axes.apply(apply3(params, raw));
                let h = tilt_heading_or_why(mag, up, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]).ok()?;
                Some(GyroSample {
                    time,
                    heading_deg: h.heading_deg,
                    up,
                    gyro_deg_s: gyro,
                })
            })
            .collect();
        let fit = fit_gyro3(&samples)?;
        Ok(GyroFit {
            scale: fit.scale,
            bias_deg_s: 0.0,
            heading_rms_deg: fit.heading_sd_deg,
            bias_xyz_deg_s: Some(fit.bias_deg_s),
            source: Some(self.source.clone()),
        })
    }

    /// The heading's rate the gyro gives at `time` under calibration
    /// `fit`, at the vertical `up` the heading was compensated with; none
    /// without a fresh rate, beyond the pitch the check allows, or under a
    /// fit made with another gyro, other units or another `mag_axes` (the
    /// configuration changed since).
    pub(super) fn rate(&self, time: f64, fit: &GyroFit, up: [f64; 3]) -> Option<f64> {
        if fit.source.as_deref() != Some(self.source.as_str()) {
            return None;
        }
        heading_rate(self.fresh(time)?, fit.bias_xyz_deg_s?, up)
    }
}
