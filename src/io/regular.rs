//! Opening the files fieldcal reads as inputs (captures, CSV recordings,
//! configurations, calibrations, state files): regular files only.
//!
//! A path can name something that is not a file: a FIFO, whose `open`
//! blocks until a writer comes (before the daemon is READY, and deaf to
//! SIGTERM while it waits); a device such as `/dev/zero`, which never ends
//! and fills memory; a directory or a socket. [`open_regular`] refuses all of
//! them before anything can block: it looks at the path first (without
//! opening a device, whose `open` alone can act: a watchdog arms, a modem
//! line waits for carrier), then opens with `O_NONBLOCK | O_NOCTTY` and
//! checks the opened file again, so a path swapped between the two looks
//! is caught too. Symbolic links are followed: a configuration or a
//! recording reached through a link is a normal setup; where the link
//! ends must be a regular file.
//!
//! [`read_regular`] reads such a file whole, up to a cap the caller gives.
//! Both report through [`io::Error`], so every caller's existing error
//! (which names the path and says what it was reading) carries them; the
//! inner error is a [`NotRegular`] or a [`TooLarge`].

use std::fs::{File, FileType, OpenOptions};
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// What is at a path where a regular file was expected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpecialKind {
    Directory,
    Fifo,
    CharDevice,
    BlockDevice,
    Socket,
    Other,
}

impl SpecialKind {
    fn of(file_type: FileType) -> SpecialKind {
        if file_type.is_dir() {
            SpecialKind::Directory
        } else if file_type.is_fifo() {
            SpecialKind::Fifo
        } else if file_type.is_char_device() {
            SpecialKind::CharDevice
        } else if file_type.is_block_device() {
            SpecialKind::BlockDevice
        } else if file_type.is_socket() {
            SpecialKind::Socket
        } else {
            SpecialKind::Other
        }
    }

    fn describe(self) -> &'static str {
        match self {
            SpecialKind::Directory => "a directory",
            SpecialKind::Fifo => "a FIFO (named pipe), which would wait for a writer",
            SpecialKind::CharDevice => "a character device, which may never end",
            SpecialKind::BlockDevice => "a block device",
            SpecialKind::Socket => "a socket",
            SpecialKind::Other => "not a regular file",
        }
    }
}

/// The path names something other than a regular file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("it is {}, not a regular file: give the path of a regular file", .kind.describe())]
pub struct NotRegular {
    pub kind: SpecialKind,
}

/// The file is larger than what its reader accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("it holds more than {max} bytes, more than a file of this kind can be")]
pub struct TooLarge {
    pub max: u64,
}

fn not_regular(file_type: FileType) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        NotRegular {
            kind: SpecialKind::of(file_type),
        },
    )
}

/// Opens `path` for reading if it is a regular file (after following
/// symbolic links); anything else is an [`io::ErrorKind::InvalidInput`]
/// error holding a [`NotRegular`]. Never blocks on a FIFO or a device.
pub fn open_regular(path: &Path) -> io::Result<File> {
    // The path first: a device or FIFO is refused without being opened.
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(not_regular(meta.file_type()));
    }
    // O_NONBLOCK: should the path have become a FIFO since, open returns
    // at once instead of waiting for a writer (and reads of a regular file
    // ignore the flag). O_NOCTTY: a terminal never becomes ours.
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(not_regular(meta.file_type()));
    }
    Ok(file)
}

/// The bytes of the regular file at `path` (see [`open_regular`]), at most
/// `max` of them: a larger file is an [`io::ErrorKind::InvalidData`] error
/// holding a [`TooLarge`], found from its size before reading, and again
/// while reading should it grow meanwhile.
pub fn read_regular(path: &Path, max: u64) -> io::Result<Vec<u8>> {
    let file = open_regular(path)?;
    let too_large = || io::Error::new(io::ErrorKind::InvalidData, TooLarge { max });
    let len = file.metadata()?.len();
    if len > max {
        return Err(too_large());
    }
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(max.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(too_large());
    }
    Ok(bytes)
}

/// The [`NotRegular`] inside `e`, if that is what it is.
pub fn not_regular_kind(e: &io::Error) -> Option<SpecialKind> {
    e.get_ref()
        .and_then(|inner| inner.downcast_ref::<NotRegular>())
        .map(|n| n.kind)
}
