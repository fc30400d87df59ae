//! The report of `fieldcal heading`: the board's headings, the field
//! against the model and the check against the gyro
//! ([`crate::model::heading_analysis`]), as text for a person and as JSON
//! for a program.

use std::path::PathBuf;

use serde_json::{Value, json};

use crate::geomag::MagUnits;
use crate::model::gyro::HeadingCheck;
use crate::model::heading_analysis::{
    DeclinationSource, GyroChecks, HeadingReport, Sensor, fusion_verdict, max_abs,
};
use crate::model::tilt::{MAX_GAP_PERIODS, RobustSpread};

fn finite(v: f64) -> Value {
    if v.is_finite() { json!(v) } else { Value::Null }
}

fn units_name(u: MagUnits) -> &'static str {
    match u {
        MagUnits::Gauss => "gauss",
        MagUnits::Microtesla => "uT",
        MagUnits::Nanotesla => "nT",
    }
}

/// The report as one JSON object.
pub fn heading_json(report: &HeadingReport) -> Value {
    let r = report;
    json!({
        "magnetometer": magnetometer_json(r),
        "accelerometer": accelerometer_json(r),
        "axes_auto": r.choice.as_ref().map(|c| json!({
            "chosen": c.chosen.map.to_string(),
            "inclination_spread_deg": c.chosen.inclination.spread,
            "runner_up": c.runner_up.map.to_string(),
            "runner_up_spread_deg": c.runner_up.inclination.spread,
            "tilt_range_deg": c.tilt_range_deg,
            "mirror_rule": c.mirror_rule,
        })),
        "forward": r.forward,
        "up": r.up,
        "north": r.declination.north(),
        "declination_deg": r.declination.deg,
        "declination_source": r.declination.source.name(),
        "n": r.n,
        "n_heading": r.stats.n_heading,
        "tilt_deg": {
            "median": r.stats.tilt.map(|t| t.median),
            "max": finite(r.stats.max_tilt),
        },
        "inclination_deg": spread_json(r.stats.inclination.as_ref()),
        "field": {
            "magnitude": finite(r.field.magnitude),
            "units": r.field.units.map(units_name),
            "magnitude_nt": r.field.magnitude_nt.map(finite),
            "source": r.field.source,
        },
        "model": r.model,
        "comparison": r.comparison,
        "vertical": match &r.fusion {
            None => json!({"source": "accelerometer"}),
            Some(f) => json!({
                "source": "accelerometer+gyro",
                "rates": {"file": f.file.display().to_string(), "columns": f.columns},
                "tau_s": f.tau_s,
            }),
        },
        "gyro": r.gyro.as_ref().map(|g| gyro_json(r, g)),
    })
}

fn sensor_json(s: &Sensor) -> Value {
    json!({
        "file": s.file.display().to_string(),
        "columns": s.columns,
        "calibration": s.calibration.as_ref().map(|p| p.display().to_string()),
    })
}

fn magnetometer_json(r: &HeadingReport) -> Value {
    let mut mag = sensor_json(&r.mag);
    mag["units"] = json!(r.field.units.map(units_name));
    mag["axes"] = json!(r.map.to_string());
    mag["axes_source"] = json!(if r.choice.is_some() { "auto" } else { "given" });
    mag
}

fn accelerometer_json(r: &HeadingReport) -> Value {
    let mut accel = sensor_json(&r.accel);
    accel["interpolated"] = json!(r.interpolation.is_some());
    if let Some(i) = &r.interpolation {
        accel["period_s"] = json!(i.period);
        accel["outside"] = json!(i.outside);
        accel["in_gaps"] = json!(i.in_gaps);
    }
    accel
}

fn spread_json(s: Option<&RobustSpread>) -> Value {
    s.map_or(
        Value::Null,
        |s| json!({"median": s.median, "spread": s.spread, "n": s.n}),
    )
}

fn check_json(c: &Result<HeadingCheck, String>) -> Value {
    let c = match c {
        Ok(c) => c,
        Err(e) => return json!({"error": e}),
    };
    json!({
        "rms_deg": c.rms_deg,
        "max_abs_deg": max_abs(c),
        "peak_to_peak_deg": c.peak_to_peak_deg,
        "n": c.n,
        "gyro_scale": c.gyro_scale,
        "gyro_bias_deg_s": c.gyro_bias_deg_s,
    })
}

fn gyro_json(r: &HeadingReport, g: &GyroChecks) -> Value {
    let compensation = r.compensation(g);
    let delta = compensation.as_ref().map(|(d, _)| *d);
    let fusion_gain = match (&g.accel_only, &g.tilt) {
        (Some(Ok(a)), Ok(t)) => Some(t.worse_by(a)),
        _ => None,
    };
    json!({
        "column": g.column,
        "tilt_compensated": check_json(&g.tilt),
        "tilt_compensated_accel_only": g.accel_only.as_ref().map(check_json),
        "level": check_json(&g.level),
        "level_worse_by_deg": delta.map(|d| finite(d.delta_rms_deg)),
        "level_worse_by_se_deg": delta.map(|d| finite(d.se_deg)),
        "accel_only_worse_by_deg": fusion_gain.map(|d| finite(d.delta_rms_deg)),
        "accel_only_worse_by_se_deg": fusion_gain.map(|d| finite(d.se_deg)),
        "verdict": compensation.map(|(_, verdict)| verdict),
    })
}

/// The report as text for a person.
pub fn heading_text(report: &HeadingReport) -> String {
    let mut s = sources_text(report);
    s += &headings_text(report);
    s += &field_text(report);
    if let Some(g) = &report.gyro {
        s += &gyro_text(report, g);
    }
    s
}

