//! Who may connect and what they may do: the token buckets that pace
//! accepts and commands, the listener a subscriber came through
//! ([`Origin`]), the token and the [`Access`] rules for `recalibrate`, the
//! hub's [`Policy`], and the subscriber limit derived from the process's
//! descriptor limit.

use std::fmt;
use std::sync::{Arc, RwLock};
use std::time::Duration;

use serde::Serialize;
use tokio::time::Instant;

/// Commands a subscriber may send: 10 a second, in bursts of 20. A person
/// at a terminal or a robot's supervisor sends a few a minute (a status
/// poll, a recalibrate after a mount change); a status poll at 10 Hz is
/// already more than any display needs. The bound keeps one client's flood
/// to a few hundred microseconds of the daemon's loop a second.
pub const COMMAND_RATE: Rate = Rate {
    per_s: 10.0,
    burst: 20.0,
};
/// Connections accepted per listener: 100 a second, in bursts of 64 (the
/// default [`Policy::max_subscribers`], so a whole crowd reconnecting after
/// a restart is taken at once). An accept, register and close costs tens
/// of microseconds, so a connect/close flood costs the daemon well under a
/// tenth of a core; the rest waits in (or is refused by) the kernel's
/// backlog.
pub const ACCEPT_RATE: Rate = Rate {
    per_s: 100.0,
    burst: 64.0,
};
/// The most subscribers the daemon allows by default, when the descriptor
/// limit leaves room for more: gpsd's default is 64 clients as well
/// (MAX_CLIENTS), and each one costs a queue of up to `queue` lines.
pub const DEFAULT_MAX_SUBSCRIBERS: usize = 64;
/// Descriptors kept for the daemon itself out of RLIMIT_NOFILE, never given
/// to subscribers: stdin/stdout/stderr (3), the runtime's epoll and waker
/// (2), the signal pipe (2), three listeners (3), the sources' ports or
/// files (1 to 2 each, up to 8 sources: 12), the state writer (the
/// temporary file, the directory it fsyncs, a stored file read at start:
/// 3), the systemd notify socket (1), 6 for the live page's short
/// requests and a connection being refused, and 6 for new page
/// connections waiting for their first bytes while the page is full
/// ([`crate::daemon::http::WAITING`]).
pub const RESERVED_DESCRIPTORS: u64 = 38;

/// A token bucket's rate: `per_s` tokens a second, holding at most `burst`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rate {
    pub per_s: f64,
    pub burst: f64,
}

/// A token bucket; `take` says how long to wait when it is empty.
#[derive(Debug)]
pub(super) struct Bucket {
    rate: Rate,
    tokens: f64,
    last: Instant,
}

impl Bucket {
    pub(super) fn new(rate: Rate) -> Bucket {
        Bucket {
            rate,
            tokens: rate.burst.max(1.0),
            last: Instant::now(),
        }
    }

    /// Takes a token, or says how long until one is there.
    pub(super) fn take(&mut self, now: Instant) -> Option<Duration> {
        let per_s = self.rate.per_s.max(1e-3);
        let elapsed = now.saturating_duration_since(self.last).as_secs_f64();
        self.last = now;
        self.tokens = (self.tokens + elapsed * per_s).min(self.rate.burst.max(1.0));
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            None
        } else {
            Some(Duration::from_secs_f64((1.0 - self.tokens) / per_s))
        }
    }

    /// Waits for a token.
    pub(super) async fn wait(&mut self) {
        while let Some(wait) = self.take(Instant::now()) {
            tokio::time::sleep(wait).await;
        }
    }
}

/// Which listener a subscriber came through; decides what it may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Origin {
    /// The Unix socket: who may connect is set by its mode and group.
    Unix,
    /// The TCP listener: any local user (or any host, with `tcp_public`).
    Tcp,
    /// The live page (its recalibrate button).
    Http,
}

impl Origin {
    pub const ALL: [Origin; 3] = [Origin::Unix, Origin::Tcp, Origin::Http];

