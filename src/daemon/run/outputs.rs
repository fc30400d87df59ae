//! The daemon's started outputs. Each kind's start function is in
//! [`crate::daemon::output_kinds`]; each serves the hub's lines until the
//! outputs are stopped, after the last line is published.

use std::time::Duration;

use tokio::sync::watch;

use super::DaemonError;
use crate::daemon::config::Config;
use crate::daemon::output_kinds::{Running, Start};
use crate::daemon::progress::ProgressFeed;
use crate::daemon::publish::Hub;
use crate::daemon::publish::http::PageConfig;

pub(super) use crate::daemon::output_kinds::Commands;

/// The started outputs, and what stops them.
pub(super) struct Outputs {
    /// The live page's configuration, which a reload updates.
    pub(super) page: Option<PageConfig>,
    running: Vec<Running>,
    stop_tx: watch::Sender<bool>,
}

impl Outputs {
    /// Starts every configured output on `hub`, in the kinds' order; their
    /// clients' commands go to `commands`.
    pub(super) async fn start(
        config: &Config,
        hub: &Hub,
        commands: Commands,
        progress: Option<&ProgressFeed>,
    ) -> Result<Outputs, DaemonError> {
        let (stop_tx, stop) = watch::channel(false);
        let start = Start {
            config,
            hub,
            commands: &commands,
            stop: &stop,
            progress,
        };
        // Built first, so an output that fails to start drops it, and the
        // ones started before are told to stop (see `Drop`).
        let mut outputs = Outputs {
            page: None,
            running: Vec::with_capacity(config.outputs.outputs.len()),
            stop_tx,
        };
        for output in &config.outputs.outputs {
            outputs.running.push(output.start(&start).await?);
        }
        outputs.page = outputs.running.iter_mut().find_map(|r| r.page.take());
        Ok(outputs)
    }

    /// Stops the outputs once the hub is closed: each writer is given 1 s
    /// to write what it holds, then what was undone at start is (the Unix
    /// socket bound at start is removed; a file put at the path since
    /// stays).
    pub(super) async fn stop(mut self) {
        let _ = self.stop_tx.send(true);
        let mut undo = Vec::new();
        for running in std::mem::take(&mut self.running) {
            if let Some(task) = running.finish {
                let _ = tokio::time::timeout(Duration::from_secs(1), task).await;
            }
            undo.extend(running.undo);
        }
        for undo in undo {
            undo();
        }
    }
}

impl Drop for Outputs {
    /// Outputs dropped unstopped (the daemon failed after they started, or
    /// its loop panicked) are told to stop all the same: the stdout writer
    /// may run on a thread of the blocking pool (stdout a terminal, a file
    /// or a socket), which the runtime waits for when it is dropped.
    fn drop(&mut self) {
        let _ = self.stop_tx.send(true);
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
