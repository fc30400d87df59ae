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
                    // A terminal, a file, a socket: a thread of its own,
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
/// task that polls it. Only a pipe: its non-blocking mode is the pipe's
/// own (a terminal's would be the shell's too, and a file cannot wait for
/// room). The mode is set back to blocking when the writer ends, for
/// whatever writes to standard output after it.
struct PipeStdout(tokio::net::unix::pipe::Sender);

impl PipeStdout {
    /// Standard output, if it is a pipe open for writing.
    fn open() -> Option<Self> {
        use std::os::fd::AsFd;
        let fd = std::io::stdout().as_fd().try_clone_to_owned().ok()?;
        tokio::net::unix::pipe::Sender::from_owned_fd(fd)
            .ok()
            .map(PipeStdout)
    }
}

impl Drop for PipeStdout {
    fn drop(&mut self) {
        use std::os::fd::AsRawFd;
        let fd = self.0.as_raw_fd();
        // SAFETY: fcntl on a descriptor this value owns; no memory is
        // touched. A failure leaves the mode as it is (nothing to undo).
        unsafe {
            let flags = libc::fcntl(fd, libc::F_GETFL);
            if flags >= 0 {
                libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK);
            }
        }
    }
}

impl tokio::io::AsyncWrite for PipeStdout {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.0).poll_write(cx, buf)
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_shutdown(cx)
    }
}

/// Standard output written straight from the thread that polls it: for a
/// writer with a thread of its own, which may block in a write (a pipe
/// nobody reads) without holding up the runtime's workers. Such a thread
/// is left behind at exit (`fieldcal run` shuts its runtime down with a
/// timeout); its writes never wait, so the close grace is checked between
/// them.
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
