//! A turn, or no calibration: the turn gate on real recordings, on simulated
//! readings that never turned (through the binary), and on a randomised
//! sweep of real turns.

mod common;

use std::fs;

use common::run;
use common::table::Table;
use fieldcal::model::FitError;
use fieldcal::model::turn::{MAX_HOLE_FRACTION, RADIUS_OVER_NOISE, TurnCheck, check_turn};
use fieldcal::sim::SimSensor;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Uniform};

const RUNS: [&str; 4] = [
    "rotate-360ccw-around-x-pointing-forward",
    "rotate-360ccw-around-y-pointing-left",
    "rotate-360ccw-around-z-pointing-up",
    "tilt-sphere",
];

fn table(run: &str, file: &str) -> Table {
    Table::sunsided(run, file)
}

fn is_no_turn(e: &FitError) -> bool {
    matches!(
        e,
        FitError::NotTurning { .. } | FitError::DiscNotRing { .. } | FitError::NoFullTurn { .. }
    )
}

fn figures(c: &TurnCheck) -> String {
    format!(
        "spread/noise {:.1}, hole {:.1} %, coverage {:.0}° ({} of {} samples on the ring)",
        c.spread_over_noise,
        100.0 * c.hole_fraction,
        c.coverage.covered_deg,
        c.ring_samples,
        c.n
    )
}

/// Length of a window of a still hand, in seconds, and the most the board
/// may turn in it, by the gyro: the path ∫|ω| dt of the MPU-6050's three
/// rates. 6° in 0.5 s is 12 °/s on average, within the MPU-6050's zero-rate
/// offset tolerance (±20 °/s, datasheet): a hand at rest, not a turn.
const STILL_WINDOW_S: f64 = 0.5;
const STILL_PATH_DEG: f64 = 6.0;

/// The first and last half second of each run whose gyro says the board
/// was still (the hand before it starts and after it stops), found on the
/// gyro's clock and cut from each file by time.
fn still_windows() -> Vec<(&'static str, f64, f64, f64)> {
    let mut found = Vec::new();
    for run in RUNS {
        let imu = table(run, "mpu6050.csv");
        let t = imu.col("t_s");
        let g: Vec<[f64; 3]> = {
            let (gx, gy, gz) = (imu.col("gyro_x"), imu.col("gyro_y"), imu.col("gyro_z"));
            (0..t.len()).map(|i| [gx[i], gy[i], gz[i]]).collect()
        };
        let end = t[t.len() - 1];
        for (from, to) in [
            (t[0], t[0] + STILL_WINDOW_S),
            (end - STILL_WINDOW_S, end + 1.0),
        ] {
            let path: f64 = (1..t.len())
                .filter(|&i| t[i] >= from && t[i] < to)
                .map(|i| (t[i] - t[i - 1]) * g[i].iter().map(|r| r * r).sum::<f64>().sqrt())
                .sum();
            if path < STILL_PATH_DEG {
                found.push((run, from, to, path));
            }
        }
    }
    found
}

#[test]
fn every_still_stretch_of_the_real_recordings_is_refused() {
    let windows = still_windows();
    // The end of every run, and the start of the y run (5.7° of path).
    assert!(windows.len() >= 5, "{windows:?}");
    let mut refused = 0;
    for (run, from, to, path) in &windows {
        let mag = table(run, "hmc5883l_mag.csv");
        let imu = table(run, "mpu6050.csv");
        let pairs = [
            (&mag, "mag_x", "mag_y"),
            (&mag, "mag_x", "mag_z"),
            (&mag, "mag_y", "mag_z"),
            (&imu, "acc_x", "acc_y"),
            (&imu, "acc_x", "acc_z"),
            (&imu, "acc_y", "acc_z"),
        ];
        for (file, a, b) in pairs {
            let (x, y) = file.pair(a, b, *from, *to);
            assert!(x.len() >= 30, "{run} {a}/{b}: {} samples", x.len());
            let err = check_turn(&x, &y, 300.0).unwrap_err();
            eprintln!("{run} {from:.2}-{to:.2} s (gyro path {path:.1}°) {a}/{b}: {err}");
            assert!(is_no_turn(&err), "{run} {a}/{b}: {err:?}");
            // Still readings are refused as a cloud, not only for coverage.
            assert!(
                matches!(err, FitError::NotTurning { .. }),
                "{run} {a}/{b}: {err:?}"
            );
            refused += 1;
        }
    }
    assert_eq!(refused, windows.len() * 6);
}

