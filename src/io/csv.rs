//! CSV in and out.
//!
//! Input: a header line, then one sample per line. The two turning axes come
//! from `x` and `y` (or columns the user names), time from `t` when present,
//! and every other numeric column is kept as a covariate under its header
//! name. Every error names the file, the line and the column.

use std::fs::File;
use std::io::{self, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use crate::io::atomic::AtomicFile;
use crate::sample::{Covariate, Dataset};

/// Time columns looked for, in order, when the user names none.
pub const DEFAULT_TIME_COLUMNS: [&str; 4] = ["t", "t_s", "time", "time_s"];

/// Which columns of the file hold what.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ColumnSpec {
    pub x: String,
    pub y: String,
    /// `None`: use the first of [`DEFAULT_TIME_COLUMNS`] present, if any.
    /// `Some(name)`: that column must exist.
    pub t: Option<String>,
}

impl Default for ColumnSpec {
    fn default() -> Self {
        ColumnSpec {
            x: "x".into(),
            y: "y".into(),
            t: None,
        }
    }
}

/// What can go wrong reading a CSV recording. Each variant names the file,
/// and the line and column where there is one.
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    #[error("{path}: cannot read the file: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "{path}: the file is empty; it needs a header line such as `t,x,y` and one sample per line"
    )]
    Empty { path: PathBuf },
    #[error("{path}:{line}: {message}")]
    Malformed {
        path: PathBuf,
        line: u64,
        message: String,
    },
    #[error(
        "{path}: no column '{name}' for {role} in the header (columns: {available}); name the right one with {flag}"
    )]
    MissingColumn {
        path: PathBuf,
        name: String,
        role: &'static str,
        flag: &'static str,
        available: String,
    },
    #[error(
        "{path}:1: column '{name}' appears twice in the header (fields {first} and {second}); rename one"
    )]
    DuplicateColumn {
        path: PathBuf,
        name: String,
        first: usize,
        second: usize,
    },
    #[error(
        "{path}:1: columns {x} and {y} are the same column; x and y must be two different axes"
    )]
    SameAxis { path: PathBuf, x: String, y: String },
    #[error("{path}:{line}: column '{column}' (field {field}): {problem}")]
    BadValue {
        path: PathBuf,
        line: u64,
        column: String,
        field: usize,
        problem: String,
    },
}

/// A column of the file we keep, and where its values go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    X,
    Y,
    T,
    Covariate(usize),
    /// A text column (first value not a number): not a covariate.
    Ignored,
}

