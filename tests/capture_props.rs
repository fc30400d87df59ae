//! Properties of the capture format, on generated cases: the reader never
//! panics, whatever it is given, and what the writer writes reads back.

use fieldcal::capture::{
    CaptureFile, CaptureHeader, CaptureWriter, Chunk, MAGIC, StreamInfo, StreamKind, Truncation,
    TruncationReason, VERSION, nanos_to_seconds, parse_capture,
};
use fieldcal::protocol::chips::Chip;
use proptest::prelude::*;

/// Stream ids the generated headers declare.
const IDS: [u8; 3] = [0, 1, 200];

fn header(started_unix: f64, port: Option<String>, note: Option<String>) -> CaptureHeader {
    CaptureHeader {
        version: VERSION,
        streams: vec![
            StreamInfo {
                id: IDS[0],
                kind: StreamKind::Falcon,
            },
            StreamInfo {
                id: IDS[1],
                kind: StreamKind::Chip {
                    chip: Chip::Lsm303dlhcMag,
                    address: 0x1E,
                },
            },
            StreamInfo {
                id: IDS[2],
                kind: StreamKind::Chip {
                    chip: Chip::Adxl345,
                    address: 0x53,
                },
            },
        ],
        port,
        baud: Some(38400),
        started_unix,
        nominal_period_s: 0.03,
        note,
    }
}

fn write(header: &CaptureHeader, chunks: &[Chunk]) -> Vec<u8> {
    let mut w = CaptureWriter::new(Vec::new(), header).unwrap();
    for c in chunks {
        w.write_chunk(c.time, c.stream, &c.bytes).unwrap();
    }
    w.into_inner().unwrap()
}

/// Chunks of declared streams, at whole nanoseconds up to about 28 hours.
fn chunks() -> impl Strategy<Value = Vec<Chunk>> {
    proptest::collection::vec(
        (
            0u64..100_000_000_000_000,
            proptest::sample::select(IDS.to_vec()),
            proptest::collection::vec(any::<u8>(), 0..40),
        )
            .prop_map(|(ns, stream, bytes)| Chunk {
                time: nanos_to_seconds(ns),
                stream,
                bytes,
            }),
        0..30,
    )
}

