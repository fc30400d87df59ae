//! The TCP transport: subscribers accepted on the daemon's TCP port.

use tokio::sync::{mpsc, watch};

use super::access::Origin;
use super::commands::ClientCommand;
use super::hub::Hub;
use super::subscriber::ReplyTo;

impl Hub {
    /// Accepts TCP subscribers until `shutdown` turns true; each is served
    /// by its own task. Connections already open stay until [`Hub::close`].
    pub async fn serve_tcp(
        &self,
        listener: tokio::net::TcpListener,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
        shutdown: watch::Receiver<bool>,
    ) {
        let accept = || async {
            let (stream, addr) = listener.accept().await?;
            // Lines are batched by the writer; do not let Nagle delay them.
            let _ = stream.set_nodelay(true);
            Ok((stream, addr.to_string()))
        };
        self.accept_loop(Origin::Tcp, accept, commands, shutdown)
            .await;
    }
}
