//! The records of a recording after its header, as one `csv` reader reads
//! them, but faster on plain lines, and each on the line it starts on.
//!
//! A plain line is what a recorder writes: fields separated by commas, no
//! quote, no carriage return but one before its LF, and as many fields as
//! the header. Such a line is one record and its fields are the bytes
//! between its commas, so it is split here with a few SIMD scans
//! (`memchr`) instead of the csv crate's byte-at-a-time state machine, and
//! only as far as the last column read; the rest of its commas are only
//! counted. Blank lines and `#` comments are skipped here too. From the
//! first line that is not plain (or a line longer than the buffer, or a
//! last line with no newline) the csv crate reads the rest, from that
//! line's first byte: every record and every message is the one a single
//! `csv` reader gives from the header on.
//!
//! Lines are those of the file: the one a record starts on, counting
//! every LF before it. (The csv crate's own `position` is where its reader
//! stood before the blank lines, comments or the LF of a CRLF it skipped
//! first; its records are given the line they start on instead.)

use std::io::{self, Read};
use std::path::Path;

use super::{CsvError, READ_BYTES, csv_error, unequal_lengths};

/// Bytes held for plain lines: a line longer than this goes to the csv
/// crate.
const PLAIN_BYTES: usize = 4 * READ_BYTES;

/// What the csv crate reads first, before the bytes it is handed: one
/// record, on its line 1.
const PRIMER: &[u8] = b"-\n";

/// The line in the file of the csv crate's `line` (counted from its
/// [`PRIMER`]), after `lines_before` of the file.
fn in_file(line: u64, lines_before: u64) -> u64 {
    line.saturating_sub(1) + lines_before
}

/// A reader that keeps the last bytes read through it: those a csv reader
/// had buffered past the header, when the header is read through it (its
/// buffer reads only once it has used what it held, so the bytes it has
/// not used are all of its last read).
pub(super) struct Tap<R> {
    inner: R,
    /// Bytes read through it.
    pulled: u64,
    last: Vec<u8>,
}

impl<R> Tap<R> {
    pub(super) fn new(inner: R) -> Self {
        Tap {
            inner,
            pulled: 0,
            last: Vec::new(),
        }
    }
}

impl<R: Read> Read for Tap<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.pulled += n as u64;
        self.last.clear();
        self.last.extend_from_slice(&buf[..n]);
        Ok(n)
    }
}

/// Bytes held back, then a reader: what the csv crate reads once the
/// lines stop being plain. It keeps what it last handed out, so that the
/// byte a record ended on can be looked up ([`Held::ended_on_newline`]).
pub(super) struct Held<R> {
    held: Vec<u8>,
    at: usize,
    inner: R,
    /// Bytes handed out.
    pulled: u64,
    /// The last bytes handed out (a copy of the last read).
    last: Vec<u8>,
    /// Whether a read has given no bytes: the end.
    eof: bool,
}

impl<R> Held<R> {
    fn new(held: Vec<u8>, inner: R) -> Self {
        Held {
            held,
            at: 0,
            inner,
            pulled: 0,
            last: Vec::new(),
            eof: false,
        }
    }

    /// Whether a record that the csv crate read up to byte `end` (its
    /// position after it) ended on the newline it consumed: not at the end
    /// of the bytes (a last line with no newline, a quote left open), and
    /// not on a CR (whose LF, if any, the crate takes with what follows).
    /// The crate's buffered reader reads again only once it has used what
    /// it held, and gives a record back as soon as it has taken the byte
    /// that ends it, so that byte lies within the last read.
    fn ended_on_newline(&self, end: u64) -> bool {
        if self.eof && end == self.pulled {
            return false;
        }
        let first = self.pulled - self.last.len() as u64;
        debug_assert!(end > first, "record end {end}, last read from {first}");
        let byte = end
            .checked_sub(1 + first)
            .and_then(|at| usize::try_from(at).ok())
            .and_then(|at| self.last.get(at));
        byte == Some(&b'\n')
    }
}

