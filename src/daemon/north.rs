//! True north and the Earth's field for the daemon's magnetometers.
//!
//! A magnetometer sensor with `declination_deg = D` (degrees east of true
//! north), or a `[sensor.location]` (`latitude`, `longitude`, `height_m`,
//! `date`) from which NOAA's World Magnetic Model gives D ([`crate::geomag`]),
//! publishes beside each magnetic `heading_deg` a `true_heading_deg`: the
//! magnetic heading plus D, in [0, 360). `[daemon] declination_deg` or
//! `[daemon.location]` is the default of every magnetometer of a device
//! source (a csv sensor's columns name no field: it takes its own keys
//! only), as ArduPilot's `COMPASS_DEC` is the vehicle's.
//!
//! With a location, a 3-axis magnetometer's CALIBRATION puts the fitted
//! field beside the model's ([`earth`]): the magnitude r against the total
//! intensity F (when `lsb_per_gauss` gives the units) and the inclination
//! measured with its tilt accelerometer against the model's, within the
//! allowances of [`crate::geomag`] (the chip's gain tolerance, the two
//! chips' alignment, NOAA's published 1σ of the model).

use serde::{Deserialize, Serialize};

use crate::geomag::{
    self, CivilDate, GeomagError, ModelField, Place, inclination_allowed_deg, intensity_allowed_nt,
    is_mirrored, model_field, wmm_name,
};
use crate::model::tilt::RobustSpread;

/// Heights the bundled World Magnetic Model covers, metres (the crate's
/// `MIN_HEIGHT_KM`, `MAX_HEIGHT_KM`: -1 km to 850 km, the WMM's
/// validity from the Technical Report §1.2).
pub const HEIGHT_RANGE_M: (f64, f64) = (-1_000.0, 850_000.0);

/// `[sensor.location]` or `[daemon.location]` as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LocationKeys {
    /// WGS 84 latitude, degrees north.
    pub latitude: f64,
    /// WGS 84 longitude, degrees east.
    pub longitude: f64,
    /// Height above the WGS 84 ellipsoid, metres; default 0.
    #[serde(default)]
    pub height_m: f64,
    /// `YYYY-MM-DD`; default the host's date when the configuration is
    /// read (at start and at each reload).
    pub date: Option<String>,
}

/// A magnetometer's true north, resolved from its configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct North {
    /// Degrees east of true north: true heading = magnetic heading + D.
    pub declination_deg: f64,
    /// `"config"`, or `"WMM2025 at 50.1109,8.6821,2026-06-01"`.
    pub source: String,
    /// The model's field at the place (with a location).
    pub model: Option<ModelField>,
    /// The date is the host's: the location gives none.
    pub date_is_today: bool,
}

/// Why a `declination_deg` or a location was refused: the sub-key
/// (`""` for the key itself, else `latitude`, `longitude`, `height_m`,
/// `date`) and what to do.
#[derive(Debug, Clone, PartialEq)]
pub struct NorthError {
    pub key: &'static str,
    pub problem: String,
}

impl North {
    /// A declination given in the configuration.
    pub fn declination(d: f64) -> Result<North, NorthError> {
        if !(d.is_finite() && (-180.0..=180.0).contains(&d)) {
            return Err(NorthError {
                key: "",
                problem: format!(
                    "{d} is not a declination: give degrees east of true north (west negative), \
                     -180 to 180"
                ),
            });
        }
        Ok(North {
            declination_deg: d,
            source: "config".into(),
            model: None,
            date_is_today: false,
        })
    }

    /// The World Magnetic Model at a location; `today` is the date used
    /// when the location gives none.
    pub fn location(keys: &LocationKeys, today: Option<CivilDate>) -> Result<North, NorthError> {
        let err = |key, problem: String| NorthError { key, problem };
        let (lat, lon, h) = (keys.latitude, keys.longitude, keys.height_m);
        if !(lat.is_finite() && (-90.0..=90.0).contains(&lat)) {
            return Err(err(
                "latitude",
                format!("{lat}: give WGS 84 degrees north, -90 to 90"),
            ));
        }
        if !(lon.is_finite() && (-180.0..=180.0).contains(&lon)) {
            return Err(err(
                "longitude",
                format!("{lon}: give WGS 84 degrees east, -180 to 180 (west negative)"),
            ));
        }
        let (lo, hi) = HEIGHT_RANGE_M;
        if !(h.is_finite() && (lo..=hi).contains(&h)) {
            return Err(err(
                "height_m",
                format!(
                    "{h} m: give the height above the WGS 84 ellipsoid in metres, {lo} to {hi} \
                     (the World Magnetic Model's range)"
                ),
            ));
        }
        let (date, date_is_today) = match &keys.date {
            Some(text) => (
                CivilDate::parse(text).map_err(|e| err("date", e.to_string()))?,
                false,
            ),
            None => (
                today.ok_or_else(|| {
                    err(
                        "date",
                        "the host's clock gives no date: give the date as YYYY-MM-DD".into(),
                    )
                })?,
                true,
            ),
        };
        let model = model_field(&Place {
            latitude_deg: lat,
            longitude_deg: lon,
            altitude_m: h,
            date,
        })
        .map_err(|e| match e {
            GeomagError::Model { .. } if date_is_today => err(
                "date",
                format!(
                    "no date given, and the host's date: {e}; give a date within the model's range"
                ),
            ),
            other => err("date", other.to_string()),
        })?;
        Ok(North {
            declination_deg: model.declination_deg,
            source: format!("{} at {lat},{lon},{date}", wmm_name(date)),
            model: Some(model),
            date_is_today,
        })
    }

