//! Properties of the capture format, on generated cases: the reader never
//! panics, whatever it is given, and what the writer writes reads back.

use fieldcal::capture::{
    CaptureFile, CaptureHeader, CaptureWriter, Chunk, MAGIC, StreamInfo, StreamKind, Truncation,
    TruncationReason, VERSION, nanos_to_seconds, parse_capture,
};
use std::sync::atomic::AtomicBool;

use fieldcal::capture::{Playable, open_capture, read_capture};
use fieldcal::protocol::chips::Chip;
use fieldcal::source::SourceCounters;
use fieldcal::source::replay::{ReplaySummary, Speed, replay_counted, replay_playable};
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

/// A replay of the file at `path` read whole, and read as it plays: every
/// reading handed on, and the summary (or the error's message).
type Played = Result<(Vec<fieldcal::sample::Reading>, ReplaySummary), String>;

fn play_both(path: &std::path::Path) -> (Played, Played) {
    let stop = AtomicBool::new(false);
    let whole = read_capture(path)
        .map_err(|e| e.to_string())
        .and_then(|file| {
            let mut readings = Vec::new();
            let counters = SourceCounters::default();
            replay_counted(&file, "f", Speed::Max, &stop, &counters, &mut |r| {
                readings.push(r)
            })
            .map(|summary| (readings, summary))
            .map_err(|e| e.to_string())
        });
    let streamed = open_capture(path)
        .map_err(|e| e.to_string())
        .and_then(|mut file| {
            let mut readings = Vec::new();
            let counters = SourceCounters::default();
            replay_playable(&mut file, "f", Speed::Max, &stop, &counters, &mut |r| {
                readings.push(r)
            })
            .map(|summary| (readings, summary))
            .map_err(|e| e.to_string())
        });
    (whole, streamed)
}