impl<R: Read> Read for Held<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = if self.at < self.held.len() {
            let n = (self.held.len() - self.at).min(buf.len());
            buf[..n].copy_from_slice(&self.held[self.at..self.at + n]);
            self.at += n;
            n
        } else {
            self.inner.read(buf)?
        };
        if n == 0 {
            if !buf.is_empty() {
                self.eof = true;
            }
            return Ok(0);
        }
        self.last.clear();
        self.last.extend_from_slice(&buf[..n]);
        self.pulled += n as u64;
        Ok(n)
    }
}

/// The records of a file, read on from where a csv reader read its header.
pub(super) struct Records<'p, R> {
    /// Plain lines are read through it (while `plain` is some), and the
    /// rest by it.
    csv: csv::Reader<Held<R>>,
    plain: Option<Plain>,
    /// Lines of the file before the bytes the csv crate reads after its
    /// [`PRIMER`].
    lines_before: u64,
    /// Fields in every record (the header's).
    fields: usize,
    path: &'p Path,
}

/// Plain lines, split here.
struct Plain {
    buf: Vec<u8>,
    /// The first byte not yet read as a record.
    start: usize,
    /// Bytes held.
    end: usize,
    /// The first quote or carriage return held: no line is plain from the
    /// one that holds it.
    special: Option<usize>,
    eof: bool,
    /// The line the reader stands on (the next line's number).
    line: u64,
    /// Fields split out of each line; the others are only counted.
    split: usize,
    /// The last plain line split: where it starts in `buf`, its length
    /// without its newline, its number, and where its fields end in it.
    row: (usize, usize, u64),
    ends: Vec<usize>,
}

/// A record as [`Records::read_row`] gives it: a plain line's fields in
/// place, or what the csv crate read.
pub(super) enum Row<'a> {
    Plain {
        line: &'a [u8],
        /// Where each field split out ends in `line` (the next begins one
        /// byte after, past its comma).
        ends: &'a [usize],
        number: u64,
    },
    Record(&'a csv::ByteRecord),
}

impl Row<'_> {
    /// Field `i`, if the record holds it ([`Records::read`]'s record holds
    /// the same fields).
    pub(super) fn get(&self, i: usize) -> Option<&[u8]> {
        match self {
            Row::Plain { line, ends, .. } => {
                let end = *ends.get(i)?;
                let start = match i.checked_sub(1) {
                    Some(before) => ends[before] + 1,
                    None => 0,
                };
                line.get(start..end)
            }
            Row::Record(record) => record.get(i),
        }
    }

    /// The line the record starts on in the file.
    pub(super) fn line(&self) -> u64 {
        match self {
            Row::Plain { number, .. } => *number,
            Row::Record(record) => record.position().map_or(0, |p| p.line()),
        }
    }
}

/// Whether a plain line gave a record.
enum Next {
    Record,
    End,
    /// The csv crate reads on from here.
    NotPlain,
}

impl<'p, R: Read> Records<'p, R> {
    /// The records after the header `csv` has read (through a [`Tap`]),
    /// each of `fields` fields; `path` names the file in messages.
    pub(super) fn after_header(
        csv: csv::Reader<Tap<R>>,
        fields: usize,
        path: &'p Path,
    ) -> Result<Self, CsvError> {
        Records::after_header_holding(csv, fields, path, PLAIN_BYTES)
    }