    /// The true heading of a magnetic heading, in [0, 360).
    pub fn true_heading(&self, magnetic_deg: f64) -> f64 {
        let h = crate::model::heading::wrap_degrees(magnetic_deg + self.declination_deg);
        // rem_euclid of a tiny negative number rounds to 360.
        if h >= 360.0 { 0.0 } else { h }
    }

    /// The model's 1σ of the declination, with a location.
    pub fn uncertainty_deg(&self) -> Option<f64> {
        self.model.as_ref().map(|m| m.declination_uncertainty_deg)
    }

    /// One line for the log: where the declination comes from, and that
    /// the date is the host's when the location gives none.
    pub fn describe(&self) -> String {
        let mut s = format!(
            "true north: declination {:+.2}° ({})",
            self.declination_deg, self.source
        );
        if let Some(m) = &self.model {
            s.push_str(&format!(
                ", ± {:.2}°; field {:.0} nT, inclination {:.2}°",
                m.declination_uncertainty_deg, m.total_intensity_nt, m.inclination_deg
            ));
        }
        if self.date_is_today {
            s.push_str("; the date is the host's today (the location gives no date)");
        }
        s
    }
}

/// The measured field beside the World Magnetic Model's, in a 3-axis
/// magnetometer's CALIBRATION (`earth`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Earth {
    /// `WMM2025` or `WMM2020`.
    pub model: String,
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub height_m: f64,
    /// YYYY-MM-DD.
    pub date: String,
    /// The model's total intensity F and its 1σ, nanotesla.
    pub field_nt: f64,
    pub field_uncertainty_nt: f64,
    /// The model's inclination and its 1σ, degrees.
    pub inclination_deg: f64,
    pub inclination_uncertainty_deg: f64,
    /// The fitted field radius r in nanotesla (with `lsb_per_gauss`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub r_nt: Option<f64>,
    /// r / F.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ratio: Option<f64>,
    /// The largest |r / F − 1| the chip's gain and the model allow.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ratio_allowed: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub magnitude_agrees: Option<bool>,
    /// The inclination measured with the tilt accelerometer: the median
    /// and robust spread over the fitted samples, and how many.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_inclination_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_inclination_spread_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_inclination_n: Option<usize>,
    /// Whether the tilt accelerometer was corrected by its calibration
    /// when the inclination was measured: `"calibrated"` or `"raw"` (not
    /// calibrated yet; its zero-g bias and gains tilt the vertical).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_inclination_accelerometer: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub inclination_allowed_deg: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub inclination_agrees: Option<bool>,
    /// What the comparison says, in a sentence.
    pub verdict: String,
}

/// The inclination measured over a fit's samples with the tilt
/// accelerometer beside each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredDip {
    /// Median, robust spread and count, degrees.
    pub spread: RobustSpread,
    /// Whether the accelerometer's readings were corrected by its
    /// calibration (false: raw, not calibrated yet).
    pub accelerometer_calibrated: bool,
}

