//! `fieldcal heading`: a 3-axis magnetometer and accelerometer on one
//! board, calibrated, give the tilt-compensated heading of every sample.
//!
//! This file reads the recordings and the calibrations and puts every
//! sensor on the magnetometer's times; the analysis is
//! [`fieldcal::model::heading_analysis`], the report
//! [`fieldcal::report::heading`].

use fieldcal::io::csv::Covariates;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use fieldcal::geomag::{CivilDate, ModelField, Place, model_field};
use fieldcal::io::atomic::AtomicFile;
use fieldcal::model::gyro::HeadingReference;
use fieldcal::model::heading_analysis::{
    Board, Declination, FieldMagnitude, Fusion, GyroChecks, HeadingReport, HeadingStats, Sensor,
    calibrated, rate_reference,
};
use fieldcal::model::tilt::{
    AxisChoice, AxisMap, Calibration3, HeadingSeries, Resampled, choose_axis_map, parse_axis,
    resample,
};
use fieldcal::report::heading::{heading_json, heading_text};

use crate::HeadingArgs;
use crate::output::write_stdout;

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
    interpolation: Option<Resampled>,
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
            cols.push(c.values.as_slice());
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
        read_time: true,
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
    let only = columns_named(&args);
    let done = match heading_of(&args, &only) {
        // What went wrong may be a column missing: its message names
        // every numeric column of the recording. Nothing is written yet.
        Err(_) if only != Covariates::All => heading_of(&args, &Covariates::All)?,
        done => done?,
    };
    if let Some(output) = &args.output {
        write_series(output, &done.t, &done.series)
            .with_context(|| format!("cannot write the headings to {}", output.display()))?;
    }
    write_stdout(done.text.as_bytes())
}

/// What `heading` writes: the series for --output, and the report.
struct Headings {
    t: Vec<f64>,
    series: HeadingSeries,
    text: String,
}

/// The columns of the magnetometer's recording the options name (the
/// accelerometer's, the gyro's), read beside its axes: the others are not
/// parsed. Every numeric column when the options cannot be read (their
/// message comes from the reading that fails).
fn columns_named(args: &HeadingArgs) -> Covariates {
    let mut names = Vec::new();
    for spec in std::iter::once(&args.accel).chain(&args.rates) {
        let Ok((_, columns)) = split_columns(spec, "", "") else {
            return Covariates::All;
        };
        names.extend(columns.map(|c| c.trim_start_matches('-').to_string()));
    }
    if let Some(gyro) = &args.input.gyro {
        names.push(
            gyro.rsplit_once(':')
                .map_or(gyro.as_str(), |(_, c)| c)
                .to_string(),
        );
    }
    Covariates::Only(names)
}

fn heading_of(args: &HeadingArgs, covariates: &Covariates) -> Result<Headings> {
    let mag_file = args.input.file.clone();
    let main = mag_file.display().to_string();
    let z = args.input.z_column()?.unwrap_or_else(|| "z".to_string());
    let data = args.input.read3(&z, covariates)?;
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
    let mag_sensor = Sensor {
        file: mag_file.clone(),
        columns: mag_columns,
        calibration: args.mag_calibration.clone(),
        points: calibrated(mag_cal.as_ref(), data.points.clone()),
    };
    let (accel_sensor, interpolation) = read_accelerometer(args, &data, &mag_file, &mag_t)?;

    // The place: the model's declination and field.
    let model = place_model(args)?;
    let declination = Declination::choose(model.as_ref(), args.declination)?;

    // The magnetometer's axes on the board.
    let (map, choice) = mag_axes(
        &args.mag_axes,
        &mag_sensor.points,
        &accel_sensor.points,
        model.as_ref(),
        &main,
    )?;
    let body: Vec<[f64; 3]> = mag_sensor.points.iter().map(|m| map.apply(*m)).collect();

    // The board's vertical: the accelerometer's, or with --rates the
    // accelerometer's steadied by the gyro (the hand's accelerations out).
    let fusion = match &args.rates {
        None => None,
        Some(spec) => Some(read_fusion(
            args,
            spec,
            &data,
            &mag_t,
            &accel_sensor.points,
        )?),
    };
    let board = Board {
        forward,
        up,
        declination_deg: declination.deg,
    };
    let series = match &fusion {
        Some(f) => board.headings(&body, &f.up)?,
        None => board.headings(&body, &accel_sensor.points)?,
    };
    let stats = HeadingStats::of(&series).with_context(|| main.clone())?;

    // The field's magnitude, in the magnetometer's units.
    let field = FieldMagnitude::measure(mag_cal.as_ref(), args.mag_units, &mag_sensor.points);
    let comparison = field.compare(model.as_ref(), stats.inclination.as_ref());

    // The gyro: a column of its own, or without --gyro, the three rates
    // give the rate about the vertical.
    let reference = match (&args.input.gyro, &fusion) {
        (Some(spec), _) => Some(gyro_reference(args, spec, &data, &mag_t, &main)?),
        (None, Some(f)) => Some(
            rate_reference(&mag_t, f, args.input.gyro_units)
                .with_context(|| format!("{main}: the gyro's rate about the vertical"))?,
        ),
        (None, None) => None,
    };
    let gyro = match &reference {
        None => None,
        Some(reference) => Some(GyroChecks::check(
            reference,
            &series,
            fusion.as_ref(),
            &board,
            &body,
            &accel_sensor.points,
        )?),
    };

    let report = HeadingReport {
        mag: mag_sensor,
        accel: accel_sensor,
        interpolation,
        map,
        choice,
        forward: args.forward.clone(),
        up: args.up.clone(),
        declination,
        n: mag_t.len(),
        stats,
        field,
        model,
        comparison,
        gyro,
        fusion,
    };
    let text = if args.json {
        serde_json::to_string(&heading_json(&report))? + "\n"
    } else {
        heading_text(&report)
    };
    Ok(Headings {
        t: mag_t,
        series,
        text,
    })
}

