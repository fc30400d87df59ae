//! The writer transport: the hub's lines to stdout (or any writer), as a
//! subscriber that is never refused nor evicted.

use tokio::io::AsyncWrite;
use tokio::sync::watch;
use tokio::time::Instant;

use super::hub::{CLOSE_GRACE, Hub};
use super::session::{log_end, turned_true, write_loop};

impl Hub {
    /// Writes the hub's lines to `out` (stdout, or any writer) as a
    /// subscriber like the others. When `shutdown` turns true it flushes
    /// what is queued (for at most [`CLOSE_GRACE`]) and returns.
    pub fn serve_writer<W>(
        &self,
        mut out: W,
        mut shutdown: watch::Receiver<bool>,
    ) -> impl std::future::Future<Output = ()> + Send + 'static
    where
        W: AsyncWrite + Unpin + Send + 'static,
    {
        // Registered now, not when the future first runs: lines published
        // between spawning the writer and its first poll reach it too.
        let reg = self.register("writer".to_owned(), None, false);
        async move {
            let Ok(reg) = reg else {
                return;
            };
            let sub = &reg.sub;
            let writing = write_loop(sub, &mut out);
            tokio::pin!(writing);
            let end = tokio::select! {
                end = &mut writing => end,
                () = turned_true(&mut shutdown) => {
                    sub.begin_close(Instant::now() + CLOSE_GRACE);
                    writing.await
                }
            };
            log_end(sub, end);
        }
    }
}
