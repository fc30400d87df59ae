//! `diagnose` across sample counts, from 50 to 2,000,000: with no hidden
//! effect nothing is suggested, and each effect of the catalogue (both
//! non-linearities included) is still suggested first where it lowers the
//! rms by more than a quarter. Sensors are drawn as in diagnose_sweep.rs
//! (fields of 0.5 to 30,000, gains 0.6 to 1.6, offsets up to two fields,
//! noise 0.05 % to 1 % of the field, one to three turns), at each count.
//!
//! Why these case counts suffice (measured on 2 cores of a test build, with
//! other builds running: the clean half takes 100 s, the effects half about
//! 3 minutes more; one diagnosis of 2,000,000 samples 40 to 70 s, of
//! 200,000 5 to 9 s):
//! - Up to 10,000 samples a false alarm is a matter of chance (the noise
//!   part of ΔBIC is a χ² of a couple of degrees of freedom), so the rate
//!   is measured: 100 clean sensors per count with at most 3 alarms. Were
//!   the true rate 8 %, that would pass with probability below 4 %
//!   (binomial), so the bound holds the rate near the 3 % asked.
//! - At 200,000 and 2,000,000 what could fire is not chance but the bias
//!   noise puts into |s|/r - 1: it grows as n times the noise's square and
//!   is the same in every seed of a configuration (its seed-to-seed spread
//!   is a few units of ΔBIC against hundreds to thousands of bias, as
//!   measured on one sensor before the materiality gate: -196 to -213 at 200,000 and
//!   -2306 to -2541 at 2,000,000). A configuration therefore fails in every
//!   seed or in none, and a handful of cases show it, provided they cover
//!   the configurations where the bias is largest: the corners of the
//!   range (1 % noise, gains 2.7:1 apart, one and three turns) and the
//!   quietest, not random draws. Any alarm there fails the test.
//! - Effects: at counts up to 10,000, 15 (4 at 10,000) random sensors per
//!   effect and count; at 200,000 one per effect. A detectable effect's
//!   ΔBIC grows with n while its rivals' stay in proportion, so which one
//!   wins is settled at 200,000 as at 2,000,000; the two non-linearities,
//!   which differ only by the turn's centre, are also tried at 2,000,000.
//!   Pooled per effect (about 55 cases) and per count (about 100 below
//!   200,000), at least 97 % must be suggested first.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use fieldcal::model::diagnose::diagnose;
use fieldcal::model::effects::{Effect, PAPER};
use fieldcal::model::nonlinear::fit_model;
use fieldcal::sim::{SimEffects, SimSensor};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The effects of the catalogue, as hidden in the simulator.
fn catalogue() -> Vec<Effect> {
    vec![
        Effect::CrossAxis,
        Effect::Drift,
        Effect::Covariate("temp".into()),
        Effect::Covariate("current".into()),
        Effect::Cubic,
        Effect::CubicCentred,
        Effect::Outliers,
    ]
}

/// How a sensor is chosen: at random, or at a fixed corner of the range.
#[derive(Clone, Copy, Debug)]
enum Draw {
    Random,
    /// Noise as a fraction of the field, gain_x, gain_y, turns.
    Corner(f64, f64, f64, f64),
}

/// The corners where the noise's bias in |s|/r - 1 is largest (1 % noise,
/// gains far apart, one and three turns), and the quietest sensor.
const CORNERS: [Draw; 4] = [
    Draw::Corner(0.01, 0.6, 1.6, 1.0),
    Draw::Corner(0.01, 1.6, 0.6, 3.0),
    Draw::Corner(0.01, 1.0, 1.0, 2.0),
    Draw::Corner(0.0005, 1.0, 1.2, 1.0),
];

/// One diagnosis to run.
#[derive(Clone, Debug)]
struct Job {
    samples: usize,
    hidden: Option<Effect>,
    draw: Draw,
    seed: u64,
}

