//! The Unix-socket transport: subscribers accepted on the daemon's Unix
//! socket ([`Hub::serve_unix`]), and the socket file itself: what may be at
//! its path before the bind, the mode it gets, and removing it at shutdown
//! only if it is still ours.
//!
//! - A socket left by a daemon that died (nothing answers on it) is removed
//!   and bound again. Anything else at the path (a regular file, a
//!   directory, a live daemon's socket) stops the start with a message
//!   naming what is there.
//! - The socket's mode is set explicitly after the bind ([`SOCKET_MODE`],
//!   or `[outputs] unix_mode`), and its group when `[outputs] unix_group`
//!   names one, so who may connect (and send commands) does not follow the
//!   umask or group the daemon happened to start with.
//! - At shutdown the path is removed only if it still names the socket
//!   bound at start (same device and inode): a file someone put there
//!   since, or another daemon's socket, is left alone.

use std::io;
use std::os::unix::fs::{FileTypeExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

use tokio::sync::{mpsc, watch};

use super::access::Origin;
use super::commands::ClientCommand;
use super::hub::Hub;
use super::subscriber::ReplyTo;

/// The mode of the socket file: read and write (connect) for the owner and
/// its group, nothing for others. Connecting to a Unix socket needs write
/// permission on it, and a subscriber can send commands, so others get
/// none; the group is how a person or service is let in (systemd's
/// `Group=` / `RuntimeDirectory=`).
pub const SOCKET_MODE: u32 = 0o660;

impl Hub {
    /// Accepts Unix-socket subscribers until `shutdown` turns true, like
    /// [`Hub::serve_tcp`].
    pub async fn serve_unix(
        &self,
        listener: tokio::net::UnixListener,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
        shutdown: watch::Receiver<bool>,
    ) {
        let accept = || async {
            let (stream, _addr) = listener.accept().await?;
            Ok((stream, "unix".to_owned()))
        };
        self.accept_loop(Origin::Unix, accept, commands, shutdown)
            .await;
    }
}

/// Why the socket could not be made.
#[derive(Debug, thiserror::Error)]
pub enum UnixSocketError {
    #[error(
        "a {what} is at the Unix socket path {}: remove it or choose another [outputs] unix",
        path.display()
    )]
    PathTaken { path: PathBuf, what: &'static str },
    #[error(
        "another fieldcal (or another program) is listening on the Unix socket {}: stop it, \
         or choose another [outputs] unix",
        path.display()
    )]
    InUse { path: PathBuf },
    #[error(
        "cannot listen on the Unix socket {}: {source}; check that its directory exists and \
         is writable",
        path.display()
    )]
    Bind {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "cannot give the Unix socket {} to group {gid}: {source}; the daemon's user must be \
         a member of the group of [outputs] unix_group (or run with Group= of it)",
        path.display()
    )]
    Group {
        path: PathBuf,
        gid: u32,
        #[source]
        source: io::Error,
    },
    #[error(
        "cannot set the mode of the Unix socket {} to {mode:o}: {source}",
        path.display()
    )]
    Mode {
        path: PathBuf,
        mode: u32,
        #[source]
        source: io::Error,
    },
}

/// The socket file bound at start: its path and identity.
#[derive(Debug, Clone)]
pub struct BoundSocket {
    path: PathBuf,
    dev: u64,
    ino: u64,
}

/// Checks what is at `path`, removes a dead daemon's socket, binds with
/// `bind` (the caller's listener type), sets `mode`, and records the
/// file's identity for [`BoundSocket::remove_if_ours`].
pub fn bind<L>(
    path: &Path,
    mode: u32,
    bind: impl FnOnce(&Path) -> io::Result<L>,
) -> Result<(L, BoundSocket), UnixSocketError> {
    bind_owned(path, mode, None, bind)
}

