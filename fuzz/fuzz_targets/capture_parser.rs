//! Capture files (.fcap): any bytes parse to a capture or an error, never a
//! panic.
#![no_main]

use fieldcal::capture::parse_capture;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(e) = parse_capture(data, "fuzz.fcap") {
        let _ = e.to_string();
    }
});
