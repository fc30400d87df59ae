//! CSV in and out.
//!
//! Input: a header line, then one sample per line. The two turning axes come
//! from `x` and `y` (or columns the user names), time from `t` when present,
//! and every other numeric column is kept as a covariate under its header
//! name. Every error names the file, the line and the column.

use std::fs::File;
use std::io::{self, Read};
use std::path::{Path, PathBuf};

use crate::io::regular::{not_regular_kind, open_regular};
use crate::sample::{Covariate, Dataset, Dataset3};

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
    /// Whether the time column's values are read. `false` for a command
    /// that does not use them: the column is still found (and is no
    /// covariate), its values are not parsed, and the dataset has no times
    /// (as for a column of other numbers the command does not read, a
    /// value there that is not a number is not its concern).
    pub read_time: bool,
}

impl Default for ColumnSpec {
    fn default() -> Self {
        ColumnSpec {
            x: "x".into(),
            y: "y".into(),
            t: None,
            read_time: true,
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
    #[error(
        "{path}: the header ({columns}) has no sample after it; record some, one per line, and try again"
    )]
    NoRows { path: PathBuf, columns: String },
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
        "column '{name}' is in both {first} and {second}: a sensor of a source of several files \
         must name columns found in one file only; rename one of them"
    )]
    AmbiguousColumn {
        name: String,
        first: PathBuf,
        second: PathBuf,
    },
    #[error(
        "'{name}' is a column of {path} but '{other}' of {other_path}: a row carries only its \
         own file's columns, so a sensor's columns must all come from one file"
    )]
    SplitColumns {
        name: String,
        path: PathBuf,
        other: String,
        other_path: PathBuf,
    },
    #[error(
        "{first} covers {first_start:.3} to {first_end:.3} s and {second} covers \
         {second_start:.3} to {second_end:.3} s: the files of one csv source do not overlap in \
         time, so they are not on one clock; give files recorded together"
    )]
    Disjoint {
        first: PathBuf,
        first_start: f64,
        first_end: f64,
        second: PathBuf,
        second_start: f64,
        second_end: f64,
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
    #[error("{path} is not a regular file: give a CSV recording")]
    NotAFile { path: PathBuf },
    #[error(
        "{path}:{line}: the header has time column '{column}', so period_s does not apply: remove period_s (the rows' times come from '{column}')"
    )]
    TimeAndPeriod {
        path: PathBuf,
        line: u64,
        column: String,
    },
    #[error(
        "{path}:{line}: no time column (t, t_s, time or time_s) in the header (columns: {available}): give period_s, the seconds between rows, or name the time column with time_column"
    )]
    NoTime {
        path: PathBuf,
        line: u64,
        available: String,
    },
    #[error(
        "{path}:{line}: column '{column}': time {time} s is not after {previous} s on line {previous_line}: the rows must be in increasing time; sort the file by '{column}'"
    )]
    NotIncreasing {
        path: PathBuf,
        line: u64,
        column: String,
        time: f64,
        previous: f64,
        previous_line: u64,
    },
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

/// Which of the other columns a reader keeps as covariates.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum Covariates {
    /// Every numeric column (an analysis that tries them all).
    #[default]
    All,
    /// Only these, where the file has them and they are numeric: the
    /// other columns are neither parsed nor checked, and cost nothing.
    Only(Vec<String>),
}

impl Covariates {
    fn wants(&self, name: &str) -> bool {
        match self {
            Covariates::All => true,
            Covariates::Only(names) => names.iter().any(|n| n == name),
        }
    }
}

/// Reads a recording from a file.
pub fn read_dataset(path: &Path, spec: &ColumnSpec) -> Result<Dataset, CsvError> {
    read_dataset_with(path, spec, &Covariates::All)
}

/// [`read_dataset`], keeping only the `covariates` chosen.
pub fn read_dataset_with(
    path: &Path,
    spec: &ColumnSpec,
    covariates: &Covariates,
) -> Result<Dataset, CsvError> {
    read_file(path, spec, covariates, None)
}