/// [`bind`], giving the socket to group `group` (when Some) before its mode
/// is set.
pub fn bind_owned<L>(
    path: &Path,
    mode: u32,
    group: Option<u32>,
    bind: impl FnOnce(&Path) -> io::Result<L>,
) -> Result<(L, BoundSocket), UnixSocketError> {
    clear_path(path)?;
    let listener = bind(path).map_err(|source| UnixSocketError::Bind {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(gid) = group {
        std::os::unix::fs::chown(path, None, Some(gid)).map_err(|source| {
            UnixSocketError::Group {
                path: path.to_path_buf(),
                gid,
                source,
            }
        })?;
    }
    let mode_error = |source| UnixSocketError::Mode {
        path: path.to_path_buf(),
        mode,
        source,
    };
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).map_err(mode_error)?;
    let meta = std::fs::symlink_metadata(path).map_err(mode_error)?;
    Ok((
        listener,
        BoundSocket {
            path: path.to_path_buf(),
            dev: meta.dev(),
            ino: meta.ino(),
        },
    ))
}

/// Makes way for the bind: nothing there, or a socket nobody answers on
/// (removed). Anything else is an error naming it.
fn clear_path(path: &Path) -> Result<(), UnixSocketError> {
    let Ok(meta) = std::fs::symlink_metadata(path) else {
        return Ok(());
    };
    let file_type = meta.file_type();
    let what = if file_type.is_socket() {
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            return Err(UnixSocketError::InUse {
                path: path.to_path_buf(),
            });
        }
        // Left by a daemon that died: ours to replace.
        return match std::fs::remove_file(path) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
            Err(source) => Err(UnixSocketError::Bind {
                path: path.to_path_buf(),
                source,
            }),
        };
    } else if file_type.is_file() {
        "regular file"
    } else if file_type.is_dir() {
        "directory"
    } else if file_type.is_symlink() {
        "symbolic link"
    } else if file_type.is_fifo() {
        "FIFO"
    } else {
        "device or other special file"
    };
    Err(UnixSocketError::PathTaken {
        path: path.to_path_buf(),
        what,
    })
}

impl BoundSocket {
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Removes the socket file if the path still names the one bound at
    /// start. Returns whether it did.
    pub fn remove_if_ours(&self) -> bool {
        match std::fs::symlink_metadata(&self.path) {
            Ok(meta)
                if meta.file_type().is_socket()
                    && meta.dev() == self.dev
                    && meta.ino() == self.ino =>
            {
                std::fs::remove_file(&self.path).is_ok()
            }
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::net::UnixListener;

    #[test]
    fn binds_with_the_mode_and_removes_only_its_own_socket() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sock");
        let (listener, bound) = bind(&path, 0o660, |p| UnixListener::bind(p)).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o660);
        // Another file put in its place is not removed.
        drop(listener);
        std::fs::remove_file(&path).unwrap();
        std::fs::write(&path, "not ours").unwrap();
        assert!(!bound.remove_if_ours());
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "not ours");
        // And a regular file at the path stops the next bind, named as such.
        let err = bind(&path, 0o660, |p| UnixListener::bind(p)).unwrap_err();
        assert!(matches!(
            err,
            UnixSocketError::PathTaken {
                what: "regular file",
                ..
            }
        ));
        assert!(
            err.to_string()
                .contains("remove it or choose another [outputs] unix")
        );
    }

    #[test]
    fn a_dead_socket_is_replaced_a_live_one_is_not() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sock");
        let live = UnixListener::bind(&path).unwrap();
        let err = bind(&path, 0o660, |p| UnixListener::bind(p)).unwrap_err();
        assert!(matches!(err, UnixSocketError::InUse { .. }), "{err}");
        drop(live); // the file stays, nothing answers: a dead daemon's
        let (_listener, bound) = bind(&path, 0o600, |p| UnixListener::bind(p)).unwrap();
        assert!(bound.remove_if_ours());
        assert!(std::fs::symlink_metadata(&path).is_err());
    }
}
