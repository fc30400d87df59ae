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

pub fn simulate(args: SimulateArgs) -> Result<()> {
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
    if args.json && args.output.is_none() {
        bail!("--json prints the true calibration on stdout, so the data needs --output FILE");
    }
    // Refuse before simulating; the write itself checks again (a file
    // may appear meanwhile) and never replaces one without --force.
    if let Some(path) = &args.output
        && !args.force
        && std::fs::symlink_metadata(path).is_ok()
    {
        bail!("{}", exists_message(path));
    }
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
            match &args.output {
                Some(path) => write_file(path, args.force, |out| write_dataset_to(out, &data))?,
                None => {
                    let mut buffer = Vec::with_capacity(data.len() * 40);
                    write_dataset_to(&mut buffer, &data)?;
                    write_stdout(&buffer)?;
                }
            }
            data.len()
        }
        SimFormat::Falcon | SimFormat::FalconRaw => {
            let Some(path) = &args.output else {
                bail!("Falcon-GX frames are binary: write them to a file with --output FILE");
            };
            let (header, chunks) = sensor.falcon_capture(&wire)?;
            if args.format == SimFormat::Falcon {
                write_file(path, args.force, |out| write_capture(out, &header, &chunks))?;
            } else {
                write_file(path, args.force, |out| write_raw(out, &chunks))?;
            }
            chunks.len()
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
    CubicCentred(f64),
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
        "cubic-centred" => SimEffectArg::CubicCentred(number(value)?),
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
