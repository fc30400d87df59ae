//! The daemon's streamed CSV source (`io::csv::CsvRows`, issue 11): any
//! bytes give a header error or rows and skipped rows, never a panic; good
//! rows have one value per column, a finite time, and times that increase.
//! The first byte picks the time base: a time column, or `period_s`.
#![no_main]

use std::io::BufReader;
use std::path::Path;

use fieldcal::io::csv::{CsvLayout, CsvLines, CsvRows, read_header};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&mode, text)) = data.split_first() else {
        return;
    };
    let path = Path::new("fuzz.csv");
    let mut lines = CsvLines::new(BufReader::new(text));
    let Ok(header) = read_header(&mut lines, path) else {
        return;
    };
    let period = (mode & 1 == 1).then_some(0.05);
    let Ok(layout) = CsvLayout::resolve(path, header, None, period) else {
        return;
    };
    let columns = layout.names.len();
    // The first two columns are read (as a sensor's axes would be).
    let required: Vec<usize> = (0..columns.min(2)).collect();
    let mut rows = CsvRows::new(lines, layout, &required);
    let mut last = f64::NEG_INFINITY;
    // Every call consumes at least one line, so there are at most as many
    // rows as bytes (plus the end).
    for _ in 0..=text.len() {
        match rows.next_row() {
            Ok(Some(Ok(row))) => {
                assert_eq!(row.values.len(), columns);
                assert!(row.time.is_finite());
                assert!(row.time > last, "{} after {last}", row.time);
                last = row.time;
            }
            Ok(Some(Err(_))) => {}
            Ok(None) | Err(_) => return,
        }
    }
    panic!("more rows than bytes");
});