/// A sensor of `samples` samples with `hidden` in it, drawn from `seed`.
fn sensor(job: &Job) -> SimSensor {
    let mut rng = ChaCha8Rng::seed_from_u64(job.seed);
    let field = [0.5, 1000.0, 30_000.0][rng.random_range(0..3)];
    let (noise, gain_x, gain_y, turns) = match job.draw {
        Draw::Random => (
            [0.0005, 0.002, 0.005, 0.01][rng.random_range(0..4)],
            rng.random_range(0.6..1.6),
            rng.random_range(0.6..1.6),
            // Fewer than 50 samples a turn is not a turn's worth of headings.
            if job.samples < 150 {
                1.0
            } else {
                [1.0, 1.0, 2.0, 3.0][rng.random_range(0..4)]
            },
        ),
        Draw::Corner(noise, gx, gy, turns) => (noise, gx, gy, turns),
    };
    // A non-linearity as datasheets give it (0.1-0.5 % at full scale;
    // `diagnose` believes up to 1 % without a gyro) shows only on a quiet
    // sensor; against 1 % noise it would never be detectable.
    let cubic = matches!(job.hidden, Some(Effect::Cubic | Effect::CubicCentred));
    let noise = if cubic && matches!(job.draw, Draw::Random) {
        [0.0002, 0.0005, 0.001][rng.random_range(0..3)]
    } else {
        noise
    } * field;
    let turn_seconds = [5.0, 10.0, 20.0][rng.random_range(0..3)];
    let run_s = turns * turn_seconds;
    let both = rng.random_bool(0.5);
    let pair = |value: f64, rng: &mut ChaCha8Rng| -> [f64; 2] {
        if both {
            [value, -0.6 * value]
        } else if rng.random_bool(0.5) {
            [value, 0.0]
        } else {
            [0.0, value]
        }
    };
    let size = rng.random_range(1.0..30.0);
    let mut effects = SimEffects::default();
    match &job.hidden {
        None => {}
        Some(Effect::CrossAxis) => effects.cross_axis_deg = rng.random_range(0.3..10.0),
        Some(Effect::Drift) => effects.drift_per_s = pair(size * noise / run_s, &mut rng),
        Some(Effect::Covariate(c)) if c == "temp" => {
            effects.temp_per_c = Some(pair(size * noise / 10.0, &mut rng))
        }
        Some(Effect::Covariate(_)) => {
            effects.current_per_a = Some(pair(size * noise / 2.0, &mut rng))
        }
        Some(Effect::Cubic) => effects.cubic = pair(rng.random_range(0.001..0.005), &mut rng),
        Some(Effect::CubicCentred) => {
            let size = rng.random_range(0.001..0.005);
            effects.cubic_centred = [if rng.random_bool(0.5) { size } else { -size }; 2];
        }
        Some(Effect::Outliers) => effects.outliers = rng.random_range(0.01..0.05),
        Some(other) => panic!("{other} is not hidden by this sweep"),
    }
    SimSensor {
        field,
        gain_x,
        gain_y,
        offset_x: rng.random_range(-2.0..2.0) * field,
        offset_y: rng.random_range(-2.0..2.0) * field,
        noise,
        period: run_s / job.samples as f64,
        turns,
        turn_seconds,
        start_heading_deg: rng.random_range(0.0..360.0),
        seed: rng.random(),
        effects,
    }
}

/// What one diagnosis found.
#[derive(Debug)]
enum Outcome {
    /// Clean: what was suggested, if anything.
    Clean(Option<Effect>),
    /// Hidden effect: whether it lowers the rms by more than a quarter, and
    /// what was suggested first.
    Hidden {
        detectable: bool,
        suggested: Option<Effect>,
        /// The rival the diagnosis names beside the suggestion when the
        /// recording cannot tell the two apart.
        close_second: Option<Effect>,
        /// The hidden effect's evidence, as the diagnosis judged it.
        evidence: String,
    },
}

