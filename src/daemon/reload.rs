//! Reloading the configuration while the daemon runs (SIGHUP under
//! `fieldcal run`, `ExecReload=` in the systemd unit).
//!
//! The file the daemon started from ([`Config::path`]) is read again and
//! checked as a start checks it ([`check`]: [`super::config::load`], then
//! every replayed capture read and every csv recording scanned with its
//! sensors' columns found, as `run` does before READY), off the main loop so
//! readings keep flowing. A file that fails is refused whole: the log (at
//! error) and every subscriber (an `ERROR` line naming the file, line and
//! key) say why, and the running configuration is kept unchanged.
//!
//! A file that passes is compared with the running configuration
//! ([`plan`], a pure function) and applied as far as it can be live:
//!
//! - a sensor whose `[[sensor]]` section is unchanged keeps everything: its
//!   calibration, its rotation buffer mid-turn, its counts;
//! - a sensor whose section changed (model, axes, rotation, limits, gyro,
//!   ...) starts a new rotation under the new settings; the calibration it
//!   has keeps correcting readings (its CALIBRATION names its own model)
//!   until one under the new settings is accepted, and ids go on from it;
//! - a sensor added is started (with its stored calibration, if the state
//!   directory has one); a sensor removed is no longer read or published,
//!   its stored calibration stays on disk;
//! - `[daemon] status_interval_s` applies at once;
//! - sources, `[outputs]`, `state_dir` and `log_format` need a restart:
//!   each change is reported ("[outputs] tcp changed to ...: restart
//!   fieldcal to apply; kept 127.0.0.1:2947") and what runs stays as it
//!   started. A sensor whose section changed but whose source changed too
//!   (or is new) keeps running as it was until that restart: its settings
//!   may only make sense for the new source.
//!
//! Every applied change is one `RELOAD` line (and one log line), and a
//! last `RELOAD` line sums the reload up.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc;

use super::Calibration;
use super::config::{self, Config, ConfigError, SensorConfig, SensorGeometry, SourceConfig};
use super::messages::CalibrationEvent;
use super::notify::Notifier;
use super::sensor::Sensor;
use super::state::StateStore;
use crate::capture::CaptureError;
use crate::io::csv::{CsvError, CsvLayout};

/// Why a new configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ReloadError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error(transparent)]
    Csv(#[from] CsvError),
}

impl ReloadError {
    /// The dotted key the error is about, if it is about one.
    pub fn key(&self) -> Option<&str> {
        match self {
            ReloadError::Config(e) => e.key(),
            _ => None,
        }
    }

    /// The line and column in the configuration, where known.
    pub fn position(&self) -> Option<config::Position> {
        match self {
            ReloadError::Config(e) => e.position(),
            _ => None,
        }
    }
}

/// Reads and checks the configuration at `path` as a start does: the file
/// itself ([`config::load`]), then what `run` checks before READY (each
/// replayed capture read whole, each csv recording scanned and its
/// sensors' columns found in its header). Opens no port and binds nothing,
/// so listener addresses are only checked for their form. Blocking: run it
/// off the main loop.
pub fn check(path: &Path) -> Result<Config, ReloadError> {
    let config = config::load(path)?;
    for source in &config.sources {
        source.kind.preflight(&source.name, &config.sensors)?;
    }
    Ok(config)
}

/// What a reload does, worked out from the running and the new
/// configuration alone.
#[derive(Debug, Clone, PartialEq)]
pub struct ReloadPlan {
    /// The new file's sensors in its order, then those it removed.
    pub sensors: Vec<SensorPlan>,
    /// The new `status_interval_s`, when it changed (applied live).
    pub status_interval: Option<Duration>,
    /// Changes that only a restart applies, one message each.
    pub restart: Vec<String>,
    /// A new or removed token of `[outputs] token_file` (applied live: a
    /// token that leaked must stop working at once).
    pub token: Option<TokenChange>,
}

/// What a reload does to the token of `[outputs] token_file`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TokenChange {
    /// The file holds another token: it replaces the old one at every
    /// listener, and the old one is refused.
    Replaced,
    /// `token_file` was removed: no token is accepted any more.
    Revoked,
}

