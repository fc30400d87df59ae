//! Fit timings: the closed form against the paper's gradient descent, on the
//! shipped one-turn recordings (`tests/data/`) and on simulations of one
//! rotation of 200, 2,000 and 200,000 samples; and the general model with
//! every effect (Levenberg-Marquardt, IRLS) on data carrying those effects;
//! and the diagnosis the daemon runs on every completed rotation (all
//! candidate effects fitted and ranked), on one rotation of 200 and 2,000.
//!
//! Run: `cargo bench --bench fit`

use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, SamplingMode, criterion_group, criterion_main};
use fieldcal::io::csv::{ColumnSpec, read_dataset};
use fieldcal::model::diagnose::diagnose;
use fieldcal::model::effects::parse_list;
use fieldcal::model::nonlinear::fit_model;
use fieldcal::model::paper::{GradientDescentOptions, closed_form, gradient_descent};
use fieldcal::sample::Dataset;
use fieldcal::sim::{SimEffects, SimSensor};

const SIZES: [usize; 3] = [200, 2_000, 200_000];
/// Every effect of the catalogue the simulation can hide.
const ALL_EFFECTS: &str = "offset,scale,cross-axis,drift,covariate:temp,cubic,outliers";

fn shipped(name: &str) -> (Vec<f64>, Vec<f64>) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    let d = read_dataset(&path, &ColumnSpec::default()).expect("shipped test data");
    (d.x, d.y)
}

/// One rotation of `n` samples (50 ms apart) of a sensor with the paper's
/// effects only.
fn paper_rotation(n: usize) -> Dataset {
    SimSensor {
        offset_x: 30.0,
        offset_y: -20.0,
        gain_x: 1.05,
        noise: 3.0,
        turn_seconds: n as f64 * 0.05,
        ..Default::default()
    }
    .simulate()
    .expect("simulation")
}

/// One rotation of `n` samples of a sensor with every effect.
fn effects_rotation(n: usize) -> Dataset {
    SimSensor {
        offset_x: 120.0,
        offset_y: -80.0,
        gain_x: 1.08,
        noise: 2.0,
        turn_seconds: n as f64 * 0.05,
        effects: SimEffects {
            cross_axis_deg: 2.0,
            drift_per_s: [0.5 * 200.0 / n as f64, -0.3 * 200.0 / n as f64],
            temp_per_c: Some([1.5, -1.0]),
            cubic: [0.01, 0.005],
            outliers: 0.01,
            ..Default::default()
        },
        ..Default::default()
    }
    .simulate_with_truth()
    .expect("simulation")
    .0
}

fn shipped_turns(c: &mut Criterion) {
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
}

