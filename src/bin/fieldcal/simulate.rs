//! `fieldcal simulate`: a simulated sensor, as CSV or as a Falcon-GX capture.

use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result, bail};

use fieldcal::capture::CaptureWriter;
use fieldcal::io::atomic::AtomicFile;
use fieldcal::io::csv::write_dataset_to;
use fieldcal::sample::count;
use fieldcal::sim::{FalconWire, SimEffects, SimSensor};

use crate::output::write_stdout;
use crate::{SimFormat, SimulateArgs};
use fieldcal::sim3::{ImuMotion, SimAxes3, SimImu3, write_imu_csv};

pub fn simulate(args: SimulateArgs) -> Result<()> {
    if args.three.axes == 3 {
        return simulate3(args);
    }
    if args.three.axes != 2 {
        bail!("--axes must be 2 or 3, got {}", args.three.axes);
    }
    let sensor = SimSensor {
        field: args.field,
        gain_x: args.gain_x,
        gain_y: args.gain_y,
        offset_x: args.offset_x,
        offset_y: args.offset_y,
        noise: args.noise,
        period: args.period,
        turns: args.turns,
        turn_seconds: args.turn_seconds,
        start_heading_deg: args.start_heading,
        seed: args.seed,
        effects: sim_effects(&args.effect, args.temp_rise),
    };
    check_output(&args)?;
    let wire = FalconWire {
        garbage: args.garbage,
        ..Default::default()
    };
    if args.format != SimFormat::Csv {
        // A capture too large is refused before the samples are simulated.
        sensor.check_capture(&wire)?;
    }
    let (data, model_truth) = sensor.simulate_with_truth()?;
    let n = match args.format {
        SimFormat::Csv => {
            write_csv(&args, |mut out| write_dataset_to(&mut out, &data))?;
            data.len()
        }
        SimFormat::Falcon | SimFormat::FalconRaw => {
            write_frames(&args, || Ok(sensor.falcon_capture(&wire)?))?
        }
    };
    let truth = sensor.truth();
    if args.json {
        let json = serde_json::json!({
            "file": args.output.as_deref().map(Path::display).map(|d| d.to_string()),
            "n": n,
            "sensor": sensor,
            "truth": truth,
            "params": model_truth.params,
            "outliers": model_truth.outliers,
        });
        write_stdout(format!("{json}\n").as_bytes())?;
    } else if let Some(path) = &args.output {
        if args.effect.is_empty() {
            eprintln!(
                "wrote {} to {}; true calibration: a = {}, b = {}, d = {}, r = {}",
                count(n as u64, "sample"),
                path.display(),
                truth.a,
                truth.b,
                truth.d,
                truth.r
            );
        } else {
            let params: Vec<String> = model_truth
                .params
                .iter()
                .filter(|(name, value)| **value != 0.0 || ["b", "d"].contains(&name.as_str()))
                .map(|(name, value)| format!("{name} = {value}"))
                .collect();
            eprintln!(
                "wrote {} to {} ({}); true parameters of the general model: {}",
                count(n as u64, "sample"),
                path.display(),
                count(model_truth.outliers.len() as u64, "spike"),
                params.join(", ")
            );
        }
    }
    Ok(())
}

/// One `--effect NAME=VALUE` of `fieldcal simulate`.
#[derive(Debug, Clone, PartialEq)]
pub enum SimEffectArg {
    CrossAxisDeg(f64),
    Drift([f64; 2]),
    Temp([f64; 2]),
    Current([f64; 2]),
    Cubic([f64; 2]),
    CubicCentred([f64; 2]),
    Outliers(f64),
}

/// Parses `cross-axis=3deg`, `drift=0.5,-0.3`, `covariate:temp=4`,
/// `cubic=0.02`, `cubic-centred=0.02`, `outliers=0.01`...
pub fn parse_effect(text: &str) -> Result<SimEffectArg, String> {
    let (name, value) = text.split_once('=').ok_or_else(|| {
        format!("'{text}' needs a value, as in cross-axis=3deg, drift=0.5, covariate:temp=4, cubic=0.02 or outliers=0.01")
    })?;
    let number = |v: &str| -> Result<f64, String> {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("'{v}' in '{text}' is not a number"))
    };
    let pair = |v: &str| -> Result<[f64; 2], String> {
        match v.split_once(',') {
            Some((x, y)) => Ok([number(x)?, number(y)?]),
            None => number(v).map(|both| [both, both]),
        }
    };
    Ok(match name.trim() {
        "cross-axis" => {
            let v = value.trim();
            SimEffectArg::CrossAxisDeg(number(v.strip_suffix("deg").unwrap_or(v))?)
        }
        "drift" => SimEffectArg::Drift(pair(value)?),
        "covariate:temp" => SimEffectArg::Temp(pair(value)?),
        "covariate:current" => SimEffectArg::Current(pair(value)?),
        "cubic" => SimEffectArg::Cubic(pair(value)?),
        "cubic-centred" => SimEffectArg::CubicCentred(pair(value)?),
        "outliers" => SimEffectArg::Outliers(number(value)?),
        other => {
            return Err(format!(
                "'{other}' is not an effect the simulator has; choose cross-axis, drift, covariate:temp, covariate:current, cubic, cubic-centred or outliers"
            ));
        }
    })
}

