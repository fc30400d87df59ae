//! I2C chip data: the first byte picks the chip, the rest is the poll's
//! data. Decoding never panics; a decoded reading re-encodes to the bytes.
#![no_main]

use fieldcal::protocol::chips::Chip;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    let chip = Chip::ALL[usize::from(first) % Chip::ALL.len()];
    match chip.decode(rest, 0.0) {
        Ok(reading) => {
            assert_eq!(rest.len(), chip.data_len());
            let again = chip.encode(&reading);
            assert_eq!(again.len(), rest.len());
            // The 12-bit registers drop their low nibble; compare decoded.
            assert_eq!(chip.decode(&again, 0.0).unwrap(), reading);
        }
        Err(_) => assert_ne!(rest.len(), chip.data_len()),
    }
});
