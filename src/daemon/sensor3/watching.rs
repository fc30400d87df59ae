//! What a calibrated 3-axis sensor does with each later covered sphere:
//! fitted with the same model and compared with the calibration, parameter
//! by parameter in standard errors ([`crate::model::watch`]), it agrees, or
//! shows the calibration stale (a `STALE` line, then the readings
//! distrusted, or the calibration replaced), or tells nothing (a sphere
//! whose fit fails ArduPilot's limits: said in the log only).

use super::*;
use crate::daemon::config::OnStale;
use crate::daemon::stale::Stale;
use crate::model::watch::{Comparison, Refit};

impl Sensor3 {
    /// A sphere covered after the calibration was accepted: fitted and
    /// compared with it. The samples are let go either way, and the next
    /// sphere is collected afresh.
    pub(super) fn watch(
        &mut self,
        life: &mut Lifecycle,
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let current = life.current.clone()?;
        let stored = current.ellipsoid?;
        let fit = match ellipsoid::fit(self.buffer.points(), self.config.model) {
            Ok(fit) => fit,
            Err(e @ ellipsoid::Ellipsoid3Error::NotCovered { .. }) => {
                tracing::debug!(sensor = %self.name, "a later sphere, not yet: {e}");
                self.buffer.not_yet();
                return None;
            }
            Err(e) => {
                tracing::debug!(sensor = %self.name, "a later sphere tells nothing of calibration #{}: {e}", current.id);
                self.reset_sphere();
                return None;
            }
        };
        let max_rms = self.config.sphere.max_rms;
        if let Err(reason) = check_limits(&fit, self.field, self.config.lsb_per_unit, max_rms) {
            tracing::debug!(sensor = %self.name, "a later sphere tells nothing of calibration #{}: {reason}", current.id);
            self.reset_sphere();
            return None;
        }
        let points = self.buffer.points();
        let residuals: Vec<f64> = points.iter().map(|p| fit.magnitude_error(*p)).collect();
        let refit = watch::sphere_refit(&fit, &residuals);
        let error = watch::direction_error_deg(&stored, &params_of(&fit), points);
        let comparison = watch::compare(&current, &refit, error);
        if comparison.stale() {
            let replaced = self.stale(life, &current, &comparison, (&fit, &refit), time, emit);
            self.reset_sphere();
            return replaced;
        }
        self.reset_sphere();
        if comparison.agrees() {
            tracing::debug!(sensor = %self.name, "a later sphere agrees with calibration #{}", current.id);
        } else {
            tracing::info!(
                sensor = %self.name,
                "a later sphere moved calibration #{} ({}), but turns a reading by at most {:.2}°, within its noise (limit {:.2}°: 3 σ): kept",
                current.id,
                comparison.moved_text(),
                comparison.heading_error_deg,
                comparison.heading_limit_deg
            );
        }
        None
    }

    /// A later sphere showed calibration `current` stale: a `STALE` line,
    /// and either every reading distrusted until the sensor is
    /// recalibrated (`on_stale = "warn"`), or the new fit accepted in its
    /// place (`"replace"`) when its rms is the sensor's (a sphere that
    /// straddled the change is no calibration of the sensor as it is now:
    /// then a new sphere is collected).
    fn stale(
        &mut self,
        life: &mut Lifecycle,
        current: &Calibration,
        comparison: &Comparison,
        (fit, refit): (&Ellipsoid3Fit, &Refit),
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let id = current.id;
        let replace = self.config.on_stale == OnStale::Replace;
        let stale = Stale {
            sensor: &self.name,
            later: crate::daemon::stale::SPHERE,
            id,
            comparison,
            refit_rms: refit.rms,
            stored_rms: current.rms,
            replace,
            time,
        };
        if !stale.announce(life, emit) {
            if replace {
                life.restart();
            }
            return None;
        }
        let (mut calibration, _) = self.calibration_of(life, fit, time);
        calibration.parent = Some(id);
        let message = self.message(&calibration, Some(fit), 0.0, "replaced", None);
        emit.calibration(|| Some(message.event()), to_line(&message));
        life.accept(calibration);
        life.current.clone()
    }
}
