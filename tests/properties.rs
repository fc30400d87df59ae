//! Properties that hold for every input, checked on generated cases.

use std::path::Path;

use fieldcal::io::csv::{ColumnSpec, parse_dataset};
use fieldcal::model::fit::{FitOptions, fit_paper};
use fieldcal::model::paper::{PaperCalibration, closed_form};
use proptest::prelude::*;

fn ellipse_points(cal: &PaperCalibration, n: usize, start: f64) -> (Vec<f64>, Vec<f64>) {
    (0..n)
        .map(|i| {
            let h = start + i as f64 / n as f64 * std::f64::consts::TAU;
            ((cal.r * h.cos() - cal.b) / cal.a, cal.r * h.sin() - cal.d)
        })
        .unzip()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// Any bytes at all: the reader returns a dataset or an error, never
    /// panics, and whatever it returns holds only finite numbers.
    #[test]
    fn csv_reader_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut input = b"t,x,y,c\n".to_vec();
        input.extend_from_slice(&bytes);
        if let Ok(d) = parse_dataset(&input[..], Path::new("fuzz.csv"), &ColumnSpec::default()) {
            prop_assert!(d.x.iter().chain(&d.y).all(|v| v.is_finite()));
            prop_assert_eq!(d.x.len(), d.y.len());
        }
    }

    /// Numbers the reader accepts come back exactly as written.
    #[test]
    fn csv_values_round_trip(rows in proptest::collection::vec((-1e6f64..1e6, -1e6f64..1e6), 1..50)) {
        let text: String = std::iter::once("x,y\n".to_string())
            .chain(rows.iter().map(|(x, y)| format!("{x},{y}\n")))
            .collect();
        let d = parse_dataset(text.as_bytes(), Path::new("p.csv"), &ColumnSpec::default()).unwrap();
        prop_assert_eq!(d.x, rows.iter().map(|r| r.0).collect::<Vec<_>>());
    }

    /// Noiseless samples of any ellipse of the paper's family, at any offset
    /// up to 50 field radii: the closed form recovers it to 1e-7 relative.
    #[test]
    fn closed_form_recovers_any_noiseless_ellipse(
        a in 0.2f64..5.0,
        centre_x in -50.0f64..50.0,
        centre_y in -50.0f64..50.0,
        r in 1.0f64..40_000.0,
        n in 8usize..400,
        start in 0.0f64..6.3,
    ) {
        let cal = PaperCalibration { a, b: -a * centre_x * r, d: -centre_y * r, r };
        let (x, y) = ellipse_points(&cal, n, start);
        let fit = closed_form(&x, &y).unwrap().to_calibration().unwrap();
        prop_assert!((fit.a / a - 1.0).abs() < 1e-7, "a {} vs {}", fit.a, a);
        prop_assert!((fit.r / r - 1.0).abs() < 1e-7, "r {} vs {}", fit.r, r);
        prop_assert!((fit.b - cal.b).abs() < 1e-7 * (r + cal.b.abs()), "b {} vs {}", fit.b, cal.b);
        prop_assert!((fit.d - cal.d).abs() < 1e-7 * (r + cal.d.abs()), "d {} vs {}", fit.d, cal.d);
    }

    /// Whatever finite points come in, a fit is a calibration with finite
    /// numbers or an error: never NaN, never a panic.
    #[test]
    fn fit_never_returns_nan(points in proptest::collection::vec((-1e4f64..1e4, -1e4f64..1e4), 0..60)) {
        let (x, y): (Vec<f64>, Vec<f64>) = points.into_iter().unzip();
        if let Ok(report) = fit_paper(&x, &y, &FitOptions::default(), &mut |_| {}) {
            let c = report.calibration;
            prop_assert!([c.a, c.b, c.d, c.r, report.rms].iter().all(|v| v.is_finite()));
        }
    }
}
