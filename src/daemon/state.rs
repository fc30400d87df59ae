//! The calibration store: one JSON file per sensor in the state directory,
//! so the last good calibration survives restarts.
//!
//! Writes go through [`AtomicFile`] (temporary file, fsync, rename, fsync of
//! the directory): a crash or a full disk leaves the old file or the new
//! one, never a torn one. A file that cannot be trusted on load is moved
//! aside (never overwritten, never used) so a person can look at it later,
//! and the daemon carries on as if the sensor had no calibration yet.
//! A writer killed mid-write leaves its temporary file; [`StateStore::open`]
//! removes those of writers that are no longer alive.
//!
//! File layout (format 1):
//!
//! ```json
//! {"format":1,"calibration":{"sensor":"compass","id":3,"model":"offset+scale",
//!  "params":{"a":1.02,"b":-31.5,"d":12.25,"r":412.0},"rms":0.004,
//!  "coverage_deg":358.0,"n":412,"time":1700000000.5}}
//! ```

use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::daemon::Calibration;
use crate::io::atomic::AtomicFile;

/// The version of the file layout this module reads and writes (kept in
/// the model, which `fieldcal check` reads the file with).
pub use crate::model::calibration::FORMAT_VERSION;

/// A calibration file is a few hundred bytes; anything far larger is not
/// one of ours, and is not read whole into memory.
const MAX_FILE_LEN: u64 = 64 * 1024;

/// The calibrations of all sensors, kept in one directory.
#[derive(Debug, Clone)]
pub struct StateStore {
    dir: PathBuf,
    /// Set when the directory could be read but not written at open (a
    /// read-only mount, missing permission): a [`StateError::ReadOnly`].
    unwritable: Option<std::sync::Arc<StateError>>,
}

/// Why the store could not be opened, or a calibration loaded or saved.
/// Every message names the file or directory and says what to do.
#[derive(Debug, thiserror::Error)]
pub enum StateError {
    #[error(
        "state directory {}: a file that is not a directory is in its place: \
         remove it, or set daemon.state_dir to a directory",
        dir.display()
    )]
    NotADirectory { dir: PathBuf },
    #[error(
        "cannot create the state directory {}: {source}: create it and let the user \
         fieldcal runs as write to it, or set daemon.state_dir",
        dir.display()
    )]
    CreateDir {
        dir: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "state directory {} is not usable ({source}): calibrations could not be kept; \
         let the user fieldcal runs as read and write it, or set daemon.state_dir",
        dir.display()
    )]
    NotWritable {
        dir: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "stored calibration {} cannot be trusted ({problem}): it was moved aside to {} \
         and the sensor starts uncalibrated; a new calibration is stored after the next \
         full turn",
        path.display(),
        moved_to.display()
    )]
    Corrupt {
        path: PathBuf,
        moved_to: PathBuf,
        problem: String,
    },
    #[error(
        "stored calibration {} cannot be trusted ({problem}) and could not be moved aside \
         ({source}): it is ignored; move or delete it by hand",
        path.display()
    )]
    CorruptNotMoved {
        path: PathBuf,
        problem: String,
        #[source]
        source: io::Error,
    },
    #[error(
        "state directory {} cannot be written ({source}): the calibrations in it are loaded, \
         but new ones cannot be stored and are lost at the next restart; let the user \
         fieldcal runs as write to it (or mount it read-write), or set daemon.state_dir",
        dir.display()
    )]
    ReadOnly {
        dir: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("cannot write {}: {source}; {before}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: io::Error,
        /// What is left of the stored calibration after the failure.
        before: StoredBefore,
    },
    #[error(
        "refusing to store the calibration of sensor '{sensor}' in {}: {problem} \
         (the calibration stored before is unchanged)",
        path.display()
    )]
    Invalid {
        sensor: String,
        path: PathBuf,
        problem: String,
    },
}

/// After a failed save: what is left of the sensor's stored calibration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StoredBefore {
    /// Its file is there, as it was.
    Unchanged,
    /// The directory is there, but no calibration of the sensor was stored.
    Nothing,
    /// The state directory itself is gone (deleted, moved, or something
    /// else in its place), and any calibration stored in it with it.
    DirectoryGone { dir: PathBuf },
}

impl std::fmt::Display for StoredBefore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StoredBefore::Unchanged => f.write_str(
                "the calibration stored before is unchanged: check that the state directory \
                 is writable and the disk is not full",
            ),
            StoredBefore::Nothing => f.write_str(
                "no calibration of this sensor was stored before, so none survives a \
                 restart: check that the state directory is writable and the disk is not full",
            ),
            StoredBefore::DirectoryGone { dir } => write!(
                f,
                "the state directory {} is gone (deleted, moved, or replaced by a file), and \
                 no stored calibration is left: create the directory again (a restart of \
                 fieldcal does) and recalibrate, or set daemon.state_dir",
                dir.display()
            ),
        }
    }
}

