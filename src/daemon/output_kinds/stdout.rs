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
            None => tokio::spawn(hub.serve_writer(tokio::io::stdout(), stop)),
        };
        Ok(Running {
            finish: Some(task),
            ..Running::default()
        })
    }
}
