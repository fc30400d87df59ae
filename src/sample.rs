//! The data that flows through fieldcal: a recording of one sensor's two
//! turning axes, with optional time and any logged covariates.
//!
//! Stored column-wise (one `Vec` per column) because every consumer — the
//! fit, the residual analysis, the writers — walks whole columns.

/// One extra numeric column of a recording (temperature, motor current...),
/// kept by its header name so effects such as `covariate:temp_c` can use it.
#[derive(Debug, Clone, PartialEq)]
pub struct Covariate {
    pub name: String,
    pub values: Vec<f64>,
}

/// A recording of a sensor turning in a constant field.
///
/// Invariant: `x`, `y`, every covariate and `t` (when present) have the same
/// length, and every value is finite. The readers enforce it; code that builds
/// a `Dataset` by hand goes through [`Dataset::new`], which checks it.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Column names the two axes were read from (for messages and output).
    pub x_name: String,
    pub y_name: String,
    /// Sample times in seconds, when the recording has them.
    pub t: Option<Vec<f64>>,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub covariates: Vec<Covariate>,
}

/// Why a set of columns cannot form a [`Dataset`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DatasetError {
    #[error("column '{name}' has {found} values but '{reference}' has {expected}")]
    LengthMismatch {
        name: String,
        found: usize,
        reference: String,
        expected: usize,
    },
    #[error("column '{name}' holds a non-finite value ({value}) at row {row}")]
    NonFinite {
        name: String,
        row: usize,
        value: f64,
    },
    #[error(
        "column '{name}' holds {value:e} at row {row}: too large to square in f64 (the fit squares readings; give values of magnitude at most {max:e}, such as the sensor's counts or physical units)",
        max = MAX_MAGNITUDE
    )]
    TooLarge {
        name: String,
        row: usize,
        value: f64,
    },
}

/// Largest magnitude of a reading (or covariate, or time) that enters a fit.
///
/// The fits square readings and sum products of them over every sample
/// (the paper's features x², xy, y², Kåsa's u² + v², normal equations).
/// sqrt(f64::MAX) is about 1.34e154: a value above it overflows when
/// squared. 1e150 squared is 1e300, which leaves a factor of over 1e8
/// below f64::MAX ≈ 1.8e308 for sums over up to 10^8 samples. No sensor
/// reads anything near it (an i32 count is below 2.2e9), so a value this
/// large is not a reading: it is refused with that reason rather than
/// reported later as a degenerate turn, or left to hang a solver.
pub const MAX_MAGNITUDE: f64 = 1e150;

