//! A connected subscriber's session: the writer that drains its queue into
//! the stream, the reader that takes its command lines, the deadline that
//! cuts off a client that does not read, and the accept loop the socket
//! listeners share.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::access::{Access, Bucket, Origin};
use super::commands::{
    ClientCommand, CommandError, LineSplitter, LineTooLong, MAX_COMMAND_LEN, error_line,
    parse_request,
};
use super::hub::{Hub, SubscribeError};
use super::queue::{Lane, QueueState};
use super::subscriber::{ReplyTo, Subscriber};

/// Bytes a writer gathers into one write: few syscalls, bounded memory.
const MAX_BATCH_BYTES: usize = 64 * 1024;
/// Pause after a failed accept (e.g. out of file descriptors) so the loop
/// does not spin.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);

/// Above this many bytes an idle writer's batch buffer is freed.
const SHRINK_BUF_ABOVE: usize = 16 * 1024;
/// How long a refused connection's one ERROR line may take to write: it
/// goes into an empty socket buffer, so this only bounds a broken peer.
const REFUSE_WRITE: Duration = Duration::from_millis(100);

impl Hub {
    /// Serves one connected stream (TCP or Unix) until it closes: writes
    /// the hub's lines, reads command lines and forwards them with a
    /// [`ReplyTo`]. Ends when the client hangs up (EOF on its side counts:
    /// as in gpsd), on an I/O error, on eviction, or after [`Hub::close`].
    /// The subscriber came through `origin`, which decides what it may
    /// do. At
    /// [`Policy::max_subscribers`](super::Policy::max_subscribers) it is
    /// sent one ERROR line and closed.
    pub async fn serve_connection_from<S>(
        &self,
        mut stream: S,
        peer: String,
        origin: Origin,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
    ) where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let reg = match self.register(peer, Some(origin), false) {
            Ok(reg) => reg,
            Err(SubscribeError::Closed) => {
                tracing::debug!("subscriber refused: the hub is closed");
                return;
            }
            Err(e @ SubscribeError::Full { .. }) => {
                refuse(&mut stream, &e).await;
                return;
            }
        };
        let sub = &reg.sub;
        tracing::debug!(id = sub.id, peer = %sub.peer, "subscriber connected");
        let (mut rd, mut wr) = tokio::io::split(stream);
        let mut bucket = Bucket::new(self.inner.policy.commands);
        let access = &self.inner.policy.access;
        let end = tokio::select! {
            end = write_loop(sub, &mut wr) => end,
            end = read_loop(sub, &mut rd, &commands, origin, access, &mut bucket) => end,
        };
        log_end(sub, end);
    }

    /// The accept loop both listeners share: each connection gets its own
    /// task; a failed accept (out of descriptors, say) is retried after a
    /// pause instead of spinning.
    pub(super) async fn accept_loop<S, F, Fut>(
        &self,
        origin: Origin,
        mut accept: F,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
        mut shutdown: watch::Receiver<bool>,
    ) where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
        F: FnMut() -> Fut,
        Fut: Future<Output = std::io::Result<(S, String)>>,
    {
        let kind = match origin {
            Origin::Tcp => "TCP",
            Origin::Unix => "Unix-socket",
            Origin::Http => "HTTP",
        };
        let mut bucket = Bucket::new(self.inner.policy.accepts);
        loop {
            // Over the accept budget, stop accepting for a moment: the
            // kernel's backlog holds (or refuses) the rest.
            if let Some(wait) = bucket.take(Instant::now()) {
                tokio::select! {
                    () = tokio::time::sleep(wait) => continue,
                    () = turned_true(&mut shutdown) => break,
                }
            }
            let accepted = tokio::select! {
                accepted = accept() => accepted,
                () = turned_true(&mut shutdown) => break,
            };
            match accepted {
                Ok((mut stream, peer)) => {
                    // Refused here, not in a task: a refused connection
                    // holds its descriptor only for this one write.
                    if self.is_full() {
                        let max = self.inner.policy.max_subscribers;
                        refuse(&mut stream, &SubscribeError::Full { max }).await;
                        self.inner.counters.refused.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    let hub = self.clone();
                    let commands = commands.clone();
                    tokio::spawn(async move {
                        hub.serve_connection_from(stream, peer, origin, commands)
                            .await;
                    });
                }
                Err(e) => {
                    tracing::warn!(error = %e, "accepting a {kind} subscriber failed; retrying in {ACCEPT_BACKOFF:?}");
                    tokio::time::sleep(ACCEPT_BACKOFF).await;
                }
            }
        }
    }
}

/// Sends a refused connection its one ERROR line and closes it.
async fn refuse<S: AsyncWrite + Unpin>(stream: &mut S, why: &SubscribeError) {
    tracing::debug!(%why, "subscriber refused");
    let mut line = error_line(&why.to_string()).to_string();
    line.push('\n');
    let _ = tokio::time::timeout(REFUSE_WRITE, async {
        stream.write_all(line.as_bytes()).await?;
        stream.shutdown().await
    })
    .await;
}

