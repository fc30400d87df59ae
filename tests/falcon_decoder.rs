//! The Falcon decoder on long generated streams fed in random chunks, the
//! way the `ublox` crate's `parser_binary_dump_test` replays a capture.

use fieldcal::protocol::falcon::{FRAME_LEN, FalconDecoder, FalconFrame, HEADER, checksum};
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SEEDS: [u64; 5] = [1, 2, 3, 0xFA1C0, 0xDEAD_BEEF];

fn random_frame(rng: &mut impl Rng, timer: u16) -> FalconFrame {
    let mut triple = || [rng.random(), rng.random(), rng.random()];
    FalconFrame {
        mag: triple(),
        accel: triple(),
        rate: triple(),
        timer,
    }
}

/// Garbage as a line produces it: random bytes, bursts of header bytes and
/// truncated starts of other frames.
fn random_garbage(rng: &mut impl Rng) -> Vec<u8> {
    let mut g = Vec::new();
    for _ in 0..rng.random_range(1..=3) {
        match rng.random_range(0..3) {
            0 => {
                let n = rng.random_range(1..=40);
                g.extend((0..n).map(|_| rng.random::<u8>()));
            }
            1 => g.extend(std::iter::repeat_n(HEADER, rng.random_range(1..=3))),
            _ => {
                let timer = rng.random();
                let f = random_frame(rng, timer).encode();
                g.extend_from_slice(&f[..rng.random_range(1..FRAME_LEN)]);
            }
        }
    }
    g
}

/// A false frame that passes the checksum (1 chance in 65536 per false
/// header) cannot be told from a real one by any decoder, and would hide the
/// real frame it overlaps. Generated garbage must not contain one, so a
/// header in `garbage` whose 23-byte window (running into `next`, the bytes
/// that follow) checks out is replaced.
fn defuse(garbage: &mut [u8], next: &[u8]) {
    loop {
        let joined: Vec<u8> = garbage.iter().chain(next).copied().collect();
        let valid = (0..garbage.len()).find(|&q| {
            joined[q] == HEADER
                && joined.len() >= q + FRAME_LEN
                && checksum(&joined[q..q + FRAME_LEN - 2])
                    == u16::from_be_bytes([joined[q + 21], joined[q + 22]])
        });
        match valid {
            Some(q) => garbage[q] = 0x55,
            None => return,
        }
    }
}

struct Stream {
    bytes: Vec<u8>,
    frames: Vec<FalconFrame>,
    /// Start of every garbage byte in `bytes`, for exact expectations.
    garbage_at: Vec<usize>,
}

/// `n` valid frames with a regular timer (crossing the wrap), garbage
/// spliced before about a third of them and after the last.
fn build_stream(rng: &mut impl Rng, n: usize, step: u16) -> Stream {
    let frames: Vec<FalconFrame> = {
        let t0: u16 = rng.random();
        (0..n)
            .map(|i| random_frame(rng, t0.wrapping_add((i as u16).wrapping_mul(step))))
            .collect()
    };
    let mut bytes = Vec::new();
    let mut garbage_at = Vec::new();
    let mut push_garbage = |bytes: &mut Vec<u8>, g: &[u8]| {
        garbage_at.extend(bytes.len()..bytes.len() + g.len());
        bytes.extend_from_slice(g);
    };
    for f in &frames {
        let enc = f.encode();
        if rng.random_range(0..3) == 0 {
            let mut g = random_garbage(rng);
            defuse(&mut g, &enc);
            push_garbage(&mut bytes, &g);
        }
        bytes.extend_from_slice(&enc);
    }
    let mut tail = random_garbage(rng);
    defuse(&mut tail, &[]);
    push_garbage(&mut bytes, &tail);
    Stream {
        bytes,
        frames,
        garbage_at,
    }
}

/// Feeds `bytes` in random chunks of 1..=100 bytes.
fn feed_chunked(dec: &mut FalconDecoder, bytes: &[u8], rng: &mut impl Rng) -> Vec<FalconFrame> {
    let mut out = Vec::new();
    let mut rest = bytes;
    while !rest.is_empty() {
        let n = rng.random_range(1..=100).min(rest.len());
        let (chunk, tail) = rest.split_at(n);
        dec.decode(chunk, |f| out.push(f));
        assert!(dec.pending() < FRAME_LEN);
        rest = tail;
    }
    out
}

