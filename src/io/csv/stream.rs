//! Streaming: a recording read row by row (the daemon's csv source), with
//! bounded memory whatever the file holds. Pure: any `BufRead` in, rows out.

use super::*;

/// Longest line of a streamed recording, in bytes: a row of [`MAX_COLUMNS`]
/// numbers of 64 characters fits; a longer line is a bad row, skipped with
/// the memory it could take bounded.
pub const MAX_LINE_BYTES: usize = 64 * 1024;
/// Most columns of a streamed recording: far more than any logger writes;
/// bounds the per-row work and the width of every READING.
pub const MAX_COLUMNS: usize = 1024;

/// The lines of a file, each at most [`MAX_LINE_BYTES`], numbered from 1,
/// with the bytes read so far.
pub struct CsvLines<R> {
    inner: R,
    line: u64,
    bytes: u64,
    pub(super) buf: Vec<u8>,
}

/// One physical line.
enum Line {
    /// Its bytes (without the end of line) are in the buffer.
    Text,
    /// Longer than [`MAX_LINE_BYTES`]: skipped, `len` bytes.
    TooLong { len: usize },
}

impl<R: io::BufRead> CsvLines<R> {
    pub fn new(inner: R) -> Self {
        CsvLines {
            inner,
            line: 0,
            bytes: 0,
            buf: Vec::new(),
        }
    }

    /// Bytes consumed so far, line ends included.
    pub fn bytes_read(&self) -> u64 {
        self.bytes
    }

    /// The next line and its number, `None` at the end of the file. Reads at
    /// most [`MAX_LINE_BYTES`] into memory however long the line is.
    fn next_line(&mut self) -> io::Result<Option<(u64, Line)>> {
        self.buf.clear();
        let mut len = 0usize;
        let mut any = false;
        loop {
            let chunk = self.inner.fill_buf()?;
            if chunk.is_empty() {
                if !any {
                    return Ok(None);
                }
                break;
            }
            any = true;
            let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
                Some(i) => (i, true),
                None => (chunk.len(), false),
            };
            if len + take <= MAX_LINE_BYTES {
                self.buf.extend_from_slice(&chunk[..take]);
            }
            len += take;
            let used = take + usize::from(done);
            self.inner.consume(used);
            self.bytes += used as u64;
            if done {
                break;
            }
        }
        self.line += 1;
        if len > MAX_LINE_BYTES {
            return Ok(Some((self.line, Line::TooLong { len })));
        }
        if self.buf.last() == Some(&b'\r') {
            self.buf.pop();
        }
        Ok(Some((self.line, Line::Text)))
    }

    /// The next line that holds a record (not blank, not a `#` comment),
    /// split into trimmed fields; `Err` for a line too long or not CSV.
    fn next_record(
        &mut self,
        record: &mut csv::ByteRecord,
    ) -> io::Result<Option<(u64, Result<(), String>)>> {
        loop {
            let Some((line, kind)) = self.next_line()? else {
                return Ok(None);
            };
            if let Line::TooLong { len } = kind {
                return Ok(Some((
                    line,
                    Err(format!(
                        "the line is {len} bytes long, more than the {MAX_LINE_BYTES} a row may have"
                    )),
                )));
            }
            let text = self.buf.trim_ascii();
            if text.is_empty() || text.starts_with(b"#") {
                continue;
            }
            return Ok(Some((line, split_fields(text, record))));
        }
    }
}

/// Splits one line into trimmed fields with the csv crate (quotes work
/// within a line; a record never spans lines here).
fn split_fields(line: &[u8], record: &mut csv::ByteRecord) -> Result<(), String> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .buffer_capacity(line.len() + 1)
        .from_reader(line);
    record.clear();
    match reader.read_byte_record(record) {
        Ok(_) => Ok(()),
        Err(e) => Err(format!("not a CSV line: {e}")),
    }
}

/// A streamed recording's header: its column names and the line it is on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CsvHeader {
    pub names: Vec<String>,
    pub line: u64,
}

