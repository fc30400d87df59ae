//! `fieldcal heading`: a 3-axis magnetometer and accelerometer on one
//! board, calibrated, give the tilt-compensated heading of every sample.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde_json::{Value, json};

use fieldcal::geomag::{
    CivilDate, FieldComparison, MagUnits, ModelField, Place, compare_field, model_field,
};
use fieldcal::io::atomic::AtomicFile;
use fieldcal::model::gyro::{HeadingCheck, HeadingReference};
use fieldcal::model::tilt::{
    AxisChoice, AxisMap, Calibration3, HeadingSeries, RobustSpread, choose_axis_map,
    heading_series, parse_axis, resample, robust_spread,
};
use fieldcal::model::vertical::{fuse_vertical, rate_about_vertical};

use crate::HeadingArgs;
use crate::output::write_stdout;

/// One sensor's readings, calibrated (or not), on the magnetometer's times.
struct Sensor {
    file: PathBuf,
    columns: [String; 3],
    calibration: Option<PathBuf>,
    points: Vec<[f64; 3]>,
}

fn read_calibration(path: &Path, columns: &[String; 3], what: &str) -> Result<Calibration3> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the {what} calibration {}", path.display()))?;
    let cal = Calibration3::from_json(&text)
        .with_context(|| format!("{}: the {what} calibration", path.display()))?;
    if &cal.columns != columns {
        bail!(
            "{}: the {what} calibration was fitted to the columns {} and is applied to {}: give the calibration of these columns (or name the same columns)",
            path.display(),
            cal.columns.join(", "),
            columns.join(", ")
        );
    }
    Ok(cal)
}

/// `[FILE:]X,Y,Z` of option `flag`, naming `what` in its message.
fn split_columns(text: &str, flag: &str, what: &str) -> Result<(Option<PathBuf>, [String; 3])> {
    let (file, columns) = match text.rsplit_once(':') {
        Some((file, columns)) => (Some(PathBuf::from(file)), columns),
        None => (None, text),
    };
    let parts: Vec<&str> = columns.split(',').map(str::trim).collect();
    match parts.as_slice() {
        [x, y, z] if !x.is_empty() && !y.is_empty() && !z.is_empty() => Ok((
            file.filter(|f| !f.as_os_str().is_empty()),
            [x.to_string(), y.to_string(), z.to_string()],
        )),
        _ => bail!(
            "{flag} '{text}': give {what}'s three columns, X,Y,Z of the magnetometer's file or FILE:X,Y,Z of a second file on the same clock"
        ),
    }
}

/// Three columns read at the magnetometer's times: from its own file, or
/// from a second file on the same clock, interpolated.
struct Triplet {
    /// The file the columns came from.
    file: PathBuf,
    columns: [String; 3],
    values: Vec<[f64; 3]>,
    /// How a second file was put on the magnetometer's times.
    interpolation: Option<fieldcal::model::tilt::Resampled>,
}

/// With `signed`, a column named with a leading `-` is read negated (an
/// axis that points the other way).
fn read_triplet(
    spec: &str,
    flag: &str,
    what: &str,
    signed: bool,
    data: &fieldcal::sample::Dataset3,
    mag_file: &Path,
    mag_t: &[f64],
) -> Result<Triplet> {
    let (file, named) = split_columns(spec, flag, what)?;
    let signs = named.clone().map(|c| {
        if signed && c.starts_with('-') {
            -1.0
        } else {
            1.0
        }
    });
    let columns = named.clone().map(|c| {
        if signed {
            c.trim_start_matches('-').to_string()
        } else {
            c
        }
    });
    let mut t = read_columns(file, columns, flag, what, data, mag_file, mag_t)?;
    for v in &mut t.values {
        for (x, s) in v.iter_mut().zip(signs) {
            *x *= s;
        }
    }
    t.columns = named;
    Ok(t)
}