/// The file as written.
#[derive(Serialize)]
struct StoredRef<'a> {
    format: u32,
    calibration: &'a Calibration,
}

/// The file as read: the version first, so a newer layout is recognised as
/// such rather than reported as a mismatch of fields.
#[derive(Deserialize)]
struct StoredVersion {
    format: u32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Stored {
    #[allow(dead_code)] // checked through `StoredVersion`
    format: u32,
    calibration: Calibration,
}

impl StateError {
    /// Whether the process had no descriptor free (EMFILE, ENFILE): a
    /// moment later, when a client has gone, the same write succeeds.
    pub fn out_of_descriptors(&self) -> bool {
        let mut cause: Option<&(dyn std::error::Error + 'static)> = Some(self);
        while let Some(e) = cause {
            if let Some(io) = e.downcast_ref::<io::Error>()
                && matches!(io.raw_os_error(), Some(libc::EMFILE | libc::ENFILE))
            {
                return true;
            }
            cause = e.source();
        }
        false
    }
}

/// The largest calibration id: 2^53 − 1, the largest integer a JSON client
/// (a browser's page) reads exactly. A sensor reaches it after 285 million
/// years of a calibration a second; a stored id beyond it was edited by
/// hand, and a next id past it would wrap or repeat.
pub const MAX_ID: u64 = (1 << 53) - 1;

/// Waits before each retry of a save that found no descriptor free: the
/// budget keeps descriptors for the state writer, so this is the last guard
/// against a leak elsewhere, and a little over 3 s in all.
pub const SAVE_RETRIES_MS: [u64; 4] = [50, 200, 800, 2400];

impl StateStore {
    /// [`StateStore::save`], tried again after each of [`SAVE_RETRIES_MS`]
    /// while no descriptor is free.
    pub fn save_retrying(&self, calibration: &Calibration) -> Result<(), StateError> {
        let mut waits = SAVE_RETRIES_MS.iter();
        loop {
            match self.save(calibration) {
                Err(e) if e.out_of_descriptors() => match waits.next() {
                    Some(ms) => {
                        tracing::warn!(
                            sensor = calibration.sensor,
                            "no file descriptor free to store the calibration; trying again in {ms} ms"
                        );
                        std::thread::sleep(std::time::Duration::from_millis(*ms));
                    }
                    None => return Err(e),
                },
                other => return other,
            }
        }
    }

    /// Opens (creating if needed) the state directory. The directory must
    /// exist or be creatable, and be listable. One that can be read but not
    /// written (a read-only file system, missing permission) still opens:
    /// the calibrations in it load and correct readings, and
    /// [`StateStore::unwritable`] says why new ones cannot be kept, for
    /// the caller to report at start. Saves are still tried (the directory
    /// may be made writable meanwhile) and report their own failure.
    pub fn open(dir: &Path) -> Result<StateStore, StateError> {
        match fs::metadata(dir) {
            Ok(meta) if !meta.is_dir() => {
                return Err(StateError::NotADirectory {
                    dir: dir.to_path_buf(),
                });
            }
            Ok(_) => {}
            // NotADirectory: a parent is a regular file; creating says so.
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::NotFound | io::ErrorKind::NotADirectory
                ) =>
            {
                fs::create_dir_all(dir).map_err(|source| StateError::CreateDir {
                    dir: dir.to_path_buf(),
                    source,
                })?;
            }
            Err(source) => {
                return Err(StateError::NotWritable {
                    dir: dir.to_path_buf(),
                    source,
                });
            }
        }
        // Probe: can we list it and create a file in it? The probe file is
        // removed when dropped uncommitted.
        if let Err(source) = fs::read_dir(dir) {
            return Err(StateError::NotWritable {
                dir: dir.to_path_buf(),
                source,
            });
        }
        if let Err(source) = AtomicFile::create(&dir.join(".fieldcal-probe")) {
            return Ok(StateStore {
                dir: dir.to_path_buf(),
                unwritable: Some(std::sync::Arc::new(StateError::ReadOnly {
                    dir: dir.to_path_buf(),
                    source,
                })),
            });
        }
        remove_stale_temporaries(dir);
        Ok(StateStore {
            dir: dir.to_path_buf(),
            unwritable: None,
        })
    }

    /// Why new calibrations cannot be stored, when the directory could not
    /// be written at open: a [`StateError::ReadOnly`].
    pub fn unwritable(&self) -> Option<&StateError> {
        self.unwritable.as_deref()
    }

