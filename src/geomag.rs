//! The field the Earth should give: NOAA's World Magnetic Model (WMM2020
//! and WMM2025, by the `world_magnetic_model` crate) at a place and date,
//! and how a measured field compares with it.
//!
//! Declination D is the angle from true north to magnetic north, positive
//! east: a true heading is the magnetic heading plus D. Inclination I is
//! the field's angle below the horizontal (positive where it points down,
//! in the northern hemisphere), as in [`crate::model::tilt`].

use serde::Serialize;
use world_magnetic_model::GeomagneticField;
use world_magnetic_model::time::{Date, Month};
use world_magnetic_model::uom::si::angle::degree;
use world_magnetic_model::uom::si::f32::{Angle, Length};
use world_magnetic_model::uom::si::length::meter;
use world_magnetic_model::uom::si::magnetic_flux_density::nanotesla;

use crate::model::gyro::COMPARISON_BATCHES;
use crate::model::tilt::RobustSpread;

/// Why the model gave no field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeomagError {
    #[error("'{text}' is not a date: give it as YYYY-MM-DD (for example 2026-03-15)")]
    BadDate { text: String },
    #[error(
        "the World Magnetic Model has no field for {place}: {source}; the bundled models (WMM2020, WMM2025) cover 2020-01-01 to 2029-12-31, latitudes -90..90°, longitudes -180..180° and heights -1 km to 850 km"
    )]
    Model {
        place: String,
        source: world_magnetic_model::Error,
    },
    #[error("the {what} {value} is not a finite number")]
    NotFinite { what: &'static str, value: f64 },
}

/// A date of the proleptic Gregorian calendar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CivilDate {
    pub year: i32,
    pub month: u8,
    pub day: u8,
}

impl CivilDate {
    /// From `YYYY-MM-DD`.
    pub fn parse(text: &str) -> Result<CivilDate, GeomagError> {
        let bad = || GeomagError::BadDate {
            text: crate::io::excerpt(text).to_string(),
        };
        let parts: Vec<&str> = text.trim().split('-').collect();
        let [y, m, d] = parts.as_slice() else {
            return Err(bad());
        };
        if y.len() != 4 || m.len() != 2 || d.len() != 2 {
            return Err(bad());
        }
        let date = CivilDate {
            year: y.parse().map_err(|_| bad())?,
            month: m.parse().map_err(|_| bad())?,
            day: d.parse().map_err(|_| bad())?,
        };
        date.to_date().map(|_| date).ok_or_else(bad)
    }

    /// The date `days` after 1970-01-01 (a Unix time's day).
    pub fn from_unix_days(days: i64) -> Option<CivilDate> {
        // Julian day number of 1970-01-01.
        let jd = i32::try_from(2_440_588 + days).ok()?;
        let date = Date::from_julian_day(jd).ok()?;
        Some(CivilDate {
            year: date.year(),
            month: date.month() as u8,
            day: date.day(),
        })
    }

    /// Today, by the system clock (UTC).
    pub fn today() -> Option<CivilDate> {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .ok()?
            .as_secs();
        CivilDate::from_unix_days(i64::try_from(secs / 86_400).ok()?)
    }

    fn to_date(self) -> Option<Date> {
        let month = Month::try_from(self.month).ok()?;
        Date::from_calendar_date(self.year, month, self.day).ok()
    }
}

impl std::fmt::Display for CivilDate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

/// Where and when.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Place {
    /// WGS 84 latitude, degrees, north positive.
    pub latitude_deg: f64,
    /// WGS 84 longitude, degrees, east positive.
    pub longitude_deg: f64,
    /// Height above the WGS 84 ellipsoid, metres.
    pub altitude_m: f64,
    pub date: CivilDate,
}

/// The World Magnetic Model's field at a place and date, with the
/// model's own uncertainties (1σ, NOAA's error model).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ModelField {
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub altitude_m: f64,
    /// YYYY-MM-DD.
    #[serde(serialize_with = "serialize_date")]
    pub date: CivilDate,
    pub declination_deg: f64,
    pub declination_uncertainty_deg: f64,
    pub inclination_deg: f64,
    pub inclination_uncertainty_deg: f64,
    /// Total intensity F, nanotesla.
    pub total_intensity_nt: f64,
    pub total_intensity_uncertainty_nt: f64,
    /// Horizontal intensity H, nanotesla.
    pub horizontal_intensity_nt: f64,
}

fn serialize_date<S: serde::Serializer>(date: &CivilDate, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(date)
}

