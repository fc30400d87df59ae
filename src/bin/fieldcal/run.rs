//! `fieldcal run --config FILE`: the daemon.

use anyhow::{Context, Result};
use tokio::sync::watch;

use fieldcal::daemon::config::{LogFormat, load};

use crate::RunArgs;

pub fn run(args: RunArgs) -> Result<()> {
    // A bad configuration starts nothing: no port is opened, no socket bound.
    let config = load(&args.config)?;
    crate::init_logging(config.daemon.log_format == LogFormat::Json);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the runtime")?;
    runtime.block_on(async {
        let (stop_tx, stop_rx) = watch::channel(false);
        tokio::spawn(crate::signals::forward_signals(stop_tx));
        fieldcal::daemon::run::run(config, stop_rx).await
    })?;
    Ok(())
}
