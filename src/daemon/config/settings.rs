//! `[daemon]`: the state directory, STATUS interval, log format and the
//! daemon-wide true north.

use super::*;

impl Checker<'_> {
    /// `declination_deg` or `location` of a sensor or of `[daemon]`
    /// (`key` is `sensor[N]` or `daemon`): the true north it gives, if any.
    pub(super) fn check_north(
        &self,
        key: &str,
        declination: Option<f64>,
        location: Option<LocationKeys>,
        today: Option<crate::geomag::CivilDate>,
    ) -> Result<Option<North>, ConfigError> {
        let found = match (declination, &location) {
            (None, None) => return Ok(None),
            (Some(_), Some(_)) => {
                return Err(self.error(
                    &format!("{key}.location"),
                    format!(
                        "both declination_deg and [{key}.location] are given: give one (the \
                         declination, or the place whose declination the World Magnetic Model \
                         gives)",
                        key = key.split('[').next().unwrap_or(key)
                    ),
                ));
            }
            (Some(d), None) => North::declination(d).map_err(|e| (e, "declination_deg")),
            (None, Some(place)) => North::location(place, today).map_err(|e| (e, "location")),
        };
        found.map(Some).map_err(|(e, what)| {
            let at = if e.key.is_empty() {
                format!("{key}.{what}")
            } else {
                format!("{key}.{what}.{}", e.key)
            };
            self.error(&at, e.problem)
        })
    }

    pub(super) fn check_daemon(&self, raw: RawDaemon) -> Result<DaemonConfig, ConfigError> {
        let state_dir = match raw.state_dir {
            Some(dir) if dir.as_os_str().is_empty() => {
                return Err(self.error(
                    "daemon.state_dir",
                    "empty: give a directory, or leave the key out for the default",
                ));
            }
            Some(dir) => self.resolve(&dir),
            None => default_state_dir(),
        };
        let status_interval = match raw.status_interval_s {
            None => Duration::from_secs(1),
            Some(s) => self.seconds_in(
                "daemon.status_interval_s",
                s,
                MIN_STATUS_INTERVAL_S,
                86_400.0,
            )?,
        };
        Ok(DaemonConfig {
            state_dir,
            status_interval,
            log_format: raw.log_format,
        })
    }
}

/// `$STATE_DIRECTORY` (systemd's `StateDirectory=`; the first if several),
/// else `./state`.
pub(super) fn default_state_dir() -> PathBuf {
    std::env::var_os("STATE_DIRECTORY")
        .and_then(|v| {
            let first = v.to_string_lossy().split(':').next().map(str::to_string)?;
            (!first.is_empty()).then(|| PathBuf::from(first))
        })
        .unwrap_or_else(|| PathBuf::from("./state"))
}
