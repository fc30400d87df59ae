//! Properties of the decoders and parsers that take bytes from outside the
//! process, on generated cases: I2C chip data, USB-ISS requests and replies,
//! the daemon configuration and the publisher's command lines. Whatever they
//! are given, they answer with a value or an error, never a panic. (The
//! Falcon decoder, captures and CSV recordings have their own property
//! tests: falcon_props.rs, capture_props.rs, properties.rs.)
//!
//! The fuzz targets in fuzz/ run the same entry points for longer; inputs
//! they find that once failed belong here as plain tests.

use std::path::{Path, PathBuf};

use fieldcal::daemon::config;
use fieldcal::daemon::publish::{ClientCommand, CommandError, parse_command};
use fieldcal::protocol::chips::{Chip, ChipError};
use fieldcal::protocol::usb_iss::{
    self, I2C_AD1, I2C_TEST, I2cSpeed, MAX_READ, MAX_WRITE, MODE_OK, UsbIssError,
};
use fieldcal::sample::Reading;
use proptest::prelude::*;

const CASES: u32 = 256;

fn arb_chip() -> impl Strategy<Value = Chip> {
    prop::sample::select(Chip::ALL.to_vec())
}

fn i12() -> impl Strategy<Value = i16> {
    -2048i16..=2047
}

/// A reading as `chip` reports it: only the fields it has, each within the
/// chip's range (12 bits where the register is 12 bits wide).
fn arb_reading(chip: Chip) -> BoxedStrategy<Reading> {
    let time = -1e6f64..1e6;
    match chip {
        Chip::Adxl345 => (time, any::<[i16; 3]>())
            .prop_map(|(time, accel)| Reading {
                time,
                accel: Some(accel),
                ..Reading::default()
            })
            .boxed(),
        Chip::Mpu6050 => (time, any::<[i16; 3]>(), any::<i16>(), any::<[i16; 3]>())
            .prop_map(|(time, accel, temp_raw, gyro)| Reading {
                time,
                accel: Some(accel),
                gyro: Some(gyro),
                temp_raw: Some(temp_raw),
                temp_c: Some(fieldcal::protocol::chips::mpu6050::temp_c(temp_raw)),
                ..Reading::default()
            })
            .boxed(),
        Chip::Lsm303dlhcAccel => (time, [i12(), i12(), i12()])
            .prop_map(|(time, accel)| Reading {
                time,
                accel: Some(accel),
                ..Reading::default()
            })
            .boxed(),
        Chip::Lsm303dlhcMag => (time, any::<[i16; 3]>(), i12())
            .prop_map(|(time, mag, temp_raw)| Reading {
                time,
                mag: Some(mag),
                temp_raw: Some(temp_raw),
                ..Reading::default()
            })
            .boxed(),
    }
}

fn arb_chip_reading() -> impl Strategy<Value = (Chip, Reading)> {
    arb_chip().prop_flat_map(|chip| (Just(chip), arb_reading(chip)))
}

// ---------------------------------------------------------------- chips

