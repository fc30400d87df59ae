//! The Falcon-GX decoder on a long simulated capture with 1 % garbage
//! between frames: throughput in bytes (criterion) and frames per second
//! (printed), fed whole and in 4 KiB reads as a serial port delivers them.
//!
//! Run: `cargo bench --bench decoder`

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use fieldcal::protocol::falcon::FalconDecoder;

#[path = "support/mod.rs"]
mod support;

/// Turns of 200 frames: 900 turns = 180,000 frames, about 4.2 MB.
const TURNS: f64 = 900.0;

fn capture_bytes() -> Vec<u8> {
    let (_, chunks) = support::falcon_chunks(&support::compass(TURNS));
    chunks.into_iter().flat_map(|c| c.bytes).collect()
}

fn decode_all(bytes: &[u8], read: usize) -> u64 {
    let mut decoder = FalconDecoder::new();
    let mut frames = 0u64;
    for chunk in bytes.chunks(read) {
        decoder.decode(chunk, |f| {
            black_box(f);
            frames += 1;
        });
    }
    frames
}

fn decoder(c: &mut Criterion) {
    let bytes = capture_bytes();
    let mut group = c.benchmark_group("falcon decoder, 1% garbage");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    for (label, read) in [("whole", bytes.len()), ("4KiB reads", 4096)] {
        let frames = decode_all(&bytes, read);
        // A plain timed loop for frames/s, next to criterion's bytes/s.
        let runs = 20;
        let started = Instant::now();
        for _ in 0..runs {
            black_box(decode_all(black_box(&bytes), read));
        }
        let per_run = started.elapsed().as_secs_f64() / runs as f64;
        println!(
            "decoder ({label}): {:.2} MB capture, {frames} frames, {:.0} MB/s, {:.1} million frames/s",
            bytes.len() as f64 / 1e6,
            bytes.len() as f64 / per_run / 1e6,
            frames as f64 / per_run / 1e6
        );
        group.bench_function(BenchmarkId::new("decode", label), |b| {
            b.iter(|| decode_all(black_box(&bytes), read))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(Duration::from_secs(3));
    targets = decoder
}
criterion_main!(benches);