/// `1 sample` or `2 samples`: a count and its noun, for messages.
pub fn count(n: impl Into<u64>, noun: &str) -> String {
    let n = n.into();
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

/// `1 sample is` or `2 samples are`: a count as the subject of a message.
pub fn count_is(n: impl Into<u64>, noun: &str) -> String {
    let n = n.into();
    if n == 1 {
        format!("1 {noun} is")
    } else {
        format!("{n} {noun}s are")
    }
}

/// Refuses a value whose square (or a sum of squares) would overflow f64.
pub fn too_large(value: f64) -> bool {
    value.abs() > MAX_MAGNITUDE
}

/// Whether every value is finite and not [`too_large`]: a fold without an
/// early exit, so that it runs several values at a time.
fn all_within(values: &[f64]) -> bool {
    values.chunks(64).all(|chunk| {
        chunk
            .iter()
            .fold(true, |ok, v| ok & (v.abs() <= MAX_MAGNITUDE))
    })
}

impl Dataset {
    /// Builds a dataset from plain columns, checking lengths and finiteness.
    pub fn new(
        x_name: impl Into<String>,
        y_name: impl Into<String>,
        t: Option<Vec<f64>>,
        x: Vec<f64>,
        y: Vec<f64>,
        covariates: Vec<Covariate>,
    ) -> Result<Self, DatasetError> {
        let dataset = Dataset {
            x_name: x_name.into(),
            y_name: y_name.into(),
            t,
            x,
            y,
            covariates,
        };
        dataset.check()?;
        Ok(dataset)
    }

    /// The dataset without the rows `drop` (ascending indices).
    pub fn without_rows(mut self, drop: &[usize]) -> Self {
        if drop.is_empty() {
            return self;
        }
        let keep = kept(self.len(), drop);
        retain_rows(&mut self.x, &keep);
        retain_rows(&mut self.y, &keep);
        if let Some(t) = &mut self.t {
            retain_rows(t, &keep);
        }
        for c in &mut self.covariates {
            retain_rows(&mut c.values, &keep);
        }
        self
    }

    /// A dataset of just two axes, named `x` and `y`.
    pub fn from_xy(x: Vec<f64>, y: Vec<f64>) -> Result<Self, DatasetError> {
        Self::new("x", "y", None, x, y, Vec::new())
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// The covariate column of that name, if the recording has one.
    pub fn covariate(&self, name: &str) -> Option<&Covariate> {
        self.covariates.iter().find(|c| c.name == name)
    }

    fn columns(&self) -> impl Iterator<Item = (&str, &[f64])> {
        let t = self.t.as_deref().map(|t| ("t", t));
        [
            (self.x_name.as_str(), &self.x[..]),
            (self.y_name.as_str(), &self.y[..]),
        ]
        .into_iter()
        .chain(t)
        .chain(
            self.covariates
                .iter()
                .map(|c| (c.name.as_str(), &c.values[..])),
        )
    }

    fn check(&self) -> Result<(), DatasetError> {
        let expected = self.x.len();
        for (name, values) in self.columns() {
            if values.len() != expected {
                return Err(DatasetError::LengthMismatch {
                    name: name.to_string(),
                    found: values.len(),
                    reference: self.x_name.clone(),
                    expected,
                });
            }
            // Nearly always all within the limit (NaN is not): one pass
            // that the compiler can widen, before the passes that find the
            // first value of each kind.
            if all_within(values) {
                continue;
            }
            if let Some((row, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(DatasetError::NonFinite {
                    name: name.to_string(),
                    row,
                    value,
                });
            }
            if let Some((row, &value)) = values.iter().enumerate().find(|(_, v)| too_large(**v)) {
                return Err(DatasetError::TooLarge {
                    name: name.to_string(),
                    row,
                    value,
                });
            }
        }
        Ok(())
    }
}

/// A recording of a 3-axis sensor: the points `[x, y, z]` with the same
/// times and covariates as a [`Dataset`] (same invariant: equal lengths,
/// finite values).
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset3 {
    pub x_name: String,
    pub y_name: String,
    pub z_name: String,
    pub t: Option<Vec<f64>>,
    pub points: Vec<[f64; 3]>,
    pub covariates: Vec<Covariate>,
}

impl Dataset3 {
    /// The 3-axis recording whose z is the covariate `z_name` of a
    /// 2-axis one; `None` when it has no such covariate.
    pub fn from_dataset(dataset: Dataset, z_name: &str) -> Option<Self> {
        let Dataset {
            x_name,
            y_name,
            t,
            x,
            y,
            mut covariates,
        } = dataset;
        let k = covariates.iter().position(|c| c.name == z_name)?;
        let z = covariates.remove(k);
        let points = x
            .iter()
            .zip(&y)
            .zip(&z.values)
            .map(|((&x, &y), &z)| [x, y, z])
            .collect();
        Some(Dataset3 {
            x_name,
            y_name,
            z_name: z.name,
            t,
            points,
            covariates,
        })
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The covariate column of that name, if the recording has one.
    pub fn covariate(&self, name: &str) -> Option<&Covariate> {
        self.covariates.iter().find(|c| c.name == name)
    }

    /// The recording without the rows `drop` (ascending indices).
    pub fn without_rows(mut self, drop: &[usize]) -> Self {
        if drop.is_empty() {
            return self;
        }
        let keep = kept(self.len(), drop);
        retain_rows(&mut self.points, &keep);
        if let Some(t) = &mut self.t {
            retain_rows(t, &keep);
        }
        for c in &mut self.covariates {
            retain_rows(&mut c.values, &keep);
        }
        self
    }
}

/// Which of `n` rows stay when the rows `drop` go.
fn kept(n: usize, drop: &[usize]) -> Vec<bool> {
    let mut keep = vec![true; n];
    for &i in drop {
        if let Some(k) = keep.get_mut(i) {
            *k = false;
        }
    }
    keep
}

fn retain_rows<T>(values: &mut Vec<T>, keep: &[bool]) {
    let mut row = 0;
    values.retain(|_| {
        let k = keep.get(row).copied().unwrap_or(true);
        row += 1;
        k
    });
}

/// What a device reported in one frame or one poll, in raw counts, stamped
/// with the host's receive time. Devices fill the fields they have.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Reading {
    /// Host receive time in seconds: since the Unix epoch for a live source,
    /// since the start of the capture for a replay (which `run` re-stamps
    /// onto the Unix clock: see [`crate::daemon::messages`]).
    pub time: f64,
    /// Which byte stream of its source the reading came from: 0 for a
    /// Falcon-GX, the chip's place in the poll list for an I2C bridge.
    #[serde(default)]
    pub stream: u8,
    /// Magnetometer x, y, z in counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mag: Option<[i16; 3]>,
    /// Accelerometer x, y, z in counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accel: Option<[i16; 3]>,
    /// Angular rate x, y, z in counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gyro: Option<[i16; 3]>,
    /// Temperature register, in counts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temp_raw: Option<i16>,
    /// Temperature in degrees Celsius, where the chip's conversion is known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temp_c: Option<f64>,
    /// The device's own frame timer (Falcon-GX), which wraps at 65536.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timer: Option<u16>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_x(x: Vec<f64>) -> Result<Dataset, DatasetError> {
        let y = vec![0.0; x.len()];
        Dataset::new("x", "y", None, x, y, Vec::new())
    }

    /// The one-pass check lets through what the two passes let through,
    /// and refuses the same row for the same reason: a value that is not
    /// finite before one too large, wherever each lies in the column.
    #[test]
    fn the_check_finds_the_row_the_passes_find() {
        let mut x = vec![1.0; 200];
        x[199] = MAX_MAGNITUDE;
        x[0] = -MAX_MAGNITUDE;
        assert!(with_x(x.clone()).is_ok());
        x[70] = 2.0 * MAX_MAGNITUDE;
        assert!(
            matches!(
                with_x(x.clone()),
                Err(DatasetError::TooLarge { row: 70, .. })
            ),
            "{:?}",
            with_x(x.clone()).err()
        );
        x[150] = f64::NAN;
        assert!(
            matches!(
                with_x(x.clone()),
                Err(DatasetError::NonFinite { row: 150, .. })
            ),
            "{:?}",
            with_x(x.clone()).err()
        );
        for bad in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN] {
            let mut x = vec![1.0; 130];
            x[129] = bad;
            assert!(
                matches!(with_x(x), Err(DatasetError::NonFinite { row: 129, .. })),
                "{bad}"
            );
        }
    }
}
