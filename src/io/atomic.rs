//! Atomic file replacement: write a temporary file beside the target, fsync
//! it, rename it over the target, fsync the directory. A reader (or a crash)
//! sees either the old file or the whole new one, never a torn one; a full
//! disk fails the write and leaves the old file untouched.
//!
//! On Linux the new content is first an unnamed file (`O_TMPFILE`) that only
//! gets a name when it is complete: a run killed while writing (even by
//! SIGKILL, or a power cut) leaves no temporary file behind, however large.
//! Where the file system cannot make unnamed files (or `/proc` is not
//! mounted), a hidden named temporary file is used, removed on any error.

use std::fs::{self, File, OpenOptions};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

static COUNTER: AtomicU64 = AtomicU64::new(0);

/// A file being written that replaces `target` only on [`AtomicFile::commit`].
/// Dropped without commit, the temporary file is removed.
#[derive(Debug)]
pub struct AtomicFile {
    target: PathBuf,
    /// The hidden name the content is written under, or (for an unnamed
    /// file) linked under just before it is renamed over the target.
    temp: PathBuf,
    file: File,
    /// The content has no name yet (`O_TMPFILE`).
    unnamed: bool,
    committed: bool,
}

/// Opens an unnamed file in `dir`, or None where that cannot be done here
/// (no `O_TMPFILE` on this file system or kernel, or no `/proc` to name it
/// by later).
#[cfg(target_os = "linux")]
fn open_unnamed(dir: &Path) -> Option<File> {
    use std::os::unix::fs::OpenOptionsExt;
    if !Path::new("/proc/self/fd").is_dir() {
        return None;
    }
    OpenOptions::new()
        .write(true)
        .custom_flags(libc::O_TMPFILE)
        .mode(0o666)
        .open(dir)
        .ok()
}

#[cfg(not(target_os = "linux"))]
fn open_unnamed(_dir: &Path) -> Option<File> {
    None
}

/// Gives the unnamed `file` the name `to`; fails with AlreadyExists if the
/// name is taken (linkat never replaces).
#[cfg(target_os = "linux")]
fn name_unnamed(file: &File, to: &Path) -> io::Result<()> {
    use std::os::fd::AsRawFd;
    use std::os::unix::ffi::OsStrExt;
    let from = std::ffi::CString::new(format!("/proc/self/fd/{}", file.as_raw_fd()))
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
    let to = std::ffi::CString::new(to.as_os_str().as_bytes())
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
    // SAFETY: linkat(2) with two NUL-terminated paths that outlive the call.
    let done = unsafe {
        libc::linkat(
            libc::AT_FDCWD,
            from.as_ptr(),
            libc::AT_FDCWD,
            to.as_ptr(),
            libc::AT_SYMLINK_FOLLOW,
        )
    };
    if done == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

#[cfg(not(target_os = "linux"))]
fn name_unnamed(_file: &File, _to: &Path) -> io::Result<()> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "unnamed files are not supported here",
    ))
}

impl AtomicFile {
    pub fn create(target: &Path) -> io::Result<Self> {
        let dir = parent_dir(target);
        let name = target
            .file_name()
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "the path names no file"))?;
        let temp = dir.join(format!(
            ".{}.tmp.{}.{}",
            name.to_string_lossy(),
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let (file, unnamed) = match open_unnamed(dir) {
            Some(file) => (file, true),
            None => (
                OpenOptions::new()
                    .write(true)
                    .create_new(true)
                    .open(&temp)?,
                false,
            ),
        };
        let atomic = AtomicFile {
            target: target.to_path_buf(),
            temp,
            file,
            unnamed,
            committed: false,
        };
        // The new file takes the place of the old one and keeps its mode: a
        // calibration kept 0600 stays 0600 (dropped on error, the temporary
        // file is removed). A new target gets the umask's default.
        if let Ok(meta) = fs::metadata(target)
            && meta.is_file()
        {
            atomic.file.set_permissions(meta.permissions())?;
        }
        Ok(atomic)
    }

    pub fn as_file_mut(&mut self) -> &mut File {
        &mut self.file
    }

    /// Makes the new content durable and puts it in place of the target.
    pub fn commit(mut self) -> io::Result<()> {
        self.file.sync_all()?;
        if self.unnamed {
            // Named under the hidden name only now, for the rename.
            name_unnamed(&self.file, &self.temp)?;
            self.unnamed = false;
        }
        fs::rename(&self.temp, &self.target)?;
        self.committed = true;
        // The rename itself is durable only once the directory is synced.
        File::open(parent_dir(&self.target))?.sync_all()
    }

    /// As [`AtomicFile::commit`], but never replaces a file: if the target
    /// exists (even one created since [`AtomicFile::create`]) this fails
    /// with [`io::ErrorKind::AlreadyExists`] and the temporary file is
    /// removed. The new name is a hard link to the finished file, made
    /// only if the name is free; where the file system has no hard links
    /// (FAT on an SD card), the target is checked and then renamed over.
    pub fn commit_new(mut self) -> io::Result<()> {
        self.file.sync_all()?;
        if self.unnamed {
            // linkat never replaces: a name taken since is AlreadyExists.
            // (File systems without hard links have no O_TMPFILE either,
            // so they took the named path below.)
            name_unnamed(&self.file, &self.target)?;
            self.committed = true;
            return File::open(parent_dir(&self.target))?.sync_all();
        }
        match fs::hard_link(&self.temp, &self.target) {
            Ok(()) => {
                self.committed = true;
                fs::remove_file(&self.temp)?;
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => return Err(e),
            Err(_) => {
                if fs::symlink_metadata(&self.target).is_ok() {
                    return Err(io::Error::new(
                        io::ErrorKind::AlreadyExists,
                        "the file exists",
                    ));
                }
                fs::rename(&self.temp, &self.target)?;
                self.committed = true;
            }
        }
        File::open(parent_dir(&self.target))?.sync_all()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if !self.committed && !self.unnamed {
            let _ = fs::remove_file(&self.temp);
        }
    }
}

fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}