proptest! {
    #![proptest_config(ProptestConfig::with_cases(CASES))]

    /// Any bytes of any length: a reading when the length is the chip's
    /// poll length, a length error naming both lengths otherwise.
    #[test]
    fn chip_decode_any_bytes(
        chip in arb_chip(),
        bytes in prop::collection::vec(any::<u8>(), 0..64),
        time in any::<f64>(),
    ) {
        match chip.decode(&bytes, time) {
            Ok(reading) => {
                prop_assert_eq!(bytes.len(), chip.data_len());
                prop_assert_eq!(reading.time.to_bits(), time.to_bits());
                // What was decoded encodes to bytes that decode the same.
                let again = chip.encode(&reading);
                prop_assert_eq!(again.len(), chip.data_len());
                let twice = chip.decode(&again, time).unwrap();
                prop_assert_eq!(twice.accel, reading.accel);
                prop_assert_eq!(twice.mag, reading.mag);
                prop_assert_eq!(twice.gyro, reading.gyro);
                prop_assert_eq!(twice.temp_raw, reading.temp_raw);
            }
            Err(ChipError::DataLength { chip: c, expected, found }) => {
                prop_assert_eq!(c, chip);
                prop_assert_eq!(expected, chip.data_len());
                prop_assert_eq!(found, bytes.len());
                prop_assert_ne!(found, expected);
            }
            Err(other) => prop_assert!(false, "unexpected error {other}"),
        }
    }

    /// Poll-length bytes always decode, and 12-bit registers ignore their
    /// low nibble exactly as the chip does.
    #[test]
    fn chip_decode_exact_length(chip in arb_chip(), seed in prop::collection::vec(any::<u8>(), 14)) {
        let bytes = &seed[..chip.data_len()];
        prop_assert!(chip.decode(bytes, 0.0).is_ok());
    }

    /// decode(encode(r)) == r for every reading within the chip's range.
    #[test]
    fn chip_encode_decode_round_trip((chip, reading) in arb_chip_reading()) {
        let bytes = chip.encode(&reading);
        prop_assert_eq!(bytes.len(), chip.data_len());
        let back = chip.decode(&bytes, reading.time).unwrap();
        prop_assert_eq!(back, reading);
    }

    /// Out-of-range 12-bit values are clamped, not wrapped.
    #[test]
    fn chip_encode_clamps_twelve_bit_registers(accel in any::<[i16; 3]>(), temp in any::<i16>()) {
        let reading = Reading { accel: Some(accel), mag: Some([0; 3]), temp_raw: Some(temp), ..Reading::default() };
        let a = Chip::Lsm303dlhcAccel.decode(&Chip::Lsm303dlhcAccel.encode(&reading), 0.0).unwrap();
        prop_assert_eq!(a.accel, Some(accel.map(|v| v.clamp(-2048, 2047))));
        let m = Chip::Lsm303dlhcMag.decode(&Chip::Lsm303dlhcMag.encode(&reading), 0.0).unwrap();
        prop_assert_eq!(m.temp_raw, Some(temp.clamp(-2048, 2047)));
    }
}

// -------------------------------------------------------------- USB-ISS

