//! SVG plots of a 3-axis diagnosis (`fieldcal diagnose --report DIR` on
//! three axes), and the page that shows them. Plain data in
//! ([`Report3Data`]), pictures out; drawn with `plotters` as
//! [`super::plots`] does, with the same embedded font.
//!
//! - `sphere_residual.svg`: the residual against direction, on an
//!   equirectangular map of the sphere (azimuth × elevation, in the sensor
//!   frame of the calibrated samples), coloured by the residual; the
//!   regions of the coverage partition no sample reached are hatched grey.
//! - `ellipsoid_views.svg`: the raw points and the fitted ellipsoid's
//!   outline in three projections (x–y, x–z, y–z).
//! - `residual_time.svg`: the residual against time, before and after the
//!   ladder's effects, with the noise floor as a band.
//! - `ladder.svg`: the rms of each step of the ladder against the noise
//!   floor.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix2, Matrix3};
use plotters::prelude::*;

use super::chart::{
    BEFORE, DrawError, FAMILY, FIT, FLOOR, FrameLayout, Svg, Thinning, before_and_after,
    draw_sized as draw, ensure_font, floor_band, legend_sized, write_figures,
};
use super::html::{PAGE3, render_page};
use super::plots::{Figure, ReportError};
use super::scale::{equal_aspect, residual_scale, span};
use crate::model::sphere;

/// Everything a 3-axis report shows. Per-sample vectors have one value per
/// sample (`raw`'s length); non-finite values are skipped when drawing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Report3Data {
    pub title: String,
    /// The diagnosis as an HTML fragment, already escaped.
    pub summary_html: String,
    /// Raw readings, sensor units.
    pub raw: Vec<[f64; 3]>,
    /// Column names of the three axes.
    pub axes: [String; 3],
    /// The baseline fit: o, W (row-major, det 1) and r.
    pub offset: [f64; 3],
    pub matrix: [[f64; 3]; 3],
    pub r: f64,
    /// Per sample: the calibrated direction (any length) by the final
    /// model of the ladder.
    pub directions: Vec<[f64; 3]>,
    /// Per sample: |calibrated|/r − 1 by the baseline and by the final model
    /// (the latter may be empty when the ladder has one step).
    pub residual_before: Vec<f64>,
    pub residual_after: Vec<f64>,
    pub before_label: String,
    pub after_label: String,
    /// Per sample: time, seconds.
    pub time: Option<Vec<f64>>,
    /// Per region of [`sphere`]'s partition: whether a sample reached it.
    pub covered: Vec<bool>,
    /// The noise floor (fraction of the field).
    pub noise_floor: f64,
    /// The ladder: model name and rms.
    pub ladder: Vec<(String, f64)>,
}

/// The layout of the 3-axis charts: a little tighter than the 2-D
/// report's.
const LAYOUT: FrameLayout = FrameLayout {
    margin: 12,
    x_label_area: 40,
    y_label_area: 60,
    tick_font: 12,
    desc_font: 14,
};

/// Every k-th sample, so no figure draws more than
/// [`super::plots::MAX_POINTS`].
fn thinned(n: usize) -> impl Iterator<Item = usize> + Clone {
    Thinning::new(n).indices()
}

fn check(data: &Report3Data) -> Result<(), ReportError> {
    let n = data.raw.len();
    if n == 0 {
        return Err(ReportError::Empty {
            what: "the raw samples",
        });
    }
    let lengths = [
        ("directions", data.directions.len()),
        ("residual_before", data.residual_before.len()),
    ];
    for (what, len) in lengths {
        if len != n {
            return Err(ReportError::Length {
                what: what.into(),
                len,
                expected: n,
            });
        }
    }
    if !data.residual_after.is_empty() && data.residual_after.len() != n {
        return Err(ReportError::Length {
            what: "residual_after".into(),
            len: data.residual_after.len(),
            expected: n,
        });
    }
    if let Some(t) = &data.time
        && t.len() != n
    {
        return Err(ReportError::Length {
            what: "time".into(),
            len: t.len(),
            expected: n,
        });
    }
    Ok(())
}