fn read_columns(
    file: Option<PathBuf>,
    columns: [String; 3],
    flag: &str,
    what: &str,
    data: &fieldcal::sample::Dataset3,
    mag_file: &Path,
    mag_t: &[f64],
) -> Result<Triplet> {
    let main = mag_file.display().to_string();
    let same_file = match &file {
        None => true,
        Some(f) => matches!(
            (std::fs::canonicalize(f), std::fs::canonicalize(mag_file)),
            (Ok(a), Ok(b)) if a == b
        ),
    };
    if same_file {
        let mut cols = Vec::with_capacity(3);
        for name in &columns {
            let Some(c) = data.covariate(name) else {
                let names: Vec<&str> = data.covariates.iter().map(|c| c.name.as_str()).collect();
                bail!(
                    "{main}: no column '{name}' for {what} among the numeric columns other than the magnetometer's and time (they are: {}); name them with {flag} X,Y,Z, or {flag} FILE:X,Y,Z for a second file",
                    if names.is_empty() {
                        "none".to_string()
                    } else {
                        names.join(", ")
                    }
                );
            };
            cols.push(c.values.clone());
        }
        return Ok(Triplet {
            file: mag_file.to_path_buf(),
            columns,
            values: (0..data.len())
                .map(|i| [cols[0][i], cols[1][i], cols[2][i]])
                .collect(),
            interpolation: None,
        });
    }
    let file = file.unwrap_or_default();
    let spec = fieldcal::io::csv::ColumnSpec {
        x: columns[0].clone(),
        y: columns[1].clone(),
        t: None,
    };
    let other = fieldcal::io::csv::read_dataset3(&file, &spec, &columns[2])?;
    let Some(t) = other.t.as_deref() else {
        bail!(
            "{}: {what}'s file has no time column (t, t_s, time or time_s): it is joined to {main} by time",
            file.display()
        );
    };
    let r = resample(what, t, &other.points, mag_t)
        .with_context(|| format!("{} against {main}", file.display()))?;
    Ok(Triplet {
        file,
        columns,
        values: r.values.clone(),
        interpolation: Some(r),
    })
}

fn axis(text: &str, flag: &str) -> Result<[f64; 3]> {
    parse_axis(text).with_context(|| {
        format!("{flag} '{text}': give an axis of the board, x, y or z, with a sign if it points the other way (-y)")
    })
}

