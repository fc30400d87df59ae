//! The configuration of `fieldcal run`: one TOML file naming the sources
//! (ports, bridges, replayed captures), the sensors calibrated on them, the
//! outputs and the daemon's own settings.
//!
//! [`load`] only reads and checks: nothing is opened, bound or started, so a
//! configuration error stops the daemon before it touches any device. Every
//! error names the file, the key as a dotted path (`sensor[1].axes`, indices
//! from 0 in file order), what was found and what is allowed, with the line
//! and column where the key or value is in the file.
//!
//! # Example, every key
//!
//! ```toml
//! [daemon]
//! # Where calibrations are kept, one JSON file per sensor. Default:
//! # $STATE_DIRECTORY (set by systemd's StateDirectory=), else ./state in
//! # the working directory.
//! state_dir = "/var/lib/fieldcal"
//! # Seconds between STATUS messages (and systemd status lines). Default 1.
//! status_interval_s = 1.0   # 0.05 to 86400 s; default 1
//! # Log lines on stderr: "text" (default) or "json".
//! log_format = "text"
//! # True north for every magnetometer (field = "mag") of a device source:
//! # the declination, degrees east of true north, -180 to 180...
//! # declination_deg = 3.8
//! # ...or (not both) the place, whose declination NOAA's World Magnetic
//! # Model (WMM2020/WMM2025, 2020-01-01 to 2029-12-31) gives. A sensor's own
//! # declination_deg or [sensor.location] replaces it; csv sensors take
//! # only their own.
//! [daemon.location]
//! latitude = 50.1109        # WGS 84 degrees north, -90 to 90
//! longitude = 8.6821        # WGS 84 degrees east, -180 to 180
//! height_m = 100.0          # above the WGS 84 ellipsoid, -1000 to 850000; default 0
//! date = "2026-06-01"       # default: the host's date at start and at each reload
//!
//! [outputs]
//! # Newline-delimited JSON on standard output. Default true.
//! stdout = true
//! # A TCP listener, as IP:PORT. Optional. Only loopback addresses unless
//! # tcp_public = true (readings are not authenticated).
//! tcp = "127.0.0.1:2948"
//! tcp_public = false
//! # A Unix-socket listener. Optional.
//! unix = "/run/fieldcal/fieldcal.sock"
//! # The live page in a browser (and its JSON/server-sent-events API), as
//! # IP:PORT; port 0 picks a free one (the log says which). Optional. Only
//! # loopback addresses unless http_public = true (no authentication, and
//! # the page can start a recalibration).
//! http = "127.0.0.1:8080"
//! http_public = false
//! # Lines queued per subscriber before a slow one is dropped. Default 4096.
//! queue = 4096
//! # Subscribers at once (TCP, Unix socket, live page streams; stdout does
//! # not count); 1 to 100000. Default: 64, fewer when the descriptor limit
//! # (RLIMIT_NOFILE) minus 32 kept for the daemon is less; a value that does
//! # not leave those 32 stops the start.
//! max_subscribers = 64
//! # The Unix socket's mode, octal (default "0660"), and its group (a name
//! # or a number; default the daemon's group).
//! unix_mode = "0660"
//! unix_group = "fieldcal"
//! # Listeners whose subscribers may send "recalibrate": any of "unix",
//! # "tcp", "http". Default ["unix"]. "status" is open to all.
//! recalibrate_from = ["unix"]
//! # A file holding a token (not readable by others, not writable by its
//! # group); a command carrying "token":"..." equal to it may recalibrate
//! # from any listener. Optional.
//! token_file = "/etc/fieldcal/token"
//!
//! [[source]]
//! name = "imu"              # letters, digits, '-', '_'
//! kind = "falcon"           # falcon | usb-iss | replay
//! port = "/dev/ttyUSB0"     # falcon, usb-iss: the serial device
//! baud = 38400              # falcon only; default 38400
//! retry_s = 2.0             # seconds between tries after a failure; 0.05 to 3600; default 2
//!
//! [[source]]
//! name = "bridge"
//! kind = "usb-iss"
//! port = "/dev/ttyACM0"
//! # NAME or NAME@ADDR (7-bit address, 0x.. hex or decimal); the default
//! # address is the chip's usual one. Chips: adxl345, mpu6050,
//! # lsm303dlhc-accel, lsm303dlhc-mag.
//! chips = ["mpu6050", "lsm303dlhc-mag@0x1e"]
//! poll_ms = 30              # 1..=60000; default 30
//! i2c_khz = 100             # 100 (default) or 400
//!
//! [[source]]
//! name = "bench"
//! kind = "replay"
//! file = "captures/turn.fcap"  # relative to this file's directory
//! speed = 1.0               # a factor from 0.001 to 1e6, or "max"; default 1
//!
//! [[source]]
//! name = "log"
//! kind = "csv"              # a CSV recording, played row by row
//! file = "robot.csv"        # relative to this file's directory
//! time_column = "t_s"       # default: the first of t, t_s, time, time_s
//! period_s = 0.1            # only when the file has no time column
//! speed = "max"             # as for kind = "replay"; default 1
//!
//! [[sensor]]                # a sensor of a csv source names two columns
//! name = "robot-compass"
//! source = "log"
//! axes = ["mag_x", "mag_z"] # no `field`, no `chip`: columns of the file
//! gyro = "gyro_y"           # a column, for the heading check; or "none"
//! gyro_units = "deg/s"      # or "rad/s"; default deg/s
//! out_of_plane = "mag_y"    # the column across the turn, for the trust
//!                           # monitor (a device's sensor: its axis, "z")
//! tilt = "board-level"      # the 3-axis accel sensor of the same source: the
//!                           # trust monitor distrusts a heading tilted from
//!                           # the attitude of its calibration (a device's
//!                           # 2-axis sensor takes `tilt` too)
//!
//! [[source]]
//! name = "board"
//! kind = "csv"              # several files recorded on one clock, each with
//! files = ["mag.csv", "imu.csv"]  # its own header and time column; rows
//!                           # played merged in time order; 1 to 16 files;
//!                           # not with `file`, nor `period_s`
//!
//! [[sensor]]                # a 3-axis sensor of a csv source: three columns
//! name = "board-compass"    # of one file (its x, y, z) and the field
//! source = "board"
//! axes = ["mag_x", "mag_y", "mag_z"]
//! field = "mag"             # required with three columns: mag | accel
//! lsb_per_gauss = 1090      # and tilt, model, [sensor.sphere] as for a device
//! tilt = "board-level"      # a 3-axis accel sensor of the same source; its
//!                           # latest row older than 0.1 s leaves the heading out
//!
//! [[sensor]]
//! name = "compass"          # letters, digits, '-', '_'; names the state file
//! source = "bridge"
//! chip = "lsm303dlhc-mag"   # which chip of a usb-iss source (or of a replayed
//!                           # bridge capture); optional when it has one
//! field = "mag"             # mag | accel | gyro
//! axes = ["x", "y"]         # the two axes that turn, two different of x, y, z
//! model = "paper"           # or ["offset", "scale"], or "offset+scale"
//! # The gyro axis about which the sensor turns, for the heading check of
//! # each CALIBRATION: "x", "y", "z" or "none". Default: the axis
//! # perpendicular to `axes` when the sensor's stream carries a gyro (a
//! # Falcon-GX frame, an MPU-6050), else none.
//! gyro = "z"
//! gyro_chip = "mpu6050"     # the gyro of another chip of the same source
//!                           # (then `gyro` is required: mountings differ)
//! gyro_lsb_per_deg_s = 131.0  # counts per deg/s; default the chip's
//!                           # (MPU-6050 at +-250 deg/s: 131; Falcon-GX: 10)
//! # A magnetometer's true north (also for a csv sensor): READINGs carry
//! # true_heading_deg, CALIBRATIONs declination_deg and its source.
//! declination_deg = -1.5    # or [sensor.location], as [daemon.location]
//! [sensor.rotation]         # the rotation buffer's settings
//! [sensor.limits]           # the acceptance limits of a fit
//!
//! [[sensor]]                # a 3-axis sensor: all three axes
//! name = "compass3"
//! source = "imu"
//! field = "mag"
//! axes = ["x", "y", "z"]    # in the order of the sensor's x, y, z
//! model = "offset+scale+cross-axis"  # or "offset", "offset+scale"; default "full"
//! lsb_per_gauss = 1090.0    # a magnetometer's counts per gauss (lsb_per_g: an accelerometer's)
//! tilt = "level"            # the 3-axis accelerometer sensor of the same source
//! mag_axes = "-x,-z,y"      # with tilt: the magnetometer's axis along the
//!                           # accelerometer's x, y, z; default "x,y,z"
//! gyro = "none"             # with tilt: the heading is checked against the
//!                           # tilt chip's gyro when it has one; "none": not
//!                           # (a csv compass: gyro = ["gx", "gy", "gz"], its
//!                           # three columns in the accelerometer's axes)
//! on_stale = "warn"         # a later sphere that moved it: "warn" or "replace"
//! [sensor.location]         # the WMM's declination, and its field beside the fitted one
//! latitude = 50.1109
//! longitude = 8.6821
//! [sensor.sphere]           # min_samples, max_samples, max_rms, still (an accelerometer at rest in poses)
//! ```
//!
//! Relative paths in the file (`file`, `state_dir`, `unix`) are relative to
//! the file's own directory, so a configuration works from any working
//! directory.

