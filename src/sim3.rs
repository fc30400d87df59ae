//! A simulated 3-axis sensor in a constant field: its readings are
//! raw = W⁻¹·(r·u) + o + noise, u the field's direction in the sensor
//! frame, so that the calibration W·(raw − o) gives back r·u. The sensor
//! is tumbled (smooth random rotations that cover the sphere), turned
//! about a wobbling axis, or kept within a cap of directions, seeded as
//! [`crate::sim`] is, for tests and for `simulate --axes 3`.

use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal};
use serde::Serialize;

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
                let wobble = Wobble::new(&mut rng, turns, tilt);
                for i in 0..n {
                    let s = i as f64 / n.max(1) as f64;
                    let phi = std::f64::consts::TAU * turns * s;
                    // Field fixed in the world; the sensor turns by phi
                    // about its z axis and tilts.
                    let world = Vector3::new(inc.cos(), 0.0, inc.sin());
                    let yaw = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), -phi);
                    let (ta, tb) = wobble.at(s);
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

// ---------------------------------------------------------------------------
// An IMU: one orientation sequence, the Earth's field and gravity turned
// into the body frame, each through its own sensor.

/// How the simulated IMU moves.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum ImuMotion {
    /// Turns about a body axis that walks smoothly at random over the
    /// sphere (`axis_path_rad` radians in all): a hand tumbling a board.
    Tumble { turns: f64, axis_path_rad: f64 },
    /// Turns about the vertical, the board rolling and pitching by up to
    /// `tilt_deg` at incommensurate rates (a boat, a hand-held turn).
    WobblingTurn { turns: f64, tilt_deg: f64 },
    /// `poses` orientations drawn uniformly, each held for an equal share
    /// of the samples (the accelerometer's six-face calibration): still
    /// for its first three quarters, then turned to the next pose at a
    /// steady rate (as a hand moves it; a jump would be an infinite rate).
    Static { poses: usize },
}

/// One 3-axis sensor of the IMU: it reads W⁻¹·(true vector) + o + noise,
/// so that the calibration W·(raw − o) gives back the true vector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SimAxes3 {
    /// The calibration W (symmetric positive definite).
    pub matrix: [[f64; 3]; 3],
    /// o, raw units.
    pub offset: [f64; 3],
    /// Gaussian noise SD per axis, raw units.
    pub noise: f64,
}

impl SimAxes3 {
    fn inverse(&self, name: &'static str) -> Result<Matrix3<f64>, Sim3Error> {
        let w = Matrix3::from_fn(|i, j| self.matrix[i][j]);
        if w.iter().chain(self.offset.iter()).any(|v| !v.is_finite()) {
            return Err(Sim3Error::Invalid {
                name,
                rule: "finite",
                value: f64::NAN,
            });
        }
        let symmetric = (w - w.transpose()).abs().max() <= 1e-12 * w.abs().max();
        let spd = symmetric && w.cholesky().is_some();
        let inverse = w.try_inverse().filter(|_| spd).ok_or(Sim3Error::NotSpd)?;
        if !(self.noise >= 0.0 && self.noise.is_finite()) {
            return Err(Sim3Error::Invalid {
                name: "noise",
                rule: "zero or more",
                value: self.noise,
            });
        }
        Ok(inverse)
    }

    /// The truth in the fit's convention (det W = 1), for a true vector of
    /// magnitude `r`: (o, W, r).
    pub fn truth(&self, r: f64) -> ([f64; 3], [[f64; 3]; 3], f64) {
        let w = Matrix3::from_fn(|i, j| self.matrix[i][j]);
        let c = w.determinant().cbrt();
        let wn = w / c;
        (
            self.offset,
            [0, 1, 2].map(|i| [wn[(i, 0)], wn[(i, 1)], wn[(i, 2)]]),
            r / c,
        )
    }
}

