//! The attitude a 2-axis compass was calibrated in, from its tilt
//! accelerometer, for the trust monitor's tilt check
//! ([`crate::model::trust`]): the rotation's vertical and its tilt spread.

use nalgebra::Vector3;

/// √(2 ln 2): the median of a Rayleigh distribution of σ 1 (the size of a
/// 2-D normal vector of σ 1 along each axis).
pub const RAYLEIGH_MEDIAN: f64 = 1.177_410_022_515_474_7;

/// The angle between two directions, degrees; none for a zero or
/// non-finite vector.
pub fn angle_between_deg(a: [f64; 3], b: [f64; 3]) -> Option<f64> {
    let (a, b) = (Vector3::from(a), Vector3::from(b));
    let (na, nb) = (a.norm(), b.norm());
    if !(na.is_finite() && nb.is_finite() && na > 0.0 && nb > 0.0) {
        return None;
    }
    // atan2 of the cross and dot products: exact at small angles, where
    // acos of the dot product loses half its digits.
    Some(a.cross(&b).norm().atan2(a.dot(&b)).to_degrees())
}

/// The attitude a 2-axis compass was calibrated in, from its tilt
/// accelerometer's raw readings over the rotation: the direction of their
/// component-wise median (robust to the few a hand's jerk throws off),
/// and the tilt's spread about it along one axis, the median tilt over
/// [`RAYLEIGH_MEDIAN`]. None without a reading of non-zero, finite size.
pub fn level_of(accels: &[[f64; 3]]) -> Option<crate::model::calibration::LevelFit> {
    let unit: Vec<Vector3<f64>> = accels
        .iter()
        .map(|a| Vector3::from(*a))
        .filter(|a| a.iter().all(|v| v.is_finite()))
        .filter_map(|a| {
            let n = a.norm();
            (n > 0.0 && n.is_finite()).then(|| a / n)
        })
        .collect();
    if unit.is_empty() {
        return None;
    }
    let mut column = Vec::with_capacity(unit.len());
    let mut median = [0.0; 3];
    for (k, m) in median.iter_mut().enumerate() {
        column.clear();
        column.extend(unit.iter().map(|u| u[k]));
        *m = super::tilt::median_of(&mut column);
    }
    let up = Vector3::from(median);
    let norm = up.norm();
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    let up = up / norm;
    let mut tilts: Vec<f64> = unit
        .iter()
        .filter_map(|u| angle_between_deg((*u).into(), up.into()))
        .collect();
    if tilts.is_empty() {
        return None;
    }
    let tilt_sd_deg = super::tilt::median_of(&mut tilts) / RAYLEIGH_MEDIAN;
    Some(crate::model::calibration::LevelFit {
        up: up.into(),
        tilt_sd_deg,
        n: unit.len(),
        tilt: None,
    })
}
