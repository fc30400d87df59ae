//! What a calibrated plane does with each later rotation: fitted and
//! compared with the calibration ([`crate::model::watch`]), it agrees (and
//! refines it with `learn`), or shows it stale (a `STALE` line, then the
//! readings distrusted, or the calibration replaced).

use super::*;
use crate::daemon::stale::Stale;

impl Plane {
    /// A rotation completed after the calibration was accepted: fitted and
    /// compared with it ([`watch`]). It agrees (and refines it when
    /// `learn`), or shows it stale (a `STALE` line; the calibration is
    /// distrusted, or replaced), or cannot tell (a rotation that gives no
    /// acceptable fit, a move within the noise): said in the log only.
    pub(super) fn watch(
        &mut self,
        life: &mut Lifecycle,
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let (t, x, y) = self.buffer.take();
        let current = life.current.as_ref()?;
        let fitted = self
            .fit_rotation(t, x, y, false)
            .map_err(|(reason, _)| reason)
            .and_then(|fit| match acceptance::check(&fit.0, &self.limits) {
                Ok(()) => Ok(fit),
                Err(reason) => Err(reason),
            });
        let (report, terms, rotation, refit) = match fitted {
            Ok(fit) => fit,
            Err(reason) => {
                if let Some(gyro) = &mut self.gyro {
                    gyro.clear();
                }
                tracing::debug!(sensor = %self.config.name, "a later rotation tells nothing of calibration #{}: {reason}", current.id);
                return None;
            }
        };
        let heading_error = watch::heading_error_deg(
            |x, y| current.apply(x, y),
            |x, y| crate::daemon::apply(&report.calibration, &terms, x, y),
            &rotation.x,
            &rotation.y,
        );
        let comparison = watch::compare(current, &refit, heading_error);
        let previous = self
            .last_rotation
            .replace((rotation.x.clone(), rotation.y.clone()));
        if comparison.stale() {
            let id = current.id;
            return self.stale(
                life,
                id,
                &comparison,
                (report, terms, rotation, refit),
                time,
                emit,
            );
        }
        if let Some(gyro) = &mut self.gyro {
            gyro.clear();
        }
        if !comparison.agrees() {
            tracing::info!(
                sensor = %self.config.name,
                "a later rotation moved calibration #{} ({}), but by at most {:.2}° of heading, within a reading's noise (limit {:.2}°: 3 σ): kept",
                current.id,
                comparison.moved_text(),
                comparison.heading_error_deg,
                comparison.heading_limit_deg
            );
            return None;
        }
        if !self.plane.watch.learn {
            tracing::debug!(sensor = %self.config.name, "a later rotation agrees with calibration #{}", current.id);
            return None;
        }
        self.learn(life, &refit, previous, &rotation, time, emit)
    }

    /// Refines the current calibration with an agreeing rotation's `refit`
    /// (`learn = true`): kept when it still agrees with the rotation and is
    /// not worse than its parent over this rotation and the one before.
    fn learn(
        &mut self,
        life: &mut Lifecycle,
        refit: &Refit,
        previous: Option<(Vec<f64>, Vec<f64>)>,
        rotation: &Dataset,
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let parent = life.current.as_ref()?;
        let Some(mut refined) = watch::refine(parent, refit) else {
            tracing::debug!(sensor = %self.config.name, "calibration #{} has no standard errors to refine it by", parent.id);
            return None;
        };
        let (mut ux, mut uy) = previous.unwrap_or_default();
        ux.extend_from_slice(&rotation.x);
        uy.extend_from_slice(&rotation.y);
        let (rms, parent_rms) = (
            watch::rms_on(&refined, &ux, &uy),
            watch::rms_on(parent, &ux, &uy),
        );
        let holds = watch::compare(&refined, refit, 0.0).agrees();
        // A refinement is a weighted mean of two fits that passed: still
        // held to what a stored calibration must be.
        let valid = crate::model::validity::plane_problem(
            &refined.params,
            &refined.terms,
            self.limits.max_scale_ratio,
            self.limits.max_offset_ratio,
        )
        .is_none();
        if !(holds && valid && rms <= parent_rms) {
            tracing::debug!(
                sensor = %self.config.name,
                "refinement of calibration #{} not kept: rms {rms:.5} against its parent's {parent_rms:.5} over the last two rotations",
                parent.id
            );
            return None;
        }
        refined.id = life.next_id;
        refined.time = time;
        refined.rms = rms;
        refined.n = parent.n.saturating_add(rotation.x.len());
        let parent_id = parent.id;
        let message = CalibrationMessage {
            origin: "refined",
            ..CalibrationMessage::loaded(&refined).with_north(self.config.north.as_ref())
        };
        emit.calibration(|| message.event(), to_line(&message));
        tracing::info!(
            sensor = %self.config.name,
            id = refined.id,
            parent = parent_id,
            "calibration refined by a later rotation that agrees with it"
        );
        life.accept(refined);
        life.current.clone()
    }

    /// A later rotation showed calibration `id` stale: a `STALE` line, and
    /// either every reading distrusted until the sensor is recalibrated
    /// (`on_stale = "warn"`) or the new fit accepted in its place
    /// (`"replace"`, when it passes the acceptance limits).
    fn stale(
        &mut self,
        life: &mut Lifecycle,
        id: u64,
        comparison: &watch::Comparison,
        (report, terms, rotation, refit): (FitReport, Terms, Dataset, Refit),
        time: f64,
        emit: &mut Emitter<'_>,
    ) -> Option<Calibration> {
        let replace = self.plane.watch.on_stale == OnStale::Replace;
        // The rotation that shows a change usually straddles it: its fit
        // then scatters well beyond the sensor's noise, and is no
        // calibration of the sensor as it is now. A clean rotation is
        // collected to replace it instead.
        let stale = Stale {
            sensor: &self.config.name,
            later: crate::daemon::stale::ROTATION,
            id,
            comparison,
            refit_rms: refit.rms,
            stored_rms: life.current.as_ref().map_or(f64::INFINITY, |c| c.rms),
            replace,
            time,
        };
        if !stale.announce(life, emit) {
            if let Some(gyro) = &mut self.gyro {
                gyro.clear();
            }
            if replace {
                self.replacing = Some(id);
                life.restart();
            }
            return None;
        }
        let heading = self.heading_check(&rotation, &report, &terms);
        let mut calibration = self.calibration_of(life, (&report, terms, &refit, &rotation), time);
        calibration.parent = Some(id);
        let (heading_vs_gyro, heading_check) = match heading {
            Ok(check) => (Some(check), None),
            Err(why) => (None, Some(why)),
        };
        calibration.gyro = heading_vs_gyro.as_ref().map(gyro_fit);
        let message = CalibrationMessage {
            origin: "replaced",
            heading_vs_gyro,
            heading_check,
            ..CalibrationMessage::loaded(&calibration).with_north(self.config.north.as_ref())
        };
        emit.calibration(|| message.event(), to_line(&message));
        life.accept(calibration);
        life.current.clone()
    }
}
