//! `unix = "PATH"`: newline-delimited JSON over a Unix socket, with its
//! mode (`unix_mode`) and group (`unix_group`).

use std::path::PathBuf;

use super::{Kind, Running, Start};
use crate::daemon::config::{ConfigError, Keys};
use crate::daemon::publish::unix::{SOCKET_MODE, bind_owned};
use crate::daemon::run::DaemonError;

/// The Unix socket's path, mode and group.
#[derive(Debug, Clone, PartialEq)]
pub struct Unix {
    pub path: PathBuf,
    /// The socket's mode.
    pub mode: u32,
    /// The socket's group id, when set.
    pub group: Option<u32>,
}

impl Kind for Unix {
    const NAME: &'static str = "unix";
    const KEYS: &'static [&'static str] = &["unix", "unix_mode", "unix_group"];

    /// The path, and the mode and group (checked even without a path).
    fn check(keys: &Keys<'_, '_>) -> Result<Option<Self>, ConfigError> {
        let checker = keys.checker();
        let path = match keys.get::<PathBuf>("unix")? {
            Some(p) if p.as_os_str().is_empty() => {
                return Err(keys.error(
                    "unix",
                    "empty: give a socket path, or leave the key out",
                ));
            }
            Some(p) => Some(checker.resolve(&p)),
            None => None,
        };
        let mode = match keys.get::<String>("unix_mode")? {
            None => SOCKET_MODE,
            Some(text) => checker.unix_mode(&text)?,
        };
        let group = match keys.raw("unix_group") {
            None => None,
            Some(value) => Some(checker.unix_group(value)?),
        };
        Ok(path.map(|path| Unix { path, mode, group }))
    }

    fn describe(&self) -> String {
        self.path.display().to_string()
    }

    /// Binds the socket with its mode and group; the stop removes it if
    /// it is still the one bound (a file put at the path since stays).
    async fn start(&self, start: &Start<'_>) -> Result<Running, DaemonError> {
        let (listener, bound) = bind_owned(&self.path, self.mode, self.group, |p| {
            tokio::net::UnixListener::bind(p)
        })?;
        tracing::info!(path = %self.path.display(), "listening on a Unix socket");
        tokio::spawn({
            let hub = start.hub.clone();
            let (commands, stop) = (start.commands.clone(), start.stop.clone());
            async move { hub.serve_unix(listener, commands, stop).await }
        });
        Ok(Running {
            undo: Some(Box::new(move || {
                bound.remove_if_ours();
            })),
            ..Running::default()
        })
    }
}