/// The fitted field beside the model's, when `north` has a location: `r`
/// the fitted radius in counts, `lsb_per_gauss` the units when
/// configured, `inclination` the measured inclination over the fitted
/// samples or why there is none.
pub fn earth(
    north: &North,
    r: f64,
    lsb_per_gauss: Option<f64>,
    inclination: Result<MeasuredDip, String>,
) -> Option<Earth> {
    let m = north.model.as_ref()?;
    let f = m.total_intensity_nt;
    let r_nt = lsb_per_gauss
        .filter(|u| *u > 0.0)
        .map(|u| r / u * geomag::MagUnits::Gauss.nanotesla())
        .filter(|v| v.is_finite());
    let ratio = r_nt.map(|v| v / f);
    let ratio_allowed = intensity_allowed_nt(m) / f;
    let magnitude_agrees = ratio.map(|q| (q - 1.0).abs() <= ratio_allowed);
    let raw_accel = inclination
        .as_ref()
        .is_ok_and(|d| !d.accelerometer_calibrated);
    // Said beside the figure when the accelerometer was not corrected.
    let with = if raw_accel {
        " (with the raw, uncalibrated accelerometer)"
    } else {
        ""
    };
    let incl = inclination.as_ref().ok().map(|d| {
        let i = &d.spread;
        let allowed = inclination_allowed_deg(i, m);
        (i, allowed, (i.median - m.inclination_deg).abs() <= allowed)
    });

    let mut wrong = Vec::new();
    let mut causes = Vec::new();
    let mut right = Vec::new();
    let mut not_compared = Vec::new();
    match (ratio, magnitude_agrees) {
        (Some(q), Some(false)) => {
            wrong.push(format!(
                "r/F = {q:.3}: the field reads {:.0} nT where the model gives {f:.0} nT, \
                 allowed ±{:.1} %",
                r_nt.unwrap_or(f64::NAN),
                ratio_allowed * 100.0
            ));
            causes.push(
                "lsb_per_gauss is not the chip's gain setting, iron or a magnet near the sensor \
                 that does not turn with it adds its field (a magnetised environment), or the \
                 location or date is wrong",
            );
        }
        (Some(q), _) => right.push(format!("r/F = {q:.3}")),
        (None, _) => not_compared.push(
            "the magnitude cannot be compared: the sensor's units are unknown (give its counts \
             per gauss with lsb_per_gauss)"
                .to_string(),
        ),
    }
    match (&incl, &inclination) {
        (Some((i, allowed, false)), _) => {
            wrong.push(format!(
                "inclination {:.1}°{with} against the model's {:.1}°, allowed ±{allowed:.1}°",
                i.median, m.inclination_deg
            ));
            if raw_accel && !is_mirrored(i.median, m, *allowed) {
                causes.push(
                    "the tilt accelerometer is not calibrated yet (its zero-g bias and gains \
                     tilt the vertical it gives: compare again once it is)",
                );
            }
            causes.push(if is_mirrored(i.median, m, *allowed) {
                "the measured dip has the model's size and the opposite sign: the \
                 magnetometer's axes are mirrored against the tilt accelerometer's (check the \
                 order and signs of both sensors' axes)"
            } else {
                "iron near the sensor bends the field, the tilt accelerometer's axes are not \
                 the magnetometer's, or the location is wrong"
            });
        }
        (Some((i, _, true)), _) => right.push(format!(
            "inclination {:.1}°{with} against {:.1}°",
            i.median, m.inclination_deg
        )),
        (None, Err(why)) => not_compared.push(format!("the inclination is not compared: {why}")),
        (None, Ok(_)) => {}
    }
    let mut verdict = if !wrong.is_empty() {
        let mut causes_text = causes.join("; or ");
        causes_text.insert_str(0, ": ");
        format!(
            "the measured field disagrees with the {}'s beyond what the sensors and the model \
             allow ({}){causes_text}",
            wmm_name(m.date),
            wrong.join("; ")
        )
    } else if !right.is_empty() {
        format!(
            "the measured field agrees with the {}'s within what the sensors and the model \
             allow ({})",
            wmm_name(m.date),
            right.join(", ")
        )
    } else {
        "nothing measured could be compared with the model".to_string()
    };
    for n in &not_compared {
        verdict.push_str("; ");
        verdict.push_str(n);
    }
    Some(Earth {
        model: wmm_name(m.date),
        latitude_deg: m.latitude_deg,
        longitude_deg: m.longitude_deg,
        height_m: m.altitude_m,
        date: m.date.to_string(),
        field_nt: f,
        field_uncertainty_nt: m.total_intensity_uncertainty_nt,
        inclination_deg: m.inclination_deg,
        inclination_uncertainty_deg: m.inclination_uncertainty_deg,
        r_nt,
        ratio,
        ratio_allowed: ratio.map(|_| ratio_allowed),
        magnitude_agrees,
        measured_inclination_deg: incl.map(|(i, _, _)| i.median),
        measured_inclination_spread_deg: incl.map(|(i, _, _)| i.spread),
        measured_inclination_n: incl.map(|(i, _, _)| i.n),
        measured_inclination_accelerometer: inclination.as_ref().ok().map(|d| {
            if d.accelerometer_calibrated {
                "calibrated"
            } else {
                "raw"
            }
        }),
        inclination_allowed_deg: incl.map(|(_, a, _)| a),
        inclination_agrees: incl.map(|(_, _, ok)| ok),
        verdict,
    })
}
