//! `diagnose` on sensors drawn at random from a wide range, so it is judged
//! on cases nobody tuned it to: field magnitudes from 0.5 (gauss) to 30,000
//! (counts), gains up to 2.5:1 apart, offsets up to two fields, noise from
//! 0.05 % to 1 % of the field, 50 to 3,000 samples over one to three turns,
//! and one hidden effect (or none) of random size and on one or both axes.
//!
//! An effect counts as detectable when fitting it lowers the rms by more
//! than a quarter; a detectable effect must be suggested first. With no
//! hidden effect, nothing should be suggested. The bounds leave room for
//! the cases that are ambiguous by nature (a temperature that rises and
//! falls through a single turn follows heading, and cross-axis explains it
//! as well).

use fieldcal::model::diagnose::diagnose;
use fieldcal::model::effects::{Effect, PAPER};
use fieldcal::model::nonlinear::fit_model;
use fieldcal::sim::{SimEffects, SimSensor};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const CASES: usize = 600;

/// One simulated recording and the effect hidden in it.
fn draw(rng: &mut ChaCha8Rng) -> (SimSensor, Option<Effect>) {
    let field = [0.5, 1000.0, 30_000.0][rng.random_range(0..3)];
    let gain_x = rng.random_range(0.6..1.6);
    let gain_y = rng.random_range(0.6..1.6);
    let noise = field * [0.0005, 0.002, 0.005, 0.01][rng.random_range(0..4)];
    let turns = [1.0, 1.0, 2.0, 3.0][rng.random_range(0..4)];
    let samples_per_turn = [50.0, 100.0, 200.0, 1000.0][rng.random_range(0..4)];
    let turn_seconds = [5.0, 10.0, 20.0][rng.random_range(0..3)];
    let mut effects = SimEffects::default();
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
    // Sizes in noise SDs (or their natural unit), from barely to clearly.
    let size = rng.random_range(1.0..30.0);
    let run_s = turns * turn_seconds;
    let hidden = match rng.random_range(0..7) {
        0 => None,
        1 => {
            effects.cross_axis_deg = rng.random_range(0.3..10.0);
            Some(Effect::CrossAxis)
        }
        2 => {
            effects.drift_per_s = pair(size * noise / run_s, rng);
            Some(Effect::Drift)
        }
        3 => {
            // 10 °C of warming and cooling.
            effects.temp_per_c = Some(pair(size * noise / 10.0, rng));
            Some(Effect::Covariate("temp".into()))
        }
        4 => {
            // A 2 A motor.
            effects.current_per_a = Some(pair(size * noise / 2.0, rng));
            Some(Effect::Covariate("current".into()))
        }
        5 => {
            effects.cubic = pair(rng.random_range(0.001..0.005), rng);
            Some(Effect::Cubic)
        }
        _ => {
            effects.outliers = rng.random_range(0.01..0.05);
            Some(Effect::Outliers)
        }
    };
    let sensor = SimSensor {
        field,
        gain_x,
        gain_y,
        offset_x: rng.random_range(-2.0..2.0) * field,
        offset_y: rng.random_range(-2.0..2.0) * field,
        noise,
        period: turn_seconds / samples_per_turn,
        turns,
        turn_seconds,
        start_heading_deg: rng.random_range(0.0..360.0),
        seed: rng.random(),
        effects,
    };
    (sensor, hidden)
}

#[test]
fn random_sensors_get_the_hidden_effect_or_nothing() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_2026);
    let (mut detectable, mut found) = (0, 0);
    let (mut clean, mut false_alarms) = (0, 0);
    let mut misses = Vec::new();
    for case in 0..CASES {
        let (sensor, hidden) = draw(&mut rng);
        let data = sensor.simulate().expect("simulation");
        let d = diagnose(&data, &[], None).expect("diagnosis");
        match hidden {
            None => {
                clean += 1;
                if let Some(s) = &d.suggested {
                    false_alarms += 1;
                    misses.push(format!("case {case}: clean, suggested {s}"));
                }
            }
            Some(effect) => {
                let mut with = PAPER.to_vec();
                with.push(effect.clone());
                with.sort();
                let Ok(true_fit) = fit_model(&data, &with) else {
                    continue;
                };
                if d.baseline.rms > 1.25 * true_fit.rms {
                    detectable += 1;
                    if d.suggested.as_ref() == Some(&effect) {
                        found += 1;
                    } else {
                        misses.push(format!(
                            "case {case}: {effect} (rms {:.4} -> {:.4}), suggested {:?}",
                            d.baseline.rms,
                            true_fit.rms,
                            d.suggested.map(|e| e.to_string())
                        ));
                    }
                }
            }
        }
    }
    eprintln!(
        "detectable {found}/{detectable} suggested first; clean {false_alarms}/{clean} false alarms"
    );
    for miss in &misses {
        eprintln!("  {miss}");
    }
    assert!(
        detectable >= CASES / 2,
        "too few detectable cases: {detectable}"
    );
    assert!(clean >= 20, "too few clean cases: {clean}");
    assert!(
        found as f64 >= 0.97 * detectable as f64,
        "{found} of {detectable} detectable effects suggested first:\n{}",
        misses.join("\n")
    );
    assert!(
        false_alarms as f64 <= 0.05 * clean as f64,
        "{false_alarms} of {clean} clean recordings got a suggestion:\n{}",
        misses.join("\n")
    );
}
