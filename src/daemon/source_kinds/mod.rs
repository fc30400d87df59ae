//! The kinds of `[[source]]`, listed once as gpsd lists its drivers.
//!
//! Each kind is a module here: its settings, the keys it takes and their
//! checks, what a reload compares, what a reload reads before it is
//! applied, and its start function (the [`Kind`] trait). [`kinds!`]'s one
//! invocation below lists them; the configuration, the run loop and the
//! reload reach a kind only through [`SourceKind`]'s methods. Adding a kind
//! is a module and its line in that list.

use serde::Deserialize;
use serde::de::{self, Deserializer, EnumAccess, VariantAccess, Visitor};

use crate::daemon::config::{ConfigError, Keys, SensorConfig, SourceConfig, StreamDesc};
use crate::daemon::reload::ReloadError;
use crate::daemon::run::{DaemonError, Start, Started};
use crate::io::csv::CsvLayout;
use crate::source::replay::Speed;

/// What a kind of source provides.
pub(crate) trait Kind: Sized {
    /// Its name, as in `kind = "..."`.
    const NAME: &'static str;
    /// The keys it takes besides name, kind and retry_s, in the order the
    /// documentation gives them.
    const KEYS: &'static [&'static str];

    /// Its settings from the keys of its section, checked: the streams it
    /// carries and, for a csv source, each file's header.
    fn check(keys: &Keys<'_, '_>) -> Result<Checked<Self>, ConfigError>;

    /// The keys whose values differ from `new`'s, for a reload's message.
    fn changed(&self, new: &Self) -> Vec<&'static str>;

    /// What a reload reads before it is applied, as a start would
    /// (a capture read whole, csv headers and their sensors' columns).
    fn preflight(&self, _name: &str, _sensors: &[SensorConfig]) -> Result<(), ReloadError> {
        Ok(())
    }

    /// How fast a replayed file plays; `None` for a device.
    fn speed(&self) -> Option<Speed> {
        None
    }

    /// Starts the source: a task or thread that owns its port or file and
    /// sends its events.
    fn spawn(&self, source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError>;
}

/// A kind's settings as its check leaves them.
pub(crate) struct Checked<K> {
    pub settings: K,
    /// The byte streams it carries: one for a Falcon-GX or a csv file, one
    /// per chip for an I2C bridge, those a capture declares.
    pub streams: Vec<StreamDesc>,
    /// A csv source's files' headers, for its sensors' columns.
    pub layouts: Option<Vec<CsvLayout>>,
}

/// A checked source of any kind.
pub(crate) type CheckedKind = Checked<SourceKind>;

/// Lists the kinds: each `Variant(module::Settings)` is a variant of
/// [`SourceKind`], and every method of [`SourceKind`] dispatches to it.
macro_rules! kinds {
    ($($variant:ident($module:ident::$settings:ident)),* $(,)?) => {
        $(pub mod $module;)*
        $(pub use $module::$settings;)*

        /// What a source reads, with the settings of its kind.
        #[derive(Debug, Clone, PartialEq)]
        pub enum SourceKind {
            $($variant($settings),)*
        }

        /// The kinds' names and keys, in the list's order.
        const TABLE: &[(&str, &[&str])] = &[$(($settings::NAME, $settings::KEYS)),*];

        /// The kinds' names, in the list's order (serde's "expected one of").
        const NAMES: &[&str] = &[$($settings::NAME),*];

        impl SourceKind {
            /// Its name, as in `kind = "..."`.
            pub fn name(&self) -> &'static str {
                match self {
                    $(SourceKind::$variant(_) => $settings::NAME,)*
                }
            }

            /// How fast a replayed file plays (`replay` and `csv` sources).
            pub fn speed(&self) -> Option<Speed> {
                match self {
                    $(SourceKind::$variant(k) => k.speed(),)*
                }
            }

            /// The keys whose values differ from `new`'s (`kind` when the
            /// kinds differ; `settings` when only something unnamed does).
            pub fn changed(&self, new: &SourceKind) -> Vec<&'static str> {
                #[allow(unreachable_patterns)]
                let keys = match (self, new) {
                    $((SourceKind::$variant(a), SourceKind::$variant(b)) => a.changed(b),)*
                    _ => vec!["kind"],
                };
                keys
            }

            /// What a reload reads before it is applied.
            pub fn preflight(&self, name: &str, sensors: &[SensorConfig]) -> Result<(), ReloadError> {
                match self {
                    $(SourceKind::$variant(k) => k.preflight(name, sensors),)*
                }
            }

            /// Starts the source.
            pub(crate) fn spawn(&self, source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError> {
                match self {
                    $(SourceKind::$variant(k) => k.spawn(source, start),)*
                }
            }

            /// The settings of kind `name` from its section's keys.
            pub(crate) fn check(name: &str, keys: &Keys<'_, '_>) -> Option<Result<CheckedKind, ConfigError>> {
                $(if name == $settings::NAME {
                    return Some($settings::check(keys).map(|c| Checked {
                        settings: SourceKind::$variant(c.settings),
                        streams: c.streams,
                        layouts: c.layouts,
                    }));
                })*
                None
            }
        }
    };
}

kinds! {
    Falcon(falcon::Falcon),
    UsbIss(usb_iss::UsbIss),
    Replay(replay::Replay),
    Csv(csv::Csv),
}

/// The keys of kind `name`, if it is one.
pub(crate) fn keys_of(name: &str) -> Option<&'static [&'static str]> {
    TABLE
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, keys)| *keys)
}

/// Every key some kind takes, each kind's in its own order: a key new to
/// the list goes before the first of its kind's later keys already there,
/// else at the end.
pub(crate) fn all_keys() -> Vec<&'static str> {
    let mut all: Vec<&'static str> = Vec::new();
    for (_, keys) in TABLE {
        for (j, key) in keys.iter().enumerate() {
            if all.contains(key) {
                continue;
            }
            let later = keys[j + 1..]
                .iter()
                .find_map(|k| all.iter().position(|a| a == k));
            all.insert(later.unwrap_or(all.len()), key);
        }
    }
    all
}

/// A source's `kind`: one of the listed names, refused in serde's words
/// otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct KindName(pub(crate) &'static str);

impl<'de> Deserialize<'de> for KindName {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Name;
        impl<'de> Visitor<'de> for Name {
            type Value = KindName;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a kind of source")
            }

            fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<KindName, A::Error> {
                let (name, variant): (String, _) = data.variant()?;
                variant.unit_variant()?;
                NAMES
                    .iter()
                    .find(|n| **n == name)
                    .map(|n| KindName(n))
                    .ok_or_else(|| de::Error::unknown_variant(&name, NAMES))
            }
        }
        deserializer.deserialize_enum("SourceKind", NAMES, Name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_of_every_kind_is_listed_once_in_each_kinds_order() {
        let all = all_keys();
        assert_eq!(
            all,
            [
                "port",
                "baud",
                "chips",
                "poll_ms",
                "i2c_khz",
                "file",
                "files",
                "speed",
                "time_column",
                "period_s"
            ]
        );
        for (_, keys) in TABLE {
            let at: Vec<usize> = keys
                .iter()
                .map(|k| all.iter().position(|a| a == k).unwrap())
                .collect();
            assert!(at.windows(2).all(|w| w[0] < w[1]), "{keys:?}");
        }
    }
}
