//! The capture file format: raw bytes exactly as they came off the wire,
//! each chunk stamped with its receive time, so that a replay reproduces the
//! timing and any garbage.
//!
//! One capture records one source. A source has one or more byte streams,
//! numbered by a `u8` id: stream 0 for a Falcon-GX serial line; for an I2C
//! bridge one stream per polled chip, each chunk the data bytes of one poll.
//! `docs/capture-format.md` is the full specification, written for someone
//! implementing a reader in another language; this is its summary.
//!
//! # Layout (all integers little-endian, offsets 0-based)
//!
//! ```text
//! offset  size  field
//! 0       16    magic: the ASCII bytes "FIELDCAL-CAPTURE"      (MAGIC)
//! 16      4     header length H, u32, at most 1 MiB             (MAX_HEADER_LEN)
//! 20      H     header: one UTF-8 JSON object                   (CaptureHeader)
//! 20+H    ...   records, one after another, to the end of the file
//!
//! record:
//! 0       8     time since the start, u64 nanoseconds
//! 8       1     stream id, u8 (declared in the header)
//! 9       4     data length L, u32
//! 13      L     data: the bytes exactly as received
//! 13+L    4     CRC-32 (zlib / ISO-HDLC) of bytes 0 .. 13+L of the record
//! ```
//!
//! The header, serialised from [`CaptureHeader`] (absent options omitted):
//!
//! ```json
//! {"version":1,
//!  "streams":[{"id":0,"kind":"falcon"},
//!             {"id":1,"kind":"chip","chip":"mpu6050","address":104}],
//!  "port":"/dev/ttyUSB0","baud":38400,
//!  "started_unix":1700000000.25,"nominal_period_s":0.05,"note":"bench"}
//! ```
//!
//! Record time 0 is the instant `started_unix` (seconds since the Unix
//! epoch); `fieldcal record` reads it just before it opens the device, and
//! each record's time is the monotonic interval since. Records come in
//! the order they were written, which is not necessarily sorted by time
//! across streams.
//!
//! # Reading rules
//!
//! - A file that does not start with [`MAGIC`] is a plain raw dump
//!   ([`CaptureFile::Raw`]); the caller decides whether it holds frames. An
//!   empty file, a file cut inside the magic or the header, a damaged header
//!   (length, JSON, fields), an unknown version, or an intact record of a
//!   stream the header does not declare, are [`CaptureError`]s.
//! - Reading stops at the first record that is not intact: one that runs
//!   past the end of the file (a torn tail: the recorder was killed, the
//!   disk filled up) or one whose CRC does not match (damaged bytes: a power
//!   cut can leave zeros at the end of a file). The chunks before it are
//!   returned with a [`Truncation`] saying where and why; a replay plays
//!   them and then warns. There is no resynchronisation after a damaged
//!   record: everything from it to the end of the file is dropped.
//! - Every length read from the file is checked against the bytes left
//!   before anything is sliced or allocated; no input makes the reader panic.
//!
//! # Writing
//!
//! [`CaptureWriter`] writes the magic and header in [`CaptureWriter::new`]
//! (and flushes them), then one record per [`CaptureWriter::write_chunk`],
//! each in a single `write_all`. Put a `BufWriter` under it and call
//! [`CaptureWriter::flush`] periodically: a recorder killed at any byte
//! leaves a file whose flushed records all read back, followed at most by a
//! torn tail the reader reports. After any write error the writer refuses
//! further chunks, so a failed write can never be followed by a good record.

use std::fmt;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::protocol::chips::Chip;

mod stream;
pub use stream::{CaptureStream, ChunkRef, Playable, RawDump, open_capture};

/// The first bytes of every capture file.
pub const MAGIC: &[u8] = b"FIELDCAL-CAPTURE";

/// The format version this module writes, and the only one it reads.
pub const VERSION: u32 = 1;

/// The largest header a reader accepts, in bytes. A larger length field
/// means the file is damaged (real headers are a few hundred bytes).
pub const MAX_HEADER_LEN: u32 = 1 << 20;

