//! The one value of a 3-D calibration: calibrated = W·(raw − o), with
//! |calibrated| = r (see [`super::ellipsoid`] for the fit).
//!
//! Whoever holds a 3-D calibration (the fit, the daemon's state file,
//! `fieldcal check`, `fieldcal heading`) corrects a reading with
//! [`correct3`], reads the offset, W and r of a JSON document with
//! [`Calibration3D::from_json`], and asks [`Calibration3D::validate`] whether
//! the numbers can be a calibration at all.

use serde::Serialize;
use serde_json::Value;

/// W·(raw − o): a raw 3-axis reading corrected by the offset `offset` and
/// the row-major matrix `matrix`. The one place this product is written.
pub fn correct3(offset: &[f64; 3], matrix: &[[f64; 3]; 3], raw: [f64; 3]) -> [f64; 3] {
    let d = [0, 1, 2].map(|i| raw[i] - offset[i]);
    let w = matrix;
    [0, 1, 2].map(|i| w[i][0] * d[0] + w[i][1] * d[1] + w[i][2] * d[2])
}

/// A 3-D calibration: calibrated = W·(raw − o), |calibrated| = r.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Calibration3D {
    /// o, raw units.
    pub offset: [f64; 3],
    /// W, row-major; a fit's is symmetric with det W = 1.
    pub matrix: [[f64; 3]; 3],
    /// The field's magnitude, raw units.
    pub r: f64,
}

/// Why a JSON document's offset or matrix could not be read. Each caller
/// words it for its own command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Calibration3JsonError {
    /// The field (an offset, or a row of a matrix) is not a list of three
    /// numbers.
    #[error("{field} is not a list of three numbers")]
    NotTriple { field: &'static str },
    /// The matrix is not a list of three rows.
    #[error("{field} is not a 3 × 3 list of rows")]
    NotRows { field: &'static str },
}

/// Why numbers cannot be a 3-D calibration.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Calibration3Invalid {
    /// `field` (the first of offset, matrix, r that does) holds a number
    /// that is not finite.
    #[error("its offset, matrix or r holds a number that is not finite")]
    NotFinite { field: &'static str },
    /// The field's magnitude is zero or negative.
    #[error("r = {r} must be positive")]
    RadiusNotPositive { r: f64 },
    /// W is not symmetric (beyond 1e-6 of its largest entry).
    #[error("its matrix W is not symmetric")]
    NotSymmetric,
    /// W has an eigenvalue that is not above zero: a mirror or a collapse.
    #[error("its matrix W is not positive definite")]
    NotPositiveDefinite,
    /// W stretches one direction more than [`MAX_STRETCH`] times another.
    #[error(
        "its matrix W stretches one direction {ratio:.3e} times another, beyond {MAX_STRETCH} (ArduPilot's soft-iron diagonal bounds, 0.2 to 5)"
    )]
    Stretched { ratio: f64 },
    /// An offset of more than [`MAX_OFFSET_RADII`] field radii.
    #[error(
        "its offset on {axis} is {radii:.3e} field radii, beyond {MAX_OFFSET_RADII} (ArduPilot's COMPASS_OFFS_MAX beside the Earth's field)"
    )]
    OffsetTooLarge { axis: &'static str, radii: f64 },
}

/// The most W may stretch one direction against another: 343. A matrix
/// within ArduPilot's soft-iron bounds (diagonal 0.2 to 5, off-diagonal
/// below 1, CompassCalibrator::fit_acceptable), normalised to det W = 1,
/// has eigenvalues of at most 5 + 2 = 7, so its smallest is at least
/// 1/7² and the ratio at most 7³ = 343: every fit the daemon accepts is
/// within it, while a hand-edited 1e308 is not.
pub const MAX_STRETCH: f64 = 343.0;
/// The largest offset per axis, in field radii: 12. ArduPilot accepts
/// offsets up to COMPASS_OFFS_MAX (1800 mG) beside fields down to
/// FIELD_RADIUS_MIN (150 mG), which is 12 radii; the daemon's limits
/// relative to the radius are tighter (5), so every calibration it accepts
/// passes, while an offset of 1e308 does not.
pub const MAX_OFFSET_RADII: f64 = 12.0;