/// Draws the figures, in the order the page shows them.
pub fn render_figures3(data: &Report3Data) -> Result<Vec<Figure>, ReportError> {
    check(data)?;
    ensure_font()?;
    let mut figures = Vec::new();
    let shown = if data.residual_after.is_empty() {
        &data.residual_before
    } else {
        &data.residual_after
    };
    let label = if data.residual_after.is_empty() {
        &data.before_label
    } else {
        &data.after_label
    };
    let title = format!("Residual against direction ({label})");
    figures.push(Figure {
        file: "sphere_residual.svg".into(),
        caption: format!(
            "{}: every sample at the direction of its calibrated reading (azimuth from +x toward +y, elevation toward +z, sensor frame; equirectangular), coloured by |s|/r − 1 under {label}: red above the field, blue below, white at zero. Patches of one colour are structure tied to direction (a leftover offset shows as one warm and one cold hemisphere, a leftover gain or coupling as two of each); speckle is noise. Hatched grey: regions of the 100-region equal-area partition no sample reached.",
            data.title
        ),
        svg: draw("sphere_residual.svg", (900, 520), |area| {
            sphere_map(area, &title, data, shown)
        })?,
        title,
    });
    let title = "Raw readings and the fitted ellipsoid, three views".to_string();
    figures.push(Figure {
        file: "ellipsoid_views.svg".into(),
        caption: format!(
            "The raw readings projected on the planes of two axes, with the outline of the ellipsoid the baseline model ({}) fits (its shadow on that plane). Equal scales on both axes of each view.",
            data.before_label
        ),
        svg: draw("ellipsoid_views.svg", (1200, 430), |area| {
            ellipsoid_views(area, &title, data)
        })?,
        title,
    });
    if let Some(time) = &data.time {
        let title = "Residual against time".to_string();
        figures.push(Figure {
            file: "residual_time.svg".into(),
            caption: "|s|/r − 1 against time, under the baseline model (blue) and the last model of the ladder (orange); the grey band is the noise floor (±rms). A slope or a slow wander means the offset moves during the run; bursts that follow the motion are not a calibration effect.".into(),
            svg: draw("residual_time.svg", (900, 480), |area| {
                residual_time(area, &title, data, time)
            })?,
            title,
        });
    }
    if !data.ladder.is_empty() {
        let title = "Error per model step".to_string();
        figures.push(Figure {
            file: "ladder.svg".into(),
            caption: "The rms of |s|/r − 1 as effects are added one at a time; the dashed line is the noise floor. When the last bar reaches it, what remains is noise.".into(),
            svg: draw("ladder.svg", (900, 420), |area| ladder(area, &title, data))?,
            title,
        });
    }
    Ok(figures)
}

/// Writes the SVGs and `index.html` into `dir`; returns the paths (the
/// page last).
pub fn write_report3(dir: &Path, data: &Report3Data) -> Result<Vec<PathBuf>, ReportError> {
    let figures = render_figures3(data)?;
    write_figures(dir, &figures, |figures| index(data, figures))
}

fn index(data: &Report3Data, figures: &[Figure]) -> String {
    render_page(&PAGE3, &data.title, &data.summary_html, figures)
}

/// Diverging colour: blue (−1) through white (0) to red (+1).
fn diverging(v: f64) -> RGBColor {
    let v = v.clamp(-1.0, 1.0);
    let mix = |a: u8, b: u8, t: f64| (a as f64 + (b as f64 - a as f64) * t).round() as u8;
    if v >= 0.0 {
        RGBColor(mix(255, 200, v), mix(255, 30, v), mix(255, 30, v))
    } else {
        RGBColor(mix(255, 31, -v), mix(255, 90, -v), mix(255, 200, -v))
    }
}

fn azimuth_elevation(d: &[f64; 3]) -> Option<(f64, f64)> {
    let m = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if !(m > 0.0) || !m.is_finite() {
        return None;
    }
    Some((
        d[1].atan2(d[0]).to_degrees(),
        (d[2] / m).clamp(-1.0, 1.0).asin().to_degrees(),
    ))
}