/// The World Magnetic Model at `place`.
pub fn model_field(place: &Place) -> Result<ModelField, GeomagError> {
    for (what, value) in [
        ("latitude", place.latitude_deg),
        ("longitude", place.longitude_deg),
        ("altitude", place.altitude_m),
    ] {
        if !value.is_finite() {
            return Err(GeomagError::NotFinite { what, value });
        }
    }
    let label = format!(
        "latitude {}°, longitude {}°, {} m on {}",
        place.latitude_deg, place.longitude_deg, place.altitude_m, place.date
    );
    let date = place.date.to_date().ok_or_else(|| GeomagError::BadDate {
        text: place.date.to_string(),
    })?;
    let field = GeomagneticField::new(
        Length::new::<meter>(place.altitude_m as f32),
        Angle::new::<degree>(place.latitude_deg as f32),
        Angle::new::<degree>(place.longitude_deg as f32),
        date,
    )
    .map_err(|source| GeomagError::Model {
        place: label,
        source,
    })?;
    let deg = |a: Angle| f64::from(a.get::<degree>());
    let nt = |b: world_magnetic_model::uom::si::f32::MagneticFluxDensity| {
        f64::from(b.get::<nanotesla>())
    };
    Ok(ModelField {
        latitude_deg: place.latitude_deg,
        longitude_deg: place.longitude_deg,
        altitude_m: place.altitude_m,
        date: place.date,
        declination_deg: deg(field.declination()),
        declination_uncertainty_deg: deg(field.declination_uncertainty()),
        inclination_deg: deg(field.inclination()),
        inclination_uncertainty_deg: deg(field.inclination_uncertainty()),
        total_intensity_nt: nt(field.f()),
        total_intensity_uncertainty_nt: nt(field.f_uncertainty()),
        horizontal_intensity_nt: nt(field.h()),
    })
}

/// Units of a magnetometer's readings (after calibration, whose W has
/// determinant 1, they keep the raw units).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
pub enum MagUnits {
    /// gauss (1 G = 100 000 nT): the HMC5883L's and LSM303's datasheets.
    #[value(name = "gauss", alias = "G")]
    Gauss,
    /// microtesla.
    #[value(name = "uT", alias = "ut")]
    Microtesla,
    /// nanotesla.
    #[value(name = "nT", alias = "nt")]
    Nanotesla,
}

impl MagUnits {
    /// Nanotesla in one unit.
    pub fn nanotesla(self) -> f64 {
        match self {
            MagUnits::Gauss => 100_000.0,
            MagUnits::Microtesla => 1_000.0,
            MagUnits::Nanotesla => 1.0,
        }
    }

    /// From a calibration's `units` string; `None` for anything else
    /// (counts, g, unknown).
    pub fn from_name(name: &str) -> Option<MagUnits> {
        match name.trim() {
            "gauss" | "G" | "Gs" => Some(MagUnits::Gauss),
            "uT" | "µT" | "ut" | "microtesla" => Some(MagUnits::Microtesla),
            "nT" | "nt" | "nanotesla" => Some(MagUnits::Nanotesla),
            _ => None,
        }
    }
}

/// How far a magnetometer's field magnitude may be from the truth from its
/// gain alone: the HMC5883L's gain tolerance is ±5 % (datasheet, "Gain
/// Tolerance", all gain settings); a calibration with det W = 1 keeps the
/// sensor's mean gain, so its r carries that tolerance.
pub const GAIN_TOLERANCE: f64 = 0.05;

/// How far the measured inclination may be from the truth from the two
/// chips' alignment on the board alone, degrees: each chip's axes may be
/// off the board's by its cross-axis sensitivity, ±2 % for the MPU-6050
/// (PS-MPU-6000A-00 §6.2, "Cross-Axis Sensitivity": atan 0.02 = 1.15°),
/// and a separately calibrated magnetometer and accelerometer are not
/// aligned to each other by their fits (W is symmetric: no rotation), so
/// the two add: 2 × 1.15°.
pub const ALIGNMENT_ALLOWANCE_DEG: f64 = 2.0 * 1.145_762_838_175_079;

/// Standard errors between the measured and the model's value that count
/// as a disagreement (with the allowances above).
pub const DISAGREEMENT_SIGMAS: f64 = 3.0;

/// The measured field beside the model's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldComparison {
    /// The measured inclination: median and robust spread over the
    /// samples, degrees.
    pub measured_inclination_deg: f64,
    pub measured_inclination_spread_deg: f64,
    pub model_inclination_deg: f64,
    /// The largest difference the sensors and the model allow, degrees.
    pub inclination_allowed_deg: f64,
    pub inclination_agrees: bool,
    /// The measured magnitude, nanotesla (`None`: the magnetometer's units
    /// are unknown, so it is not compared).
    pub measured_intensity_nt: Option<f64>,
    pub model_intensity_nt: f64,
    pub intensity_allowed_nt: f64,
    pub intensity_agrees: Option<bool>,
    /// What the comparison means, in a sentence.
    pub verdict: String,
}

