//! The sphere buffer of a 3-axis sensor: the samples kept while it
//! collects, until their directions cover enough of the sphere for the
//! configured 3-D model ([`ellipsoid::supports`]). Directions are judged
//! about a closed-form estimate every [`CHECK_EVERY`] samples; when the
//! buffer is full the most crowded direction region gives up its older
//! half. With `still` the samples are those of poses held still
//! ([`StillStream`]) instead of every reading.
//!
//! Pure: no I/O, no clock, no messages. The daemon's 3-axis sensor
//! (`crate::daemon::sensor3`) pushes each reading and fits when
//! [`SphereBuffer::push`] says the directions support the model.

use serde::{Deserialize, Serialize};

use crate::model::ellipsoid::{self, Ellipsoid3Model};
use crate::model::sphere::{self, MissingDirections, SphereCoverage};
use crate::model::still_stream::{StillState, StillStream};

/// ArduPilot's compass calibrator collects `COMPASS_CAL_NUM_SAMPLES` = 300
/// samples before it fits (AP_Compass/CompassCalibrator.h): the default
/// fewest samples a 3-D fit is tried on.
pub const DEFAULT_MIN_SAMPLES: usize = 300;

/// Default cap on the samples held while collecting: ten times
/// [`DEFAULT_MIN_SAMPLES`]. When full, the most crowded direction region
/// gives up its older half, so a hand that dwells on some directions
/// cannot crowd out the rest and memory stays bounded (ArduPilot thins its
/// buffer likewise, `thin_samples`).
pub const DEFAULT_MAX_SAMPLES: usize = 3000;

/// Hard bounds of the two settings above.
pub const SAMPLES_RANGE: (usize, usize) = (20, 1_000_000);

/// The coverage is judged (a closed-form fit for the directions, then
/// [`ellipsoid::supports`]) once every this many samples: at 20 Hz four
/// times a second, and the cost of a judgement (linear in the samples
/// held) stays a small share of the readings' path.
pub const CHECK_EVERY: usize = 5;

/// `[sensor.sphere]`: how a 3-axis sensor collects, and its rms limit.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct SphereSettings {
    /// Fewest samples a fit is tried on.
    pub min_samples: usize,
    /// Most samples held (see [`DEFAULT_MAX_SAMPLES`]).
    pub max_samples: usize,
    /// Largest rms of |calibrated|/r − 1, a fraction of the field; when
    /// absent, ArduPilot's 16 mG for a magnetometer whose units are known,
    /// 5 % otherwise.
    pub max_rms: Option<f64>,
    /// An accelerometer fitted on poses held still
    /// ([`crate::model::still_stream`]) instead of every reading of a
    /// tumble, whose hand accelerations spoil the fit: ArduPilot's
    /// six-position calibration. `min_samples` is then not used: a fit
    /// needs as many poses as the model has unknowns (6 for
    /// `offset+scale`), and directions that determine it.
    pub still: bool,
}

impl Default for SphereSettings {
    fn default() -> Self {
        SphereSettings {
            min_samples: DEFAULT_MIN_SAMPLES,
            max_samples: DEFAULT_MAX_SAMPLES,
            max_rms: None,
            still: false,
        }
    }
}

impl SphereSettings {
    /// Checks the settings; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = SAMPLES_RANGE;
        if !(lo..=hi).contains(&self.min_samples) {
            return Err(format!(
                "min_samples must be between {lo} and {hi}, got {}",
                self.min_samples
            ));
        }
        if !(self.min_samples..=hi).contains(&self.max_samples) {
            return Err(format!(
                "max_samples must be between min_samples ({}) and {hi}, got {}",
                self.min_samples, self.max_samples
            ));
        }
        if let Some(v) = self.max_rms
            && !(v.is_finite() && v > 0.0 && v <= 1.0)
        {
            return Err(format!(
                "max_rms must be a fraction of the field above 0 and at most 1 (0.05 = 5 %), got {v}"
            ));
        }
        Ok(())
    }
}

/// A 3-axis sensor's progress in `STATUS`, while collecting.
#[derive(Debug, Clone, Serialize)]
pub struct SphereProgress {
    /// Samples held.
    pub samples: usize,
    /// The share of the sphere's 100 equal-area regions reached, percent,
    /// about the current closed-form estimate.
    pub coverage_pct: f64,
    pub regions: usize,
    pub covered: usize,
    /// The missing directions, in words ("missing: -z (...)").
    pub missing_text: String,
    /// The missing directions, largest first.
    pub missing: Vec<MissingDirections>,
    /// The indices of the regions no direction reached yet (the regions'
    /// geometry is `sphere_regions` of `/api/config`): the live page's map.
    pub missing_regions: Vec<usize>,
    /// The model being collected for.
    pub model: &'static str,
    /// The richest model the directions so far support, if any.
    pub supported: Option<&'static str>,
    /// With `still`: the poses held so far and the detector's state.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub still: Option<StillProgress>,
}

