//! A capture read as it plays: one record in memory at a time, whatever
//! the file's length.
//!
//! [`open_capture`] reads the magic and the header, then looks over the
//! records' heads once (their lengths and streams, skipping their data) so
//! that a file the whole-file reader ([`super::read_capture`]) refuses is
//! refused before anything plays. [`CaptureStream::next_chunk`] then reads
//! each record into one reused buffer, checks its CRC, and stops at a torn
//! tail or a damaged record as the whole-file reader does, with the same
//! [`Truncation`]. A raw dump is read in blocks ([`RawDump::blocks`]).

use std::fs::File;
use std::io::{self, BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use super::{
    CRC_LEN, CaptureError, CaptureFile, CaptureHeader, HEAD_LEN_AT_MOST, MAX_CAPTURE_LEN,
    RECORD_HEAD_LEN, RECORD_OVERHEAD, Record, Truncation, TruncationReason, nanos_to_seconds,
    parse_head, read_capture, read_record,
};
use crate::io::regular::{TooLarge, open_regular};

/// Bytes read from the file at a time.
const BLOCK: usize = 1 << 16;

/// A capture ready to play.
#[derive(Debug)]
pub enum Playable {
    /// Records read as they play.
    Stream(Box<CaptureStream>),
    /// A capture read whole: one whose records the look-over could not
    /// clear (a record of an undeclared stream, which is an error unless a
    /// damaged record before it ends the reading first), read as
    /// [`read_capture`] reads it.
    Whole(CaptureFile),
    /// A plain dump of bytes, with no records.
    Raw(RawDump),
}

/// Opens the capture (or raw dump) at `path` to be played as it is read:
/// the same checks and errors as [`read_capture`] (a regular file of at
/// most [`MAX_CAPTURE_LEN`] bytes, a good header, no record of an
/// undeclared stream), with memory that does not grow with the file.
pub fn open_capture(path: &Path) -> Result<Playable, CaptureError> {
    let io_error = |source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = open_regular(path).map_err(io_error)?;
    let len = file.metadata().map_err(io_error)?.len();
    if len > MAX_CAPTURE_LEN {
        let too_large = TooLarge {
            max: MAX_CAPTURE_LEN,
        };
        return Err(io_error(io::Error::new(
            io::ErrorKind::InvalidData,
            too_large,
        )));
    }
    let name = path.display().to_string();
    let mut head = Vec::new();
    (&mut file)
        .take((HEAD_LEN_AT_MOST as u64).min(len))
        .read_to_end(&mut head)
        .map_err(io_error)?;
    let Some((header, records_at)) = parse_head(&head, &name)? else {
        return Ok(Playable::Raw(RawDump { file, len, name }));
    };
    drop(head);
    let records_at = records_at as u64;
    file.seek(SeekFrom::Start(records_at)).map_err(io_error)?;
    let mut reader = BufReader::with_capacity(BLOCK, file);
    let declared = header.declared();
    if !all_declared(&mut reader, records_at, len, &declared).map_err(io_error)? {
        return read_capture(path).map(Playable::Whole);
    }
    reader.seek(SeekFrom::Start(records_at)).map_err(io_error)?;
    Ok(Playable::Stream(Box::new(CaptureStream {
        reader,
        name,
        header,
        declared,
        pos: records_at,
        len,
        chunks: 0,
        record: Vec::new(),
        truncated: None,
        failed: None,
    })))
}

/// Whether every record whose length fits the file, from `pos`, is of a
/// declared stream (their data skipped, their CRCs not checked). A head
/// the reader holds whole is read where it lies, and a record the reader
/// holds whole is passed over in it: the same file offsets and reads as
/// `read_exact` and `seek_relative` on each record, a fraction of their
/// cost on records of a few dozen bytes.
fn all_declared(
    reader: &mut BufReader<File>,
    mut pos: u64,
    len: u64,
    declared: &[bool; 256],
) -> io::Result<bool> {
    let mut head = [0u8; RECORD_HEAD_LEN];
    // Each pass moves `pos` on by at least a record's overhead.
    while len.saturating_sub(pos) >= RECORD_OVERHEAD as u64 {
        // How much of the record the reader has passed once `head` is read.
        let read = match reader.buffer().get(..RECORD_HEAD_LEN) {
            Some(held) => {
                head.copy_from_slice(held);
                0
            }
            None => {
                reader.read_exact(&mut head)?;
                RECORD_HEAD_LEN as u64
            }
        };
        let [.., stream, l0, l1, l2, l3] = head;
        let data = u64::from(u32::from_le_bytes([l0, l1, l2, l3]));
        let size = RECORD_OVERHEAD as u64 + data;
        if len - pos < size {
            // A torn tail: the reading ends before it.
            break;
        }
        if !declared[usize::from(stream)] {
            return Ok(false);
        }
        let rest = size - read;
        match usize::try_from(rest) {
            Ok(held) if held <= reader.buffer().len() => reader.consume(held),
            _ => reader.seek_relative(rest as i64)?,
        }
        pos += size;
    }
    Ok(true)
}

/// One record of a capture, borrowed from the reader's buffer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChunkRef<'a> {
    /// Seconds since the start of the capture, as [`super::Chunk::time`].
    pub time: f64,
    pub stream: u8,
    pub bytes: &'a [u8],
}

