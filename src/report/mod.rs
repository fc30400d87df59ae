//! What fieldcal tells a person (text) or a program (JSON) about its work.

mod chart;
pub mod diagnosis;
pub mod diagnosis3;
pub mod fit;
pub mod fit3;
pub mod heading;
pub mod html;
pub mod monitor;
pub mod plots;
pub mod plots3;
mod scale;

// The number formatting lives below the models ([`crate::numfmt`]); also
// here, at the path the reports and their callers have always used.
pub use crate::numfmt::significant;