fn sim_effects(args: &[SimEffectArg], temp_rise: f64) -> SimEffects {
    let mut effects = SimEffects {
        temp_rise,
        ..Default::default()
    };
    for arg in args {
        match *arg {
            SimEffectArg::CrossAxisDeg(deg) => effects.cross_axis_deg = deg,
            SimEffectArg::Drift(v) => effects.drift_per_s = v,
            SimEffectArg::Temp(v) => effects.temp_per_c = Some(v),
            SimEffectArg::Current(v) => effects.current_per_a = Some(v),
            SimEffectArg::Cubic(v) => effects.cubic = v,
            SimEffectArg::CubicCentred(v) => effects.cubic_centred = v,
            SimEffectArg::Outliers(f) => effects.outliers = f,
        }
    }
    effects
}

fn exists_message(path: &Path) -> String {
    format!(
        "{} exists: simulate never overwrites a file; choose another --output, or add --force to replace it",
        path.display()
    )
}

/// The output checks before anything is simulated: `--json` needs
/// `--output`, and an existing file is refused without `--force` (the
/// write itself checks again: a file may appear meanwhile).
fn check_output(args: &SimulateArgs) -> Result<()> {
    if args.json && args.output.is_none() {
        bail!("--json prints the true calibration on stdout, so the data needs --output FILE");
    }
    if let Some(path) = &args.output
        && !args.force
        && std::fs::symlink_metadata(path).is_ok()
    {
        bail!("{}", exists_message(path));
    }
    Ok(())
}