/// What happens to one sensor.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorPlan {
    /// Its section is unchanged: it keeps its state, rotation and
    /// calibration.
    Unchanged(String),
    /// Its section changed (the keys named): a new rotation under the new
    /// settings; its calibration corrects until a new one is accepted.
    Changed {
        name: String,
        keys: Vec<&'static str>,
    },
    /// Only its true north changed (`declination_deg`, the location, or
    /// the host's date a location without `date` takes): applied live, the
    /// calibration and the rotation being collected kept.
    North(String),
    /// New in the file, on a running source: started.
    Added(String),
    /// Gone from the file: no longer read or published.
    Removed(String),
    /// Its section changed (or is new) but its source is new or changed,
    /// which needs a restart: it keeps running as it was (or is not
    /// started) until then.
    Held {
        name: String,
        source: String,
        added: bool,
    },
}

impl ReloadPlan {
    /// Whether the file changes nothing at all.
    pub fn is_empty(&self) -> bool {
        self.status_interval.is_none()
            && self.token.is_none()
            && self.restart.is_empty()
            && self
                .sensors
                .iter()
                .all(|s| matches!(s, SensorPlan::Unchanged(_)))
    }
}

/// Compares the running configuration `old` with the new file's `new`.
/// Pure: reads nothing, changes nothing.
pub fn plan(old: &Config, new: &Config) -> ReloadPlan {
    // A source runs live only as it started: a sensor can take new
    // settings live only on a source that the file leaves as it runs.
    let live =
        |name: &str| matches!((old.source(name), new.source(name)), (Some(a), Some(b)) if a == b);
    let mut sensors = Vec::new();
    for s in &new.sensors {
        let before = old.sensors.iter().find(|o| o.name == s.name);
        sensors.push(match before {
            Some(o) if o == s => SensorPlan::Unchanged(s.name.clone()),
            Some(o)
                if SensorConfig {
                    north: s.north.clone(),
                    ..o.clone()
                } == *s =>
            {
                SensorPlan::North(s.name.clone())
            }
            _ if !live(&s.source) => SensorPlan::Held {
                name: s.name.clone(),
                source: s.source.clone(),
                added: before.is_none(),
            },
            Some(o) => SensorPlan::Changed {
                name: s.name.clone(),
                keys: changed_keys(o, s),
            },
            None => SensorPlan::Added(s.name.clone()),
        });
    }
    for o in &old.sensors {
        if !new.sensors.iter().any(|s| s.name == o.name) {
            sensors.push(SensorPlan::Removed(o.name.clone()));
        }
    }
    let status_interval = (old.daemon.status_interval != new.daemon.status_interval)
        .then_some(new.daemon.status_interval);
    let token = match (&old.outputs.access.token, &new.outputs.access.token) {
        (Some(was), Some(now)) if was != now => Some(TokenChange::Replaced),
        (Some(was), None) if !was.is_empty() => Some(TokenChange::Revoked),
        _ => None,
    };
    ReloadPlan {
        sensors,
        status_interval,
        restart: restart_changes(old, new),
        token,
    }
}

/// The keys of a `[[sensor]]` section that differ.
fn changed_keys(old: &SensorConfig, new: &SensorConfig) -> Vec<&'static str> {
    let mut keys = Vec::new();
    if old.source != new.source {
        keys.push("source");
    }
    if old.stream != new.stream {
        keys.push("chip");
    }
    if old.field != new.field {
        keys.push("field");
    }
    // Each key as the file gives it; a 3-axis sensor has no rotation,
    // limits or gyro of its own (the defaults stand for them).
    let axes = |s: &SensorConfig| match &s.geometry {
        SensorGeometry::Plane(p) => (p.axes, p.columns.clone()),
        SensorGeometry::Sphere(t) => ([t.axes[0], t.axes[1]], None),
    };
    let plane = |s: &SensorConfig| match &s.geometry {
        SensorGeometry::Plane(p) => (Some(p.gyro.clone()), p.rotation.clone(), p.limits.clone()),
        SensorGeometry::Sphere(_) => (None, Default::default(), Default::default()),
    };
    let (old_plane, new_plane) = (plane(old), plane(new));
    if axes(old) != axes(new) {
        keys.push("axes");
    }
    if old.effects() != new.effects() {
        keys.push("model");
    }
    if old_plane.0 != new_plane.0 {
        keys.push("gyro");
    }
    if old_plane.1 != new_plane.1 {
        keys.push("rotation");
    }
    if old_plane.2 != new_plane.2 {
        keys.push("limits");
    }
    if old.sphere() != new.sphere() {
        keys.push("axes, model, tilt, units or sphere");
    }
    if old.north != new.north {
        keys.push("declination or location");
    }
    if keys.is_empty() && old != new {
        keys.push("settings");
    }
    keys
}