/// Reads the header (the first line that is not blank or a `#` comment):
/// bounded in length and columns, names unique.
pub fn read_header<R: io::BufRead>(
    lines: &mut CsvLines<R>,
    path: &Path,
) -> Result<CsvHeader, CsvError> {
    let io_err = |source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut record = csv::ByteRecord::new();
    let Some((line, split)) = lines.next_record(&mut record).map_err(io_err)? else {
        return Err(CsvError::Empty {
            path: path.to_path_buf(),
        });
    };
    let malformed = |message: String| CsvError::Malformed {
        path: path.to_path_buf(),
        line,
        message: format!("{message}; the first line must be the header, such as `t,x,y`"),
    };
    split.map_err(malformed)?;
    if record.len() > MAX_COLUMNS {
        return Err(malformed(format!(
            "{} columns, more than the {MAX_COLUMNS} a recording may have",
            record.len()
        )));
    }
    let mut names = Vec::with_capacity(record.len());
    for (i, field) in record.iter().enumerate() {
        match std::str::from_utf8(field) {
            Ok(name) if !name.is_empty() => names.push(name.to_string()),
            Ok(_) => return Err(malformed(format!("column {} has no name", i + 1))),
            Err(_) => return Err(malformed(format!("column {} is not UTF-8 text", i + 1))),
        }
    }
    check_unique(&names, path).map_err(|e| match e {
        CsvError::DuplicateColumn {
            path,
            name,
            first,
            second,
        } => CsvError::Malformed {
            path,
            line,
            message: format!(
                "column '{name}' appears twice in the header (fields {first} and {second}); rename one"
            ),
        },
        other => other,
    })?;
    Ok(CsvHeader { names, line })
}

/// Where a streamed row's time comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TimeBase {
    /// The column at this index, in seconds.
    Column(usize),
    /// Row k (from 0, bad rows included) is at k times this many seconds.
    Period(f64),
}

/// A streamed recording's columns, resolved once: rows are then read by
/// index, never by name.
#[derive(Debug, Clone, PartialEq)]
pub struct CsvLayout {
    pub names: Vec<String>,
    pub time: TimeBase,
    /// The header's line in the file.
    pub header_line: u64,
}

impl CsvLayout {
    /// The time base of a header: `time_column` when given (it must
    /// exist), else the first of [`DEFAULT_TIME_COLUMNS`]; `period_s` only
    /// when there is no time column, and then it is required.
    pub fn resolve(
        path: &Path,
        header: CsvHeader,
        time_column: Option<&str>,
        period_s: Option<f64>,
    ) -> Result<Self, CsvError> {
        let find = |name: &str| header.names.iter().position(|n| n == name);
        let column = match time_column {
            Some(name) => Some(find(name).ok_or_else(|| CsvError::MissingColumn {
                path: path.to_path_buf(),
                name: name.to_string(),
                role: "time",
                flag: "time_column",
                available: crate::io::name_list(&header.names),
            })?),
            None => DEFAULT_TIME_COLUMNS.iter().find_map(|t| find(t)),
        };
        let time = match (column, period_s) {
            (Some(i), None) => TimeBase::Column(i),
            (Some(i), Some(_)) => {
                return Err(CsvError::TimeAndPeriod {
                    path: path.to_path_buf(),
                    line: header.line,
                    column: crate::io::excerpt(&header.names[i]).into_owned(),
                });
            }
            (None, Some(p)) => TimeBase::Period(p),
            (None, None) => {
                return Err(CsvError::NoTime {
                    path: path.to_path_buf(),
                    line: header.line,
                    available: crate::io::name_list(&header.names),
                });
            }
        };
        Ok(CsvLayout {
            names: header.names,
            time,
            header_line: header.line,
        })
    }

    /// The index of column `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// The column names, comma-separated, for messages.
    pub fn available(&self) -> String {
        crate::io::name_list(&self.names)
    }

    /// The time column's index, if the time comes from one.
    pub fn time_index(&self) -> Option<usize> {
        match self.time {
            TimeBase::Column(i) => Some(i),
            TimeBase::Period(_) => None,
        }
    }

