//! Falcon-GX stream decoder: any bytes, cut into chunks of a size taken from
//! the first byte, must decode without a panic and hold fewer than one
//! frame's worth of bytes between calls.
#![no_main]

use fieldcal::protocol::falcon::{FRAME_LEN, FalconDecoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(first % 64) + 1;
    let mut decoder = FalconDecoder::new();
    let mut frames = 0usize;
    for piece in rest.chunks(chunk) {
        decoder.decode(piece, |_| frames += 1);
        assert!(
            decoder.pending() < FRAME_LEN,
            "pending {}",
            decoder.pending()
        );
    }
    assert!(frames <= rest.len() / FRAME_LEN);
    let _ = decoder.counters();
    decoder.discard_partial();
    assert_eq!(decoder.pending(), 0);
});
