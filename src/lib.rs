//! fieldcal: calibration of 2-axis field sensors (magnetometers,
//! accelerometers) turning in a constant field, after Veriñaz, Vela and
//! Ponguillo's gradient-descent method, with an exact closed-form solver.
//!
//! The pipeline, one module a stage:
//! - [`sample`]: the data that flows (a recording's columns);
//! - [`io`]: CSV in and out, atomic writes;
//! - [`model`]: the paper's model, its solvers, coverage of the turn;
//! - [`report`]: what a fit tells a person or a program;
//! - [`sim`]: a simulated sensor, for trying fieldcal with no hardware.

// `!(x > 0.0)` is how this crate says "not positive, or NaN": the NaN case
// matters for input checks, so clippy's preferred rewrite would be wrong.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod io;
pub mod model;
pub mod report;
pub mod sample;
pub mod sim;