/// The largest capture (or raw dump) a reader takes, in bytes: the
/// whole-file reader ([`read_capture`]) holds it in memory, and the one that
/// plays it as it reads ([`open_capture`]) refuses the same files. The Falcon-GX's line at 38 400 baud carries at
/// most 3 840 bytes/s, so a day of it, with each record's 17 bytes of
/// overhead, stays under 0.4 GB; 1 GiB holds well over two days of one and
/// is still an allocation a 32-bit board can make. Anything larger is not a
/// recording of this device (a disk image, a log gone wild) and is refused
/// with this reason rather than read until memory runs out.
pub const MAX_CAPTURE_LEN: u64 = 1 << 30;

/// Bytes a record takes besides its data: the 13-byte head (time, stream,
/// length) and the 4-byte CRC.
pub const RECORD_OVERHEAD: usize = RECORD_HEAD_LEN + CRC_LEN;

const LENGTH_FIELD_LEN: usize = 4;
const RECORD_HEAD_LEN: usize = 13;
const CRC_LEN: usize = 4;
const NANOS_PER_SECOND: f64 = 1e9;
/// 2^64 as an `f64`: the first value that does not fit a `u64`.
const U64_LIMIT: f64 = 18_446_744_073_709_551_616.0;

/// The JSON header of a capture: what was recorded, from where, and when.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CaptureHeader {
    /// Format version; [`VERSION`] for files this module writes.
    pub version: u32,
    /// The byte streams of the source, each id declared once.
    pub streams: Vec<StreamInfo>,
    /// The device the bytes came from (`/dev/ttyUSB0`), when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub port: Option<String>,
    /// The line speed, when the port has one that matters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baud: Option<u32>,
    /// Seconds since the Unix epoch at record time 0 (the first byte).
    pub started_unix: f64,
    /// The period the device was expected to send or be polled at, seconds.
    pub nominal_period_s: f64,
    /// Free text from whoever recorded it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// One byte stream of a capture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StreamInfo {
    /// The id records of this stream carry.
    pub id: u8,
    #[serde(flatten)]
    pub kind: StreamKind,
}

/// What a stream's bytes are.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum StreamKind {
    /// The bytes of a Falcon-GX-style serial line, as read (any split).
    Falcon,
    /// The data bytes of polls of one I2C chip, one chunk per poll.
    Chip {
        chip: Chip,
        /// The chip's 7-bit I2C address.
        address: u8,
    },
}

impl CaptureHeader {
    /// The declaration of stream `id`, if the header has one.
    pub fn stream(&self, id: u8) -> Option<&StreamInfo> {
        self.streams.iter().find(|s| s.id == id)
    }

    /// Why this header cannot go into a capture, if it cannot: a version
    /// other than [`VERSION`], no streams, an id declared twice, an address
    /// above 0x7F, a non-finite start time, or a period that is not positive.
    pub fn problem(&self) -> Option<String> {
        if self.version != VERSION {
            return Some(format!(
                "version {} is not the supported version {VERSION}",
                self.version
            ));
        }
        fields_problem(self)
    }

    fn declared(&self) -> [bool; 256] {
        let mut declared = [false; 256];
        for s in &self.streams {
            declared[usize::from(s.id)] = true;
        }
        declared
    }
}

/// Checks every field but the version (the reader reports that separately).
fn fields_problem(h: &CaptureHeader) -> Option<String> {
    if h.streams.is_empty() {
        return Some("it declares no streams".into());
    }
    let mut seen = [false; 256];
    for s in &h.streams {
        if std::mem::replace(&mut seen[usize::from(s.id)], true) {
            return Some(format!("it declares stream {} twice", s.id));
        }
        match s.kind {
            StreamKind::Chip { address, .. } if address > 0x7F => {
                return Some(format!(
                    "stream {}: address {address:#04x} is not a 7-bit I2C address",
                    s.id
                ));
            }
            _ => {}
        }
    }
    if !h.started_unix.is_finite() {
        return Some(format!("started_unix is {}, not a time", h.started_unix));
    }
    if !(h.nominal_period_s > 0.0 && h.nominal_period_s.is_finite()) {
        return Some(format!(
            "nominal_period_s is {}, not a positive number of seconds",
            h.nominal_period_s
        ));
    }
    None
}

