//! The configuration file as written: serde structs with every key
//! optional where it has a default, unknown keys refused (naming the key
//! and the allowed ones). [`Checker`](super::Checker) turns them into a
//! checked [`Config`](super::Config).

use super::*;
use crate::daemon::source_kinds::KindName;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConfig {
    #[serde(default)]
    pub(super) daemon: RawDaemon,
    #[serde(default)]
    pub(super) outputs: RawKeys,
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

/// One `[[source]]`: its name, kind and retry, and the keys of its kind
/// (checked by the kind, in [`crate::daemon::source_kinds`]).
#[derive(Deserialize)]
pub(super) struct RawSource {
    pub(super) name: String,
    pub(super) kind: KindName,
    pub(super) retry_s: Option<f64>,
    #[serde(flatten)]
    pub(super) keys: RawKeys,
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
    /// A 2-axis sensor's gyro axis or column; a 3-axis csv compass's three
    /// gyro columns, or "none".
    pub(super) gyro: Option<RawGyro>,
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
    /// A 2-axis sensor: the axis (device) or column (csv) across its turn.
    pub(super) out_of_plane: Option<String>,
    /// A 3-axis magnetometer with `tilt`: how its axes lie on the
    /// accelerometer's (as `fieldcal heading --mag-axes`).
    pub(super) mag_axes: Option<String>,
    /// A 3-axis magnetometer's counts per gauss.
    pub(super) lsb_per_gauss: Option<f64>,
    /// A 3-axis accelerometer's counts per g.
    pub(super) lsb_per_g: Option<f64>,
    /// A 3-axis sensor's collection and rms limit.
    pub(super) sphere: Option<crate::daemon::sensor3::SphereSettings>,
    /// A magnetometer's true north: a declination, or a place for the WMM.
    pub(super) declination_deg: Option<f64>,
    pub(super) location: Option<LocationKeys>,
    /// A 2-axis sensor: refine the calibration with later rotations that agree.
    pub(super) learn: Option<bool>,
    /// A 2-axis sensor: what a later rotation that moved the calibration does.
    pub(super) on_stale: Option<super::sensors::OnStale>,
}

/// `gyro`: one axis or column (a 2-axis sensor's, or "none"), or three
/// columns (a 3-axis csv compass's, in its tilt accelerometer's x, y, z).
#[derive(Clone)]
pub(super) enum RawGyro {
    One(String),
    Three(Vec<String>),
}

impl<'de> Deserialize<'de> for RawGyro {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = RawGyro;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(
                    "a gyro axis or column (\"z\", \"gyro_z\") or \"none\"; or a 3-axis \
                     compass's three gyro columns ([\"gyro_x\", \"gyro_y\", \"gyro_z\"])",
                )
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<RawGyro, E> {
                Ok(RawGyro::One(v.to_string()))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<RawGyro, A::Error> {
                let mut columns = Vec::new();
                // Three are wanted; a few more are read to say how many.
                while let Some(name) = seq.next_element::<String>()? {
                    if columns.len() >= 16 {
                        return Err(serde::de::Error::custom(
                            "more than 16 gyro columns: a 3-axis compass's gyro is three",
                        ));
                    }
                    columns.push(name);
                }
                Ok(RawGyro::Three(columns))
            }
        }
        deserializer.deserialize_any(Visitor)
    }
}

impl RawSensor {
    /// `gyro` when it is one name; three columns are none.
    pub(super) fn gyro_one(&self) -> Option<&str> {
        match &self.gyro {
            Some(RawGyro::One(name)) => Some(name.as_str()),
            _ => None,
        }
    }
}
