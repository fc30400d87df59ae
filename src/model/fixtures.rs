//! Fixtures shared by the model's unit tests: the simulated recordings
//! several modules test against, written once.

use crate::sim3::{Motion3, SimSensor3};

/// A sensor tumbled by hand through 20 turns while its axis of turn
/// wanders 10 rad, so the samples cover the sphere: `n` readings of a
/// sensor with calibration `matrix` and `offset` in a field of magnitude
/// `r`, with Gaussian `noise` (raw units) drawn from `seed`.
pub(crate) fn tumbling(
    matrix: [[f64; 3]; 3],
    offset: [f64; 3],
    r: f64,
    noise: f64,
    n: usize,
    seed: u64,
) -> SimSensor3 {
    SimSensor3 {
        matrix,
        offset,
        r,
        noise,
        n,
        motion: Motion3::Tumble {
            turns: 20.0,
            axis_path_rad: 10.0,
        },
        seed,
    }
}
