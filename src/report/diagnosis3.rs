//! The report of `fieldcal diagnose --report DIR` on three axes: the
//! diagnosis turned into the plain data [`super::plots3`] draws.

use super::diagnosis::ladder_bars;
use super::html::preformatted;
use super::plots3::Report3Data;
use crate::model::diagnose3::Diagnosis3;
use crate::model::ellipsoid::Ellipsoid3Model;
use crate::model::ellipsoid_effects::{Effects3Error, fit_effects};
use crate::model::sphere;
use crate::sample::Dataset3;

/// Builds the report's data: the baseline and the last model of the
/// ladder are refitted (the diagnosis keeps only their numbers).
pub fn report3_data(
    data: &Dataset3,
    diagnosis: &Diagnosis3,
    title: &str,
    summary: &str,
) -> Result<Report3Data, Effects3Error> {
    let before = fit_effects(data, Ellipsoid3Model::Offset, &diagnosis.baseline.effects)?;
    let last = diagnosis
        .ladder
        .last()
        .map_or(&diagnosis.baseline.effects, |s| &s.effects);
    let after = if diagnosis.ladder.len() > 1 {
        Some(fit_effects(data, Ellipsoid3Model::Offset, last)?)
    } else {
        None
    };
    let shown = after.as_ref().unwrap_or(&before);
    let reached = sphere::coverage(shown.calibrated.iter().copied()).reached;
    Ok(Report3Data {
        title: title.to_string(),
        summary_html: preformatted(summary),
        raw: data.points.clone(),
        axes: [
            data.x_name.clone(),
            data.y_name.clone(),
            data.z_name.clone(),
        ],
        offset: before.offset,
        matrix: before.matrix,
        r: before.r,
        directions: shown.calibrated.clone(),
        residual_before: before.residuals.clone(),
        residual_after: after.as_ref().map_or(Vec::new(), |f| f.residuals.clone()),
        before_label: diagnosis.baseline.model.clone(),
        after_label: after.as_ref().map_or(String::new(), |_| {
            last.iter()
                .map(|e| e.to_string())
                .collect::<Vec<_>>()
                .join("+")
        }),
        time: data.t.clone(),
        covered: reached.to_vec(),
        noise_floor: diagnosis.noise_floor.rms,
        ladder: ladder_bars(&diagnosis.ladder, |s| (&s.model, s.rms)),
    })
}