/// One chunk of bytes of one stream, as received.
#[derive(Debug, Clone, PartialEq)]
pub struct Chunk {
    /// Receive time in seconds since the start of the capture: the stored
    /// nanoseconds divided by 1e9.
    pub time: f64,
    pub stream: u8,
    pub bytes: Vec<u8>,
}

/// Seconds to whole nanoseconds, rounded to nearest; `None` for a negative,
/// non-finite or too large (beyond 584 years) time.
pub fn seconds_to_nanos(time: f64) -> Option<u64> {
    if !(time >= 0.0) {
        return None;
    }
    let ns = (time * NANOS_PER_SECOND).round();
    (ns < U64_LIMIT).then_some(ns as u64)
}

/// Stored nanoseconds to the seconds a [`Chunk`] carries.
pub fn nanos_to_seconds(ns: u64) -> f64 {
    ns as f64 / NANOS_PER_SECOND
}

/// Writes a capture: the header at once, then one record per chunk.
///
/// Give it a `BufWriter` and call [`flush`](Self::flush) every second or so:
/// whatever was flushed reads back even if the process dies mid-record.
#[derive(Debug)]
pub struct CaptureWriter<W: Write> {
    out: W,
    declared: [bool; 256],
    record: Vec<u8>,
    chunks: u64,
    failed: bool,
}