/// The records of a capture, read one at a time ([`open_capture`]).
#[derive(Debug)]
pub struct CaptureStream {
    reader: BufReader<File>,
    name: String,
    header: CaptureHeader,
    declared: [bool; 256],
    /// Offset of the next record.
    pos: u64,
    /// The file's length when it was opened: nothing past it is read.
    len: u64,
    /// Records read intact.
    chunks: usize,
    /// The record being read: head, data and CRC.
    record: Vec<u8>,
    truncated: Option<Truncation>,
    /// A read that failed (not a file cut short): the reading ended there.
    failed: Option<io::Error>,
}

impl CaptureStream {
    pub fn header(&self) -> &CaptureHeader {
        &self.header
    }

    /// The file's name, as messages give it.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Where the reading stopped before the end of the file, once it has.
    pub fn truncated(&self) -> Option<&Truncation> {
        self.truncated.as_ref()
    }

    /// A read of the file that failed, once it has (the records before it
    /// were handed on).
    pub fn take_error(&mut self) -> Option<io::Error> {
        self.failed.take()
    }

    /// The next intact record; `None` at the end of the file, at a torn
    /// or damaged record ([`CaptureStream::truncated`] says which), or at
    /// a read that fails ([`CaptureStream::take_error`]).
    pub fn next_chunk(&mut self) -> Option<ChunkRef<'_>> {
        loop {
            if self.truncated.is_some() || self.failed.is_some() || self.pos >= self.len {
                return None;
            }
            let reason = match self.read_next() {
                Ok(Err(reason)) => reason,
                // A file cut shorter since it was opened: a torn tail.
                Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => TruncationReason::Torn,
                Err(e) => {
                    self.failed = Some(e);
                    return None;
                }
                Ok(Ok((time_ns, stream, size))) => {
                    self.pos += size as u64;
                    // Cleared when the file was opened: only a file changed
                    // since holds one, and its record is not played.
                    if !self.declared[usize::from(stream)] {
                        continue;
                    }
                    self.chunks += 1;
                    return Some(ChunkRef {
                        time: nanos_to_seconds(time_ns),
                        stream,
                        bytes: &self.record[RECORD_HEAD_LEN..size - CRC_LEN],
                    });
                }
            };
            self.truncated = Some(Truncation {
                offset: self.pos,
                chunks_intact: self.chunks,
                bytes_dropped: self.len - self.pos,
                reason,
            });
        }
    }

    /// Reads the next record into the buffer: its time, stream and size
    /// when it is intact, else why not.
    fn read_next(&mut self) -> io::Result<Result<(u64, u8, usize), TruncationReason>> {
        let rest = self.len - self.pos;
        if rest < RECORD_HEAD_LEN as u64 {
            return Ok(Err(TruncationReason::Torn));
        }
        self.record.resize(RECORD_HEAD_LEN, 0);
        self.reader.read_exact(&mut self.record)?;
        let [.., l0, l1, l2, l3] = self.record[..] else {
            return Ok(Err(TruncationReason::Torn));
        };
        let size = RECORD_OVERHEAD as u64 + u64::from(u32::from_le_bytes([l0, l1, l2, l3]));
        if rest < size {
            return Ok(Err(TruncationReason::Torn));
        }
        // At most the file's length, which is at most MAX_CAPTURE_LEN.
        let size = usize::try_from(size).map_err(|_| io::ErrorKind::InvalidData)?;
        self.record.resize(size, 0);
        self.reader
            .read_exact(&mut self.record[RECORD_HEAD_LEN..])?;
        Ok(match read_record(&self.record) {
            Record::Intact {
                time_ns,
                stream,
                size,
                ..
            } => Ok((time_ns, stream, size)),
            Record::Torn => Err(TruncationReason::Torn),
            Record::BadChecksum => Err(TruncationReason::BadChecksum),
        })
    }
}

/// A raw dump (`cat /dev/ttyUSB0 > file`), read in blocks.
#[derive(Debug)]
pub struct RawDump {
    file: File,
    len: u64,
    name: String,
}

impl RawDump {
    /// Its length in bytes when it was opened.
    pub fn len(&self) -> u64 {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Calls `each` with the dump's bytes in order, a block at a time, from
    /// the start to its length when opened. `each` returns false to stop.
    pub fn blocks(&mut self, each: &mut dyn FnMut(&[u8]) -> bool) -> io::Result<()> {
        self.file.seek(SeekFrom::Start(0))?;
        let mut reader = BufReader::with_capacity(BLOCK, (&self.file).take(self.len));
        loop {
            let block = reader.fill_buf()?;
            if block.is_empty() {
                return Ok(());
            }
            let n = block.len();
            if !each(block) {
                return Ok(());
            }
            reader.consume(n);
        }
    }
}