fn run(job: &Job) -> (Outcome, f64) {
    let data = sensor(job).simulate().expect("simulation");
    assert_eq!(data.len(), job.samples, "{job:?}");
    let started = Instant::now();
    let d = diagnose(&data, &[], None).unwrap_or_else(|e| panic!("{job:?}: {e}"));
    let seconds = started.elapsed().as_secs_f64();
    let outcome = match &job.hidden {
        None => Outcome::Clean(d.suggested),
        Some(effect) => {
            let mut with = PAPER.to_vec();
            with.push(effect.clone());
            with.sort();
            let detectable =
                fit_model(&data, &with).is_ok_and(|fit| d.baseline.rms > 1.25 * fit.rms);
            let evidence = d
                .candidates
                .iter()
                .find(|c| &c.effect == effect)
                .map_or("not a candidate".into(), |c| c.evidence.clone());
            Outcome::Hidden {
                detectable,
                suggested: d.suggested,
                close_second: d.close_second,
                evidence,
            }
        }
    };
    (outcome, seconds)
}

/// The jobs: per count, clean cases and cases of each effect.
fn jobs() -> Vec<Job> {
    let mut jobs = Vec::new();
    let mut seed = 0x5a3b_1e00u64;
    let mut next = || {
        seed += 1;
        seed
    };
    // (samples, clean random cases, cases per effect)
    for (samples, clean, per_effect) in [
        (50, 100, 15),
        (200, 100, 15),
        (1_000, 100, 15),
        (10_000, 30, 4),
        (200_000, 2, 1),
        (2_000_000, 0, 0),
    ] {
        for _ in 0..clean {
            jobs.push(Job {
                samples,
                hidden: None,
                draw: Draw::Random,
                seed: next(),
            });
        }
        for effect in catalogue() {
            for _ in 0..per_effect {
                jobs.push(Job {
                    samples,
                    hidden: Some(effect.clone()),
                    draw: Draw::Random,
                    seed: next(),
                });
            }
        }
    }
    for samples in [200_000, 2_000_000] {
        for draw in CORNERS {
            jobs.push(Job {
                samples,
                hidden: None,
                draw,
                seed: next(),
            });
        }
    }
    for effect in [Effect::Cubic, Effect::CubicCentred] {
        jobs.push(Job {
            samples: 2_000_000,
            hidden: Some(effect),
            draw: Draw::Random,
            seed: next(),
        });
    }
    // The longest first, so two threads finish together.
    jobs.sort_by_key(|j| std::cmp::Reverse(j.samples));
    jobs
}

/// Runs the jobs on two threads, each taking the next job until none is
/// left (the longest first, so they finish together).
fn run_all(jobs: &[Job]) -> Vec<(Job, Outcome, f64)> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<(Job, Outcome, f64)>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                // Each thread takes the next job until none is left.
                while let Some(job) = jobs.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let (outcome, seconds) = run(job);
                    results
                        .lock()
                        .expect("no thread panicked holding the lock")
                        .push((job.clone(), outcome, seconds));
                }
            });
        }
    });
    results.into_inner().expect("no thread panicked")
}