/// Falcon-GX frames that decode, split anywhere, for the Falcon stream.
fn falcon_bytes(frames: usize, seed: u8) -> Vec<u8> {
    let mut bytes = Vec::new();
    for k in 0..frames {
        let frame = fieldcal::protocol::falcon::FalconFrame {
            timer: (k as u16).wrapping_mul(50),
            mag: [1000 + i16::from(seed), -(k as i16), 200],
            accel: [0, 0, 4096],
            rate: [0, 0, 360],
        };
        bytes.extend_from_slice(&frame.encode());
    }
    bytes
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// Read as it plays, a capture gives what it gives read whole: the
    /// same readings, summary, truncation and errors, whole, cut anywhere,
    /// with a byte damaged anywhere, with a record of a stream the header
    /// does not declare, and as a raw dump.
    #[test]
    fn a_capture_read_as_it_plays_plays_as_one_read_whole(
        chunks in chunks(),
        frames in 0usize..30,
        split in 1usize..40,
        cut in any::<prop::sample::Index>(),
        flip in any::<prop::sample::Index>(),
        damage in 0u8..5,
    ) {
        let falcon = falcon_bytes(frames, 3);
        let mut all = chunks;
        for (k, part) in falcon.chunks(split).enumerate() {
            all.push(Chunk { time: 1e-3 * k as f64, stream: IDS[0], bytes: part.to_vec() });
        }
        let mut bytes = match damage {
            // A raw dump: the Falcon bytes alone.
            4 => falcon.clone(),
            _ => write(&header(0.0, None, None), &all),
        };
        match damage {
            1 if !bytes.is_empty() => bytes.truncate(cut.index(bytes.len())),
            2 if !bytes.is_empty() => {
                let at = flip.index(bytes.len());
                bytes[at] ^= 0x5A;
            }
            3 => {
                // A record of stream 7 (undeclared), intact, in the middle.
                let mut wider = header(0.0, None, None);
                wider.streams.push(StreamInfo { id: 7, kind: StreamKind::Falcon });
                let mut odd = all.clone();
                odd.insert(cut.index(odd.len() + 1), Chunk { time: 0.5, stream: 7, bytes: vec![1, 2] });
                let written = write(&wider, &odd);
                let records = records_at(&written);
                bytes = write(&header(0.0, None, None), &[]);
                bytes.extend_from_slice(&written[records..]);
                if cut.index(4) == 0 {
                    // And a damaged record before everything.
                    let first = records_at(&bytes) + 13;
                    if first < bytes.len() {
                        bytes[first] ^= 1;
                    }
                }
            }
            _ => {}
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.fcap");
        std::fs::write(&path, &bytes).unwrap();
        let (whole, streamed) = play_both(&path);
        prop_assert_eq!(whole, streamed);
    }
}

/// Where the records of a capture written by [`write`] start.
fn records_at(bytes: &[u8]) -> usize {
    let at = MAGIC.len();
    let len = u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    at + 4 + len as usize
}

/// A raw dump longer than a block of the reader (64 KiB), with garbage
/// between its frames and a torn frame at its end, plays as it does read
/// whole: frames split across blocks are decoded once each.
#[test]
fn a_long_raw_dump_plays_across_blocks_as_read_whole() {
    let mut bytes = Vec::new();
    for k in 0..10_000 {
        bytes.extend_from_slice(&falcon_bytes(1, (k % 7) as u8));
        if k % 13 == 0 {
            bytes.extend_from_slice(&[0x00, 0x17, 0x42]);
        }
    }
    bytes.extend_from_slice(&falcon_bytes(1, 1)[..9]);
    assert!(bytes.len() > 3 * (1 << 16));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dump.bin");
    std::fs::write(&path, &bytes).unwrap();
    let (whole, streamed) = play_both(&path);
    let (readings, summary) = whole.clone().unwrap();
    assert_eq!(readings.len(), 10_000);
    assert!(summary.truncated.is_some());
    assert_eq!(whole, streamed);
}

/// A capture longer than the reader's buffer (64 KiB), its records of
/// every small length so that heads and records lie across the buffer's
/// ends, is looked over to its last record before it plays: a record of
/// an undeclared stream anywhere in it (the first, the one whose head lies
/// across the first buffer's end, the one after it, the last) refuses the
/// file at that record, as read whole; without one, it plays as it is
/// read, as read whole, and so with a torn tail.
#[test]
fn a_long_capture_is_looked_over_across_the_readers_buffer() {
    let all: Vec<Chunk> = (0..6_000)
        .map(|k: usize| Chunk {
            time: 1e-3 * k as f64,
            stream: IDS[k % 3],
            bytes: vec![(k % 251) as u8; (k * 7_919) % 61 + 1],
        })
        .collect();
    let mut wider = header(0.0, None, None);
    wider.streams.push(StreamInfo {
        id: 7,
        kind: StreamKind::Falcon,
    });
    // A record is a 13-byte head, its data and a 4-byte CRC; the reader's
    // first 64 KiB start at the first record. The record inserted before
    // record `across` starts where it did, its head across that end.
    let mut start = 0;
    let across = all
        .iter()
        .position(|c| {
            let head_end = start + 13;
            start += 13 + c.bytes.len() + 4;
            head_end > 1 << 16
        })
        .unwrap();
    assert!(start - (13 + all[across].bytes.len() + 4) < 1 << 16);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.fcap");
    let mut refused = 0;
    for at in [
        None,
        Some(0),
        Some(across),
        Some(across + 1),
        Some(2_950),
        Some(5_999),
        Some(6_000),
    ] {
        let mut chunks = all.clone();
        if let Some(at) = at {
            chunks.insert(
                at,
                Chunk {
                    time: 0.5,
                    stream: 7,
                    bytes: vec![1, 2],
                },
            );
        }
        // Written under a header that declares stream 7, then read under one
        // that does not.
        let written = write(&wider, &chunks);
        let mut bytes = write(&header(0.0, None, None), &[]);
        bytes.extend_from_slice(&written[records_at(&written)..]);
        assert!(bytes.len() > 4 * (1 << 16));
        for torn in [0, 5] {
            std::fs::write(&path, &bytes[..bytes.len() - torn]).unwrap();
            let (whole, streamed) = play_both(&path);
            assert_eq!(whole, streamed, "{at:?} {torn}");
            match (at, &streamed) {
                // A torn last record of stream 7 is only a torn tail.
                (Some(6_000), _) if torn > 0 => assert!(streamed.is_ok()),
                (Some(_), Err(e)) if e.contains("stream 7") => refused += 1,
                (None, Ok((readings, _))) => {
                    assert!(!readings.is_empty());
                    // Looked over and cleared, not left to the whole-file reader.
                    assert!(matches!(open_capture(&path), Ok(Playable::Stream(_))));
                }
                _ => panic!("{at:?} {torn}: {streamed:?}"),
            }
        }
    }
    assert_eq!(refused, 11);
}
