//! Signals: Ctrl-C and SIGTERM stop the work in hand cleanly; under
//! `fieldcal run`, SIGHUP asks the daemon to reload its configuration.

use std::future::Future;
use std::pin::Pin;

use tokio::sync::{mpsc, watch};

/// Turns Ctrl-C and SIGTERM into a stop request.
pub async fn forward_signals(stop: watch::Sender<bool>) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
    let _ = stop.send(true);
}

/// For the daemon: Ctrl-C and SIGTERM into a stop request, SIGHUP into a
/// reload request on `reload` (one waiting request stands for any number of
/// signals). The handlers are installed before this returns (call it
/// inside the runtime, before the daemon says it is ready); the future it
/// returns forwards them. SIGHUP never kills: once installed its handler
/// stays for the life of the process, so one during the shutdown is
/// ignored.
pub fn forward_daemon_signals(
    stop: watch::Sender<bool>,
    reload: mpsc::Sender<()>,
) -> std::io::Result<Pin<Box<dyn Future<Output = ()> + Send>>> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let mut interrupt = signal(SignalKind::interrupt())?;
        let mut term = signal(SignalKind::terminate())?;
        let mut hangup = signal(SignalKind::hangup())?;
        Ok(Box::pin(async move {
            loop {
                tokio::select! {
                    _ = interrupt.recv() => break,
                    _ = term.recv() => break,
                    _ = hangup.recv() => {
                        // Full: a reload is already asked for, and it
                        // reads the file as it is now.
                        let _ = reload.try_send(());
                    }
                }
            }
            let _ = stop.send(true);
        }))
    }
    #[cfg(not(unix))]
    {
        drop(reload);
        Ok(Box::pin(forward_signals(stop)))
    }
}