use std::collections::HashMap;
use std::fmt;
use std::io::Read;
use std::net::SocketAddr;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use toml::Spanned;
use toml::de::{DeTable, DeValue};

use super::north::{LocationKeys, North};
use super::publish::{Access, Origin, Token};
use crate::capture::{self, CaptureFile, StreamKind};
use crate::io::csv::{CsvLayout, open_rows};
use crate::model::effects::{self, Effect};
use crate::model::gyro::GyroUnits;
use crate::protocol::chips::Chip;
use crate::protocol::falcon;
use crate::source::bridge::BridgeConfig;
use crate::source::replay::Speed;

/// When a sensor's rotation counts as complete (`[sensor.rotation]`).
pub type RotationSettings = crate::daemon::rotation::RotationConfig;
/// The limits a fit must meet to be accepted (`[sensor.limits]`).
pub type LimitSettings = crate::daemon::acceptance::Limits;

/// Shortest `daemon.status_interval_s`: 50 ms, the Falcon-GX's frame period
/// (the I2C bridge polls every 30 ms by default). A STATUS line more often
/// than readings arrive says nothing new, and a microsecond interval filled
/// a slow subscriber's queue in milliseconds and left the loop handling
/// one reading in a hundred (issue 12).
const MIN_STATUS_INTERVAL_S: f64 = 0.05;
/// Shortest `retry_s` of a source: a USB serial adapter takes hundreds of
/// milliseconds to enumerate again after a replug, so trying to reopen it
/// more than 20 times a second only burns CPU and fills the log.
const MIN_RETRY_S: f64 = 0.05;
/// Names become file names and JSON values: keep them short.
const NAME_MAX: usize = 64;
/// A checked configuration.
#[derive(Debug, Clone)]
pub struct Config {
    pub daemon: DaemonConfig,
    pub outputs: OutputsConfig,
    /// In file order.
    pub sources: Vec<SourceConfig>,
    /// In file order; at least one.
    pub sensors: Vec<SensorConfig>,
    /// The file it was read from, as given.
    pub path: PathBuf,
}