/// Where the readings came from and how they were put on the board.
fn sources_text(r: &HeadingReport) -> String {
    let mut s = String::new();
    let cal = |c: &Option<PathBuf>| match c {
        Some(p) => format!("calibrated by {}", p.display()),
        None => "raw (no calibration)".to_string(),
    };
    s += &format!(
        "magnetometer: {} ({}), {}\n",
        r.mag.file.display(),
        r.mag.columns.join(", "),
        cal(&r.mag.calibration)
    );
    s += &format!(
        "accelerometer: {} ({}), {}",
        r.accel.file.display(),
        r.accel.columns.join(", "),
        cal(&r.accel.calibration)
    );
    if let Some(i) = &r.interpolation {
        s += &format!(
            "; interpolated to the magnetometer's times (period {:.4} s; {} outside its span, {} in gaps over {} periods)",
            i.period, i.outside, i.in_gaps, MAX_GAP_PERIODS
        );
    }
    s += "\n";
    if let Some(f) = &r.fusion {
        s += &format!(
            "vertical: the accelerometer's, steadied by the gyro {} ({}) with a time constant of {:.2} s\n",
            f.file.display(),
            f.columns.join(", "),
            f.tau_s
        );
    }
    match &r.choice {
        Some(c) => {
            s += &format!(
                "magnetometer axes on the board: {} (auto: the dip's robust SD {:.2}°, the next best mapping {} {:.2}°; the board's vertical moved up to {:.0}°; {})\n",
                r.map,
                c.chosen.inclination.spread,
                c.runner_up.map,
                c.runner_up.inclination.spread,
                c.tilt_range_deg,
                c.mirror_rule
            );
        }
        None => s += &format!("magnetometer axes on the board: {}\n", r.map),
    }
    s
}

/// Which heading, from which north, and what the samples hold.
fn headings_text(r: &HeadingReport) -> String {
    let mut s = format!(
        "heading of the board's {} axis (up {}), clockwise from {} north",
        r.forward,
        r.up,
        r.declination.north()
    );
    match r.declination.source {
        DeclinationSource::Wmm => {
            s += &format!(
                ", declination {:+.2}° from the World Magnetic Model\n",
                r.declination.deg
            )
        }
        DeclinationSource::Given => {
            s += &format!(", declination {:+.2}° as given\n", r.declination.deg)
        }
        DeclinationSource::None => s += " (no declination given)\n",
    }
    s += &format!("samples: {}, with a heading: {}\n", r.n, r.stats.n_heading);
    if let Some(t) = &r.stats.tilt {
        s += &format!(
            "tilt: median {:.1}°, up to {:.1}°\n",
            t.median, r.stats.max_tilt
        );
    }
    if let Some(i) = &r.stats.inclination {
        s += &format!(
            "measured inclination: {:.2}° (robust SD {:.2}° over the samples)\n",
            i.median, i.spread
        );
    }
    s
}

/// The measured field, the model's, and how they compare.
fn field_text(r: &HeadingReport) -> String {
    let f = &r.field;
    let mut s = match (f.units, f.magnitude_nt) {
        (Some(u), Some(nt)) => format!(
            "measured field: {:.4} {} = {:.0} nT ({})\n",
            f.magnitude,
            units_name(u),
            nt,
            f.source
        ),
        _ => format!(
            "measured field: {:.4} in the readings' units ({}; units unknown: --mag-units)\n",
            f.magnitude, f.source
        ),
    };
    if let Some(m) = &r.model {
        s += &format!(
            "World Magnetic Model at {:.4}°, {:.4}°, {} m on {}: declination {:+.2}° ± {:.2}°, inclination {:.2}° ± {:.2}°, field {:.0} ± {:.0} nT\n",
            m.latitude_deg,
            m.longitude_deg,
            m.altitude_m,
            m.date,
            m.declination_deg,
            m.declination_uncertainty_deg,
            m.inclination_deg,
            m.inclination_uncertainty_deg,
            m.total_intensity_nt,
            m.total_intensity_uncertainty_nt
        );
    }
    if let Some(c) = &r.comparison {
        s += &format!("field against the model: {}\n", c.verdict);
    }
    s
}

/// The headings against the gyro, and what that says.
fn gyro_text(r: &HeadingReport, g: &GyroChecks) -> String {
    let mut s = format!(
        "against the gyro '{}' (its offset, scale and bias fitted; counter-clockwise about up is positive):\n",
        g.column
    );
    let mut lines = Vec::with_capacity(3);
    match &g.accel_only {
        Some(a) => {
            lines.push(("tilt-compensated (accelerometer and gyro)", &g.tilt));
            lines.push(("tilt-compensated (accelerometer alone)", a));
        }
        None => lines.push(("tilt-compensated", &g.tilt)),
    }
    lines.push(("level (uncompensated)", &g.level));
    for (what, c) in lines {
        match c {
            Ok(c) => {
                s += &format!(
                    "  {what}: rms {:.2}°, max {:.2}° over {} samples (gyro scale {:+.3})\n",
                    c.rms_deg,
                    max_abs(c),
                    c.n,
                    c.gyro_scale
                )
            }
            Err(e) => s += &format!("  {what}: not checked: {e}\n"),
        }
    }
    if let Some((d, verdict)) = r.compensation(g) {
        s += &format!(
            "  the level heading is worse by {:+.2}° ± {:.2}° rms (on the samples both have)\n",
            d.delta_rms_deg, d.se_deg
        );
        s += &format!("  {verdict}\n");
    }
    if let (Some(Ok(a)), Ok(t)) = (&g.accel_only, &g.tilt) {
        let d = t.worse_by(a);
        s += &format!(
            "  the accelerometer alone is worse by {:+.2}° ± {:.2}° rms: {}\n",
            d.delta_rms_deg,
            d.se_deg,
            fusion_verdict(d)
        );
    }
    s
}
