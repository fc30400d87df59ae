//! fieldcal: calibration of 2- and 3-axis field sensors (magnetometers,
//! accelerometers) turning in a constant field, after Veriñaz, Vela and
//! Ponguillo's gradient-descent method, with an exact closed-form solver.
//!
//! The pipeline, one module a stage:
//! - [`sample`]: the data that flows (a recording's columns);
//! - [`io`]: CSV in and out, atomic writes;
//! - [`model`]: the paper's model and the ellipsoid, their solvers,
//!   coverage of the turn and of the sphere, diagnosis and checks;
//! - [`report`]: what a fit tells a person or a program;
//! - [`numfmt`]: numbers with significant digits, for the models and reports;
//! - [`protocol`]: wire protocols, sans-IO (Falcon-GX frames, USB-ISS, chips);
//! - [`i2c`]: the I2C bus trait and its backends (USB-ISS bridge, Linux);
//! - [`capture`]: the file format that keeps raw bytes with their timing;
//! - [`source`]: the I/O tasks that own a port or a file;
//! - [`daemon`]: rotation buffer, live fit, publishing, state, systemd;
//! - [`record`]: writing a source's raw bytes to a capture;
//! - [`mock`]: simulated devices that answer like real ones, for tests;
//! - [`sim`]: a simulated sensor, for trying fieldcal with no hardware;
//! - [`sim3`]: a simulated 3-axis sensor, tumbled through the sphere.

// `!(x > 0.0)` is how this crate says "not positive, or NaN": the NaN case
// matters for input checks, so clippy's preferred rewrite would be wrong.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod capture;
pub mod daemon;
pub mod geomag;
pub mod i2c;
pub mod io;
pub mod mock;
pub mod model;
pub mod numfmt;
pub mod parallel;
pub mod protocol;
pub mod record;
pub mod report;
pub mod sample;
pub mod sim;
pub mod sim3;
pub mod source;