    /// [`Records::after_header`] holding plain lines of up to `bytes`.
    fn after_header_holding(
        csv: csv::Reader<Tap<R>>,
        fields: usize,
        path: &'p Path,
        bytes: usize,
    ) -> Result<Self, CsvError> {
        let consumed = csv.position().byte();
        let line = csv.position().line();
        let tap = csv.into_inner();
        let last_from = tap.pulled - tap.last.len() as u64;
        let unread = consumed
            .checked_sub(last_from)
            .and_then(|at| usize::try_from(at).ok())
            .and_then(|at| tap.last.get(at..));
        let Some(unread) = unread else {
            // Not what a csv reader does; never a row lost for it.
            return Err(CsvError::Io {
                path: path.to_path_buf(),
                source: io::Error::other(format!(
                    "the header's reader stopped at byte {consumed}, outside its last read \
                     (bytes {last_from} to {}); please report this",
                    tap.pulled
                )),
            });
        };
        let mut buf = vec![0; bytes.max(unread.len())];
        buf[..unread.len()].copy_from_slice(unread);
        let plain = Plain {
            end: unread.len(),
            buf,
            start: 0,
            special: memchr::memchr2(b'"', b'\r', unread),
            eof: false,
            line,
            split: fields,
            row: (0, 0, 0),
            ends: Vec::new(),
        };
        Ok(Records::new(tap.inner, plain, fields, path))
    }

    /// The records of `reader` from its first byte (no header), each of
    /// `fields` fields, of which the first `split` are read.
    pub(super) fn headerless(reader: R, fields: usize, split: usize, path: &'p Path) -> Self {
        let plain = Plain {
            buf: vec![0; PLAIN_BYTES],
            start: 0,
            end: 0,
            special: None,
            eof: false,
            line: 1,
            split: split.min(fields),
            row: (0, 0, 0),
            ends: Vec::new(),
        };
        Records::new(reader, plain, fields, path)
    }

    fn new(reader: R, plain: Plain, fields: usize, path: &'p Path) -> Self {
        let held = Held::new(PRIMER.to_vec(), reader);
        let mut csv = csv::ReaderBuilder::new()
            .has_headers(false)
            // Lengths are checked against the header's, as the reader
            // of the header checks them.
            .flexible(true)
            .comment(Some(b'#'))
            .buffer_capacity(READ_BYTES)
            .from_reader(held);
        // A csv reader strips a byte-order mark from the start of its
        // first read, which the one reader of a file does only before its
        // header: the primer is that first read, read here and dropped
        // (a record of its own, which the reader's lines count).
        let _ = csv.read_byte_record(&mut csv::ByteRecord::new());
        Records {
            csv,
            plain: Some(plain),
            lines_before: 0,
            fields,
            path,
        }
    }

    /// Only the first `split` fields of a plain line are read from now on:
    /// a record read then holds only those (the others are checked to be
    /// there).
    pub(super) fn split_first(&mut self, split: usize) {
        if let Some(plain) = &mut self.plain {
            plain.split = split.min(self.fields);
        }
    }

    /// The next record into `record`, its position the line it starts on
    /// in the file; `false` past the last. Its fields are
    /// the header's number (checked), or, of a plain line, the first
    /// [`Records::split_first`] of them.
    pub(super) fn read(&mut self, record: &mut csv::ByteRecord) -> Result<bool, CsvError> {
        match self.next_plain()? {
            Next::Record => {
                let row = self.plain_row()?;
                record.clear();
                (0..)
                    .map_while(|i| row.get(i))
                    .for_each(|field| record.push_field(field));
                set_line(record, row.line());
                Ok(true)
            }
            Next::End => Ok(false),
            Next::NotPlain => self.read_by_csv(record),
        }
    }

