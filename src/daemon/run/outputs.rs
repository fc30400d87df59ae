//! The daemon's outputs, one start function per kind, listed once in
//! [`Outputs::start`]: the TCP and Unix-socket listeners, the live page and
//! stdout. Each serves the hub's lines until the outputs are stopped, after
//! the last line is published.

use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::DaemonError;
use crate::daemon::config::Config;
use crate::daemon::progress::ProgressFeed;
use crate::daemon::publish::http::PageConfig;
use crate::daemon::publish::unix::BoundSocket;
use crate::daemon::publish::{ClientCommand, Hub, ReplyTo};

/// The commands subscribers send, and where their replies go.
pub(super) type Commands = mpsc::Sender<(ClientCommand, ReplyTo)>;

/// The started outputs, and what stops them.
pub(super) struct Outputs {
    /// The live page's configuration, which a reload updates.
    pub(super) page: Option<PageConfig>,
    /// The Unix socket bound at start, removed at stop.
    unix: Option<BoundSocket>,
    stdout: Option<tokio::task::JoinHandle<()>>,
    stop_tx: watch::Sender<bool>,
}

impl Outputs {
    /// Starts every configured output on `hub`, in order; their clients'
    /// commands go to `commands`. Listeners first: a bad address stops the
    /// start before any port opens.
    pub(super) async fn start(
        config: &Config,
        hub: &Hub,
        commands: Commands,
        progress: Option<&ProgressFeed>,
    ) -> Result<Outputs, DaemonError> {
        let (stop_tx, stop) = watch::channel(false);
        if let Some(address) = &config.outputs.tcp {
            start_tcp(*address, hub, &commands, &stop).await?;
        }
        let unix = match &config.outputs.unix {
            Some(path) => Some(start_unix(path, config, hub, &commands, &stop)?),
            None => None,
        };
        let page = match &config.outputs.http {
            Some(address) => Some(spawn_live_page(*address, hub, &commands, &stop, config).await?),
            None => None,
        };
        let stdout = config
            .outputs
            .stdout
            .then(|| start_stdout(hub, progress, &stop));
        Ok(Outputs {
            page,
            unix,
            stdout,
            stop_tx,
        })
    }

    /// Stops the outputs once the hub is closed: stdout is given 1 s to
    /// write what it holds, and the Unix socket bound at start is removed
    /// (a file put at the path since stays).
    pub(super) async fn stop(self) {
        let _ = self.stop_tx.send(true);
        if let Some(task) = self.stdout {
            let _ = tokio::time::timeout(Duration::from_secs(1), task).await;
        }
        if let Some(bound) = self.unix {
            bound.remove_if_ours();
        }
    }
}

/// Newline-delimited JSON over TCP.
async fn start_tcp(
    address: std::net::SocketAddr,
    hub: &Hub,
    commands: &Commands,
    stop: &watch::Receiver<bool>,
) -> Result<(), DaemonError> {
    let listener = tokio::net::TcpListener::bind(address)
        .await
        .map_err(|source| DaemonError::Tcp {
            address: address.to_string(),
            source,
        })?;
    // The port bound, not 0 when the configuration let the system pick.
    let address = listener.local_addr().unwrap_or(address);
    tracing::info!(%address, "listening on TCP");
    tokio::spawn({
        let hub = hub.clone();
        let (commands, stop) = (commands.clone(), stop.clone());
        async move { hub.serve_tcp(listener, commands, stop).await }
    });
    Ok(())
}

/// Newline-delimited JSON over a Unix socket, with the configured mode and
/// group.
fn start_unix(
    path: &std::path::Path,
    config: &Config,
    hub: &Hub,
    commands: &Commands,
    stop: &watch::Receiver<bool>,
) -> Result<BoundSocket, DaemonError> {
    let (listener, bound) = crate::daemon::publish::unix::bind_owned(
        path,
        config.outputs.unix_mode,
        config.outputs.unix_group,
        |p| tokio::net::UnixListener::bind(p),
    )?;
    tracing::info!(path = %path.display(), "listening on a Unix socket");
    tokio::spawn({
        let hub = hub.clone();
        let (commands, stop) = (commands.clone(), stop.clone());
        async move { hub.serve_unix(listener, commands, stop).await }
    });
    Ok(bound)
}

/// Newline-delimited JSON on standard output, above the progress lines
/// when a terminal shows them.
fn start_stdout(
    hub: &Hub,
    progress: Option<&ProgressFeed>,
    stop: &watch::Receiver<bool>,
) -> tokio::task::JoinHandle<()> {
    let hub = hub.clone();
    let stop = stop.clone();
    match progress.and_then(ProgressFeed::stdout_above) {
        Some(out) => tokio::spawn(hub.serve_writer(out, stop)),
        None => tokio::spawn(hub.serve_writer(tokio::io::stdout(), stop)),
    }
}

/// The hub's limits and rights from `[outputs]`: the subscriber maximum
/// checked against the descriptor limit (or derived from it), the command
/// and accept rates, who may recalibrate.
pub(super) fn subscriber_policy(
    config: &Config,
) -> Result<crate::daemon::publish::Policy, DaemonError> {
    use crate::daemon::publish::{
        Policy, check_max_subscribers, default_max_subscribers, descriptor_limit,
    };
    let nofile = descriptor_limit();
    let max_subscribers = match config.outputs.max_subscribers {
        Some(n) => check_max_subscribers(n, nofile).map_err(DaemonError::Limits)?,
        None => default_max_subscribers(nofile),
    };
    tracing::info!(
        max_subscribers,
        descriptor_limit = nofile,
        recalibrate_from = ?config.outputs.access.recalibrate_from,
        token = config.outputs.access.token.is_some(),
        "subscriber limits"
    );
    Ok(Policy {
        max_subscribers,
        access: config.outputs.access.clone(),
        ..Policy::default()
    })
}

/// Binds the live page's listener and serves it; the log names the bound
/// address (the port chosen when the configuration said port 0).
async fn spawn_live_page(
    address: std::net::SocketAddr,
    hub: &Hub,
    commands: &mpsc::Sender<(ClientCommand, ReplyTo)>,
    stop: &watch::Receiver<bool>,
    config: &Config,
) -> Result<crate::daemon::publish::http::PageConfig, DaemonError> {
    let listener = tokio::net::TcpListener::bind(address)
        .await
        .map_err(|source| DaemonError::Http {
            address: address.to_string(),
            source,
        })?;
    let bound = listener.local_addr().unwrap_or(address);
    hub.keep_for_replay(crate::daemon::publish::http::REPLAY_READINGS);
    let (router, page_config) =
        crate::daemon::publish::http::router_with_config(hub.clone(), commands.clone(), config);
    tracing::info!(address = %bound, "live page at http://{bound}/");
    tokio::spawn(crate::daemon::publish::http::serve(
        listener,
        router,
        stop.clone(),
    ));
    Ok(page_config)
}
