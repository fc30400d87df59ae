//! A simulated 3-axis sensor in a constant field: its readings are
//! raw = W⁻¹·(r·u) + o + noise, u the field's direction in the sensor
//! frame, so that the calibration W·(raw − o) gives back r·u. The sensor
//! is tumbled (smooth random rotations that cover the sphere), turned
//! about a wobbling axis, or kept within a cap of directions, seeded as
//! [`crate::sim`] is, for tests and for `simulate --axes 3`.

use nalgebra::{Matrix3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal};

use rand::RngExt as _;

/// How the sensor moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motion3 {
    /// Smooth random rotations: `turns` fast turns about an axis that
    /// walks smoothly at random over the sphere, `axis_path_rad` radians in
    /// all (π: from one pole to the other).
    Tumble { turns: f64, axis_path_rad: f64 },
    /// Turns about the sensor's z axis in a field of inclination
    /// `inclination_deg` (above the turn's plane), the axis wobbling by up
    /// to `tilt_deg` (a hand-held turn). Tilt 0, inclination 0: a ring.
    WobblingTurn {
        turns: f64,
        inclination_deg: f64,
        tilt_deg: f64,
    },
    /// Directions drawn uniformly within `half_angle_deg` of the sensor's
    /// +z axis (90: a half sphere; 180: the whole sphere).
    Cap { half_angle_deg: f64 },
}

/// A 3-axis sensor and its motion.
#[derive(Debug, Clone, PartialEq)]
pub struct SimSensor3 {
    /// The calibration W (symmetric positive definite): the sensor reads
    /// W⁻¹ of the field.
    pub matrix: [[f64; 3]; 3],
    /// o, raw units.
    pub offset: [f64; 3],
    /// The field's magnitude.
    pub r: f64,
    /// Gaussian noise SD per axis, raw units.
    pub noise: f64,
    /// Samples.
    pub n: usize,
    pub motion: Motion3,
    pub seed: u64,
}

/// Why a simulated sensor cannot be sampled.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Sim3Error {
    #[error("the simulated matrix W is not symmetric positive definite")]
    NotSpd,
    #[error("simulated {name} must be {rule} (got {value})")]
    Invalid {
        name: &'static str,
        rule: &'static str,
        value: f64,
    },
}

/// Most samples one simulation makes (as [`crate::sim::MAX_SAMPLES`]).
pub const MAX_SAMPLES: usize = crate::sim::MAX_SAMPLES;

fn tangent_noise(rng: &mut ChaCha8Rng, u: &Vector3<f64>) -> Vector3<f64> {
    let g = Vector3::new(
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
        StandardNormal.sample(rng),
    );
    g - u * u.dot(&g)
}

impl SimSensor3 {
    /// The unit directions of the field in the sensor frame, one a sample.
    pub fn directions(&self) -> Result<Vec<[f64; 3]>, Sim3Error> {
        if self.n > MAX_SAMPLES {
            return Err(Sim3Error::Invalid {
                name: "sample count",
                rule: "at most 20 000 000",
                value: self.n as f64,
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let n = self.n;
        let mut out = Vec::with_capacity(n);
        match self.motion {
            Motion3::Tumble {
                turns,
                axis_path_rad,
            } => {
                for (name, value) in [("tumble turns", turns), ("tumble axis path", axis_path_rad)]
                {
                    if !(value > 0.0) || !value.is_finite() {
                        return Err(Sim3Error::Invalid {
                            name,
                            rule: "positive",
                            value,
                        });
                    }
                }
                // The sensor turns fast about an axis (the field sweeps
                // great circles about it) while the axis itself walks
                // slowly and smoothly over the sphere, as a hand tumbles a
                // board: turn, change the axis, turn again.
                let step = axis_path_rad / n.max(1) as f64;
                let mut axis = tangent_noise(&mut rng, &Vector3::zeros());
                axis = if axis.norm() > 0.0 {
                    axis.normalize()
                } else {
                    Vector3::z()
                };
                let mut velocity = tangent_noise(&mut rng, &axis).normalize();
                // The axis's direction of travel turns by a random walk
                // whose correlation length is about one radian of its path.
                let wander = step.sqrt();
                let mut reference = Vector3::x();
                for i in 0..n {
                    // An orthonormal frame (e1, e2) about the axis, carried
                    // along smoothly (parallel transport of `reference`).
                    let mut e1 = reference - axis * axis.dot(&reference);
                    if e1.norm() < 1e-6 {
                        e1 = axis.cross(&Vector3::y());
                    }
                    e1 = e1.normalize();
                    reference = e1;
                    let e2 = axis.cross(&e1);
                    let phi = std::f64::consts::TAU * turns * i as f64 / n.max(1) as f64;
                    out.push((e1 * phi.cos() + e2 * phi.sin()).into());
                    velocity += tangent_noise(&mut rng, &axis) * wander;
                    velocity -= axis * axis.dot(&velocity);
                    if velocity.norm() > 0.0 {
                        velocity = velocity.normalize();
                    }
                    axis = (axis + velocity * step).normalize();
                }
            }
            Motion3::WobblingTurn {
                turns,
                inclination_deg,
                tilt_deg,
            } => {
                let inc = inclination_deg.to_radians();
                let tilt = tilt_deg.to_radians();
                // The wobble: tilt about x and y at incommensurate rates.
                let (fa, fb) = (1.7, 2.9);
                let (pa, pb) = (
                    std::f64::consts::TAU * rng.random::<f64>(),
                    std::f64::consts::TAU * rng.random::<f64>(),
                );
                for i in 0..n {
                    let s = i as f64 / n.max(1) as f64;
                    let phi = std::f64::consts::TAU * turns * s;
                    // Field fixed in the world; the sensor turns by phi
                    // about its z axis and tilts.
                    let world = Vector3::new(inc.cos(), 0.0, inc.sin());
                    let yaw = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), -phi);
                    let ta = tilt * (fa * std::f64::consts::TAU * turns * s + pa).sin();
                    let tb = tilt * (fb * std::f64::consts::TAU * turns * s + pb).sin();
                    let wob = nalgebra::Rotation3::from_euler_angles(ta, tb, 0.0);
                    out.push((wob * yaw * world).into());
                }
            }
            Motion3::Cap { half_angle_deg } => {
                if !(half_angle_deg > 0.0 && half_angle_deg <= 180.0) {
                    return Err(Sim3Error::Invalid {
                        name: "cap half-angle",
                        rule: "in (0, 180] degrees",
                        value: half_angle_deg,
                    });
                }
                let low = half_angle_deg.to_radians().cos();
                for _ in 0..n {
                    let z = low + (1.0 - low) * rng.random::<f64>();
                    let phi = std::f64::consts::TAU * rng.random::<f64>();
                    let rho = (1.0 - z * z).max(0.0).sqrt();
                    out.push([rho * phi.cos(), rho * phi.sin(), z]);
                }
            }
        }
        Ok(out)
    }

    /// The raw readings.
    pub fn simulate(&self) -> Result<Vec<[f64; 3]>, Sim3Error> {
        let w = Matrix3::from_fn(|i, j| self.matrix[i][j]);
        let symmetric = (w - w.transpose()).abs().max() <= 1e-12 * w.abs().max();
        let spd = symmetric && w.cholesky().is_some();
        let w_inv = w.try_inverse().filter(|_| spd).ok_or(Sim3Error::NotSpd)?;
        if !(self.r > 0.0) || !self.r.is_finite() {
            return Err(Sim3Error::Invalid {
                name: "field r",
                rule: "positive",
                value: self.r,
            });
        }
        let noise = Normal::new(0.0, self.noise).map_err(|_| Sim3Error::Invalid {
            name: "noise",
            rule: "zero or more",
            value: self.noise,
        })?;
        let directions = self.directions()?;
        // Noise from its own stream, so the path of a seed stays the same
        // at any noise level.
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6e6f_6973_6533_0000);
        let o = Vector3::from(self.offset);
        Ok(directions
            .into_iter()
            .map(|u| {
                let raw = w_inv * (Vector3::from(u) * self.r) + o;
                [0, 1, 2].map(|i| raw[i] + noise.sample(&mut rng))
            })
            .collect())
    }

