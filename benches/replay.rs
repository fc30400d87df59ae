//! `fieldcal replay --speed max` of a long capture through the daemon's
//! whole pipeline (decoder, rotation buffer, fits, acceptance, JSON lines)
//! to a null sink, in readings per second.
//!
//! Run: `cargo bench --bench replay`

use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use fieldcal::capture::{CaptureFile, Playable, parse_capture};
use fieldcal::daemon::config::{Config, parse};
use fieldcal::daemon::run::replay_through_pipeline;

#[path = "support/mod.rs"]
mod support;
use fieldcal::source::replay::Speed;

/// Turns of 200 frames (50 ms apart): 500 turns = 100,000 frames.
const TURNS: f64 = 500.0;

fn pipeline_config() -> Config {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/pipeline.toml");
    let text = std::fs::read_to_string(&path).expect("tests/data/pipeline.toml");
    parse(&text, &path).expect("pipeline configuration")
}

fn long_capture() -> CaptureFile {
    let bytes = support::write_capture(Vec::new(), &support::compass(TURNS));
    parse_capture(&bytes, "long.fcap").expect("capture parses")
}

fn replay(c: &mut Criterion) {
    let config = pipeline_config();
    let mut capture = Playable::Whole(long_capture());
    let mut run = || {
        replay_through_pipeline(
            &config,
            &mut capture,
            "long.fcap",
            None,
            Speed::Max,
            &mut std::io::sink(),
        )
        .expect("replay")
    };
    let started = Instant::now();
    let summary = run();
    let once = started.elapsed().as_secs_f64();
    let readings = summary.readings;
    println!(
        "replay --speed max, {readings} readings ({} chunks): one run {:.1} ms, {:.2} million readings/s",
        summary.chunks,
        once * 1e3,
        readings as f64 / once / 1e6
    );
    let mut group = c.benchmark_group("replay through the pipeline");
    group.throughput(Throughput::Elements(readings));
    group.sample_size(10);
    group.bench_function("speed max, 100k frames, JSON to a null sink", |b| {
        b.iter(&mut run)
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().measurement_time(Duration::from_secs(3));
    targets = replay
}
criterion_main!(benches);