pub fn heading(args: HeadingArgs) -> Result<()> {
    let mag_file = args.input.file.clone();
    let main = mag_file.display().to_string();
    let z = args.input.z_column()?.unwrap_or_else(|| "z".to_string());
    let data = args.input.read3(&z)?;
    let Some(mag_t) = data.t.clone() else {
        bail!(
            "{main}: the magnetometer's recording has no time column (t, t_s, time or time_s, or choose one with --t): the accelerometer and the gyro are joined to it by time"
        );
    };
    let mag_columns = [
        data.x_name.clone(),
        data.y_name.clone(),
        data.z_name.clone(),
    ];
    let forward = axis(&args.forward, "--forward")?;
    let up = axis(&args.up, "--up")?;

    // The magnetometer, calibrated.
    let mag_cal = match &args.mag_calibration {
        Some(p) => Some(read_calibration(p, &mag_columns, "magnetometer")?),
        None => None,
    };
    let mag: Vec<[f64; 3]> = match &mag_cal {
        Some(c) => data.points.iter().map(|p| c.apply(*p)).collect(),
        None => data.points.clone(),
    };

    // The accelerometer: columns of this file, or of a second one on the
    // same clock, interpolated to the magnetometer's times.
    let accel_in = read_triplet(
        &args.accel,
        "--accel",
        "the accelerometer",
        false,
        &data,
        &mag_file,
        &mag_t,
    )?;
    let interpolation = accel_in.interpolation;
    let accel_raw = accel_in.values;
    let accel_columns = accel_in.columns;
    let accel_cal = match &args.accel_calibration {
        Some(p) => Some(read_calibration(p, &accel_columns, "accelerometer")?),
        None => None,
    };
    let accel: Vec<[f64; 3]> = match &accel_cal {
        Some(c) => accel_raw.iter().map(|p| c.apply(*p)).collect(),
        None => accel_raw,
    };
    let accel_sensor = Sensor {
        file: accel_in.file,
        columns: accel_columns,
        calibration: args.accel_calibration.clone(),
        points: accel,
    };
    let mag_sensor = Sensor {
        file: mag_file.clone(),
        columns: mag_columns,
        calibration: args.mag_calibration.clone(),
        points: mag,
    };

    // The place: the model's declination and field.
    let model = match (args.latitude, args.longitude) {
        (Some(latitude_deg), Some(longitude_deg)) => {
            let date = match &args.date {
                Some(d) => CivilDate::parse(d)?,
                None => CivilDate::today()
                    .context("the system clock gives no date: give the recording's with --date")?,
            };
            Some(model_field(&Place {
                latitude_deg,
                longitude_deg,
                altitude_m: args.altitude,
                date,
            })?)
        }
        _ => None,
    };
    let (declination, declination_source) = match (&model, args.declination) {
        (Some(m), _) => (m.declination_deg, "wmm"),
        (None, Some(d)) if d.is_finite() && d.abs() <= 180.0 => (d, "given"),
        (None, Some(d)) => bail!("--declination {d}: give degrees east of true north, -180 to 180"),
        (None, None) => (0.0, "none"),
    };

    // The magnetometer's axes on the board.
    let (map, choice): (AxisMap, Option<AxisChoice>) = if args.mag_axes.trim() == "auto" {
        let choice = choose_axis_map(
            &mag_sensor.points,
            &accel_sensor.points,
            model.as_ref().map(|m| m.inclination_deg),
        )
        .with_context(|| format!("{main}: --mag-axes auto"))?;
        (choice.chosen.map, Some(choice))
    } else {
        (
            args.mag_axes
                .parse::<AxisMap>()
                .with_context(|| "--mag-axes".to_string())?,
            None,
        )
    };
    let body: Vec<[f64; 3]> = mag_sensor.points.iter().map(|m| map.apply(*m)).collect();

    // The board's vertical: the accelerometer's, or with --rates the
    // accelerometer's steadied by the gyro (the hand's accelerations out).
    let fusion = match &args.rates {
        None => None,
        Some(spec) => {
            let rates = read_triplet(spec, "--rates", "the gyro", true, &data, &mag_file, &mag_t)?;
            let to_rad = args.input.gyro_units.to_deg_per_second().to_radians();
            let rad: Vec<[f64; 3]> = rates.values.iter().map(|w| w.map(|v| v * to_rad)).collect();
            let up = fuse_vertical(&mag_t, &accel_sensor.points, &rad, args.fusion_tau)
                .context("--fusion-tau")?;
            Some(Fusion {
                file: rates.file,
                columns: rates.columns,
                tau_s: args.fusion_tau,
                up,
                rates: rates.values,
            })
        }
    };
    let series = match &fusion {
        Some(f) => heading_series(&body, &f.up, forward, up, declination)?,
        None => heading_series(&body, &accel_sensor.points, forward, up, declination)?,
    };
    let n_heading = series.heading_deg.iter().filter(|h| h.is_finite()).count();
    if n_heading == 0 {
        bail!(
            "{main}: no sample has a heading: each needs a field with a horizontal part and an accelerometer reading at its time (check --accel, the clocks, and --mag-axes)"
        );
    }
    let inclination = robust_spread(&series.inclination_deg);
    let tilt = robust_spread(&series.tilt_deg);
    let max_tilt = series
        .tilt_deg
        .iter()
        .copied()
        .filter(|t| t.is_finite())
        .fold(0.0, f64::max);

    // The field's magnitude, in the magnetometer's units.
    let units = args.mag_units.or_else(|| {
        mag_cal
            .as_ref()
            .and_then(|c| c.units.as_deref())
            .and_then(MagUnits::from_name)
    });
    let magnitude = match &mag_cal {
        Some(c) => c.calibration.r,
        None => {
            let norms: Vec<f64> = mag_sensor
                .points
                .iter()
                .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
                .collect();
            robust_spread(&norms).map_or(f64::NAN, |s| s.median)
        }
    };
    let magnitude_nt = units.map(|u| magnitude * u.nanotesla());
    let comparison = match (&model, &inclination) {
        (Some(m), Some(i)) => Some(compare_field(i, magnitude_nt, m)),
        _ => None,
    };

    // The gyro: the heading turns clockwise, a gyro about up reads a
    // counter-clockwise turn as positive, so it is checked against the
    // counter-clockwise angle (−heading): scale +1 for a gyro about up.
    // Without --gyro, the three rates give the rate about the vertical.
    let reference = match (&args.input.gyro, &fusion) {
        (Some(spec), _) => Some(gyro_reference(&args, spec, &data, &mag_t, &main)?),
        (None, Some(f)) => {
            // Integrated over the samples that have a rate and a vertical
            // (outside the gyro's or the accelerometer's span they have not).
            let (rate_t, rate): (Vec<f64>, Vec<f64>) = mag_t
                .iter()
                .copied()
                .zip(rate_about_vertical(&f.rates, &f.up))
                .filter(|(_, r)| r.is_finite())
                .unzip();
            Some(
                HeadingReference::from_rates(
                    RATE_ABOUT_VERTICAL,
                    &mag_t,
                    &rate_t,
                    &rate,
                    args.input.gyro_units,
                )
                .with_context(|| format!("{main}: the gyro's rate about the vertical"))?,
            )
        }
        (None, None) => None,
    };
    let gyro = match reference {
        None => None,
        Some(reference) => {
            let ccw = |h: &[f64]| -> Vec<f64> { h.iter().map(|d| -d.to_radians()).collect() };
            // A heading that does not follow the gyro (a level compass
            // tilted in a steep field) is a finding, not a failure.
            let check = |h: &[f64]| reference.check(&ccw(h), &[]).map_err(|e| e.to_string());
            let accel_only = match &fusion {
                Some(_) => Some(check(
                    &heading_series(&body, &accel_sensor.points, forward, up, declination)?
                        .heading_deg,
                )),
                None => None,
            };
            Some(GyroChecks {
                column: reference.column().to_string(),
                tilt: check(&series.heading_deg),
                accel_only,
                level: check(&series.level_deg),
            })
        }
    };

    if let Some(output) = &args.output {
        write_series(output, &mag_t, &series)
            .with_context(|| format!("cannot write the headings to {}", output.display()))?;
    }

    let report = Report {
        mag: &mag_sensor,
        accel: &accel_sensor,
        units,
        map,
        choice: choice.as_ref(),
        forward: &args.forward,
        up: &args.up,
        declination,
        declination_source,
        n: mag_t.len(),
        n_heading,
        interpolation: interpolation.as_ref(),
        inclination: inclination.as_ref(),
        tilt: tilt.as_ref(),
        max_tilt,
        magnitude,
        magnitude_nt,
        magnitude_source: if mag_cal.is_some() {
            "calibration r"
        } else {
            "median |reading|"
        },
        model: model.as_ref(),
        comparison: comparison.as_ref(),
        gyro: gyro.as_ref(),
        fusion: fusion.as_ref(),
    };
    let text = if args.json {
        serde_json::to_string(&report.json())? + "\n"
    } else {
        report.text()
    };
    write_stdout(text.as_bytes())
}

