//! ArduPilot's acceptance limits of a 3-D fit ([`check_limits`]): the
//! field's radius, the offsets, the fitness and the soft-iron matrix of a
//! magnetometer, an accelerometer's offsets and scales, or limits relative
//! to the radius when the units are not configured.

use super::config::Field;
use crate::model::ellipsoid::Ellipsoid3Fit;

/// ArduPilot's field radius bounds, milligauss: `FIELD_RADIUS_MIN` 150 and
/// `FIELD_RADIUS_MAX` 950 (CompassCalibrator.cpp, "Earth's magnetic field
/// strength range: 250-850mG").
pub const FIELD_RADIUS_MGAUSS: (f64, f64) = (150.0, 950.0);
/// ArduPilot's largest offset per axis, milligauss: `COMPASS_OFFS_MAX`,
/// default 1800 (AP_Compass.cpp).
pub const MAX_OFFSET_MGAUSS: f64 = 1800.0;
/// ArduPilot's fitness tolerance: the rms residual in milligauss,
/// `COMPASS_CAL_FIT` default 16 (`AP_COMPASS_CALIBRATION_FITNESS_DEFAULT`).
pub const MAX_FITNESS_MGAUSS: f64 = 16.0;
/// ArduPilot's bounds of the soft-iron matrix's diagonal, 0.2 to 5, and of
/// its off-diagonal entries, |·| < 1 (CompassCalibrator::fit_acceptable).
pub const MAG_DIAGONAL: (f64, f64) = (0.2, 5.0);
pub const MAG_MAX_OFF_DIAGONAL: f64 = 1.0;
/// ArduPilot's accelerometer bounds (AccelCalibrator::accept_result): each
/// offset at most 1 g (`GRAVITY_MSS`), each diagonal scale 0.8 to 1.2.
pub const ACCEL_MAX_OFFSET_G: f64 = 1.0;
pub const ACCEL_DIAGONAL: (f64, f64) = (0.8, 1.2);
/// When the sensor's units are not configured, the limits are relative to
/// the fitted radius: offsets at most 5 radii (the 2-D daemon's
/// `max_offset_ratio`, from the same COMPASS_OFFS_MAX beside the Earth's
/// 250-850 mG) and an rms of at most 5 % of the field (the 2-D `max_rms`;
/// ArduPilot's 16 mG is 2-6 % of the Earth's field).
pub const RELATIVE_MAX_OFFSET: f64 = 5.0;
pub const RELATIVE_MAX_RMS: f64 = 0.05;

