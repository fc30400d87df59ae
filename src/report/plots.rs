//! SVG plots of a calibration diagnosis, and the report directory that shows
//! them (`index.html`, see [`super::html`]).
//!
//! The input is plain data ([`ReportData`]): the caller (the diagnosis)
//! computes every number, this module only draws. A person opens the
//! directory in a browser with no network, so everything is local: SVG files
//! drawn with `plotters`, text laid out with a font embedded in the binary
//! (no system fonts needed), and an HTML page with inline CSS.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::chart::{
    AFTER, BEFORE, DrawError, FAMILY, FIT, FLOOR, FrameLayout, Plane, Svg, Thinning,
    before_and_after, draw_sized, ensure_font, floor_band, legend_sized, point_series,
    write_figures,
};
use super::scale::{equal_aspect, residual_scale, span, tick_label, with_legend_room};

/// Everything a report shows. Per-sample vectors (`heading_deg`,
/// `residual_before`, `residual_after`, `time`, each covariate) have one
/// value per sample and the same length; non-finite values are skipped when
/// drawing, not an error.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReportData {
    /// The report's heading, e.g. "hmc5883l_mag.csv: x = mag_x, y = mag_z".
    pub title: String,
    /// Raw x and y readings (sensor units), one pair per sample.
    pub raw: (Vec<f64>, Vec<f64>),
    /// Points along the fitted ellipse, in raw coordinates (may be empty).
    pub ellipse: Vec<(f64, f64)>,
    /// Samples calibrated by the baseline model, divided by r (unit circle).
    pub calibrated_before: Vec<(f64, f64)>,
    /// Samples calibrated by the model with the suggested effect(s), divided
    /// by r (may be empty when nothing is suggested).
    pub calibrated_after: Vec<(f64, f64)>,
    /// Legend name of the baseline model, e.g. "offset+scale".
    pub before_label: String,
    /// Legend name of the improved model, e.g. "offset+scale+cross-axis".
    pub after_label: String,
    /// Per sample: heading by the baseline model, degrees.
    pub heading_deg: Vec<f64>,
    /// Per sample: time in seconds, when the data has a `t` column.
    pub time: Option<Vec<f64>>,
    /// Per sample: |s|/r - 1 under the baseline model (a fraction).
    pub residual_before: Vec<f64>,
    /// Per sample: |s|/r - 1 under the improved model (may be empty).
    pub residual_after: Vec<f64>,
    /// Per sample: other logged columns, by name.
    pub covariates: Vec<(String, Vec<f64>)>,
    /// Estimated noise floor as an rms of |s|/r - 1 (a fraction); drawn as
    /// a ±band. Zero or non-finite: not drawn.
    pub noise_floor: f64,
    /// The ladder of models, each with the rms (fraction) it reaches, in
    /// the order the effects were added.
    pub ladder: Vec<(String, f64)>,
    /// Per model of the ladder (when a gyro was given): its name and its
    /// heading error against the gyro per sample, degrees (NaN where not
    /// checked). Empty: no gyro, no figure.
    pub heading_errors: Vec<(String, Vec<f64>)>,
    /// The gyro column the heading errors are taken against.
    pub heading_reference: String,
    /// The text of the diagnosis as an HTML fragment, already escaped by the
    /// caller; inserted into the page as is.
    pub summary_html: String,
}

/// Why a report could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("nothing to report: {what} is empty")]
    Empty { what: &'static str },
    #[error(
        "inconsistent report data: {what} has {len} values, expected {expected} (one per sample)"
    )]
    Length {
        what: String,
        len: usize,
        expected: usize,
    },
    #[error(
        "cannot create the report directory {}: {source}; choose another directory or fix its permissions",
        path.display()
    )]
    CreateDir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "cannot write {}: {source}; check the disk space and the directory's permissions",
        path.display()
    )]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot draw {file}: {message}")]
    Draw { file: String, message: String },
    #[error("the embedded font could not be loaded (this is a bug in fieldcal)")]
    Font,
}

/// One SVG figure of the report: its file name in the report directory, a
/// title and a caption for the page, and the SVG text.
#[derive(Debug, Clone)]
pub struct Figure {
    pub file: String,
    pub title: String,
    pub caption: String,
    pub svg: String,
}

/// Above this many points a series is thinned (every k-th sample) so each
/// SVG stays well under a megabyte and opens quickly; the plot title and
/// the page say so.
pub const MAX_POINTS: usize = 5_000;

