//! The house style both reports draw with ([`super::plots`] on the plane
//! of a turn, [`super::plots3`] on the sphere of a tumble): the embedded
//! font, the colours, a chart's frame and legend, the series every report
//! draws (samples, residuals before and after, the noise floor), rendering
//! a figure to SVG text, thinning large inputs, and writing the report
//! directory.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use super::plots::{Figure, INDEX_FILE, MAX_POINTS, ReportError};
use super::scale::tick_label;

/// DejaVu Sans (Bitstream Vera licence, see assets/DejaVuSans.LICENSE.txt):
/// plotters needs a font to measure text and we cannot count on system
/// fonts on a headless box.
const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// The family plotters asks for by default and writes into the SVG's
/// `font-family`: a browser without DejaVu Sans falls back to its own sans.
pub(super) const FAMILY: &str = "sans-serif";

/// The house colours: the baseline model, the improved model, a fitted
/// curve, and the noise floor.
pub(super) const BEFORE: RGBColor = RGBColor(31, 119, 180);
pub(super) const AFTER: RGBColor = RGBColor(230, 110, 0);
pub(super) const FIT: RGBColor = RGBColor(200, 30, 30);
pub(super) const FLOOR: RGBColor = RGBColor(90, 90, 90);

/// The drawing area every figure is drawn on.
pub(super) type Svg<'a> = DrawingArea<SVGBackend<'a>, Shift>;
/// The coordinates of every chart: x and y as plain numbers.
pub(super) type Plane = Cartesian2d<RangedCoordf64, RangedCoordf64>;
/// What drawing on an [`Svg`] can fail with.
pub(super) type DrawError = DrawingAreaErrorKind<std::io::Error>;

/// The sizes (pixels) a chart's frame and mesh are laid out with.
#[derive(Debug, Clone, Copy)]
pub(super) struct FrameLayout {
    pub margin: u32,
    pub x_label_area: u32,
    pub y_label_area: u32,
    /// The font size of the tick labels.
    pub tick_font: u32,
    /// The font size of the axis descriptions.
    pub desc_font: u32,
}

/// Registers the embedded font once per process.
pub(super) fn ensure_font() -> Result<(), ReportError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| register_font(FAMILY, FontStyle::Normal, FONT).is_ok());
    if ok { Ok(()) } else { Err(ReportError::Font) }
}