    /// The state directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The file of `sensor`: `<dir>/<sensor>.json`. Names outside the
    /// configuration's charset (letters, digits, `-`, `_`) are escaped
    /// byte-wise as `%XX`, so no name leaves the directory (`/`, `..`) or
    /// hides (a leading `.`), and two names never share a file.
    pub fn path_for(&self, sensor: &str) -> PathBuf {
        let mut stem = String::with_capacity(sensor.len());
        for byte in sensor.bytes() {
            if byte.is_ascii_alphanumeric() || byte == b'-' || byte == b'_' {
                stem.push(char::from(byte));
            } else {
                stem.push_str(&format!("%{byte:02X}"));
            }
        }
        if stem.is_empty() {
            // No valid name is empty, and no escaped one is a lone "%".
            stem.push('%');
        }
        self.dir.join(format!("{stem}.json"))
    }

    /// The stored calibration of `sensor`, if any.
    ///
    /// A file that is unreadable, not JSON of this layout, of another format
    /// version, holds non-finite or impossible numbers, or belongs to another
    /// sensor, is moved aside to `<name>.corrupt-<unix seconds>` and
    /// reported as [`StateError::Corrupt`]; the caller logs it and goes on
    /// uncalibrated. Moving it keeps it for a person to inspect and keeps a
    /// later save from overwriting the evidence.
    pub fn load(&self, sensor: &str) -> Result<Option<Calibration>, StateError> {
        let path = self.path_for(sensor);
        let problem = match read_bounded(&path) {
            Ok(None) => return Ok(None),
            Ok(Some(bytes)) => match decode(&bytes, sensor) {
                Ok(calibration) => return Ok(Some(calibration)),
                Err(problem) => problem,
            },
            Err(e) => format!("unreadable: {e}"),
        };
        Err(self.move_aside(path, problem))
    }

    /// [`StateStore::load`], then `check` (the sensor's geometry and its
    /// acceptance limits) on what it found: a calibration it refuses is
    /// moved aside as a corrupt one, and an earlier one of its history it
    /// refuses is dropped (never rolled back to).
    pub fn load_checked(
        &self,
        sensor: &str,
        check: impl Fn(&Calibration) -> Option<String>,
    ) -> Result<Option<Calibration>, StateError> {
        let Some(mut calibration) = self.load(sensor)? else {
            return Ok(None);
        };
        if let Some(problem) = check(&calibration) {
            return Err(self.move_aside(self.path_for(sensor), problem));
        }
        calibration.history.retain(|h| check(h).is_none());
        Ok(Some(calibration))
    }

    /// Atomically replaces the sensor's file. On any error the old file is
    /// intact, and the error says so.
    pub fn save(&self, calibration: &Calibration) -> Result<(), StateError> {
        let path = self.path_for(&calibration.sensor);
        if let Some(problem) = calibration_problem(calibration) {
            return Err(StateError::Invalid {
                sensor: calibration.sensor.clone(),
                path,
                problem,
            });
        }
        let stored = StoredRef {
            format: FORMAT_VERSION,
            calibration,
        };
        let mut json = serde_json::to_vec_pretty(&stored)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))
            .map_err(|source| StateError::Write {
                before: self.stored_before(&path),
                path: path.clone(),
                source,
            })?;
        json.push(b'\n');
        let write = || -> io::Result<()> {
            let mut file = AtomicFile::create(&path)?;
            file.as_file_mut().write_all(&json)?;
            file.commit()
        };
        write().map_err(|source| StateError::Write {
            before: self.stored_before(&path),
            path: path.clone(),
            source,
        })
    }

    /// After a failed save of `path`: what is left of what was stored.
    fn stored_before(&self, path: &Path) -> StoredBefore {
        let gone = StoredBefore::DirectoryGone {
            dir: self.dir.clone(),
        };
        match fs::metadata(&self.dir) {
            Ok(meta) if !meta.is_dir() => gone,
            Ok(_) => match fs::symlink_metadata(path) {
                Err(e) if e.kind() == io::ErrorKind::NotFound => StoredBefore::Nothing,
                _ => StoredBefore::Unchanged,
            },
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::NotFound | io::ErrorKind::NotADirectory
                ) =>
            {
                gone
            }
            // Cannot tell (a permission on the way): nothing was touched.
            Err(_) => StoredBefore::Unchanged,
        }
    }

    fn move_aside(&self, path: PathBuf, problem: String) -> StateError {
        let seconds = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // Two corruptions within one second must not overwrite each other.
        let mut moved_to = self.dir.join(format!("{name}.corrupt-{seconds}"));
        let mut n = 1u32;
        while fs::symlink_metadata(&moved_to).is_ok() && n < 1000 {
            moved_to = self.dir.join(format!("{name}.corrupt-{seconds}-{n}"));
            n += 1;
        }
        match fs::rename(&path, &moved_to) {
            Ok(()) => StateError::Corrupt {
                path,
                moved_to,
                problem,
            },
            Err(source) => StateError::CorruptNotMoved {
                path,
                problem,
                source,
            },
        }
    }
}

