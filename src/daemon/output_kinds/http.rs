//! `http = "IP:PORT"`: the live page, loopback unless `http_public = true`.

use std::net::SocketAddr;

use super::{Kind, Running, Start};
use crate::daemon::config::{ConfigError, Keys};
use crate::daemon::publish::http::{REPLAY_READINGS, router_with_config, serve};
use crate::daemon::run::DaemonError;

/// The live page's listener address, and the names it answers to beside
/// IP addresses, `localhost` and this machine's name (`http_hosts`).
#[derive(Debug, Clone, PartialEq)]
pub struct Http {
    pub address: SocketAddr,
    pub hosts: Vec<String>,
}

impl Kind for Http {
    const NAME: &'static str = "http";
    const KEYS: &'static [&'static str] = &["http", "http_public", "http_hosts"];

    fn check(keys: &Keys<'_, '_>) -> Result<Option<Self>, ConfigError> {
        let address = keys.checker().listen_address(keys, "http", 8080)?;
        let hosts = keys.get::<Vec<String>>("http_hosts")?.unwrap_or_default();
        for name in &hosts {
            let plain = !name.is_empty()
                && name
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'.');
            if !plain {
                return Err(keys.error(
                    "http_hosts",
                    format!(
                        "{name:?} is not a host name: give names as a browser's address bar has them, without a port or scheme (\"robot.lan\")"
                    ),
                ));
            }
        }
        Ok(address.map(|address| Http { address, hosts }))
    }

    fn describe(&self) -> String {
        self.address.to_string()
    }

    /// Binds the listener and serves the page; the log names the bound
    /// address (the port chosen when the configuration said port 0).
    async fn start(&self, start: &Start<'_>) -> Result<Running, DaemonError> {
        let listener = tokio::net::TcpListener::bind(self.address)
            .await
            .map_err(|source| DaemonError::Http {
                address: self.address.to_string(),
                source,
            })?;
        let bound = listener.local_addr().unwrap_or(self.address);
        start.hub.keep_for_replay(REPLAY_READINGS);
        let (router, page) =
            router_with_config(start.hub.clone(), start.commands.clone(), start.config);
        tracing::info!(address = %bound, "live page at http://{bound}/");
        tokio::spawn(serve(listener, router, start.stop.clone()));
        Ok(Running {
            page: Some(page),
            ..Running::default()
        })
    }
}