/// A still-pose sensor's progress in `STATUS`.
#[derive(Debug, Clone, Serialize)]
pub struct StillProgress {
    /// Poses held still so far (the one being held included, once it
    /// spans a window).
    pub poses: usize,
    /// Poses the model needs at least: its unknowns.
    pub poses_needed: usize,
    #[serde(flatten)]
    pub state: StillState,
}

/// One 3-axis sensor's samples while it collects, with the estimate their
/// directions are judged about and the coverage found.
#[derive(Debug, Clone)]
pub struct SphereBuffer {
    /// The model collected for.
    model: Ellipsoid3Model,
    settings: SphereSettings,
    points: Vec<[f64; 3]>,
    /// The closed-form estimate the directions are judged about: (o, A),
    /// A(raw − o) on the unit sphere.
    estimate: Option<([f64; 3], [[f64; 3]; 3])>,
    since_check: usize,
    coverage: SphereCoverage,
    supported: Option<Ellipsoid3Model>,
    /// After a fit refused for coverage, samples to take before the next
    /// try (so a refusal is not repeated every check).
    wait: usize,
    /// The tilt source's raw reading beside each of `points` (a sensor
    /// with `tilt`; else empty), for the measured inclination.
    accel_at: Vec<Option<[f64; 3]>>,
    /// With `[sensor.sphere] still`: the still-pose detector, and the
    /// poses `points` were last built from.
    still: Option<StillStream>,
    poses: usize,
}

impl SphereBuffer {
    /// An empty buffer collecting for `model` under `settings`;
    /// `lsb_per_unit` (counts per g) tunes the still-pose detector.
    pub fn new(
        model: Ellipsoid3Model,
        settings: SphereSettings,
        lsb_per_unit: Option<f64>,
    ) -> Self {
        SphereBuffer {
            model,
            points: Vec::new(),
            estimate: None,
            since_check: 0,
            coverage: sphere::coverage(std::iter::empty()),
            supported: None,
            wait: 0,
            accel_at: Vec::new(),
            still: settings.still.then(|| StillStream::new(lsb_per_unit)),
            poses: 0,
            settings,
        }
    }

    /// The samples held, raw.
    pub fn points(&self) -> &[[f64; 3]] {
        &self.points
    }

    /// The tilt source's reading beside each sample (empty without one).
    pub fn accel_at(&self) -> &[Option<[f64; 3]>] {
        &self.accel_at
    }

    /// With `still`: the poses the samples were last built from.
    pub fn still_poses(&self) -> Option<usize> {
        self.still.is_some().then_some(self.poses)
    }

    /// Starts afresh: no samples, no poses, no estimate.
    pub fn reset(&mut self) {
        self.points.clear();
        self.accel_at.clear();
        if let Some(still) = &mut self.still {
            still.clear_poses();
        }
        self.poses = 0;
        self.estimate = None;
        self.since_check = 0;
        self.wait = 0;
        self.coverage = sphere::coverage(std::iter::empty());
        self.supported = None;
    }

    /// Progress while collecting.
    pub fn progress(&self) -> SphereProgress {
        SphereProgress {
            samples: self.points.len(),
            coverage_pct: self.coverage.fraction * 100.0,
            regions: self.coverage.regions,
            covered: self.coverage.covered,
            missing_text: self.coverage.missing_text(),
            missing: self.coverage.missing.clone(),
            missing_regions: (0..self.coverage.reached.len())
                .filter(|&k| !self.coverage.reached[k])
                .collect(),
            model: self.model.name(),
            supported: self.supported.map(Ellipsoid3Model::name),
            still: self.still.as_ref().map(|still| StillProgress {
                // Judged now: a later noise estimate may drop a pose.
                poses: still.pose_count(),
                poses_needed: self.model.unknowns(),
                state: still.state(),
            }),
        }
    }

    /// Keeps a finite sample, thinning the most crowded region when the
    /// buffer is full; `accel` is the tilt source's reading beside it
    /// (`Some(None)`: it has one, but stale; `None`: it has none). True
    /// when the coverage now supports the model: time to fit.
    pub fn push(&mut self, time: f64, raw: [f64; 3], accel: Option<Option<[f64; 3]>>) -> bool {
        if self.still.is_some() {
            return self.push_still(time, raw);
        }
        if self.points.len() >= self.settings.max_samples {
            self.thin();
        }
        self.points.push(raw);
        if let Some(fresh) = accel {
            self.accel_at.push(fresh);
        }
        self.wait = self.wait.saturating_sub(1);
        self.since_check += 1;
        if self.since_check < CHECK_EVERY {
            return false;
        }
        self.since_check = 0;
        self.judge();
        let n = self.points.len();
        !(n < self.settings.min_samples
            || self.wait > 0
            || self
                .supported
                .is_none_or(|m| m.unknowns() < self.model.unknowns()))
    }