/// Removes the temporaries a killed writer left (`.<sensor>.json.tmp.<pid>.<n>`
/// and `.fieldcal-probe.tmp.<pid>.<n>`, see [`AtomicFile`]) when process
/// `<pid>` is gone: a kill between creating and renaming the temporary file
/// leaves it, and without this each crash would add one. A temporary of a
/// live process (another fieldcal writing, or an unrelated process that
/// reuses the pid) is left alone, as is anything else in the directory.
/// Where `/proc` is missing, liveness cannot be told and nothing is removed.
/// Best effort: a failure to list or remove is ignored.
fn remove_stale_temporaries(dir: &Path) {
    if !Path::new("/proc/self").exists() {
        return;
    }
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    let own = std::process::id();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(stale_temporary_pid) else {
            continue;
        };
        if pid != own && !Path::new(&format!("/proc/{pid}")).exists() {
            match fs::remove_file(entry.path()) {
                Ok(()) => tracing::info!(
                    file = %entry.path().display(),
                    "removed a temporary file left by a writer that was killed"
                ),
                Err(e) => tracing::debug!(file = %entry.path().display(), "{e}"),
            }
        }
    }
}

/// The writer's pid when `name` is one of the store's temporaries:
/// `.<stem>.json.tmp.<pid>.<n>` or `.fieldcal-probe.tmp.<pid>.<n>`.
fn stale_temporary_pid(name: &str) -> Option<u32> {
    let rest = name.strip_prefix('.')?;
    let (stem, suffix) = rest.rsplit_once(".tmp.")?;
    if !(stem.ends_with(".json") || stem == "fieldcal-probe") {
        return None;
    }
    let (pid, n) = suffix.split_once('.')?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !(digits(pid) && digits(n)) {
        return None;
    }
    pid.parse().ok()
}

/// The file's bytes, `None` when there is no file; a file above
/// [`MAX_FILE_LEN`] is an error rather than a large allocation, and so is
/// anything but a regular file: a FIFO put in a state file's place would
/// otherwise hold the start in `open` (before READY, deaf to SIGTERM).
fn read_bounded(path: &Path) -> io::Result<Option<Vec<u8>>> {
    match crate::io::regular::read_regular(path, MAX_FILE_LEN) {
        Ok(bytes) => Ok(Some(bytes)),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e),
    }
}

/// A state file's bytes as [`StateStore::load`] reads them for `sensor`
/// (without the file system): the calibration, or why the file is corrupt.
/// For tools and the fuzz target of the loader.
pub fn decode_state(bytes: &[u8], sensor: &str) -> Result<Calibration, String> {
    decode(bytes, sensor)
}

/// Parses and checks a stored file; the error is the problem, for a person.
fn decode(bytes: &[u8], sensor: &str) -> Result<Calibration, String> {
    if bytes.is_empty() {
        return Err("empty file".into());
    }
    let version: StoredVersion =
        serde_json::from_slice(bytes).map_err(|e| format!("not a calibration file: {e}"))?;
    if version.format != FORMAT_VERSION {
        return Err(format!(
            "format version {}, this fieldcal reads version {FORMAT_VERSION}",
            version.format
        ));
    }
    let stored: Stored =
        serde_json::from_slice(bytes).map_err(|e| format!("not a calibration file: {e}"))?;
    let mut calibration = stored.calibration;
    // An earlier calibration that could not correct readings (another
    // sensor's, the other geometry's, an impossible number) is dropped from
    // the history, never rolled back to; the current one is judged below.
    let geometry = calibration.ellipsoid.is_some();
    let before = calibration.history.len();
    calibration.history.retain(|h| {
        h.sensor == sensor && h.ellipsoid.is_some() == geometry && calibration_problem(h).is_none()
    });
    let excess = calibration
        .history
        .len()
        .saturating_sub(crate::model::watch::HISTORY);
    calibration.history.drain(..excess);
    for h in &mut calibration.history {
        h.history.clear();
    }
    if calibration.history.len() + excess < before {
        tracing::warn!(
            sensor,
            dropped = before - excess - calibration.history.len(),
            "earlier calibrations in the state file that could not correct readings were dropped from its history"
        );
    }
    if calibration.sensor != sensor {
        return Err(format!(
            "it holds the calibration of sensor '{}', not of '{sensor}'",
            calibration.sensor
        ));
    }
    if let Some(problem) = calibration_problem(&calibration) {
        return Err(problem);
    }
    Ok(calibration)
}

