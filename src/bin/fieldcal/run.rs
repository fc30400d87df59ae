//! `fieldcal run --config FILE`: the daemon.

use std::io::IsTerminal as _;

use anyhow::{Context, Result};
use tokio::sync::{mpsc, watch};

use fieldcal::daemon::config::{LogFormat, load};
use fieldcal::daemon::progress::{Live, ProgressFeed, ProgressMode, draw_target};
use fieldcal::daemon::run::RunOptions;

use crate::RunArgs;

pub fn run(args: RunArgs) -> Result<()> {
    // Until the reload handler is installed (inside the runtime, below), a
    // SIGHUP is ignored rather than killing a daemon that is starting.
    #[cfg(unix)]
    // SAFETY: signal(2) with SIG_IGN, before any other thread exists.
    unsafe {
        libc::signal(libc::SIGHUP, libc::SIG_IGN);
    }
    // A bad configuration starts nothing: no port is opened, no socket bound.
    let config = load(&args.config)?;
    let mode: ProgressMode = args.progress.parse().map_err(anyhow::Error::msg)?;
    let live = mode.live(std::io::stderr().is_terminal());
    let multi = live.then(|| {
        indicatif::MultiProgress::with_draw_target(draw_target(mode == ProgressMode::Always))
    });
    crate::init_logging_to(config.daemon.log_format == LogFormat::Json, multi.clone());
    // Without live lines, the milestones go to the log.
    let feed = ProgressFeed::new(!live);
    // Published lines on the same terminal go above the live lines.
    let feed = match &multi {
        Some(multi) if std::io::stdout().is_terminal() => feed.with_stdout_above(multi.clone()),
        _ => feed,
    };
    let display = match multi {
        Some(multi) => {
            Some(Live::spawn(feed.clone(), multi).context("cannot start the progress display")?)
        }
        None => None,
    };
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the runtime")?;
    // The daemon's loop is a task on the workers, not the main thread's:
    // a reading a source task sends is taken up on the same worker next
    // (its LIFO slot), with no wake-up of another thread in between. The
    // price: a task the loop wakes (a subscriber's writer) waits for the
    // loop's turn to end, which a fit in it lengthens (about 0.1 ms for a
    // turn, 1.3 ms for a sphere, once a rotation), as every reading that
    // arrives during the fit waits for it anyway.
    let daemon = async {
        let (stop_tx, stop_rx) = watch::channel(false);
        // SIGHUP reloads the configuration: the library reads the file again.
        let (reload_tx, reload_rx) = mpsc::channel(1);
        let signals = crate::signals::forward_daemon_signals(stop_tx, reload_tx)
            .context("cannot install the signal handlers")?;
        tokio::spawn(signals);
        let options = RunOptions {
            progress: Some(feed),
            reload: Some(reload_rx),
        };
        fieldcal::daemon::run::run_with(config, stop_rx, options)
            .await
            .map_err(anyhow::Error::from)
    };
    let joined = runtime.block_on(runtime.spawn(daemon));
    // A writer thread stuck in a write nobody reads (a socket, a terminal
    // or a pipe shared with stderr; its 1 s
    // grace is over) does not keep the process from ending, even when the
    // loop panicked (its panic goes on once the runtime is down).
    runtime.shutdown_timeout(std::time::Duration::from_secs(1));
    if let Some(display) = display {
        display.finish();
    }
    match joined {
        Ok(result) => result,
        Err(e) if e.is_panic() => std::panic::resume_unwind(e.into_panic()),
        Err(e) => Err(anyhow::anyhow!("the daemon's task ended early: {e}")),
    }
}