/// The file name of the page that shows the figures.
pub const INDEX_FILE: &str = "index.html";

const SIZE: (u32, u32) = (800, 500);
const MARGIN: u32 = 12;
const X_LABEL_AREA: u32 = 45;
const Y_LABEL_AREA: u32 = 70;
const TITLE_SIZE: u32 = 20;
const LABEL_SIZE: u32 = 15;

/// The house layout of this module's charts (fixed margins and label
/// areas, so [`plot_pixels`] can predict the plotting area).
const HOUSE: FrameLayout = FrameLayout {
    margin: MARGIN,
    x_label_area: X_LABEL_AREA,
    y_label_area: Y_LABEL_AREA,
    tick_font: 13,
    desc_font: LABEL_SIZE,
};

/// Creates `dir` (and its parents), writes one SVG per figure and
/// `index.html`, and returns the paths written (the page last).
pub fn write_report(dir: &Path, data: &ReportData) -> Result<Vec<PathBuf>, ReportError> {
    validate(data)?;
    ensure_font()?;
    let figures = render_figures(data)?;
    write_figures(dir, &figures, |figures| {
        super::html::render_index(data, figures)
    })
}

/// Checks what every plot relies on, so a bad input is a clear error
/// rather than a misleading picture.
fn validate(data: &ReportData) -> Result<(), ReportError> {
    let (x, y) = &data.raw;
    if x.is_empty() || y.is_empty() {
        return Err(ReportError::Empty {
            what: "the raw samples",
        });
    }
    check_len("raw y", y.len(), x.len())?;
    if data.residual_before.is_empty() {
        return Err(ReportError::Empty {
            what: "the baseline residual",
        });
    }
    let n = data.residual_before.len();
    check_len("heading_deg", data.heading_deg.len(), n)?;
    if !data.residual_after.is_empty() {
        check_len("residual_after", data.residual_after.len(), n)?;
    }
    if let Some(t) = &data.time {
        check_len("time", t.len(), n)?;
    }
    for (name, values) in &data.covariates {
        check_len(&format!("covariate {name}"), values.len(), n)?;
    }
    Ok(())
}

fn check_len(what: &str, len: usize, expected: usize) -> Result<(), ReportError> {
    if len == expected {
        Ok(())
    } else {
        Err(ReportError::Length {
            what: what.to_string(),
            len,
            expected,
        })
    }
}

