//! Daemon configuration: any text (bytes read as lossy UTF-8) parses to a
//! configuration or an error, never a panic.
#![no_main]

use std::path::Path;

use fieldcal::daemon::config;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let _ = config::parse(&text, Path::new("fuzz.toml"));
});