/// `[daemon]`.
#[derive(Debug, Clone, PartialEq)]
pub struct DaemonConfig {
    /// Where the calibrations are kept.
    pub state_dir: PathBuf,
    /// Time between STATUS messages.
    pub status_interval: Duration,
    pub log_format: LogFormat,
}

/// How log lines are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// For people (journalctl, a terminal).
    #[default]
    Text,
    /// One JSON object a line, for log collectors.
    Json,
}

/// `[outputs]`.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputsConfig {
    /// The outputs to start, in the order of the kinds' list
    /// ([`crate::daemon::output_kinds`]), each kind at most once.
    pub outputs: Vec<Output>,
    /// Lines queued per subscriber.
    pub queue: usize,
    /// Subscribers at once; None: derived from the descriptor limit at start.
    pub max_subscribers: Option<usize>,
    /// Who may recalibrate (`recalibrate_from`, and the token of `token_file`).
    pub access: Access,
}

impl OutputsConfig {
    /// Whether the lines go to stdout.
    pub fn stdout(&self) -> bool {
        self.outputs.iter().any(|o| matches!(o, Output::Stdout(_)))
    }

    /// The TCP listener's address (loopback unless `tcp_public = true`).
    pub fn tcp(&self) -> Option<SocketAddr> {
        self.outputs.iter().find_map(|o| match o {
            Output::Tcp(t) => Some(t.address),
            _ => None,
        })
    }