fn sphere_map(area: &Svg, title: &str, data: &Report3Data, e: &[f64]) -> Result<(), DrawError> {
    let body = area.titled(title, (FAMILY, 18).into_font().color(&BLACK))?;
    let (map, key) = body.split_horizontally(body.dim_in_pixel().0.saturating_sub(110));
    let mut chart = LAYOUT.frame(
        &map,
        -180.0..180.0,
        -90.0..90.0,
        "azimuth (°, from +x toward +y)",
        "elevation (°, toward +z)",
    )?;
    // Uncovered regions: grey with hatching (azimuth 0..360 → −180..180).
    for (k, covered) in data.covered.iter().enumerate() {
        if *covered {
            continue;
        }
        let region = sphere::region(k);
        let (el0, el1) = region.elevation_deg;
        let (a0, a1) = region.azimuth_deg;
        let pieces: Vec<(f64, f64)> = if a1 <= 180.0 {
            vec![(a0, a1)]
        } else if a0 >= 180.0 {
            vec![(a0 - 360.0, a1 - 360.0)]
        } else {
            vec![(a0, 180.0), (-180.0, a1 - 360.0)]
        };
        for (lo, hi) in pieces {
            chart.draw_series(std::iter::once(Rectangle::new(
                [(lo, el0), (hi, el1)],
                RGBColor(200, 200, 200).mix(0.6).filled(),
            )))?;
            let mut lines = Vec::new();
            let mut x = lo;
            while x < hi {
                lines.push(PathElement::new(
                    vec![(x, el0), ((x + (el1 - el0) * 0.5).min(hi), el1)],
                    RGBColor(120, 120, 120).stroke_width(1),
                ));
                x += 6.0;
            }
            chart.draw_series(lines)?;
        }
    }
    let finite: Vec<f64> = e.iter().copied().filter(|v| v.is_finite()).collect();
    let scale = residual_scale(&finite, None);
    let limit = scale
        .range
        .start
        .abs()
        .max(scale.range.end.abs())
        .max(1e-12);
    let points: Vec<((f64, f64), f64)> = thinned(e.len())
        .filter_map(|i| {
            let ae = azimuth_elevation(data.directions.get(i)?)?;
            let v = *e.get(i)?;
            v.is_finite().then_some((ae, v))
        })
        .collect();
    let size = if points.len() > 2000 { 2 } else { 3 };
    chart.draw_series(
        points
            .iter()
            .map(|&(p, v)| Circle::new(p, size, diverging(v / limit).filled())),
    )?;
    // The colour key.
    let (_, h) = key.dim_in_pixel();
    let top = 40i32;
    let bottom = h as i32 - 60;
    let steps = 40;
    for s in 0..steps {
        let v = 1.0 - 2.0 * s as f64 / (steps - 1) as f64;
        let y0 = top + (bottom - top) * s / steps;
        let y1 = top + (bottom - top) * (s + 1) / steps;
        key.draw(&Rectangle::new([(10, y0), (35, y1)], diverging(v).filled()))?;
    }
    let label = |v: f64| format!("{} %", super::significant(v * 100.0, 2));
    let style = (FAMILY, 12).into_font().color(&BLACK);
    key.draw(&Text::new(label(limit), (40, top - 6), style.clone()))?;
    key.draw(&Text::new(
        "0".to_string(),
        (40, (top + bottom) / 2 - 6),
        style.clone(),
    ))?;
    key.draw(&Text::new(label(-limit), (40, bottom - 6), style.clone()))?;
    key.draw(&Rectangle::new(
        [(10, bottom + 15), (35, bottom + 30)],
        RGBColor(200, 200, 200).filled(),
    ))?;
    key.draw(&Text::new(
        "no sample".to_string(),
        (10, bottom + 34),
        style,
    ))?;
    Ok(())
}

/// The shadow of the ellipsoid {x: |W(x − o)| = r} on the plane of axes
/// (i, j): with Σ = r²·(WᵀW)⁻¹, the outline is o + L·(cos φ, sin φ), L the
/// Cholesky factor of Σ's (i, j) block.
fn outline(data: &Report3Data, i: usize, j: usize) -> Vec<(f64, f64)> {
    let w = Matrix3::from_fn(|a, b| data.matrix[a][b]);
    let Some(inv) = (w.transpose() * w).try_inverse() else {
        return Vec::new();
    };
    let sigma = inv * (data.r * data.r);
    let block = Matrix2::new(sigma[(i, i)], sigma[(i, j)], sigma[(j, i)], sigma[(j, j)]);
    let Some(chol) = block.cholesky() else {
        return Vec::new();
    };
    let l = chol.l();
    (0..=180)
        .map(|k| {
            let phi = k as f64 / 180.0 * std::f64::consts::TAU;
            let (c, s) = (phi.cos(), phi.sin());
            (
                data.offset[i] + l[(0, 0)] * c,
                data.offset[j] + l[(1, 0)] * c + l[(1, 1)] * s,
            )
        })
        .collect()
}