    /// [`Records::read`], a plain line's fields given in place (not
    /// copied into `record`, which holds the csv crate's records).
    pub(super) fn read_row<'s>(
        &'s mut self,
        record: &'s mut csv::ByteRecord,
    ) -> Result<Option<Row<'s>>, CsvError> {
        match self.next_plain()? {
            Next::Record => self.plain_row().map(Some),
            Next::End => Ok(None),
            Next::NotPlain => Ok(self.read_by_csv(record)?.then_some(Row::Record(record))),
        }
    }

    /// The next plain line split (`Record`), the end, or (`NotPlain`) the
    /// csv crate to read the next record: from the first line that is not
    /// plain, whose bytes it is handed, on.
    fn next_plain(&mut self) -> Result<Next, CsvError> {
        let Some(plain) = &mut self.plain else {
            return Ok(Next::NotPlain);
        };
        let reader = &mut self.csv.get_mut().inner;
        let next = plain
            .next(reader, self.fields)
            .map_err(|source| CsvError::Io {
                path: self.path.to_path_buf(),
                source,
            })?;
        if let Next::NotPlain = next {
            // The csv crate reads on from the line's first byte.
            let held = self.csv.get_mut();
            held.held = plain.buf[plain.start..plain.end].to_vec();
            held.at = 0;
            self.lines_before = plain.line - 1;
            self.plain = None;
        }
        Ok(next)
    }

    /// The plain line last split, in place.
    fn plain_row(&self) -> Result<Row<'_>, CsvError> {
        let row = self.plain.as_ref().and_then(|plain| {
            let (start, length, number) = plain.row;
            Some(Row::Plain {
                line: plain.buf.get(start..start + length)?,
                ends: &plain.ends,
                number,
            })
        });
        row.ok_or_else(|| CsvError::Io {
            path: self.path.to_path_buf(),
            source: io::Error::other("a plain line was split but not held; please report this"),
        })
    }

    /// The next record by the csv crate, its position the line it starts
    /// on in the file; `false` past the last.
    fn read_by_csv(&mut self, record: &mut csv::ByteRecord) -> Result<bool, CsvError> {
        let lines_before = self.lines_before;
        let more = (self.csv)
            .read_byte_record(record)
            .map_err(|e| csv_error(self.path, e).relined(|line| in_file(line, lines_before)))?;
        if !more {
            return Ok(false);
        }
        // The line the record starts on: the crate's `position` is where
        // it stood before the blank lines, comments or the LF of a CRLF it
        // skipped first, so the line is counted back from where the record
        // ended, past the newlines within its fields and the one it ended
        // on.
        let end = self.csv.position();
        let within = record.as_slice().iter().filter(|&&b| b == b'\n').count() as u64;
        let ended_on = u64::from(self.csv.get_ref().ended_on_newline(end.byte()));
        let line = in_file(end.line().saturating_sub(within + ended_on), lines_before);
        set_line(record, line);
        if record.len() != self.fields {
            return Err(CsvError::Malformed {
                path: self.path.to_path_buf(),
                line,
                message: unequal_lengths(record.len(), self.fields),
            });
        }
        Ok(true)
    }

    /// The line the reader stands on: one past the LFs it has read.
    pub(super) fn line(&self) -> u64 {
        match &self.plain {
            Some(plain) => plain.line,
            None => in_file(self.csv.position().line(), self.lines_before),
        }
    }

    pub(super) fn get_ref(&self) -> &R {
        &self.csv.get_ref().inner
    }

    pub(super) fn get_mut(&mut self) -> &mut R {
        &mut self.csv.get_mut().inner
    }
}

impl Plain {
    /// The next plain line of `reader` as a record of `fields` fields.
    fn next(&mut self, reader: &mut impl Read, fields: usize) -> io::Result<Next> {
        loop {
            let held = &self.buf[self.start..self.end];
            if let Some(length) = memchr::memchr(b'\n', held) {
                // The line without its LF, or the CRLF that ends it.
                let line = held[..length]
                    .strip_suffix(b"\r")
                    .unwrap_or(&held[..length]);
                // A comment runs to its LF, whatever it holds.
                let comment = line.first() == Some(&b'#');
                if !comment && self.special.is_some_and(|at| at < self.start + line.len()) {
                    return Ok(Next::NotPlain);
                }
                if !line.is_empty() && !comment {
                    if !split_line(line, self.split, fields, &mut self.ends) {
                        return Ok(Next::NotPlain);
                    }
                    self.row = (self.start, line.len(), self.line);
                }
                self.start += length + 1;
                self.line += 1;
                if self.special.is_some_and(|at| at < self.start) {
                    let rest = &self.buf[self.start..self.end];
                    self.special = memchr::memchr2(b'"', b'\r', rest).map(|at| self.start + at);
                }
                if line.is_empty() || comment {
                    // Blank lines and comments are no records.
                    continue;
                }
                return Ok(Next::Record);
            }
            if self.eof {
                // A last line with no newline is the crate's to read.
                return Ok(match held.is_empty() {
                    true => Next::End,
                    false => Next::NotPlain,
                });
            }
            if self.start > 0 {
                self.buf.copy_within(self.start..self.end, 0);
                self.end -= self.start;
                self.special = self.special.map(|at| at - self.start);
                self.start = 0;
            }
            if self.end == self.buf.len() {
                // A line longer than the buffer.
                return Ok(Next::NotPlain);
            }
            let n = reader.read(&mut self.buf[self.end..])?;
            let read = &self.buf[self.end..self.end + n];
            if self.special.is_none() {
                self.special = memchr::memchr2(b'"', b'\r', read).map(|at| self.end + at);
            }
            self.end += n;
            self.eof = n == 0;
        }
    }
}

