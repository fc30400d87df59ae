//! `tcp = "IP:PORT"`: newline-delimited JSON over TCP, loopback unless
//! `tcp_public = true`.

use std::net::SocketAddr;

use super::{Kind, Running, Start};
use crate::daemon::config::{ConfigError, Keys};
use crate::daemon::run::DaemonError;

/// The TCP listener's address.
#[derive(Debug, Clone, PartialEq)]
pub struct Tcp {
    pub address: SocketAddr,
}

impl Kind for Tcp {
    const NAME: &'static str = "tcp";
    const KEYS: &'static [&'static str] = &["tcp", "tcp_public"];

    fn check(keys: &Keys<'_, '_>) -> Result<Option<Self>, ConfigError> {
        let address = keys.checker().listen_address(keys, "tcp", 2948)?;
        Ok(address.map(|address| Tcp { address }))
    }

    fn describe(&self) -> String {
        self.address.to_string()
    }

    async fn start(&self, start: &Start<'_>) -> Result<Running, DaemonError> {
        let listener = tokio::net::TcpListener::bind(self.address)
            .await
            .map_err(|source| DaemonError::Tcp {
                address: self.address.to_string(),
                source,
            })?;
        // The port bound, not 0 when the configuration let the system pick.
        let address = listener.local_addr().unwrap_or(self.address);
        tracing::info!(%address, "listening on TCP");
        tokio::spawn({
            let hub = start.hub.clone();
            let (commands, stop) = (start.commands.clone(), start.stop.clone());
            async move { hub.serve_tcp(listener, commands, stop).await }
        });
        Ok(Running::default())
    }
}