/// Reads a recording from a file.
pub fn read_dataset(path: &Path, spec: &ColumnSpec) -> Result<Dataset, CsvError> {
    let file = File::open(path).map_err(|source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_dataset(io::BufReader::with_capacity(1 << 16, file), path, spec)
}

/// The number in field `i` of a record, or an error naming the file, the
/// line, the column and the field.
fn cell(
    record: &csv::ByteRecord,
    i: usize,
    names: &[String],
    path: &Path,
    line: u64,
) -> Result<f64, CsvError> {
    parse_number(&record[i]).map_err(|problem| CsvError::BadValue {
        path: path.to_path_buf(),
        line,
        column: names[i].clone(),
        field: i + 1,
        problem,
    })
}

/// A CSV reader as fieldcal reads recordings (a header line, trimmed
/// fields, `#` comments), and the header's column names; an empty header
/// is an error naming the file.
fn open_with_header<R: Read>(
    reader: R,
    path: &Path,
) -> Result<(csv::Reader<R>, Vec<String>), CsvError> {
    let mut csv = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(false)
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(reader);
    let header = csv.byte_headers().map_err(|e| csv_error(path, e))?.clone();
    if header.is_empty() || (header.len() == 1 && header[0].is_empty()) {
        return Err(CsvError::Empty {
            path: path.to_path_buf(),
        });
    }
    let names = header
        .iter()
        .map(|h| String::from_utf8_lossy(h).into_owned())
        .collect();
    Ok((csv, names))
}

/// Reads a recording from any reader; `path` is used in messages only.
pub fn parse_dataset<R: Read>(
    reader: R,
    path: &Path,
    spec: &ColumnSpec,
) -> Result<Dataset, CsvError> {
    let (mut csv, names) = open_with_header(reader, path)?;
    let err_at = |e: csv::Error| csv_error(path, e);
    for (i, name) in names.iter().enumerate() {
        if let Some(j) = names[i + 1..].iter().position(|n| n == name) {
            return Err(CsvError::DuplicateColumn {
                path: path.to_path_buf(),
                name: name.clone(),
                first: i + 1,
                second: i + j + 2,
            });
        }
    }
    if spec.x == spec.y {
        return Err(CsvError::SameAxis {
            path: path.to_path_buf(),
            x: spec.x.clone(),
            y: spec.y.clone(),
        });
    }

    let find = |name: &str| names.iter().position(|n| n == name);
    let missing = |name: &str, role: &'static str, flag: &'static str| CsvError::MissingColumn {
        path: path.to_path_buf(),
        name: name.to_string(),
        role,
        flag,
        available: names.join(", "),
    };
    let x_index = find(&spec.x).ok_or_else(|| missing(&spec.x, "the x axis", "--x"))?;
    let y_index = find(&spec.y).ok_or_else(|| missing(&spec.y, "the y axis", "--y"))?;
    let t_index = match &spec.t {
        Some(t) => Some(find(t).ok_or_else(|| missing(t, "time", "--t"))?),
        None => DEFAULT_TIME_COLUMNS.iter().find_map(|t| find(t)),
    };
    if t_index == Some(x_index) || t_index == Some(y_index) {
        let t = &names[t_index.unwrap_or_default()];
        return Err(CsvError::SameAxis {
            path: path.to_path_buf(),
            x: format!("'{t}' (time)"),
            y: "an axis".into(),
        });
    }

    let mut roles: Vec<Role> = (0..names.len())
        .map(|i| match i {
            _ if i == x_index => Role::X,
            _ if i == y_index => Role::Y,
            _ if Some(i) == t_index => Role::T,
            _ => Role::Covariate(usize::MAX), // numbered once the first row shows it is numeric
        })
        .collect();

    let mut x = Vec::new();
    let mut y = Vec::new();
    let mut t = t_index.map(|_| Vec::new());
    let mut covariates: Vec<Covariate> = Vec::new();
    let mut record = csv::ByteRecord::new();
    let mut first_row = true;

    while csv.read_byte_record(&mut record).map_err(err_at)? {
        let line = record.position().map_or(0, |p| p.line());
        if first_row {
            // A column whose first value is not a number is a text column
            // (a label, a unit): it is not a covariate, and is skipped.
            for (i, role) in roles.iter_mut().enumerate() {
                if let Role::Covariate(_) = role {
                    *role = if parse_number(&record[i]).is_ok() {
                        covariates.push(Covariate {
                            name: names[i].clone(),
                            values: Vec::new(),
                        });
                        Role::Covariate(covariates.len() - 1)
                    } else {
                        Role::Ignored
                    };
                }
            }
            first_row = false;
        }
        for (i, role) in roles.iter().enumerate() {
            if *role == Role::Ignored {
                continue;
            }
            let value = cell(&record, i, &names, path, line)?;
            match *role {
                Role::X => x.push(value),
                Role::Y => y.push(value),
                Role::T => {
                    if let Some(t) = t.as_mut() {
                        t.push(value)
                    }
                }
                Role::Covariate(k) => covariates[k].values.push(value),
                Role::Ignored => {}
            }
        }
    }

    // The reader checked lengths and finiteness value by value.
    Dataset::new(
        names[x_index].clone(),
        names[y_index].clone(),
        t,
        x,
        y,
        covariates,
    )
    .map_err(|e| CsvError::Malformed {
        path: path.to_path_buf(),
        line: 0,
        message: e.to_string(),
    })
}

/// One column of a file against that file's own time column: a gyro axis
/// recorded beside the sensor on the same clock.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// The time column found (one of [`DEFAULT_TIME_COLUMNS`]).
    pub time_name: String,
    pub t: Vec<f64>,
    pub values: Vec<f64>,
}