/// The gyro's heading reference at the magnetometer's times: a column of
/// the magnetometer's file, or FILE:COLUMN of another on the same clock.
fn gyro_reference(
    args: &HeadingArgs,
    spec: &str,
    data: &fieldcal::sample::Dataset3,
    mag_t: &[f64],
    main: &str,
) -> Result<HeadingReference> {
    let (file, column) = match spec.rsplit_once(':') {
        Some((file, column)) => (Some(PathBuf::from(file)), column),
        None => (None, spec),
    };
    if column.is_empty() || file.as_ref().is_some_and(|f| f.as_os_str().is_empty()) {
        bail!(
            "--gyro '{spec}': give a column of the recording (--gyro gyro_z) or a file and its column (--gyro imu.csv:gyro_z)"
        );
    }
    let units = args.input.gyro_units;
    let other = file.filter(|_| !args.input.gyro_in_recording());
    match other {
        None => {
            let Some(c) = data.covariate(column) else {
                bail!(
                    "{main}: no gyro column '{column}'; name it with --gyro COLUMN, or --gyro FILE:COLUMN for a second file"
                );
            };
            HeadingReference::from_rates(column, mag_t, mag_t, &c.values, units)
                .with_context(|| format!("{main}: gyro '{column}'"))
        }
        Some(file) => {
            let series = fieldcal::io::csv::read_series(&file, column, "the gyro", "--gyro")?;
            HeadingReference::from_rates(column, mag_t, &series.t, &series.values, units)
                .with_context(|| {
                    format!(
                        "{}: gyro '{column}' against {main} (joined by time: '{}' there)",
                        file.display(),
                        series.time_name
                    )
                })
        }
    }
}

