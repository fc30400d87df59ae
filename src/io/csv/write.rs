//! CSV out: calibrated samples and recordings, written atomically (a
//! reader sees the old file or the whole new one).

use std::io::{self, BufWriter, Write};
use std::path::Path;

use crate::io::atomic::AtomicFile;
use crate::sample::Dataset;

/// Writes calibrated samples as CSV (`t,x,y` or `x,y`), in input order,
/// atomically: a reader sees the old file or the whole new one, and a full
/// disk leaves the old file in place.
pub fn write_calibrated(path: &Path, t: Option<&[f64]>, x: &[f64], y: &[f64]) -> io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut out = BufWriter::with_capacity(1 << 16, file.as_file_mut());
        write_calibrated_to(&mut out, t, x, y)?;
        out.flush()?;
    }
    file.commit()
}

/// Writes calibrated samples as CSV to any writer.
pub fn write_calibrated_to<W: Write>(
    out: &mut W,
    t: Option<&[f64]>,
    x: &[f64],
    y: &[f64],
) -> io::Result<()> {
    match t {
        Some(t) => {
            writeln!(out, "t,x,y")?;
            for ((t, x), y) in t.iter().zip(x).zip(y) {
                writeln!(out, "{t},{x},{y}")?;
            }
        }
        None => {
            writeln!(out, "x,y")?;
            for (x, y) in x.iter().zip(y) {
                writeln!(out, "{x},{y}")?;
            }
        }
    }
    Ok(())
}

/// Writes calibrated 3-axis samples as CSV (`t,x,y,z` or `x,y,z`), in
/// input order, atomically as [`write_calibrated`].
pub fn write_calibrated3(path: &Path, t: Option<&[f64]>, points: &[[f64; 3]]) -> io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut out = BufWriter::with_capacity(1 << 16, file.as_file_mut());
        match t {
            Some(t) => {
                writeln!(out, "t,x,y,z")?;
                for (t, p) in t.iter().zip(points) {
                    writeln!(out, "{t},{},{},{}", p[0], p[1], p[2])?;
                }
            }
            None => {
                writeln!(out, "x,y,z")?;
                for p in points {
                    writeln!(out, "{},{},{}", p[0], p[1], p[2])?;
                }
            }
        }
        out.flush()?;
    }
    file.commit()
}

/// Writes a recording as CSV (`t,x,y` then its covariate columns by name)
/// to any writer, so a simulated sensor's covariates travel with its
/// readings. With no covariates the bytes are those of [`write_calibrated`].
pub fn write_dataset_to<W: Write>(out: &mut W, data: &Dataset) -> io::Result<()> {
    if data.covariates.is_empty() {
        return write_calibrated_to(out, data.t.as_deref(), &data.x, &data.y);
    }
    let mut header: Vec<&str> = Vec::new();
    if data.t.is_some() {
        header.push("t");
    }
    header.extend([data.x_name.as_str(), data.y_name.as_str()]);
    header.extend(data.covariates.iter().map(|c| c.name.as_str()));
    writeln!(out, "{}", header.join(","))?;
    for i in 0..data.len() {
        if let Some(t) = &data.t {
            write!(out, "{},", t[i])?;
        }
        write!(out, "{},{}", data.x[i], data.y[i])?;
        for c in &data.covariates {
            write!(out, ",{}", c.values[i])?;
        }
        writeln!(out)?;
    }
    Ok(())
}