fn invalid(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

impl<W: Write> CaptureWriter<W> {
    /// Writes the magic and the header and flushes them, so that even a
    /// capture that gets no chunk at all is a readable file.
    ///
    /// Fails with `InvalidInput` for a header that [`CaptureHeader::problem`]
    /// rejects, or with the error of `out`.
    pub fn new(mut out: W, header: &CaptureHeader) -> io::Result<Self> {
        if let Some(problem) = header.problem() {
            return Err(invalid(format!(
                "cannot write this capture header: {problem}"
            )));
        }
        let json = serde_json::to_vec(header).map_err(io::Error::other)?;
        let len = u32::try_from(json.len())
            .ok()
            .filter(|&len| len <= MAX_HEADER_LEN)
            .ok_or_else(|| {
                invalid(format!(
                    "the capture header is {} bytes of JSON, more than the limit of {MAX_HEADER_LEN}; shorten the note",
                    json.len()
                ))
            })?;
        let mut start = Vec::with_capacity(MAGIC.len() + LENGTH_FIELD_LEN + json.len());
        start.extend_from_slice(MAGIC);
        start.extend_from_slice(&len.to_le_bytes());
        start.extend_from_slice(&json);
        out.write_all(&start)?;
        out.flush()?;
        Ok(CaptureWriter {
            out,
            declared: header.declared(),
            record: Vec::new(),
            chunks: 0,
            failed: false,
        })
    }

    /// Appends one chunk received `time` seconds after the start.
    ///
    /// `InvalidInput` for a negative or non-finite time, a stream the header
    /// does not declare or more than `u32::MAX` bytes; nothing is written
    /// then and the writer stays usable.
    pub fn write_chunk(&mut self, time: f64, stream: u8, bytes: &[u8]) -> io::Result<()> {
        let ns = seconds_to_nanos(time).ok_or_else(|| {
            invalid(format!(
                "chunk time {time} s is not a time since the start of the capture (it must be finite and not negative); use a monotonic clock"
            ))
        })?;
        self.write_chunk_ns(ns, stream, bytes)
    }

    /// Appends one chunk received `time_ns` nanoseconds after the start:
    /// exact, for a recorder that measures with `Instant`/`Duration`.
    pub fn write_chunk_ns(&mut self, time_ns: u64, stream: u8, bytes: &[u8]) -> io::Result<()> {
        self.check_usable()?;
        if !self.declared[usize::from(stream)] {
            return Err(invalid(format!(
                "stream {stream} is not declared in the capture header"
            )));
        }
        let len = u32::try_from(bytes.len()).map_err(|_| {
            invalid(format!(
                "a chunk of {} bytes is too long for one record (limit {})",
                bytes.len(),
                u32::MAX
            ))
        })?;
        self.record.clear();
        self.record.extend_from_slice(&time_ns.to_le_bytes());
        self.record.push(stream);
        self.record.extend_from_slice(&len.to_le_bytes());
        self.record.extend_from_slice(bytes);
        let crc = crc32(&self.record);
        self.record.extend_from_slice(&crc.to_le_bytes());
        let result = self.out.write_all(&self.record);
        self.note_result(result)?;
        self.chunks += 1;
        Ok(())
    }

    /// Pushes buffered records down to `out` (and flushes `out`).
    pub fn flush(&mut self) -> io::Result<()> {
        self.check_usable()?;
        let result = self.out.flush();
        self.note_result(result)
    }

    /// Flushes and hands back the underlying writer.
    pub fn into_inner(mut self) -> io::Result<W> {
        self.flush()?;
        Ok(self.out)
    }

    /// Chunks written so far.
    pub fn chunks_written(&self) -> u64 {
        self.chunks
    }

    /// The underlying writer, e.g. to `sync_data` the file it wraps.
    pub fn get_ref(&self) -> &W {
        &self.out
    }

    fn check_usable(&self) -> io::Result<()> {
        if self.failed {
            return Err(io::Error::other(
                "an earlier write to this capture failed; it ends at its last complete record, start a new capture",
            ));
        }
        Ok(())
    }

    fn note_result(&mut self, result: io::Result<()>) -> io::Result<()> {
        if result.is_err() {
            // A part of a record may be out: nothing may follow it.
            self.failed = true;
        }
        result
    }
}

/// Why a capture cannot be read. Offsets are 0-based bytes from the start
/// of the file.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("{path}: cannot read the capture: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "{name}: the file is empty, nothing to replay; record again and check that the device sends data"
    )]
    Empty { name: String },
    #[error(
        "{name}: byte {offset}: the capture ends inside its {part} ({present} of {needed} bytes present); the recorder stopped before writing any data, record again"
    )]
    TruncatedHeader {
        name: String,
        offset: u64,
        /// "magic", "header length" or "header".
        part: &'static str,
        present: u64,
        needed: u64,
    },
    #[error(
        "{name}: byte {offset}: the capture header is damaged: {problem}; the recording cannot be replayed, record again (or repair the header by hand, see docs/capture-format.md)"
    )]
    BadHeader {
        name: String,
        offset: u64,
        problem: String,
    },
    #[error(
        "{name}: byte {offset}: capture format version {found}, but this fieldcal reads only version {supported}; use the fieldcal that recorded it, or a newer one"
    )]
    UnsupportedVersion {
        name: String,
        offset: u64,
        found: u64,
        supported: u32,
    },
    #[error(
        "{name}: byte {offset}: record {index} belongs to stream {stream}, which the header does not declare (declared: {declared}); the file was written by a faulty recorder or edited, so its streams cannot be trusted: record again and report the recorder bug"
    )]
    UndeclaredStream {
        name: String,
        offset: u64,
        /// 0-based index of the record.
        index: usize,
        stream: u8,
        declared: String,
    },
}

/// A capture or a plain raw byte dump (`cat /dev/ttyUSB0 > file`).
#[derive(Debug, Clone, PartialEq)]
pub enum CaptureFile {
    Capture {
        header: CaptureHeader,
        chunks: Vec<Chunk>,
        /// Set when reading stopped before the end of the file.
        truncated: Option<Truncation>,
    },
    /// The file does not start with [`MAGIC`]: its bytes, whole.
    Raw { bytes: Vec<u8> },
}

