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
use crate::source::bridge::{BridgeConfig, I2cSpeed};
use crate::source::replay::Speed;

/// When a sensor's rotation counts as complete (`[sensor.rotation]`).
pub type RotationSettings = crate::daemon::rotation::RotationConfig;
/// The limits a fit must meet to be accepted (`[sensor.limits]`).
pub type LimitSettings = crate::daemon::acceptance::Limits;

/// Polls per second are bounded by what a USB-ISS can do; a minute between
/// polls is already useless for a turning sensor.
const POLL_MS_MAX: u64 = 60_000;
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
/// The effects the daemon can fit and apply to live readings: those that
/// depend on the reading alone (drift needs the time base and covariates a
/// logged column at correction time).
const LIVE_EFFECTS: [Effect; 6] = [
    Effect::Offset,
    Effect::Scale,
    Effect::CrossAxis,
    Effect::Cubic,
    Effect::CubicCentred,
    Effect::Outliers,
];

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
    pub stdout: bool,
    /// Loopback unless the file said `tcp_public = true`.
    pub tcp: Option<SocketAddr>,
    pub unix: Option<PathBuf>,
    /// The live page's HTTP listener; loopback unless the file said
    /// `http_public = true`.
    pub http: Option<SocketAddr>,
    /// Lines queued per subscriber.
    pub queue: usize,
    /// Subscribers at once; None: derived from the descriptor limit at start.
    pub max_subscribers: Option<usize>,
    /// The Unix socket's mode.
    pub unix_mode: u32,
    /// The Unix socket's group id, when set.
    pub unix_group: Option<u32>,
    /// Who may recalibrate (`recalibrate_from`, and the token of `token_file`).
    pub access: Access,
}

/// One `[[source]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceConfig {
    pub name: String,
    pub kind: SourceKind,
    /// Time between tries after a failure.
    pub retry: Duration,
}

/// What a source reads, with the settings of that kind.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceKind {
    /// A Falcon-GX-style IMU on a serial line: one stream (0).
    Falcon { port: PathBuf, baud: u32 },
    /// Chips behind a USB-ISS bridge, polled in this order: stream k is
    /// `chips[k]`.
    UsbIss {
        port: PathBuf,
        chips: Vec<(Chip, u8)>,
        poll: Duration,
        i2c_khz: u32,
    },
    /// A capture (or raw Falcon dump) played back.
    Replay { file: PathBuf, speed: Speed },
    /// A CSV recording played row by row (one stream, 0): the rows' times
    /// come from `time_column` (else the first of t, t_s, time, time_s) or,
    /// when the file has none, row k is at k * `period_s`. Several files
    /// recorded on one clock (`files`, each with its own header and time
    /// column) are played merged in time order; a source of one file
    /// (`file`) has one here.
    Csv {
        files: Vec<PathBuf>,
        speed: Speed,
        time_column: Option<String>,
        period_s: Option<f64>,
    },
}

impl SourceKind {
    /// How fast a replayed file plays (`replay` and `csv` sources).
    pub fn speed(&self) -> Option<Speed> {
        match self {
            SourceKind::Replay { speed, .. } | SourceKind::Csv { speed, .. } => Some(*speed),
            _ => None,
        }
    }
}

