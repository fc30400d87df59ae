//! Fit timings: the closed form against the paper's gradient descent, on the
//! shipped one-turn recordings (`tests/data/`) and on larger simulations.
//!
//! Run: `cargo bench --bench fit`

use std::hint::black_box;
use std::path::Path;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use fieldcal::io::csv::{ColumnSpec, read_dataset};
use fieldcal::model::paper::{GradientDescentOptions, closed_form, gradient_descent};
use fieldcal::sim::SimSensor;

fn shipped(name: &str) -> (Vec<f64>, Vec<f64>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    let d = read_dataset(&path, &ColumnSpec::default()).expect("shipped test data");
    (d.x, d.y)
}

fn solvers(c: &mut Criterion) {
    let mut group = c.benchmark_group("one turn, 200 samples");
    for name in ["sim_mild.csv", "sim_strong.csv"] {
        let (x, y) = shipped(name);
        let options = GradientDescentOptions::default();
        let iterations = gradient_descent(&x, &y, &options, &mut |_| {})
            .map(|o| o.iterations)
            .unwrap_or(0);
        println!("{name}: the paper's gradient descent takes {iterations} iterations");
        group.bench_function(BenchmarkId::new("lsq", name), |b| {
            b.iter(|| closed_form(black_box(&x), black_box(&y)))
        });
        group.bench_function(BenchmarkId::new("paper-gd", name), |b| {
            b.iter(|| gradient_descent(black_box(&x), black_box(&y), &options, &mut |_| {}))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("closed form by size");
    for n in [200usize, 2_000, 200_000] {
        let sensor = SimSensor {
            offset_x: 30.0,
            offset_y: -20.0,
            gain_x: 1.05,
            noise: 3.0,
            turn_seconds: n as f64 * 0.05,
            ..Default::default()
        };
        let d = sensor.simulate().expect("simulation");
        group.bench_function(BenchmarkId::new("lsq", n), |b| {
            b.iter(|| closed_form(black_box(&d.x), black_box(&d.y)))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(std::time::Duration::from_secs(3));
    targets = solvers
}
criterion_main!(benches);