/// Where and why reading a capture stopped before the end of the file. Its
/// `Display` is a warning for the user (it does not name the file).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Truncation {
    /// Byte offset of the first record not read.
    pub offset: u64,
    /// Chunks read intact before it (all of them returned).
    pub chunks_intact: usize,
    /// Bytes from `offset` to the end of the file, dropped.
    pub bytes_dropped: u64,
    pub reason: TruncationReason,
}

/// What was wrong with the first record not read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TruncationReason {
    /// The file ends before the record does: a torn tail, left when the
    /// recorder is killed or the disk fills up (or a damaged length field).
    Torn,
    /// The record is complete by its length but its CRC does not match: the
    /// bytes were damaged (a power cut can leave zeros at the end of a file).
    BadChecksum,
}

impl fmt::Display for Truncation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Truncation {
            offset,
            chunks_intact,
            bytes_dropped,
            reason,
        } = self;
        match reason {
            TruncationReason::Torn => write!(
                f,
                "the capture is cut off at byte {offset}: its last record is incomplete \
                 ({bytes_dropped} bytes dropped), as when the recorder is killed or the disk \
                 fills up; the {chunks_intact} chunks before it are intact"
            ),
            TruncationReason::BadChecksum => write!(
                f,
                "the record at byte {offset} fails its checksum, so reading stopped there and \
                 the last {bytes_dropped} bytes were dropped; the {chunks_intact} chunks before \
                 it are intact (a power cut can damage the end of a file; damage far from the \
                 end means the file was corrupted after recording)"
            ),
        }
    }
}

/// Reads a capture, or a raw dump, from a file. The path must be a regular
/// file of at most [`MAX_CAPTURE_LEN`] bytes (see
/// [`crate::io::regular::read_regular`]): a FIFO, a device such as
/// `/dev/zero` or a directory is refused before anything is read. The
/// daemon's configuration check refuses the same files.
pub fn read_capture(path: &Path) -> Result<CaptureFile, CaptureError> {
    let bytes = crate::io::regular::read_regular(path, MAX_CAPTURE_LEN).map_err(|source| {
        CaptureError::Io {
            path: path.to_path_buf(),
            source,
        }
    })?;
    match parse(&bytes, &path.display().to_string())? {
        Some(capture) => Ok(capture),
        None => Ok(CaptureFile::Raw { bytes }),
    }
}

/// Parses a capture, or recognises a raw dump, from its bytes; `name` (the
/// file's name) is for messages. Does no I/O.
pub fn parse_capture(bytes: &[u8], name: &str) -> Result<CaptureFile, CaptureError> {
    match parse(bytes, name)? {
        Some(capture) => Ok(capture),
        None => Ok(CaptureFile::Raw {
            bytes: bytes.to_vec(),
        }),
    }
}

/// The parse: `None` for a raw dump (the caller owns the bytes).
fn parse(bytes: &[u8], name: &str) -> Result<Option<CaptureFile>, CaptureError> {
    let Some((header, json_end)) = parse_head(bytes, name)? else {
        return Ok(None);
    };
    let declared = header.declared();
    let mut chunks = Vec::new();
    let mut pos = json_end;
    let mut truncated = None;
    while let Some(rest) = bytes.get(pos..).filter(|rest| !rest.is_empty()) {
        let reason = match read_record(rest) {
            Record::Intact {
                time_ns,
                stream,
                data,
                size,
            } => {
                if !declared[usize::from(stream)] {
                    return Err(undeclared(name, &header, pos as u64, chunks.len(), stream));
                }
                chunks.push(Chunk {
                    time: nanos_to_seconds(time_ns),
                    stream,
                    bytes: data.to_vec(),
                });
                pos += size;
                continue;
            }
            Record::Torn => TruncationReason::Torn,
            Record::BadChecksum => TruncationReason::BadChecksum,
        };
        truncated = Some(Truncation {
            offset: pos as u64,
            chunks_intact: chunks.len(),
            bytes_dropped: rest.len() as u64,
            reason,
        });
        break;
    }
    Ok(Some(CaptureFile::Capture {
        header,
        chunks,
        truncated,
    }))
}