/// The changes outside the sensors that need a restart, one message each.
fn restart_changes(old: &Config, new: &Config) -> Vec<String> {
    const RESTART: &str = "restart fieldcal to apply";
    let mut out = Vec::new();
    let changed = |out: &mut Vec<String>, what: &str, now: String, kept: String| {
        out.push(format!("{what} changed to {now}: {RESTART}; kept {kept}"));
    };
    let (od, nd) = (&old.daemon, &new.daemon);
    if od.state_dir != nd.state_dir {
        changed(
            &mut out,
            "[daemon] state_dir",
            nd.state_dir.display().to_string(),
            od.state_dir.display().to_string(),
        );
    }
    if od.log_format != nd.log_format {
        changed(
            &mut out,
            "[daemon] log_format",
            format!("{:?}", nd.log_format).to_lowercase(),
            format!("{:?}", od.log_format).to_lowercase(),
        );
    }
    let (oo, no) = (&old.outputs, &new.outputs);
    let before = out.len();
    // Each kind of output, named by its address or path (or its "off"
    // word) when that changed.
    for (kind, _, off) in crate::daemon::output_kinds::TABLE {
        let (was, now) = (
            oo.outputs.iter().find(|o| o.name() == *kind),
            no.outputs.iter().find(|o| o.name() == *kind),
        );
        if was == now {
            continue;
        }
        let describe = |o: Option<&config::Output>| o.map_or(off.to_string(), |o| o.describe());
        let (was, now) = (describe(was), describe(now));
        if was != now {
            changed(&mut out, &format!("[outputs] {kind}"), now, was);
        }
    }
    if oo.queue != no.queue {
        changed(
            &mut out,
            "[outputs] queue",
            no.queue.to_string(),
            oo.queue.to_string(),
        );
    }
    // The token is applied live (ReloadPlan::token), except where the
    // daemon started without one.
    let without_token = |o: &config::OutputsConfig| {
        let mut o = o.clone();
        o.access.token = None;
        o
    };
    if out.len() == before && without_token(oo) != without_token(no) {
        out.push(format!(
            "[outputs] changed: {RESTART}; kept the outputs it started with"
        ));
    }
    if oo.access.token.is_none() && no.access.token.is_some() {
        out.push(format!(
            "[outputs] token_file set: {RESTART}; until then no token is accepted"
        ));
    }
    for s in &new.sources {
        match old.source(&s.name) {
            None => out.push(format!(
                "[[source]] {} added: restart fieldcal to start it",
                s.name
            )),
            Some(o) if o != s => out.push(format!(
                "[[source]] {} changed ({}): {RESTART}; it keeps running as it started",
                s.name,
                source_keys(o, s).join(", ")
            )),
            Some(_) => {}
        }
    }
    for o in &old.sources {
        if new.source(&o.name).is_none() {
            out.push(format!(
                "[[source]] {} removed: restart fieldcal to stop it; it keeps running",
                o.name
            ));
        }
    }
    out
}

/// The keys of a `[[source]]` section that differ.
fn source_keys(old: &SourceConfig, new: &SourceConfig) -> Vec<&'static str> {
    let mut keys = Vec::new();
    if old.retry != new.retry {
        keys.push("retry_s");
    }
    keys.extend(old.kind.changed(&new.kind));
    if keys.is_empty() {
        keys.push("settings");
    }
    keys
}