/// Where `line`'s first `split` fields end, into `ends` (the rest of its
/// `fields` only counted); `false` (and the line left to be read again)
/// when it has another number of fields.
fn split_line(line: &[u8], split: usize, fields: usize, ends: &mut Vec<usize>) -> bool {
    ends.clear();
    let mut commas = memchr::memchr_iter(b',', line);
    while ends.len() + 1 < split {
        let Some(comma) = commas.next() else {
            return false;
        };
        ends.push(comma);
    }
    // The field `split` ends at the next comma, or the line's end.
    let from = ends.last().map_or(0, |&end| end + 1);
    let (end, more) = match memchr::memchr(b',', &line[from..]) {
        Some(comma) => (from + comma, 1 + count_commas(&line[from + comma + 1..])),
        None => (line.len(), 0),
    };
    ends.push(end);
    ends.len() + more == fields
}

/// Commas in `bytes`: counted 32 bytes at a time into one byte each,
/// which the compiler does in a few vector instructions.
fn count_commas(bytes: &[u8]) -> usize {
    let mut chunks = bytes.chunks_exact(32);
    let mut count = 0;
    for chunk in &mut chunks {
        let mut in_chunk = 0u8;
        for &b in chunk {
            in_chunk += u8::from(b == b',');
        }
        count += usize::from(in_chunk);
    }
    count + chunks.remainder().iter().filter(|&&b| b == b',').count()
}