#[test]
fn every_frame_survives_garbage_and_chunking() {
    for seed in SEEDS {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let stream = build_stream(&mut rng, 2000, 7);
        let mut dec = FalconDecoder::new();
        let out = feed_chunked(&mut dec, &stream.bytes, &mut rng);
        assert_eq!(out.len(), stream.frames.len(), "seed {seed}");
        assert!(out == stream.frames, "seed {seed}: frames differ");

        // Exact expectations: every garbage header with a full window after
        // it is one bad candidate; a garbage header too close to the end
        // stalls the decoder, and the rest stays pending.
        let len = stream.bytes.len();
        let headers: Vec<usize> = stream
            .garbage_at
            .iter()
            .copied()
            .filter(|&i| stream.bytes[i] == HEADER)
            .collect();
        let bad = headers.iter().filter(|&&i| i + FRAME_LEN <= len).count();
        let pending = headers
            .iter()
            .find(|&&i| i + FRAME_LEN > len)
            .map_or(0, |&i| len - i);
        let c = dec.counters();
        assert_eq!(c.frames_good, 2000, "seed {seed}");
        assert_eq!(c.frames_bad, bad as u64, "seed {seed}");
        assert_eq!(dec.pending(), pending, "seed {seed}");
        assert_eq!(
            c.bytes_skipped,
            (stream.garbage_at.len() - pending) as u64,
            "seed {seed}"
        );
        assert_eq!(
            c.bytes_skipped + FRAME_LEN as u64 * c.frames_good + dec.pending() as u64,
            len as u64
        );
        assert_eq!(dec.ticks_per_frame(), Some(7));
        assert_eq!(c.frames_lost, 0, "seed {seed}");
        assert_eq!(c.timer_resets, 0, "seed {seed}");
        // The idle timeout drops what is left, as skipped.
        assert_eq!(dec.discard_partial(), pending);
        assert_eq!(dec.counters().bytes_skipped, stream.garbage_at.len() as u64);
    }
}

#[test]
fn headerless_garbage_is_skipped_byte_for_byte() {
    for seed in SEEDS {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let garbage: Vec<u8> = (0..50_000)
            .map(|_| rng.random::<u8>())
            .filter(|&b| b != HEADER)
            .collect();
        let mut dec = FalconDecoder::new();
        assert!(feed_chunked(&mut dec, &garbage, &mut rng).is_empty());
        let c = dec.counters();
        assert_eq!(c.bytes_skipped, garbage.len() as u64, "seed {seed}");
        assert_eq!(c.frames_bad, 0);
        assert_eq!(c.frames_good, 0);
        assert_eq!(dec.pending(), 0);
    }
}

#[test]
fn dropped_frames_are_counted_from_the_timer() {
    for seed in SEEDS {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let step = rng.random_range(1..=500u16);
        let stream = build_stream(&mut rng, 2000, step);
        // Drop about 5 % of the frames (not among the first 9, which teach
        // the default decoder the step) by cutting them out of the stream.
        let mut kept = Vec::new();
        let mut bytes = Vec::new();
        let mut lost = 0u64;
        let mut pos = 0;
        for (i, f) in stream.frames.iter().enumerate() {
            let enc = f.encode();
            let at = pos
                + stream.bytes[pos..]
                    .windows(FRAME_LEN)
                    .position(|w| w == enc)
                    .expect("frame is in the stream");
            let garbage = &stream.bytes[pos..at];
            pos = at + FRAME_LEN;
            // A dropped frame takes the garbage before it along: that garbage
            // was only checked for false frames against this frame.
            if i >= 9 && i + 1 < stream.frames.len() && rng.random_range(0..20) == 0 {
                lost += 1;
            } else {
                bytes.extend_from_slice(garbage);
                bytes.extend_from_slice(&enc);
                kept.push(*f);
            }
        }
        bytes.extend_from_slice(&stream.bytes[pos..]);

        for mut dec in [
            FalconDecoder::new(),
            FalconDecoder::with_ticks_per_frame(step),
        ] {
            let out = feed_chunked(&mut dec, &bytes, &mut rng);
            assert!(out == kept, "seed {seed}: frames differ");
            let c = dec.counters();
            assert_eq!(c.frames_lost, lost, "seed {seed}, step {step}");
            assert_eq!(c.timer_resets, 0, "seed {seed}");
            assert_eq!(dec.ticks_per_frame(), Some(step));
        }
    }
}

/// Throughput on a capture with about 1 % garbage, fed in 4 KiB reads.
/// `cargo test --release --test falcon_decoder -- --ignored --nocapture`
#[test]
#[ignore = "measurement, run in release"]
fn throughput() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let mut bytes = Vec::new();
    let mut garbage = 0usize;
    let mut timer = 0u16;
    while bytes.len() < 64 << 20 {
        if rng.random_range(0..10) == 0 {
            let n = rng.random_range(1..=4);
            garbage += n;
            bytes.extend((0..n).map(|_| rng.random::<u8>()));
        }
        bytes.extend_from_slice(&random_frame(&mut rng, timer).encode());
        timer = timer.wrapping_add(1);
    }
    let mut best = f64::INFINITY;
    let mut frames = 0u64;
    for _ in 0..5 {
        let mut dec = FalconDecoder::new();
        let start = std::time::Instant::now();
        for chunk in bytes.chunks(4096) {
            dec.decode(std::hint::black_box(chunk), |f| {
                std::hint::black_box(f);
            });
        }
        best = best.min(start.elapsed().as_secs_f64());
        frames = dec.counters().frames_good;
    }
    println!(
        "{} MB, {:.2} % garbage, {} frames: {:.0} MB/s",
        bytes.len() >> 20,
        100.0 * garbage as f64 / bytes.len() as f64,
        frames,
        bytes.len() as f64 / best / 1e6
    );
}