/// `--output`: t, heading, level_heading, tilt, pitch, inclination (an
/// empty field where a sample has none), atomically.
fn write_series(path: &Path, t: &[f64], s: &HeadingSeries) -> std::io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut out = BufWriter::with_capacity(1 << 16, file.as_file_mut());
        writeln!(out, "t,heading,level_heading,tilt,pitch,inclination")?;
        let f = |v: f64| {
            if v.is_finite() {
                v.to_string()
            } else {
                String::new()
            }
        };
        for (i, t) in t.iter().enumerate() {
            writeln!(
                out,
                "{},{},{},{},{},{}",
                t,
                f(s.heading_deg[i]),
                f(s.level_deg[i]),
                f(s.tilt_deg[i]),
                f(s.pitch_deg[i]),
                f(s.inclination_deg[i])
            )?;
        }
        out.flush()?;
    }
    file.commit()
}

/// The tilt-compensated and the level heading against the gyro; an error
/// says why one could not be checked.
struct GyroChecks {
    column: String,
    /// The tilt-compensated heading (on the fused vertical with --rates).
    tilt: std::result::Result<HeadingCheck, String>,
    /// With --rates: the heading on the accelerometer's vertical alone.
    accel_only: Option<std::result::Result<HeadingCheck, String>>,
    level: std::result::Result<HeadingCheck, String>,
}

/// The name of the heading reference integrated from the three rates.
const RATE_ABOUT_VERTICAL: &str = "rate about the vertical";

/// `--rates`: the gyro that steadies the vertical.
struct Fusion {
    file: PathBuf,
    columns: [String; 3],
    tau_s: f64,
    /// The fused vertical at each magnetometer time.
    up: Vec<[f64; 3]>,
    /// The rates at each magnetometer time, in --gyro-units.
    rates: Vec<[f64; 3]>,
}

struct Report<'a> {
    mag: &'a Sensor,
    accel: &'a Sensor,
    units: Option<MagUnits>,
    map: AxisMap,
    choice: Option<&'a AxisChoice>,
    forward: &'a str,
    up: &'a str,
    declination: f64,
    declination_source: &'static str,
    n: usize,
    n_heading: usize,
    interpolation: Option<&'a fieldcal::model::tilt::Resampled>,
    inclination: Option<&'a RobustSpread>,
    tilt: Option<&'a RobustSpread>,
    max_tilt: f64,
    magnitude: f64,
    magnitude_nt: Option<f64>,
    magnitude_source: &'static str,
    model: Option<&'a ModelField>,
    comparison: Option<&'a FieldComparison>,
    gyro: Option<&'a GyroChecks>,
    fusion: Option<&'a Fusion>,
}

fn max_abs(check: &HeadingCheck) -> f64 {
    check
        .errors_deg
        .iter()
        .copied()
        .filter(|e| e.is_finite())
        .fold(0.0, |m, e| m.max(e.abs()))
}

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