/// Reads `column` and the file's time column (the first of
/// [`DEFAULT_TIME_COLUMNS`]). `role` and `flag` say in messages what the
/// column is for and which option names it.
pub fn read_series(
    path: &Path,
    column: &str,
    role: &'static str,
    flag: &'static str,
) -> Result<Series, CsvError> {
    let file = File::open(path).map_err(|source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_series(
        io::BufReader::with_capacity(1 << 16, file),
        path,
        column,
        role,
        flag,
    )
}

/// [`read_series`] from any reader; `path` is used in messages only.
pub fn parse_series<R: Read>(
    reader: R,
    path: &Path,
    column: &str,
    role: &'static str,
    flag: &'static str,
) -> Result<Series, CsvError> {
    let (mut csv, names) = open_with_header(reader, path)?;
    let find = |name: &str| names.iter().position(|n| n == name);
    let value_index = find(column).ok_or_else(|| CsvError::MissingColumn {
        path: path.to_path_buf(),
        name: column.to_string(),
        role,
        flag,
        available: names.join(", "),
    })?;
    let t_index = DEFAULT_TIME_COLUMNS
        .iter()
        .find_map(|t| find(t))
        .ok_or_else(|| CsvError::MissingColumn {
            path: path.to_path_buf(),
            name: DEFAULT_TIME_COLUMNS.join(" or "),
            role: "time (a second file is joined to the recording by time)",
            flag,
            available: names.join(", "),
        })?;
    if t_index == value_index {
        return Err(CsvError::SameAxis {
            path: path.to_path_buf(),
            x: format!("'{column}' ({role})"),
            y: "time".into(),
        });
    }
    let mut t = Vec::new();
    let mut values = Vec::new();
    let mut record = csv::ByteRecord::new();
    while csv
        .read_byte_record(&mut record)
        .map_err(|e| csv_error(path, e))?
    {
        let line = record.position().map_or(0, |p| p.line());
        for (i, out) in [(t_index, &mut t), (value_index, &mut values)] {
            out.push(cell(&record, i, &names, path, line)?);
        }
    }
    Ok(Series {
        time_name: names[t_index].clone(),
        t,
        values,
    })
}

/// Parses one field as a finite number, or says what is wrong with it.
fn parse_number(field: &[u8]) -> Result<f64, String> {
    let text =
        std::str::from_utf8(field).map_err(|_| "the value is not valid UTF-8 text".to_string())?;
    if text.is_empty() {
        return Err("the value is empty; every sample needs a number here".into());
    }
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("'{text}' is not a finite number")),
        Err(_) => Err(format!("'{text}' is not a number")),
    }
}

fn csv_error(path: &Path, e: csv::Error) -> CsvError {
    let line = e.position().map_or(0, |p| p.line());
    match e.into_kind() {
        csv::ErrorKind::Io(source) => CsvError::Io {
            path: path.to_path_buf(),
            source,
        },
        csv::ErrorKind::UnequalLengths {
            expected_len, len, ..
        } => CsvError::Malformed {
            path: path.to_path_buf(),
            line,
            message: format!("this line has {len} fields but the header has {expected_len}"),
        },
        csv::ErrorKind::Utf8 { .. } => CsvError::Malformed {
            path: path.to_path_buf(),
            line,
            message: "this line is not valid UTF-8 text".into(),
        },
        other => CsvError::Malformed {
            path: path.to_path_buf(),
            line,
            message: format!("{other:?}"),
        },
    }
}

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

/// Writes a recording as CSV (`t,x,y` then its covariate columns by name),
/// atomically, so a simulated sensor's covariates travel with its readings.
/// With no covariates the bytes are those of [`write_calibrated`].
pub fn write_dataset(path: &Path, data: &Dataset) -> io::Result<()> {
    let mut file = AtomicFile::create(path)?;
    {
        let mut out = BufWriter::with_capacity(1 << 16, file.as_file_mut());
        write_dataset_to(&mut out, data)?;
        out.flush()?;
    }
    file.commit()
}