    /// The Unix socket's path.
    pub fn unix(&self) -> Option<&Path> {
        self.outputs.iter().find_map(|o| match o {
            Output::Unix(u) => Some(u.path.as_path()),
            _ => None,
        })
    }

    /// The live page's address (loopback unless `http_public = true`).
    pub fn http(&self) -> Option<SocketAddr> {
        self.outputs.iter().find_map(|o| match o {
            Output::Http(h) => Some(h.address),
            _ => None,
        })
    }
}

/// One `[[source]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceConfig {
    pub name: String,
    pub kind: SourceKind,
    /// Time between tries after a failure.
    pub retry: Duration,
}

impl SourceConfig {
    /// The bridge settings of a `usb-iss` source, `None` for other kinds.
    pub fn bridge_config(&self) -> Option<BridgeConfig> {
        match &self.kind {
            SourceKind::UsbIss(bridge) => Some(bridge.bridge_config(self.retry)),
            _ => None,
        }
    }
}

/// Which quantity of a reading a sensor calibrates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Field {
    Mag,
    Accel,
    Gyro,
}

impl Field {
    pub fn name(self) -> &'static str {
        match self {
            Field::Mag => "mag",
            Field::Accel => "accel",
            Field::Gyro => "gyro",
        }
    }
}

/// An axis of a 3-axis reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    pub fn name(self) -> &'static str {
        match self {
            Axis::X => "x",
            Axis::Y => "y",
            Axis::Z => "z",
        }
    }

    /// The index into a reading's `[x, y, z]`.
    pub fn index(self) -> usize {
        match self {
            Axis::X => 0,
            Axis::Y => 1,
            Axis::Z => 2,
        }
    }
}

/// One `[[sensor]]`: two or three axes of one field of one stream of a
/// source.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorConfig {
    pub name: String,
    /// The name of its source (present in [`Config::sources`]).
    pub source: String,
    /// The stream of the source: the chip's place in a usb-iss `chips`
    /// list, the stream id of a replayed capture, 0 for a Falcon.
    pub stream: u8,
    pub field: Field,
    /// What it measures with: two axes turned in a plane, or three over a
    /// sphere, each with the settings of that geometry only.
    pub geometry: SensorGeometry,
    /// A magnetometer's true north (`declination_deg` or `[sensor.location]`,
    /// else `[daemon]`'s for a device's magnetometer): its readings then
    /// carry `true_heading_deg`.
    pub north: Option<North>,
}

/// The gyro a sensor's heading is checked against (`gyro`, `gyro_chip`,
/// `gyro_lsb_per_deg_s`).
#[derive(Debug, Clone, PartialEq)]
pub enum GyroChoice {
    /// The angular rate about the turn's axis: `axis` of the gyro of the
    /// source's stream `stream`, `lsb_per_deg_s` counts per degree/second.
    Rate {
        stream: u8,
        axis: Axis,
        lsb_per_deg_s: f64,
    },
    /// The angular rate about the turn's axis in a column of the sensor's
    /// CSV recording, in `units`.
    Column { name: String, units: GyroUnits },
    /// No heading check, and why (said in each CALIBRATION).
    Off(String),
}

impl Config {
    /// The source named `name`.
    pub fn source(&self, name: &str) -> Option<&SourceConfig> {
        self.sources.iter().find(|s| s.name == name)
    }
}