/// Writes a CSV (by `write`) to `--output`, or to stdout.
fn write_csv(
    args: &SimulateArgs,
    write: impl Fn(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    match &args.output {
        Some(path) => write_file(path, args.force, |mut out| write(&mut out)),
        None => {
            let mut buffer = Vec::new();
            write(&mut buffer)?;
            write_stdout(&buffer)
        }
    }
}

/// Writes the Falcon-GX frames `frames` makes to `--output`: a capture, or
/// (`falcon-raw`) the bytes alone. Returns the number of frames.
fn write_frames(
    args: &SimulateArgs,
    frames: impl FnOnce() -> Result<(
        fieldcal::capture::CaptureHeader,
        Vec<fieldcal::capture::Chunk>,
    )>,
) -> Result<usize> {
    let Some(path) = &args.output else {
        bail!("Falcon-GX frames are binary: write them to a file with --output FILE");
    };
    let (header, chunks) = frames()?;
    if args.format == SimFormat::Falcon {
        write_file(path, args.force, |out| write_capture(out, &header, &chunks))?;
    } else {
        write_file(path, args.force, |out| write_raw(out, &chunks))?;
    }
    Ok(chunks.len())
}

/// Writes `path` atomically (a reader sees the old file or the whole new
/// one); without `force`, never replaces an existing file.
fn write_file(
    path: &Path,
    force: bool,
    body: impl FnOnce(&mut BufWriter<&mut std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    let written = (|| {
        let mut file = AtomicFile::create(path)?;
        {
            let mut out = BufWriter::with_capacity(1 << 16, file.as_file_mut());
            body(&mut out)?;
            out.flush()?;
        }
        if force {
            file.commit()
        } else {
            file.commit_new()
        }
    })();
    match written {
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            bail!("{}", exists_message(path))
        }
        written => written.with_context(|| format!("cannot write {}", path.display())),
    }
}

fn write_capture<W: Write>(
    out: &mut W,
    header: &fieldcal::capture::CaptureHeader,
    chunks: &[fieldcal::capture::Chunk],
) -> std::io::Result<()> {
    let mut writer = CaptureWriter::new(out, header)?;
    for chunk in chunks {
        writer.write_chunk(chunk.time, chunk.stream, &chunk.bytes)?;
    }
    writer.into_inner()?.flush()
}

fn write_raw<W: Write>(out: &mut W, chunks: &[fieldcal::capture::Chunk]) -> std::io::Result<()> {
    for chunk in chunks {
        out.write_all(&chunk.bytes)?;
    }
    Ok(())
}

/// The options of `simulate --axes 3`: a tumbled (or turning, or still)
/// IMU whose magnetometer and accelerometer are 3-axis sensors.
#[derive(Debug, Clone, clap::Args)]
pub struct Sim3Args {
    /// 2: a magnetometer turning in a plane (the paper's sensor); 3: an IMU (magnetometer, accelerometer, gyro) moved through 3-D (--motion), written as CSV columns t,x,y,z (magnetometer), ax,ay,az, gx,gy,gz (deg/s), heading, tilt (the truth), or as Falcon-GX frames carrying all three axes.
    #[arg(long, default_value_t = 2)]
    pub axes: u8,
    /// --axes 3: how the board moves: tumble (through every direction), wobble (turns about the vertical, rolling and pitching by up to --tilt), static (--poses still orientations).
    #[arg(long, value_enum, default_value_t = Motion3Arg::Tumble)]
    pub motion: Motion3Arg,
    /// --axes 3, tumble: how far the tumble's axis walks over the sphere, radians (default: half of --turns).
    #[arg(long, value_name = "RAD")]
    pub axis_path: Option<f64>,
    /// --axes 3, wobble: largest roll and pitch, degrees.
    #[arg(
        long,
        value_name = "DEG",
        default_value_t = 20.0,
        allow_negative_numbers = true
    )]
    pub tilt: f64,
    /// --axes 3, static: how many still orientations.
    #[arg(long, default_value_t = 6)]
    pub poses: usize,
    /// --axes 3: the field's inclination below the horizontal, degrees.
    #[arg(
        long,
        value_name = "DEG",
        default_value_t = 60.0,
        allow_negative_numbers = true
    )]
    pub inclination: f64,
    /// --axes 3: offset of the magnetometer's z axis, in counts (x, y: --offset-x, --offset-y).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub offset_z: f64,
    /// --axes 3: the magnetometer's calibration W (soft iron, gains, cross-axis), symmetric positive definite: 9 numbers row-major, or 3 for a diagonal. The sensor reads W⁻¹ of the field.
    #[arg(long, value_name = "W", value_parser = parse_matrix, allow_negative_numbers = true)]
    pub matrix: Option<Matrix3Arg>,
    /// --axes 3: 1 g in the accelerometer's counts (4096 as the Falcon-GX simulation).
    #[arg(long, default_value_t = 4096.0, allow_negative_numbers = true)]
    pub gravity: f64,
    /// --axes 3: the accelerometer's calibration W, as --matrix.
    #[arg(long, value_name = "W", value_parser = parse_matrix, allow_negative_numbers = true)]
    pub accel_matrix: Option<Matrix3Arg>,
    /// --axes 3: the accelerometer's zero-g offsets x,y,z in counts.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_triple, allow_negative_numbers = true)]
    pub accel_offset: Option<[f64; 3]>,
    /// --axes 3: standard deviation of the accelerometer's noise, in counts.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub accel_noise: f64,
    /// --axes 3: standard deviation of the gyro's noise, deg/s.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub gyro_noise: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Motion3Arg {
    Tumble,
    Wobble,
    Static,
}

/// A 3×3 matrix given on the command line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matrix3Arg(pub [[f64; 3]; 3]);

fn numbers(text: &str) -> Result<Vec<f64>, String> {
    text.split(',')
        .map(|v| {
            v.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("'{}' in '{text}' is not a number", v.trim()))
        })
        .collect()
}

/// `1.1,0.05,0,0.05,0.95,0,0,0,1` (row-major) or `1.1,0.95,1` (diagonal).
pub fn parse_matrix(text: &str) -> Result<Matrix3Arg, String> {
    let v = numbers(text)?;
    match v.as_slice() {
        [a, b, c] => Ok(Matrix3Arg([[*a, 0.0, 0.0], [0.0, *b, 0.0], [0.0, 0.0, *c]])),
        [a, b, c, d, e, f, g, h, i] => Ok(Matrix3Arg([[*a, *b, *c], [*d, *e, *f], [*g, *h, *i]])),
        other => Err(format!(
            "{} numbers given: give 9 (the matrix row by row) or 3 (its diagonal)",
            other.len()
        )),
    }
}

