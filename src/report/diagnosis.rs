//! The report of `fieldcal diagnose --report DIR`: the diagnosis turned into
//! the plain data the plots draw.

use std::f64::consts::TAU;

use super::html::preformatted;
use super::plots::ReportData;
use crate::model::FitError;
use crate::model::centred_split::fit_with_gyro;
use crate::model::diagnose::Diagnosis;
use crate::model::effects::model_name;
use crate::model::gyro::HeadingReference;
use crate::model::nonlinear::ModelFit;
use crate::sample::Dataset;

/// Points of the baseline model's ellipse in raw coordinates, at the mean
/// offsets (drift and covariate terms at their means, no cubic).
fn ellipse(fit: &ModelFit) -> Vec<(f64, f64)> {
    let p = fit.paper();
    let c = fit.value("c");
    (0..=360)
        .map(|i| {
            let phi = i as f64 / 360.0 * TAU;
            let (sx, sy) = (p.r * phi.cos(), p.r * phi.sin());
            ((sx - p.b - c * sy) / p.a, sy - p.d)
        })
        .collect()
}

fn on_unit_circle(fit: &ModelFit) -> Vec<(f64, f64)> {
    let r = fit.paper().r;
    fit.calibrated
        .iter()
        .map(|&(x, y)| (x / r, y / r))
        .collect()
}

/// The ladder as the report draws it: each step's model name and rms.
/// `step` reads them off a step of either geometry's ladder.
pub(super) fn ladder_bars<S>(
    ladder: &[S],
    step: impl Fn(&S) -> (&String, f64),
) -> Vec<(String, f64)> {
    ladder
        .iter()
        .map(|s| {
            let (model, rms) = step(s);
            (model.clone(), rms)
        })
        .collect()
}

/// Builds the report's data: the baseline fit and the last model of the
/// ladder are refitted (the diagnosis keeps only their numbers).
/// `summary` is the diagnosis as text; it is shown escaped, as written.
/// `reference`: the gyro the diagnosis was given, which splits a centred
/// cubic per axis as it did.
pub fn report_data(
    data: &Dataset,
    diagnosis: &Diagnosis,
    reference: Option<&HeadingReference>,
    title: &str,
    summary: &str,
) -> Result<ReportData, FitError> {
    let before = fit_with_gyro(data, &diagnosis.baseline.effects, reference)?;
    let last = diagnosis
        .ladder
        .last()
        .map_or(&diagnosis.baseline.effects, |s| &s.effects);
    let after = fit_with_gyro(data, last, reference)?;
    Ok(ReportData {
        title: title.to_string(),
        raw: (data.x.clone(), data.y.clone()),
        ellipse: ellipse(&before),
        calibrated_before: on_unit_circle(&before),
        calibrated_after: on_unit_circle(&after),
        before_label: model_name(&before.effects),
        after_label: model_name(&after.effects),
        heading_deg: before
            .headings
            .iter()
            .map(|h| h.to_degrees().rem_euclid(360.0))
            .collect(),
        time: data.t.clone(),
        residual_before: before.residuals.clone(),
        residual_after: after.residuals.clone(),
        covariates: data
            .covariates
            .iter()
            .map(|c| (c.name.clone(), c.values.clone()))
            .collect(),
        noise_floor: diagnosis.noise_floor.rms,
        ladder: ladder_bars(&diagnosis.ladder, |s| (&s.model, s.rms)),
        heading_errors: diagnosis
            .ladder
            .iter()
            .filter_map(|s| {
                let check = s.heading_vs_gyro.as_ref()?;
                Some((s.model.clone(), check.errors_deg.clone()))
            })
            .collect(),
        heading_reference: diagnosis
            .baseline
            .heading_vs_gyro
            .as_ref()
            .map_or(String::new(), |h| h.gyro_column.clone()),
        summary_html: preformatted(summary),
    })
}