/// Where in the file: 1-based line and column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Position {
    pub line: usize,
    pub column: usize,
}

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.line, self.column)
    }
}

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read the configuration {}: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}:{position}: not valid TOML: {message}", path.display())]
    Syntax {
        path: PathBuf,
        position: Position,
        message: String,
    },
    /// A key with a wrong, missing or unknown value.
    #[error("{}: {key}: {problem}", located(path, position))]
    Invalid {
        path: PathBuf,
        /// Dotted path, e.g. `sensor[1].axes`; empty for the whole file.
        key: String,
        position: Option<Position>,
        problem: String,
    },
}

impl ConfigError {
    /// The dotted key the error is about, if it is about one.
    pub fn key(&self) -> Option<&str> {
        match self {
            ConfigError::Invalid { key, .. } => Some(key),
            _ => None,
        }
    }

    /// The line and column, where known.
    pub fn position(&self) -> Option<Position> {
        match self {
            ConfigError::Read { .. } => None,
            ConfigError::Syntax { position, .. } => Some(*position),
            ConfigError::Invalid { position, .. } => *position,
        }
    }
}

/// The largest configuration file read, in bytes. A configuration of a
/// dozen sources and sensors with comments is a few kilobytes; a file of a
/// megabyte is not one, and is refused rather than read into memory.
pub const MAX_CONFIG_LEN: u64 = 1 << 20;

/// Reads and checks the configuration at `path`. Starts nothing. The path
/// must be a regular file (a FIFO or a device is refused before it can
/// block, see [`crate::io::regular`]) of at most [`MAX_CONFIG_LEN`] bytes.
pub fn load(path: &Path) -> Result<Config, ConfigError> {
    let read = |source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    };
    let bytes = crate::io::regular::read_regular(path, MAX_CONFIG_LEN).map_err(read)?;
    let text = String::from_utf8(bytes)
        .map_err(|e| read(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))?;
    parse(&text, path)
}

/// Checks a configuration's text; `path` is named in errors and anchors
/// relative paths. Reads nothing but replayed captures' headers.
pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
    let doc = match DeTable::parse(text) {
        Ok(doc) => doc,
        Err(e) => {
            return Err(ConfigError::Syntax {
                path: path.to_path_buf(),
                position: e
                    .span()
                    .map(|s| position_of(text, s.start))
                    .unwrap_or(Position { line: 1, column: 1 }),
                message: e.message().trim_end().to_string(),
            });
        }
    };
    let checker = Checker {
        text,
        path,
        doc: &doc,
        base: match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        },
    };
    let raw: RawConfig = toml::from_str(text).map_err(|e| checker.serde_error(&e))?;
    checker.check(raw)
}

mod columns;
mod keys;
mod outputs;
mod raw;
mod sensors;
mod settings;
mod sources;
mod spans;
mod tilt;

pub use crate::daemon::output_kinds::Output;
pub use crate::daemon::source_kinds::SourceKind;
use columns::Columns;
pub(crate) use keys::{Keys, RawKeys};
use raw::*;
use sensors::PlaneSensor;
pub use sensors::{
    Gyro3Choice, OnStale, OutOfPlane, PlaneConfig, Sensor3Config, SensorGeometry, TiltSource,
    WatchSettings,
};
pub use sources::StreamDesc;
use sources::*;
use spans::*;

// ---------------------------------------------------------------------------
// Checking, with positions looked up in the spanned document.

pub(crate) struct Checker<'a> {
    text: &'a str,
    path: &'a Path,
    doc: &'a Spanned<DeTable<'a>>,
    base: PathBuf,
}