/// Draws every figure the data allows, in the order the page shows them.
pub fn render_figures(data: &ReportData) -> Result<Vec<Figure>, ReportError> {
    ensure_font()?;
    let n = data.residual_before.len();
    let mut figures = Vec::new();

    let file = "raw_ellipse.svg";
    let thin = Thinning::new(data.raw.0.len());
    let title = format!("Raw readings and fitted ellipse{}", thin.note());
    figures.push(Figure {
        file: file.into(),
        caption: format!(
            "{}: the raw readings and the ellipse the baseline model fits. \
             Equal scales on both axes, so the shape is the true shape.{}",
            data.title,
            thin.sentence()
        ),
        svg: draw(file, |area| raw_plot(area, &title, data, &thin))?,
        title,
    });

    let file = "calibrated.svg";
    let title = "Calibrated readings on the unit circle".to_string();
    let thin_note = Thinning::new(
        data.calibrated_before
            .len()
            .max(data.calibrated_after.len()),
    );
    figures.push(Figure {
        file: file.into(),
        caption: format!(
            "Samples calibrated and divided by r: left by {}, right by {}. \
             A good model puts them on the unit circle (grey).{}",
            display_label(&data.before_label, "the baseline model"),
            display_label(&data.after_label, "the improved model"),
            thin_note.sentence()
        ),
        svg: draw_sized(file, (1000, 520), |area| calibrated_plot(area, data))?,
        title,
    });

    let thin = Thinning::new(n);
    let file = "residual_heading.svg";
    let title = format!("Residual against heading{}", thin.note());
    figures.push(Figure {
        file: file.into(),
        caption: format!(
            "|s|/r − 1 of every sample against its heading, before and after the suggested \
             effect. Structure that repeats with heading (one or two waves per turn) is what \
             a model effect can remove; the grey band is the noise floor (±rms).{}",
            thin.sentence()
        ),
        svg: draw(file, |area| {
            residual_plot(area, &title, "heading (°)", &data.heading_deg, data, &thin)
        })?,
        title,
    });

    if let Some(time) = &data.time {
        let file = "residual_time.svg";
        let title = format!("Residual against time{}", thin.note());
        figures.push(Figure {
            file: file.into(),
            caption: format!(
                "|s|/r − 1 against time. A slope or a slow wander means the offset drifts \
                 during the run (warm-up).{}",
                thin.sentence()
            ),
            svg: draw(file, |area| {
                residual_plot(area, &title, "time (s)", time, data, &thin)
            })?,
            title,
        });
    }

    for (i, (name, values)) in data.covariates.iter().enumerate() {
        let file = format!("residual_covariate_{}.svg", i + 1);
        let title = format!("Residual against {name}{}", thin.note());
        let x_desc = format!("{name} (as logged)");
        figures.push(Figure {
            caption: format!(
                "|s|/r − 1 against the logged column “{name}”. A trend means the offset \
                 follows this quantity (effect covariate:{name}).{}",
                thin.sentence()
            ),
            svg: draw(&file, |area| {
                residual_plot(area, &title, &x_desc, values, data, &thin)
            })?,
            file,
            title,
        });
    }

    if !data.heading_errors.is_empty() {
        let file = "heading_gyro.svg";
        let title = format!(
            "Heading error against {}{}",
            data.heading_reference,
            thin.note()
        );
        figures.push(Figure {
            file: file.into(),
            caption: format!(
                "The heading of each model of the ladder less the heading the gyro {} \
                 integrates to (its scale, sign and bias fitted), against the heading. A model \
                 that makes |s| rounder by bending where samples point shows here as a larger \
                 wave.{}",
                data.heading_reference,
                thin.sentence()
            ),
            svg: draw(file, |area| heading_error_plot(area, &title, data, &thin))?,
            title,
        });
    }

    if !data.ladder.is_empty() {
        let file = "ladder.svg";
        let title = "Error per model step".to_string();
        figures.push(Figure {
            file: file.into(),
            caption: "The rms of |s|/r − 1 as effects are added one at a time. When a bar \
                      reaches the noise floor (dashed line), what is left is noise."
                .into(),
            svg: draw(file, |area| {
                ladder_plot(area, &title, &data.ladder, data.noise_floor)
            })?,
            title,
        });
    }
    Ok(figures)
}

fn display_label<'a>(label: &'a str, fallback: &'a str) -> &'a str {
    if label.trim().is_empty() {
        fallback
    } else {
        label
    }
}

fn draw(file: &str, f: impl FnOnce(&Svg) -> Result<(), DrawError>) -> Result<String, ReportError> {
    draw_sized(file, SIZE, f)
}

/// The plotting area a chart built by [`HOUSE`]'s [`FrameLayout::frame`]
/// gets inside `area` (after the title): the label areas and margins are
/// fixed sizes.
fn plot_pixels(area: &Svg) -> (u32, u32) {
    let (w, h) = area.dim_in_pixel();
    (
        w.saturating_sub(2 * MARGIN + Y_LABEL_AREA),
        h.saturating_sub(2 * MARGIN + X_LABEL_AREA),
    )
}

fn is_finite_pair(&(x, y): &(f64, f64)) -> bool {
    x.is_finite() && y.is_finite()
}

fn title_style() -> TextStyle<'static> {
    (FAMILY, TITLE_SIZE).into_font().color(&BLACK)
}

fn legend<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
) -> Result<(), DrawError> {
    legend_sized(chart, 13)
}

fn raw_plot(area: &Svg, title: &str, data: &ReportData, thin: &Thinning) -> Result<(), DrawError> {
    let body = area.titled(title, title_style())?;
    let (xs, ys) = &data.raw;
    let points: Vec<(f64, f64)> = thin
        .indices()
        .filter_map(|i| Some((*xs.get(i)?, *ys.get(i)?)))
        .filter(is_finite_pair)
        .collect();
    let ellipse: Vec<(f64, f64)> = data
        .ellipse
        .iter()
        .copied()
        .filter(is_finite_pair)
        .collect();
    let all = || points.iter().chain(ellipse.iter());
    let x = span(all().map(|p| p.0)).unwrap_or(-1.0..1.0);
    let y = span(all().map(|p| p.1)).unwrap_or(-1.0..1.0);
    let (x, y) = equal_aspect(x, y, plot_pixels(&body));
    let mut chart = HOUSE.frame(&body, x, y, "raw x (sensor units)", "raw y (sensor units)")?;
    sample_dots(&mut chart, &points, BEFORE)?;
    if !ellipse.is_empty() {
        let mut closed = ellipse.clone();
        closed.extend(ellipse.first().copied());
        chart
            .draw_series(LineSeries::new(closed, FIT.stroke_width(2)))?
            .label("fitted ellipse")
            .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], FIT.stroke_width(2)));
    }
    legend(&mut chart)
}