/// Whatever the reader returns is self-consistent.
fn check_consistent(file: &CaptureFile, len: usize) -> Result<(), TestCaseError> {
    if let CaptureFile::Capture {
        header,
        chunks,
        truncated,
    } = file
    {
        for c in chunks {
            prop_assert!(header.stream(c.stream).is_some());
            prop_assert!(c.time >= 0.0 && c.time.is_finite());
        }
        if let Some(Truncation {
            offset,
            chunks_intact,
            bytes_dropped,
            ..
        }) = truncated
        {
            prop_assert_eq!(*chunks_intact, chunks.len());
            prop_assert!(*bytes_dropped > 0);
            prop_assert_eq!(offset + bytes_dropped, len as u64);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Any bytes at all: a capture, a raw dump or an error, never a panic.
    /// Bytes that do not start like the magic come back whole as raw.
    #[test]
    fn any_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        match parse_capture(&bytes, "fuzz.bin") {
            Ok(file) => {
                check_consistent(&file, bytes.len())?;
                if !bytes.starts_with(MAGIC) {
                    prop_assert_eq!(file, CaptureFile::Raw { bytes: bytes.clone() });
                }
            }
            Err(e) => prop_assert!(e.to_string().starts_with("fuzz.bin: ")),
        }
    }

    /// Any bytes after the magic: never a panic, and errors name the file.
    #[test]
    fn any_bytes_after_magic_never_panic(
        len in proptest::option::of(0u32..300),
        bytes in proptest::collection::vec(any::<u8>(), 0..600),
    ) {
        let mut file = MAGIC.to_vec();
        // Half the cases with a plausible header length, to get past it.
        if let Some(len) = len {
            file.extend_from_slice(&len.to_le_bytes());
        }
        file.extend_from_slice(&bytes);
        match parse_capture(&file, "fuzz.cap") {
            Ok(parsed) => {
                prop_assert!(matches!(parsed, CaptureFile::Capture { .. }), "read as raw");
                check_consistent(&parsed, file.len())?;
            }
            Err(e) => prop_assert!(e.to_string().starts_with("fuzz.cap: byte ")),
        }
    }

    /// A valid header followed by any bytes: the record reader never
    /// panics, and never allocates from a length it has not checked (a
    /// huge length in the garbage would abort the test if it did).
    #[test]
    fn any_records_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut file = write(&header(1.7e9, None, None), &[]);
        file.extend_from_slice(&tail);
        match parse_capture(&file, "tail.cap") {
            Ok(parsed) => check_consistent(&parsed, file.len())?,
            Err(e) => prop_assert!(e.to_string().starts_with("tail.cap: byte ")),
        }
    }

    /// Write then read gives back the header and every chunk, times to the
    /// nanosecond.
    #[test]
    fn write_then_read_is_identity(
        chunks in chunks(),
        started_unix in -1e10f64..1e10,
        port in proptest::option::of("\\PC{0,20}"),
        note in proptest::option::of("\\PC{0,60}"),
    ) {
        let header = header(started_unix, port, note);
        let file = write(&header, &chunks);
        match parse_capture(&file, "rt.cap").unwrap() {
            CaptureFile::Capture { header: h, chunks: c, truncated } => {
                prop_assert_eq!(h, header);
                prop_assert_eq!(c, chunks);
                prop_assert_eq!(truncated, None);
            }
            CaptureFile::Raw { .. } => prop_assert!(false, "read as raw"),
        }
    }

    /// A writer killed at any byte after the header: every complete record
    /// reads back, and a partial one is reported as torn.
    #[test]
    fn any_cut_keeps_the_complete_records(chunks in chunks(), at in any::<prop::sample::Index>()) {
        let header = header(1.7e9, Some("/dev/ttyUSB1".into()), None);
        let start = write(&header, &[]).len();
        let file = write(&header, &chunks);
        let cut = start + at.index(file.len() - start + 1);
        let CaptureFile::Capture { chunks: c, truncated, .. } =
            parse_capture(&file[..cut], "cut.cap").unwrap()
        else {
            return Err(TestCaseError::fail("read as raw"));
        };
        prop_assert_eq!(&c[..], &chunks[..c.len()]);
        let complete: usize = c.iter().map(|c| c.bytes.len() + 17).sum::<usize>() + start;
        match truncated {
            None => prop_assert_eq!(complete, cut),
            Some(t) => {
                prop_assert_eq!(t.offset, complete as u64);
                prop_assert_eq!(t.reason, TruncationReason::Torn);
                prop_assert!(c.len() < chunks.len());
            }
        }
    }

    /// One damaged byte among the records: the chunks before it read back,
    /// and the read stops at its record.
    #[test]
    fn a_damaged_byte_stops_the_read_at_its_record(
        chunks in chunks().prop_filter("some records", |c| !c.is_empty()),
        at in any::<prop::sample::Index>(),
        flip in 1u8..=255,
    ) {
        let header = header(1.7e9, None, Some("damaged".into()));
        let start = write(&header, &[]).len();
        let mut file = write(&header, &chunks);
        let pos = start + at.index(file.len() - start);
        file[pos] ^= flip;
        let CaptureFile::Capture { chunks: c, truncated, .. } =
            parse_capture(&file, "flip.cap").unwrap()
        else {
            return Err(TestCaseError::fail("read as raw"));
        };
        // The record holding the damaged byte.
        let mut record_start = start;
        let mut index = 0;
        for ch in &chunks {
            let end = record_start + ch.bytes.len() + 17;
            if pos < end {
                break;
            }
            record_start = end;
            index += 1;
        }
        prop_assert_eq!(&c[..], &chunks[..index]);
        let t = truncated.unwrap();
        prop_assert_eq!(t.offset, record_start as u64);
        prop_assert_eq!(t.chunks_intact, index);
    }
}