/// A running source as a reload sees it: its name, and for a csv source
/// the files it plays and their headers (sensors bind their columns to
/// them).
pub struct RunningSource<'a> {
    pub name: &'a str,
    #[allow(clippy::type_complexity)]
    pub csv: Option<(&'a [std::path::PathBuf], &'a [Arc<CsvLayout>])>,
}

/// What a reload did, for the main loop to publish and apply.
#[derive(Debug, Default)]
pub struct Outcome {
    /// `RELOAD` (or, refused, `ERROR`) lines to publish, in order.
    pub lines: Vec<String>,
    /// The outcomes of the `CALIBRATION` lines among `lines` (an added
    /// sensor's stored calibration), for the progress board, in order.
    pub calibrations: Vec<CalibrationEvent>,
    /// The new STATUS interval, when it changed.
    pub status_interval: Option<Duration>,
}

/// Applies a checked file (or reports a refused one): `running` is the
/// running configuration (sources, outputs and daemon settings as started,
/// sensors as last applied), `sensors` the running sensors with the index
/// of their source in `sources`, in `running.sensors`' order; both are
/// updated together. `store` loads the stored calibration of an added
/// sensor. Logs each line it returns.
pub fn apply(
    checked: Result<Config, ReloadError>,
    running: &mut Config,
    sensors: &mut Vec<(usize, Sensor)>,
    sources: &[RunningSource<'_>],
    store: Option<&StateStore>,
) -> Outcome {
    let file = running.path.display().to_string();
    let new = match checked {
        Ok(new) => new,
        Err(e) => return refused(&file, &e),
    };
    let plan = plan(running, &new);
    match apply_plan(&plan, &new, running, sensors, sources, store) {
        Ok(outcome) => outcome,
        Err(e) => refused(&file, &ReloadError::Csv(e)),
    }
}

fn refused(file: &str, e: &ReloadError) -> Outcome {
    let message = format!("reload of {file} refused: {e}; the running configuration is kept");
    tracing::error!("{message}");
    let mut line = serde_json::json!({ "class": "ERROR", "file": file, "message": message });
    if let Some(key) = e.key() {
        line["key"] = key.into();
    }
    if let Some(p) = e.position() {
        line["line"] = p.line.into();
        line["column"] = p.column.into();
    }
    Outcome {
        lines: vec![line.to_string()],
        calibrations: Vec::new(),
        status_interval: None,
    }
}

fn reload_line(file: &str, message: &str, sensor: Option<&str>, restart: bool) -> String {
    let mut line = serde_json::json!({ "class": "RELOAD", "file": file, "message": message });
    if let Some(sensor) = sensor {
        line["sensor"] = sensor.into();
    }
    if restart {
        line["restart"] = true.into();
    }
    line.to_string()
}

fn plural(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

fn model_of(config: &SensorConfig) -> String {
    let effects = crate::model::effects::parse_list(&config.effects().join(","))
        .unwrap_or_else(|_| crate::model::effects::PAPER.to_vec());
    crate::model::effects::model_name(&effects)
}

/// The plan applied: every fallible step (binding csv columns) first, so
/// an error changes nothing.
fn apply_plan(
    plan: &ReloadPlan,
    new: &Config,
    running: &mut Config,
    sensors: &mut Vec<(usize, Sensor)>,
    sources: &[RunningSource<'_>],
    store: Option<&StateStore>,
) -> Result<Outcome, CsvError> {
    let file = running.path.display().to_string();
    // Built and bound before anything running is touched.
    let mut built = build_sensors(plan, new, sources, store)?;

    // Nothing below can fail.
    let mut old: HashMap<String, ((usize, Sensor), SensorConfig)> = sensors
        .drain(..)
        .zip(running.sensors.drain(..))
        .map(|(s, c)| (c.name.clone(), (s, c)))
        .collect();
    let mut lines = Vec::new();
    let mut calibrations = Vec::new();
    let info = |lines: &mut Vec<String>, message: String, sensor: Option<&str>| {
        tracing::info!("{message}");
        lines.push(reload_line(&file, &message, sensor, false));
    };
    let mut counts = [0usize; 4]; // changed, added, removed, unchanged
    for entry in &plan.sensors {
        match entry {
            SensorPlan::Unchanged(name) => {
                if let Some((s, c)) = old.remove(name) {
                    sensors.push(s);
                    running.sensors.push(c);
                    counts[3] += 1;
                }
            }
            SensorPlan::Changed { name, keys } => {
                let Some((before, was)) = old.remove(name) else {
                    continue;
                };
                let Some((index, mut sensor)) = built.remove(name.as_str()) else {
                    // Not built (its source is not running): as it was.
                    sensors.push(before);
                    running.sensors.push(was);
                    continue;
                };
                let Some(config) = new.sensors.iter().find(|s| &s.name == name) else {
                    continue;
                };
                let what = what_changed(keys, &was, config);
                let keeps = carried(before.1.calibration(), config);
                sensor.carry_over(before.1);
                info(
                    &mut lines,
                    format!(
                        "sensor '{name}': {what}: a new rotation starts under the new settings; {keeps}"
                    ),
                    Some(name),
                );
                sensors.push((index, sensor));
                running.sensors.push(config.clone());
                counts[0] += 1;
            }
            SensorPlan::North(name) => {
                let (Some(((index, mut sensor), was)), Some(config)) = (
                    old.remove(name),
                    new.sensors.iter().find(|s| &s.name == name),
                ) else {
                    continue;
                };
                sensor.set_north(config.north.clone());
                info(
                    &mut lines,
                    format!(
                        "sensor '{name}': {} -> {}: applied; its calibration and rotation are kept",
                        declination(&was.north),
                        declination(&config.north)
                    ),
                    Some(name),
                );
                sensors.push((index, sensor));
                running.sensors.push(config.clone());
                counts[0] += 1;
            }
            SensorPlan::Added(name) => {
                let Some((index, sensor)) = built.remove(name.as_str()) else {
                    continue;
                };
                let Some(config) = new.sensors.iter().find(|s| &s.name == name) else {
                    continue;
                };
                let how = added(&sensor, &mut lines, &mut calibrations);
                info(
                    &mut lines,
                    format!(
                        "sensor '{name}' added on source '{}': it {how}",
                        config.source
                    ),
                    Some(name),
                );
                sensors.push((index, sensor));
                running.sensors.push(config.clone());
                counts[1] += 1;
            }
            SensorPlan::Removed(name) => {
                if old.remove(name).is_some() {
                    info(
                        &mut lines,
                        format!(
                            "sensor '{name}' removed: no longer read or published; its stored calibration stays in the state directory"
                        ),
                        Some(name),
                    );
                    counts[2] += 1;
                }
            }
            SensorPlan::Held {
                name,
                source,
                added,
            } => {
                let message = held(name, source, *added);
                tracing::warn!("{message}");
                lines.push(reload_line(&file, &message, Some(name), true));
                if let Some((s, c)) = old.remove(name) {
                    sensors.push(s);
                    running.sensors.push(c);
                }
            }
        }
    }
    apply_daemon_changes(plan, running, new, &file, &mut lines);
    info(&mut lines, summary(plan, &file, counts), None);
    Ok(Outcome {
        lines,
        calibrations,
        status_interval: plan.status_interval,
    })
}

/// The sensors a reload changes or adds, built and bound to their running
/// source's files, by name; nothing running is touched.
fn build_sensors<'a>(
    plan: &'a ReloadPlan,
    new: &Config,
    sources: &[RunningSource<'_>],
    store: Option<&StateStore>,
) -> Result<HashMap<&'a str, (usize, Sensor)>, CsvError> {
    let source_of = |name: &str| sources.iter().position(|s| s.name == name);
    let mut built: HashMap<&str, (usize, Sensor)> = HashMap::new();
    for entry in &plan.sensors {
        let (name, added) = match entry {
            SensorPlan::Changed { name, .. } => (name, false),
            SensorPlan::Added(name) => (name, true),
            _ => continue,
        };
        let Some(config) = new.sensors.iter().find(|s| &s.name == name) else {
            continue;
        };
        let Some(index) = source_of(&config.source) else {
            continue;
        };
        let stored = if added {
            store.and_then(|store| {
                match store.load_checked(name, |c| crate::daemon::sensor::stored_problem(config, c))
                {
                    Ok(found) => found,
                    Err(e) => {
                        tracing::warn!("{e}; the sensor starts uncalibrated");
                        None
                    }
                }
            })
        } else {
            None
        };
        let mut sensor = Sensor::new(config.clone(), stored);
        // A live source is as it runs: its file is the running one's.
        if let Some((files, layouts)) = sources[index].csv {
            sensor.bind_csv(layouts, files)?;
        }
        built.insert(name.as_str(), (index, sensor));
    }
    Ok(built)
}

/// What becomes of a changed sensor's calibration `c` under its new
/// section `config`, said for the reload's line.
fn carried(c: Option<&Calibration>, config: &SensorConfig) -> String {
    let Some(c) = c else {
        return "it has no calibration yet".to_string();
    };
    let three = matches!(config.geometry, SensorGeometry::Sphere(_));
    if c.ellipsoid.is_some() == three {
        return format!(
            "calibration #{} ({}) keeps correcting until one under them is accepted",
            c.id, c.model
        );
    }
    let (had, has, how) = if three {
        (2, 3, "tumble it through every direction")
    } else {
        (3, 2, "turn it one full turn")
    };
    format!(
        "its axes went from {had} to {has}, so calibration #{} ({}) cannot correct it: its readings go out uncalibrated until a new one is accepted ({how}); ids go on where they were, and its counts are kept",
        c.id, c.model
    )
}

/// The `[daemon]` changes a reload applies (the STATUS interval), and the
/// ones that need a restart, each said in a line.
fn apply_daemon_changes(
    plan: &ReloadPlan,
    running: &mut Config,
    new: &Config,
    file: &str,
    lines: &mut Vec<String>,
) {
    // The running token is the one every listener shares.
    let token = running.outputs.access.token.as_ref();
    let applied = match (plan.token, token, &new.outputs.access.token) {
        (Some(TokenChange::Replaced), Some(running), Some(new)) => {
            running.replace_with(new);
            Some(
                "[outputs] token_file holds a new token: applied; the old one is refused from now on",
            )
        }
        (Some(TokenChange::Revoked), Some(running), _) => {
            running.revoke();
            Some("[outputs] token_file removed: applied; no token is accepted from now on")
        }
        _ => None,
    };
    if let Some(message) = applied {
        tracing::warn!("{message}");
        lines.push(reload_line(file, message, None, false));
    }
    if let Some(interval) = plan.status_interval {
        let message = format!(
            "[daemon] status_interval_s changed from {} s to {} s: applied",
            running.daemon.status_interval.as_secs_f64(),
            interval.as_secs_f64()
        );
        tracing::info!("{message}");
        lines.push(reload_line(file, &message, None, false));
        running.daemon.status_interval = interval;
    }
    for message in &plan.restart {
        tracing::warn!("{message}");
        lines.push(reload_line(file, message, None, true));
    }
}

/// What a sensor a reload adds does first; its stored calibration, if it
/// has one, is published (`lines`) and shown (`calibrations`).
fn added(
    sensor: &Sensor,
    lines: &mut Vec<String>,
    calibrations: &mut Vec<CalibrationEvent>,
) -> String {
    match sensor.calibration() {
        Some(c) => {
            if let Some((line, event)) = sensor.loaded_calibration() {
                lines.push(line);
                calibrations.extend(event);
            }
            format!(
                "corrects with calibration #{} from the state directory and waits for a recalibrate",
                c.id
            )
        }
        None => "collects its first rotation".to_string(),
    }
}

/// A sensor's declination, as a reload line names it.
fn declination(north: &Option<super::north::North>) -> String {
    match north {
        Some(n) => format!("declination {:+.2}° ({})", n.declination_deg, n.source),
        None => "no declination".to_string(),
    }
}

/// Why a sensor on a new or changed source waits for a restart.
fn held(name: &str, source: &str, added: bool) -> String {
    if added {
        format!(
            "sensor '{name}' is on source '{source}', which is new or changed: restart fieldcal to start it"
        )
    } else {
        format!(
            "sensor '{name}' changed, on source '{source}', which is new or changed: restart fieldcal to apply; it keeps running as it was"
        )
    }
}

/// What changed in a sensor's settings, the model first.
fn what_changed(keys: &[&str], was: &SensorConfig, now: &SensorConfig) -> String {
    let (model_was, model_now) = (model_of(was), model_of(now));
    if keys.contains(&"model") {
        let others: Vec<&str> = keys.iter().copied().filter(|k| *k != "model").collect();
        let mut what = format!("model {model_was} -> {model_now}");
        if !others.is_empty() {
            what.push_str(&format!("; {} changed", others.join(", ")));
        }
        what
    } else {
        format!("{} changed", keys.join(", "))
    }
}

/// The last line of a reload: what it applied, or that nothing changed.
fn summary(plan: &ReloadPlan, file: &str, counts: [usize; 4]) -> String {
    let held = plan
        .sensors
        .iter()
        .filter(|s| matches!(s, SensorPlan::Held { .. }))
        .count();
    if plan.is_empty() {
        format!("reload of {file}: no change")
    } else {
        let restarts = plan.restart.len() + held;
        format!(
            "reload of {file} applied: {} changed, {} added, {} removed, {} unchanged; {}",
            plural(counts[0], "sensor", "sensors"),
            counts[1],
            counts[2],
            counts[3],
            plural(restarts, "change needs a restart", "changes need a restart"),
        )
    }
}

/// What [`Reloader::next`] brings.
pub enum ReloadEvent {
    /// A reload was asked for: [`Reloader::start`].
    Requested,
    /// A file was checked: [`apply`] it, then [`Reloader::done`].
    Checked(Box<Result<Config, ReloadError>>),
}

/// The next request; never, when nothing can ask any more. Cancel-safe.
async fn next_request(requests: &mut Option<mpsc::Receiver<()>>) {
    if let Some(rx) = requests {
        if rx.recv().await.is_some() {
            return;
        }
        *requests = None;
    }
    std::future::pending::<()>().await;
}

/// The reload requests and the checks they start, for the main loop:
/// requests that come while a check runs are folded into one more check
/// after it (the file may have changed again), and systemd is told
/// `RELOADING=1` when a check starts and `READY=1` when it is over.
pub struct Reloader {
    path: PathBuf,
    requests: Option<mpsc::Receiver<()>>,
    checked_tx: mpsc::Sender<Result<Config, ReloadError>>,
    checked_rx: mpsc::Receiver<Result<Config, ReloadError>>,
    busy: bool,
    again: bool,
}

impl Reloader {
    /// Reloads read `path`; `requests` is `None` when nothing can ask.
    pub fn new(path: PathBuf, requests: Option<mpsc::Receiver<()>>) -> Reloader {
        let (checked_tx, checked_rx) = mpsc::channel(1);
        Reloader {
            path,
            requests,
            checked_tx,
            checked_rx,
            busy: false,
            again: false,
        }
    }

    /// The next request, or the result of the running check.
    /// Cancel-safe (for `select!`).
    pub async fn next(&mut self) -> ReloadEvent {
        tokio::select! {
            () = next_request(&mut self.requests) => ReloadEvent::Requested,
            Some(checked) = self.checked_rx.recv() => ReloadEvent::Checked(Box::new(checked)),
        }
    }

    /// Starts a check of the file, or notes one more for after the
    /// running check.
    pub fn start(&mut self, notifier: &Notifier) {
        if self.busy {
            self.again = true;
            return;
        }
        self.busy = true;
        notifier.reloading();
        tracing::info!("reloading the configuration {}", self.path.display());
        let (path, tx) = (self.path.clone(), self.checked_tx.clone());
        tokio::task::spawn_blocking(move || {
            let _ = tx.blocking_send(check(&path));
        });
    }

    /// The check's result is applied: tells systemd, and starts the check
    /// asked for meanwhile, if any.
    pub fn done(&mut self, notifier: &Notifier, status: &str) {
        self.busy = false;
        notifier.ready();
        notifier.status(status);
        if std::mem::take(&mut self.again) {
            self.start(notifier);
        }
    }
}