#[test]
fn the_tumble_fills_a_disc_and_is_refused() {
    let mag = table("tilt-sphere", "hmc5883l_mag.csv");
    let imu = table("tilt-sphere", "mpu6050.csv");
    let (x, y) = mag.pair("mag_x", "mag_y", f64::MIN, f64::MAX);
    let err = check_turn(&x, &y, 300.0).unwrap_err();
    match &err {
        FitError::DiscNotRing { percent, .. } => {
            assert!(*percent > 100.0 * MAX_HOLE_FRACTION, "{percent}")
        }
        other => panic!("tilt-sphere mag_x/mag_y: {other:?}"),
    }
    assert!(err.to_string().contains("fill a disc"), "{err}");
    // Every other pair of the tumble: report what the gate sees; none of
    // them is a turn in one plane.
    for (file, a, b) in [
        (&mag, "mag_x", "mag_z"),
        (&mag, "mag_y", "mag_z"),
        (&imu, "acc_x", "acc_y"),
        (&imu, "acc_x", "acc_z"),
        (&imu, "acc_y", "acc_z"),
    ] {
        let (x, y) = file.pair(a, b, f64::MIN, f64::MAX);
        let outcome = check_turn(&x, &y, 300.0);
        eprintln!("tilt-sphere {a}/{b}: {outcome:?}");
        assert!(outcome.is_err(), "tilt-sphere {a}/{b}: {outcome:?}");
    }
}

#[test]
fn the_real_turning_axes_pass_the_gate() {
    for (run, file, a, b) in [
        (
            "rotate-360ccw-around-z-pointing-up",
            "hmc5883l_mag.csv",
            "mag_x",
            "mag_z",
        ),
        (
            "rotate-360ccw-around-x-pointing-forward",
            "hmc5883l_mag.csv",
            "mag_y",
            "mag_z",
        ),
        (
            "rotate-360ccw-around-x-pointing-forward",
            "mpu6050.csv",
            "acc_y",
            "acc_z",
        ),
        (
            "rotate-360ccw-around-y-pointing-left",
            "mpu6050.csv",
            "acc_x",
            "acc_z",
        ),
    ] {
        let (x, y) = table(run, file).pair(a, b, f64::MIN, f64::MAX);
        let c = check_turn(&x, &y, 300.0).unwrap_or_else(|e| panic!("{run} {a}/{b}: {e}"));
        eprintln!("{run} {a}/{b}: {}", figures(&c));
        assert!(c.spread_over_noise >= RADIUS_OVER_NOISE, "{c:?}");
    }
    // The y run's magnetometer turns in a tilted plane: mag_x/mag_z is a
    // thin ellipse (a = 0.17) whose wobble fills it once calibrated (11 %
    // of the readings inside half the radius), while mag_x/mag_y is the
    // plane it turned in.
    let mag = table("rotate-360ccw-around-y-pointing-left", "hmc5883l_mag.csv");
    let (x, y) = mag.pair("mag_x", "mag_z", f64::MIN, f64::MAX);
    let outcome = check_turn(&x, &y, 300.0);
    eprintln!("y run mag_x/mag_z: {outcome:?}");
    assert!(
        matches!(outcome, Err(FitError::DiscNotRing { .. })),
        "{outcome:?}"
    );
    let (x, y) = mag.pair("mag_x", "mag_y", f64::MIN, f64::MAX);
    let c = check_turn(&x, &y, 300.0).unwrap();
    eprintln!("y run mag_x/mag_y: {}", figures(&c));
}

fn write(dir: &tempfile::TempDir, name: &str, points: &[(f64, f64)]) -> String {
    let mut text = String::from("t,x,y\n");
    for (i, (x, y)) in points.iter().enumerate() {
        text.push_str(&format!("{},{x},{y}\n", i as f64 * 0.02));
    }
    let path = dir.path().join(name);
    fs::write(&path, text).unwrap();
    path.to_str().unwrap().to_string()
}

/// A turn of `arc_deg` (or `heading` per sample) about (40, -10), radius 500.
fn on_ring(heading_deg: impl Fn(usize) -> f64, n: usize, noise: f64) -> Vec<(f64, f64)> {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let g = Normal::new(0.0, noise.max(1e-300)).unwrap();
    (0..n)
        .map(|i| {
            let h = heading_deg(i).to_radians();
            (
                500.0 * h.cos() + 40.0 + g.sample(&mut rng),
                450.0 * h.sin() - 10.0 + g.sample(&mut rng),
            )
        })
        .collect()
}

