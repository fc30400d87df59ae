//! The configuration file as written: serde structs with every key
//! optional where it has a default, unknown keys refused (naming the key
//! and the allowed ones). [`Checker`](super::Checker) turns them into a
//! checked [`Config`](super::Config).

use super::*;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConfig {
    #[serde(default)]
    pub(super) daemon: RawDaemon,
    #[serde(default)]
    pub(super) outputs: RawOutputs,
    #[serde(default)]
    pub(super) source: Vec<RawSource>,
    #[serde(default)]
    pub(super) sensor: Vec<RawSensor>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawDaemon {
    pub(super) state_dir: Option<PathBuf>,
    pub(super) status_interval_s: Option<f64>,
    pub(super) log_format: LogFormat,
    /// The default true north of every magnetometer of a device source.
    pub(super) declination_deg: Option<f64>,
    pub(super) location: Option<LocationKeys>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawOutputs {
    pub(super) stdout: Option<bool>,
    pub(super) tcp: Option<String>,
    pub(super) tcp_public: bool,
    pub(super) unix: Option<PathBuf>,
    pub(super) http: Option<String>,
    pub(super) http_public: bool,
    pub(super) queue: Option<u64>,
    pub(super) max_subscribers: Option<u64>,
    pub(super) unix_mode: Option<String>,
    pub(super) unix_group: Option<toml::Value>,
    pub(super) recalibrate_from: Option<Vec<String>>,
    pub(super) token_file: Option<PathBuf>,
}

#[derive(Deserialize, Clone, Copy, PartialEq)]
#[serde(rename_all = "kebab-case")]
pub(super) enum RawKind {
    Falcon,
    UsbIss,
    Replay,
    Csv,
}

impl RawKind {
    pub(super) fn name(self) -> &'static str {
        match self {
            RawKind::Falcon => "falcon",
            RawKind::UsbIss => "usb-iss",
            RawKind::Replay => "replay",
            RawKind::Csv => "csv",
        }
    }

    /// The keys a source of this kind takes, besides name, kind, retry_s.
    pub(super) fn keys(self) -> &'static [&'static str] {
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
pub(super) struct RawSource {
    pub(super) name: String,
    pub(super) kind: RawKind,
    pub(super) port: Option<PathBuf>,
    pub(super) baud: Option<u32>,
    pub(super) chips: Option<Vec<String>>,
    pub(super) poll_ms: Option<u64>,
    pub(super) i2c_khz: Option<u32>,
    pub(super) file: Option<PathBuf>,
    pub(super) files: Option<Vec<PathBuf>>,
    pub(super) speed: Option<toml::Value>,
    pub(super) time_column: Option<String>,
    pub(super) period_s: Option<f64>,
    pub(super) retry_s: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSensor {
    pub(super) name: String,
    pub(super) source: String,
    pub(super) chip: Option<String>,
    pub(super) field: Option<Field>,
    /// Axes ("x", "y", "z") of a device's sensor, columns of a csv source's.
    pub(super) axes: Vec<String>,
    pub(super) model: Option<toml::Value>,
    pub(super) gyro: Option<String>,
    pub(super) gyro_chip: Option<String>,
    pub(super) gyro_lsb_per_deg_s: Option<f64>,
    pub(super) gyro_units: Option<String>,
    #[serde(default)]
    pub(super) rotation: RotationSettings,
    #[serde(default)]
    pub(super) limits: LimitSettings,
    /// A 3-axis sensor: the accelerometer sensor of the same source whose
    /// readings tilt-compensate its heading.
    pub(super) tilt: Option<String>,
    /// A 3-axis magnetometer's counts per gauss.
    pub(super) lsb_per_gauss: Option<f64>,
    /// A 3-axis accelerometer's counts per g.
    pub(super) lsb_per_g: Option<f64>,
    /// A 3-axis sensor's collection and rms limit.
    pub(super) sphere: Option<crate::daemon::sensor3::SphereSettings>,
    /// A magnetometer's true north: a declination, or a place for the WMM.
    pub(super) declination_deg: Option<f64>,
    pub(super) location: Option<LocationKeys>,
}