/// What makes a calibration unusable for correcting readings: a number
/// that is not finite (the corrector would publish NaN), a gain or field
/// magnitude that is not positive (it divides by them), or an rms or
/// coverage outside its range.
fn calibration_problem(c: &Calibration) -> Option<String> {
    if !(1..=MAX_ID).contains(&c.id) {
        return Some(format!(
            "id is {}: ids run from 1 to {MAX_ID} (the largest integer a JSON client reads exactly), and never go back",
            c.id
        ));
    }
    let p = &c.params;
    let numbers = [
        ("params.a", p.a),
        ("params.b", p.b),
        ("params.d", p.d),
        ("params.r", p.r),
        ("rms", c.rms),
        ("coverage_deg", c.coverage_deg),
        ("time", c.time),
    ];
    if let Some((name, v)) = numbers.iter().find(|(_, v)| !v.is_finite()) {
        return Some(format!("{name} is {v}, not a finite number"));
    }
    for (name, v) in [("params.a", p.a), ("params.r", p.r)] {
        if !(v > 0.0) {
            return Some(format!("{name} is {v}, it must be above zero"));
        }
    }
    if c.rms < 0.0 {
        return Some(format!("rms is {}, it cannot be negative", c.rms));
    }
    if let Some(g) = &c.gyro {
        // A heading check's scale is near ±1 (a gyro about the turn's
        // axis, either way round); its noise and bias are finite.
        let sane = g.scale.is_finite()
            && (0.5..=2.0).contains(&g.scale.abs())
            && g.bias_deg_s.is_finite()
            && g.heading_rms_deg.is_finite()
            && g.heading_rms_deg >= 0.0;
        if !sane {
            return Some(format!(
                "gyro is {g:?}: a heading check's scale is within 0.5-2 either way and its numbers finite"
            ));
        }
    }
    if let Some(e) = &c.ellipsoid {
        // A mirror, a collapse, a matrix no sensor has or an offset of
        // 1e308 would correct every reading wrongly while saying so.
        if let Err(e) = e.calibration().validate() {
            return Some(format!("ellipsoid: {e}"));
        }
        if !(0.0..=1.0).contains(&e.coverage) {
            return Some(format!(
                "ellipsoid.coverage is {}, not a fraction",
                e.coverage
            ));
        }
    }
    if !(0.0..=360.0).contains(&c.coverage_deg) {
        return Some(format!(
            "coverage_deg is {}, not between 0 and 360",
            c.coverage_deg
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognises_only_the_store_temporaries() {
        assert_eq!(stale_temporary_pid(".compass.json.tmp.123.4"), Some(123));
        assert_eq!(stale_temporary_pid(".fieldcal-probe.tmp.9.0"), Some(9));
        assert_eq!(stale_temporary_pid(".a%2Eb.json.tmp.77.12"), Some(77));
        for other in [
            "compass.json",
            "compass.json.corrupt-1700000000",
            ".compass.json.tmp.123",
            ".compass.json.tmp.x.1",
            ".compass.json.tmp.1.",
            ".notes.txt.tmp.1.2",
            "compass.json.tmp.1.2",
        ] {
            assert_eq!(stale_temporary_pid(other), None, "{other}");
        }
    }

    #[test]
    fn open_removes_temporaries_of_dead_writers_only() {
        let dir = tempfile::tempdir().unwrap();
        // Above the largest pid_max Linux allows (2^22): never alive.
        let dead = 4_194_305u32;
        let own = std::process::id();
        let keep = [
            "compass.json".to_string(),
            format!(".compass.json.tmp.{own}.7"), // this process: a live writer
            format!(".notes.tmp.{dead}.1"),       // not one of ours
            format!("compass.json.corrupt-{dead}"),
        ];
        let remove = [
            format!(".compass.json.tmp.{dead}.3"),
            format!(".gyro_2.json.tmp.{dead}.0"),
            format!(".fieldcal-probe.tmp.{dead}.1"),
        ];
        for name in keep.iter().chain(&remove) {
            fs::write(dir.path().join(name), "x").unwrap();
        }
        StateStore::open(dir.path()).unwrap();
        let mut left: Vec<String> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        let mut expected = keep.to_vec();
        expected.sort();
        assert_eq!(left, expected);
    }
}
