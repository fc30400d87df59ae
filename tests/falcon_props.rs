//! Properties of the Falcon decoder that hold for every input.

use fieldcal::protocol::falcon::{FRAME_LEN, FalconDecoder, FalconFrame, HEADER};
use proptest::prelude::*;

fn arb_frame() -> impl Strategy<Value = FalconFrame> {
    (
        any::<[i16; 3]>(),
        any::<[i16; 3]>(),
        any::<[i16; 3]>(),
        any::<u16>(),
    )
        .prop_map(|(mag, accel, rate, timer)| FalconFrame {
            mag,
            accel,
            rate,
            timer,
        })
}

/// Any byte but the header.
fn headerless_byte() -> impl Strategy<Value = u8> {
    any::<u8>().prop_map(|b| if b == HEADER { 0x55 } else { b })
}

/// Feeds `bytes` cycling through `chunks` sizes; checks the held bytes stay
/// bounded after every call.
fn feed(
    dec: &mut FalconDecoder,
    bytes: &[u8],
    chunks: &[usize],
) -> Result<Vec<FalconFrame>, TestCaseError> {
    let mut out = Vec::new();
    let mut rest = bytes;
    for &n in chunks.iter().cycle() {
        if rest.is_empty() {
            break;
        }
        let (chunk, tail) = rest.split_at(n.min(rest.len()));
        dec.decode(chunk, |f| out.push(f));
        prop_assert!(dec.pending() < 2 * FRAME_LEN);
        prop_assert!(dec.pending() < FRAME_LEN);
        rest = tail;
    }
    Ok(out)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any bytes in any chunking: no panic, bounded memory, every byte
    /// accounted for, and the same result as one call with everything.
    #[test]
    fn any_bytes_any_chunking(
        bytes in proptest::collection::vec(
            prop_oneof![3 => any::<u8>(), 1 => Just(HEADER)], 0..3000),
        frames in proptest::collection::vec(arb_frame(), 0..5),
        chunks in proptest::collection::vec(1usize..=100, 1..20),
    ) {
        // Sprinkle a few real frames in so the good path is exercised too.
        let mut stream = bytes.clone();
        for (i, f) in frames.iter().enumerate() {
            let at = (i * 613) % (stream.len() + 1);
            stream.splice(at..at, f.encode());
        }
        let mut chunked = FalconDecoder::new();
        let out = feed(&mut chunked, &stream, &chunks)?;
        let mut whole = FalconDecoder::new();
        let mut out_whole = Vec::new();
        whole.decode(&stream, |f| out_whole.push(f));

        prop_assert_eq!(&out, &out_whole);
        prop_assert_eq!(chunked.counters(), whole.counters());
        prop_assert_eq!(chunked.pending(), whole.pending());
        let c = chunked.counters();
        prop_assert_eq!(c.frames_good, out.len() as u64);
        prop_assert_eq!(
            c.bytes_skipped + FRAME_LEN as u64 * c.frames_good + chunked.pending() as u64,
            stream.len() as u64
        );
    }

    /// Valid frames between garbage with no header byte all come out, in
    /// order, and exactly the garbage is skipped.
    #[test]
    fn frames_between_headerless_garbage_are_recovered(
        parts in proptest::collection::vec(
            (proptest::collection::vec(headerless_byte(), 0..40), arb_frame()), 0..40),
        tail in proptest::collection::vec(headerless_byte(), 0..40),
        chunks in proptest::collection::vec(1usize..=100, 1..20),
    ) {
        let mut stream = Vec::new();
        for (garbage, f) in &parts {
            stream.extend_from_slice(garbage);
            stream.extend_from_slice(&f.encode());
        }
        stream.extend_from_slice(&tail);
        let garbage_len = parts.iter().map(|(g, _)| g.len()).sum::<usize>() + tail.len();

        let mut dec = FalconDecoder::new();
        let out = feed(&mut dec, &stream, &chunks)?;
        let expected: Vec<FalconFrame> = parts.iter().map(|(_, f)| *f).collect();
        prop_assert_eq!(out, expected);
        let c = dec.counters();
        prop_assert_eq!(c.bytes_skipped, garbage_len as u64);
        prop_assert_eq!(c.frames_bad, 0);
        prop_assert_eq!(dec.pending(), 0);
    }

    /// decode(encode(f)) == f.
    #[test]
    fn encode_then_decode_is_identity(f in arb_frame()) {
        let bytes = f.encode();
        prop_assert_eq!(bytes.len(), FRAME_LEN);
        prop_assert_eq!(bytes[0], HEADER);
        prop_assert_eq!(FalconFrame::parse(&bytes), Ok(f));
        let mut dec = FalconDecoder::new();
        let mut out = Vec::new();
        dec.decode(&bytes, |g| out.push(g));
        prop_assert_eq!(out, vec![f]);
        prop_assert_eq!(dec.pending(), 0);
    }
}