fn calibrated_plot(area: &Svg, data: &ReportData) -> Result<(), DrawError> {
    let panels = area.split_evenly((1, 2));
    let sides = [
        (
            &data.calibrated_before,
            display_label(&data.before_label, "baseline"),
            BEFORE,
        ),
        (
            &data.calibrated_after,
            display_label(&data.after_label, "with the suggested effect"),
            AFTER,
        ),
    ];
    for (panel, (points, label, color)) in panels.iter().zip(sides) {
        let thin = Thinning::new(points.len());
        let body = panel.titled(&format!("{label}{}", thin.note()), (FAMILY, 16).into_font())?;
        let shown: Vec<(f64, f64)> = thin
            .indices()
            .filter_map(|i| points.get(i).copied())
            .filter(is_finite_pair)
            .collect();
        // At least the unit circle with a little room, more if points lie
        // further out.
        let reach = shown
            .iter()
            .map(|&(x, y)| x.abs().max(y.abs()))
            .fold(1.0_f64, f64::max)
            * 1.08;
        let (x, y) = equal_aspect(-reach..reach, -reach..reach, plot_pixels(&body));
        let mut chart = HOUSE.frame(&body, x, y, "x / r", "y / r")?;
        let circle: Vec<(f64, f64)> = (0..=360)
            .map(|d| f64::from(d).to_radians())
            .map(|a| (a.cos(), a.sin()))
            .collect();
        chart
            .draw_series(LineSeries::new(circle, FLOOR.stroke_width(1)))?
            .label("unit circle")
            .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], FLOOR));
        if shown.is_empty() {
            chart.draw_series(std::iter::once(Text::new(
                "no data for this model",
                (-0.5, 0.0),
                (FAMILY, 15).into_font(),
            )))?;
        } else {
            sample_dots(&mut chart, &shown, color)?;
        }
        legend(&mut chart)?;
    }
    Ok(())
}

/// Residual (in %) against `xs`, before and after, with the noise floor as
/// a grey ±band and dashed edges.
fn residual_plot(
    area: &Svg,
    title: &str,
    x_desc: &str,
    xs: &[f64],
    data: &ReportData,
    thin: &Thinning,
) -> Result<(), DrawError> {
    let body = area.titled(title, title_style())?;
    let series = |values: &[f64]| -> Vec<(f64, f64)> {
        thin.indices()
            .filter_map(|i| Some((*xs.get(i)?, *values.get(i)? * 100.0)))
            .filter(is_finite_pair)
            .collect()
    };
    let before = series(&data.residual_before);
    let after = series(&data.residual_after);
    let floor = if data.noise_floor.is_finite() && data.noise_floor > 0.0 {
        Some(data.noise_floor * 100.0)
    } else {
        None
    };
    let all = || before.iter().chain(after.iter());
    let mut x = span(all().map(|p| p.0)).unwrap_or(0.0..1.0);
    if x_desc.starts_with("heading") {
        // Whole turns read better than a padded data range.
        if x.start >= -20.0 && x.end <= 380.0 {
            x = 0.0..360.0;
        } else if x.start >= -200.0 && x.end <= 200.0 {
            x = -180.0..180.0;
        }
    }
    let values: Vec<f64> = all().map(|p| p.1).collect();
    let scale = residual_scale(&values, floor);
    let rows = 1
        + usize::from(floor.is_some())
        + usize::from(!after.is_empty())
        + usize::from(scale.clipped);
    let y = with_legend_room(scale.range.clone(), rows, plot_pixels(&body).1);
    let mut chart = HOUSE.frame(&body, x.clone(), y, x_desc, "|s|/r − 1 (%)")?;
    if let Some(f) = floor {
        floor_band(&mut chart, &x, f, 0.15)?;
        for edge in [f, -f] {
            chart.draw_series(DashedLineSeries::new(
                [(x.start, edge), (x.end, edge)],
                6,
                4,
                FLOOR.stroke_width(1),
            ))?;
        }
    }
    let size = if before.len() > 2000 { 1 } else { 2 };
    let on_scale = |p: &&(f64, f64)| scale.range.contains(&p.1);
    before_and_after(
        &mut chart,
        (&before, &after),
        |p| on_scale(&p).then_some(*p),
        size,
        (
            display_label(&data.before_label, "baseline").to_string(),
            display_label(&data.after_label, "with the suggested effect").to_string(),
        ),
    )?;
    if scale.clipped {
        // Points off the scale stay visible: a triangle at the edge, in
        // their model's colour, pointing the way they went.
        let range = &scale.range;
        let edge_markers = |points: &[(f64, f64)], colour: RGBColor| {
            points
                .iter()
                .filter(|p| !range.contains(&p.1))
                .map(|&(x, y)| {
                    let (at, tip, base) = if y >= range.end {
                        (range.end, -4, 4)
                    } else {
                        (range.start, 4, -4)
                    };
                    EmptyElement::at((x, at))
                        + Polygon::new(vec![(0, tip), (-4, base), (4, base)], colour.filled())
                })
                .collect::<Vec<_>>()
        };
        // Counted by sample: both models' markers of one sample share its x.
        let mut off_scale: Vec<u64> = all()
            .filter(|p| !range.contains(&p.1))
            .map(|p| p.0.to_bits())
            .collect();
        off_scale.sort_unstable();
        off_scale.dedup();
        let samples = off_scale.len();
        chart.draw_series(edge_markers(&after, AFTER))?;
        chart
            .draw_series(edge_markers(&before, BEFORE))?
            .label(format!(
                "{samples} sample{} beyond the scale, at its edge",
                if samples == 1 { "" } else { "s" }
            ))
            .legend(|(x, y)| {
                Polygon::new(
                    vec![(x, y - 4), (x - 4, y + 4), (x + 4, y + 4)],
                    FLOOR.filled(),
                )
            });
    }
    legend(&mut chart)
}

