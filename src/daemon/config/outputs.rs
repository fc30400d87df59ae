//! `[outputs]`: stdout, the TCP, Unix-socket and HTTP listeners, who may
//! connect and command (tokens, origins, Unix modes and groups), queues
//! and subscriber limits.

use super::*;
use crate::daemon::output_kinds::{self, Output};

impl Checker<'_> {
    /// `[outputs]`: each kind of output from its own keys (refused when
    /// no kind and no common key names them), then the queue, the
    /// subscriber limit and who may recalibrate.
    pub(super) fn check_outputs(&self, raw: &RawKeys) -> Result<OutputsConfig, ConfigError> {
        let mut keys = Keys {
            checker: self,
            key: "outputs".into(),
            kind: "",
            values: raw,
        };
        let outputs = Output::check_all(&mut keys)?;
        let queue = match keys.get::<u64>("queue")? {
            None => 4096,
            Some(q) if (1..=1_000_000).contains(&q) => usize::try_from(q).unwrap_or(4096),
            Some(q) => {
                return Err(self.error(
                    "outputs.queue",
                    format!("{q} lines: give 1 to 1000000 lines per subscriber"),
                ));
            }
        };
        let max_subscribers = match keys.get::<u64>("max_subscribers")? {
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
        let recalibrate_from = match keys.get::<Vec<String>>("recalibrate_from")? {
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
        let token = match keys.get::<PathBuf>("token_file")? {
            None => None,
            Some(path) => Some(self.token_file(&self.resolve(&path))?),
        };
        Ok(OutputsConfig {
            outputs,
            queue,
            max_subscribers,
            access: Access {
                recalibrate_from,
                token,
            },
        })
    }

    /// Every `[outputs]` key that no kind of output takes and that is not
    /// a common one, refused in serde's words.
    pub(super) fn refuse_unknown_output_keys(&self, raw: &RawKeys) -> Result<(), ConfigError> {
        let allowed: Vec<&str> = output_kinds::TABLE
            .iter()
            .flat_map(|(_, keys, _)| keys.iter().copied())
            .chain(COMMON_OUTPUT_KEYS.iter().copied())
            .collect();
        self.refuse_unknown("outputs", raw, &allowed)
    }

    /// `outputs.unix_mode`: octal permission bits, at most 0777.
    pub(crate) fn unix_mode(&self, text: &str) -> Result<u32, ConfigError> {
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
    pub(crate) fn unix_group(&self, value: &toml::Value) -> Result<u32, ConfigError> {
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
    pub(super) fn token_file(&self, path: &Path) -> Result<Token, ConfigError> {
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
        let token = Token::new(&text).ok_or_else(|| {
            self.error(
                key,
                format!(
                    "{shown} is empty: put the token in it (for example: openssl rand -hex 32)"
                ),
            )
        })?;
        if token.len() < crate::daemon::publish::MIN_TOKEN_BYTES {
            return Err(self.error(
                key,
                format!(
                    "{shown} holds a token of {} bytes: at least {} are needed, or it is guessed (for example: openssl rand -hex 32)",
                    token.len(),
                    crate::daemon::publish::MIN_TOKEN_BYTES
                ),
            ));
        }
        Ok(token)
    }

    /// `outputs.KEY` as a socket address, refused when it is not loopback
    /// unless `outputs.KEY_public = true` (neither listener authenticates).
    pub(crate) fn listen_address(
        &self,
        keys: &Keys<'_, '_>,
        key: &str,
        example_port: u16,
    ) -> Result<Option<SocketAddr>, ConfigError> {
        let text = keys.get::<String>(key)?;
        let public = keys.get::<bool>(&format!("{key}_public"))?.unwrap_or(false);
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
}

/// The `[outputs]` keys that are no kind's: the hub's queue and limit,
/// and who may recalibrate.
const COMMON_OUTPUT_KEYS: &[&str] = &["queue", "max_subscribers", "recalibrate_from", "token_file"];

/// `outputs.max_subscribers` at most: far beyond any descriptor limit a
/// service gets by default; the start checks the real limit.
pub(super) const MAX_SUBSCRIBERS_LIMIT: u64 = 100_000;
/// A token file's size at most: a token is one short line.
pub(super) const MAX_TOKEN_FILE_BYTES: u64 = 4096;
/// Bytes of a group entry's buffer at most (getgrnam_r): groups with
/// thousands of members need more than the suggested size.
pub(super) const MAX_GROUP_BUFFER: usize = 1 << 20;

/// The id of the group named `name`, via getgrnam_r.
pub(super) fn group_id(name: &str) -> Option<u32> {
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
