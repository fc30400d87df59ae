//! systemd notification (`Type=notify`): readiness, status text, watchdog
//! pings and stopping, as datagrams to `$NOTIFY_SOCKET`.
//!
//! The environment is read once, in [`Notifier::from_env`], and never
//! changed: tests run in parallel threads of one process, and removing a
//! variable while another thread reads the environment is undefined
//! behaviour. Sending failures are logged at debug and otherwise ignored:
//! the daemon's work matters more than telling systemd about it, and when
//! systemd is gone there is no one to tell.

use std::ffi::OsString;
use std::io;
use std::os::unix::net::UnixDatagram;
use std::time::Duration;

use sd_notify::NotifyState;

/// Where notifications go, if anywhere, and the watchdog period.
#[derive(Debug, Clone, Default)]
pub struct Notifier {
    /// `$NOTIFY_SOCKET`: a path, or `@name` for an abstract socket.
    socket: Option<OsString>,
    /// `$WATCHDOG_USEC`, when the watchdog is meant for this process.
    watchdog: Option<Duration>,
}

impl Notifier {
    /// Reads `NOTIFY_SOCKET`, `WATCHDOG_USEC` and `WATCHDOG_PID` (the
    /// watchdog counts only when `WATCHDOG_PID` is unset or this process).
    /// Not under systemd, every method is a no-op.
    pub fn from_env() -> Notifier {
        Notifier {
            socket: std::env::var_os("NOTIFY_SOCKET").filter(|s| !s.is_empty()),
            watchdog: sd_notify::watchdog_enabled().filter(|d| !d.is_zero()),
        }
    }

    /// A notifier sending to `socket`, with a watchdog of `watchdog_usec`
    /// microseconds: what [`Notifier::from_env`] builds, without touching the
    /// environment (for tests, and for callers that read it themselves).
    pub fn with_socket(socket: impl Into<OsString>, watchdog_usec: Option<u64>) -> Notifier {
        Notifier {
            socket: Some(socket.into()),
            watchdog: watchdog_usec
                .filter(|&us| us > 0)
                .map(Duration::from_micros),
        }
    }

    /// A notifier that sends nothing.
    pub fn disabled() -> Notifier {
        Notifier::default()
    }

    /// Whether there is a socket to notify (running under systemd).
    pub fn is_enabled(&self) -> bool {
        self.socket.is_some()
    }

    /// `READY=1`: start-up is over (configuration loaded, state read,
    /// outputs listening).
    pub fn ready(&self) {
        self.send(&[NotifyState::Ready]);
    }

    /// `STATUS=...`: one line for `systemctl status`. Line breaks would end
    /// the field early, so they become spaces.
    pub fn status(&self, text: &str) {
        let line: String = text
            .chars()
            .map(|c| if c == '\n' || c == '\r' { ' ' } else { c })
            .collect();
        self.send(&[NotifyState::Status(&line)]);
    }

    /// How often to [`Notifier::ping`]: half of `WATCHDOG_USEC`, as
    /// systemd recommends, so one late ping does not get the service killed.
    /// `None` when no watchdog is set.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog.map(|d| d / 2)
    }

    /// `WATCHDOG=1`: the main loop is alive. (Sent even with no watchdog
    /// set: systemd ignores it then, and callers need not check.)
    pub fn ping(&self) {
        self.send(&[NotifyState::Watchdog]);
    }

    /// `RELOADING=1` with `MONOTONIC_USEC=` (CLOCK_MONOTONIC, as systemd
    /// requires with it): the configuration is being reloaded; a
    /// [`Notifier::ready`] follows when it is over, applied or refused.
    pub fn reloading(&self) {
        match NotifyState::monotonic_usec_now() {
            Ok(now) => self.send(&[NotifyState::Reloading, now]),
            Err(_) => self.send(&[NotifyState::Reloading]),
        }
    }

    /// `STOPPING=1`: shutting down on request, not crashing.
    pub fn stopping(&self) {
        self.send(&[NotifyState::Stopping]);
    }

    fn send(&self, states: &[NotifyState]) {
        let Some(socket) = &self.socket else {
            return;
        };
        let mut message = String::new();
        for state in states {
            message.push_str(&state.to_string());
            message.push('\n');
        }
        if let Err(e) = send_datagram(socket, message.as_bytes()) {
            tracing::debug!(
                socket = %socket.to_string_lossy(),
                error = %e,
                "could not notify systemd: {}",
                message.trim_end()
            );
        }
    }
}

/// Sends one datagram to a path socket, or to an abstract one (`@name`,
/// which systemd uses for user services on some systems).
fn send_datagram(socket: &OsString, bytes: &[u8]) -> io::Result<()> {
    let sock = UnixDatagram::unbound()?;
    let raw = socket.as_encoded_bytes();
    if let Some(name) = raw.strip_prefix(b"@") {
        connect_abstract(&sock, name)?;
    } else {
        sock.connect(socket)?;
    }
    let sent = sock.send(bytes)?;
    if sent != bytes.len() {
        return Err(io::Error::new(
            io::ErrorKind::WriteZero,
            "datagram cut short",
        ));
    }
    Ok(())
}

#[cfg(target_os = "linux")]
fn connect_abstract(sock: &UnixDatagram, name: &[u8]) -> io::Result<()> {
    use std::os::linux::net::SocketAddrExt;
    let addr = std::os::unix::net::SocketAddr::from_abstract_name(name)?;
    sock.connect_addr(&addr)
}

#[cfg(not(target_os = "linux"))]
fn connect_abstract(_sock: &UnixDatagram, _name: &[u8]) -> io::Result<()> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "abstract sockets exist only on Linux",
    ))
}