    pub fn name(self) -> &'static str {
        match self {
            Origin::Unix => "unix",
            Origin::Tcp => "tcp",
            Origin::Http => "http",
        }
    }
}

/// A secret read from `[outputs] token_file`. Compared in constant time;
/// never printed. Its clones (the hub's, the live page's) share one cell,
/// so a reload that reads a new token file changes it for every listener
/// at once ([`Token::replace_with`]), or revokes it ([`Token::revoke`]).
#[derive(Clone)]
pub struct Token(Arc<RwLock<Box<[u8]>>>);

/// The shortest token `token_file` may hold: 16 bytes. A token is sent
/// over the TCP and HTTP listeners, where a client may try as many as it
/// likes; 16 characters of `openssl rand -hex` are 64 bits, beyond any
/// number of tries at the listeners' rate limit.
pub const MIN_TOKEN_BYTES: usize = 16;

impl Token {
    /// None for an empty token.
    pub fn new(text: &str) -> Option<Token> {
        let text = text.trim();
        (!text.is_empty()).then(|| Token(Arc::new(RwLock::new(text.as_bytes().into()))))
    }

    /// The secret (a poisoned lock still holds a whole one: it is only
    /// ever replaced whole).
    fn secret(&self) -> std::sync::RwLockReadGuard<'_, Box<[u8]>> {
        self.0
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Its length in bytes.
    pub fn len(&self) -> usize {
        self.secret().len()
    }

    /// Whether it is empty: revoked (never, as made by [`Token::new`]).
    pub fn is_empty(&self) -> bool {
        self.secret().is_empty()
    }

    /// Whether `given` is the token; the time taken depends only on the
    /// lengths, not on where they differ. A revoked token matches nothing.
    pub fn matches(&self, given: &str) -> bool {
        let secret = self.secret();
        let given = given.as_bytes();
        let mut diff = u8::from(given.len() != secret.len() || secret.is_empty());
        for (i, &b) in secret.iter().enumerate() {
            diff |= b ^ given.get(i).copied().unwrap_or(!b);
        }
        std::hint::black_box(diff) == 0
    }

    /// Takes `new`'s secret, for every clone of this token.
    pub fn replace_with(&self, new: &Token) {
        let secret = new.secret().clone();
        *self
            .0
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = secret;
    }