fn by_size(c: &mut Criterion) {
    let options = GradientDescentOptions::default();
    let mut group = c.benchmark_group("closed form by size");
    for n in SIZES {
        let d = paper_rotation(n);
        group.bench_function(BenchmarkId::new("lsq", n), |b| {
            b.iter(|| closed_form(black_box(&d.x), black_box(&d.y)))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("paper gd by size");
    for n in SIZES {
        let d = paper_rotation(n);
        let started = Instant::now();
        let outcome = gradient_descent(&d.x, &d.y, &options, &mut |_| {});
        let once = started.elapsed();
        match &outcome {
            Ok(o) => println!(
                "paper-gd, {n} samples: {} iterations, one run {:.3} ms",
                o.iterations,
                once.as_secs_f64() * 1e3
            ),
            Err(e) => println!("paper-gd, {n} samples: {e}"),
        }
        if once > Duration::from_millis(500) {
            // Too slow for repeated samples: the single timed run above is
            // the figure.
            continue;
        }
        group.bench_function(BenchmarkId::new("paper-gd", n), |b| {
            b.iter(|| gradient_descent(black_box(&d.x), black_box(&d.y), &options, &mut |_| {}))
        });
    }
    group.finish();

    let effects = parse_list(ALL_EFFECTS).expect("effects");
    let mut group = c.benchmark_group("nonlinear, every effect, by size");
    group.sampling_mode(SamplingMode::Flat);
    group.sample_size(10);
    for n in SIZES {
        let d = effects_rotation(n);
        let started = Instant::now();
        match fit_model(&d, &effects) {
            Ok(fit) => println!(
                "nonlinear [{ALL_EFFECTS}], {n} samples: {} LM iterations, rms {:.2e}, {} flagged, one run {:.3} ms",
                fit.iterations,
                fit.rms,
                fit.flagged.len(),
                started.elapsed().as_secs_f64() * 1e3
            ),
            Err(e) => println!("nonlinear, {n} samples: {e}"),
        }
        group.bench_function(BenchmarkId::new("fit_model", n), |b| {
            b.iter(|| fit_model(black_box(&d), &effects))
        });
    }
    group.finish();
}

/// What a completed rotation costs the daemon beyond the fit: the
/// diagnosis that finds its noise floor and the `suggested` effect, run in
/// the event loop, so it bounds the pause one rotation puts on readings.
fn live_diagnosis(c: &mut Criterion) {
    let mut group = c.benchmark_group("diagnosis of one rotation");
    for n in [200, 2_000] {
        let d = paper_rotation(n);
        let started = Instant::now();
        match diagnose(&d, &[], None) {
            Ok(found) => println!(
                "diagnosis, {n} samples: {} candidates, suggested {:?}, one run {:.3} ms",
                found.candidates.len(),
                found.suggested.map(|e| e.to_string()),
                started.elapsed().as_secs_f64() * 1e3
            ),
            Err(e) => println!("diagnosis, {n} samples: {e}"),
        }
        group.bench_function(BenchmarkId::new("diagnose", n), |b| {
            b.iter(|| diagnose(black_box(&d), &[], None))
        });
    }
    group.finish();
}

/// The trust monitor's cost per calibrated reading (field and gyro checks
/// with the 2 s window full), beside the reading path's (`cargo bench
/// --bench replay` gives the whole path per reading).
fn trust_monitor(c: &mut Criterion) {
    use fieldcal::model::trust::{GyroModel, Observation, TrustLimits, TrustMonitor};
    let gyro = GyroModel {
        scale: 1.0,
        bias_deg_s: 0.0,
    };
    let limits = TrustLimits::from_rms(0.003, Some(0.2), Some(gyro));
    let readings: Vec<Observation> = (0..20_000)
        .map(|k| {
            let t = k as f64 / 20.0;
            Observation {
                time: t,
                field_ratio: 1.0 + 0.003 * (k as f64 * 2.39).sin(),
                heading_deg: (18.0 * t).rem_euclid(360.0),
                gyro_deg_s: Some(18.0),
                dip_deg: None,
                across: None,
                tilt_deg: None,
            }
        })
        .collect();
    let mut group = c.benchmark_group("trust monitor");
    group.throughput(criterion::Throughput::Elements(readings.len() as u64));
    group.bench_function("20,000 readings with a gyro", |b| {
        b.iter(|| {
            let mut monitor = TrustMonitor::new(limits);
            let mut trusted = 0usize;
            for r in &readings {
                trusted += usize::from(monitor.check(*black_box(r)).trusted);
            }
            trusted
        })
    });
    group.finish();
}

/// What the daemon does with each later rotation of a calibrated sensor
/// (`model/watch.rs`): the fit of 400 samples (a 20 s turn at 20 Hz), its
/// widened standard errors, the heading error against the calibration,
/// and the comparison. Per reading it is this over 400.
fn watch_rotation(c: &mut Criterion) {
    use fieldcal::model::calibration::Calibration;
    use fieldcal::model::fit::{FitOptions, fit_paper};
    use fieldcal::model::watch;
    let turn = |phase: f64| -> (Vec<f64>, Vec<f64>) {
        (0..400)
            .map(|k| {
                let h = (phase + k as f64 * 0.9).to_radians();
                let wobble = 0.002 * (k as f64 * 2.39).sin();
                (
                    120.0 + 1.1 * 500.0 * (1.0 + wobble) * h.cos(),
                    -80.0 + 500.0 * (1.0 - wobble) * h.sin(),
                )
            })
            .unzip()
    };
    let (x0, y0) = turn(0.0);
    let report = fit_paper(&x0, &y0, &FitOptions::default(), &mut |_| {}).expect("a turn");
    let refit = watch::paper_refit(&x0, &y0, &report);
    let stored = Calibration {
        sensor: "compass".into(),
        id: 1,
        model: "offset+scale".into(),
        params: report.calibration,
        rms: report.rms,
        coverage_deg: 360.0,
        n: 400,
        time: 0.0,
        terms: Default::default(),
        ellipsoid: None,
        se: watch::se_map(&refit.params),
        parent: None,
        history: Vec::new(),
        gyro: None,
        dip: None,
        across: None,
        level: None,
    };
    let (x, y) = turn(37.0);
    let mut group = c.benchmark_group("watch");
    group.throughput(criterion::Throughput::Elements(x.len() as u64));
    group.bench_function("one later rotation of 400 samples", |b| {
        b.iter(|| {
            let (x, y) = (black_box(&x), black_box(&y));
            let now =
                fieldcal::model::fit::fit_paper_turned(x, y, &FitOptions::default(), &mut |_| {})
                    .expect("a turn");
            let refit = watch::paper_refit(x, y, &now);
            let error = watch::heading_error_deg(
                |x, y| stored.apply(x, y),
                |x, y| fieldcal::model::calibration::apply(&now.calibration, &stored.terms, x, y),
                x,
                y,
            );
            watch::compare(&stored, &refit, error).stale()
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20).measurement_time(Duration::from_secs(3));
    targets = shipped_turns, by_size, live_diagnosis, trust_monitor, watch_rotation
}
criterion_main!(benches);