proptest! {
    #![proptest_config(ProptestConfig::with_cases(CASES))]

    /// Any 2-byte mode reply: OK only for FF 00, a rejection for 00 xx, a
    /// bad reply otherwise; every error has a message.
    #[test]
    fn usb_iss_mode_reply_any_bytes(reply in any::<[u8; 2]>()) {
        match usb_iss::check_set_mode_reply(reply) {
            Ok(()) => prop_assert_eq!(reply, MODE_OK),
            Err(UsbIssError::ModeRejected { code }) => {
                prop_assert_eq!(reply, [0x00, code]);
            }
            Err(e @ UsbIssError::BadModeReply { .. }) => {
                prop_assert_ne!(reply, MODE_OK);
                prop_assert_ne!(reply[0], 0x00);
                prop_assert!(!e.to_string().is_empty());
            }
            Err(other) => prop_assert!(false, "unexpected error {other}"),
        }
        prop_assert!(!usb_iss::mode_error_name(reply[1]).is_empty());
    }

    /// Any write reply byte is an ACK or a NACK.
    #[test]
    fn usb_iss_write_reply_any_byte(reply in any::<u8>()) {
        prop_assert_eq!(usb_iss::write_acked(reply), reply != 0);
    }

    /// Reads: 7-bit addresses and lengths up to MAX_READ are encoded, the
    /// rest refused, whatever the numbers.
    #[test]
    fn usb_iss_encode_read_validates(address in any::<u8>(), register in any::<u8>(), len in prop_oneof![0usize..=2 * MAX_READ, any::<usize>()]) {
        match usb_iss::encode_read(address, register, len) {
            Ok(bytes) => {
                prop_assert!(address <= 0x7F && len <= MAX_READ);
                prop_assert_eq!(bytes, [I2C_AD1, (address << 1) | 1, register, len as u8]);
            }
            Err(UsbIssError::BadAddress { address: a }) => {
                prop_assert!(address > 0x7F);
                prop_assert_eq!(a, address);
            }
            Err(UsbIssError::ReadTooLong { len: l }) => {
                prop_assert!(address <= 0x7F && len > MAX_READ);
                prop_assert_eq!(l, len);
            }
            Err(other) => prop_assert!(false, "unexpected error {other}"),
        }
    }

    /// Writes: 7-bit addresses and up to MAX_WRITE data bytes are encoded as
    /// header + data, the rest refused.
    #[test]
    fn usb_iss_encode_write_validates(address in any::<u8>(), register in any::<u8>(), data in prop::collection::vec(any::<u8>(), 0..=2 * MAX_WRITE)) {
        match usb_iss::encode_write(address, register, &data) {
            Ok(bytes) => {
                prop_assert!(address <= 0x7F && data.len() <= MAX_WRITE);
                prop_assert_eq!(&bytes[..4], &[I2C_AD1, address << 1, register, data.len() as u8]);
                prop_assert_eq!(&bytes[4..], &data[..]);
            }
            Err(UsbIssError::BadAddress { address: a }) => {
                prop_assert!(address > 0x7F);
                prop_assert_eq!(a, address);
            }
            Err(UsbIssError::WriteTooLong { len }) => {
                prop_assert!(address <= 0x7F && data.len() > MAX_WRITE);
                prop_assert_eq!(len, data.len());
            }
            Err(other) => prop_assert!(false, "unexpected error {other}"),
        }
    }

    /// Probes: 7-bit addresses only; the address goes out shifted.
    #[test]
    fn usb_iss_encode_test_validates(address in any::<u8>()) {
        match usb_iss::encode_test(address) {
            Ok(bytes) => {
                prop_assert!(address <= 0x7F);
                prop_assert_eq!(bytes, [I2C_TEST, address << 1]);
            }
            Err(e) => {
                prop_assert!(address > 0x7F);
                prop_assert_eq!(e, UsbIssError::BadAddress { address });
            }
        }
    }
}

#[test]
fn usb_iss_set_mode_bytes_are_fixed() {
    for speed in [I2cSpeed::Khz100, I2cSpeed::Khz400] {
        let bytes = usb_iss::encode_set_mode(speed);
        assert_eq!(bytes[2], speed.mode_byte());
    }
}

// ---------------------------------------------------------------- config

fn manifest_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// Valid configurations to mutate, with the path each is parsed as (demo's
/// replay file is relative to it).
fn valid_configs() -> Vec<(String, PathBuf)> {
    ["config/fieldcal.toml", "config/demo.toml"]
        .iter()
        .map(|rel| {
            let path = manifest_path(rel);
            let text = std::fs::read_to_string(&path).unwrap();
            (text, path)
        })
        .collect()
}

/// Pieces of TOML and of fieldcal's vocabulary, so mutations reach the
/// checker and not just the TOML parser.
const TOKENS: &[&str] = &[
    "[daemon]",
    "[outputs]",
    "[[source]]",
    "[[sensor]]",
    "[sensor.rotation]",
    "[sensor.limits]",
    "name = \"imu\"",
    "kind = \"replay\"",
    "kind = \"falcon\"",
    "kind = \"usb-iss\"",
    "source = \"nowhere\"",
    "field = \"mag\"",
    "field = \"gyro\"",
    "axes = [\"x\", \"x\"]",
    "axes = []",
    "chips = [\"mpu6050@0x1FF\", \"adxl345@\"]",
    "chip = \"lsm303dlhc-mag\"",
    "speed = -1.0",
    "speed = nan",
    "sectors = 0",
    "min_per_sector = 18446744073709551615",
    "timeout_s = inf",
    "poll_ms = -5",
    "baud = 0",
    "queue = 0",
    "tcp = \"not an address\"",
    "file = \"/nonexistent.fcap\"",
    "= 1",
    "\"",
    "'''",
    "\u{0}",
    "é",
    "\n",
    "=",
    "[",
    "]",
    "{",
    "}",
    ",",
    "1e400",
    "-0",
];

