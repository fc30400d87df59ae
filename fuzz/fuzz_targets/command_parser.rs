//! Publisher command lines: any bytes parse to a command or an error, never
//! a panic.
#![no_main]

use fieldcal::daemon::publish::parse_command;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(e) = parse_command(data) {
        let _ = e.to_string();
    }
});