/// The samples of a plot of readings, as dots in `colour`, counted in the
/// legend.
fn sample_dots<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
    points: &[(f64, f64)],
    colour: RGBColor,
) -> Result<(), DrawError> {
    point_series(
        chart,
        points.iter().copied(),
        (2, colour.mix(0.45)),
        colour,
        format!("samples ({})", points.len()),
    )
}

/// Colours of the ladder's models in the heading plot, in order.
const MODEL_COLOURS: [RGBColor; 6] = [
    BEFORE,
    AFTER,
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];

/// Heading error against the gyro, per model of the ladder, against the
/// baseline's heading: the residual plots' heading axis and robust scale.
fn heading_error_plot(
    area: &Svg,
    title: &str,
    data: &ReportData,
    thin: &Thinning,
) -> Result<(), DrawError> {
    let body = area.titled(title, title_style())?;
    let models: Vec<(&str, Vec<(f64, f64)>)> = data
        .heading_errors
        .iter()
        .map(|(name, errors)| {
            let points = thin
                .indices()
                .filter_map(|i| Some((*data.heading_deg.get(i)?, *errors.get(i)?)))
                .filter(is_finite_pair)
                .collect();
            (name.as_str(), points)
        })
        .collect();
    let values: Vec<f64> = models
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.1))
        .collect();
    let scale = residual_scale(&values, None);
    let y = with_legend_room(scale.range.clone(), models.len(), plot_pixels(&body).1);
    let mut chart = HOUSE.frame(&body, 0.0..360.0, y, "heading (°)", "heading − gyro (°)")?;
    let size = if values.len() > 2000 { 1 } else { 2 };
    for (k, (name, points)) in models.iter().enumerate() {
        let colour = MODEL_COLOURS[k % MODEL_COLOURS.len()];
        point_series(
            &mut chart,
            points
                .iter()
                .filter(|p| scale.range.contains(&p.1))
                .copied(),
            (size, colour.mix(0.5)),
            colour,
            display_label(name, "model").to_string(),
        )?;
    }
    legend(&mut chart)
}