#[derive(Debug, Clone)]
enum Mutation {
    DeleteLine(usize),
    DuplicateLine(usize),
    ReplaceLine(usize, String),
    InsertLine(usize, String),
    DeleteChars(usize, usize),
    InsertChars(usize, String),
    ReplaceValue(usize, String),
}

fn arb_fragment() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => prop::sample::select(TOKENS).prop_map(str::to_owned),
        1 => "\\PC{0,12}",
        1 => any::<i64>().prop_map(|n| n.to_string()),
        1 => any::<f64>().prop_map(|x| x.to_string()),
    ]
}

fn arb_mutation() -> impl Strategy<Value = Mutation> {
    let at = any::<usize>();
    prop_oneof![
        at.prop_map(Mutation::DeleteLine),
        at.prop_map(Mutation::DuplicateLine),
        (at, arb_fragment()).prop_map(|(i, s)| Mutation::ReplaceLine(i, s)),
        (at, arb_fragment()).prop_map(|(i, s)| Mutation::InsertLine(i, s)),
        (at, 1usize..20).prop_map(|(i, n)| Mutation::DeleteChars(i, n)),
        (at, arb_fragment()).prop_map(|(i, s)| Mutation::InsertChars(i, s)),
        (at, arb_fragment()).prop_map(|(i, s)| Mutation::ReplaceValue(i, s)),
    ]
}

fn mutate(text: &str, mutations: &[Mutation]) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    for m in mutations {
        if lines.is_empty() {
            lines.push(String::new());
        }
        let n = lines.len();
        match m {
            Mutation::DeleteLine(i) => {
                lines.remove(i % n);
            }
            Mutation::DuplicateLine(i) => {
                let line = lines[i % n].clone();
                lines.insert(i % n, line);
            }
            Mutation::ReplaceLine(i, s) => lines[i % n] = s.clone(),
            Mutation::InsertLine(i, s) => lines.insert(i % (n + 1), s.clone()),
            Mutation::DeleteChars(i, len) => {
                let line: Vec<char> = lines[i % n].chars().collect();
                if !line.is_empty() {
                    let start = (i / n) % line.len();
                    let end = (start + len).min(line.len());
                    lines[i % n] = line[..start].iter().chain(&line[end..]).collect();
                }
            }
            Mutation::InsertChars(i, s) => {
                let line: Vec<char> = lines[i % n].chars().collect();
                let at = (i / n) % (line.len() + 1);
                let mut out: String = line[..at].iter().collect();
                out.push_str(s);
                out.extend(&line[at..]);
                lines[i % n] = out;
            }
            Mutation::ReplaceValue(i, s) => {
                // Keep the key, change what follows "=".
                let line = &lines[i % n];
                if let Some(eq) = line.find('=') {
                    lines[i % n] = format!("{}= {}", &line[..eq], s);
                }
            }
        }
    }
    lines.join("\n")
}

