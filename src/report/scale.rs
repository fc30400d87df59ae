//! The scales of the report's plots: the range an axis spans, how its ticks
//! read, and how a residual plot keeps a few spikes from flattening the rest.
//! Plain numbers in and out; [`super::plots`] draws with them.

use std::ops::Range;

/// The smallest range holding every finite value, padded by 5 % (and made
/// non-empty) so points do not sit on the frame.
pub(super) fn span(values: impl IntoIterator<Item = f64>) -> Option<Range<f64>> {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if !lo.is_finite() || !hi.is_finite() {
        return None;
    }
    let width = hi - lo;
    let pad = if width > 0.0 {
        0.05 * width
    } else {
        (0.05 * lo.abs()).max(1e-9)
    };
    Some(lo - pad..hi + pad)
}

/// A tick value as people write it: "50", "0.5", "-2", not "50.0" (ticks are
/// round numbers; six decimals absorb binary noise such as 0.30000000000000004).
pub(super) fn tick_label(value: f64) -> String {
    let text = format!("{value:.6}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    match text {
        "-0" => "0".to_string(),
        _ => text.to_string(),
    }
}

/// The vertical scale of a residual plot. Spikes hundreds of noise SDs tall
/// would flatten everything else, so when the extremes reach far beyond
/// the bulk the scale holds the bulk (the 1st to 99th percentile, and the
/// noise band) and the points beyond are drawn at its edge, counted.
#[derive(Debug)]
pub(super) struct ResidualScale {
    pub range: Range<f64>,
    /// True when some values lie outside `range` (drawn at its edge).
    pub clipped: bool,
}

/// How far past the bulk's span the extremes may reach before the scale
/// stops following them: the full span is kept up to this many bulk spans.
const FULL_SPAN_LIMIT: f64 = 3.0;

pub(super) fn residual_scale(values: &[f64], band: Option<f64>) -> ResidualScale {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(f64::total_cmp);
    let band = band.into_iter().flat_map(|f| [f, -f]);
    let full = span(sorted.iter().copied().chain(band.clone())).unwrap_or(-1.0..1.0);
    let whole = ResidualScale {
        range: full.clone(),
        clipped: false,
    };
    // Percentiles of a few points say nothing about a bulk.
    if sorted.len() < 20 {
        return whole;
    }
    let quantile = |q: f64| sorted[((sorted.len() - 1) as f64 * q).round() as usize];
    let Some(bulk) = span([quantile(0.01), quantile(0.99)].into_iter().chain(band)) else {
        return whole;
    };
    let bulk_width = bulk.end - bulk.start;
    if full.end - full.start <= FULL_SPAN_LIMIT * bulk_width {
        return whole;
    }
    // Room beyond the bulk for the edge markers.
    let pad = 0.1 * bulk_width;
    let range = bulk.start - pad..bulk.end + pad;
    let clipped = sorted.iter().any(|v| !range.contains(v));
    ResidualScale { range, clipped }
}

/// Raises the top of `range` so a legend of `rows` fits above the data on a
/// plotting area `pixels` high.
pub(super) fn with_legend_room(range: Range<f64>, rows: usize, pixels: u32) -> Range<f64> {
    let legend_px = 14.0 + 20.0 * rows as f64;
    let share = (legend_px / f64::from(pixels.max(1))).min(0.5);
    let width = range.end - range.start;
    range.start..range.start + width / (1.0 - share)
}

/// Widens one of the ranges so one unit is as many pixels on x as on y on a
/// plotting area of `pixels`: an ellipse then looks like the ellipse it is.
pub(super) fn equal_aspect(
    x: Range<f64>,
    y: Range<f64>,
    pixels: (u32, u32),
) -> (Range<f64>, Range<f64>) {
    let (pw, ph) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
    let per_pixel = ((x.end - x.start) / pw).max((y.end - y.start) / ph);
    let (cx, cy) = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
    let (hw, hh) = (per_pixel * pw / 2.0, per_pixel * ph / 2.0);
    (cx - hw..cx + hw, cy - hh..cy + hh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_drop_needless_decimals() {
        assert_eq!(tick_label(50.0), "50");
        assert_eq!(tick_label(0.5), "0.5");
        assert_eq!(tick_label(-2.0), "-2");
        assert_eq!(tick_label(0.1 + 0.2), "0.3");
        assert_eq!(tick_label(-0.0), "0");
        assert_eq!(tick_label(0.0002), "0.0002");
    }

    #[test]
    fn residual_scale_follows_the_bulk_not_a_spike() {
        // A sine of amplitude 1 over 200 samples and a noise band of 0.1.
        let mut values: Vec<f64> = (0..200).map(|i| (f64::from(i) * 0.1).sin()).collect();
        let clean = residual_scale(&values, Some(0.1));
        assert!(!clean.clipped);
        assert!(
            clean.range.start < -0.99 && clean.range.end > 0.99,
            "{clean:?}"
        );
        assert!(clean.range.end - clean.range.start < 2.3, "{clean:?}");
        // One spike 40 times the amplitude: the scale keeps the sine.
        values[57] = 40.0;
        let spiked = residual_scale(&values, Some(0.1));
        assert!(spiked.clipped, "{spiked:?}");
        assert!(spiked.range.end < 3.0, "{spiked:?}");
        assert!(spiked.range.start < -0.99 && spiked.range.end > 0.99);
        // Extremes within three spans of the bulk are kept whole.
        values[57] = 2.5;
        assert!(!residual_scale(&values, Some(0.1)).clipped);
        // Too few points for percentiles: the whole range.
        assert!(!residual_scale(&[0.0, 0.1, 50.0], None).clipped);
    }
}