    /// [`SphereBuffer::push`] of a still-pose sensor: the points are the
    /// poses' samples, judged again when a pose ends and, while one is
    /// held, every [`CHECK_EVERY`] samples.
    fn push_still(&mut self, time: f64, raw: [f64; 3]) -> bool {
        let Some(still) = self.still.as_mut() else {
            return false;
        };
        let ended = still.push(time, raw).is_some();
        self.since_check += 1;
        let held = still.still_now() && self.since_check >= CHECK_EVERY;
        if !(ended || held) {
            return false;
        }
        self.since_check = 0;
        let poses = still.poses();
        self.poses = poses.len();
        self.points = poses
            .iter()
            .flat_map(|p| p.samples.iter().copied())
            .collect();
        if self.poses < self.model.unknowns() {
            // Too few poses to fit a centre: their directions about zero
            // (a resting accelerometer reads g plus a zero-g offset far
            // below g), for the progress's missing directions.
            self.estimate = Some((
                [0.0; 3],
                [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            ));
            self.coverage = sphere::coverage(self.directions());
            self.supported = None;
            return false;
        }
        self.judge();
        !(self.poses < self.model.unknowns()
            || self
                .supported
                .is_none_or(|m| m.unknowns() < self.model.unknowns()))
    }

    /// After a fit the samples were handed to: accepted or rejected, the
    /// points are gone and a still-pose sensor's next calibration starts
    /// from new poses; a fit refused for coverage keeps them.
    pub fn after_fit(&mut self) {
        if self.points.is_empty()
            && let Some(still) = &mut self.still
        {
            still.clear_poses();
            self.poses = 0;
        }
    }

    /// The estimate's directions looked complete, the fit's did not:
    /// collect on, and try again a quarter (at least min_samples / 4)
    /// further on.
    pub fn not_yet(&mut self) {
        let n = self.points.len();
        self.wait = (n / 4).max(self.settings.min_samples / 4);
    }

    /// The samples' fit was refused: collect anew.
    pub fn rejected(&mut self) {
        self.points.clear();
        self.accel_at.clear();
        self.estimate = None;
        self.wait = 0;
        self.coverage = sphere::coverage(std::iter::empty());
        self.supported = None;
    }

    /// The directions of the points about the current estimate.
    fn directions(&self) -> Vec<[f64; 3]> {
        let (o, a) = self.estimate.unwrap_or_else(|| {
            // Before a closed form: the centre of the readings' box.
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for p in &self.points {
                for i in 0..3 {
                    lo[i] = lo[i].min(p[i]);
                    hi[i] = hi[i].max(p[i]);
                }
            }
            let o = [0, 1, 2].map(|i| (lo[i] + hi[i]) / 2.0);
            (o, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        });
        self.points
            .iter()
            .map(|p| {
                let d = [0, 1, 2].map(|i| p[i] - o[i]);
                [0, 1, 2].map(|i| a[i][0] * d[0] + a[i][1] * d[1] + a[i][2] * d[2])
            })
            .collect()
    }

    /// Updates the estimate, the coverage and the supported model.
    fn judge(&mut self) {
        if self.points.len() >= 4 * self.model.unknowns()
            && let Ok(estimate) = ellipsoid::closed_form(&self.points, self.model)
            && estimate
                .0
                .iter()
                .chain(estimate.1.iter().flatten())
                .all(|v| v.is_finite())
        {
            self.estimate = Some(estimate);
        }
        let dirs = self.directions();
        self.coverage = sphere::coverage(dirs.iter().copied());
        self.supported = if self.estimate.is_some() {
            ellipsoid::best_supported(&dirs)
        } else {
            None
        };
    }

    /// Drops the older half of the most crowded region's samples.
    fn thin(&mut self) {
        let regions: Vec<Option<usize>> = self
            .directions()
            .into_iter()
            .map(sphere::region_of)
            .collect();
        let mut counts = [0usize; sphere::REGIONS];
        for k in regions.iter().flatten() {
            if let Some(c) = counts.get_mut(*k) {
                *c += 1;
            }
        }
        let Some((crowded, &most)) = counts.iter().enumerate().max_by_key(|(_, c)| **c) else {
            return;
        };
        let mut drop = (most / 2).max(1);
        let keep: Vec<bool> = regions
            .iter()
            .map(|r| {
                let keep = !(drop > 0 && *r == Some(crowded));
                if !keep {
                    drop -= 1;
                }
                keep
            })
            .collect();
        let mut i = 0;
        self.points.retain(|_| {
            i += 1;
            keep.get(i - 1).copied().unwrap_or(true)
        });
        let mut i = 0;
        self.accel_at.retain(|_| {
            i += 1;
            keep.get(i - 1).copied().unwrap_or(true)
        });
        if self.points.len() >= self.settings.max_samples {
            // No direction (a degenerate estimate): drop the oldest.
            self.points.remove(0);
            if !self.accel_at.is_empty() {
                self.accel_at.remove(0);
            }
        }
    }
}