impl Checker<'_> {
    pub(crate) fn error(&self, key: &str, problem: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            path: self.path.to_path_buf(),
            key: key.to_string(),
            position: self.span_of(key).map(|s| position_of(self.text, s.start)),
            problem: problem.into(),
        }
    }

    /// A deserialisation error, with the key found from its span.
    fn serde_error(&self, e: &toml::de::Error) -> ConfigError {
        let message = e.message().trim_end().to_string();
        let span = e.span();
        let mut key = span
            .as_ref()
            .and_then(|s| path_at(self.doc, s.start))
            .unwrap_or_default();
        // "missing field `x`" points at the table; name the missing key.
        if let Some(missing) = message
            .strip_prefix("missing field `")
            .and_then(|m| m.split('`').next())
        {
            key = if key.is_empty() {
                missing.to_string()
            } else {
                format!("{key}.{missing}")
            };
        }
        ConfigError::Invalid {
            path: self.path.to_path_buf(),
            key,
            position: span.map(|s| position_of(self.text, s.start)),
            problem: message,
        }
    }

    /// Messages show the path as the user would write it: without `.`
    /// components (not `././mag.csv`).
    pub(crate) fn resolve(&self, path: &Path) -> PathBuf {
        let joined = if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.base.join(path)
        };
        let tidy: PathBuf = joined
            .components()
            .filter(|c| !matches!(c, std::path::Component::CurDir))
            .collect();
        if tidy.as_os_str().is_empty() {
            PathBuf::from(".")
        } else {
            tidy
        }
    }

    fn check(&self, mut raw: RawConfig) -> Result<Config, ConfigError> {
        self.refuse_unknown_output_keys(&raw.outputs)?;
        self.refuse_unknown_source_keys(&raw.source)?;
        let today = crate::geomag::CivilDate::today();
        let daemon_north = self.check_north(
            "daemon",
            raw.daemon.declination_deg,
            raw.daemon.location.take(),
            today,
        )?;
        let daemon = self.check_daemon(raw.daemon)?;
        let outputs = self.check_outputs(&raw.outputs)?;
        let checked = self.check_sources(raw.source)?;
        let sensors = self.check_sensors(raw.sensor, &checked, daemon_north, today)?;
        Ok(Config {
            daemon,
            outputs,
            sources: checked.sources,
            sensors,
            path: self.path.to_path_buf(),
        })
    }

    /// Every `[[source]]`, each under a name of its own.
    fn check_sources(&self, raw: Vec<RawSource>) -> Result<CheckedSources, ConfigError> {
        let mut sources = Vec::with_capacity(raw.len());
        let mut streams: Vec<Vec<StreamDesc>> = Vec::with_capacity(raw.len());
        // The header of each csv source's file, resolved.
        let mut layouts: Vec<Option<Vec<CsvLayout>>> = Vec::with_capacity(raw.len());
        let mut source_index: HashMap<String, usize> = HashMap::new();
        for (i, s) in raw.into_iter().enumerate() {
            let key = format!("source[{i}]");
            self.check_name(&format!("{key}.name"), &s.name)?;
            if let Some(j) = source_index.get(&s.name) {
                return Err(self.error(
                    &format!("{key}.name"),
                    format!(
                        "'{}' is already the name of source[{j}]: give every source its own name",
                        s.name
                    ),
                ));
            }
            source_index.insert(s.name.clone(), i);
            let checked = self.check_source(&key, &s)?;
            sources.push(checked.settings);
            streams.push(checked.streams);
            layouts.push(checked.layouts);
        }
        Ok(CheckedSources {
            sources,
            streams,
            layouts,
            index: source_index,
        })
    }

    /// Every `[[sensor]]`, each under a name of its own and on a source of
    /// the file; then the tilt sources they name.
    fn check_sensors(
        &self,
        raw: Vec<RawSensor>,
        checked: &CheckedSources,
        daemon_north: Option<North>,
        today: Option<crate::geomag::CivilDate>,
    ) -> Result<Vec<SensorConfig>, ConfigError> {
        let CheckedSources {
            sources,
            streams,
            layouts,
            index: source_index,
        } = checked;
        if raw.is_empty() {
            return Err(self.error(
                "sensor",
                "no [[sensor]] in the file: `fieldcal run` needs at least one sensor to \
                 calibrate (name, source, field, axes)",
            ));
        }
        let mut sensors = Vec::with_capacity(raw.len());
        let mut sensor_index: HashMap<String, usize> = HashMap::new();
        let mut pending_tilts: Vec<(usize, String)> = Vec::new();
        for (i, s) in raw.into_iter().enumerate() {
            let key = format!("sensor[{i}]");
            self.check_name(&format!("{key}.name"), &s.name)?;
            if let Some(j) = sensor_index.get(&s.name) {
                return Err(self.error(
                    &format!("{key}.name"),
                    format!(
                        "'{}' is already the name of sensor[{j}]: give every sensor its own \
                         name (it names the sensor's calibration file)",
                        s.name
                    ),
                ));
            }
            sensor_index.insert(s.name.clone(), i);
            let north = self.check_north(&key, s.declination_deg, s.location.clone(), today)?;
            let Some(&src) = source_index.get(&s.source) else {
                let names: Vec<&str> = sources.iter().map(|s| s.name.as_str()).collect();
                return Err(self.error(
                    &format!("{key}.source"),
                    if names.is_empty() {
                        format!(
                            "no source named '{}': the file has no [[source]]; add one",
                            s.source
                        )
                    } else {
                        format!(
                            "no source named '{}': the sources are {}",
                            s.source,
                            names.join(", ")
                        )
                    },
                ));
            };
            let (src_name, src_kind) = match sources.get(src) {
                Some(source) => (source.name.as_str(), source.kind.name()),
                None => ("", ""),
            };
            if let (Some(Some(layout)), Some(source)) = (layouts.get(src), sources.get(src)) {
                let location_given = s.location.is_some();
                let (mut sensor, tilt) = self.check_csv_sensor(&key, s, source, layout)?;
                // A 3-axis csv sensor names its field: true north is a
                // magnetometer's (a 2-axis one's columns carry no field).
                if north.is_some() && sensor.sphere().is_some() && sensor.field != Field::Mag {
                    return Err(self.north_not_magnetometer(&key, location_given, sensor.field));
                }
                sensor.north = north;
                if let Some(tilt) = tilt {
                    pending_tilts.push((i, tilt));
                }
                sensors.push(sensor);
                continue;
            }
            let stream_list = streams.get(src).map(Vec::as_slice).unwrap_or(&[]);
            let on = DeviceSource {
                name: src_name,
                kind: src_kind,
                streams: stream_list,
            };
            let (sensor, tilt) = self.check_device_sensor(&key, s, north, &daemon_north, on)?;
            if let Some(tilt) = tilt {
                pending_tilts.push((i, tilt));
            }
            sensors.push(sensor);
        }
        self.link_tilts(&mut sensors, &pending_tilts)?;
        tilt::link_gyros3(&mut sensors, checked);
        Ok(sensors)
    }

    /// A sensor of a device source (a serial IMU, an I2C bridge or a
    /// replayed capture): its stream, field and axes, then a 3-axis or a
    /// 2-axis sensor's own keys. `north` is the sensor's own; only a
    /// magnetometer may have one, and a magnetometer without one takes
    /// the daemon's.
    fn check_device_sensor(
        &self,
        key: &str,
        s: RawSensor,
        north: Option<North>,
        daemon_north: &Option<North>,
        on: DeviceSource<'_>,
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        let (src_name, src_kind, stream_list) = (on.name, on.kind, on.streams);
        {
            let Some(field) = s.field else {
                return Err(self.error(
                    &format!("{key}.field"),
                    format!(
                        "missing: give the quantity the sensor calibrates on source '{src_name}': \
                         \"mag\", \"accel\" or \"gyro\""
                    ),
                ));
            };
            let north = match north {
                Some(_) if field != Field::Mag => {
                    return Err(self.north_not_magnetometer(key, s.location.is_some(), field));
                }
                Some(n) => Some(n),
                None if field == Field::Mag => daemon_north.clone(),
                None => None,
            };
            if s.gyro_units.is_some() {
                return Err(self.error(
                    &format!("{key}.gyro_units"),
                    format!(
                        "a sensor of a {src_kind} source has no `gyro_units`: its gyro's scale \
                         is gyro_lsb_per_deg_s (gyro_units is for a csv source's gyro column)"
                    ),
                ));
            }
            let stream =
                self.resolve_stream(key, s.chip.as_deref(), src_name, src_kind, stream_list)?;
            let fields = stream.fields();
            if !fields.contains(&field) {
                let names: Vec<&str> = fields.iter().map(|f| f.name()).collect();
                return Err(self.error(
                    &format!("{key}.field"),
                    format!(
                        "'{}' is not measured by {} of source '{src_name}': it gives {}",
                        field.name(),
                        stream.describe(),
                        names.join(", ")
                    ),
                ));
            }
            let mut parsed = Vec::with_capacity(s.axes.len());
            for (k, name) in s.axes.iter().enumerate() {
                parsed.push(match name.trim() {
                    "x" => Axis::X,
                    "y" => Axis::Y,
                    "z" => Axis::Z,
                    other => {
                        return Err(self.error(
                            &format!("{key}.axes[{k}]"),
                            format!(
                                "\"{other}\" is not an axis: a sensor of a {src_kind} source \
                                 gives two different of \"x\", \"y\", \"z\" of its field \
                                 (column names are for sensors of a kind = \"csv\" source)"
                            ),
                        ));
                    }
                });
            }
            if parsed.len() == 3 {
                self.refuse_gyro_columns(key, &s, src_kind)?;
                let (mut sensor, tilt) =
                    self.check_sensor3(key, s, field, stream.id, &parsed, src_name)?;
                sensor.north = north;
                return Ok((sensor, tilt));
            }
            for (name, given) in [
                ("mag_axes", s.mag_axes.is_some()),
                ("lsb_per_gauss", s.lsb_per_gauss.is_some()),
                ("lsb_per_g", s.lsb_per_g.is_some()),
                ("sphere", s.sphere.is_some()),
            ] {
                if given {
                    return Err(self.error(
                        &format!("{key}.{name}"),
                        format!(
                            "`{name}` is for a 3-axis sensor: give axes = [\"x\", \"y\", \"z\"], \
                             or leave `{name}` out of this 2-axis sensor"
                        ),
                    ));
                }
            }
            let axes = match parsed.as_slice() {
                [a, b] if a == b => {
                    return Err(self.error(
                        &format!("{key}.axes"),
                        format!(
                            "both axes are \"{}\": give the two axes that turn, two different \
                             of \"x\", \"y\", \"z\"",
                            a.name()
                        ),
                    ));
                }
                [a, b] => [*a, *b],
                other => {
                    return Err(self.error(
                        &format!("{key}.axes"),
                        format!(
                            "{} axes given: give exactly two different of \"x\", \"y\", \"z\" \
                             (the two that turn), or all three for a 3-D calibration",
                            other.len()
                        ),
                    ));
                }
            };
            let effects = self.check_model(&format!("{key}.model"), s.model.as_ref())?;
            let gyro = self.check_gyro(key, &s, axes, stream, src_name, stream_list)?;
            let out_of_plane =
                self.check_axis_out_of_plane(key, s.out_of_plane.as_deref(), axes)?;
            let plane = PlaneSensor {
                stream: stream.id,
                field,
                axes,
                effects,
                gyro,
                columns: None,
                north,
                out_of_plane,
            };
            let tilt = s.tilt.clone();
            Ok((self.plane_sensor(key, s, plane)?, tilt))
        }
    }
}