impl SourceConfig {
    /// The bridge settings of a `usb-iss` source, `None` for other kinds.
    pub fn bridge_config(&self) -> Option<BridgeConfig> {
        let SourceKind::UsbIss {
            port,
            chips,
            poll,
            i2c_khz,
        } = &self.kind
        else {
            return None;
        };
        let mut config = BridgeConfig::new(port.clone(), chips.clone());
        config.period = *poll;
        config.speed = if *i2c_khz == 400 {
            I2cSpeed::Khz400
        } else {
            I2cSpeed::Khz100
        };
        config.retry_interval = self.retry;
        Some(config)
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

/// One `[[sensor]]`: two axes of one field of one stream of a source.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorConfig {
    pub name: String,
    /// The name of its source (present in [`Config::sources`]).
    pub source: String,
    /// The stream of the source: the chip's place in a usb-iss `chips`
    /// list, the stream id of a replayed capture, 0 for a Falcon.
    pub stream: u8,
    pub field: Field,
    /// The raw x and y of the paper's model, in that order; different.
    pub axes: [Axis; 2],
    /// The model's effects, in catalogue order (the paper's: offset, scale).
    pub effects: Vec<String>,
    pub rotation: RotationSettings,
    pub limits: LimitSettings,
    /// Where the heading check of each rotation takes its gyro from.
    pub gyro: GyroChoice,
    /// A sensor of a csv source: the two columns that turn (the raw x and
    /// y, in that order); then `stream`, `field` and `axes` are unused
    /// (0, mag, x and y).
    pub columns: Option<[String; 2]>,
    /// A 3-axis sensor (`axes = ["x", "y", "z"]`): its model, units, tilt
    /// source and collection; then `axes` holds its first two axes, and
    /// `effects`, `gyro`, `rotation` and `limits` are unused.
    pub three: Option<crate::daemon::sensor3::Sensor3Config>,
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

fn located(path: &Path, position: &Option<Position>) -> String {
    match position {
        Some(p) => format!("{}:{p}", path.display()),
        None => path.display().to_string(),
    }
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

// ---------------------------------------------------------------------------
// The file as written: every key optional where it has a default, unknown
// keys refused (naming the key and the allowed ones).

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    #[serde(default)]
    daemon: RawDaemon,
    #[serde(default)]
    outputs: RawOutputs,
    #[serde(default)]
    source: Vec<RawSource>,
    #[serde(default)]
    sensor: Vec<RawSensor>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawDaemon {
    state_dir: Option<PathBuf>,
    status_interval_s: Option<f64>,
    log_format: LogFormat,
    /// The default true north of every magnetometer of a device source.
    declination_deg: Option<f64>,
    location: Option<LocationKeys>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct RawOutputs {
    stdout: Option<bool>,
    tcp: Option<String>,
    tcp_public: bool,
    unix: Option<PathBuf>,
    http: Option<String>,
    http_public: bool,
    queue: Option<u64>,
    max_subscribers: Option<u64>,
    unix_mode: Option<String>,
    unix_group: Option<toml::Value>,
    recalibrate_from: Option<Vec<String>>,
    token_file: Option<PathBuf>,
}

#[derive(Deserialize, Clone, Copy, PartialEq)]
#[serde(rename_all = "kebab-case")]
enum RawKind {
    Falcon,
    UsbIss,
    Replay,
    Csv,
}

impl RawKind {
    fn name(self) -> &'static str {
        match self {
            RawKind::Falcon => "falcon",
            RawKind::UsbIss => "usb-iss",
            RawKind::Replay => "replay",
            RawKind::Csv => "csv",
        }
    }

    /// The keys a source of this kind takes, besides name, kind, retry_s.
    fn keys(self) -> &'static [&'static str] {
        match self {
            RawKind::Falcon => &["port", "baud"],
            RawKind::UsbIss => &["port", "chips", "poll_ms", "i2c_khz"],
            RawKind::Replay => &["file", "speed"],
            RawKind::Csv => &["file", "files", "speed", "time_column", "period_s"],
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSource {
    name: String,
    kind: RawKind,
    port: Option<PathBuf>,
    baud: Option<u32>,
    chips: Option<Vec<String>>,
    poll_ms: Option<u64>,
    i2c_khz: Option<u32>,
    file: Option<PathBuf>,
    files: Option<Vec<PathBuf>>,
    speed: Option<toml::Value>,
    time_column: Option<String>,
    period_s: Option<f64>,
    retry_s: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSensor {
    name: String,
    source: String,
    chip: Option<String>,
    field: Option<Field>,
    /// Axes ("x", "y", "z") of a device's sensor, columns of a csv source's.
    axes: Vec<String>,
    model: Option<toml::Value>,
    gyro: Option<String>,
    gyro_chip: Option<String>,
    gyro_lsb_per_deg_s: Option<f64>,
    gyro_units: Option<String>,
    #[serde(default)]
    rotation: RotationSettings,
    #[serde(default)]
    limits: LimitSettings,
    /// A 3-axis sensor: the accelerometer sensor of the same source whose
    /// readings tilt-compensate its heading.
    tilt: Option<String>,
    /// A 3-axis magnetometer's counts per gauss.
    lsb_per_gauss: Option<f64>,
    /// A 3-axis accelerometer's counts per g.
    lsb_per_g: Option<f64>,
    /// A 3-axis sensor's collection and rms limit.
    sphere: Option<crate::daemon::sensor3::SphereSettings>,
    /// A magnetometer's true north: a declination, or a place for the WMM.
    declination_deg: Option<f64>,
    location: Option<LocationKeys>,
}

/// One byte stream of a source: its id and, for a chip, which one.
#[derive(Debug, Clone, Copy)]
struct StreamDesc {
    id: u8,
    /// `None` for a Falcon-GX stream.
    chip: Option<(Chip, u8)>,
}

impl StreamDesc {
    fn fields(self) -> Vec<Field> {
        match self.chip {
            None => vec![Field::Mag, Field::Accel, Field::Gyro],
            Some((chip, _)) => chip_fields(chip),
        }
    }

    fn describe(self) -> String {
        match self.chip {
            None => "a Falcon-GX stream".into(),
            Some((chip, address)) => format!("{}@0x{address:02x}", chip.name()),
        }
    }
}

/// The fields a chip reports: decoding a poll of zeros shows which it
/// fills, so this cannot drift from the chip drivers.
fn chip_fields(chip: Chip) -> Vec<Field> {
    let Ok(reading) = chip.decode(&vec![0; chip.data_len()], 0.0) else {
        return Vec::new();
    };
    let mut fields = Vec::new();
    if reading.mag.is_some() {
        fields.push(Field::Mag);
    }
    if reading.accel.is_some() {
        fields.push(Field::Accel);
    }
    if reading.gyro.is_some() {
        fields.push(Field::Gyro);
    }
    fields
}

// ---------------------------------------------------------------------------
// Checking, with positions looked up in the spanned document.

struct Checker<'a> {
    text: &'a str,
    path: &'a Path,
    doc: &'a Spanned<DeTable<'a>>,
    base: PathBuf,
}

impl Checker<'_> {
    fn error(&self, key: &str, problem: impl Into<String>) -> ConfigError {
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

    /// The span of the value at a dotted key such as `sensor[1].axes`, or
    /// of the nearest enclosing one that is in the file.
    fn span_of(&self, key: &str) -> Option<Range<usize>> {
        let mut best: Option<Range<usize>> = None;
        let mut table: &DeTable = self.doc.get_ref();
        let mut value: Option<&Spanned<DeValue>> = None;
        for part in key.split('.').filter(|p| !p.is_empty()) {
            let (name, index) = match part.split_once('[') {
                Some((name, rest)) => (name, rest.trim_end_matches(']').parse::<usize>().ok()),
                None => (part, None),
            };
            if let Some(v) = value {
                match v.get_ref() {
                    DeValue::Table(t) => table = t,
                    _ => return best,
                }
            }
            let Some(v) = table.get(name) else {
                return best;
            };
            best = Some(v.span());
            value = Some(v);
            if let Some(i) = index {
                let DeValue::Array(items) = v.get_ref() else {
                    return best;
                };
                let Some(item) = items.get(i) else {
                    return best;
                };
                best = Some(item.span());
                value = Some(item);
            }
        }
        best
    }

    fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.base.join(path)
        }
    }

    fn check(&self, mut raw: RawConfig) -> Result<Config, ConfigError> {
        let today = crate::geomag::CivilDate::today();
        let daemon_north = self.check_north(
            "daemon",
            raw.daemon.declination_deg,
            raw.daemon.location.take(),
            today,
        )?;
        let daemon = self.check_daemon(raw.daemon)?;
        let outputs = self.check_outputs(raw.outputs)?;

        let mut sources = Vec::with_capacity(raw.source.len());
        let mut streams: Vec<Vec<StreamDesc>> = Vec::with_capacity(raw.source.len());
        // The header of each csv source's file, resolved.
        let mut layouts: Vec<Option<Vec<CsvLayout>>> = Vec::with_capacity(raw.source.len());
        let mut source_index: HashMap<String, usize> = HashMap::new();
        for (i, s) in raw.source.into_iter().enumerate() {
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
            let (source, desc, layout) = self.check_source(&key, s)?;
            sources.push(source);
            streams.push(desc);
            layouts.push(layout);
        }

        if raw.sensor.is_empty() {
            return Err(self.error(
                "sensor",
                "no [[sensor]] in the file: `fieldcal run` needs at least one sensor to \
                 calibrate (name, source, field, axes)",
            ));
        }
        let mut sensors = Vec::with_capacity(raw.sensor.len());
        let mut sensor_index: HashMap<String, usize> = HashMap::new();
        let mut pending_tilts: Vec<(usize, String)> = Vec::new();
        for (i, s) in raw.sensor.into_iter().enumerate() {
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
                Some(source) => (source.name.as_str(), kind_name(&source.kind)),
                None => ("", ""),
            };
            if let (Some(Some(layout)), Some(source)) = (layouts.get(src), sources.get(src)) {
                let location_given = s.location.is_some();
                let (mut sensor, tilt) = self.check_csv_sensor(&key, s, source, layout)?;
                // A 3-axis csv sensor names its field: true north is a
                // magnetometer's (a 2-axis one's columns carry no field).
                if north.is_some() && sensor.three.is_some() && sensor.field != Field::Mag {
                    return Err(self.north_not_magnetometer(&key, location_given, sensor.field));
                }
                sensor.north = north;
                if let Some(tilt) = tilt {
                    pending_tilts.push((i, tilt));
                }
                sensors.push(sensor);
                continue;
            }
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
                    return Err(self.north_not_magnetometer(&key, s.location.is_some(), field));
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
            let stream_list = streams.get(src).map(Vec::as_slice).unwrap_or(&[]);
            let stream =
                self.resolve_stream(&key, s.chip.as_deref(), src_name, src_kind, stream_list)?;
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
                let (mut sensor, tilt) =
                    self.check_sensor3(&key, s, field, stream.id, &parsed, src_name)?;
                if let Some(tilt) = tilt {
                    pending_tilts.push((i, tilt));
                }
                sensor.north = north;
                sensors.push(sensor);
                continue;
            }
            for (name, given) in [
                ("tilt", s.tilt.is_some()),
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
            let gyro = self.check_gyro(&key, &s, axes, stream, src_name, stream_list)?;
            if let Err(problem) = s.rotation.validate() {
                return Err(self.error(&format!("{key}.rotation"), problem));
            }
            if let Err(problem) = s.limits.validate() {
                return Err(self.error(&format!("{key}.limits"), problem));
            }
            sensors.push(SensorConfig {
                name: s.name,
                source: s.source,
                stream: stream.id,
                field,
                axes,
                effects,
                rotation: s.rotation,
                limits: s.limits,
                gyro,
                columns: None,
                three: None,
                north,
            });
        }
        self.link_tilts(&mut sensors, &pending_tilts)?;

        Ok(Config {
            daemon,
            outputs,
            sources,
            sensors,
            path: self.path.to_path_buf(),
        })
    }

    /// `declination_deg` or `location` of a sensor or of `[daemon]`
    /// (`key` is `sensor[N]` or `daemon`): the true north it gives, if any.
    fn check_north(
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

    fn check_daemon(&self, raw: RawDaemon) -> Result<DaemonConfig, ConfigError> {
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

    fn check_outputs(&self, raw: RawOutputs) -> Result<OutputsConfig, ConfigError> {
        let tcp = self.listen_address("tcp", raw.tcp, raw.tcp_public, 2948)?;
        let http = self.listen_address("http", raw.http, raw.http_public, 8080)?;
        let unix = match raw.unix {
            Some(p) if p.as_os_str().is_empty() => {
                return Err(self.error(
                    "outputs.unix",
                    "empty: give a socket path, or leave the key out",
                ));
            }
            Some(p) => Some(self.resolve(&p)),
            None => None,
        };
        let queue = match raw.queue {
            None => 4096,
            Some(q) if (1..=1_000_000).contains(&q) => usize::try_from(q).unwrap_or(4096),
            Some(q) => {
                return Err(self.error(
                    "outputs.queue",
                    format!("{q} lines: give 1 to 1000000 lines per subscriber"),
                ));
            }
        };
        let max_subscribers = match raw.max_subscribers {
            None => None,
            Some(n) if (1..=MAX_SUBSCRIBERS_LIMIT).contains(&n) => usize::try_from(n).ok(),
            Some(n) => {
                return Err(self.error(
                    "outputs.max_subscribers",
                    format!(
                        "{n}: give 1 to {MAX_SUBSCRIBERS_LIMIT} subscribers, or leave the key out \
                         for the default (64, fewer under a low descriptor limit)"
                    ),
                ));
            }
        };
        let unix_mode = match raw.unix_mode {
            None => super::publish::unix::SOCKET_MODE,
            Some(text) => self.unix_mode(&text)?,
        };
        let unix_group = match raw.unix_group {
            None => None,
            Some(value) => Some(self.unix_group(&value)?),
        };
        let recalibrate_from = match raw.recalibrate_from {
            None => Access::default().recalibrate_from,
            Some(list) => {
                let mut from = Vec::new();
                for name in list {
                    let Some(origin) = Origin::ALL.into_iter().find(|o| o.name() == name) else {
                        return Err(self.error(
                            "outputs.recalibrate_from",
                            format!(
                                "'{name}' is not a listener: give a list of \"unix\", \"tcp\", \"http\" \
                                 (or [] to refuse recalibrate without the token)"
                            ),
                        ));
                    };
                    if !from.contains(&origin) {
                        from.push(origin);
                    }
                }
                from
            }
        };
        let token = match raw.token_file {
            None => None,
            Some(path) => Some(self.token_file(&self.resolve(&path))?),
        };
        Ok(OutputsConfig {
            stdout: raw.stdout.unwrap_or(true),
            tcp,
            unix,
            http,
            queue,
            max_subscribers,
            unix_mode,
            unix_group,
            access: Access {
                recalibrate_from,
                token,
            },
        })
    }

    /// `outputs.unix_mode`: octal permission bits, at most 0777.
    fn unix_mode(&self, text: &str) -> Result<u32, ConfigError> {
        let digits = text.trim();
        let digits = digits.strip_prefix("0o").unwrap_or(digits);
        match u32::from_str_radix(digits, 8) {
            Ok(mode) if !digits.is_empty() && mode <= 0o777 && !digits.starts_with('+') => Ok(mode),
            _ => Err(self.error(
                "outputs.unix_mode",
                format!(
                    "'{text}' is not a file mode: give octal permission bits from \"0000\" to \
                     \"0777\", such as \"0660\" (owner and group may connect)"
                ),
            )),
        }
    }

    /// `outputs.unix_group`: a group name or number, which must exist.
    fn unix_group(&self, value: &toml::Value) -> Result<u32, ConfigError> {
        let key = "outputs.unix_group";
        let name = match value {
            toml::Value::Integer(n) => {
                return u32::try_from(*n).map_err(|_| {
                    self.error(
                        key,
                        format!("{n} is not a group id: give 0 to {}", u32::MAX),
                    )
                });
            }
            toml::Value::String(s) => s.trim(),
            other => {
                return Err(self.error(
                    key,
                    format!(
                        "a {} is not a group: give a group name (\"fieldcal\") or number",
                        type_name(other)
                    ),
                ));
            }
        };
        if let Ok(gid) = name.parse::<u32>() {
            return Ok(gid);
        }
        match group_id(name) {
            Some(gid) => Ok(gid),
            None => Err(self.error(
                key,
                format!(
                    "no group named '{name}' on this system (see /etc/group, getent group): \
                     create it, or give an existing group's name or number"
                ),
            )),
        }
    }

    /// Reads the token of `outputs.token_file`: a regular file that others
    /// cannot read and its group cannot write (as ssh refuses a key others
    /// can read), whose trimmed content is the token.
    fn token_file(&self, path: &Path) -> Result<Token, ConfigError> {
        use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
        let key = "outputs.token_file";
        let shown = path.display();
        let meta = std::fs::metadata(path)
            .map_err(|e| self.error(key, format!("cannot read {shown}: {e}")))?;
        if !meta.is_file() {
            return Err(self.error(
                key,
                format!("{shown} is not a regular file: give a file holding the token"),
            ));
        }
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o027 != 0 {
            return Err(self.error(
                key,
                format!(
                    "{shown} has mode {mode:04o}: a token others can read, or its group can \
                     change, is no secret; chmod 600 (or 640) it"
                ),
            ));
        }
        let mut text = String::new();
        std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(path)
            .and_then(|f| f.take(MAX_TOKEN_FILE_BYTES + 1).read_to_string(&mut text))
            .map_err(|e| self.error(key, format!("cannot read {shown}: {e}")))?;
        if text.len() as u64 > MAX_TOKEN_FILE_BYTES {
            return Err(self.error(
                key,
                format!(
                    "{shown} is longer than {MAX_TOKEN_FILE_BYTES} bytes: a token is one short line"
                ),
            ));
        }
        Token::new(&text).ok_or_else(|| {
            self.error(
                key,
                format!(
                    "{shown} is empty: put the token in it (for example: openssl rand -hex 32)"
                ),
            )
        })
    }

    /// `outputs.KEY` as a socket address, refused when it is not loopback
    /// unless `outputs.KEY_public = true` (neither listener authenticates).
    fn listen_address(
        &self,
        key: &str,
        text: Option<String>,
        public: bool,
        example_port: u16,
    ) -> Result<Option<SocketAddr>, ConfigError> {
        let Some(text) = text else {
            return Ok(None);
        };
        let addr: SocketAddr = text.trim().parse().map_err(|_| {
            self.error(
                &format!("outputs.{key}"),
                format!(
                    "'{text}' is not a socket address: give IP:PORT, such as \
                     \"127.0.0.1:{example_port}\" or \"[::1]:{example_port}\" (host names are not resolved)"
                ),
            )
        })?;
        if !addr.ip().is_loopback() && !public {
            let what = if key == "http" {
                "other machines could open the live page and start a recalibration"
            } else {
                "other machines could read the readings"
            };
            return Err(self.error(
                &format!("outputs.{key}"),
                format!(
                    "{addr} is not a loopback address, so {what} (there is no authentication): \
                     use 127.0.0.1 or ::1, or set outputs.{key}_public = true to allow it"
                ),
            ));
        }
        Ok(Some(addr))
    }

    #[allow(clippy::type_complexity)]
    fn check_source(
        &self,
        key: &str,
        s: RawSource,
    ) -> Result<(SourceConfig, Vec<StreamDesc>, Option<Vec<CsvLayout>>), ConfigError> {
        let kind = s.kind;
        let present = [
            ("port", s.port.is_some()),
            ("baud", s.baud.is_some()),
            ("chips", s.chips.is_some()),
            ("poll_ms", s.poll_ms.is_some()),
            ("i2c_khz", s.i2c_khz.is_some()),
            ("file", s.file.is_some()),
            ("files", s.files.is_some()),
            ("speed", s.speed.is_some()),
            ("time_column", s.time_column.is_some()),
            ("period_s", s.period_s.is_some()),
        ];
        if let Some((name, _)) = present
            .iter()
            .find(|(name, given)| *given && !kind.keys().contains(name))
        {
            return Err(self.error(
                &format!("{key}.{name}"),
                format!(
                    "a {} source has no `{name}`: its keys are name, kind, {}, retry_s",
                    kind.name(),
                    kind.keys().join(", ")
                ),
            ));
        }
        let retry = match s.retry_s {
            None => Duration::from_secs(2),
            Some(v) => self.seconds_in(&format!("{key}.retry_s"), v, MIN_RETRY_S, 3600.0)?,
        };
        let require_port = |port: Option<PathBuf>| match port {
            Some(p) if !p.as_os_str().is_empty() => Ok(p),
            _ => Err(self.error(
                &format!("{key}.port"),
                format!(
                    "a {} source needs `port`, its serial device (such as \"{}\")",
                    kind.name(),
                    if kind == RawKind::Falcon {
                        "/dev/ttyUSB0"
                    } else {
                        "/dev/ttyACM0"
                    }
                ),
            )),
        };
        let mut layout = None;
        let (source_kind, streams) = match kind {
            RawKind::Falcon => {
                let port = require_port(s.port)?;
                let baud = s.baud.unwrap_or(falcon::BAUD);
                if baud == 0 {
                    return Err(self.error(
                        &format!("{key}.baud"),
                        format!(
                            "0 is not a line speed: give the device's, such as {}",
                            falcon::BAUD
                        ),
                    ));
                }
                (
                    SourceKind::Falcon { port, baud },
                    vec![StreamDesc { id: 0, chip: None }],
                )
            }
            RawKind::UsbIss => {
                let port = require_port(s.port)?;
                let chips = self.check_chips(key, s.chips.unwrap_or_default())?;
                let poll_ms = s.poll_ms.unwrap_or(30);
                if !(1..=POLL_MS_MAX).contains(&poll_ms) {
                    return Err(self.error(
                        &format!("{key}.poll_ms"),
                        format!("{poll_ms} ms: give 1 to {POLL_MS_MAX} ms between polls"),
                    ));
                }
                let i2c_khz = s.i2c_khz.unwrap_or(100);
                if i2c_khz != 100 && i2c_khz != 400 {
                    return Err(self.error(
                        &format!("{key}.i2c_khz"),
                        format!("{i2c_khz} kHz: the USB-ISS runs the bus at 100 or 400 kHz"),
                    ));
                }
                let streams = chips
                    .iter()
                    .enumerate()
                    .map(|(k, &chip)| StreamDesc {
                        id: u8::try_from(k).unwrap_or(u8::MAX),
                        chip: Some(chip),
                    })
                    .collect();
                (
                    SourceKind::UsbIss {
                        port,
                        chips,
                        poll: Duration::from_millis(poll_ms),
                        i2c_khz,
                    },
                    streams,
                )
            }
            RawKind::Replay => {
                let Some(file) = s.file.filter(|f| !f.as_os_str().is_empty()) else {
                    return Err(self.error(
                        &format!("{key}.file"),
                        "a replay source needs `file`, a capture or raw dump (relative to the \
                         configuration's directory)",
                    ));
                };
                let file = self.resolve(&file);
                let streams = self.replay_streams(&format!("{key}.file"), &file)?;
                let speed = self.check_speed(&format!("{key}.speed"), s.speed.as_ref())?;
                (SourceKind::Replay { file, speed }, streams)
            }
            RawKind::Csv => {
                let (files, listed) = self.csv_files(key, s.file, s.files)?;
                let speed = self.check_speed(&format!("{key}.speed"), s.speed.as_ref())?;
                let period_s = match s.period_s {
                    None => None,
                    Some(_) if files.len() > 1 => {
                        return Err(self.error(
                            &format!("{key}.period_s"),
                            "`period_s` is for a single file without a time column: the files of \
                             one clock are merged by their time columns, so each needs one \
                             (name it with time_column)",
                        ));
                    }
                    Some(p) => {
                        self.seconds(&format!("{key}.period_s"), p, 86_400.0)?;
                        Some(p)
                    }
                };
                let time_column = s.time_column.map(|t| t.trim().to_string());
                let mut found = Vec::with_capacity(files.len());
                for (k, file) in files.iter().enumerate() {
                    let on = if listed {
                        format!("{key}.files[{k}]")
                    } else {
                        format!("{key}.file")
                    };
                    found.push(self.csv_layout(
                        key,
                        &on,
                        file,
                        time_column.as_deref(),
                        period_s,
                    )?);
                }
                layout = Some(found);
                (
                    SourceKind::Csv {
                        files,
                        speed,
                        time_column,
                        period_s,
                    },
                    vec![StreamDesc { id: 0, chip: None }],
                )
            }
        };
        Ok((
            SourceConfig {
                name: s.name,
                kind: source_kind,
                retry,
            },
            streams,
            layout,
        ))
    }

    /// A csv source's `file` or `files` (one of the two; at most
    /// [`crate::source::csv::MAX_FILES`], each once), resolved against the
    /// configuration's directory.
    fn csv_files(
        &self,
        key: &str,
        file: Option<PathBuf>,
        files: Option<Vec<PathBuf>>,
    ) -> Result<(Vec<PathBuf>, bool), ConfigError> {
        use crate::source::csv::MAX_FILES;
        let list = match (file, files) {
            (Some(_), Some(_)) => {
                return Err(self.error(
                    &format!("{key}.files"),
                    "both `file` and `files` given: give `file` for one recording, or `files` \
                     for several recorded on one clock, not both",
                ));
            }
            (None, None) => {
                return Err(self.error(
                    &format!("{key}.file"),
                    "a csv source needs `file`, a CSV recording with a header line \
                     (relative to the configuration's directory), or `files`, several recorded \
                     on one clock",
                ));
            }
            (Some(file), None) => {
                if file.as_os_str().is_empty() {
                    return Err(self.error(
                        &format!("{key}.file"),
                        "a csv source needs `file`, a CSV recording with a header line \
                         (relative to the configuration's directory)",
                    ));
                }
                return Ok((vec![self.resolve(&file)], false));
            }
            (None, Some(files)) => files,
        };
        if list.is_empty() || list.len() > MAX_FILES {
            return Err(self.error(
                &format!("{key}.files"),
                format!(
                    "{} files: give 1 to {MAX_FILES} CSV recordings made on one clock",
                    list.len()
                ),
            ));
        }
        let mut resolved: Vec<PathBuf> = Vec::with_capacity(list.len());
        for (k, f) in list.iter().enumerate() {
            if f.as_os_str().is_empty() {
                return Err(self.error(
                    &format!("{key}.files[{k}]"),
                    "an empty path: give a CSV recording (relative to the configuration's \
                     directory)",
                ));
            }
            let path = self.resolve(f);
            if let Some(j) = resolved.iter().position(|p| *p == path) {
                return Err(self.error(
                    &format!("{key}.files[{k}]"),
                    format!(
                        "{} is already files[{j}]: give each file once",
                        path.display()
                    ),
                ));
            }
            resolved.push(path);
        }
        Ok((resolved, true))
    }

    /// The header of a csv source's file, resolved: the error, if any, is
    /// put on the key it is about (`on_file`, the file's own key
    /// `source[N].file` or `source[N].files[K]`, or `time_column` or
    /// `period_s`).
    fn csv_layout(
        &self,
        key: &str,
        on_file: &str,
        file: &Path,
        time_column: Option<&str>,
        period_s: Option<f64>,
    ) -> Result<CsvLayout, ConfigError> {
        use crate::io::csv::CsvError;
        match open_rows(file, time_column, period_s, &[]) {
            Ok(rows) => Ok(rows.layout().clone()),
            Err(e) => {
                let on = match &e {
                    CsvError::TimeAndPeriod { .. } => "period_s",
                    CsvError::NoTime { .. } if time_column.is_none() => "period_s",
                    CsvError::MissingColumn { .. } => "time_column",
                    _ => "",
                };
                let hint = match &e {
                    CsvError::Io { .. } => {
                        format!(" (relative paths are relative to {})", self.base.display())
                    }
                    _ => String::new(),
                };
                let on = if on.is_empty() {
                    on_file.to_string()
                } else {
                    format!("{key}.{on}")
                };
                Err(self.error(&on, format!("{e}{hint}")))
            }
        }
    }

    /// A sensor of a csv source: two columns of its file (or of one of its
    /// files), and optionally a gyro column; or three columns and a `field`,
    /// a 3-axis sensor. The keys of a device's sensor are refused by name.
    /// Returns the sensor and the name its `tilt` gives.
    fn check_csv_sensor(
        &self,
        key: &str,
        s: RawSensor,
        source: &SourceConfig,
        layouts: &[CsvLayout],
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        let paths: &[PathBuf] = match &source.kind {
            SourceKind::Csv { files, .. } => files,
            _ => &[],
        };
        let file = paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(" or ");
        let src = &source.name;
        // Where a column is: (file index, name); errors name the key `k`.
        let column = |k: String, name: &str, what: &str| -> Result<(usize, String), ConfigError> {
            let name = name.trim();
            let mut hit: Option<usize> = None;
            for (f, layout) in layouts.iter().enumerate() {
                let Some(i) = layout.index(name) else {
                    continue;
                };
                let this = paths
                    .get(f)
                    .map(|p| p.display().to_string())
                    .unwrap_or_default();
                if Some(i) == layout.time_index() {
                    return Err(self.error(
                        &k,
                        format!("'{name}' is the time column of {this}: give a column of {what}"),
                    ));
                }
                if let Some(first) = hit {
                    let that = paths
                        .get(first)
                        .map(|p| p.display().to_string())
                        .unwrap_or_default();
                    return Err(self.error(
                        &k,
                        format!(
                            "'{name}' is a column of both {that} and {this}: the files of one \
                             source must not share a column a sensor reads (rename it in one of \
                             them)"
                        ),
                    ));
                }
                hit = Some(f);
            }
            if let Some(f) = hit {
                return Ok((f, name.to_string()));
            }
            let device = matches!(name, "x" | "y" | "z")
                .then_some(
                    " (a csv source's sensors name columns of the file, not the x, y, z \
                     of a device)",
                )
                .unwrap_or_default();
            Err(self.error(
                &k,
                match layouts {
                    [layout] => format!(
                        "{file}:{}: no column '{name}' in the header (columns: {}): give a \
                         column of {what}{device}",
                        layout.header_line,
                        layout.available()
                    ),
                    _ => format!(
                        "no column '{name}' in the headers of {file} (columns: {}): give a \
                         column of {what}{device}",
                        layouts
                            .iter()
                            .zip(paths)
                            .map(|(l, p)| format!("{} in {}", l.available(), p.display()))
                            .collect::<Vec<_>>()
                            .join("; ")
                    ),
                },
            ))
        };
        // Every column of one sensor from one file: `found[0]`'s.
        let one_file = |found: &[(usize, String)], keys: &[String]| -> Result<usize, ConfigError> {
            let first = found.first().map_or(0, |f| f.0);
            for ((f, name), k) in found.iter().zip(keys) {
                if *f != first {
                    let of = |f: usize| {
                        paths
                            .get(f)
                            .map(|p| p.display().to_string())
                            .unwrap_or_default()
                    };
                    return Err(self.error(
                        k,
                        format!(
                            "'{name}' is a column of {}, but '{}' is of {}: a row carries only \
                             its own file's columns, so a sensor's columns must all come from \
                             one file",
                            of(*f),
                            found[0].1,
                            of(first)
                        ),
                    ));
                }
            }
            Ok(first)
        };
        if s.axes.len() == 3 {
            return self.check_csv_sensor3(key, s, &file, column, one_file);
        }
        for (name, given) in [
            ("field", s.field.is_some()),
            ("chip", s.chip.is_some()),
            ("tilt", s.tilt.is_some()),
            ("lsb_per_gauss", s.lsb_per_gauss.is_some()),
            ("lsb_per_g", s.lsb_per_g.is_some()),
            ("sphere", s.sphere.is_some()),
            ("gyro_chip", s.gyro_chip.is_some()),
            ("gyro_lsb_per_deg_s", s.gyro_lsb_per_deg_s.is_some()),
        ] {
            if given {
                return Err(self.error(
                    &format!("{key}.{name}"),
                    format!(
                        "a sensor of csv source '{src}' has no `{name}`: it names two columns \
                         of {file} in axes (and a gyro column in gyro, with gyro_units){}",
                        if matches!(
                            name,
                            "field" | "tilt" | "lsb_per_gauss" | "lsb_per_g" | "sphere"
                        ) {
                            "; a 3-axis sensor names three columns in axes, with field"
                        } else {
                            ""
                        }
                    ),
                ));
            }
        }
        let columns = match s.axes.as_slice() {
            [a, b] if a.trim() == b.trim() => {
                return Err(self.error(
                    &format!("{key}.axes"),
                    format!(
                        "both axes are \"{}\": give the two columns that turn, two different \
                         columns of {file}",
                        a.trim()
                    ),
                ));
            }
            [a, b] => {
                let keys = [format!("{key}.axes[0]"), format!("{key}.axes[1]")];
                let found = [
                    column(keys[0].clone(), a, "the axes that turn")?,
                    column(keys[1].clone(), b, "the axes that turn")?,
                ];
                one_file(&found, &keys)?;
                found
            }
            other => {
                return Err(self.error(
                    &format!("{key}.axes"),
                    format!(
                        "{} columns given: give exactly two different columns of {file} (the \
                         two axes that turn), or three with field = \"mag\" or \"accel\" for a \
                         3-axis sensor",
                        other.len()
                    ),
                ));
            }
        };
        let file_of_axes = columns[0].0;
        let columns = [columns[0].1.clone(), columns[1].1.clone()];
        let units_key = format!("{key}.gyro_units");
        let units = match s.gyro_units.as_deref().map(str::trim) {
            None | Some("deg/s") => GyroUnits::DegPerSecond,
            Some("rad/s") => GyroUnits::RadPerSecond,
            Some(other) => {
                return Err(self.error(
                    &units_key,
                    format!(
                        "\"{other}\" is not a unit of angular rate: give \"deg/s\" or \"rad/s\""
                    ),
                ));
            }
        };
        let gyro = match s.gyro.as_deref().map(str::trim) {
            None | Some("none") if s.gyro_units.is_some() => {
                return Err(self.error(
                    &units_key,
                    "given without a gyro column: name it with gyro = \"COLUMN\", or leave \
                     gyro_units out",
                ));
            }
            None => GyroChoice::Off(format!(
                "no heading check: name a gyro column of {file} with gyro = \"COLUMN\""
            )),
            Some("none") => {
                GyroChoice::Off("no heading check: gyro = \"none\" in the configuration".into())
            }
            Some(name) => {
                let gyro_key = format!("{key}.gyro");
                let (gyro_file, name) = column(
                    gyro_key.clone(),
                    name,
                    "the angular rate about the turn's axis",
                )?;
                if gyro_file != file_of_axes {
                    let of = |f: usize| {
                        paths
                            .get(f)
                            .map(|p| p.display().to_string())
                            .unwrap_or_default()
                    };
                    return Err(self.error(
                        &gyro_key,
                        format!(
                            "'{name}' is a column of {}, but the axes are of {}: a row carries \
                             only its own file's columns, so the gyro must be in the axes' file",
                            of(gyro_file),
                            of(file_of_axes)
                        ),
                    ));
                }
                if columns.contains(&name) {
                    return Err(self.error(
                        &gyro_key,
                        format!(
                            "'{name}' is one of the two axes that turn: give the gyro column of \
                             the turn's axis, or \"none\""
                        ),
                    ));
                }
                GyroChoice::Column { name, units }
            }
        };
        let effects = self.check_model(&format!("{key}.model"), s.model.as_ref())?;
        if let Err(problem) = s.rotation.validate() {
            return Err(self.error(&format!("{key}.rotation"), problem));
        }
        if let Err(problem) = s.limits.validate() {
            return Err(self.error(&format!("{key}.limits"), problem));
        }
        Ok((
            SensorConfig {
                name: s.name,
                source: s.source,
                stream: 0,
                field: Field::Mag,
                axes: [Axis::X, Axis::Y],
                effects,
                rotation: s.rotation,
                limits: s.limits,
                gyro,
                columns: Some(columns),
                three: None,
                north: None,
            },
            None,
        ))
    }

    /// A 3-axis sensor of a csv source: three different columns of one of
    /// its files (the sensor's x, y, z), the `field` they measure (columns
    /// carry none), and the 3-axis keys of a device's sensor.
    fn check_csv_sensor3(
        &self,
        key: &str,
        s: RawSensor,
        file: &str,
        column: impl Fn(String, &str, &str) -> Result<(usize, String), ConfigError>,
        one_file: impl Fn(&[(usize, String)], &[String]) -> Result<usize, ConfigError>,
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        for (name, given) in [
            ("chip", s.chip.is_some()),
            ("gyro_units", s.gyro_units.is_some()),
        ] {
            if given {
                return Err(self.error(
                    &format!("{key}.{name}"),
                    format!(
                        "a 3-axis sensor of csv source '{}' has no `{name}`: it names three \
                         columns of {file} in axes, with field = \"mag\" or \"accel\"",
                        s.source
                    ),
                ));
            }
        }
        let Some(field) = s.field else {
            return Err(self.error(
                &format!("{key}.field"),
                "missing: three columns carry no field, so a 3-axis sensor of a csv source \
                 needs field = \"mag\" (a magnetometer) or \"accel\" (an accelerometer)",
            ));
        };
        let names: Vec<&str> = s.axes.iter().map(|a| a.trim()).collect();
        for j in 1..names.len() {
            if let Some(i) = names[..j].iter().position(|n| *n == names[j]) {
                return Err(self.error(
                    &format!("{key}.axes[{j}]"),
                    format!(
                        "'{}' is already axes[{i}]: give three different columns of {file}, the \
                         sensor's x, y, z in that order",
                        names[j]
                    ),
                ));
            }
        }
        let what = match field {
            Field::Accel => "the sensor's acceleration (x, y, z)",
            _ => "the sensor's field (x, y, z)",
        };
        let keys: Vec<String> = (0..3).map(|k| format!("{key}.axes[{k}]")).collect();
        let mut found = Vec::with_capacity(3);
        for (k, name) in keys.iter().zip(&names) {
            found.push(column(k.clone(), name, what)?);
        }
        one_file(&found, &keys)?;
        let columns = [found[0].1.clone(), found[1].1.clone(), found[2].1.clone()];
        let (mut sensor, tilt) =
            self.check_sensor3(key, s, field, 0, &[Axis::X, Axis::Y, Axis::Z], "")?;
        if let Some(three) = sensor.three.as_mut() {
            three.columns = Some(columns);
        }
        Ok((sensor, tilt))
    }

    fn check_chips(&self, key: &str, chips: Vec<String>) -> Result<Vec<(Chip, u8)>, ConfigError> {
        if chips.is_empty() {
            return Err(self.error(
                &format!("{key}.chips"),
                format!(
                    "a usb-iss source needs `chips`, the chips to poll as NAME or NAME@ADDR \
                     (such as [\"mpu6050\", \"lsm303dlhc-mag@0x1e\"]); chips: {}",
                    chip_names()
                ),
            ));
        }
        if chips.len() > usize::from(u8::MAX) + 1 {
            return Err(self.error(
                &format!("{key}.chips"),
                format!("{} chips: at most 256 can be polled", chips.len()),
            ));
        }
        let mut parsed: Vec<(Chip, u8)> = Vec::with_capacity(chips.len());
        for (k, text) in chips.iter().enumerate() {
            let item = format!("{key}.chips[{k}]");
            let (chip, address) = parse_chip(text).map_err(|problem| self.error(&item, problem))?;
            let address = address.unwrap_or(chip.default_address());
            if let Some((other, _)) = parsed.iter().find(|(_, a)| *a == address) {
                return Err(self.error(
                    &item,
                    format!(
                        "{} and {} are both at 0x{address:02x}: two chips on one bus need \
                         different addresses; give this one's as NAME@ADDR",
                        other.name(),
                        chip.name()
                    ),
                ));
            }
            parsed.push((chip, address));
        }
        Ok(parsed)
    }

    fn check_speed(&self, key: &str, value: Option<&toml::Value>) -> Result<Speed, ConfigError> {
        let factor = match value {
            None => return Ok(Speed::Times(1.0)),
            Some(toml::Value::String(s)) => {
                return s
                    .parse::<Speed>()
                    .map_err(|problem| self.error(key, problem));
            }
            Some(toml::Value::Integer(i)) => *i as f64,
            Some(toml::Value::Float(f)) => *f,
            Some(other) => {
                return Err(self.error(
                    key,
                    format!(
                        "found {}: give a positive factor (1 = as recorded) or \"max\"",
                        type_name(other)
                    ),
                ));
            }
        };
        Speed::times(factor).map_err(|problem| self.error(key, problem))
    }

    /// The streams of a replayed file: those its capture header declares,
    /// or one Falcon stream for a raw dump. Reads the header only.
    fn replay_streams(&self, key: &str, file: &Path) -> Result<Vec<StreamDesc>, ConfigError> {
        let meta = std::fs::metadata(file).map_err(|e| {
            self.error(
                key,
                format!(
                    "{}: {e}: give an existing capture (relative paths are relative to {})",
                    file.display(),
                    self.base.display()
                ),
            )
        })?;
        if !meta.is_file() {
            return Err(self.error(
                key,
                format!(
                    "{} is not a file: give a capture or raw dump",
                    file.display()
                ),
            ));
        }
        if meta.len() > capture::MAX_CAPTURE_LEN {
            return Err(self.error(
                key,
                format!(
                    "{} holds {} bytes, more than the {} a capture can be: give a capture or \
                     raw dump of the device",
                    file.display(),
                    meta.len(),
                    capture::MAX_CAPTURE_LEN
                ),
            ));
        }
        if crate::io::csv::looks_like_csv(file) {
            return Err(self.error(
                key,
                format!(
                    "{} is a CSV recording, not a capture: give this source kind = \"csv\", \
                     and its sensors the file's columns in axes",
                    file.display()
                ),
            ));
        }
        let prefix = read_capture_prefix(file)
            .map_err(|e| self.error(key, format!("cannot read {}: {e}", file.display())))?;
        if prefix.is_empty() {
            return Err(self.error(
                key,
                format!("{} is empty: there is nothing to replay", file.display()),
            ));
        }
        if !prefix.starts_with(capture::MAGIC) {
            return Ok(vec![StreamDesc { id: 0, chip: None }]);
        }
        match capture::parse_capture(&prefix, &file.display().to_string()) {
            Ok(CaptureFile::Capture { header, .. }) => Ok(header
                .streams
                .iter()
                .map(|s| StreamDesc {
                    id: s.id,
                    chip: match s.kind {
                        StreamKind::Falcon => None,
                        StreamKind::Chip { chip, address } => Some((chip, address)),
                    },
                })
                .collect()),
            Ok(CaptureFile::Raw { .. }) => Ok(vec![StreamDesc { id: 0, chip: None }]),
            Err(e) => Err(self.error(key, e.to_string())),
        }
    }

    fn resolve_stream(
        &self,
        key: &str,
        chip: Option<&str>,
        source: &str,
        kind: &str,
        streams: &[StreamDesc],
    ) -> Result<StreamDesc, ConfigError> {
        let listed = || {
            streams
                .iter()
                .map(|s| s.describe())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let Some(text) = chip else {
            return match streams {
                [only] => Ok(*only),
                _ => Err(self.error(
                    &format!("{key}.chip"),
                    format!(
                        "source '{source}' has several streams ({}): say which this sensor \
                         reads with chip = \"NAME\" or \"NAME@ADDR\"",
                        listed()
                    ),
                )),
            };
        };
        let key = format!("{key}.chip");
        let (want, address) = parse_chip(text).map_err(|problem| self.error(&key, problem))?;
        let matches: Vec<StreamDesc> = streams
            .iter()
            .filter(|s| match s.chip {
                Some((c, a)) => c == want && address.is_none_or(|want_a| want_a == a),
                None => false,
            })
            .copied()
            .collect();
        match matches.as_slice() {
            [one] => Ok(*one),
            [] if streams.iter().all(|s| s.chip.is_none()) => Err(self.error(
                &key,
                format!(
                    "'{text}' is not on source '{source}': a {kind} source of Falcon-GX \
                     frames has no chips; leave `chip` out"
                ),
            )),
            [] => Err(self.error(
                &key,
                format!(
                    "'{text}' is not on source '{source}': its chips are {}",
                    listed()
                ),
            )),
            _ => Err(self.error(
                &key,
                format!(
                    "'{text}' is ambiguous on source '{source}' ({}): give NAME@ADDR",
                    listed()
                ),
            )),
        }
    }

    /// `declination_deg` or `location` on a sensor that is no magnetometer.
    fn north_not_magnetometer(&self, key: &str, location_given: bool, field: Field) -> ConfigError {
        let name = if location_given {
            "location"
        } else {
            "declination_deg"
        };
        self.error(
            &format!("{key}.{name}"),
            format!(
                "`{name}` is a magnetometer's: this sensor measures {}, whose heading owes \
                 nothing to the Earth's magnetic north; leave it out",
                field.name()
            ),
        )
    }

    /// A `[[sensor]]` with three axes: its 3-D settings, and the name its
    /// `tilt` gives (resolved by [`Checker::link_tilts`] once every sensor
    /// is read).
    fn check_sensor3(
        &self,
        key: &str,
        s: RawSensor,
        field: Field,
        stream: u8,
        parsed: &[Axis],
        src_name: &str,
    ) -> Result<(SensorConfig, Option<String>), ConfigError> {
        use crate::daemon::sensor3::Sensor3Config;
        use crate::model::ellipsoid::Ellipsoid3Model;
        let axes = [parsed[0], parsed[1], parsed[2]];
        if axes[0] == axes[1] || axes[0] == axes[2] || axes[1] == axes[2] {
            return Err(self.error(
                &format!("{key}.axes"),
                "an axis is given twice: a 3-axis sensor gives \"x\", \"y\", \"z\", each once \
                 (in the order of its x, y, z)",
            ));
        }
        if field == Field::Gyro {
            return Err(self.error(
                &format!("{key}.field"),
                "a gyro measures no constant field: a 3-axis sensor is \"mag\" or \"accel\"",
            ));
        }
        for (name, given) in [
            ("gyro", s.gyro.is_some()),
            ("gyro_chip", s.gyro_chip.is_some()),
            ("gyro_lsb_per_deg_s", s.gyro_lsb_per_deg_s.is_some()),
            ("rotation", s.rotation != RotationSettings::default()),
            ("limits", s.limits != LimitSettings::default()),
        ] {
            if given {
                return Err(self.error(
                    &format!("{key}.{name}"),
                    format!(
                        "`{name}` is for a 2-axis sensor's rotation: a 3-axis sensor collects \
                         until its directions cover the sphere, set in [sensor.sphere] \
                         (min_samples, max_samples, max_rms)"
                    ),
                ));
            }
        }
        let model = match &s.model {
            None => Ellipsoid3Model::Full,
            Some(toml::Value::String(text)) => text
                .trim()
                .parse::<Ellipsoid3Model>()
                .map_err(|e| self.error(&format!("{key}.model"), e))?,
            Some(other) => {
                return Err(self.error(
                    &format!("{key}.model"),
                    format!(
                        "found {}: a 3-axis sensor's model is a string, \"offset\", \
                         \"offset+scale\" or \"offset+scale+cross-axis\" (the default)",
                        type_name(other)
                    ),
                ));
            }
        };
        let (unit_key, wrong_key, unit) = match field {
            Field::Accel => ("lsb_per_g", "lsb_per_gauss", s.lsb_per_g),
            _ => ("lsb_per_gauss", "lsb_per_g", s.lsb_per_gauss),
        };
        let wrong = match field {
            Field::Accel => s.lsb_per_gauss,
            _ => s.lsb_per_g,
        };
        if wrong.is_some() {
            return Err(self.error(
                &format!("{key}.{wrong_key}"),
                format!(
                    "a {} sensor's units are `{unit_key}`, not `{wrong_key}`",
                    field.name()
                ),
            ));
        }
        if let Some(u) = unit
            && !(u.is_finite() && u > 0.0 && u <= 1e9)
        {
            return Err(self.error(
                &format!("{key}.{unit_key}"),
                format!("must be a positive number of counts (at most 1e9), got {u}"),
            ));
        }
        let sphere = s.sphere.unwrap_or_default();
        if let Err(problem) = sphere.validate() {
            return Err(self.error(&format!("{key}.sphere"), problem));
        }
        if sphere.still && field != Field::Accel {
            return Err(self.error(
                &format!("{key}.sphere.still"),
                format!(
                    "still poses are for an accelerometer (field = \"accel\"): a {} reads the \
                     same whether it moves or rests; tumble it through every direction and leave \
                     `still` out",
                    field.name()
                ),
            ));
        }
        let _ = src_name;
        let three = Sensor3Config {
            axes,
            model,
            lsb_per_unit: unit,
            // Resolved by link_tilts.
            tilt: None,
            sphere,
            columns: None,
        };
        Ok((
            SensorConfig {
                name: s.name,
                source: s.source,
                stream,
                field,
                axes: [axes[0], axes[1]],
                effects: model.name().split('+').map(String::from).collect(),
                rotation: RotationSettings::default(),
                limits: LimitSettings::default(),
                gyro: GyroChoice::Off(
                    "a 3-axis sensor: its fit is judged by the sphere's coverage, not a gyro"
                        .into(),
                ),
                columns: None,
                three: Some(three),
                north: None,
            },
            s.tilt,
        ))
    }

    /// Resolves each 3-axis sensor's `tilt`: another 3-axis accelerometer
    /// sensor of the same source.
    fn link_tilts(
        &self,
        sensors: &mut [SensorConfig],
        pending: &[(usize, String)],
    ) -> Result<(), ConfigError> {
        use crate::daemon::sensor3::TiltSource;
        for (i, name) in pending {
            let key = format!("sensor[{i}].tilt");
            let Some(me) = sensors.get(*i) else { continue };
            let found = sensors.iter().position(|s| &s.name == name);
            let Some(j) = found else {
                let names: Vec<&str> = sensors
                    .iter()
                    .filter(|s| s.three.is_some() && s.field == Field::Accel)
                    .map(|s| s.name.as_str())
                    .collect();
                return Err(self.error(
                    &key,
                    format!(
                        "no sensor named '{name}': give the 3-axis accelerometer sensor of source \
                         '{}' ({})",
                        me.source,
                        if names.is_empty() {
                            "the file has none: add one with field = \"accel\" and axes = \
                             [\"x\", \"y\", \"z\"]"
                                .to_string()
                        } else {
                            format!("the file has {}", names.join(", "))
                        }
                    ),
                ));
            };
            let other = &sensors[j];
            let problem = if j == *i {
                Some("a sensor cannot be its own tilt source".to_string())
            } else if other.three.is_none() {
                Some(format!(
                    "'{name}' is a 2-axis sensor: the tilt source must be a 3-axis accelerometer \
                     (axes = [\"x\", \"y\", \"z\"], field = \"accel\")"
                ))
            } else if other.field != Field::Accel {
                Some(format!(
                    "'{name}' measures {}: the tilt source must be an accelerometer (field = \"accel\")",
                    other.field.name()
                ))
            } else if other.source != me.source {
                Some(format!(
                    "'{name}' is a sensor of source '{}', not of '{}': the tilt source must be on \
                     the same board, read by the same source",
                    other.source, me.source
                ))
            } else if me.field != Field::Mag {
                Some(format!(
                    "a tilt-compensated heading is a magnetometer's: this sensor measures {}",
                    me.field.name()
                ))
            } else {
                None
            };
            if let Some(problem) = problem {
                return Err(self.error(&key, problem));
            }
            let tilt = other.three.as_ref().map(|t| TiltSource {
                sensor: name.clone(),
                stream: other.stream,
                axes: t.axes,
                columns: t.columns.clone(),
            });
            if let Some(three) = sensors.get_mut(*i).and_then(|s| s.three.as_mut()) {
                three.tilt = tilt;
            }
        }
        Ok(())
    }

    fn check_model(
        &self,
        key: &str,
        model: Option<&toml::Value>,
    ) -> Result<Vec<String>, ConfigError> {
        let mut names: Vec<(String, String)> = Vec::new(); // (key, name)
        match model {
            None => names.push((key.to_string(), "paper".into())),
            Some(toml::Value::String(s)) => {
                names.extend(
                    s.split('+')
                        .map(|n| (key.to_string(), n.trim().to_string())),
                );
            }
            Some(toml::Value::Array(items)) => {
                if items.is_empty() {
                    return Err(self.error(
                        key,
                        "an empty list: give \"paper\" or a list of effects such as \
                         [\"offset\", \"scale\"]",
                    ));
                }
                for (k, item) in items.iter().enumerate() {
                    let item_key = format!("{key}[{k}]");
                    match item {
                        toml::Value::String(s) => names.push((item_key, s.trim().to_string())),
                        other => {
                            return Err(self.error(
                                &item_key,
                                format!("found {}: effect names are strings", type_name(other)),
                            ));
                        }
                    }
                }
            }
            Some(other) => {
                return Err(self.error(
                    key,
                    format!(
                        "found {}: give \"paper\" or a list of effect names",
                        type_name(other)
                    ),
                ));
            }
        }
        let mut effects: Vec<Effect> = Vec::new();
        for (item_key, name) in &names {
            if name == "paper" {
                effects.extend(effects::PAPER);
                continue;
            }
            let effect: Effect = name
                .parse()
                .map_err(|problem| self.error(item_key, problem))?;
            if !LIVE_EFFECTS.contains(&effect) {
                return Err(self.error(
                    item_key,
                    format!(
                        "the effect '{effect}' cannot correct live readings: it needs the time base or a \
                         logged column at correction time; the daemon fits {}; analyse it offline with \
                         `fieldcal fit --effects {effect}` or `fieldcal diagnose`",
                        LIVE_EFFECTS.iter().map(Effect::to_string).collect::<Vec<_>>().join(", ")
                    ),
                ));
            }
            effects.push(effect);
        }
        let missing: Vec<String> = effects::PAPER
            .iter()
            .filter(|e| !effects.contains(e))
            .map(Effect::to_string)
            .collect();
        if !missing.is_empty() {
            return Err(self.error(
                key,
                format!(
                    "the model lacks {}: every model is the paper's (offset, scale) plus \
                     effects, so include both, or write \"paper\"",
                    missing.join(" and ")
                ),
            ));
        }
        // Catalogue order, each once.
        effects.sort();
        effects.dedup();
        Ok(effects.iter().map(Effect::to_string).collect())
    }

    /// The gyro of a sensor's heading check: the keys `gyro`, `gyro_chip`
    /// and `gyro_lsb_per_deg_s` of `sensor[i]` (`key`).
    fn check_gyro(
        &self,
        key: &str,
        s: &RawSensor,
        axes: [Axis; 2],
        own: StreamDesc,
        source: &str,
        streams: &[StreamDesc],
    ) -> Result<GyroChoice, ConfigError> {
        let axis_key = format!("{key}.gyro");
        let chosen = match s.gyro.as_deref().map(str::trim) {
            None => None,
            Some("none") => {
                if s.gyro_chip.is_some() {
                    return Err(self.error(
                        &format!("{key}.gyro_chip"),
                        "given with gyro = \"none\": name the gyro axis, or leave gyro_chip out",
                    ));
                }
                return Ok(GyroChoice::Off(
                    "no heading check: gyro = \"none\" in the configuration".into(),
                ));
            }
            Some("x") => Some(Axis::X),
            Some("y") => Some(Axis::Y),
            Some("z") => Some(Axis::Z),
            Some(other) => {
                return Err(self.error(
                    &axis_key,
                    format!(
                        "\"{other}\" is not a gyro axis: give \"x\", \"y\" or \"z\" (the \
                         gyro axis the sensor turns about) or \"none\""
                    ),
                ));
            }
        };
        let stream = match s.gyro_chip.as_deref() {
            None => own,
            Some(text) => self.gyro_stream(&format!("{key}.gyro_chip"), text, source, streams)?,
        };
        let has_gyro = stream.fields().contains(&Field::Gyro);
        if !has_gyro {
            return match chosen {
                None => Ok(GyroChoice::Off(format!(
                    "no heading check: {} of source '{source}' has no gyro (give gyro_chip for \
                     another chip's)",
                    stream.describe()
                ))),
                Some(_) => Err(self.error(
                    &axis_key,
                    format!(
                        "{} of source '{source}' has no gyro: give gyro_chip = \"NAME\" for \
                         another chip's, or leave gyro out",
                        stream.describe()
                    ),
                )),
            };
        }
        let same_stream = stream.id == own.id;
        let axis = match chosen {
            Some(axis) if same_stream && axes.contains(&axis) => {
                return Err(self.error(
                    &axis_key,
                    format!(
                        "\"{}\" is one of the two axes that turn ({}, {}): the turn is about the \
                         third, give it, or \"none\"",
                        axis.name(),
                        axes[0].name(),
                        axes[1].name()
                    ),
                ));
            }
            Some(axis) => axis,
            None if !same_stream => {
                return Err(self.error(
                    &axis_key,
                    "missing: with gyro_chip, say which of its axes the sensor turns about \
                     (\"x\", \"y\" or \"z\"): chips are not always mounted alike",
                ));
            }
            None if s.field == Some(Field::Gyro) => {
                return Ok(GyroChoice::Off(
                    "no heading check: the sensor is itself the gyro".into(),
                ));
            }
            None => [Axis::X, Axis::Y, Axis::Z]
                .into_iter()
                .find(|a| !axes.contains(a))
                .unwrap_or(Axis::Z),
        };
        let lsb_key = format!("{key}.gyro_lsb_per_deg_s");
        let lsb_per_deg_s = match (s.gyro_lsb_per_deg_s, gyro_lsb_per_deg_s(stream)) {
            (Some(v), _) if v.is_finite() && v > 0.0 && v <= 1e6 => v,
            (Some(v), _) => {
                return Err(self.error(
                    &lsb_key,
                    format!("{v}: give the gyro's counts per degree/second, above 0 (at most 1e6)"),
                ));
            }
            (None, Some(v)) => v,
            (None, None) => {
                return Err(self.error(
                    &lsb_key,
                    format!(
                        "missing: the scale of the gyro of {} is not known; give its counts per \
                         degree/second",
                        stream.describe()
                    ),
                ));
            }
        };
        Ok(GyroChoice::Rate {
            stream: stream.id,
            axis,
            lsb_per_deg_s,
        })
    }

    /// The stream of the chip named by `gyro_chip` on a sensor's source.
    fn gyro_stream(
        &self,
        key: &str,
        text: &str,
        source: &str,
        streams: &[StreamDesc],
    ) -> Result<StreamDesc, ConfigError> {
        let (want, address) = parse_chip(text).map_err(|problem| self.error(key, problem))?;
        let listed = streams
            .iter()
            .map(|s| s.describe())
            .collect::<Vec<_>>()
            .join(", ");
        let matches: Vec<StreamDesc> = streams
            .iter()
            .filter(|s| {
                s.chip
                    .is_some_and(|(c, a)| c == want && address.is_none_or(|w| w == a))
            })
            .copied()
            .collect();
        match matches.as_slice() {
            [one] if one.fields().contains(&Field::Gyro) => Ok(*one),
            [one] => Err(self.error(
                key,
                format!("{} has no gyro: name a chip that has one", one.describe()),
            )),
            [] if streams.iter().all(|s| s.chip.is_none()) => Err(self.error(
                key,
                format!(
                    "source '{source}' is of Falcon-GX frames, which have no chips: leave \
                     gyro_chip out (the frame's own gyro is used)"
                ),
            )),
            [] => Err(self.error(
                key,
                format!("'{text}' is not on source '{source}': its chips are {listed}"),
            )),
            _ => Err(self.error(
                key,
                format!("'{text}' is ambiguous on source '{source}' ({listed}): give NAME@ADDR"),
            )),
        }
    }

    fn check_name(&self, key: &str, name: &str) -> Result<(), ConfigError> {
        let problem = if name.is_empty() {
            Some("empty".to_string())
        } else if name.len() > NAME_MAX {
            Some(format!(
                "{} characters long, at most {NAME_MAX}",
                name.len()
            ))
        } else {
            name.chars()
                .find(|c| !(c.is_ascii_alphanumeric() || *c == '-' || *c == '_'))
                .map(|c| format!("it contains {c:?}"))
        };
        match problem {
            None => Ok(()),
            Some(p) => Err(self.error(
                key,
                format!(
                    "'{name}' is not a usable name ({p}): use letters, digits, '-' and '_' \
                     (it names files and appears in messages)"
                ),
            )),
        }
    }

    /// Seconds from `min` to `max`, both included.
    fn seconds_in(
        &self,
        key: &str,
        value: f64,
        min: f64,
        max: f64,
    ) -> Result<Duration, ConfigError> {
        if value >= min
            && value <= max
            && let Ok(d) = Duration::try_from_secs_f64(value)
        {
            return Ok(d);
        }
        Err(self.error(
            key,
            format!("{value} seconds: give a number of seconds from {min} to {max}"),
        ))
    }

    fn seconds(&self, key: &str, value: f64, max: f64) -> Result<Duration, ConfigError> {
        if value > 0.0
            && value <= max
            && let Ok(d) = Duration::try_from_secs_f64(value)
        {
            return Ok(d);
        }
        Err(self.error(
            key,
            format!("{value} seconds: give a number of seconds above 0 and at most {max}"),
        ))
    }
}

/// Counts per degree/second of a stream's gyro, where the chip (or frame)
/// defines it: the MPU-6050 as the bridge sets it up (+-250 deg/s), the
/// Falcon-GX-style frame as this project defines it.
fn gyro_lsb_per_deg_s(stream: StreamDesc) -> Option<f64> {
    match stream.chip {
        None => Some(falcon::RATE_LSB_PER_DEG_S),
        Some((Chip::Mpu6050, _)) => Some(crate::protocol::chips::mpu6050::GYRO_LSB_PER_DEG_S),
        Some(_) => None,
    }
}

fn kind_name(kind: &SourceKind) -> &'static str {
    match kind {
        SourceKind::Falcon { .. } => "falcon",
        SourceKind::UsbIss { .. } => "usb-iss",
        SourceKind::Replay { .. } => "replay",
        SourceKind::Csv { .. } => "csv",
    }
}

fn chip_names() -> String {
    Chip::ALL
        .iter()
        .map(|c| c.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// `NAME` or `NAME@ADDR` (7-bit; `0x..` hex or decimal); the address is
/// `None` when not given.
fn parse_chip(text: &str) -> Result<(Chip, Option<u8>), String> {
    let (name, address) = match text.split_once('@') {
        Some((name, address)) => (name.trim(), Some(address.trim())),
        None => (text.trim(), None),
    };
    let chip = Chip::ALL
        .into_iter()
        .find(|c| c.name().eq_ignore_ascii_case(name))
        .ok_or_else(|| {
            format!(
                "'{name}' is not a chip fieldcal knows: choose one of {}",
                chip_names()
            )
        })?;
    let address = match address {
        None => None,
        Some(a) => {
            let parsed = match a.strip_prefix("0x").or_else(|| a.strip_prefix("0X")) {
                Some(hex) => u8::from_str_radix(hex, 16),
                None => a.parse::<u8>(),
            };
            match parsed {
                Ok(v) if v <= 0x7F => Some(v),
                _ => {
                    return Err(format!(
                        "'{a}' in '{text}' is not a 7-bit I2C address: give 0x00 to 0x7f \
                         (or 0 to 127)"
                    ));
                }
            }
        }
    };
    Ok((chip, address))
}

/// The magic, length and header of a capture, or the first bytes of a raw
/// dump: enough to tell its streams without reading the whole file.
fn read_capture_prefix(file: &Path) -> std::io::Result<Vec<u8>> {
    // The same check as `read_capture`: a regular file, never waited on.
    let mut f = crate::io::regular::open_regular(file)?;
    let mut head = Vec::new();
    (&mut f)
        .take(capture::MAGIC.len() as u64 + 4)
        .read_to_end(&mut head)?;
    if head.len() < capture::MAGIC.len() + 4 || !head.starts_with(capture::MAGIC) {
        return Ok(head);
    }
    let len_bytes: [u8; 4] = head[capture::MAGIC.len()..].try_into().unwrap_or([0; 4]);
    let len = u32::from_le_bytes(len_bytes).min(capture::MAX_HEADER_LEN);
    f.take(u64::from(len)).read_to_end(&mut head)?;
    Ok(head)
}

/// `$STATE_DIRECTORY` (systemd's `StateDirectory=`; the first if several),
/// else `./state`.
/// `outputs.max_subscribers` at most: far beyond any descriptor limit a
/// service gets by default; the start checks the real limit.
const MAX_SUBSCRIBERS_LIMIT: u64 = 100_000;
/// A token file's size at most: a token is one short line.
const MAX_TOKEN_FILE_BYTES: u64 = 4096;
/// Bytes of a group entry's buffer at most (getgrnam_r): groups with
/// thousands of members need more than the suggested size.
const MAX_GROUP_BUFFER: usize = 1 << 20;

/// The id of the group named `name`, via getgrnam_r.
fn group_id(name: &str) -> Option<u32> {
    let name = std::ffi::CString::new(name).ok()?;
    let mut size = 4096usize;
    loop {
        let mut buf = vec![0 as libc::c_char; size];
        // SAFETY: an all-zero `group` is a valid value to be overwritten.
        let mut group: libc::group = unsafe { std::mem::zeroed() };
        let mut result: *mut libc::group = std::ptr::null_mut();
        // SAFETY: every pointer is to live memory of the size given.
        let rc = unsafe {
            libc::getgrnam_r(
                name.as_ptr(),
                &mut group,
                buf.as_mut_ptr(),
                buf.len(),
                &mut result,
            )
        };
        if rc == libc::ERANGE && size < MAX_GROUP_BUFFER {
            size *= 2;
            continue;
        }
        return (rc == 0 && !result.is_null()).then_some(group.gr_gid);
    }
}

fn default_state_dir() -> PathBuf {
    std::env::var_os("STATE_DIRECTORY")
        .and_then(|v| {
            let first = v.to_string_lossy().split(':').next().map(str::to_string)?;
            (!first.is_empty()).then(|| PathBuf::from(first))
        })
        .unwrap_or_else(|| PathBuf::from("./state"))
}

fn type_name(value: &toml::Value) -> &'static str {
    match value {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date-time",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

/// 1-based line and column (in characters) of a byte offset.
fn position_of(text: &str, offset: usize) -> Position {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = text[line_start..offset].chars().count() + 1;
    Position { line, column }
}

/// The dotted key whose key or value span holds byte `pos`: the smallest
/// such span wins, so an error inside `axes = ["x", "w"]` is `axes[1]`.
fn path_at(doc: &Spanned<DeTable>, pos: usize) -> Option<String> {
    let mut best: Option<(usize, String)> = None;
    let mut path = String::new();
    walk_table(doc.get_ref(), &mut path, pos, &mut best);
    best.map(|(_, p)| p)
}

fn contains(span: &Range<usize>, pos: usize) -> bool {
    span.contains(&pos) || (span.is_empty() && span.start == pos)
}

fn consider(best: &mut Option<(usize, String)>, span: Range<usize>, path: &str, pos: usize) {
    if !contains(&span, pos) {
        return;
    }
    let len = span.len();
    // Ties go to the later (deeper) candidate.
    if best.as_ref().is_none_or(|(l, _)| len <= *l) {
        *best = Some((len, path.to_string()));
    }
}

fn walk_table(table: &DeTable, path: &mut String, pos: usize, best: &mut Option<(usize, String)>) {
    for (key, value) in table.iter() {
        let saved = path.len();
        if !path.is_empty() {
            path.push('.');
        }
        path.push_str(key.get_ref());
        consider(best, key.span(), path, pos);
        walk_value(value, path, pos, best);
        path.truncate(saved);
    }
}

fn walk_value(
    value: &Spanned<DeValue>,
    path: &mut String,
    pos: usize,
    best: &mut Option<(usize, String)>,
) {
    match value.get_ref() {
        DeValue::Table(t) => {
            // A table's own span (a header, or an inline table) loses to
            // any of its keys that also holds the position.
            consider(best, value.span(), path, pos);
            walk_table(t, path, pos, best);
        }
        DeValue::Array(items) => {
            consider(best, value.span(), path, pos);
            for (i, item) in items.iter().enumerate() {
                let saved = path.len();
                path.push_str(&format!("[{i}]"));
                walk_value(item, path, pos, best);
                path.truncate(saved);
            }
        }
        _ => consider(best, value.span(), path, pos),
    }
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