/// A simulated IMU: a magnetometer, an accelerometer and a gyro on one
/// board, in the Earth's field and gravity.
///
/// The world frame is east, north, up; the field points north and
/// `inclination_deg` below the horizontal; the accelerometer reads the
/// specific force (up at rest, as [`crate::model::tilt`]); the board's
/// forward axis is body +x, its up axis body +z, and its heading is
/// clockwise from (magnetic) north to body +x.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimImu3 {
    /// The Earth's field's magnitude, in the magnetometer's raw units.
    pub field: f64,
    /// The field's angle below the horizontal, degrees (−90..90).
    pub inclination_deg: f64,
    /// 1 g in the accelerometer's raw units.
    pub gravity: f64,
    pub mag: SimAxes3,
    pub accel: SimAxes3,
    /// Gaussian noise SD of the gyro, deg/s.
    pub gyro_noise: f64,
    /// Seconds between samples.
    pub period: f64,
    /// Samples.
    pub n: usize,
    pub motion: ImuMotion,
    pub seed: u64,
}

/// One sample of the simulated IMU, with the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    pub t: f64,
    /// Raw magnetometer.
    pub mag: [f64; 3],
    /// Raw accelerometer.
    pub accel: [f64; 3],
    /// The body's angular rate, deg/s, about body x, y, z (plus noise).
    pub gyro: [f64; 3],
    /// True heading, clockwise from north to body +x, degrees in [0, 360).
    pub heading_deg: f64,
    /// True angle between body +z and the vertical, degrees.
    pub tilt_deg: f64,
}

fn check_positive(name: &'static str, value: f64) -> Result<(), Sim3Error> {
    if value > 0.0 && value.is_finite() {
        Ok(())
    } else {
        Err(Sim3Error::Invalid {
            name,
            rule: "a positive number",
            value,
        })
    }
}

fn unit_or(v: Vector3<f64>, fallback: Vector3<f64>) -> Vector3<f64> {
    let n = v.norm();
    if n > 0.0 && n.is_finite() {
        v / n
    } else {
        fallback
    }
}

impl SimImu3 {
    /// Checks the settings, before anything is simulated.
    pub fn validate(&self) -> Result<(), Sim3Error> {
        if self.n > MAX_SAMPLES {
            return Err(Sim3Error::Invalid {
                name: "sample count",
                rule: "at most 20 000 000",
                value: self.n as f64,
            });
        }
        check_positive("field", self.field)?;
        check_positive("gravity", self.gravity)?;
        check_positive("period", self.period)?;
        if !(self.inclination_deg.abs() <= 90.0) {
            return Err(Sim3Error::Invalid {
                name: "inclination",
                rule: "between -90 and 90 degrees",
                value: self.inclination_deg,
            });
        }
        if !(self.gyro_noise >= 0.0 && self.gyro_noise.is_finite()) {
            return Err(Sim3Error::Invalid {
                name: "gyro noise",
                rule: "zero or more",
                value: self.gyro_noise,
            });
        }
        self.mag.inverse("magnetometer matrix and offsets")?;
        self.accel.inverse("accelerometer matrix and offsets")?;
        match self.motion {
            ImuMotion::Tumble {
                turns,
                axis_path_rad,
            } => {
                check_positive("tumble turns", turns)?;
                check_positive("tumble axis path", axis_path_rad)?;
            }
            ImuMotion::WobblingTurn { turns, tilt_deg } => {
                check_positive("turns", turns)?;
                if !(0.0..=80.0).contains(&tilt_deg) {
                    return Err(Sim3Error::Invalid {
                        name: "wobble tilt",
                        rule: "between 0 and 80 degrees",
                        value: tilt_deg,
                    });
                }
            }
            ImuMotion::Static { poses } => {
                if poses == 0 || poses > 10_000 {
                    return Err(Sim3Error::Invalid {
                        name: "static poses",
                        rule: "from 1 to 10000",
                        value: poses as f64,
                    });
                }
            }
        }
        Ok(())
    }