/// The largest difference between a measured inclination (median and
/// robust spread over the samples) and the model's that the sensors and
/// the model allow, degrees: the two chips' alignment
/// ([`ALIGNMENT_ALLOWANCE_DEG`]) plus [`DISAGREEMENT_SIGMAS`] of the
/// model's 1σ and of the median's standard error, 1.25 × spread /
/// √[`COMPARISON_BATCHES`] (the median's efficiency, over about 20
/// independent stretches of samples that are not independent).
pub fn inclination_allowed_deg(inclination: &RobustSpread, model: &ModelField) -> f64 {
    let se_median = 1.2533 * inclination.spread / (COMPARISON_BATCHES as f64).sqrt();
    ALIGNMENT_ALLOWANCE_DEG
        + DISAGREEMENT_SIGMAS
            * (model.inclination_uncertainty_deg.powi(2) + se_median.powi(2)).sqrt()
}

/// The largest difference between a measured field magnitude and the
/// model's total intensity F that the sensor and the model allow,
/// nanotesla: the magnetometer's gain tolerance ([`GAIN_TOLERANCE`] of F)
/// plus [`DISAGREEMENT_SIGMAS`] of the model's 1σ of F. NOAA's error model
/// (WMM2025 Technical Report §3.4: 138 nT for F) is the model's total
/// error against observatory and satellite data, the crustal field it
/// leaves out included, so ordinary local anomalies are inside it; iron
/// near the sensor is not.
pub fn intensity_allowed_nt(model: &ModelField) -> f64 {
    GAIN_TOLERANCE * model.total_intensity_nt
        + DISAGREEMENT_SIGMAS * model.total_intensity_uncertainty_nt
}

/// Whether a measured inclination that disagrees with the model's has its
/// size and the opposite sign: the magnetometer's axes mirrored against
/// the accelerometer's.
pub fn is_mirrored(measured_deg: f64, model: &ModelField, allowed_deg: f64) -> bool {
    measured_deg * model.inclination_deg < 0.0
        && (measured_deg + model.inclination_deg).abs() <= allowed_deg
}

/// The name of the World Magnetic Model the bundled crate evaluates on
/// `date`: each coefficient set serves the five years from its epoch
/// (WMM2020 for 2020-2024, WMM2025 for 2025-2029).
pub fn wmm_name(date: CivilDate) -> String {
    format!("WMM{}", date.year - date.year.rem_euclid(5))
}

/// Compares the measured inclination (over the samples) and magnitude
/// (the calibration's r, or the readings' median magnitude, in
/// nanotesla) with the model's. The inclination's median is known to
/// 1.25 × spread / √[`COMPARISON_BATCHES`] (the median's efficiency, over
/// about 20 independent stretches of a recording whose samples are not
/// independent).
pub fn compare_field(
    inclination: &RobustSpread,
    intensity_nt: Option<f64>,
    model: &ModelField,
) -> FieldComparison {
    let inclination_allowed = inclination_allowed_deg(inclination, model);
    let inclination_agrees =
        (inclination.median - model.inclination_deg).abs() <= inclination_allowed;
    let intensity_allowed = intensity_allowed_nt(model);
    let intensity_agrees = intensity_nt
        .filter(|v| v.is_finite())
        .map(|v| (v - model.total_intensity_nt).abs() <= intensity_allowed);
    let verdict = match (inclination_agrees, intensity_agrees) {
        (true, Some(true)) => "the measured field agrees with the model's within what the sensors' accuracy allows".to_string(),
        (true, None) => "the measured inclination agrees with the model's within what the sensors' accuracy allows; the magnitude is not compared (give the magnetometer's units with --mag-units)".to_string(),
        (i, m) => {
            let mut what = Vec::new();
            if !i {
                what.push(format!(
                    "inclination {:.1}° against the model's {:.1}° (allowed ±{:.1}°)",
                    inclination.median, model.inclination_deg, inclination_allowed
                ));
            }
            if m == Some(false) {
                what.push(format!(
                    "magnitude {:.0} nT against the model's {:.0} nT (allowed ±{:.0} nT)",
                    intensity_nt.unwrap_or(f64::NAN),
                    model.total_intensity_nt,
                    intensity_allowed
                ));
            }
            let mirrored = !i && is_mirrored(inclination.median, model, inclination_allowed);
            let cause = if mirrored {
                "the measured dip has the model's size and the opposite sign: the magnetometer's axes are mirrored against the accelerometer's (negate all three in --mag-axes, or one axis of a chip whose sign is flipped)"
            } else {
                "the site's field is disturbed (iron, steel, currents nearby), the calibration is off, or the place or date is wrong"
            };
            format!(
                "the measured field disagrees with the model's beyond what the sensors' accuracy allows ({}): {cause}",
                what.join("; ")
            )
        }
    };
    FieldComparison {
        measured_inclination_deg: inclination.median,
        measured_inclination_spread_deg: inclination.spread,
        model_inclination_deg: model.inclination_deg,
        inclination_allowed_deg: inclination_allowed,
        inclination_agrees,
        measured_intensity_nt: intensity_nt,
        model_intensity_nt: model.total_intensity_nt,
        intensity_allowed_nt: intensity_allowed,
        intensity_agrees,
        verdict,
    }
}