/// Creates `dir` (and its parents), writes one SVG per figure and then the
/// page `index` makes of them, and returns the paths written (the page
/// last).
pub(super) fn write_figures(
    dir: &Path,
    figures: &[Figure],
    index: impl FnOnce(&[Figure]) -> String,
) -> Result<Vec<PathBuf>, ReportError> {
    std::fs::create_dir_all(dir).map_err(|source| ReportError::CreateDir {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut written = Vec::with_capacity(figures.len() + 1);
    for figure in figures {
        let path = dir.join(&figure.file);
        write_file(&path, &figure.svg)?;
        written.push(path);
    }
    let path = dir.join(INDEX_FILE);
    write_file(&path, &index(figures))?;
    written.push(path);
    Ok(written)
}

fn write_file(path: &Path, text: &str) -> Result<(), ReportError> {
    std::fs::write(path, text).map_err(|source| ReportError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Which samples a plot draws: all of them, or every `step`-th.
#[derive(Debug, Clone, Copy)]
pub(super) struct Thinning {
    n: usize,
    step: usize,
}

impl Thinning {
    /// Every sample of `n`, or every k-th so no more than [`MAX_POINTS`]
    /// are drawn.
    pub(super) fn new(n: usize) -> Self {
        Thinning {
            n,
            step: n.div_ceil(MAX_POINTS).max(1),
        }
    }

    /// The samples drawn.
    pub(super) fn indices(&self) -> impl Iterator<Item = usize> + Clone + use<> {
        (0..self.n).step_by(self.step)
    }

    /// A short note for a plot title.
    pub(super) fn note(&self) -> String {
        if self.step > 1 {
            format!(" (1 in {} of {} samples shown)", self.step, self.n)
        } else {
            String::new()
        }
    }

    /// A sentence for the page.
    pub(super) fn sentence(&self) -> String {
        if self.step > 1 {
            format!(
                " To keep the file small, every {}th of the {} samples is drawn.",
                self.step, self.n
            )
        } else {
            String::new()
        }
    }
}

/// Renders into a string (not straight to a file) so that file errors are
/// ours to report with the path, and drawing errors name the figure.
pub(super) fn draw_sized(
    file: &str,
    size: (u32, u32),
    f: impl FnOnce(&Svg) -> Result<(), DrawError>,
) -> Result<String, ReportError> {
    let mut svg = String::new();
    {
        let area = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        let result = area
            .fill(&WHITE)
            .and_then(|()| f(&area))
            .and_then(|()| area.present());
        result.map_err(|e| ReportError::Draw {
            file: file.to_string(),
            message: e.to_string(),
        })?;
    }
    Ok(svg)
}

impl FrameLayout {
    /// A chart laid out by this layout, with its mesh (light grid, tick
    /// labels by [`tick_label`], both axes described) drawn.
    pub(super) fn frame<'a, 'b: 'a>(
        &self,
        area: &'a Svg<'b>,
        x: Range<f64>,
        y: Range<f64>,
        x_desc: &str,
        y_desc: &str,
    ) -> Result<ChartContext<'a, SVGBackend<'b>, Plane>, DrawError> {
        let mut chart = ChartBuilder::on(area)
            .margin(self.margin)
            .x_label_area_size(self.x_label_area)
            .y_label_area_size(self.y_label_area)
            .build_cartesian_2d(x, y)?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .label_style((FAMILY, self.tick_font))
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .axis_desc_style((FAMILY, self.desc_font))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(215, 215, 215))
            .draw()?;
        Ok(chart)
    }
}

/// The series labels in the upper right corner, in a `font_size` font on
/// a pale box.
pub(super) fn legend_sized<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
    font_size: u32,
) -> Result<(), DrawError> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FAMILY, font_size))
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(160, 160, 160))
        .draw()
}

/// The noise floor as a grey band of ±`f` across `x` (`opacity` its fill),
/// with its legend entry.
pub(super) fn floor_band<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
    x: &Range<f64>,
    f: f64,
    opacity: f64,
) -> Result<(), DrawError> {
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(x.start, -f), (x.end, f)],
            FLOOR.mix(opacity).filled(),
        )))?
        .label(format!("noise floor ±{}%", super::significant(f, 2)))
        .legend(|(x, y)| Rectangle::new([(x - 8, y - 5), (x + 8, y + 5)], FLOOR.mix(0.3).filled()));
    Ok(())
}

/// `points` as dots of `(radius, fill)`, with a legend entry `label` (a
/// solid dot in `colour`).
pub(super) fn point_series<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
    points: impl Iterator<Item = (f64, f64)>,
    (size, fill): (i32, RGBAColor),
    colour: RGBColor,
    label: String,
) -> Result<(), DrawError> {
    chart
        .draw_series(points.map(|p| Circle::new(p, size, fill.filled())))?
        .label(label)
        .legend(move |(x, y)| Circle::new((x, y), 3, colour.filled()));
    Ok(())
}

/// A point of a figure, (x, y).
type Point = (f64, f64);

/// The residuals under the baseline model (in [`BEFORE`]) and, when there
/// are any, under the improved one (in [`AFTER`]): each point `shown` makes
/// of them as a half-transparent dot of radius `size`, with its model's
/// label in the legend.
pub(super) fn before_and_after<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
    (before, after): (&[Point], &[Point]),
    shown: impl Fn(&Point) -> Option<Point>,
    size: i32,
    (before_label, after_label): (String, String),
) -> Result<(), DrawError> {
    let models = [(before, BEFORE, before_label), (after, AFTER, after_label)];
    for (k, (points, colour, label)) in models.into_iter().enumerate() {
        // The baseline is always in the legend, the improved model only
        // when there is one.
        if k > 0 && points.is_empty() {
            continue;
        }
        let dots = points.iter().filter_map(&shown);
        point_series(chart, dots, (size, colour.mix(0.5)), colour, label)?;
    }
    Ok(())
}