impl Report<'_> {
    fn north(&self) -> &'static str {
        if self.declination_source == "none" {
            "magnetic"
        } else {
            "true"
        }
    }

    fn json(&self) -> Value {
        let sensor = |s: &Sensor| {
            json!({
                "file": s.file.display().to_string(),
                "columns": s.columns,
                "calibration": s.calibration.as_ref().map(|p| p.display().to_string()),
            })
        };
        let mut accel = sensor(self.accel);
        accel["interpolated"] = json!(self.interpolation.is_some());
        if let Some(r) = self.interpolation {
            accel["period_s"] = json!(r.period);
            accel["outside"] = json!(r.outside);
            accel["in_gaps"] = json!(r.in_gaps);
        }
        let mut mag = sensor(self.mag);
        mag["units"] = json!(self.units.map(units_name));
        mag["axes"] = json!(self.map.to_string());
        mag["axes_source"] = json!(if self.choice.is_some() {
            "auto"
        } else {
            "given"
        });
        let spread = |s: Option<&RobustSpread>| {
            s.map_or(
                Value::Null,
                |s| json!({"median": s.median, "spread": s.spread, "n": s.n}),
            )
        };
        let check = |c: &std::result::Result<HeadingCheck, String>| {
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
        };
        json!({
            "magnetometer": mag,
            "accelerometer": accel,
            "axes_auto": self.choice.map(|c| json!({
                "chosen": c.chosen.map.to_string(),
                "inclination_spread_deg": c.chosen.inclination.spread,
                "runner_up": c.runner_up.map.to_string(),
                "runner_up_spread_deg": c.runner_up.inclination.spread,
                "tilt_range_deg": c.tilt_range_deg,
                "mirror_rule": c.mirror_rule,
            })),
            "forward": self.forward,
            "up": self.up,
            "north": self.north(),
            "declination_deg": self.declination,
            "declination_source": self.declination_source,
            "n": self.n,
            "n_heading": self.n_heading,
            "tilt_deg": {
                "median": self.tilt.map(|t| t.median),
                "max": finite(self.max_tilt),
            },
            "inclination_deg": spread(self.inclination),
            "field": {
                "magnitude": finite(self.magnitude),
                "units": self.units.map(units_name),
                "magnitude_nt": self.magnitude_nt.map(finite),
                "source": self.magnitude_source,
            },
            "model": self.model,
            "comparison": self.comparison,
            "vertical": match self.fusion {
                None => json!({"source": "accelerometer"}),
                Some(f) => json!({
                    "source": "accelerometer+gyro",
                    "rates": {"file": f.file.display().to_string(), "columns": f.columns},
                    "tau_s": f.tau_s,
                }),
            },
            "gyro": self.gyro.map(|g| {
                let delta = match (&g.tilt, &g.level) {
                    (Ok(t), Ok(l)) => Some(t.worse_by(l)),
                    _ => None,
                };
                let fusion_gain = match (&g.accel_only, &g.tilt) {
                    (Some(Ok(a)), Ok(t)) => Some(t.worse_by(a)),
                    _ => None,
                };
                json!({
                    "column": g.column,
                    "tilt_compensated": check(&g.tilt),
                    "tilt_compensated_accel_only": g.accel_only.as_ref().map(check),
                    "level": check(&g.level),
                    "level_worse_by_deg": delta.map(|d| finite(d.delta_rms_deg)),
                    "level_worse_by_se_deg": delta.map(|d| finite(d.se_deg)),
                    "accel_only_worse_by_deg": fusion_gain.map(|d| finite(d.delta_rms_deg)),
                    "accel_only_worse_by_se_deg": fusion_gain.map(|d| finite(d.se_deg)),
                    "verdict": delta.map(|d| compensation_verdict(d, self.accel.calibration.is_some(), self.fusion.is_some())),
                })
            }),
        })
    }

    fn text(&self) -> String {
        let mut s = String::new();
        let cal = |c: &Option<PathBuf>| match c {
            Some(p) => format!("calibrated by {}", p.display()),
            None => "raw (no calibration)".to_string(),
        };
        s += &format!(
            "magnetometer: {} ({}), {}\n",
            self.mag.file.display(),
            self.mag.columns.join(", "),
            cal(&self.mag.calibration)
        );
        s += &format!(
            "accelerometer: {} ({}), {}",
            self.accel.file.display(),
            self.accel.columns.join(", "),
            cal(&self.accel.calibration)
        );
        if let Some(r) = self.interpolation {
            s += &format!(
                "; interpolated to the magnetometer's times (period {:.4} s; {} outside its span, {} in gaps over {} periods)",
                r.period,
                r.outside,
                r.in_gaps,
                fieldcal::model::tilt::MAX_GAP_PERIODS
            );
        }
        s += "\n";
        if let Some(f) = self.fusion {
            s += &format!(
                "vertical: the accelerometer's, steadied by the gyro {} ({}) with a time constant of {:.2} s\n",
                f.file.display(),
                f.columns.join(", "),
                f.tau_s
            );
        }
        match self.choice {
            Some(c) => {
                s += &format!(
                    "magnetometer axes on the board: {} (auto: the dip's robust SD {:.2}°, the next best mapping {} {:.2}°; the board's vertical moved up to {:.0}°; {})\n",
                    self.map,
                    c.chosen.inclination.spread,
                    c.runner_up.map,
                    c.runner_up.inclination.spread,
                    c.tilt_range_deg,
                    c.mirror_rule
                );
            }
            None => s += &format!("magnetometer axes on the board: {}\n", self.map),
        }
        s += &format!(
            "heading of the board's {} axis (up {}), clockwise from {} north",
            self.forward,
            self.up,
            self.north()
        );
        match self.declination_source {
            "wmm" => {
                s += &format!(
                    ", declination {:+.2}° from the World Magnetic Model\n",
                    self.declination
                )
            }
            "given" => s += &format!(", declination {:+.2}° as given\n", self.declination),
            _ => s += " (no declination given)\n",
        }
        s += &format!("samples: {}, with a heading: {}\n", self.n, self.n_heading);
        if let Some(t) = self.tilt {
            s += &format!(
                "tilt: median {:.1}°, up to {:.1}°\n",
                t.median, self.max_tilt
            );
        }
        if let Some(i) = self.inclination {
            s += &format!(
                "measured inclination: {:.2}° (robust SD {:.2}° over the samples)\n",
                i.median, i.spread
            );
        }
        match (self.units, self.magnitude_nt) {
            (Some(u), Some(nt)) => {
                s += &format!(
                    "measured field: {:.4} {} = {:.0} nT ({})\n",
                    self.magnitude,
                    units_name(u),
                    nt,
                    self.magnitude_source
                )
            }
            _ => {
                s += &format!(
                    "measured field: {:.4} in the readings' units ({}; units unknown: --mag-units)\n",
                    self.magnitude, self.magnitude_source
                )
            }
        }
        if let Some(m) = self.model {
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
        if let Some(c) = self.comparison {
            s += &format!("field against the model: {}\n", c.verdict);
        }
        if let Some(g) = self.gyro {
            s += &format!(
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
            if let (Ok(t), Ok(l)) = (&g.tilt, &g.level) {
                let d = t.worse_by(l);
                s += &format!(
                    "  the level heading is worse by {:+.2}° ± {:.2}° rms (on the samples both have)\n",
                    d.delta_rms_deg, d.se_deg
                );
                s += &format!(
                    "  {}\n",
                    compensation_verdict(
                        d,
                        self.accel.calibration.is_some(),
                        self.fusion.is_some()
                    )
                );
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
        }
        s
    }
}

/// Standard errors a difference of rms heading errors must exceed to be
/// called a difference (as `diagnose` calls a model's heading worse).
const VERDICT_SES: f64 = 3.0;

/// What the comparison with the gyro says about tilt compensation, in
/// words a person acts on: it helped, it made no difference, or it made the
/// heading worse, and then the physical reason to look at first.
fn compensation_verdict(
    d: fieldcal::model::gyro::HeadingDelta,
    accel_calibrated: bool,
    fused: bool,
) -> String {
    let (delta, se) = (d.delta_rms_deg, d.se_deg);
    if !(delta.is_finite() && se.is_finite()) {
        return "too few samples to compare the two headings".to_string();
    }
    if delta > VERDICT_SES * se {
        format!("tilt compensation removed {delta:.2}° rms of heading error")
    } else if delta < -VERDICT_SES * se {
        let cause = if fused {
            "the fused vertical is less accurate than the board was level: check that --rates names \
             the gyro's axes in the accelerometer's frame and its units (--gyro-units), and the gyro's \
             bias (a bias of b tilts the vertical by about b times --fusion-tau: shorten it)"
        } else if accel_calibrated {
            "the accelerometer's vertical is less accurate than the board was level: the board \
             accelerated during the turn (give the gyro's three axes with --rates to steady the \
             vertical), or the accelerometer's calibration holds the hand's accelerations \
             (calibrate it from still poses: fit --still)"
        } else {
            "the raw accelerometer's vertical is less accurate than the board was level: calibrate \
             it (fit --z on a tumble, or --still on still poses), steady it with the gyro (--rates), \
             and check --mag-axes"
        };
        format!(
            "tilt compensation made the heading WORSE by {:.2}° rms: {cause}",
            -delta
        )
    } else {
        format!(
            "tilt compensation made no difference beyond the noise ({delta:+.2}° ± {se:.2}°): the board stayed near level"
        )
    }
}

/// What steadying the vertical with the gyro did, against the
/// accelerometer alone.
fn fusion_verdict(d: fieldcal::model::gyro::HeadingDelta) -> String {
    let (delta, se) = (d.delta_rms_deg, d.se_deg);
    if !(delta.is_finite() && se.is_finite()) {
        "too few samples to compare".to_string()
    } else if delta > VERDICT_SES * se {
        "the gyro removed the board's accelerations from the vertical".to_string()
    } else if delta < -VERDICT_SES * se {
        "the gyro made the vertical worse: check the --rates columns and units, and the gyro's bias \
         (shorten --fusion-tau)"
            .to_string()
    } else {
        "no difference beyond the noise: the board's accelerations were small".to_string()
    }
}