/// The rows read so far, shown to a watcher a block at a time while the
/// rest are read: the new ones are those from `from`.
#[derive(Debug, Clone, Copy)]
pub struct RowsRead<'a> {
    pub from: usize,
    pub x: &'a [f64],
    pub y: &'a [f64],
    pub covariates: &'a [Covariate],
}

/// Rows a watcher is shown at a time.
const WATCHED_ROWS: usize = 1 << 13;

/// [`read_dataset_with`], showing `watch` the rows as they are read (a
/// spike gate can judge them meanwhile, on another core).
pub fn read_dataset_watched(
    path: &Path,
    spec: &ColumnSpec,
    covariates: &Covariates,
    watch: &mut dyn FnMut(RowsRead<'_>),
) -> Result<Dataset, CsvError> {
    read_file(path, spec, covariates, Some(watch))
}

/// A file read whole ([`read_whole`]): on two cores when it is large and
/// nobody `watch`es (a watcher, the spike gate, has the other core
/// already: a second reader would only leave it the rest of the file to
/// judge alone, after).
fn read_file(
    path: &Path,
    spec: &ColumnSpec,
    covariates: &Covariates,
    watch: Option<&mut dyn FnMut(RowsRead<'_>)>,
) -> Result<Dataset, CsvError> {
    read_whole(path, watch, |front, size, watch| {
        parse_dataset_sized(front, path, spec, covariates, size, watch)
    })
}

/// `parse` given the file at `path` (cut in two halves, to be read on two
/// cores, when it is large and there is no watcher), its size and the
/// watcher (one that looks at nothing when there is none).
fn read_whole<T>(
    path: &Path,
    watch: Option<&mut dyn FnMut(RowsRead<'_>)>,
    parse: impl FnOnce(Front<'_>, u64, &mut dyn FnMut(RowsRead<'_>)) -> Result<T, CsvError>,
) -> Result<T, CsvError> {
    let (file, size) = open_sized(path)?;
    let front = Front::file(
        &file,
        watch.is_none().then(|| halves::cut(&file, size)).flatten(),
    );
    let mut unwatched = |_: RowsRead<'_>| {};
    parse(front, size, watch.unwrap_or(&mut unwatched))
}

/// A regular file, open, and its size in bytes (0 when unknown).
fn open_sized(path: &Path) -> Result<(File, u64), CsvError> {
    let file = open_regular(path).map_err(|source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let size = file.metadata().map_or(0, |m| m.len());
    Ok((file, size))
}

/// Most bytes reserved ahead of reading, over every column read (more
/// grow as rows come): a short first row cannot reserve far more than a
/// file needs.
const RESERVED_BYTES_AT_MOST: u64 = 1 << 28;

/// The rows a file of `size` bytes holds when they are about as long as
/// `first` (its fields and their separators), with a tenth to spare, for
/// `columns` columns read: room reserved for them from the start, instead
/// of growing them through copies.
fn rows_expected(size: u64, first: &csv::ByteRecord, columns: usize) -> usize {
    let row = (first.as_slice().len() + first.len()).max(1) as u64;
    let most = RESERVED_BYTES_AT_MOST / (8 * columns.max(1) as u64);
    let rows = (size / row).saturating_add(size / row / 10).min(most);
    usize::try_from(rows).unwrap_or(0)
}

/// The number in field `i` of a record, or an error naming the file, the
/// line, the column and the field.
fn cell(
    field: Option<&[u8]>,
    i: usize,
    names: &[String],
    path: &Path,
    line: u64,
) -> Result<f64, CsvError> {
    // A record holds every field a reader reads ([`records::Records::read`]).
    let parsed = match field {
        Some(field) => parse_number(field),
        None => Err("the record was read without this field; please report this".into()),
    };
    parsed.map_err(|problem| CsvError::BadValue {
        path: path.to_path_buf(),
        line,
        column: super::excerpt(&names[i]).into_owned(),
        field: i + 1,
        problem,
    })
}

/// Bytes a reader of a recording asks for at a time.
const READ_BYTES: usize = 1 << 16;

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
        // Fields are trimmed where they are parsed ([`parse_number`]):
        // trimming whole records copies every one of them.
        .trim(csv::Trim::Headers)
        .comment(Some(b'#'))
        // Reads of 64 KiB: a file is read straight, through no buffer of
        // its own.
        .buffer_capacity(READ_BYTES)
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

/// Refuses a header that names a column twice (which would be meant?).
fn check_unique(names: &[String], path: &Path) -> Result<(), CsvError> {
    for (i, name) in names.iter().enumerate() {
        if let Some(j) = names[i + 1..].iter().position(|n| n == name) {
            return Err(CsvError::DuplicateColumn {
                path: path.to_path_buf(),
                name: super::excerpt(name).into_owned(),
                first: i + 1,
                second: i + j + 2,
            });
        }
    }
    Ok(())
}

/// Reads a recording from any reader; `path` is used in messages only.
pub fn parse_dataset<R: Read>(
    reader: R,
    path: &Path,
    spec: &ColumnSpec,
) -> Result<Dataset, CsvError> {
    let front = Front::stream(reader);
    parse_dataset_sized(front, path, spec, &Covariates::All, 0, &mut |_| {})
}

/// [`parse_dataset`] keeping the `covariates` chosen; `size`: the bytes
/// the reader holds, when known (0 otherwise), to reserve room for its
/// rows. A file with a cut is read on two cores (see [`halves`]).
fn parse_dataset_sized(
    front: Front<'_>,
    path: &Path,
    spec: &ColumnSpec,
    wanted: &Covariates,
    size: u64,
    watch: &mut dyn FnMut(RowsRead<'_>),
) -> Result<Dataset, CsvError> {
    let (csv, names) = open_with_header(records::Tap::new(front), path)?;
    check_unique(&names, path)?;
    let layout = Layout::of(&names, path, spec, wanted)?;
    let mut records = records::Records::after_header(csv, names.len(), path)?;
    let columns = std::thread::scope(|scope| {
        let reader = Reader {
            names: &names,
            path,
            size,
        };
        let read = reader.read_front(&mut records, scope, layout.roles, layout.timed, watch);
        // Before the scope waits for the other core.
        records.get_ref().stop_rest();
        read
    })?;
    if columns.x.is_empty() {
        // Nothing can be said of its columns (which are numbers) nor fitted.
        return Err(CsvError::NoRows {
            path: path.to_path_buf(),
            columns: super::name_list(&names),
        });
    }

    // The reader checked lengths and finiteness value by value.
    Dataset::new(
        names[layout.x_index].clone(),
        names[layout.y_index].clone(),
        columns.t,
        columns.x,
        columns.y,
        columns.covariates,
    )
    .map_err(|e| CsvError::Malformed {
        path: path.to_path_buf(),
        line: 0,
        message: e.to_string(),
    })
}

/// Which column of a header is what.
struct Layout {
    x_index: usize,
    y_index: usize,
    /// Whether a time column is read (one is found, and the times are wanted).
    timed: bool,
    /// Each column's role, the covariates not yet numbered.
    roles: Vec<Role>,
}

impl Layout {
    /// The columns `spec` names, and the covariates `wanted`, in a header
    /// of `names`.
    fn of(
        names: &[String],
        path: &Path,
        spec: &ColumnSpec,
        wanted: &Covariates,
    ) -> Result<Layout, CsvError> {
        if spec.x == spec.y {
            return Err(CsvError::SameAxis {
                path: path.to_path_buf(),
                x: spec.x.clone(),
                y: spec.y.clone(),
            });
        }
        let find = |name: &str| names.iter().position(|n| n == name);
        let missing =
            |name: &str, role: &'static str, flag: &'static str| CsvError::MissingColumn {
                path: path.to_path_buf(),
                name: name.to_string(),
                role,
                flag,
                available: super::name_list(names),
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
        let roles = (0..names.len())
            .map(|i| match i {
                _ if i == x_index => Role::X,
                _ if i == y_index => Role::Y,
                _ if Some(i) == t_index && spec.read_time => Role::T,
                // Found, and so no covariate; not read.
                _ if Some(i) == t_index => Role::Ignored,
                _ if !wanted.wants(&names[i]) => Role::Ignored,
                _ => Role::Covariate(usize::MAX), // numbered once the first row shows it is numeric
            })
            .collect();
        Ok(Layout {
            x_index,
            y_index,
            timed: t_index.is_some() && spec.read_time,
            roles,
        })
    }
}

/// The columns a reader parses, from the first record: a column whose
/// first value is not a number is a text column (a label, a unit), not a
/// covariate, and is skipped. The covariates it finds are numbered in
/// `roles` and pushed to `covariates`.
fn first_record(
    record: &csv::ByteRecord,
    roles: &mut [Role],
    names: &[String],
    covariates: &mut Vec<Covariate>,
) -> Vec<(usize, Role)> {
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
    let read = roles.iter().copied().enumerate();
    read.filter(|(_, role)| *role != Role::Ignored).collect()
}

/// Reads a 3-axis recording: `spec`'s x and y, and `z` (a numeric
/// column, neither x, y nor time).
pub fn read_dataset3(path: &Path, spec: &ColumnSpec, z: &str) -> Result<Dataset3, CsvError> {
    read_dataset3_with(path, spec, z, &Covariates::All)
}

/// [`read_dataset3`], keeping only the `covariates` chosen.
pub fn read_dataset3_with(
    path: &Path,
    spec: &ColumnSpec,
    z: &str,
    covariates: &Covariates,
) -> Result<Dataset3, CsvError> {
    read_file3(path, spec, z, covariates, None)
}

/// [`read_dataset3_with`], showing `watch` the rows as they are read (z
/// among their covariates, under its name).
pub fn read_dataset3_watched(
    path: &Path,
    spec: &ColumnSpec,
    z: &str,
    covariates: &Covariates,
    watch: &mut dyn FnMut(RowsRead<'_>),
) -> Result<Dataset3, CsvError> {
    read_file3(path, spec, z, covariates, Some(watch))
}

/// [`read_file`] for a 3-axis recording.
fn read_file3(
    path: &Path,
    spec: &ColumnSpec,
    z: &str,
    covariates: &Covariates,
    watch: Option<&mut dyn FnMut(RowsRead<'_>)>,
) -> Result<Dataset3, CsvError> {
    // z travels as a covariate until the dataset is built.
    let covariates = match covariates {
        Covariates::All => Covariates::All,
        Covariates::Only(names) => {
            Covariates::Only(names.iter().cloned().chain([z.to_string()]).collect())
        }
    };
    let read = read_whole(path, watch, |front, size, watch| {
        dataset3_of(front, path, spec, z, &covariates, size, watch)
    });
    match read {
        // The message lists every column z could have been: read them.
        Err(CsvError::MissingColumn { .. }) if covariates != Covariates::All => {
            read_dataset3(path, spec, z)
        }
        read => read,
    }
}

/// Reads a 3-axis recording from any reader; `path` is used in messages.
pub fn parse_dataset3<R: Read>(
    reader: R,
    path: &Path,
    spec: &ColumnSpec,
    z: &str,
) -> Result<Dataset3, CsvError> {
    let front = Front::stream(reader);
    dataset3_of(front, path, spec, z, &Covariates::All, 0, &mut |_| {})
}

fn dataset3_of(
    front: Front<'_>,
    path: &Path,
    spec: &ColumnSpec,
    z: &str,
    covariates: &Covariates,
    size: u64,
    watch: &mut dyn FnMut(RowsRead<'_>),
) -> Result<Dataset3, CsvError> {
    if z == spec.x || z == spec.y || spec.t.as_deref() == Some(z) {
        let other = if z == spec.x {
            &spec.x
        } else if z == spec.y {
            &spec.y
        } else {
            z
        };
        return Err(CsvError::SameAxis {
            path: path.to_path_buf(),
            x: format!("'{}' (z)", super::excerpt(z)),
            y: format!("'{}'", super::excerpt(other)),
        });
    }
    let dataset = parse_dataset_sized(front, path, spec, covariates, size, watch)?;
    let names: Vec<String> = dataset.covariates.iter().map(|c| c.name.clone()).collect();
    // A time column named with --t is there (it was looked for), read or not.
    let time_name = spec.t.clone();
    Dataset3::from_dataset(dataset, z).ok_or_else(|| {
        let mut available = vec![spec.x.clone(), spec.y.clone()];
        available.extend(time_name);
        available.extend(names);
        CsvError::MissingColumn {
            path: path.to_path_buf(),
            name: z.to_string(),
            role: "the z axis (a numeric column)",
            flag: "--z",
            available: super::name_list(&available),
        }
    })
}

/// The column names of a file's header (for choosing defaults, such as a
/// third axis when the file has a `z` column).
pub fn header(path: &Path) -> Result<Vec<String>, CsvError> {
    let file = open_regular(path).map_err(|source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let (_, names) = open_with_header(file, path)?;
    Ok(names)
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
    let file = open_regular(path).map_err(|source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_series(file, path, column, role, flag)
}

/// [`read_series`] from any reader; `path` is used in messages only.
pub fn parse_series<R: Read>(
    reader: R,
    path: &Path,
    column: &str,
    role: &'static str,
    flag: &'static str,
) -> Result<Series, CsvError> {
    let (csv, names) = open_with_header(records::Tap::new(reader), path)?;
    let find = |name: &str| names.iter().position(|n| n == name);
    let value_index = find(column).ok_or_else(|| CsvError::MissingColumn {
        path: path.to_path_buf(),
        name: column.to_string(),
        role,
        flag,
        available: super::name_list(&names),
    })?;
    let t_index = DEFAULT_TIME_COLUMNS
        .iter()
        .find_map(|t| find(t))
        .ok_or_else(|| CsvError::MissingColumn {
            path: path.to_path_buf(),
            name: DEFAULT_TIME_COLUMNS.join(" or "),
            role: "time (a second file is joined to the recording by time)",
            flag,
            available: super::name_list(&names),
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
    let mut records = records::Records::after_header(csv, names.len(), path)?;
    let mut record = csv::ByteRecord::new();
    while let Some(row) = records.read_row(&mut record)? {
        let line = row.line();
        for (i, out) in [(t_index, &mut t), (value_index, &mut values)] {
            out.push(cell(row.get(i), i, &names, path, line)?);
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
    let field = field.trim_ascii();
    // polars' parser (fast-float2) reads bytes and is faster than `str`'s
    // (no UTF-8 check); both round correctly, accept the same text (the
    // tests hold them to it), and any text it refuses, or a value refused
    // here, goes to `str`'s, whose verdict and message stand.
    if let Ok(v) = fast_float2::parse::<f64, _>(field)
        && v.is_finite()
        && !crate::sample::too_large(v)
    {
        return Ok(v);
    }
    parse_number_by_str(field)
}

/// [`parse_number`] of a trimmed field by `str::parse`.
fn parse_number_by_str(field: &[u8]) -> Result<f64, String> {
    let text =
        std::str::from_utf8(field).map_err(|_| "the value is not valid UTF-8 text".to_string())?;
    if text.is_empty() {
        return Err("the value is empty; every sample needs a number here".into());
    }
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && !crate::sample::too_large(v) => Ok(v),
        Ok(v) if v.is_finite() => Err(format!(
            "'{}' is too large to square in f64: the fit squares readings, so give values of magnitude at most {:e}",
            super::excerpt(text),
            crate::sample::MAX_MAGNITUDE
        )),
        Ok(_) => Err(format!("'{}' is not a finite number", super::excerpt(text))),
        Err(_) => Err(format!("'{}' is not a number", super::excerpt(text))),
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
            message: unequal_lengths(len, expected_len),
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

/// What is wrong with a line of `len` fields under a header of `expected`.
fn unequal_lengths(len: impl std::fmt::Display, expected: impl std::fmt::Display) -> String {
    format!("this line has {len} fields but the header has {expected}")
}

mod columns;
mod halves;
mod records;
mod stream;
mod write;

use columns::{Columns, Reader};
use halves::{Back, Front, Positional};

pub use stream::*;
pub use write::*;

#[cfg(test)]
mod tests {
    #[test]
    fn a_third_axis_is_read_and_named_when_missing() {
        let text = "t,mx,my,mz,temp\n0,1,2,3,20\n1,4,5,6,21\n";
        let spec = ColumnSpec {
            x: "mx".into(),
            y: "my".into(),
            ..ColumnSpec::default()
        };
        let d = parse_dataset3(text.as_bytes(), Path::new("a.csv"), &spec, "mz").unwrap();
        assert_eq!(d.points, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(d.t, Some(vec![0.0, 1.0]));
        assert_eq!(d.z_name, "mz");
        assert_eq!(d.covariates.len(), 1);
        assert_eq!(d.covariates[0].name, "temp");
        let e = parse_dataset3(text.as_bytes(), Path::new("a.csv"), &spec, "z").unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("'z'") && m.contains("--z") && m.contains("mz"),
            "{m}"
        );
        let e = parse_dataset3(text.as_bytes(), Path::new("a.csv"), &spec, "mx").unwrap_err();
        assert!(matches!(e, CsvError::SameAxis { .. }), "{e}");
    }

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

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(20_000))]
        /// Any text, of the bytes numbers and their neighbours are made
        /// of, parses (or is refused, with its message) as `str` parses it.
        #[test]
        fn a_field_parses_as_str_parses_it(
            field in "[ \t]?[+-]?[0-9]{0,22}[.]?[0-9]{0,22}([eE][+-]?[0-9]{0,4})?[ ]?|[0-9infatyINFATYxe_.+ -]{0,12}",
        ) {
            let by_str = parse_number_by_str(field.trim().as_bytes());
            proptest::prop_assert_eq!(parse_number(field.as_bytes()), by_str, "{:?}", field);
        }
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

    /// Every row of `text` (after its header) as a row or a skip message.
    fn stream(
        text: &[u8],
        time: Option<&str>,
        period: Option<f64>,
        required: &[usize],
    ) -> (CsvLayout, Vec<Result<CsvRow, String>>, u64) {
        let mut lines = CsvLines::new(text);
        let header = read_header(&mut lines, Path::new("s.csv")).unwrap();
        let layout = CsvLayout::resolve(Path::new("s.csv"), header, time, period).unwrap();
        let mut rows = CsvRows::new(lines, layout.clone(), required);
        let mut out = Vec::new();
        while let Some(next) = rows.next_row().unwrap() {
            out.push(next.map_err(|(e, _)| e.to_string()));
        }
        (layout, out, rows.bytes_read())
    }

    #[test]
    fn streamed_rows_keep_every_column_by_index_and_skip_bad_ones() {
        let text = b"# logged by the robot\r\n\"t\",a,b,label\r\n0.0,1,2,x\r\n\n0.1,3,oops,y\r\n0.2,5\r\n0.05,6,7,z\r\n0.3,inf,8,w\r\n0.4,9,10,v";
        let (layout, rows, bytes) = stream(text, None, None, &[1]);
        assert_eq!(layout.names, ["t", "a", "b", "label"]);
        assert_eq!(layout.time, TimeBase::Column(0));
        assert_eq!(layout.header_line, 2);
        assert_eq!(bytes, text.len() as u64);
        let first = rows[0].as_ref().unwrap();
        assert_eq!((first.line, first.time), (3, 0.0));
        assert_eq!(first.values[..3], [0.0, 1.0, 2.0]);
        // A cell nobody reads that is not a number is NaN; the row stays.
        assert!(first.values[3].is_nan());
        let second = rows[1].as_ref().unwrap();
        assert!(second.values[2].is_nan() && second.line == 5);
        assert_eq!(
            rows[2],
            Err("line 6: this line has 2 fields but the header has 4".into())
        );
        assert_eq!(
            rows[3],
            Err("line 7: column 't' (field 1): time 0.05 s is not after 0.1 s on line 5".into())
        );
        assert_eq!(
            rows[4],
            Err("line 8: column 'a' (field 2): 'inf' is not a finite number".into())
        );
        assert_eq!(rows[5].as_ref().unwrap().time, 0.4);
        assert_eq!(rows.len(), 6);
    }

    #[test]
    fn a_long_line_is_skipped_in_bounded_memory_and_periods_count_every_row() {
        let mut text = b"a,b\n1,2\n".to_vec();
        text.extend(std::iter::repeat_n(b'7', 3 * MAX_LINE_BYTES));
        text.extend(b",1\n3,4\n");
        let mut lines = CsvLines::new(&text[..]);
        let header = read_header(&mut lines, Path::new("s.csv")).unwrap();
        let layout = CsvLayout::resolve(Path::new("s.csv"), header, None, Some(0.1)).unwrap();
        let mut rows = CsvRows::new(lines, layout, &[0, 1]);
        assert_eq!(rows.next_row().unwrap().unwrap().unwrap().time, 0.0);
        let long = rows.next_row().unwrap().unwrap().unwrap_err().0;
        assert_eq!(long.line, 3);
        assert!(
            long.problem.contains("more than the 65536"),
            "{}",
            long.problem
        );
        assert!(rows.lines.buf.capacity() <= 2 * MAX_LINE_BYTES);
        // The skipped row keeps its place in time.
        let last = rows.next_row().unwrap().unwrap().unwrap();
        assert_eq!((last.line, last.time), (4, 0.2));
        assert!(rows.next_row().unwrap().is_none());
    }

    #[test]
    fn a_header_is_checked_for_time_and_period() {
        let resolve = |text: &str, time: Option<&str>, period: Option<f64>| {
            let mut lines = CsvLines::new(text.as_bytes());
            read_header(&mut lines, Path::new("s.csv"))
                .and_then(|h| CsvLayout::resolve(Path::new("s.csv"), h, time, period))
                .map_err(|e| e.to_string())
        };
        assert_eq!(
            resolve("a,time_s,b\n", None, None).unwrap().time,
            TimeBase::Column(1)
        );
        assert_eq!(
            resolve("a,when,b\n", Some("when"), None).unwrap().time,
            TimeBase::Column(1)
        );
        let err = resolve("a,t\n", None, Some(0.1)).unwrap_err();
        assert!(
            err.starts_with("s.csv:1: the header has time column 't'"),
            "{err}"
        );
        let err = resolve("a,b\n", None, None).unwrap_err();
        assert!(err.starts_with("s.csv:1: no time column"), "{err}");
        assert!(err.contains("(columns: a, b)"), "{err}");
        let err = resolve("a,b\n", Some("t"), None).unwrap_err();
        assert!(err.contains("no column 't' for time"), "{err}");
        let err = resolve("\n# c\n", None, None).unwrap_err();
        assert!(err.contains("the file is empty"), "{err}");
        let err = resolve("a,,b\n", None, Some(1.0)).unwrap_err();
        assert!(err.starts_with("s.csv:1: column 2 has no name"), "{err}");
        let wide = vec!["c"; MAX_COLUMNS + 1]
            .iter()
            .enumerate()
            .map(|(i, c)| format!("{c}{i}"))
            .collect::<Vec<_>>()
            .join(",");
        let err = resolve(&wide, None, Some(1.0)).unwrap_err();
        assert!(err.contains("1025 columns"), "{err}");
    }

    #[test]
    fn a_csv_is_told_from_a_capture_and_from_prose() {
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, bytes: &[u8]| {
            let path = dir.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            path
        };
        assert!(looks_like_csv(&write("a.CSV", b"")));
        assert!(looks_like_csv(&write(
            "a.log",
            b"# robot\nt,x,y\n0.0,1,2\n"
        )));
        assert!(!looks_like_csv(&write(
            "b.txt",
            b"my notes, not data\nmore notes, here\n"
        )));
        assert!(!looks_like_csv(&write(
            "c.bin",
            b"\x02\x10,\x00\n\x02,\x01\n"
        )));
        assert!(!looks_like_csv(&dir.path().join("missing")));
    }
}