/// Reads a list of three numbers.
pub fn triple(v: Option<&Value>, field: &'static str) -> Result<[f64; 3], Calibration3JsonError> {
    let list = v
        .and_then(Value::as_array)
        .filter(|l| l.len() == 3)
        .ok_or(Calibration3JsonError::NotTriple { field })?;
    let mut out = [0.0; 3];
    for (o, x) in out.iter_mut().zip(list) {
        *o = x
            .as_f64()
            .ok_or(Calibration3JsonError::NotTriple { field })?;
    }
    Ok(out)
}

/// Reads a 3 × 3 matrix as a list of three rows.
pub fn matrix(
    v: Option<&Value>,
    field: &'static str,
) -> Result<[[f64; 3]; 3], Calibration3JsonError> {
    let rows = v
        .and_then(Value::as_array)
        .filter(|m| m.len() == 3)
        .ok_or(Calibration3JsonError::NotRows { field })?;
    Ok([
        triple(rows.first(), field)?,
        triple(rows.get(1), field)?,
        triple(rows.get(2), field)?,
    ])
}

impl Calibration3D {
    /// W·(raw − o).
    pub fn correct(&self, raw: [f64; 3]) -> [f64; 3] {
        correct3(&self.offset, &self.matrix, raw)
    }

    /// Reads `{"offset": [3], "matrix": [[3]; 3], "r"}` (the `params` of
    /// `fieldcal fit --json` in 3-D, or a state file's
    /// `calibration.ellipsoid`); `fields` names the offset and the matrix
    /// in errors. A missing r reads as NaN, for [`Self::validate`] to refuse.
    pub fn from_json(
        params: &Value,
        fields: [&'static str; 2],
    ) -> Result<Calibration3D, Calibration3JsonError> {
        Ok(Calibration3D {
            offset: triple(params.get("offset"), fields[0])?,
            matrix: matrix(params.get("matrix"), fields[1])?,
            r: params.get("r").and_then(Value::as_f64).unwrap_or(f64::NAN),
        })
    }

    /// Whether the numbers can be a calibration: all finite, r above zero,
    /// W symmetric and positive definite.
    pub fn validate(&self) -> Result<(), Calibration3Invalid> {
        let fields = [
            ("offset", self.offset.iter().all(|v| v.is_finite())),
            (
                "matrix",
                self.matrix.iter().flatten().all(|v| v.is_finite()),
            ),
            ("r", self.r.is_finite()),
        ];
        if let Some((field, _)) = fields.iter().find(|(_, finite)| !finite) {
            return Err(Calibration3Invalid::NotFinite { field });
        }
        if !(self.r > 0.0) {
            return Err(Calibration3Invalid::RadiusNotPositive { r: self.r });
        }
        let m = nalgebra::Matrix3::from_fn(|i, j| self.matrix[i][j]);
        let scale = m.abs().max().max(f64::MIN_POSITIVE);
        if (m - m.transpose()).abs().max() > 1e-6 * scale {
            return Err(Calibration3Invalid::NotSymmetric);
        }
        let eigen = m.symmetric_eigenvalues();
        if eigen.iter().any(|&l| !(l > 0.0)) {
            return Err(Calibration3Invalid::NotPositiveDefinite);
        }
        let ratio = eigen.max() / eigen.min();
        if !(ratio <= MAX_STRETCH) {
            return Err(Calibration3Invalid::Stretched { ratio });
        }
        for (axis, o) in ["x", "y", "z"].into_iter().zip(self.offset) {
            let radii = o.abs() / self.r;
            if !(radii <= MAX_OFFSET_RADII) {
                return Err(Calibration3Invalid::OffsetTooLarge { axis, radii });
            }
        }
        Ok(())
    }
}