/// Sets the line a record starts on.
fn set_line(record: &mut csv::ByteRecord, line: u64) {
    let mut position = csv::Position::new();
    position.set_line(line);
    record.set_position(Some(position));
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::super::open_with_header;
    use super::*;

    /// A reader handing out at most a few bytes at a time.
    struct Trickle<'a> {
        bytes: &'a [u8],
        sizes: Vec<usize>,
        read: usize,
    }

    impl Read for Trickle<'_> {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            let size = self.sizes[self.read % self.sizes.len()];
            self.read += 1;
            let n = size.min(buf.len()).min(self.bytes.len());
            buf[..n].copy_from_slice(&self.bytes[..n]);
            self.bytes = &self.bytes[n..];
            Ok(n)
        }
    }

    /// The line of `text` each record starts on, the header's first: the
    /// records as csv-core splits them (a CR, an LF or a CRLF ends one
    /// outside quotes; blank lines, and lines that start with `#`, up to
    /// their LF, are none (but the last with no LF is one); a field that starts with a quote runs to
    /// the quote that closes it, a doubled quote within it), written
    /// here byte by byte and counting every LF before it.
    fn record_lines(text: &[u8]) -> Vec<u64> {
        // (A byte-order mark at the start is no part of a record.)
        let text = text.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(text);
        let (mut lines, mut line, mut i) = (Vec::new(), 1, 0);
        let n = text.len();
        while i < n {
            match text[i] {
                b'\n' => line += 1,
                b'\r' => {}
                b'#' => {
                    while i + 1 < n && text[i + 1] != b'\n' {
                        i += 1;
                    }
                    if i + 1 == n {
                        // csv-core reads a last comment with no LF as a
                        // record of one empty field.
                        lines.push(line);
                    }
                }
                _ => {
                    lines.push(line);
                    let (mut quoted, mut field_start) = (false, true);
                    while i < n {
                        match (quoted, text[i]) {
                            (true, b'"') if text.get(i + 1) == Some(&b'"') => i += 1,
                            (true, b'"') => quoted = false,
                            (true, b'\n') => line += 1,
                            (true, _) => {}
                            (false, b'"') if field_start => quoted = true,
                            (false, b'\r' | b'\n') => break,
                            (false, b',') => {
                                field_start = true;
                                i += 1;
                                continue;
                            }
                            (false, _) => {}
                        }
                        field_start = false;
                        i += 1;
                    }
                    continue;
                }
            }
            i += 1;
        }
        lines
    }

    /// Each record's line and first `split` fields, then the line the
    /// reader stands on at the end, or the message it stops with: as one
    /// csv reader reads `text` after its header (lengths checked against
    /// it), the way the recording readers read before plain lines, with
    /// the line each record truly starts on ([`record_lines`]).
    fn by_the_crate(text: &[u8], split: usize) -> Vec<String> {
        let path = Path::new("rec.csv");
        let (mut csv, names) = match open_with_header(text, path) {
            Ok(opened) => opened,
            Err(e) => return vec![e.to_string()],
        };
        let lines = record_lines(text);
        let mut out = vec![format!("{} fields", names.len())];
        let mut record = csv::ByteRecord::new();
        for k in 1.. {
            let line = lines.get(k).copied().unwrap_or(0);
            match csv.read_byte_record(&mut record) {
                Ok(true) => {
                    set_line(&mut record, line);
                    out.push(shown(&record, split.min(names.len())));
                }
                Ok(false) => break,
                Err(e) => {
                    // (A ragged line's message, on the line it is on.)
                    out.push(csv_error(path, e).relined(|_| line).to_string());
                    return out;
                }
            }
        }
        out.push(format!("end on line {}", csv.position().line()));
        out
    }

    /// [`by_the_crate`] by [`Records`], fed by `sizes` bytes at a time and
    /// holding plain lines of up to `holding` bytes; after the first
    /// record, by [`Records::read_row`] when `rows` (as the columns are
    /// read), else by [`Records::read`].
    fn by_records(
        text: &[u8],
        split: usize,
        sizes: Vec<usize>,
        holding: usize,
        rows: bool,
    ) -> Vec<String> {
        let path = Path::new("rec.csv");
        let reader = Trickle {
            bytes: text,
            sizes,
            read: 0,
        };
        let (csv, names) = match open_with_header(Tap::new(reader), path) {
            Ok(opened) => opened,
            Err(e) => return vec![e.to_string()],
        };
        let fields = names.len();
        let mut out = vec![format!("{fields} fields")];
        let mut records = match Records::after_header_holding(csv, fields, path, holding) {
            Ok(records) => records,
            Err(e) => return vec![e.to_string()],
        };
        let mut record = csv::ByteRecord::new();
        let mut first = true;
        let split = split.min(fields);
        loop {
            let next = if rows && !first {
                let row = records.read_row(&mut record);
                row.map(|row| row.map(|row| shown_row(&row, split)))
            } else {
                let more = records.read(&mut record);
                more.map(|more| {
                    more.then(|| {
                        // A plain line holds the fields split, or (the
                        // first, all read) every field; the crate's hold
                        // every one.
                        assert!(
                            record.len() == fields || (!first && record.len() == split),
                            "{} fields of {fields}, split at {split}",
                            record.len()
                        );
                        shown(&record, split)
                    })
                })
            };
            match next {
                Ok(Some(shown)) => {
                    out.push(shown);
                    if first {
                        records.split_first(split);
                        first = false;
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    out.push(e.to_string());
                    return out;
                }
            }
        }
        out.push(format!("end on line {}", records.line()));
        out
    }

    fn shown(record: &csv::ByteRecord, split: usize) -> String {
        let line = record.position().map_or(0, |p| p.line());
        let fields: Vec<_> = record
            .iter()
            .take(split)
            .map(String::from_utf8_lossy)
            .collect();
        format!("line {line}: {fields:?}")
    }

    /// A row's first `split` fields (all it holds, if fewer) and its line,
    /// as [`shown`] shows a record.
    fn shown_row(row: &Row<'_>, split: usize) -> String {
        let fields: Vec<_> = (0..split)
            .map_while(|i| row.get(i))
            .map(String::from_utf8_lossy)
            .collect();
        format!("line {}: {fields:?}", row.line())
    }

    /// The same by both, fed whole and a few bytes at a time, holding
    /// plain lines of any length and of a few bytes, read as records and
    /// as rows.
    fn same_by_both(text: &[u8], split: usize) {
        let want = by_the_crate(text, split);
        for (sizes, holding) in [
            (vec![READ_BYTES], PLAIN_BYTES),
            (vec![1, 3, 7, 2], PLAIN_BYTES),
            (vec![5, 64, 1], 12),
        ] {
            for rows in [false, true] {
                let got = by_records(text, split, sizes.clone(), holding, rows);
                assert_eq!(
                    got,
                    want,
                    "{:?} split at {split}, {sizes:?} bytes at a time, {holding} held, rows {rows}",
                    String::from_utf8_lossy(text)
                );
            }
        }
    }

    #[test]
    fn plain_lines_are_the_records_the_crate_reads() {
        let text = b"t,x,y,label\n0,1.5,-2,a\n1,2.5,-3,b\n2,3.5,-4,c\n";
        for split in 1..=4 {
            same_by_both(text, split);
        }
        // The records and the line the reader ends on; the first record
        // holds every field, the others those split.
        let got = by_records(text, 2, vec![READ_BYTES], PLAIN_BYTES, true);
        assert_eq!(
            got,
            [
                "4 fields",
                "line 2: [\"0\", \"1.5\"]",
                "line 3: [\"1\", \"2.5\"]",
                "line 4: [\"2\", \"3.5\"]",
                "end on line 5",
            ]
        );
    }

    #[test]
    fn from_a_line_that_is_not_plain_the_crate_reads_on() {
        for text in [
            // CRLF (the crate numbers a record from before the LF it skips).
            &b"t,x,y\r\n0,1,2\r\n1,2,3\r\n"[..],
            b"t,x,y\r\n0,1,2\r\n\r\n1,2,3\r\n",
            b"t,x,y\r\n0,1,2\r\n\"1\",2,3\r\n2,3,4\r\n3,4\r\n",
            b"t,x,y\n0,1,2\n1,2,3\r\n2,3,4\n",
            // A lone CR ends a record too.
            b"t,x,y\n0,1,2\n1,2,3\r2,3,4\n3,4,5\n",
            // Comments and blank lines, before a plain line, a quoted
            // one and one of too few fields.
            b"t,x,y\n0,1,2\n# a note\n\n1,2,3\n\n",
            b"t,x,y\n0,1,2\n\n# a \"note\"\n1,2,3\n\"2\",3,4\n\n# n\n3,4,5\n\n4,5\n",
            b"t,x,y\n0,1,2\n# a\rnote\n1,2,3\n",
            b"t,x,y\n0,1,\"2\n\n\"\n\n1,2,3\n\n2,3\n",
            // A quote left open to the end, its last byte an LF.
            b"t,x,y\n0,1,2\n1,2,\"3\n",
            b"t,x,y\r\n0,1,2\r\n\r\n1,2,\"3\r\n",
            // A blank line where a record has one field.
            b"t\n1\n\n2\n",
            // A last comment with no LF (a record of one empty field to
            // the crate).
            b"t,x,y\n0,1,2\n# last",
            b"t,x,y,n\r# n,o,t,e",
            // A comment with the header's fields.
            b"t,x,y\n0,1,2\n# a,b,c\n1,2,3\n",
            b"# before\nt,x,y\n0,1,2\n1,2,3\n",
            // A newline in quotes; a quote in a field.
            b"t,x,y,n\n0,1,2,\"a\nb\"\n1,2,3,c\n",
            b"t,x,y\n0,1,2\n1,2\"x,3\n2,3,4\n",
            // Too few or too many fields, first or later.
            b"t,x,y\n0,1\n1,2,3\n",
            b"t,x,y\n0,1,2\n1,2,3,4\n2,3,4\n",
            b"t,x,y\n0,1,2\n1,,\n",
            // No newline at the end; nothing after the header.
            b"t,x,y\n0,1,2\n1,2,3",
            b"t,x,y\n",
            b"t,x,y",
            // A byte-order mark; one after a newline stays in its field,
            // on a plain line and on the first line that is not plain
            // (which a new csv reader would strip).
            b"\xEF\xBB\xBFt,x,y\n0,1,2\n",
            b"t,x,y\n0,1,2\n\xEF\xBB\xBF1,2,3\n",
            b"t,x,y\n\xEF\xBB\xBF1,2,3",
            b"t,x,y\n\xEF\xBB\xBF1,2,3\r\n",
            b"t,x,y\n\xEF\xBB\xBF\n0,1,2\n",
            b"t,x,y\n\xEF\xBB\xBF# n\n0,1,2\n",
            b"t,x,y\r\n\xEF\xBB\xBF1,2,3\r\n",
            // Bytes that are no UTF-8, and spaces, stay as they are.
            b"t,x,y\n0, 1 ,\xFF\n",
            // A line longer than the few bytes held.
            b"t,x,y\n0,1,2\n1,2222222222222222222222,3\n2,3,4\n",
        ] {
            for split in 1..=4 {
                same_by_both(text, split);
            }
        }
    }

    #[test]
    fn commas_are_counted_in_every_position_of_a_chunk() {
        for at in 0..100 {
            let mut one = vec![b'7'; 100];
            one[at] = b',';
            assert_eq!(count_commas(&one), 1, "at {at}");
            assert_eq!(count_commas(&one[at + 1..]), 0, "after {at}");
            let upto: Vec<u8> = (0..100)
                .map(|i| if i <= at { b',' } else { b'7' })
                .collect();
            assert_eq!(count_commas(&upto), at + 1, "up to {at}");
            assert_eq!(count_commas(&upto[..=at]), at + 1, "the first {at}");
        }
        // More than a byte can count in a chunk: 255 chunks of commas.
        assert_eq!(count_commas(&vec![b','; 32 * 300 + 5]), 32 * 300 + 5);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        #[test]
        fn any_text_reads_as_the_crate_reads_it(
            lines in prop::collection::vec((0u8..16, 0u32..1000), 0..16),
            split in 1usize..5,
            end in 0u8..3,
        ) {
            let mut text = b"t,x,y,n".to_vec();
            text.extend_from_slice(match end { 0 => &b"\n"[..], 1 => b"\r\n", _ => b"\r" });
            for (kind, v) in &lines {
                let line = match kind {
                    0 => format!("{v},1.{v},-{v},ok\r\n"),
                    1 => "# n,o,t,e\n".to_string(),
                    2 => "\n".to_string(),
                    3 => format!("{v},{v}\n"),
                    4 => format!("{v},\"{v}\",1,\"a\nb\"\n"),
                    5 => format!("{v},?,1,\n"),
                    6 => format!("{v},1,2,3,4\n"),
                    7 => format!("{v},{}\n", "9".repeat(*v as usize % 40)),
                    8 => format!("{v}, {v} ,{v}\t,x\r"),
                    9 => format!("\u{feff}{v},{v},{v},b\n"),
                    10 => format!("\u{feff}# {v}\n"),
                    11 => format!("{v},{v}\r{v},{v}\n"),
                    12 => "\r\n".to_string(),
                    13 => format!("# \"{v}\r\"\r\n"),
                    _ => format!("{v},{v}.5,{},n{v}\n", -f64::from(*v)),
                };
                text.extend_from_slice(line.as_bytes());
            }
            if end == 2 {
                // No newline at the end.
                text.pop();
            }
            same_by_both(&text, split);
        }
    }
}