    /// Row `k` (from 0) of line `line` as values: the time, then every
    /// column in header order. Columns in `required` (and the time column)
    /// must hold finite numbers; any other cell that does not is NaN.
    pub fn decode(
        &self,
        record: &csv::ByteRecord,
        line: u64,
        k: u64,
        required: &[usize],
    ) -> Result<CsvRow, RowError> {
        if record.len() != self.names.len() {
            return Err(RowError {
                line,
                column: None,
                problem: format!(
                    "this line has {} fields but the header has {}",
                    record.len(),
                    self.names.len()
                ),
            });
        }
        let mut values = Vec::with_capacity(record.len());
        for (i, field) in record.iter().enumerate() {
            match parse_number(field) {
                Ok(v) => values.push(v),
                Err(problem) if required.contains(&i) || self.time_index() == Some(i) => {
                    return Err(RowError {
                        line,
                        column: Some((crate::io::excerpt(&self.names[i]).into_owned(), i + 1)),
                        problem,
                    });
                }
                Err(_) => values.push(f64::NAN),
            }
        }
        let time = match self.time {
            TimeBase::Column(i) => values[i],
            // Rounded to the nanosecond, as capture times are.
            TimeBase::Period(p) => (k as f64 * p * 1e9).round() / 1e9,
        };
        Ok(CsvRow {
            line,
            time,
            values: values.into_boxed_slice(),
            file: 0,
        })
    }
}

/// One row of a streamed recording.
#[derive(Debug, Clone, PartialEq)]
pub struct CsvRow {
    /// Its line in the file.
    pub line: u64,
    /// Seconds, on the recording's clock.
    pub time: f64,
    /// Every column in header order (the time column too); NaN where a
    /// cell of a column nobody reads is not a number.
    pub values: Box<[f64]>,
    /// Which file of its source it comes from (the place in the source's
    /// `files`; 0 for a source of one file): `values` follow that file's
    /// header.
    pub file: usize,
}

/// Why a row is skipped: its line, the column (name and 1-based field)
/// where there is one, and the problem.
#[derive(Debug, Clone, PartialEq)]
pub struct RowError {
    pub line: u64,
    pub column: Option<(String, usize)>,
    pub problem: String,
}

impl std::fmt::Display for RowError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.column {
            Some((name, field)) => write!(
                f,
                "line {}: column '{name}' (field {field}): {}",
                self.line, self.problem
            ),
            None => write!(f, "line {}: {}", self.line, self.problem),
        }
    }
}

/// The rows of a streamed recording after its header, in order: each a
/// row, or why it is skipped (a bad value in a column read, a wrong number
/// of fields, a line too long, a time not after the last good row's).
pub struct CsvRows<R> {
    pub(super) lines: CsvLines<R>,
    layout: CsvLayout,
    required: Vec<usize>,
    record: csv::ByteRecord,
    /// Data rows seen, bad ones included (the period's row number).
    k: u64,
    last: Option<(f64, u64)>,
}

/// A row whose time is not after the last good one's: its time, and the
/// previous time and its line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutOfOrder {
    pub time: f64,
    pub previous: f64,
    pub previous_line: u64,
}

impl<R: io::BufRead> CsvRows<R> {
    /// `lines` must be just past the header `layout` was resolved from.
    pub fn new(lines: CsvLines<R>, layout: CsvLayout, required: &[usize]) -> Self {
        CsvRows {
            lines,
            layout,
            required: required.to_vec(),
            record: csv::ByteRecord::new(),
            k: 0,
            last: None,
        }
    }

    pub fn layout(&self) -> &CsvLayout {
        &self.layout
    }

    /// Bytes read so far, the header included.
    pub fn bytes_read(&self) -> u64 {
        self.lines.bytes_read()
    }

    /// The next row, or why it is skipped (with, for a time out of order,
    /// the previous time and line); `None` at the end of the file.
    #[allow(clippy::type_complexity)]
    pub fn next_row(
        &mut self,
    ) -> io::Result<Option<Result<CsvRow, (RowError, Option<OutOfOrder>)>>> {
        let Some((line, split)) = self.lines.next_record(&mut self.record)? else {
            return Ok(None);
        };
        let k = self.k;
        self.k += 1;
        if let Err(problem) = split {
            return Ok(Some(Err((
                RowError {
                    line,
                    column: None,
                    problem,
                },
                None,
            ))));
        }
        let row = match self.layout.decode(&self.record, line, k, &self.required) {
            Ok(row) => row,
            Err(e) => return Ok(Some(Err((e, None)))),
        };
        if let Some((previous, previous_line)) = self.last
            && row.time <= previous
        {
            let column = self.layout.time_index().map(|i| {
                (
                    crate::io::excerpt(&self.layout.names[i]).into_owned(),
                    i + 1,
                )
            });
            return Ok(Some(Err((
                RowError {
                    line,
                    column,
                    problem: format!(
                        "time {} s is not after {previous} s on line {previous_line}",
                        row.time
                    ),
                },
                Some(OutOfOrder {
                    time: row.time,
                    previous,
                    previous_line,
                }),
            ))));
        }
        self.last = Some((row.time, line));
        Ok(Some(Ok(row)))
    }
}