/// The error for record `index` at `offset`, of a `stream` the header does
/// not declare.
fn undeclared(
    name: &str,
    header: &CaptureHeader,
    offset: u64,
    index: usize,
    stream: u8,
) -> CaptureError {
    CaptureError::UndeclaredStream {
        name: name.into(),
        offset,
        index,
        stream,
        declared: header
            .streams
            .iter()
            .map(|s| s.id.to_string())
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// The magic and header at the start of `bytes` (the whole file, or at
/// least its first [`HEAD_LEN_AT_MOST`] bytes), and where the records
/// start; `None`: a raw dump.
fn parse_head(bytes: &[u8], name: &str) -> Result<Option<(CaptureHeader, usize)>, CaptureError> {
    if bytes.is_empty() {
        return Err(CaptureError::Empty { name: name.into() });
    }
    let file_len = bytes.len() as u64;
    let cut = |part, start: usize, needed: usize| CaptureError::TruncatedHeader {
        name: name.into(),
        offset: file_len,
        part,
        present: file_len.saturating_sub(start as u64),
        needed: needed as u64,
    };
    if !bytes.starts_with(MAGIC) {
        if MAGIC.starts_with(bytes) {
            return Err(cut("magic", 0, MAGIC.len()));
        }
        return Ok(None);
    }

    let len_at = MAGIC.len();
    let Some(&[l0, l1, l2, l3]) = bytes.get(len_at..len_at + LENGTH_FIELD_LEN) else {
        return Err(cut("header length", len_at, LENGTH_FIELD_LEN));
    };
    let header_len = u32::from_le_bytes([l0, l1, l2, l3]);
    let bad = |offset: usize, problem: String| CaptureError::BadHeader {
        name: name.into(),
        offset: offset as u64,
        problem,
    };
    if header_len > MAX_HEADER_LEN {
        return Err(bad(
            len_at,
            format!(
                "its length field says {header_len} bytes, more than the limit of {MAX_HEADER_LEN}"
            ),
        ));
    }
    let json_at = len_at + LENGTH_FIELD_LEN;
    // header_len <= 1 MiB: no overflow.
    let json_end = json_at + header_len as usize;
    let Some(json) = bytes.get(json_at..json_end) else {
        return Err(cut("header", json_at, header_len as usize));
    };
    let header = parse_header(json).map_err(|e| match e {
        HeaderFault::Version(found) => CaptureError::UnsupportedVersion {
            name: name.into(),
            offset: json_at as u64,
            found,
            supported: VERSION,
        },
        HeaderFault::Problem(problem, at) => bad(json_at + at, problem),
    })?;
    Ok(Some((header, json_end)))
}

/// The most bytes the magic, the length field and the header take.
const HEAD_LEN_AT_MOST: usize = MAGIC.len() + LENGTH_FIELD_LEN + MAX_HEADER_LEN as usize;

enum HeaderFault {
    Version(u64),
    /// What is wrong, and where in the JSON when that is known.
    Problem(String, usize),
}

/// The header JSON to a checked header. The version is looked at first, so
/// that a newer file is reported as such rather than as bad JSON fields.
fn parse_header(json: &[u8]) -> Result<CaptureHeader, HeaderFault> {
    let value: serde_json::Value = serde_json::from_slice(json).map_err(|e| {
        HeaderFault::Problem(
            format!("it is not valid JSON ({e})"),
            json_error_offset(json, &e),
        )
    })?;
    let whole = |problem: &str| Err(HeaderFault::Problem(problem.into(), 0));
    if !value.is_object() {
        return whole("it is not a JSON object");
    }
    match value.get("version").map(serde_json::Value::as_u64) {
        None => return whole("it has no `version` field"),
        Some(None) => return whole("its `version` is not a whole number"),
        Some(Some(v)) if v != u64::from(VERSION) => return Err(HeaderFault::Version(v)),
        Some(Some(_)) => {}
    }
    // Parsed again from the text, for the position of a misfit field.
    let mut header: CaptureHeader = serde_json::from_slice(json).map_err(|e| {
        HeaderFault::Problem(
            format!("its fields do not fit ({e})"),
            json_error_offset(json, &e),
        )
    })?;
    if let Ok(text) = std::str::from_utf8(json) {
        header.started_unix = exact_number(text, "started_unix", header.started_unix);
        header.nominal_period_s = exact_number(text, "nominal_period_s", header.nominal_period_s);
    }
    match fields_problem(&header) {
        Some(problem) => whole(&problem),
        None => Ok(header),
    }
}

/// `approx` read again exactly from its text after `"key":`.
///
/// serde_json without its `float_roundtrip` feature (not enabled here) reads
/// some 17-digit numbers one unit in the last place off: about one time in
/// ten a `started_unix` would not read back as written. Rust's own parser is
/// exact. The text is found by its key; it is used only if it is the same
/// number give or take two units in the last place, so a look-alike key
/// elsewhere (in a nested object) can never change the value.
fn exact_number(json: &str, key: &str, approx: f64) -> f64 {
    let pattern = format!("\"{key}\"");
    for (at, _) in json.match_indices(&pattern) {
        let Some(rest) = json
            .get(at + pattern.len()..)
            .and_then(|rest| rest.trim_start().strip_prefix(':'))
        else {
            continue;
        };
        let rest = rest.trim_start();
        let end = rest
            .find(|c: char| !matches!(c, '0'..='9' | '-' | '+' | '.' | 'e' | 'E'))
            .unwrap_or(rest.len());
        let Some(Ok(exact)) = rest.get(..end).map(str::parse::<f64>) else {
            continue;
        };
        let same_sign = exact.is_sign_negative() == approx.is_sign_negative();
        if exact.is_finite() && same_sign && exact.to_bits().abs_diff(approx.to_bits()) <= 2 {
            return exact;
        }
    }
    approx
}

/// The byte offset in `json` of serde_json's 1-based line and column.
fn json_error_offset(json: &[u8], e: &serde_json::Error) -> usize {
    let line_start = json
        .split_inclusive(|&b| b == b'\n')
        .take(e.line().saturating_sub(1))
        .map(<[u8]>::len)
        .sum::<usize>();
    (line_start + e.column().saturating_sub(1)).min(json.len())
}

enum Record<'a> {
    Intact {
        time_ns: u64,
        stream: u8,
        data: &'a [u8],
        /// Bytes the whole record takes.
        size: usize,
    },
    Torn,
    BadChecksum,
}

/// Reads the record at the start of `rest` (which is not empty).
fn read_record(rest: &[u8]) -> Record<'_> {
    let Some((head, after)) = rest.split_first_chunk::<RECORD_HEAD_LEN>() else {
        return Record::Torn;
    };
    let [t0, t1, t2, t3, t4, t5, t6, t7, stream, l0, l1, l2, l3] = *head;
    let time_ns = u64::from_le_bytes([t0, t1, t2, t3, t4, t5, t6, t7]);
    let len = u32::from_le_bytes([l0, l1, l2, l3]);
    // Checked against the bytes present before slicing; nothing is allocated
    // from `len`.
    let Some((data, tail)) = usize::try_from(len)
        .ok()
        .and_then(|len| after.split_at_checked(len))
    else {
        return Record::Torn;
    };
    let Some((&stored, _)) = tail.split_first_chunk::<CRC_LEN>() else {
        return Record::Torn;
    };
    let size = RECORD_OVERHEAD + data.len();
    let mut crc = crc32fast::Hasher::new();
    crc.update(head);
    crc.update(data);
    if crc.finalize() != u32::from_le_bytes(stored) {
        return Record::BadChecksum;
    }
    Record::Intact {
        time_ns,
        stream,
        data,
        size,
    }
}

/// CRC-32 as in zlib, PNG and Ethernet (CRC-32/ISO-HDLC: reflected
/// polynomial 0xEDB88320, initial value and final xor 0xFFFFFFFF).
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}