    /// The board's orientation at each sample: the rotation from the body
    /// frame to the world frame (east, north, up).
    pub fn orientations(&self) -> Result<Vec<Rotation3<f64>>, Sim3Error> {
        self.validate()?;
        let n = self.n;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        // Body x north, y west, z up: heading 0, level.
        let level = Rotation3::from_matrix_unchecked(Matrix3::new(
            0.0, -1.0, 0.0, //
            1.0, 0.0, 0.0, //
            0.0, 0.0, 1.0,
        ));
        let mut out = Vec::with_capacity(n);
        match self.motion {
            ImuMotion::Tumble {
                turns,
                axis_path_rad,
            } => {
                // The body turns by dphi a sample about a body axis that
                // walks over the sphere as SimSensor3's tumble does.
                let dphi = std::f64::consts::TAU * turns / n.max(1) as f64;
                let step = axis_path_rad / n.max(1) as f64;
                let wander = step.sqrt();
                let mut axis = unit_or(tangent_noise(&mut rng, &Vector3::zeros()), Vector3::z());
                let mut velocity =
                    unit_or(tangent_noise(&mut rng, &axis), axis.cross(&Vector3::x()));
                let start_heading = std::f64::consts::TAU * rng.random::<f64>();
                let mut r = Rotation3::from_axis_angle(&Vector3::z_axis(), -start_heading) * level;
                for _ in 0..n {
                    out.push(r);
                    let unit = nalgebra::Unit::new_normalize(axis);
                    r *= Rotation3::from_axis_angle(&unit, dphi);
                    r.renormalize();
                    velocity += tangent_noise(&mut rng, &axis) * wander;
                    velocity -= axis * axis.dot(&velocity);
                    velocity = unit_or(velocity, axis.cross(&Vector3::y()));
                    axis = unit_or(axis + velocity * step, axis);
                }
            }
            ImuMotion::WobblingTurn { turns, tilt_deg } => {
                let tilt = tilt_deg.to_radians();
                let wobble = Wobble::new(&mut rng, turns, tilt);
                for i in 0..n {
                    let s = i as f64 / n.max(1) as f64;
                    let psi = std::f64::consts::TAU * turns * s;
                    let (roll, pitch) = wobble.at(s);
                    // Heading ψ clockwise seen from above: −ψ about up.
                    let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), -psi);
                    let wob = Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
                        * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch);
                    out.push(yaw * level * wob);
                }
            }
            ImuMotion::Static { poses } => {
                let per = n.div_ceil(poses).max(1);
                // A uniform random rotation (a normalised Gaussian
                // quaternion).
                let mut draw = || {
                    let mut g = [0.0f64; 4];
                    for v in &mut g {
                        *v = StandardNormal.sample(&mut rng);
                    }
                    let q = nalgebra::Quaternion::new(g[0], g[1], g[2], g[3]);
                    nalgebra::UnitQuaternion::from_quaternion(q)
                };
                let mut pose = draw();
                let mut next = draw();
                let hold = (per * 3).div_ceil(4);
                for i in 0..n {
                    let k = i % per;
                    if i > 0 && k == 0 {
                        pose = next;
                        next = draw();
                    }
                    let last = i / per + 1 >= poses;
                    let r = if k < hold || last {
                        pose
                    } else {
                        // The shorter way round, at a steady rate.
                        let s = (k - hold + 1) as f64 / (per - hold + 1) as f64;
                        pose.try_slerp(&next, s, 1e-9).unwrap_or(next)
                    };
                    out.push(r.to_rotation_matrix());
                }
            }
        }
        Ok(out)
    }

    /// The samples: raw magnetometer, raw accelerometer, the gyro's body
    /// rate, and the true heading and tilt.
    pub fn simulate(&self) -> Result<Vec<ImuSample>, Sim3Error> {
        let rotations = self.orientations()?;
        let mag_inv = self.mag.inverse("magnetometer matrix and offsets")?;
        let accel_inv = self.accel.inverse("accelerometer matrix and offsets")?;
        let inc = self.inclination_deg.to_radians();
        let field_world = Vector3::new(0.0, inc.cos(), -inc.sin()) * self.field;
        let up_world = Vector3::z() * self.gravity;
        // Each sensor's noise from its own stream, so the path of a seed is
        // the same at any noise level.
        let mut mag_rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6d61_676e_6f69_7365);
        let mut accel_rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6163_636e_6f69_7365);
        let mut gyro_rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6779_726f_6e6f_6973);
        let gauss = |rng: &mut ChaCha8Rng, sd: f64| -> f64 {
            if sd > 0.0 {
                let g: f64 = StandardNormal.sample(rng);
                sd * g
            } else {
                0.0
            }
        };
        let mut out = Vec::with_capacity(rotations.len());
        for (i, r) in rotations.iter().enumerate() {
            let to_body = r.inverse();
            let m = mag_inv * (to_body * field_world) + Vector3::from(self.mag.offset);
            let a = accel_inv * (to_body * up_world) + Vector3::from(self.accel.offset);
            // The body rate that carries this orientation to the next:
            // R(t + dt) = R(t)·exp(ω dt).
            let omega = match rotations.get(i + 1) {
                Some(next) => (r.inverse() * next).scaled_axis() / self.period,
                None if i > 0 => {
                    let prev = &rotations[i - 1];
                    (prev.inverse() * r).scaled_axis() / self.period
                }
                None => Vector3::zeros(),
            };
            let forward = r * Vector3::x();
            let heading = forward.x.atan2(forward.y).to_degrees().rem_euclid(360.0);
            let body_up = r * Vector3::z();
            out.push(ImuSample {
                t: i as f64 * self.period,
                mag: [0, 1, 2].map(|k| m[k] + gauss(&mut mag_rng, self.mag.noise)),
                accel: [0, 1, 2].map(|k| a[k] + gauss(&mut accel_rng, self.accel.noise)),
                gyro: [0, 1, 2]
                    .map(|k| omega[k].to_degrees() + gauss(&mut gyro_rng, self.gyro_noise)),
                heading_deg: if heading >= 360.0 { 0.0 } else { heading },
                tilt_deg: body_up.z.clamp(-1.0, 1.0).acos().to_degrees(),
            });
        }
        Ok(out)
    }

    /// The magnetometer's truth in the fit's convention: (o, W, r).
    pub fn mag_truth(&self) -> ([f64; 3], [[f64; 3]; 3], f64) {
        self.mag.truth(self.field)
    }

    /// The accelerometer's truth in the fit's convention: (o, W, r).
    pub fn accel_truth(&self) -> ([f64; 3], [[f64; 3]; 3], f64) {
        self.accel.truth(self.gravity)
    }
}