/// The accelerometer: columns of the magnetometer's file, or of a second
/// one on the same clock, interpolated to the magnetometer's times; and
/// calibrated. With how a second file was interpolated.
fn read_accelerometer(
    args: &HeadingArgs,
    data: &fieldcal::sample::Dataset3,
    mag_file: &Path,
    mag_t: &[f64],
) -> Result<(Sensor, Option<Resampled>)> {
    let accel_in = read_triplet(
        &args.accel,
        "--accel",
        "the accelerometer",
        false,
        data,
        mag_file,
        mag_t,
    )?;
    let accel_cal = match &args.accel_calibration {
        Some(p) => Some(read_calibration(p, &accel_in.columns, "accelerometer")?),
        None => None,
    };
    let sensor = Sensor {
        file: accel_in.file,
        columns: accel_in.columns,
        calibration: args.accel_calibration.clone(),
        points: calibrated(accel_cal.as_ref(), accel_in.values),
    };
    Ok((sensor, accel_in.interpolation))
}

/// The World Magnetic Model's field at --latitude, --longitude (and
/// --altitude) on --date (today without it); `None` without a place.
fn place_model(args: &HeadingArgs) -> Result<Option<ModelField>> {
    let (Some(latitude_deg), Some(longitude_deg)) = (args.latitude, args.longitude) else {
        return Ok(None);
    };
    let date = match &args.date {
        Some(d) => CivilDate::parse(d)?,
        None => CivilDate::today()
            .context("the system clock gives no date: give the recording's with --date")?,
    };
    Ok(Some(model_field(&Place {
        latitude_deg,
        longitude_deg,
        altitude_m: args.altitude,
        date,
    })?))
}

/// `--mag-axes`: a mapping as given, or `auto`: the one that keeps the dip
/// most constant (with the model's inclination, when known, to tell a
/// mapping from its mirror).
fn mag_axes(
    spec: &str,
    mag: &[[f64; 3]],
    accel: &[[f64; 3]],
    model: Option<&ModelField>,
    main: &str,
) -> Result<(AxisMap, Option<AxisChoice>)> {
    if spec.trim() == "auto" {
        let choice = choose_axis_map(mag, accel, model.map(|m| m.inclination_deg))
            .with_context(|| format!("{main}: --mag-axes auto"))?;
        Ok((choice.chosen.map, Some(choice)))
    } else {
        Ok((
            spec.parse::<AxisMap>()
                .with_context(|| "--mag-axes".to_string())?,
            None,
        ))
    }
}

/// `--rates`: the gyro's three axes, read at the magnetometer's times,
/// steadying the accelerometer's vertical `accel`.
fn read_fusion(
    args: &HeadingArgs,
    spec: &str,
    data: &fieldcal::sample::Dataset3,
    mag_t: &[f64],
    accel: &[[f64; 3]],
) -> Result<Fusion> {
    let rates = read_triplet(
        spec,
        "--rates",
        "the gyro",
        true,
        data,
        &args.input.file,
        mag_t,
    )?;
    Fusion::fuse(
        rates.file,
        rates.columns,
        args.fusion_tau,
        mag_t,
        accel,
        rates.values,
        args.input.gyro_units,
    )
    .context("--fusion-tau")
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