/// Whether `path` holds a CSV recording rather than a capture: named
/// `.csv`, or its first 4 KiB are text whose first two lines (comments and
/// blank lines aside) are a header and a row with as many fields, some of
/// them numbers. Captures start with their magic, raw dumps with binary
/// frames, and prose with commas has no row of numbers.
pub fn looks_like_csv(path: &Path) -> bool {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
    {
        return true;
    }
    // A FIFO or a device is not a recording (and must not block here).
    let Ok(file) = open_regular(path) else {
        return false;
    };
    let mut head = Vec::new();
    if file.take(4096).read_to_end(&mut head).is_err() {
        return false;
    }
    let text = |line: &[u8]| {
        line.iter()
            .all(|&b| b == b'\t' || b == b'\r' || (0x20..0x7f).contains(&b))
    };
    let mut lines = head
        .split(|&b| b == b'\n')
        .map(<[u8]>::trim_ascii)
        .filter(|l| !l.is_empty() && !l.starts_with(b"#"));
    let (Some(header), Some(row)) = (lines.next(), lines.next()) else {
        return false;
    };
    let fields = |line: &[u8]| line.iter().filter(|&&b| b == b',').count() + 1;
    text(header)
        && text(row)
        && fields(header) >= 2
        && fields(header) == fields(row)
        && row
            .split(|&b| b == b',')
            .any(|f| parse_number(f.trim_ascii()).is_ok())
}

/// What a pass over a streamed recording found.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CsvScan {
    /// Good rows.
    pub rows: u64,
    /// Rows skipped (bad values, wrong field counts, lines too long).
    pub bad: u64,
    /// Times of the first and last good rows.
    pub first_time: Option<f64>,
    pub last_time: Option<f64>,
}

/// Opens a streamed recording: its header, resolved (see
/// [`CsvLayout::resolve`]), and the reader of its rows. The path must be a
/// regular file.
pub fn open_rows(
    path: &Path,
    time_column: Option<&str>,
    period_s: Option<f64>,
    required: &[usize],
) -> Result<CsvRows<io::BufReader<File>>, CsvError> {
    let file = open_regular(path).map_err(|source| match not_regular_kind(&source) {
        Some(_) => CsvError::NotAFile {
            path: path.to_path_buf(),
        },
        None => CsvError::Io {
            path: path.to_path_buf(),
            source,
        },
    })?;
    let mut lines = CsvLines::new(io::BufReader::with_capacity(1 << 16, file));
    let header = read_header(&mut lines, path)?;
    let layout = CsvLayout::resolve(path, header, time_column, period_s)?;
    Ok(CsvRows::new(lines, layout, required))
}

/// Reads every row once, in bounded memory: counts the good and bad rows,
/// and refuses times that do not increase (naming both lines).
pub fn scan_rows<R: io::BufRead>(rows: &mut CsvRows<R>, path: &Path) -> Result<CsvScan, CsvError> {
    let mut scan = CsvScan::default();
    while let Some(next) = rows.next_row().map_err(|source| CsvError::Io {
        path: path.to_path_buf(),
        source,
    })? {
        match next {
            Ok(row) => {
                scan.rows += 1;
                scan.first_time.get_or_insert(row.time);
                scan.last_time = Some(row.time);
            }
            Err((e, Some(order))) => {
                return Err(CsvError::NotIncreasing {
                    path: path.to_path_buf(),
                    line: e.line,
                    column: e.column.map(|c| c.0).unwrap_or_default(),
                    time: order.time,
                    previous: order.previous,
                    previous_line: order.previous_line,
                });
            }
            Err(_) => scan.bad += 1,
        }
    }
    Ok(scan)
}