    /// Accepts no token any more, in every clone of this one.
    pub fn revoke(&self) {
        *self
            .0
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Box::default();
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl PartialEq for Token {
    fn eq(&self, other: &Token) -> bool {
        if Arc::ptr_eq(&self.0, &other.0) {
            return true;
        }
        let theirs = other.secret().clone();
        match std::str::from_utf8(&theirs) {
            Ok(o) if !o.is_empty() => self.matches(o),
            _ => self.is_empty() && theirs.is_empty(),
        }
    }
}

/// Who may change the daemon's state (`recalibrate`).
#[derive(Debug, Clone, PartialEq)]
pub struct Access {
    /// Listeners whose subscribers may recalibrate.
    pub recalibrate_from: Vec<Origin>,
    /// With it, a command carrying `"token"` may recalibrate from any listener.
    pub token: Option<Token>,
}

impl Default for Access {
    /// The daemon's default: the Unix socket only, no token.
    fn default() -> Access {
        Access {
            recalibrate_from: vec![Origin::Unix],
            token: None,
        }
    }
}

impl Access {
    /// Every listener may recalibrate (a hub used as a library, tests).
    pub fn everyone() -> Access {
        Access {
            recalibrate_from: Origin::ALL.to_vec(),
            token: None,
        }
    }

    /// Whether a subscriber from `origin` may recalibrate without a token.
    pub fn allows(&self, origin: Origin) -> bool {
        self.recalibrate_from.contains(&origin)
    }

    /// Ok when a recalibrate from `origin` carrying `token` is allowed; else
    /// the ERROR message, naming what to configure.
    pub fn check_recalibrate(&self, origin: Origin, token: Option<&str>) -> Result<(), String> {
        if self.allows(origin) {
            return Ok(());
        }
        // A token revoked by a reload is as none.
        match (self.token.as_ref().filter(|t| !t.is_empty()), token) {
            (Some(ours), Some(given)) if ours.matches(given) => Ok(()),
            (Some(_), Some(_)) => Err(format!(
                "recalibrate refused: the \"token\" does not match [outputs] token_file (recalibrate from {o} needs the token, or \"{o}\" in [outputs] recalibrate_from)",
                o = origin.name()
            )),
            (Some(_), None) => Err(format!(
                "recalibrate refused from {o}: send \"token\" with the content of [outputs] token_file, or add \"{o}\" to [outputs] recalibrate_from (now {from})",
                o = origin.name(),
                from = self.listed()
            )),
            (None, _) => Err(format!(
                "recalibrate refused from {o}: it is allowed from {from} ([outputs] recalibrate_from); add \"{o}\" there, or set [outputs] token_file and send \"token\"",
                o = origin.name(),
                from = self.listed()
            )),
        }
    }

    fn listed(&self) -> String {
        let names: Vec<String> = self
            .recalibrate_from
            .iter()
            .map(|o| format!("\"{}\"", o.name()))
            .collect();
        format!("[{}]", names.join(","))
    }
}

/// The hub's limits and rights.
#[derive(Debug, Clone, PartialEq)]
pub struct Policy {
    /// Subscribers at once (the writer not counted).
    pub max_subscribers: usize,
    /// Each subscriber's command budget.
    pub commands: Rate,
    /// Each listener's accept budget.
    pub accepts: Rate,
    pub access: Access,
}

impl Default for Policy {
    /// No subscriber limit, the rates above, everyone may recalibrate: the
    /// hub of [`Hub::new`](super::Hub::new). The daemon builds its own from
    /// the configuration.
    fn default() -> Policy {
        Policy {
            max_subscribers: usize::MAX,
            commands: COMMAND_RATE,
            accepts: ACCEPT_RATE,
            access: Access::everyone(),
        }
    }
}

/// The soft RLIMIT_NOFILE, if it can be read.
pub fn descriptor_limit() -> Option<u64> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes one rlimit into the struct it is given.
    let ok = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0;
    ok.then_some(limit.rlim_cur)
}

/// The default maximum of subscribers: [`DEFAULT_MAX_SUBSCRIBERS`], fewer
/// when the descriptor limit `nofile` leaves less than that beyond
/// [`RESERVED_DESCRIPTORS`] (one descriptor a subscriber).
pub fn default_max_subscribers(nofile: Option<u64>) -> usize {
    match nofile {
        None => DEFAULT_MAX_SUBSCRIBERS,
        Some(n) => usize::try_from(n.saturating_sub(RESERVED_DESCRIPTORS))
            .unwrap_or(usize::MAX)
            .min(DEFAULT_MAX_SUBSCRIBERS),
    }
}

/// Checks a configured maximum against the descriptor limit: it must leave
/// [`RESERVED_DESCRIPTORS`]. The error names the key and what to do.
pub fn check_max_subscribers(configured: usize, nofile: Option<u64>) -> Result<usize, String> {
    let Some(n) = nofile else {
        return Ok(configured);
    };
    let room = n.saturating_sub(RESERVED_DESCRIPTORS);
    if u64::try_from(configured).unwrap_or(u64::MAX) > room {
        return Err(format!(
            "[outputs] max_subscribers = {configured} leaves fewer than {RESERVED_DESCRIPTORS} of \
             the {n} descriptors this process may open (RLIMIT_NOFILE) for its ports and state \
             files: set it to at most {room}, or raise the limit (LimitNOFILE= in the unit, \
             ulimit -n)"
        ));
    }
    Ok(configured)
}