/// The columns of a simulated IMU's CSV: the magnetometer as `x`, `y`, `z`
/// (what `fit FILE` reads by default), then the accelerometer, the gyro
/// (deg/s) and the truth.
pub const IMU_CSV_HEADER: &str = "t,x,y,z,ax,ay,az,gx,gy,gz,heading,tilt";

/// Writes the samples as CSV with [`IMU_CSV_HEADER`].
pub fn write_imu_csv<W: std::io::Write>(out: &mut W, samples: &[ImuSample]) -> std::io::Result<()> {
    writeln!(out, "{IMU_CSV_HEADER}")?;
    for s in samples {
        writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            s.t,
            s.mag[0],
            s.mag[1],
            s.mag[2],
            s.accel[0],
            s.accel[1],
            s.accel[2],
            s.gyro[0],
            s.gyro[1],
            s.gyro[2],
            s.heading_deg,
            s.tilt_deg
        )?;
    }
    Ok(())
}

/// Why a simulated IMU cannot be put in Falcon-GX frames.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Wire3Error {
    #[error(transparent)]
    Sim(#[from] Sim3Error),
    #[error(
        "sample {index}: the {what} reads {value:.0} counts, outside the i16 range of a Falcon-GX frame; lower --field, --gravity, the offsets or the turn rate"
    )]
    OutOfRange {
        index: usize,
        what: &'static str,
        value: f64,
    },
    #[error("--garbage must be a fraction from 0 to {max}, got {0}", max = crate::sim::MAX_GARBAGE)]
    Garbage(f64),
    #[error(
        "the capture would take about {bytes:.0} bytes, more than the {max:.0} a simulation writes; lower --turns or --garbage, or raise --period",
        max = crate::sim::MAX_CAPTURE_BYTES
    )]
    TooLarge { bytes: f64 },
}

