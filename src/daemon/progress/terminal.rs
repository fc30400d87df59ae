//! The terminal side of the progress display: the live lines drawn with
//! indicatif from their own thread ([`Live`]), the draw target for
//! `--progress always`, and the writers that keep stdout's lines
//! ([`StdoutAbove`]) and log lines ([`LogWriter`]) from garbling them.

use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{ProgressFeed, REDRAW};

/// [`REDRAW`] from its own thread (a slow terminal never holds up the
/// daemon's loop).
pub struct Live {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Live {
    /// Draws `feed`'s lines into `multi` until [`Live::finish`].
    pub fn spawn(feed: ProgressFeed, multi: indicatif::MultiProgress) -> std::io::Result<Live> {
        let stop = Arc::new(AtomicBool::new(false));
        let thread = std::thread::Builder::new().name("progress".into()).spawn({
            let stop = stop.clone();
            move || {
                let mut bars: Vec<indicatif::ProgressBar> = Vec::new();
                loop {
                    let last = stop.load(Ordering::Acquire);
                    draw(&feed, &multi, &mut bars);
                    if last {
                        break;
                    }
                    std::thread::park_timeout(REDRAW);
                }
                // The last state stays on the screen.
                for bar in &bars {
                    bar.finish();
                }
            }
        })?;
        Ok(Live {
            stop,
            thread: Some(thread),
        })
    }

    /// Draws the last state once more and leaves it on the screen.
    pub fn finish(mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            thread.thread().unpark();
            let _ = thread.join();
        }
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            thread.thread().unpark();
            let _ = thread.join();
        }
    }
}

fn draw(
    feed: &ProgressFeed,
    multi: &indicatif::MultiProgress,
    bars: &mut Vec<indicatif::ProgressBar>,
) {
    let lines = feed.lines();
    while bars.len() < lines.len() {
        let style = indicatif::ProgressStyle::with_template("{msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner());
        bars.push(multi.add(indicatif::ProgressBar::new(0).with_style(style)));
    }
    for (bar, line) in bars.iter().zip(lines) {
        bar.set_message(line);
    }
}

/// The draw target for live lines: stderr, drawn even when it is not a
/// terminal if `force` (as `--progress always` asks).
pub fn draw_target(force: bool) -> indicatif::ProgressDrawTarget {
    use std::io::IsTerminal;
    if force && !std::io::stderr().is_terminal() {
        indicatif::ProgressDrawTarget::term_like_with_hz(Box::new(AnsiStderr::from_env()), 10)
    } else {
        indicatif::ProgressDrawTarget::stderr_with_hz(10)
    }
}

/// stderr driven with ANSI cursor moves, for `--progress always` when
/// stderr is not a terminal (indicatif hides its own stderr target then).
#[derive(Debug)]
struct AnsiStderr {
    width: u16,
}

impl AnsiStderr {
    /// Width from `COLUMNS`, else 80.
    fn from_env() -> Self {
        let width = std::env::var("COLUMNS")
            .ok()
            .and_then(|c| c.trim().parse::<u16>().ok())
            .filter(|&w| w >= 20)
            .unwrap_or(80);
        AnsiStderr { width }
    }

    fn out(&self, text: &str) -> std::io::Result<()> {
        std::io::stderr().lock().write_all(text.as_bytes())
    }
}

impl indicatif::TermLike for AnsiStderr {
    fn width(&self) -> u16 {
        self.width
    }
    fn move_cursor_up(&self, n: usize) -> std::io::Result<()> {
        if n > 0 {
            self.out(&format!("\x1b[{n}A"))
        } else {
            Ok(())
        }
    }
    fn move_cursor_down(&self, n: usize) -> std::io::Result<()> {
        if n > 0 {
            self.out(&format!("\x1b[{n}B"))
        } else {
            Ok(())
        }
    }
    fn move_cursor_right(&self, n: usize) -> std::io::Result<()> {
        if n > 0 {
            self.out(&format!("\x1b[{n}C"))
        } else {
            Ok(())
        }
    }
    fn move_cursor_left(&self, n: usize) -> std::io::Result<()> {
        if n > 0 {
            self.out(&format!("\x1b[{n}D"))
        } else {
            Ok(())
        }
    }
    fn write_line(&self, s: &str) -> std::io::Result<()> {
        self.out(&format!("{s}\n"))
    }
    fn write_str(&self, s: &str) -> std::io::Result<()> {
        self.out(s)
    }
    fn clear_line(&self) -> std::io::Result<()> {
        self.out("\r\x1b[2K")
    }
    fn flush(&self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// stdout, written above the live lines (indicatif's `suspend`). Only for
/// a stdout that is a terminal, which takes a write at once: each batch of
/// lines is written in one blocking call.
pub struct StdoutAbove {
    pub(super) multi: indicatif::MultiProgress,
}

impl tokio::io::AsyncWrite for StdoutAbove {
    fn poll_write(
        self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        let written = self.multi.suspend(|| {
            let mut out = std::io::stdout().lock();
            out.write_all(buf)?;
            out.flush()
        });
        std::task::Poll::Ready(written.map(|()| buf.len()))
    }

    fn poll_flush(
        self: std::pin::Pin<&mut Self>,
        _: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::task::Poll::Ready(std::io::stdout().flush())
    }

    fn poll_shutdown(
        self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        self.poll_flush(cx)
    }
}

/// A tracing writer that prints above the live lines (indicatif's
/// `suspend`), so a log line never garbles them.
#[derive(Clone)]
pub struct LogWriter {
    multi: indicatif::MultiProgress,
}

impl LogWriter {
    pub fn new(multi: indicatif::MultiProgress) -> Self {
        LogWriter { multi }
    }
}

impl Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.multi
            .suspend(|| std::io::stderr().lock().write_all(buf))?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for LogWriter {
    type Writer = LogWriter;
    fn make_writer(&'a self) -> LogWriter {
        self.clone()
    }
}