/// Checks that parse answers, and that an error has a message and a
/// position inside the text when it names one.
fn check_config(text: &str, path: &Path) -> Result<(), TestCaseError> {
    match config::parse(text, path) {
        Ok(_) => {}
        Err(e) => {
            prop_assert!(!e.to_string().is_empty());
            if let Some(pos) = e.position() {
                prop_assert!(pos.line >= 1 && pos.column >= 1, "{pos:?}");
                prop_assert!(pos.line <= text.lines().count().max(1) + 1, "{pos:?}");
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(CASES))]

    /// Arbitrary text: an error (or, rarely, a configuration), never a panic.
    #[test]
    fn config_parse_any_text(text in "\\PC{0,400}") {
        check_config(&text, Path::new("/tmp/fieldcal-props/fieldcal.toml"))?;
    }

    /// Arbitrary lines built from TOML and fieldcal's vocabulary.
    #[test]
    fn config_parse_token_soup(lines in prop::collection::vec(
        prop::collection::vec(arb_fragment(), 1..4).prop_map(|v| v.join(" ")), 0..40)) {
        check_config(&lines.join("\n"), Path::new("/tmp/fieldcal-props/fieldcal.toml"))?;
    }

    /// Valid configurations, mutated a few times: never a panic.
    #[test]
    fn config_parse_mutated_valid(
        which in 0usize..2,
        mutations in prop::collection::vec(arb_mutation(), 1..6),
    ) {
        let configs = valid_configs();
        let (text, path) = &configs[which % configs.len()];
        check_config(&mutate(text, &mutations), path)?;
    }
}

#[test]
fn the_unmutated_configs_parse() {
    for (text, path) in valid_configs() {
        config::parse(&text, &path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

// --------------------------------------------------------------- commands

fn arb_json_value() -> impl Strategy<Value = serde_json::Value> {
    use serde_json::Value;
    let leaf = prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<i64>().prop_map(Value::from),
        any::<f64>().prop_map(Value::from),
        prop_oneof![
            Just("recalibrate".to_string()),
            Just("status".to_string()),
            Just("command".to_string()),
            Just("sensor".to_string()),
            Just(String::new()),
            "\\PC{0,10}",
        ]
        .prop_map(Value::String),
    ];
    leaf.prop_recursive(3, 24, 4, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..4).prop_map(Value::Array),
            prop::collection::vec(
                (
                    prop_oneof![
                        Just("command".to_string()),
                        Just("sensor".to_string()),
                        "[a-z]{0,6}",
                    ],
                    inner
                ),
                0..4
            )
            .prop_map(|kv| Value::Object(kv.into_iter().collect())),
        ]
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(CASES))]

    /// Any bytes: a command or an error with a message, never a panic.
    #[test]
    fn command_parse_any_bytes(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        match parse_command(&bytes) {
            Ok(_) => {}
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
        if std::str::from_utf8(&bytes).is_err() {
            prop_assert_eq!(parse_command(&bytes), Err(CommandError::NotUtf8));
        }
    }

    /// Any JSON value: only objects with a known "command" and only the
    /// allowed fields are commands.
    #[test]
    fn command_parse_any_json(value in arb_json_value()) {
        let line = serde_json::to_vec(&value).unwrap();
        match parse_command(&line) {
            Ok(ClientCommand::Status) => {
                prop_assert_eq!(&value["command"], "status");
                prop_assert_eq!(value.as_object().unwrap().len(), 1);
            }
            Ok(command @ (ClientCommand::Recalibrate { .. } | ClientCommand::Rollback { .. })) => {
                let (name, sensor) = match command {
                    ClientCommand::Rollback { sensor } => ("rollback", sensor),
                    ClientCommand::Recalibrate { sensor } => ("recalibrate", sensor),
                    ClientCommand::Status => unreachable!(),
                };
                prop_assert_eq!(&value["command"], name);
                match sensor {
                    Some(s) => prop_assert_eq!(&value["sensor"], s.as_str()),
                    None => prop_assert!(value.get("sensor").is_none()),
                }
            }
            Err(CommandError::NotObject(_)) => prop_assert!(!value.is_object()),
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    }

    /// Valid command lines cut short or with a byte changed: never a panic.
    #[test]
    fn command_parse_damaged_lines(
        which in 0usize..3,
        cut in any::<prop::sample::Index>(),
        flip in any::<prop::sample::Index>(),
        byte in any::<u8>(),
    ) {
        let line: &[u8] = [
            &br#"{"command":"status"}"#[..],
            br#"{"command":"recalibrate"}"#,
            br#"{"command":"recalibrate","sensor":"compass"}"#,
        ][which];
        let mut damaged = line.to_vec();
        let at = flip.index(damaged.len());
        damaged[at] = byte;
        let _ = parse_command(&damaged);
        let _ = parse_command(&line[..cut.index(line.len() + 1)]);
    }
}
