//! Fixtures of the unit tests moved out of src (tests/model_units.rs,
//! tests/daemon_units.rs): simulated recordings several modules test against.

use fieldcal::sim3::{Motion3, SimSensor3};
use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// (time, reading) samples.
pub type Samples = Vec<(f64, [f64; 3])>;

/// A board's six faces in turn, each held `hold_s`, joined by turns at
/// 90 °/s, at `rate_hz`: raw = W⁻¹u·`scale` + o + noise (u the unit
/// vector of each face). Returns (t, raw) and each pose's true mean
/// reading.
pub fn six_faces(
    hold_s: f64,
    rate_hz: f64,
    (w, o, scale, noise): ([[f64; 3]; 3], [f64; 3], f64, f64),
    seed: u64,
) -> (Samples, Vec<[f64; 3]>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let winv = Matrix3::from_fn(|i, j| w[i][j]).try_inverse().unwrap();
    let o = Vector3::from(o);
    let dirs = [
        Vector3::z(),
        Vector3::x(),
        -Vector3::z(),
        Vector3::y(),
        -Vector3::x(),
        -Vector3::y(),
    ];
    let dt = 1.0 / rate_hz;
    let mut out = Vec::new();
    let mut truth = Vec::new();
    let sample = |u: Vector3<f64>, out: &mut Samples, rng: &mut ChaCha8Rng| {
        let g = Vector3::new(
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
            StandardNormal.sample(rng),
        );
        let p: Vector3<f64> = winv * u * scale + o + g * noise;
        out.push((out.len() as f64 * dt, p.into()));
    };
    for (k, &u) in dirs.iter().enumerate() {
        for _ in 0..(hold_s * rate_hz) as usize {
            sample(u, &mut out, &mut rng);
        }
        truth.push((winv * u * scale + o).into());
        if let Some(&next) = dirs.get(k + 1) {
            let angle = u.angle(&next);
            let axis = u.cross(&next);
            let axis = if axis.norm() > 1e-9 {
                axis.normalize()
            } else {
                Vector3::x()
            };
            let steps = (angle.to_degrees() / 90.0 * rate_hz).ceil() as usize;
            for i in 1..steps {
                let r = nalgebra::Rotation3::from_axis_angle(
                    &nalgebra::Unit::new_normalize(axis),
                    angle * i as f64 / steps as f64,
                );
                sample(r * u, &mut out, &mut rng);
            }
        }
    }
    (out, truth)
}

/// A sensor tumbled by hand through 20 turns while its axis of turn
/// wanders 10 rad, so the samples cover the sphere: `n` readings of a
/// sensor with calibration `matrix` and `offset` in a field of magnitude
/// `r`, with Gaussian `noise` (raw units) drawn from `seed`.
pub fn tumbling(
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
