//! The report of `fieldcal check --monitor --report DIR`: the field of
//! every calibrated reading over time, the distrusted ones in red over a
//! shaded stretch, and the limit the monitor held them to; the page lists
//! the stretches with their reasons.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::chart::{
    BEFORE, DrawError, FIT, FLOOR, Svg, Thinning, draw_sized, ensure_font, write_figures,
};
use super::plots::{Figure, ReportError};
use super::scale::span;
use crate::model::trust::RecordingTrust;

/// What the page shows: one value per reading in `t` and `field_ratio`.
#[derive(Debug, Clone)]
pub struct MonitorData<'a> {
    pub title: String,
    /// The text summary (the check's and the monitor's), shown as is.
    pub summary: String,
    pub t: &'a [f64],
    /// |corrected| / r per reading.
    pub field_ratio: &'a [f64],
    pub trust: &'a RecordingTrust,
}

/// Writes `trust.svg` and `index.html` into `dir`; returns the paths.
pub fn write_monitor_report(
    dir: &Path,
    data: &MonitorData<'_>,
) -> Result<Vec<PathBuf>, ReportError> {
    if data.t.is_empty() {
        return Err(ReportError::Empty {
            what: "the readings",
        });
    }
    for (what, len) in [
        ("field_ratio", data.field_ratio.len()),
        ("trusted", data.trust.trusted.len()),
    ] {
        if len != data.t.len() {
            return Err(ReportError::Length {
                what: what.to_string(),
                len,
                expected: data.t.len(),
            });
        }
    }
    ensure_font()?;
    let thin = Thinning::new(data.t.len());
    let file = "trust.svg";
    let title = format!(
        "The field over time, and where it was distrusted{}",
        thin.note()
    );
    let figure = Figure {
        file: file.into(),
        caption: format!(
            "|corrected|/r − 1 of every reading (blue when trusted, red when not) over the \
             stretches the monitor distrusted (shaded). The dashed lines are the field's limit \
             (5 σ of the calibration's noise); a stretch inside them was distrusted by the \
             heading's check against the gyro. {} of {} readings trusted.{}",
            data.trust.counts.trusted,
            data.trust.counts.trusted + data.trust.counts.distrusted,
            thin.sentence()
        ),
        svg: draw_sized(file, (1000, 500), |area| {
            trust_plot(area, &title, data, &thin)
        })?,
        title,
    };
    let summary = format!("<pre>{}</pre>", super::html::escape(&data.summary));
    write_figures(dir, std::slice::from_ref(&figure), |figures| {
        super::html::render_page(&super::html::PAGE2, &data.title, &summary, figures)
    })
}

fn trust_plot(
    area: &Svg,
    title: &str,
    data: &MonitorData<'_>,
    thin: &Thinning,
) -> Result<(), DrawError> {
    let body = area.titled(title, ("sans-serif", 20))?;
    let points: Vec<(f64, f64, bool)> = thin
        .indices()
        .filter_map(|i| {
            let (t, r, ok) = (
                *data.t.get(i)?,
                *data.field_ratio.get(i)?,
                *data.trust.trusted.get(i)?,
            );
            (t.is_finite() && r.is_finite()).then_some((t, (r - 1.0) * 100.0, ok))
        })
        .collect();
    let x = span(points.iter().map(|p| p.0)).unwrap_or(0.0..1.0);
    let limit = data.trust.field_limit * 100.0;
    // The limit is always in view; a far outlier is clipped to 4 limits.
    let reach = points
        .iter()
        .map(|p| p.1.abs())
        .fold(limit * 1.5, f64::max)
        .min(limit * 4.0)
        .max(1e-6);
    let y = -reach..reach;
    let mut chart = ChartBuilder::on(&body)
        .margin(10)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d(x.clone(), y.clone())?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("|s|/r − 1 (%)")
        .light_line_style(WHITE)
        .draw()?;
    chart.draw_series(data.trust.stretches.iter().map(|s| {
        Rectangle::new(
            [(s.from_s, y.start), (s.to_s.max(s.from_s), y.end)],
            FIT.mix(0.12).filled(),
        )
    }))?;
    for edge in [limit, -limit] {
        chart.draw_series(DashedLineSeries::new(
            [(x.start, edge), (x.end, edge)],
            6,
            4,
            FLOOR.stroke_width(1),
        ))?;
    }
    let clip = |v: f64| v.clamp(y.start, y.end);
    chart
        .draw_series(
            points
                .iter()
                .filter(|p| p.2)
                .map(|p| Circle::new((p.0, clip(p.1)), 1, BEFORE.filled())),
        )?
        .label("trusted")
        .legend(|(x, y)| Circle::new((x, y), 3, BEFORE.filled()));
    chart
        .draw_series(
            points
                .iter()
                .filter(|p| !p.2)
                .map(|p| Circle::new((p.0, clip(p.1)), 2, FIT.filled())),
        )?
        .label("distrusted")
        .legend(|(x, y)| Circle::new((x, y), 3, FIT.filled()));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}