/// `x,y,z`.
pub fn parse_triple(text: &str) -> Result<[f64; 3], String> {
    match numbers(text)?.as_slice() {
        [x, y, z] => Ok([*x, *y, *z]),
        other => Err(format!("{} numbers given: give three, x,y,z", other.len())),
    }
}

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The IMU of `simulate --axes 3`, its settings checked.
fn imu_of(args: &SimulateArgs) -> Result<SimImu3> {
    let three = &args.three;
    if !args.effect.is_empty() {
        bail!(
            "--effect is for the 2-axis simulator; with --axes 3 give the soft iron with --matrix, the offsets with --offset-x/-y/-z and --accel-offset, and the noise with --noise and --accel-noise"
        );
    }
    if args.gain_x != 1.0 || args.gain_y != 1.0 {
        bail!(
            "--gain-x and --gain-y are for --axes 2; with --axes 3 give the gains as the diagonal of --matrix"
        );
    }
    for (name, value) in [
        ("--period", args.period),
        ("--turns", args.turns),
        ("--turn-seconds", args.turn_seconds),
    ] {
        if !(value > 0.0 && value.is_finite()) {
            bail!("{name} must be a positive number, got {value}");
        }
    }
    // Finite: the three are positive and finite (checked above), so only
    // a too large count is refused here.
    let samples = (args.turns * args.turn_seconds / args.period).round();
    if samples.is_nan() || samples > fieldcal::sim3::MAX_SAMPLES as f64 {
        bail!(
            "--turns × --turn-seconds / --period gives {samples:.0} samples, more than the {} a simulation makes; lower --turns or raise --period",
            fieldcal::sim3::MAX_SAMPLES
        );
    }
    let motion = match three.motion {
        Motion3Arg::Tumble => ImuMotion::Tumble {
            turns: args.turns,
            axis_path_rad: three.axis_path.unwrap_or(args.turns / 2.0),
        },
        Motion3Arg::Wobble => ImuMotion::WobblingTurn {
            turns: args.turns,
            tilt_deg: three.tilt,
        },
        Motion3Arg::Static => ImuMotion::Static { poses: three.poses },
    };
    let imu = SimImu3 {
        field: args.field,
        inclination_deg: three.inclination,
        gravity: three.gravity,
        mag: SimAxes3 {
            matrix: three.matrix.map_or(IDENTITY, |m| m.0),
            offset: [args.offset_x, args.offset_y, three.offset_z],
            noise: args.noise,
        },
        accel: SimAxes3 {
            matrix: three.accel_matrix.map_or(IDENTITY, |m| m.0),
            offset: three.accel_offset.unwrap_or([0.0; 3]),
            noise: three.accel_noise,
        },
        gyro_noise: three.gyro_noise,
        period: args.period,
        n: samples.max(1.0) as usize,
        motion,
        seed: args.seed,
    };
    imu.validate()?;
    Ok(imu)
}

/// `fieldcal simulate --axes 3`.
fn simulate3(args: SimulateArgs) -> Result<()> {
    let imu = imu_of(&args)?;
    check_output(&args)?;
    let n = match args.format {
        SimFormat::Csv => {
            let samples = imu.simulate()?;
            write_csv(&args, |mut out| write_imu_csv(&mut out, &samples))?;
            samples.len()
        }
        SimFormat::Falcon | SimFormat::FalconRaw => write_frames(&args, || {
            let ticks = FalconWire::default().ticks_per_frame;
            Ok(imu.falcon_capture(args.garbage, ticks)?)
        })?,
    };
    let truth = |(o, w, r): ([f64; 3], [[f64; 3]; 3], f64)| serde_json::json!({"offset": o, "matrix": w, "r": r});
    if args.json {
        let json = serde_json::json!({
            "file": args.output.as_deref().map(Path::display).map(|d| d.to_string()),
            "n": n,
            "axes": 3,
            "imu": imu,
            "mag": truth(imu.mag_truth()),
            "accel": truth(imu.accel_truth()),
        });
        write_stdout(format!("{json}\n").as_bytes())?;
    } else if let Some(path) = &args.output {
        let (o, w, r) = imu.mag_truth();
        eprintln!(
            "wrote {} of a 3-axis IMU to {}; the magnetometer's true calibration (det W = 1): o = {o:?}, W = {w:?}, r = {r}",
            count(n as u64, "sample"),
            path.display(),
        );
    }
    Ok(())
}