/// What fails the ≥ 97 % bounds, printing the figures on the way.
fn failures(results: &[(Job, Outcome, f64)]) -> Vec<String> {
    let counts = [50, 200, 1_000, 10_000, 200_000, 2_000_000];
    let mut failures = Vec::new();
    for samples in counts {
        let here: Vec<_> = results.iter().filter(|r| r.0.samples == samples).collect();
        let slowest = here.iter().map(|r| r.2).fold(0.0f64, f64::max);
        let clean: Vec<_> = here
            .iter()
            .filter_map(|(job, outcome, _)| match outcome {
                Outcome::Clean(s) => Some((job, s)),
                Outcome::Hidden { .. } => None,
            })
            .collect();
        let alarms: Vec<String> = clean
            .iter()
            .filter_map(|(job, s)| {
                s.as_ref()
                    .map(|s| format!("{samples} samples, clean {:?}: suggested {s}", job.draw))
            })
            .collect();
        let (mut detectable, mut found) = (0, 0);
        for (job, outcome, _) in &here {
            if let Outcome::Hidden {
                detectable: true,
                suggested,
                close_second,
                evidence,
            } = outcome
            {
                detectable += 1;
                if found_first(suggested, close_second, job.hidden.as_ref()) {
                    found += 1;
                } else {
                    failures.push(format!(
                        "{samples} samples, {:?} (seed {}): suggested {:?}, close second {:?}; its evidence: {evidence}",
                        job.hidden.as_ref().map(Effect::to_string),
                        job.seed,
                        suggested.as_ref().map(Effect::to_string),
                        close_second.as_ref().map(Effect::to_string)
                    ));
                }
            }
        }
        eprintln!(
            "{samples} samples: clean {} of {} with a suggestion; detectable effects {found} of {detectable} found first (suggested, or named as the close second); slowest diagnosis {slowest:.1} s",
            alarms.len(),
            clean.len()
        );
        // At most 3 % of the clean cases; none where there are few (the
        // large counts, where an alarm would be the deterministic bias).
        if alarms.len() as f64 > 0.03 * clean.len() as f64 {
            failures.extend(alarms);
        }
        if samples < 200_000 && (found as f64) < 0.97 * detectable as f64 {
            failures.push(format!(
                "{samples} samples: only {found} of {detectable} detectable effects suggested first"
            ));
        }
    }
    let effects = results.iter().any(|r| r.0.hidden.is_some());
    for effect in catalogue().into_iter().filter(|_| effects) {
        let cases: Vec<_> = results
            .iter()
            .filter_map(|(job, outcome, _)| match outcome {
                Outcome::Hidden {
                    detectable: true,
                    suggested,
                    close_second,
                    ..
                } if job.hidden.as_ref() == Some(&effect) => Some((suggested, close_second)),
                _ => None,
            })
            .collect();
        let first = cases
            .iter()
            .filter(|(s, _)| s.as_ref() == Some(&effect))
            .count();
        let found = cases
            .iter()
            .filter(|(s, c)| found_first(s, c, Some(&effect)))
            .count();
        eprintln!(
            "{effect}: {first} of {} suggested first, {} more named as the close second of a rival the recording cannot tell it from",
            cases.len(),
            found - first
        );
        if cases.len() < 20 {
            failures.push(format!("{effect}: only {} detectable cases", cases.len()));
        }
        if (found as f64) < 0.97 * cases.len() as f64 {
            failures.push(format!(
                "{effect}: only {found} of {} suggested first",
                cases.len()
            ));
        }
    }
    failures
}

/// The hidden effect counts as found when it is suggested first, or when
/// the diagnosis says the recording cannot tell it from the suggested one
/// and names it as the close second (a temperature that rises and falls
/// through a single turn of 50 samples follows heading, as cross-axis
/// coupling does: the person is told both, and more turns would decide).
fn found_first(
    suggested: &Option<Effect>,
    close_second: &Option<Effect>,
    hidden: Option<&Effect>,
) -> bool {
    hidden.is_some() && (suggested.as_ref() == hidden || close_second.as_ref() == hidden)
}

#[test]
fn no_suggestion_on_clean_data_at_any_sample_count() {
    let jobs: Vec<Job> = jobs().into_iter().filter(|j| j.hidden.is_none()).collect();
    let failures = failures(&run_all(&jobs));
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Each effect of the catalogue, both non-linearities included, is found
/// first (see [`found_first`]) in at least 97 % of the cases where it
/// lowers the rms by more than a quarter, per effect and per sample count.
/// Measured (release): every effect suggested first in every case but
/// `covariate:temp` at 50 samples of a single turn, 31 of 37 first and the
/// other 6 named as the close second of cross-axis.
#[test]
fn each_effect_is_suggested_first_at_every_sample_count() {
    let jobs: Vec<Job> = jobs().into_iter().filter(|j| j.hidden.is_some()).collect();
    let failures = failures(&run_all(&jobs));
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