impl SimImu3 {
    /// Checks, before anything is simulated, that a capture can be made:
    /// the settings, the garbage fraction and the size (as
    /// [`crate::sim::SimSensor::check_capture`]).
    pub fn check_capture(&self, garbage: f64) -> Result<(), Wire3Error> {
        if !(0.0..=crate::sim::MAX_GARBAGE).contains(&garbage) {
            return Err(Wire3Error::Garbage(garbage));
        }
        self.validate()?;
        let bytes = self.n as f64 * crate::protocol::falcon::FRAME_LEN as f64 / (1.0 - garbage);
        if !(bytes <= crate::sim::MAX_CAPTURE_BYTES) {
            return Err(Wire3Error::TooLarge { bytes });
        }
        Ok(())
    }

    /// The IMU as a Falcon-GX-style capture: every frame carries the
    /// magnetometer's and the accelerometer's x, y, z in counts (rounded)
    /// and the body rate in the frame's gyro scale
    /// ([`crate::protocol::falcon::RATE_LSB_PER_DEG_S`]), one frame per
    /// `period`, with `garbage` of random bytes between frames.
    pub fn falcon_capture(
        &self,
        garbage: f64,
        ticks_per_frame: u16,
    ) -> Result<(crate::capture::CaptureHeader, Vec<crate::capture::Chunk>), Wire3Error> {
        use crate::protocol::falcon::{FalconFrame, RATE_LSB_PER_DEG_S};

        self.check_capture(garbage)?;
        let samples = self.simulate()?;
        let counts =
            |index: usize, what: &'static str, v: [f64; 3]| -> Result<[i16; 3], Wire3Error> {
                let mut out = [0i16; 3];
                for (o, value) in out.iter_mut().zip(v) {
                    let rounded = value.round();
                    if rounded >= i16::MIN as f64 && rounded <= i16::MAX as f64 {
                        *o = rounded as i16;
                    } else {
                        return Err(Wire3Error::OutOfRange { index, what, value });
                    }
                }
                Ok(out)
            };
        let frames = samples
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let frame = FalconFrame {
                    mag: counts(i, "magnetometer", s.mag)?,
                    accel: counts(i, "accelerometer", s.accel)?,
                    rate: counts(i, "gyro", s.gyro.map(|g| g * RATE_LSB_PER_DEG_S))?,
                    timer: (i as u64 * u64::from(ticks_per_frame) % 65_536) as u16,
                };
                Ok((s.t, frame))
            })
            .collect::<Result<Vec<_>, Wire3Error>>()?;
        let note = format!(
            "simulated IMU: field {} inclination {} gravity {} mag W {:?} o {:?} noise {}; accel W {:?} o {:?} noise {}; {:?}; seed {}",
            self.field,
            self.inclination_deg,
            self.gravity,
            self.mag.matrix,
            self.mag.offset,
            self.mag.noise,
            self.accel.matrix,
            self.accel.offset,
            self.accel.noise,
            self.motion,
            self.seed
        );
        Ok(crate::sim::pack_falcon(
            &frames,
            garbage,
            self.seed,
            self.period,
            note,
        ))
    }
}

/// A turn's wobble: tilts about two axes at incommensurate rates (1.7 and
/// 2.9 times the turn's) with random phases.
struct Wobble {
    turns: f64,
    tilt: f64,
    phases: (f64, f64),
}

impl Wobble {
    fn new(rng: &mut ChaCha8Rng, turns: f64, tilt: f64) -> Self {
        let pa = std::f64::consts::TAU * rng.random::<f64>();
        let pb = std::f64::consts::TAU * rng.random::<f64>();
        Wobble {
            turns,
            tilt,
            phases: (pa, pb),
        }
    }

    /// The two tilts, radians, at fraction `s` of the recording.
    fn at(&self, s: f64) -> (f64, f64) {
        use std::f64::consts::TAU;
        // In this order, so a seed gives the same recording as before.
        (
            self.tilt * (1.7 * TAU * self.turns * s + self.phases.0).sin(),
            self.tilt * (2.9 * TAU * self.turns * s + self.phases.1).sin(),
        )
    }
}
