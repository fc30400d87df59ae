//! docs/capture-format.md describes what a chip stream's chunks hold; the
//! decoder refuses any other length. The document's table of chip streams
//! is read here and compared with the code's constants, so the two cannot
//! drift apart again (it once gave 6 data bytes for the LSM303DLHC
//! magnetometer, whose poll is 8).

use fieldcal::protocol::chips::Chip;

const DOC: &str = include_str!("../docs/capture-format.md");

/// One row of the chip-stream table.
#[derive(Debug)]
struct Row {
    name: String,
    address: u8,
    reads: Vec<(u8, usize)>,
    data_bytes: usize,
}

fn hex(cell: &str) -> u8 {
    let digits = cell
        .trim()
        .strip_prefix("0x")
        .unwrap_or_else(|| panic!("'{cell}' is not a hexadecimal register or address (0x..)"));
    u8::from_str_radix(digits, 16).unwrap_or_else(|e| panic!("'{cell}': {e}"))
}

fn cells(line: &str) -> Vec<&str> {
    line.trim()
        .trim_start_matches('|')
        .trim_end_matches('|')
        .split('|')
        .map(str::trim)
        .collect()
}

/// The rows of the table whose header starts with "| `chip` | device |".
fn chip_table() -> Vec<Row> {
    let mut lines = DOC
        .lines()
        .skip_while(|l| !l.starts_with("| `chip` | device |"));
    let header = cells(
        lines
            .next()
            .expect("no chip-stream table in docs/capture-format.md"),
    );
    assert_eq!(
        header,
        [
            "`chip`",
            "device",
            "usual address",
            "bursts of one poll (first register: bytes)",
            "data bytes",
            "layout of a chunk"
        ]
    );
    assert!(lines.next().is_some_and(|l| l.starts_with("|---")));
    lines
        .take_while(|l| l.starts_with('|'))
        .map(|line| {
            let c = cells(line);
            assert_eq!(c.len(), 6, "{line}");
            Row {
                name: c[0].trim_matches('`').to_string(),
                address: hex(c[2]),
                reads: c[3]
                    .split(',')
                    .map(|burst| {
                        let (register, len) = burst
                            .split_once(':')
                            .unwrap_or_else(|| panic!("'{burst}' is not REGISTER: BYTES"));
                        (hex(register), len.trim().parse().expect("a byte count"))
                    })
                    .collect(),
                data_bytes: c[4].parse().expect("a byte count"),
            }
        })
        .collect()
}

#[test]
fn the_documents_chip_table_matches_the_code() {
    let rows = chip_table();
    let names: Vec<&str> = rows.iter().map(|r| r.name.as_str()).collect();
    let expected: Vec<&str> = Chip::ALL.iter().map(|c| c.name()).collect();
    assert_eq!(names, expected, "one row per chip, in the code's order");
    for (row, chip) in rows.iter().zip(Chip::ALL) {
        assert_eq!(row.address, chip.default_address(), "{}", row.name);
        assert_eq!(row.reads, chip.data_reads(), "{}: bursts", row.name);
        assert_eq!(row.data_bytes, chip.data_len(), "{}: data bytes", row.name);
        // What the decoder takes and the encoder (the simulated chip) gives.
        let data = chip.encode(&Default::default());
        assert_eq!(data.len(), row.data_bytes, "{}: encoded", row.name);
        assert!(chip.decode(&data, 0.0).is_ok(), "{}", row.name);
        assert!(
            chip.decode(&data[..data.len() - 1], 0.0).is_err(),
            "{}: one byte short must be refused",
            row.name
        );
    }
}

#[test]
fn the_header_table_names_every_chip() {
    let line = DOC
        .lines()
        .find(|l| l.starts_with("| `chip` | string, only for"))
        .expect("the stream object's `chip` field");
    for chip in Chip::ALL {
        assert!(
            line.contains(&format!("\"{}\"", chip.name())),
            "{} missing from: {line}",
            chip.name()
        );
    }
}
