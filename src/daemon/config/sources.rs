//! `[[source]]`: serial IMUs, I2C bridges with their chips, replayed
//! captures and csv files; the byte streams each one carries.

use super::*;
use crate::daemon::source_kinds::{self, Checked};

impl Checker<'_> {
    /// One `[[source]]`: its retry, and its kind's settings checked by the
    /// kind, after refusing the keys of other kinds.
    pub(super) fn check_source(
        &self,
        key: &str,
        s: &RawSource,
    ) -> Result<Checked<SourceConfig>, ConfigError> {
        let kind = s.kind.0;
        let own = source_kinds::keys_of(kind).unwrap_or_default();
        let foreign = source_kinds::all_keys()
            .into_iter()
            .find(|name| s.keys.contains_key(*name) && !own.contains(name));
        if let Some(name) = foreign {
            return Err(self.error(
                &format!("{key}.{name}"),
                format!(
                    "a {kind} source has no `{name}`: its keys are name, kind, {}, retry_s",
                    own.join(", ")
                ),
            ));
        }
        let retry = match s.retry_s {
            None => Duration::from_secs(2),
            Some(v) => self.seconds_in(&format!("{key}.retry_s"), v, MIN_RETRY_S, 3600.0)?,
        };
        let keys = Keys {
            checker: self,
            key: key.to_string(),
            kind,
            values: &s.keys,
        };
        let Checked {
            settings,
            streams,
            layouts,
        } = SourceKind::check(kind, &keys).unwrap_or_else(|| {
            Err(self.error(&format!("{key}.kind"), format!("'{kind}' is not a kind")))
        })?;
        let settings = SourceConfig {
            name: s.name.clone(),
            kind: settings,
            retry,
        };
        Ok(Checked {
            settings,
            streams,
            layouts,
        })
    }

    /// The first key of any `[[source]]` that no kind takes, refused in
    /// serde's words: checked over every source before anything else is.
    pub(super) fn refuse_unknown_source_keys(&self, raw: &[RawSource]) -> Result<(), ConfigError> {
        let allowed: Vec<&str> = ["name", "kind"]
            .into_iter()
            .chain(source_kinds::all_keys())
            .chain(["retry_s"])
            .collect();
        for (i, s) in raw.iter().enumerate() {
            self.refuse_unknown(&format!("source[{i}]"), &s.keys, &allowed)?;
        }
        Ok(())
    }

    /// A device source's `port`, or a message that names its kind and an
    /// example.
    pub(crate) fn require_port(
        &self,
        keys: &Keys<'_, '_>,
        example: &str,
    ) -> Result<PathBuf, ConfigError> {
        match keys.get::<PathBuf>("port")? {
            Some(p) if !p.as_os_str().is_empty() => Ok(p),
            _ => Err(keys.error(
                "port",
                format!(
                    "a {} source needs `port`, its serial device (such as \"{example}\")",
                    keys.kind
                ),
            )),
        }
    }

    /// A csv source's `file` or `files` (one of the two; at most
    /// [`crate::source::csv::MAX_FILES`], each once), resolved against the
    /// configuration's directory.
    pub(crate) fn csv_files(
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
    pub(crate) fn csv_layout(
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

    pub(crate) fn check_chips(
        &self,
        key: &str,
        chips: Vec<String>,
    ) -> Result<Vec<(Chip, u8)>, ConfigError> {
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

    pub(crate) fn check_speed(
        &self,
        key: &str,
        value: Option<&toml::Value>,
    ) -> Result<Speed, ConfigError> {
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
    pub(crate) fn replay_streams(
        &self,
        key: &str,
        file: &Path,
    ) -> Result<Vec<StreamDesc>, ConfigError> {
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

    pub(super) fn resolve_stream(
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
}

/// One byte stream of a source: its id and, for a chip, which one.
#[derive(Debug, Clone, Copy)]
pub struct StreamDesc {
    pub(crate) id: u8,
    /// `None` for a Falcon-GX stream.
    pub(crate) chip: Option<(Chip, u8)>,
}

impl StreamDesc {
    pub(super) fn fields(self) -> Vec<Field> {
        match self.chip {
            None => vec![Field::Mag, Field::Accel, Field::Gyro],
            Some((chip, _)) => chip_fields(chip),
        }
    }

    pub(super) fn describe(self) -> String {
        match self.chip {
            None => "a Falcon-GX stream".into(),
            Some((chip, address)) => format!("{}@0x{address:02x}", chip.name()),
        }
    }
}

/// The fields a chip reports: decoding a poll of zeros shows which it
/// fills, so this cannot drift from the chip drivers.
pub(super) fn chip_fields(chip: Chip) -> Vec<Field> {
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

pub(super) fn chip_names() -> String {
    Chip::ALL
        .iter()
        .map(|c| c.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// `NAME` or `NAME@ADDR` (7-bit; `0x..` hex or decimal); the address is
/// `None` when not given.
pub(super) fn parse_chip(text: &str) -> Result<(Chip, Option<u8>), String> {
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
pub(super) fn read_capture_prefix(file: &Path) -> std::io::Result<Vec<u8>> {
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
