//! `fieldcal simulate`: a simulated sensor, as CSV or as a Falcon-GX capture.

use std::io::{BufWriter, Write};
use std::path::Path;

use anyhow::{Context, Result, bail};

use fieldcal::capture::CaptureWriter;
use fieldcal::io::atomic::AtomicFile;
use fieldcal::io::csv::{write_calibrated, write_calibrated_to};
use fieldcal::sim::{FalconWire, SimSensor};

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
    };
    if args.json && args.output.is_none() {
        bail!("--json prints the true calibration on stdout, so the data needs --output FILE");
    }
    let n = match args.format {
        SimFormat::Csv => {
            let data = sensor.simulate()?;
            match &args.output {
                Some(path) => write_calibrated(path, data.t.as_deref(), &data.x, &data.y)
                    .with_context(|| format!("cannot write {}", path.display()))?,
                None => {
                    let mut buffer = Vec::with_capacity(data.len() * 40);
                    write_calibrated_to(&mut buffer, data.t.as_deref(), &data.x, &data.y)?;
                    write_stdout(&buffer)?;
                }
            }
            data.len()
        }
        SimFormat::Falcon | SimFormat::FalconRaw => {
            let Some(path) = &args.output else {
                bail!("Falcon-GX frames are binary: write them to a file with --output FILE");
            };
            let wire = FalconWire {
                garbage: args.garbage,
                ..Default::default()
            };
            let (header, chunks) = sensor.falcon_capture(&wire)?;
            let written = if args.format == SimFormat::Falcon {
                write_capture(path, &header, &chunks)
            } else {
                write_raw(path, &chunks)
            };
            written.with_context(|| format!("cannot write {}", path.display()))?;
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
        });
        write_stdout(format!("{json}\n").as_bytes())?;
    } else if let Some(path) = &args.output {
        eprintln!(
            "wrote {n} samples to {}; true calibration: a = {}, b = {}, d = {}, r = {}",
            path.display(),
            truth.a,
            truth.b,
            truth.d,
            truth.r
        );
    }
    Ok(())
}

fn write_capture(
    path: &Path,
    header: &fieldcal::capture::CaptureHeader,
    chunks: &[fieldcal::capture::Chunk],
) -> std::io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut writer = CaptureWriter::new(BufWriter::new(file.as_file_mut()), header)?;
        for chunk in chunks {
            writer.write_chunk(chunk.time, chunk.stream, &chunk.bytes)?;
        }
        writer.into_inner()?.flush()?;
    }
    file.commit()
}

fn write_raw(path: &Path, chunks: &[fieldcal::capture::Chunk]) -> std::io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut out = BufWriter::new(file.as_file_mut());
        for chunk in chunks {
            out.write_all(&chunk.bytes)?;
        }
        out.flush()?;
    }
    file.commit()
}