/// The sources as checked, for the sensors' checks.
struct CheckedSources {
    sources: Vec<SourceConfig>,
    /// Each source's byte streams.
    streams: Vec<Vec<StreamDesc>>,
    /// The header of each csv source's files, resolved.
    layouts: Vec<Option<Vec<CsvLayout>>>,
    /// A source's index by its name.
    index: HashMap<String, usize>,
}

/// The device source a sensor reads: its name, kind and streams.
#[derive(Clone, Copy)]
struct DeviceSource<'a> {
    name: &'a str,
    kind: &'static str,
    streams: &'a [StreamDesc],
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_are_one_based() {
        let text = "a = 1\nbé = 2\n";
        assert_eq!(position_of(text, 0), Position { line: 1, column: 1 });
        let at = text.find("= 2").unwrap_or(0);
        assert_eq!(position_of(text, at), Position { line: 2, column: 4 });
        assert_eq!(position_of(text, 10_000).line, 3);
    }

    #[test]
    fn chip_fields_follow_the_drivers() {
        assert_eq!(chip_fields(Chip::Lsm303dlhcMag), vec![Field::Mag]);
        assert_eq!(chip_fields(Chip::Mpu6050), vec![Field::Accel, Field::Gyro]);
        assert_eq!(chip_fields(Chip::Adxl345), vec![Field::Accel]);
    }
}