/// Horizontal bars, one per model step, top to bottom in ladder order, with
/// the model name written above each bar (names can be long, so not on an
/// axis) and the noise floor as a dashed vertical line.
fn ladder_plot(
    area: &Svg,
    title: &str,
    ladder: &[(String, f64)],
    noise_floor: f64,
) -> Result<(), DrawError> {
    let body = area.titled(title, title_style())?;
    let floor = (noise_floor.is_finite() && noise_floor > 0.0).then_some(noise_floor * 100.0);
    let top = ladder
        .iter()
        .map(|(_, rms)| rms * 100.0)
        .chain(floor)
        .filter(|v| v.is_finite())
        .fold(0.0_f64, f64::max);
    let top = if top > 0.0 { top * 1.15 } else { 1.0 };
    let n = ladder.len() as f64;
    let mut chart = ChartBuilder::on(&body)
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(20)
        .build_cartesian_2d(0.0..top, -0.6..n - 0.2)?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(0)
        .x_desc("rms of |s|/r − 1 (%)")
        .label_style((FAMILY, 13))
        .x_label_formatter(&|v| tick_label(*v))
        .axis_desc_style((FAMILY, LABEL_SIZE))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()?;
    for (i, (name, rms)) in ladder.iter().enumerate() {
        // Step 0 at the top.
        let row = n - 1.0 - i as f64;
        let value = rms * 100.0;
        let color = if i == 0 { BEFORE } else { AFTER };
        if value.is_finite() {
            chart.draw_series(std::iter::once(Rectangle::new(
                [(0.0, row - 0.4), (value.min(top), row)],
                color.mix(0.8).filled(),
            )))?;
        }
        let text = if value.is_finite() {
            format!("{}. {name}: {}%", i + 1, super::significant(value, 3))
        } else {
            format!("{}. {name}: not available", i + 1)
        };
        chart.draw_series(std::iter::once(Text::new(
            text,
            (top * 0.005, row + 0.17),
            (FAMILY, 14).into_font(),
        )))?;
    }
    if let Some(f) = floor {
        chart
            .draw_series(DashedLineSeries::new(
                [(f, -0.6), (f, n - 0.2)],
                6,
                4,
                FLOOR.stroke_width(2),
            ))?
            .label(format!("noise floor {}%", super::significant(f, 2)))
            .legend(|(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], FLOOR.stroke_width(2)));
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FAMILY, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .draw()?;
    }
    Ok(())
}

/// Synthetic report data: a noisy, tilted ellipse turned `n` times around
/// the circle, whose baseline residual is a second harmonic of heading that
/// the "after" model removes. Public so integration tests (and examples)
/// can draw a realistic report without a fit.
#[doc(hidden)]
pub fn demo_data(n: usize) -> ReportData {
    let noise = |i: usize, k: u64| {
        // A cheap deterministic pseudo-noise in [-1, 1]: no rand needed.
        let h = (i as u64 + 1)
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(k.wrapping_mul(1_442_695_040_888_963_407));
        ((h >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let (r, cx, cy, sx, sy, tilt) = (400.0, 120.0, -80.0, 1.1, 0.9, 0.15_f64);
    let mut data = ReportData {
        title: "synthetic.csv: x = mag_x, y = mag_y <&>".into(),
        before_label: "offset+scale".into(),
        after_label: "offset+scale+cross-axis".into(),
        noise_floor: 0.002,
        summary_html: "<p>Suggested effect: <code>cross-axis</code>.</p>".into(),
        ladder: vec![
            ("offset+scale".into(), 0.021),
            ("+cross-axis".into(), 0.0031),
            ("+cross-axis+drift".into(), 0.0021),
        ],
        ..ReportData::default()
    };
    let mut temperature = Vec::with_capacity(n);
    let mut time = Vec::with_capacity(n);
    for i in 0..n {
        let a = i as f64 / n.max(1) as f64 * std::f64::consts::TAU * 2.0;
        let (u, v) = (r * sx * a.cos(), r * sy * (a + tilt).sin());
        data.raw.0.push(cx + u + 2.0 * noise(i, 1));
        data.raw.1.push(cy + v + 2.0 * noise(i, 2));
        let before = 0.02 * (2.0 * a).cos() + 0.002 * noise(i, 3);
        let after = 0.002 * noise(i, 4);
        data.residual_before.push(before);
        data.residual_after.push(after);
        data.calibrated_before
            .push(((1.0 + before) * a.cos(), (1.0 + before) * a.sin()));
        data.calibrated_after
            .push(((1.0 + after) * a.cos(), (1.0 + after) * a.sin()));
        data.heading_deg.push(a.to_degrees().rem_euclid(360.0));
        time.push(i as f64 * 0.05);
        temperature.push(25.0 + 5.0 * i as f64 / n.max(1) as f64);
    }
    data.ellipse = (0..200)
        .map(|k| f64::from(k) / 200.0 * std::f64::consts::TAU)
        .map(|a| (cx + r * sx * a.cos(), cy + r * sy * (a + tilt).sin()))
        .collect();
    data.time = Some(time);
    data.covariates = vec![("temp °C".into(), temperature)];
    data
}
