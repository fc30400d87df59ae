//! The rows of a recording read into columns: on the calling thread, and
//! the rest of a large file on another core ([`super::halves`]).

use std::path::Path;

use super::records::{Records, Row};
use super::{
    Back, CsvError, Front, Positional, Role, RowsRead, WATCHED_ROWS, cell, first_record,
    rows_expected,
};
use crate::sample::Covariate;

/// The values read, column by column.
pub(super) struct Columns {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub t: Option<Vec<f64>>,
    pub covariates: Vec<Covariate>,
}

impl Columns {
    /// No values yet, in columns shaped as `self`'s.
    fn empty_like(&self) -> Columns {
        let covariates = self.covariates.iter().map(|c| Covariate {
            name: c.name.clone(),
            values: Vec::new(),
        });
        Columns {
            x: Vec::new(),
            y: Vec::new(),
            t: self.t.as_ref().map(|_| Vec::new()),
            covariates: covariates.collect(),
        }
    }

    /// Room for `rows` more, as a hint: a file whose first row misleads
    /// grows.
    fn reserve(&mut self, rows: usize) {
        let covariates = self.covariates.iter_mut().map(|c| &mut c.values);
        for column in [&mut self.x, &mut self.y]
            .into_iter()
            .chain(self.t.as_mut())
            .chain(covariates)
        {
            let _ = column.try_reserve_exact(rows);
        }
    }

    /// The values of `row` in the columns `read`.
    fn push(
        &mut self,
        row: &Row<'_>,
        read: &[(usize, Role)],
        reader: &Reader<'_>,
    ) -> Result<(), CsvError> {
        let line = row.line();
        for &(i, role) in read {
            let value = cell(row.get(i), i, reader.names, reader.path, line)?;
            match role {
                Role::X => self.x.push(value),
                Role::Y => self.y.push(value),
                Role::T => {
                    if let Some(t) = self.t.as_mut() {
                        t.push(value)
                    }
                }
                Role::Covariate(k) => self.covariates[k].values.push(value),
                Role::Ignored => {}
            }
        }
        Ok(())
    }

    /// `rest`'s values after these.
    fn append(&mut self, mut rest: Columns) {
        self.x.append(&mut rest.x);
        self.y.append(&mut rest.y);
        if let (Some(t), Some(rest)) = (self.t.as_mut(), rest.t.as_mut()) {
            t.append(rest);
        }
        for (mine, theirs) in self.covariates.iter_mut().zip(&mut rest.covariates) {
            mine.values.append(&mut theirs.values);
        }
    }

    /// Shows `watch` the rows from `from`, a block at a time.
    fn show(&self, from: usize, watch: &mut dyn FnMut(RowsRead<'_>)) {
        let mut shown = from;
        while shown < self.x.len() {
            let to = (shown + WATCHED_ROWS).min(self.x.len());
            watch(RowsRead {
                from: shown,
                x: &self.x[..to],
                y: &self.y[..to],
                covariates: &self.covariates,
            });
            shown = to;
        }
    }
}

/// What reading a file's rows needs to know of it.
pub(super) struct Reader<'a> {
    pub names: &'a [String],
    pub path: &'a Path,
    /// Its bytes (0 when unknown).
    pub size: u64,
}

impl Reader<'_> {
    /// The rows of `csv`, showing `watch` a block at a time as they are
    /// read; from the first row, the rest of the file is handed to another
    /// core when it can be (see [`super::halves`]), its rows joined after these.
    pub(super) fn read_front<'a: 's, 's>(
        &self,
        records: &mut Records<'_, Front<'a>>,
        scope: &'s std::thread::Scope<'s, '_>,
        mut roles: Vec<Role>,
        timed: bool,
        watch: &mut dyn FnMut(RowsRead<'_>),
    ) -> Result<Columns, CsvError> {
        let mut columns = Columns {
            x: Vec::new(),
            y: Vec::new(),
            t: timed.then(Vec::new),
            covariates: Vec::new(),
        };
        let mut record = csv::ByteRecord::new();
        let mut shown = 0;
        // The first record whole: its fields tell which columns are read.
        if records.read(&mut record)? {
            // The columns read, in the order of the record's fields.
            let read = first_record(&record, &mut roles, self.names, &mut columns.covariates);
            records.split_first(split_for(&read));
            columns.reserve(rows_expected(self.size, &record, read.len()));
            self.hand_over(records.get_mut(), scope, &read, &columns, &record);
            columns.push(&Row::Record(&record), &read, self)?;
            loop {
                if columns.x.len() - shown == WATCHED_ROWS {
                    columns.show(shown, watch);
                    shown = columns.x.len();
                }
                let Some(row) = records.read_row(&mut record)? else {
                    break;
                };
                columns.push(&row, &read, self)?;
            }
        }
        // The other core's rows, after these. Its lines are counted from
        // the cut (its first line is line 1), which follows this half's
        // lines, all read.
        if let Some(back) = records.get_mut().take_back() {
            let lines_before = records.line().saturating_sub(1);
            columns.append(back.rows.map_err(|error| error.moved_down(lines_before))?);
        }
        columns.show(shown, watch);
        Ok(columns)
    }

    /// Hands the rest of the file (if it has a cut) to another core, which
    /// reads the columns `read` into columns shaped as `columns`.
    fn hand_over<'a: 's, 's>(
        &self,
        front: &mut Front<'a>,
        scope: &'s std::thread::Scope<'s, '_>,
        read: &[(usize, Role)],
        columns: &Columns,
        first: &csv::ByteRecord,
    ) {
        let mut rest = columns.empty_like();
        let read = read.to_vec();
        let names = self.names.to_vec();
        let path = self.path.to_path_buf();
        let size = self.size;
        let row = first.clone();
        front.hand_over(scope, move |bytes| {
            let reader = Reader {
                names: &names,
                path: &path,
                size,
            };
            rest.reserve(rows_expected(
                size.saturating_sub(bytes.position()),
                &row,
                read.len(),
            ));
            let fields = names.len();
            let mut records = Records::headerless(bytes, fields, split_for(&read), &path);
            let rows = reader.read_rest(&mut records, &read, rest);
            Back {
                rows,
                quoted: records.get_ref().quoted(),
            }
        });
    }

    /// The rows of the rest of a file (no header), into `columns`.
    fn read_rest(
        &self,
        records: &mut Records<'_, Positional<'_>>,
        read: &[(usize, Role)],
        mut columns: Columns,
    ) -> Result<Columns, CsvError> {
        let mut record = csv::ByteRecord::new();
        // Records check their lengths against the header's.
        while let Some(row) = records.read_row(&mut record)? {
            columns.push(&row, read, self)?;
        }
        Ok(columns)
    }
}

/// The fields a plain line is split into for the columns `read`: up to
/// the last of them.
fn split_for(read: &[(usize, Role)]) -> usize {
    read.iter().map(|&(i, _)| i + 1).max().unwrap_or(1)
}

impl CsvError {
    /// The error with its line moved down by `lines` (found in a part of
    /// a file that begins after that many lines).
    pub(super) fn moved_down(self, lines: u64) -> CsvError {
        self.relined(|line| line + lines)
    }

    /// The error with its line (if it names one) `to` of what it was.
    pub(super) fn relined(mut self, to: impl FnOnce(u64) -> u64) -> CsvError {
        if let CsvError::Malformed { line, .. } | CsvError::BadValue { line, .. } = &mut self {
            *line = to(*line);
        }
        self
    }
}