/// Writes a recording as CSV to any writer; see [`write_dataset`].
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

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Dataset, CsvError> {
        parse_dataset(
            text.as_bytes(),
            Path::new("mem.csv"),
            &ColumnSpec::default(),
        )
    }

    #[test]
    fn reads_a_series_against_its_time() {
        let text = "t_s,gyro_x,gyro_z\n0.0,1,2\n0.1,3,4\n";
        let s = parse_series(
            text.as_bytes(),
            Path::new("g.csv"),
            "gyro_z",
            "the gyro",
            "--gyro",
        )
        .unwrap();
        assert_eq!(s.time_name, "t_s");
        assert_eq!(s.t, vec![0.0, 0.1]);
        assert_eq!(s.values, vec![2.0, 4.0]);
        let err = parse_series(
            text.as_bytes(),
            Path::new("g.csv"),
            "gyro",
            "the gyro",
            "--gyro",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("g.csv") && err.contains("'gyro'"), "{err}");
        assert!(err.contains("gyro_x, gyro_z"), "{err}");
        let err = parse_series(
            "a,b\n1,2\n".as_bytes(),
            Path::new("g.csv"),
            "b",
            "the gyro",
            "--gyro",
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("time"), "{err}");
    }

    #[test]
    fn reads_axes_time_and_covariates() {
        let d = parse("t,x,y,temp,label\n0.0,1,2,20.5,a\n0.1,3,4,20.6,b\n").unwrap();
        assert_eq!(d.t, Some(vec![0.0, 0.1]));
        assert_eq!(d.x, vec![1.0, 3.0]);
        assert_eq!(d.y, vec![2.0, 4.0]);
        assert_eq!(d.covariates.len(), 1);
        assert_eq!(d.covariates[0].name, "temp");
        assert_eq!(d.covariates[0].values, vec![20.5, 20.6]);
    }

    #[test]
    fn time_is_optional_and_found_under_common_names() {
        let d = parse("x,y\n1,2\n").unwrap();
        assert_eq!(d.t, None);
        let d = parse("t_s,x,y\n5,1,2\n").unwrap();
        assert_eq!(d.t, Some(vec![5.0]));
    }

    #[test]
    fn bad_value_names_line_and_column() {
        let err = parse("t,x,y\n0,1,2\n1,oops,2\n").unwrap_err().to_string();
        assert_eq!(
            err,
            "mem.csv:3: column 'x' (field 2): 'oops' is not a number"
        );
    }

    #[test]
    fn non_finite_values_are_refused() {
        for bad in ["NaN", "inf", "-infinity"] {
            let err = parse(&format!("x,y\n1,{bad}\n")).unwrap_err().to_string();
            assert!(err.contains("is not a finite number"), "{err}");
            assert!(err.starts_with("mem.csv:2: column 'y'"), "{err}");
        }
    }

    #[test]
    fn ragged_line_is_reported() {
        let err = parse("x,y\n1,2\n3\n").unwrap_err().to_string();
        assert_eq!(
            err,
            "mem.csv:3: this line has 1 fields but the header has 2"
        );
    }

    #[test]
    fn datasets_with_covariates_round_trip() {
        let data = Dataset::new(
            "x",
            "y",
            Some(vec![0.0, 0.5]),
            vec![1.5, -2.0],
            vec![3.0, 4.25],
            vec![crate::sample::Covariate {
                name: "temp".into(),
                values: vec![20.0, 20.125],
            }],
        )
        .unwrap();
        let mut out = Vec::new();
        write_dataset_to(&mut out, &data).unwrap();
        assert_eq!(parse(std::str::from_utf8(&out).unwrap()).unwrap(), data);
    }

    #[test]
    fn writes_round_trip_exactly() {
        let mut out = Vec::new();
        let xs = [0.1, -1e-300, 12345.678901234567];
        write_calibrated_to(&mut out, Some(&[0.0, 0.05, 0.1]), &xs, &[1.0, 2.0, 3.0]).unwrap();
        let d = parse(std::str::from_utf8(&out).unwrap()).unwrap();
        assert_eq!(d.x, xs);
    }
}
