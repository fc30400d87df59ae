//! `stdout = true` (the default): newline-delimited JSON on standard
//! output, above the progress lines when a terminal shows them.

use super::{Kind, Running, Start};
use crate::daemon::config::{ConfigError, Keys};
use crate::daemon::progress::ProgressFeed;
use crate::daemon::run::DaemonError;

/// Standard output.
#[derive(Debug, Clone, PartialEq)]
pub struct Stdout;

impl Kind for Stdout {
    const NAME: &'static str = "stdout";
    const KEYS: &'static [&'static str] = &["stdout"];
    const OFF: &'static str = "false";

    fn check(keys: &Keys<'_, '_>) -> Result<Option<Self>, ConfigError> {
        Ok(keys.get::<bool>("stdout")?.unwrap_or(true).then_some(Stdout))
    }

    fn describe(&self) -> String {
        "true".into()
    }

    /// A writer task, given 1 s at stop to write what it holds.
    async fn start(&self, start: &Start<'_>) -> Result<Running, DaemonError> {
        let hub = start.hub.clone();
        let stop = start.stop.clone();
        let task = match start.progress.and_then(ProgressFeed::stdout_above) {
            Some(out) => tokio::spawn(hub.serve_writer(out, stop)),
            None => match PipeStdout::open() {
                // A pipe (`fieldcal run | jq`, a supervisor's pipe): the
                // workers write each batch of lines to it themselves,
                // without blocking, and wait for room in it as for a
                // socket's; no thread is woken for a reading.
                Some(pipe) => tokio::spawn(hub.serve_writer(pipe, stop)),
                None => {
                    // A terminal, a file, a socket, a pipe that is
                    // stderr too: a thread of its own,
                    // writing each batch of lines with one system call
                    // (tokio's stdout hands every write to a thread of the
                    // blocking pool and waits for it: two wake-ups a batch).
                    let writing = hub.serve_writer(BlockingStdout, stop);
                    let runtime = tokio::runtime::Handle::current();
                    tokio::task::spawn_blocking(move || runtime.block_on(writing))
                }
            },
        };
        Ok(Running {
            finish: Some(task),
            ..Running::default()
        })
    }
}

/// Standard output when it is a pipe, written without blocking from the
/// task that polls it. Only a pipe: a terminal's mode is the shell's too,
/// and a file cannot wait for room. The non-blocking mode belongs to the
/// pipe's open description, which other holders of that end share: so
/// not when standard error is the same pipe (`2>&1`), whose log lines
/// would then meet a full pipe with EAGAIN. The mode found is put back
/// when the writer ends (a daemon killed outright cannot put it back; a
/// second program writing to the same pipe meanwhile sees it too).
struct PipeStdout {
    pipe: tokio::net::unix::pipe::Sender,
    /// The description's flags before: put back on drop.
    flags: libc::c_int,
}

/// The identity of a descriptor's file (device and inode), if it is a
/// pipe (a FIFO). Read through a duplicate, closed again here.
fn fifo_identity(fd: std::os::fd::BorrowedFd<'_>) -> Option<(u64, u64)> {
    use std::os::unix::fs::{FileTypeExt, MetadataExt};
    let meta = std::fs::File::from(fd.try_clone_to_owned().ok()?)
        .metadata()
        .ok()?;
    meta.file_type().is_fifo().then(|| (meta.dev(), meta.ino()))
}

impl PipeStdout {
    /// Standard output, if it is a pipe open for writing that standard
    /// error is not.
    fn open() -> Option<Self> {
        use std::os::fd::{AsFd, AsRawFd};
        let stdout = std::io::stdout();
        let out = fifo_identity(stdout.as_fd())?;
        if fifo_identity(std::io::stderr().as_fd()) == Some(out) {
            return None;
        }
        let fd = stdout.as_fd().try_clone_to_owned().ok()?;
        // SAFETY: fcntl on a descriptor owned here; no memory is touched.
        let flags = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_GETFL) };
        if flags < 0 {
            return None;
        }
        match tokio::net::unix::pipe::Sender::from_owned_fd(fd) {
            Ok(pipe) => Some(PipeStdout { pipe, flags }),
            Err(_) => {
                // It may have been made non-blocking before it failed:
                // the mode is put back through standard output itself
                // (the same description; the dup was closed with the
                // error).
                // SAFETY: as above, on standard output's own descriptor.
                unsafe { libc::fcntl(stdout.as_fd().as_raw_fd(), libc::F_SETFL, flags) };
                None
            }
        }
    }
}

impl Drop for PipeStdout {
    fn drop(&mut self) {
        use std::os::fd::AsRawFd;
        // SAFETY: fcntl on a descriptor this value owns; no memory is
        // touched. A failure leaves the mode as it is (nothing to undo).
        unsafe { libc::fcntl(self.pipe.as_raw_fd(), libc::F_SETFL, self.flags) };
    }
}

impl tokio::io::AsyncWrite for PipeStdout {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.pipe).poll_write(cx, buf)
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.pipe).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.pipe).poll_shutdown(cx)
    }
}

/// Standard output written straight from the thread that polls it: for a
/// writer with a thread of its own, which may block in a write (a socket
/// nobody reads, a terminal paused with Ctrl-S, a pipe shared with
/// standard error) without holding up the runtime's workers. Such a
/// thread is left behind at exit (`fieldcal run` shuts its runtime down
/// with a timeout); its writes never return Pending, so the close grace is
/// checked between them.
struct BlockingStdout;

impl tokio::io::AsyncWrite for BlockingStdout {
    fn poll_write(
        self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        loop {
            match out.write(buf) {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                written => return std::task::Poll::Ready(written),
            }
        }
    }

    fn poll_flush(
        self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        use std::io::Write;
        std::task::Poll::Ready(std::io::stdout().lock().flush())
    }

    fn poll_shutdown(
        self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        self.poll_flush(cx)
    }
}