/// Each case is refused by `fit` (both solvers), `fit --effects` and
/// `diagnose` with exit 1 and the gate's message.
#[test]
fn readings_that_never_turned_are_refused_by_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let still = Normal::new(0.0, 0.3).unwrap();
    let cloud: Vec<(f64, f64)> = (0..400)
        .map(|_| {
            (
                (120.0_f64 + still.sample(&mut rng)).round(),
                (-455.0_f64 + still.sample(&mut rng)).round(),
            )
        })
        .collect();
    let line: Vec<(f64, f64)> = (0..300)
        .map(|i| (i as f64 * 2.0, i as f64 + still.sample(&mut rng)))
        .collect();
    type Case = (&'static str, Vec<(f64, f64)>, &'static str);
    let cases: Vec<Case> = vec![
        ("still.csv", cloud, "the readings form a cloud"),
        (
            "arc.csv",
            on_ring(|i| i as f64 * 120.0 / 300.0, 300, 2.0),
            "the readings go only 120° round",
        ),
        (
            "sway.csv",
            on_ring(|i| 40.0 * (i as f64 * 0.05).sin(), 600, 2.0),
            "the readings go only 8",
        ),
        ("line.csv", line, "the readings go only"),
        (
            "five.csv",
            on_ring(|i| i as f64 * 72.0, 5, 0.0),
            "5 samples are too few to show a turn",
        ),
    ];
    for (name, points, expected) in cases {
        let file = write(&dir, name, &points);
        for args in [
            vec!["fit", &file],
            vec!["fit", &file, "--solver", "paper-gd"],
            vec!["fit", &file, "--effects", "cross-axis"],
            vec!["diagnose", &file],
        ] {
            let r = run(&args);
            assert_eq!(r.code, Some(1), "{args:?}: {}{}", r.stdout, r.stderr);
            assert!(r.stderr.contains(name), "{args:?}: {}", r.stderr);
            assert!(r.stderr.contains(expected), "{args:?}: {}", r.stderr);
            assert!(r.stdout.is_empty(), "{args:?}: {}", r.stdout);
        }
    }
}

/// Real turns of simulated sensors pass the gate: noise up to 8 % of the
/// field (12.5 times below it, above the gate's 10), gains 0.6 to 1.6, offsets up to 5 fields, 50 to 20,000 samples,
/// 1 to 3 turns, at least 15 samples a turn.
#[test]
fn real_turns_pass_the_gate_in_a_randomised_sweep() {
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    let unit = Uniform::new(0.0, 1.0).unwrap();
    let cases = 2000;
    let mut passed = 0;
    let mut failures = Vec::new();
    for seed in 0..cases {
        let mut u = || unit.sample(&mut rng);
        let field = 1000.0;
        let turns = 1.0 + 2.0 * u();
        // Log-uniform sample count, and at least 15 samples a turn.
        let n = (50.0 * (400f64).powf(u())).round();
        let n = n.max((15.0 * turns).ceil());
        let turn_seconds = 10.0;
        let period = turns * turn_seconds / n;
        let (gain_x, gain_y) = (0.6 + u(), 0.6 + u());
        let sensor = SimSensor {
            field,
            gain_x,
            gain_y,
            offset_x: 5.0 * field * (2.0 * u() - 1.0),
            offset_y: 5.0 * field * (2.0 * u() - 1.0),
            // Up to 8 % of the field as the sensor reads it (its smaller
            // gain), in raw counts.
            noise: 0.08 * field * gain_x.min(gain_y) * u(),
            period,
            turns,
            turn_seconds,
            start_heading_deg: 360.0 * u(),
            seed,
            ..Default::default()
        };
        let data = sensor.simulate().unwrap();
        match check_turn(&data.x, &data.y, 300.0) {
            Ok(_) => passed += 1,
            Err(e) => failures.push(format!("{sensor:?}: {e}")),
        }
    }
    let rate = passed as f64 / cases as f64;
    eprintln!(
        "real turns passing the gate: {passed} of {cases} ({:.2} %)",
        100.0 * rate
    );
    for f in failures.iter().take(5) {
        eprintln!("  {f}");
    }
    assert!(rate >= 0.995, "{rate}: {failures:#?}");
}