/// Why a 3-D fit is refused: every failed limit, named with its value and
/// its source, joined by "; ". `field` and `lsb_per_unit` give the units.
pub fn check_limits(
    fit: &Ellipsoid3Fit,
    field: Field,
    lsb_per_unit: Option<f64>,
    max_rms: Option<f64>,
) -> Result<(), String> {
    let extra = [fit.r, fit.rms];
    let mut numbers = fit
        .offset
        .iter()
        .chain(fit.matrix.iter().flatten())
        .chain(extra.iter());
    if numbers.any(|v| !v.is_finite()) || !(fit.r > 0.0) {
        return Err("the fit produced a non-finite or non-positive parameter".into());
    }
    let mut failures = Vec::new();
    let w = &fit.matrix;
    let diagonal = [w[0][0], w[1][1], w[2][2]];
    let off_diagonal = [w[0][1], w[0][2], w[1][2]];
    match (field, lsb_per_unit) {
        (Field::Mag, Some(u)) => {
            let to_mg = |counts: f64| counts / u * 1000.0;
            let r_mg = to_mg(fit.r);
            let (lo, hi) = FIELD_RADIUS_MGAUSS;
            if !(r_mg > lo && r_mg < hi) {
                failures.push(format!(
                    "field radius {r_mg:.0} mG is outside ArduPilot's {lo:.0}-{hi:.0} mG (FIELD_RADIUS_MIN/MAX; {:.1} counts at lsb_per_gauss {u})",
                    fit.r
                ));
            }
            for (axis, o) in ["x", "y", "z"].iter().zip(fit.offset) {
                if to_mg(o).abs() >= MAX_OFFSET_MGAUSS {
                    failures.push(format!(
                        "offset {axis} {:.0} mG exceeds ArduPilot's {MAX_OFFSET_MGAUSS:.0} mG (COMPASS_OFFS_MAX)",
                        to_mg(o)
                    ));
                }
            }
            let fitness = to_mg(fit.rms * fit.r);
            let limit_mg = max_rms.map_or(MAX_FITNESS_MGAUSS, |f| to_mg(f * fit.r));
            if fitness > limit_mg {
                failures.push(format!(
                    "rms {fitness:.1} mG ({:.2} % of the field) exceeds {limit_mg:.1} mG ({})",
                    fit.rms * 100.0,
                    if max_rms.is_some() {
                        "sphere.max_rms"
                    } else {
                        "ArduPilot's COMPASS_CAL_FIT"
                    }
                ));
            }
        }
        (Field::Accel, Some(u)) => {
            for (axis, o) in ["x", "y", "z"].iter().zip(fit.offset) {
                if (o / u).abs() > ACCEL_MAX_OFFSET_G {
                    failures.push(format!(
                        "offset {axis} {:.3} g exceeds ArduPilot's {ACCEL_MAX_OFFSET_G} g (AccelCalibrator)",
                        o / u
                    ));
                }
            }
            let (lo, hi) = ACCEL_DIAGONAL;
            let g = fit.r / u;
            if !(lo..=hi).contains(&g) {
                failures.push(format!(
                    "gravity reads {g:.3} g at lsb_per_g {u}: the overall scale is outside ArduPilot's {lo}-{hi} (AccelCalibrator)"
                ));
            }
        }
        _ => {
            for (axis, o) in ["x", "y", "z"].iter().zip(fit.offset) {
                if o.abs() > RELATIVE_MAX_OFFSET * fit.r {
                    failures.push(format!(
                        "offset {axis} {o:.1} counts is more than {RELATIVE_MAX_OFFSET} field radii ({:.1} counts)",
                        fit.r
                    ));
                }
            }
        }
    }
    if !(field == Field::Mag && lsb_per_unit.is_some()) {
        let limit = max_rms.unwrap_or(RELATIVE_MAX_RMS);
        if fit.rms > limit {
            failures.push(format!(
                "rms {:.2} % of the field exceeds {:.2} % ({})",
                fit.rms * 100.0,
                limit * 100.0,
                if max_rms.is_some() {
                    "sphere.max_rms"
                } else {
                    "the default"
                }
            ));
        }
    }
    let (lo, hi, off) = match field {
        Field::Accel => (ACCEL_DIAGONAL.0, ACCEL_DIAGONAL.1, MAG_MAX_OFF_DIAGONAL),
        _ => (MAG_DIAGONAL.0, MAG_DIAGONAL.1, MAG_MAX_OFF_DIAGONAL),
    };
    for (axis, d) in ["xx", "yy", "zz"].iter().zip(diagonal) {
        if !(d > lo && d < hi) {
            failures.push(format!(
                "matrix {axis} {d:.3} is outside ArduPilot's {lo}-{hi} (diagonal bound)"
            ));
        }
    }
    for (axis, d) in ["xy", "xz", "yz"].iter().zip(off_diagonal) {
        if d.abs() >= off {
            failures.push(format!(
                "matrix {axis} {d:.3} is beyond ArduPilot's ±{off} (off-diagonal bound)"
            ));
        }
    }
    // And what every 3-D calibration that enters must be
    // (Calibration3D::validate), so none is accepted and stored that the
    // next start would refuse.
    let calibration = crate::model::calibration3::Calibration3D {
        offset: fit.offset,
        matrix: fit.matrix,
        r: fit.r,
    };
    if let Err(e) = calibration.validate() {
        failures.push(format!("not a calibration: {e}"));
    }
    if failures.is_empty() {
        Ok(())
    } else {
        Err(failures.join("; "))
    }
}