/// Why a subscriber's session ended; logged only.
#[derive(Debug, thiserror::Error)]
pub(super) enum SessionEnd {
    #[error("closed by the hub")]
    Closed,
    #[error("the client hung up")]
    Hangup,
    #[error("evicted: its control queue overflowed")]
    Evicted,
    #[error("cut off: it did not take its lines before the deadline")]
    TimedOut,
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
}

pub(super) fn log_end(sub: &Subscriber, end: Result<(), SessionEnd>) {
    let reason = match end {
        Ok(()) => SessionEnd::Closed,
        Err(e) => e,
    };
    tracing::debug!(id = sub.id, peer = %sub.peer, %reason, "subscriber left");
}

/// Drains the subscriber's queue into `out` until it is closed (Ok) or
/// evicted, or `out` fails.
pub(super) async fn write_loop<W: AsyncWrite + Unpin>(
    sub: &Subscriber,
    out: &mut W,
) -> Result<(), SessionEnd> {
    let mut deadline = sub.deadline.subscribe();
    let mut buf: Vec<u8> = Vec::new();
    loop {
        buf.clear();
        let state = {
            let mut q = sub.queue();
            while buf.len() < MAX_BATCH_BYTES {
                let Some(line) = q.pop() else { break };
                buf.extend_from_slice(line.as_bytes());
                buf.push(b'\n');
            }
            if buf.is_empty() {
                q.shrink_idle();
            }
            q.state
        };
        if state == QueueState::Evicted {
            return Err(SessionEnd::Evicted);
        }
        if buf.is_empty() {
            if buf.capacity() > SHRINK_BUF_ABOVE {
                buf = Vec::new();
            }
            if state == QueueState::Closing {
                by_deadline(&mut deadline, out.shutdown()).await??;
                return Ok(());
            }
            sub.wake.notified().await;
            continue;
        }
        by_deadline(&mut deadline, async {
            out.write_all(&buf).await?;
            out.flush().await
        })
        .await??;
    }
}

/// Reads command lines and forwards them until the client hangs up.
///
/// Every line (a bad one too) takes a token from `bucket`; when it is empty
/// nothing more is read until one is there, so a flood is held back by TCP
/// itself. A `recalibrate` not allowed by `access` from `origin` is
/// answered with an ERROR.
async fn read_loop<R: AsyncRead + Unpin>(
    sub: &Arc<Subscriber>,
    rd: &mut R,
    commands: &mpsc::Sender<(ClientCommand, ReplyTo)>,
    origin: Origin,
    access: &Access,
    bucket: &mut Bucket,
) -> Result<(), SessionEnd> {
    let mut lines = LineSplitter::new(MAX_COMMAND_LEN);
    let mut chunk = vec![0u8; 4096];
    loop {
        let n = rd.read(&mut chunk).await?;
        if n == 0 {
            // A half line left in `lines` is dropped: its sender is gone.
            return Err(SessionEnd::Hangup);
        }
        lines.feed(&chunk[..n]);
        while let Some(line) = lines.next_line() {
            bucket.wait().await;
            let parsed = match line {
                Ok(line) if line.iter().all(u8::is_ascii_whitespace) => continue,
                Ok(line) => parse_request(&line).and_then(|r| match &r.command {
                    ClientCommand::Recalibrate { .. } | ClientCommand::Rollback { .. } => access
                        .check_recalibrate(origin, r.token.as_deref())
                        .map(|()| r.command)
                        .map_err(CommandError::Refused),
                    ClientCommand::Status => Ok(r.command),
                }),
                Err(LineTooLong { limit }) => Err(CommandError::TooLong { limit }),
            };
            match parsed {
                Ok(command) => {
                    let reply = ReplyTo::to(sub);
                    if commands.send((command, reply)).await.is_err() {
                        sub.push(
                            Lane::Control,
                            error_line("the daemon is not taking commands now (shutting down)"),
                        );
                    }
                }
                Err(e) => sub.push(Lane::Control, error_line(&e.to_string())),
            }
        }
    }
}

/// Runs `fut` unless the subscriber's deadline passes first. A deadline
/// already past ends the session before `fut` starts: a writer that never
/// waits (standard output on a thread of its own) would otherwise never
/// let the deadline be seen.
async fn by_deadline<F: Future>(
    deadline: &mut watch::Receiver<Option<Instant>>,
    fut: F,
) -> Result<F::Output, SessionEnd> {
    if deadline.borrow().is_some_and(|d| d <= Instant::now()) {
        return Err(SessionEnd::TimedOut);
    }
    tokio::select! {
        biased;
        out = fut => Ok(out),
        () = deadline_passed(deadline) => Err(SessionEnd::TimedOut),
    }
}

async fn deadline_passed(rx: &mut watch::Receiver<Option<Instant>>) {
    loop {
        let deadline = *rx.borrow_and_update();
        if let Some(deadline) = deadline {
            tokio::time::sleep_until(deadline).await;
            return;
        }
        if rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// Resolves once the flag is true; never, if its sender is gone while false.
pub(super) async fn turned_true(rx: &mut watch::Receiver<bool>) {
    loop {
        if *rx.borrow_and_update() {
            return;
        }
        if rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}
