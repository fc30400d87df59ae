//! Recordings (CSV): any bytes read to a dataset or an error, never a panic.
#![no_main]

use std::path::Path;

use fieldcal::io::csv::{ColumnSpec, parse_dataset};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = parse_dataset(data, Path::new("fuzz.csv"), &ColumnSpec::default());
});