    /// The truth in the fit's convention: W scaled to det W = 1 and r with
    /// it (W·(raw − o) = r·u is unchanged).
    pub fn truth(&self) -> ([f64; 3], [[f64; 3]; 3], f64) {
        let w = Matrix3::from_fn(|i, j| self.matrix[i][j]);
        let c = w.determinant().cbrt();
        let wn = w / c;
        (
            self.offset,
            [0, 1, 2].map(|i| [wn[(i, 0)], wn[(i, 1)], wn[(i, 2)]]),
            self.r / c,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noiseless_readings_calibrate_onto_the_sphere() {
        let sim = SimSensor3 {
            matrix: [[1.1, 0.1, -0.05], [0.1, 0.9, 0.15], [-0.05, 0.15, 1.0]],
            offset: [100.0, -50.0, 20.0],
            r: 400.0,
            noise: 0.0,
            n: 500,
            motion: Motion3::Tumble {
                turns: 12.0,
                axis_path_rad: 6.0,
            },
            seed: 3,
        };
        let raw = sim.simulate().unwrap();
        let (o, w, r) = sim.truth();
        for p in raw {
            let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
            let c: Vec<f64> = (0..3)
                .map(|i| w[i][0] * d[0] + w[i][1] * d[1] + w[i][2] * d[2])
                .collect();
            let m = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
            assert!((m / r - 1.0).abs() < 1e-12, "{m} vs {r}");
        }
    }

    #[test]
    fn a_tumble_covers_the_sphere_and_a_ring_does_not() {
        let tumble = SimSensor3 {
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            offset: [0.0; 3],
            r: 1.0,
            noise: 0.0,
            n: 2000,
            motion: Motion3::Tumble {
                turns: 12.0,
                axis_path_rad: 6.0,
            },
            seed: 1,
        };
        let cov = crate::model::sphere::coverage(tumble.directions().unwrap());
        assert!(cov.fraction >= 0.9, "{}", cov.fraction);
        let ring = SimSensor3 {
            motion: Motion3::WobblingTurn {
                turns: 2.0,
                inclination_deg: 0.0,
                tilt_deg: 0.0,
            },
            ..tumble
        };
        let cov = crate::model::sphere::coverage(ring.directions().unwrap());
        assert!(cov.fraction <= 0.2, "{}", cov.fraction);
    }

    #[test]
    fn refuses_a_matrix_that_is_not_spd() {
        let sim = SimSensor3 {
            matrix: [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
            offset: [0.0; 3],
            r: 1.0,
            noise: 0.0,
            n: 10,
            motion: Motion3::Cap {
                half_angle_deg: 180.0,
            },
            seed: 1,
        };
        assert_eq!(sim.simulate(), Err(Sim3Error::NotSpd));
    }
}