fn ellipsoid_views(area: &Svg, title: &str, data: &Report3Data) -> Result<(), DrawError> {
    let body = area.titled(title, (FAMILY, 18).into_font().color(&BLACK))?;
    let panels = body.split_evenly((1, 3));
    for (panel, (i, j)) in panels.iter().zip([(0, 1), (0, 2), (1, 2)]) {
        let points: Vec<(f64, f64)> = thinned(data.raw.len())
            .map(|k| (data.raw[k][i], data.raw[k][j]))
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .collect();
        let shape = outline(data, i, j);
        let all = || points.iter().chain(shape.iter());
        let x = span(all().map(|p| p.0)).unwrap_or(-1.0..1.0);
        let y = span(all().map(|p| p.1)).unwrap_or(-1.0..1.0);
        let (pw, ph) = panel.dim_in_pixel();
        let (x, y) = equal_aspect(
            x,
            y,
            (pw.saturating_sub(24 + 60), ph.saturating_sub(24 + 40)),
        );
        let mut chart = LAYOUT.frame(panel, x, y, &data.axes[i], &data.axes[j])?;
        chart.draw_series(
            points
                .iter()
                .map(|&p| Circle::new(p, 1, BEFORE.mix(0.4).filled())),
        )?;
        if !shape.is_empty() {
            chart.draw_series(LineSeries::new(shape, FIT.stroke_width(2)))?;
        }
    }
    Ok(())
}

fn residual_time(
    area: &Svg,
    title: &str,
    data: &Report3Data,
    time: &[f64],
) -> Result<(), DrawError> {
    let body = area.titled(title, (FAMILY, 18).into_font().color(&BLACK))?;
    let series = |e: &[f64]| -> Vec<(f64, f64)> {
        thinned(e.len())
            .filter_map(|i| Some((*time.get(i)?, *e.get(i)? * 100.0)))
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .collect()
    };
    let before = series(&data.residual_before);
    let after = series(&data.residual_after);
    let floor = (data.noise_floor.is_finite() && data.noise_floor > 0.0)
        .then_some(data.noise_floor * 100.0);
    let values: Vec<f64> = before.iter().chain(&after).map(|p| p.1).collect();
    let scale = residual_scale(&values, floor);
    let x = span(before.iter().map(|p| p.0)).unwrap_or(0.0..1.0);
    let mut chart = LAYOUT.frame(
        &body,
        x.clone(),
        scale.range.clone(),
        "time (s)",
        "|s|/r − 1 (%)",
    )?;
    if let Some(f) = floor {
        floor_band(&mut chart, &x, f, 0.2)?;
    }
    let range = scale.range.clone();
    let clip = move |p: &(f64, f64)| (p.0, p.1.clamp(range.start, range.end));
    before_and_after(
        &mut chart,
        (&before, &after),
        |p| Some(clip(p)),
        1,
        (data.before_label.clone(), data.after_label.clone()),
    )?;
    legend_sized(&mut chart, 12)
}

fn ladder(area: &Svg, title: &str, data: &Report3Data) -> Result<(), DrawError> {
    let body = area.titled(title, (FAMILY, 18).into_font().color(&BLACK))?;
    let top = data
        .ladder
        .iter()
        .map(|(_, r)| *r * 100.0)
        .chain(std::iter::once(data.noise_floor * 100.0))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max)
        .max(1e-9)
        * 1.15;
    let n = data.ladder.len() as f64;
    let mut chart = LAYOUT.frame(
        &body,
        -0.5..n - 0.5,
        0.0..top,
        "step of the ladder",
        "rms (%)",
    )?;
    for (k, (name, rms)) in data.ladder.iter().enumerate() {
        let x = k as f64;
        chart.draw_series(std::iter::once(Rectangle::new(
            [(x - 0.35, 0.0), (x + 0.35, rms * 100.0)],
            BEFORE.mix(0.7).filled(),
        )))?;
        chart.draw_series(std::iter::once(Text::new(
            name.clone(),
            (x - 0.33, rms * 100.0 + top * 0.03),
            (FAMILY, 11).into_font().color(&BLACK),
        )))?;
    }
    if data.noise_floor.is_finite() && data.noise_floor > 0.0 {
        let f = data.noise_floor * 100.0;
        chart.draw_series(DashedLineSeries::new(
            [(-0.5, f), (n - 0.5, f)],
            6,
            4,
            FLOOR.stroke_width(2),
        ))?;
    }
    Ok(())
}
