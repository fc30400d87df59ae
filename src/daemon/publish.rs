//! The publisher hub: fans already-serialised JSON lines out to every
//! subscriber (TCP clients, Unix-socket clients, stdout) and takes gpsd-style
//! command lines back from them.
//!
//! # Dropping
//! Each subscriber owns a bounded queue, so one slow or stuck subscriber
//! never slows the publisher or the others. [`Hub::publish`] only locks each
//! subscriber's queue for a push (no I/O, no await, no copy: lines are
//! shared `Arc<str>`); one writer task per subscriber drains its queue into
//! its socket.
//!
//! Lines travel in two lanes ([`Lane`]):
//! - [`Lane::Reading`]: the sample stream. When a subscriber's reading queue
//!   is full its OLDEST reading is dropped and counted (per subscriber and in
//!   [`HubStats::dropped`]): a late reader wants the newest data.
//! - [`Lane::Control`]: CALIBRATION, STATUS and ERROR lines, rare and
//!   important. They are never dropped for slowness. Their queue is still
//!   bounded (a client could spam bad commands and never read the ERROR
//!   replies): a subscriber whose control queue overflows is disconnected
//!   ("evicted", counted in [`HubStats::evicted`]) rather than silently losing
//!   a calibration. So every subscriber sees every control line, in order,
//!   or it is told nothing more at all.
//!
//! The two lanes of a subscriber keep publish order between them (each line
//! carries a per-subscriber sequence number and the writer takes the lower
//! one first), so a CALIBRATION never overtakes the readings before it.
//!
//! A per-subscriber `Mutex<VecDeque>` + `Notify` was chosen over a tokio
//! broadcast channel: broadcast gives drop-oldest-and-count for free, but
//! not a lane that is never dropped, nor replies to one subscriber only,
//! nor a list of subscribers to report and to check for leaks.
//!
//! # Commands
//! A subscriber may send one JSON object a line (at most
//! [`MAX_COMMAND_LEN`] bytes): `{"command":"recalibrate"}` (optional
//! `"sensor":"name"`) or `{"command":"status"}`. They are forwarded with a
//! [`ReplyTo`] for the answer; anything else gets an
//! `{"class":"ERROR","message":...}` line back to that subscriber only.
//! A command object with a key given twice is refused (naming the key):
//! JSON parsers disagree on which one wins.
//!
//! # Limits and rights
//! - At most [`Policy::max_subscribers`] subscribers (TCP, Unix socket and
//!   the live page's event streams; stdout, the "writer", never counts). One
//!   more gets a single ERROR line (an HTTP 503 for the live page) and is
//!   closed. The daemon derives the default from its descriptor limit
//!   ([`default_max_subscribers`]) so the ports and the state writer always
//!   have descriptors left.
//! - Accepts are paced by a token bucket ([`ACCEPT_RATE`]): beyond it the
//!   listener stops accepting for a moment and the kernel's backlog holds
//!   or refuses, so a connect/close flood cannot take a core.
//! - Each subscriber's command lines (bad ones too) are paced by a token
//!   bucket ([`COMMAND_RATE`]); over it the daemon simply stops reading that
//!   connection (TCP backpressure) rather than answering each line.
//! - `recalibrate` changes state: it is taken only from the listeners in
//!   [`Access::recalibrate_from`], or with the [`Access::token`]; otherwise it
//!   is answered with an ERROR naming what to configure. `status` is open.
//!
//! # stdout
//! The writer ([`Hub::serve_writer`], stdout: under systemd the journal's
//! stream) is never evicted. It may lose its oldest READINGs (counted, as
//! any subscriber), and its control lines are coalesced instead of
//! overflowing: a queued STATUS is replaced by the newer one; when the
//! control queue is still full the oldest ERROR is dropped (counted in
//! [`HubStats::coalesced`]); a CALIBRATION is never dropped. That keeps the
//! queue bounded (its bound, one STATUS, and the CALIBRATIONs): CALIBRATION lines come a few per rotation per
//! sensor (one when a rotation ends, one when it is loaded or restarted),
//! so even a stdout stalled for hours holds a handful of them per sensor
//! beyond the bound.

use std::collections::VecDeque;
use std::fmt;
use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock, RwLockReadGuard, Weak};
use std::time::Duration;

use serde::Serialize;
use serde_json::Value;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{Notify, mpsc, watch};
use tokio::time::Instant;

/// Readings a subscriber may have queued by default before its oldest are
/// dropped: a few seconds of a fast sensor.
pub const DEFAULT_QUEUE_LEN: usize = 4096;
/// Control lines (CALIBRATION, STATUS, ERROR) a subscriber may have queued
/// before it is disconnected as hopelessly behind.
pub const CONTROL_QUEUE_LEN: usize = 1024;
/// Longest command line accepted, without its newline. Commands are short;
/// the limit keeps a client from growing the daemon's memory.
pub const MAX_COMMAND_LEN: usize = 4096;
/// How long [`Hub::close`] (and a shut-down [`Hub::serve_writer`]) lets
/// subscribers flush what is queued.
pub const CLOSE_GRACE: Duration = Duration::from_secs(1);
/// Bytes a writer gathers into one write: few syscalls, bounded memory.
const MAX_BATCH_BYTES: usize = 64 * 1024;
/// Pause after a failed accept (e.g. out of file descriptors) so the loop
/// does not spin.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);

const ALLOWED: &str = r#"allowed: {"command":"recalibrate"} with an optional "sensor":"<name>" (and "token":"<token>" where one is configured), and {"command":"status"}, one JSON object a line"#;

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
/// 3), the systemd notify socket (1), and 6 for the live page's short
/// requests and a connection being refused.
pub const RESERVED_DESCRIPTORS: u64 = 32;
/// Above this many entries an idle lane gives its memory back.
const SHRINK_LANE_ABOVE: usize = 256;
/// Above this many bytes an idle writer's batch buffer is freed.
const SHRINK_BUF_ABOVE: usize = 16 * 1024;
/// How long a refused connection's one ERROR line may take to write: it
/// goes into an empty socket buffer, so this only bounds a broken peer.
const REFUSE_WRITE: Duration = Duration::from_millis(100);
/// Free memory back to the system (malloc_trim) when the subscriber count
/// falls to half its peak, once the peak was at least this.
const TRIM_PEAK: usize = 8;

/// A token bucket's rate: `per_s` tokens a second, holding at most `burst`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rate {
    pub per_s: f64,
    pub burst: f64,
}

/// A token bucket; `take` says how long to wait when it is empty.
#[derive(Debug)]
struct Bucket {
    rate: Rate,
    tokens: f64,
    last: Instant,
}

impl Bucket {
    fn new(rate: Rate) -> Bucket {
        Bucket {
            rate,
            tokens: rate.burst.max(1.0),
            last: Instant::now(),
        }
    }

    /// Takes a token, or says how long until one is there.
    fn take(&mut self, now: Instant) -> Option<Duration> {
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
    async fn wait(&mut self) {
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
/// never printed.
#[derive(Clone)]
pub struct Token(Box<[u8]>);

impl Token {
    /// None for an empty token.
    pub fn new(text: &str) -> Option<Token> {
        let text = text.trim();
        (!text.is_empty()).then(|| Token(text.as_bytes().into()))
    }

    /// Whether `given` is the token; the time taken depends only on the
    /// lengths, not on where they differ.
    pub fn matches(&self, given: &str) -> bool {
        let given = given.as_bytes();
        let mut diff = u8::from(given.len() != self.0.len());
        for (i, &b) in self.0.iter().enumerate() {
            diff |= b ^ given.get(i).copied().unwrap_or(!b);
        }
        std::hint::black_box(diff) == 0
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl PartialEq for Token {
    fn eq(&self, other: &Token) -> bool {
        std::str::from_utf8(&other.0).is_ok_and(|o| self.matches(o))
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
        match (&self.token, token) {
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
    /// hub of [`Hub::new`]. The daemon builds its own from the configuration.
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

/// Gives freed memory back to the system (glibc keeps it otherwise).
fn release_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Which lane a line travels in; decides what may be dropped for slowness.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lane {
    /// READING lines: the oldest are dropped (and counted) for a slow subscriber.
    Reading,
    /// CALIBRATION, STATUS, ERROR: never dropped; a subscriber that lets
    /// [`CONTROL_QUEUE_LEN`] of them pile up is disconnected instead.
    Control,
}

/// A command a subscriber sent.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientCommand {
    /// Start a new calibration of one sensor, or of all when `None`.
    Recalibrate { sensor: Option<String> },
    /// Send a STATUS line back to the asking subscriber.
    Status,
}

/// Counters of the hub since it was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct HubStats {
    /// Subscribers connected now.
    pub subscribers: usize,
    /// Reading lines dropped for slow subscribers, summed over subscribers
    /// (including those gone since).
    pub dropped: u64,
    /// Lines given to [`Hub::publish`].
    pub published: u64,
    /// Subscribers disconnected because their control queue overflowed.
    pub evicted: u64,
    /// Control lines the writer (stdout) did not get because it was slow:
    /// an unsent STATUS replaced by a newer one, or an ERROR (or STATUS)
    /// dropped from a full control queue.
    pub coalesced: u64,
    /// Connections refused because [`Policy::max_subscribers`] were connected.
    pub refused: u64,
}

/// One subscriber's state, for STATUS replies and diagnostics.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct SubscriberStats {
    /// Unique within the hub, in order of connection.
    pub id: u64,
    /// The peer address, or `unix`, or `writer`.
    pub peer: String,
    /// Lines waiting to be written.
    pub queued: usize,
    /// Reading lines dropped because it was slow.
    pub dropped: u64,
}

/// What is wrong with a command line; the message is sent back to the
/// client, so it says what is allowed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    #[error("command line longer than {limit} bytes; discarded up to the next newline; {allowed}", allowed = ALLOWED)]
    TooLong { limit: usize },
    #[error("command line is not UTF-8 text; {allowed}", allowed = ALLOWED)]
    NotUtf8,
    #[error("command line is not JSON ({0}); {allowed}", allowed = ALLOWED)]
    NotJson(String),
    #[error("command is a JSON {0}, not an object; {allowed}", allowed = ALLOWED)]
    NotObject(&'static str),
    #[error("command object has no \"command\" field; {allowed}", allowed = ALLOWED)]
    MissingCommand,
    #[error("\"command\" must be a string; {allowed}", allowed = ALLOWED)]
    CommandNotString,
    #[error("unknown command {0:?}; {allowed}", allowed = ALLOWED)]
    UnknownCommand(String),
    #[error("unknown field {field:?} in a {command:?} command; {allowed}", allowed = ALLOWED)]
    UnknownField { command: String, field: String },
    #[error("\"sensor\" must be a non-empty string naming a configured sensor; {allowed}", allowed = ALLOWED)]
    BadSensor,
    #[error("\"token\" must be a string; {allowed}", allowed = ALLOWED)]
    BadToken,
    /// Not allowed from this subscriber; the message says what to configure.
    #[error("{0}")]
    Refused(String),
    #[error("key {0:?} is given twice in the command object; give each key once; {allowed}", allowed = ALLOWED)]
    DuplicateKey(String),
}

/// A parsed command line: the command and the token it carried, if any.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    pub command: ClientCommand,
    pub token: Option<String>,
}

/// A top-level JSON value, objects kept as their entries in order, so a
/// key given twice can be told (serde_json's `Value` keeps the last).
enum TopLevel {
    Object(Vec<(String, Value)>),
    Other(&'static str),
}

impl<'de> serde::Deserialize<'de> for TopLevel {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<TopLevel, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = TopLevel;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a JSON value")
            }
            fn visit_bool<E>(self, _: bool) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("boolean"))
            }
            fn visit_i64<E>(self, _: i64) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("number"))
            }
            fn visit_u64<E>(self, _: u64) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("number"))
            }
            fn visit_f64<E>(self, _: f64) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("number"))
            }
            fn visit_str<E>(self, _: &str) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("string"))
            }
            fn visit_unit<E>(self) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("null"))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<TopLevel, A::Error> {
                while seq.next_element::<serde::de::IgnoredAny>()?.is_some() {}
                Ok(TopLevel::Other("array"))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<TopLevel, A::Error> {
                let mut entries = Vec::new();
                while let Some((k, v)) = map.next_entry::<String, Value>()? {
                    entries.push((k, v));
                }
                Ok(TopLevel::Object(entries))
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// Parses one command line (without its newline).
pub fn parse_command(line: &[u8]) -> Result<ClientCommand, CommandError> {
    parse_request(line).map(|r| r.command)
}

/// Parses one command line (without its newline), with its `"token"`.
pub fn parse_request(line: &[u8]) -> Result<Request, CommandError> {
    let text = std::str::from_utf8(line).map_err(|_| CommandError::NotUtf8)?;
    let top: TopLevel =
        serde_json::from_str(text).map_err(|e| CommandError::NotJson(e.to_string()))?;
    let entries = match top {
        TopLevel::Object(entries) => entries,
        TopLevel::Other(kind) => return Err(CommandError::NotObject(kind)),
    };
    let mut map = serde_json::Map::new();
    for (key, value) in entries {
        if map.contains_key(&key) {
            return Err(CommandError::DuplicateKey(key));
        }
        map.insert(key, value);
    }
    let token = match map.get("token") {
        None => None,
        Some(Value::String(t)) => Some(t.clone()),
        Some(_) => return Err(CommandError::BadToken),
    };
    let command = match map.get("command") {
        None => return Err(CommandError::MissingCommand),
        Some(Value::String(s)) => s.as_str(),
        Some(_) => return Err(CommandError::CommandNotString),
    };
    let fields: &[&str] = match command {
        "recalibrate" => &["command", "sensor", "token"],
        "status" => &["command", "token"],
        other => return Err(CommandError::UnknownCommand(other.to_owned())),
    };
    if let Some(field) = map.keys().find(|k| !fields.contains(&k.as_str())) {
        return Err(CommandError::UnknownField {
            command: command.to_owned(),
            field: field.clone(),
        });
    }
    if command == "status" {
        return Ok(Request {
            command: ClientCommand::Status,
            token,
        });
    }
    let sensor = match map.get("sensor") {
        None => None,
        Some(Value::String(s)) if !s.is_empty() => Some(s.clone()),
        Some(_) => return Err(CommandError::BadSensor),
    };
    Ok(Request {
        command: ClientCommand::Recalibrate { sensor },
        token,
    })
}

/// An `{"class":"ERROR","message":...}` line, for replies.
pub fn error_line(message: &str) -> Arc<str> {
    serde_json::json!({ "class": "ERROR", "message": message })
        .to_string()
        .into()
}

/// Where the answer to a command goes: the asking subscriber only.
///
/// Holds the subscriber weakly, so a reply kept after the subscriber left
/// keeps nothing alive and is simply not sent.
#[derive(Clone, Default)]
pub struct ReplyTo {
    sub: Weak<Subscriber>,
}

impl ReplyTo {
    /// A reply that goes nowhere, for commands that did not come from a
    /// subscriber.
    pub fn nobody() -> ReplyTo {
        ReplyTo::default()
    }

    /// Queues `line` (without its newline) in the subscriber's control lane.
    pub fn send(&self, line: Arc<str>) {
        if let Some(sub) = self.sub.upgrade() {
            sub.push(Lane::Control, line);
        }
    }

    /// Queues a STATUS reply (`status`, a JSON object) with the asking
    /// subscriber's own accounting added as `"subscriber"`: `{"id", "peer",
    /// "readings"` (READING lines given to its queue since it connected,
    /// dropped ones included), `"dropped"` (READING lines dropped for it),
    /// `"queued"` (READING lines in its queue ahead of this reply)`}`,
    /// snapshotted under the queue's lock as the reply is queued. The
    /// readings queued ahead of a reply are never dropped, so the READING
    /// lines the subscriber receives before this reply are exactly
    /// `readings - dropped`.
    pub fn send_status(&self, status: &str) {
        if let Some(sub) = self.sub.upgrade() {
            let pushed = sub.queue().push_status_reply(status, sub.id, &sub.peer);
            sub.pushed(pushed);
        }
    }

    /// Whether the subscriber is still connected and taking lines.
    pub fn is_connected(&self) -> bool {
        self.sub
            .upgrade()
            .is_some_and(|sub| sub.queue().state == QueueState::Open)
    }

    /// The subscriber's peer, while it exists.
    pub fn peer(&self) -> Option<String> {
        self.sub.upgrade().map(|sub| sub.peer.clone())
    }
}

impl fmt::Debug for ReplyTo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ReplyTo")
            .field("peer", &self.peer())
            .finish()
    }
}

/// The publisher hub. Cheap to clone; all clones share the subscribers.
#[derive(Clone)]
pub struct Hub {
    inner: Arc<Inner>,
}

struct Inner {
    reading_cap: usize,
    control_cap: usize,
    policy: Policy,
    /// The most subscribers since memory was last given back.
    peak: AtomicUsize,
    subscribers: RwLock<Vec<Arc<Subscriber>>>,
    counters: Arc<Counters>,
    next_id: AtomicU64,
    /// Set by [`Hub::close`] under the subscribers' write lock: no
    /// subscriber registers after it.
    closed: AtomicBool,
    /// Woken whenever a subscriber is removed, for [`Hub::close`].
    removed: Notify,
    /// What a late subscriber is given at once, once [`Hub::keep_for_replay`]
    /// was called.
    retained: std::sync::OnceLock<Mutex<Retained>>,
}

#[derive(Default)]
struct Counters {
    published: AtomicU64,
    dropped: AtomicU64,
    evicted: AtomicU64,
    coalesced: AtomicU64,
    refused: AtomicU64,
}

impl fmt::Debug for Hub {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Hub").field("stats", &self.stats()).finish()
    }
}

impl Hub {
    /// A hub whose subscribers each queue up to `queue_len` readings
    /// (at least 1) and [`CONTROL_QUEUE_LEN`] control lines.
    pub fn new(queue_len: usize) -> Hub {
        Hub::with_control_len(queue_len, CONTROL_QUEUE_LEN)
    }

    /// Like [`Hub::new`] with the control queue's bound chosen too (at least 1).
    pub fn with_control_len(queue_len: usize, control_len: usize) -> Hub {
        Hub::with_policy(queue_len, control_len, Policy::default())
    }

    /// A hub with limits and rights ([`Policy`]); the daemon's.
    pub fn with_policy(queue_len: usize, control_len: usize, policy: Policy) -> Hub {
        Hub {
            inner: Arc::new(Inner {
                reading_cap: queue_len.max(1),
                control_cap: control_len.max(1),
                policy,
                peak: AtomicUsize::new(0),
                subscribers: RwLock::new(Vec::new()),
                counters: Arc::default(),
                next_id: AtomicU64::new(1),
                closed: AtomicBool::new(false),
                removed: Notify::new(),
                retained: std::sync::OnceLock::new(),
            }),
        }
    }

    /// Queues `line` (without its trailing newline) for every subscriber.
    /// Never blocks on I/O: a full reading queue drops its oldest line.
    pub fn publish(&self, lane: Lane, line: Arc<str>) {
        self.inner
            .counters
            .published
            .fetch_add(1, Ordering::Relaxed);
        let subs = self.inner.read_subs();
        // Kept under the subscribers' lock, so a subscriber that registers
        // with the replay gets each line either replayed or queued, once.
        if let Some(retained) = self.inner.retained.get() {
            lock(retained).keep(lane, &line);
        }
        for sub in subs.iter() {
            sub.push(lane, Arc::clone(&line));
        }
    }

    pub fn stats(&self) -> HubStats {
        let c = &self.inner.counters;
        HubStats {
            subscribers: self.inner.read_subs().len(),
            dropped: c.dropped.load(Ordering::Relaxed),
            published: c.published.load(Ordering::Relaxed),
            evicted: c.evicted.load(Ordering::Relaxed),
            coalesced: c.coalesced.load(Ordering::Relaxed),
            refused: c.refused.load(Ordering::Relaxed),
        }
    }

    /// The limits and rights the hub applies.
    pub fn policy(&self) -> &Policy {
        &self.inner.policy
    }

    /// Whether [`Policy::max_subscribers`] are connected now.
    pub fn is_full(&self) -> bool {
        counted(&self.inner.read_subs()) >= self.inner.policy.max_subscribers
    }

    /// Every subscriber connected now (the hub's internal list).
    pub fn subscribers(&self) -> Vec<SubscriberStats> {
        self.inner
            .read_subs()
            .iter()
            .map(|sub| {
                let q = sub.queue();
                SubscriberStats {
                    id: sub.id,
                    peer: sub.peer.clone(),
                    queued: q.len(),
                    dropped: q.dropped,
                }
            })
            .collect()
    }

    /// Serves one connected stream (TCP or Unix) until it closes: writes
    /// the hub's lines, reads command lines and forwards them with a
    /// [`ReplyTo`]. Ends when the client hangs up (EOF on its side counts:
    /// as in gpsd), on an I/O error, on eviction, or after [`Hub::close`].
    pub async fn serve_connection<S>(
        &self,
        stream: S,
        peer: String,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
    ) where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        self.serve_connection_from(stream, peer, Origin::Tcp, commands)
            .await;
    }

    /// [`Hub::serve_connection`] for a subscriber that came through
    /// `origin`, which decides what it may do. At
    /// [`Policy::max_subscribers`] it is sent one ERROR line and closed.
    pub async fn serve_connection_from<S>(
        &self,
        mut stream: S,
        peer: String,
        origin: Origin,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
    ) where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let reg = match self.register(peer, Some(origin)) {
            Ok(reg) => reg,
            Err(SubscribeError::Closed) => {
                tracing::debug!("subscriber refused: the hub is closed");
                return;
            }
            Err(e @ SubscribeError::Full { .. }) => {
                refuse(&mut stream, &e).await;
                return;
            }
        };
        let sub = &reg.sub;
        tracing::debug!(id = sub.id, peer = %sub.peer, "subscriber connected");
        let (mut rd, mut wr) = tokio::io::split(stream);
        let mut bucket = Bucket::new(self.inner.policy.commands);
        let access = &self.inner.policy.access;
        let end = tokio::select! {
            end = write_loop(sub, &mut wr) => end,
            end = read_loop(sub, &mut rd, &commands, origin, access, &mut bucket) => end,
        };
        log_end(sub, end);
    }

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

    /// Accepts Unix-socket subscribers until `shutdown` turns true, like
    /// [`Hub::serve_tcp`].
    pub async fn serve_unix(
        &self,
        listener: tokio::net::UnixListener,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
        shutdown: watch::Receiver<bool>,
    ) {
        let accept = || async {
            let (stream, _addr) = listener.accept().await?;
            Ok((stream, "unix".to_owned()))
        };
        self.accept_loop(Origin::Unix, accept, commands, shutdown)
            .await;
    }

    /// The accept loop both listeners share: each connection gets its own
    /// task; a failed accept (out of descriptors, say) is retried after a
    /// pause instead of spinning.
    async fn accept_loop<S, F, Fut>(
        &self,
        origin: Origin,
        mut accept: F,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
        mut shutdown: watch::Receiver<bool>,
    ) where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
        F: FnMut() -> Fut,
        Fut: Future<Output = std::io::Result<(S, String)>>,
    {
        let kind = match origin {
            Origin::Tcp => "TCP",
            Origin::Unix => "Unix-socket",
            Origin::Http => "HTTP",
        };
        let mut bucket = Bucket::new(self.inner.policy.accepts);
        loop {
            // Over the accept budget, stop accepting for a moment: the
            // kernel's backlog holds (or refuses) the rest.
            if let Some(wait) = bucket.take(Instant::now()) {
                tokio::select! {
                    () = tokio::time::sleep(wait) => continue,
                    () = turned_true(&mut shutdown) => break,
                }
            }
            let accepted = tokio::select! {
                accepted = accept() => accepted,
                () = turned_true(&mut shutdown) => break,
            };
            match accepted {
                Ok((mut stream, peer)) => {
                    // Refused here, not in a task: a refused connection
                    // holds its descriptor only for this one write.
                    if self.is_full() {
                        let max = self.inner.policy.max_subscribers;
                        refuse(&mut stream, &SubscribeError::Full { max }).await;
                        self.inner.counters.refused.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    let hub = self.clone();
                    let commands = commands.clone();
                    tokio::spawn(async move {
                        hub.serve_connection_from(stream, peer, origin, commands)
                            .await;
                    });
                }
                Err(e) => {
                    tracing::warn!(error = %e, "accepting a {kind} subscriber failed; retrying in {ACCEPT_BACKOFF:?}");
                    tokio::time::sleep(ACCEPT_BACKOFF).await;
                }
            }
        }
    }

    /// Writes the hub's lines to `out` (stdout, or any writer) as a
    /// subscriber like the others. When `shutdown` turns true it flushes
    /// what is queued (for at most [`CLOSE_GRACE`]) and returns.
    pub fn serve_writer<W>(
        &self,
        mut out: W,
        mut shutdown: watch::Receiver<bool>,
    ) -> impl std::future::Future<Output = ()> + Send + 'static
    where
        W: AsyncWrite + Unpin + Send + 'static,
    {
        // Registered now, not when the future first runs: lines published
        // between spawning the writer and its first poll reach it too.
        let reg = self.register("writer".to_owned(), None);
        async move {
            let Ok(reg) = reg else {
                return;
            };
            let sub = &reg.sub;
            let writing = write_loop(sub, &mut out);
            tokio::pin!(writing);
            let end = tokio::select! {
                end = &mut writing => end,
                () = turned_true(&mut shutdown) => {
                    sub.begin_close(Instant::now() + CLOSE_GRACE);
                    writing.await
                }
            };
            log_end(sub, end);
        }
    }

    /// Shuts the hub: no new subscribers; every subscriber writes what is
    /// queued and is closed. Waits at most about [`CLOSE_GRACE`]: a stuck
    /// subscriber is cut off then.
    pub async fn close(&self) {
        let deadline = Instant::now() + CLOSE_GRACE;
        {
            let subs = self.inner.write_subs();
            self.inner.closed.store(true, Ordering::SeqCst);
            for sub in subs.iter() {
                sub.begin_close(deadline);
            }
        }
        // The writers give up at `deadline`; allow their tasks a moment to
        // unregister after that.
        let give_up = deadline + Duration::from_millis(200);
        loop {
            let removed = self.inner.removed.notified();
            let left = self.inner.read_subs().len();
            if left == 0 {
                return;
            }
            if tokio::time::timeout_at(give_up, removed).await.is_err() {
                tracing::warn!(
                    subscribers = left,
                    "subscribers still registered after the close grace"
                );
                return;
            }
        }
    }

    /// Adds a subscriber; `origin` None for the writer, which is never
    /// refused for the limit nor evicted.
    fn register(
        &self,
        peer: String,
        origin: Option<Origin>,
    ) -> Result<Registration, SubscribeError> {
        let mut subs = self.inner.write_subs();
        self.admit(&subs, origin)?;
        let sub = Arc::new(self.new_subscriber(peer, origin));
        subs.push(Arc::clone(&sub));
        self.inner.peak.fetch_max(subs.len(), Ordering::Relaxed);
        Ok(Registration {
            hub: self.clone(),
            sub,
        })
    }

    /// Whether one more subscriber from `origin` may join `subs`.
    fn admit(
        &self,
        subs: &[Arc<Subscriber>],
        origin: Option<Origin>,
    ) -> Result<(), SubscribeError> {
        if self.inner.closed.load(Ordering::SeqCst) {
            return Err(SubscribeError::Closed);
        }
        let max = self.inner.policy.max_subscribers;
        if origin.is_some() && counted(subs) >= max {
            self.inner.counters.refused.fetch_add(1, Ordering::Relaxed);
            return Err(SubscribeError::Full { max });
        }
        Ok(())
    }
}

/// The state a late subscriber needs: the last STATUS, each sensor's last
/// CALIBRATION and last accepted one, and the latest readings; each with
/// its place in publish order, in which they are replayed.
#[derive(Debug, Default)]
struct Retained {
    readings_cap: usize,
    next: u64,
    readings: VecDeque<(u64, Arc<str>)>,
    status: Option<(u64, Arc<str>)>,
    /// In order of first appearance, at most [`MAX_RETAINED_SENSORS`].
    calibrations: Vec<RetainedSensor>,
}

#[derive(Debug)]
struct RetainedSensor {
    sensor: String,
    last: (u64, Arc<str>),
    last_accepted: Option<(u64, Arc<str>)>,
}

/// Sensors whose calibrations are retained: sensors come from the
/// configuration, so this only bounds memory against a bug.
const MAX_RETAINED_SENSORS: usize = 1024;

/// The head of a control line, all that retention looks at.
#[derive(serde::Deserialize)]
struct LineHead {
    class: String,
    #[serde(default)]
    sensor: Option<String>,
    #[serde(default)]
    accepted: Option<bool>,
}

impl Retained {
    fn keep(&mut self, lane: Lane, line: &Arc<str>) {
        let seq = self.next;
        self.next += 1;
        let entry = (seq, Arc::clone(line));
        if lane == Lane::Reading {
            if self.readings_cap == 0 {
                return;
            }
            if self.readings.len() >= self.readings_cap {
                self.readings.pop_front();
            }
            self.readings.push_back(entry);
            return;
        }
        // Control lines are rare: parsing their head costs nothing that matters.
        let Ok(head) = serde_json::from_str::<LineHead>(line) else {
            return;
        };
        match (head.class.as_str(), head.sensor) {
            ("STATUS", _) => self.status = Some(entry),
            ("CALIBRATION", Some(sensor)) => {
                let accepted = head.accepted == Some(true);
                let full = self.calibrations.len() >= MAX_RETAINED_SENSORS;
                match self.calibrations.iter_mut().find(|s| s.sensor == sensor) {
                    Some(s) => {
                        if accepted {
                            s.last_accepted = Some(entry.clone());
                        }
                        s.last = entry;
                    }
                    None if !full => {
                        self.calibrations.push(RetainedSensor {
                            sensor,
                            last_accepted: accepted.then(|| entry.clone()),
                            last: entry,
                        });
                    }
                    None => {}
                }
            }
            _ => {}
        }
    }

    /// Queues the retained lines for a new subscriber in the order they
    /// were published: each sensor's last accepted calibration and its last
    /// (when another), the readings that fit its queue, the last STATUS.
    fn replay_into(&self, queue: &mut Queue) {
        let mut lines: Vec<(u64, Lane, &Arc<str>)> = Vec::new();
        for s in &self.calibrations {
            if let Some((seq, line)) = &s.last_accepted {
                lines.push((*seq, Lane::Control, line));
            }
            if s.last_accepted.as_ref().is_none_or(|a| a.0 != s.last.0) {
                lines.push((s.last.0, Lane::Control, &s.last.1));
            }
        }
        let skip = self.readings.len().saturating_sub(queue.reading_cap);
        for (seq, line) in self.readings.iter().skip(skip) {
            lines.push((*seq, Lane::Reading, line));
        }
        if let Some((seq, line)) = &self.status {
            lines.push((*seq, Lane::Control, line));
        }
        lines.sort_unstable_by_key(|(seq, _, _)| *seq);
        for (_, lane, line) in lines {
            queue.push(lane, Arc::clone(line));
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A subscriber served in this process rather than over a socket (the live
/// page's server-sent events): the same bounded queue, lanes and drop
/// accounting as a socket subscriber; its owner takes the lines with
/// [`Subscription::recv`]. Dropping it unsubscribes.
pub struct Subscription {
    sub: Arc<Subscriber>,
    /// None for a [`Hub::mailbox`], which is not in the hub's list.
    _registration: Option<Registration>,
}

impl fmt::Debug for Subscription {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Subscription")
            .field("id", &self.sub.id)
            .field("peer", &self.sub.peer)
            .finish()
    }
}

impl Subscription {
    /// Waits for lines and moves up to `max` (at least 1) of them, in
    /// publish order, into `out`. False once the subscription is over: the
    /// hub closed (after what was queued is taken) or it was evicted.
    pub async fn recv(&mut self, out: &mut Vec<Arc<str>>, max: usize) -> bool {
        let max = max.max(1);
        loop {
            let state = {
                let mut q = self.sub.queue();
                let mut taken = 0;
                while taken < max {
                    let Some(line) = q.pop() else { break };
                    out.push(line);
                    taken += 1;
                }
                if taken > 0 && q.state != QueueState::Evicted {
                    if q.len() == 0 {
                        q.shrink_idle();
                    }
                    return true;
                }
                q.state
            };
            if state != QueueState::Open {
                return false;
            }
            self.sub.wake.notified().await;
        }
    }

    /// Reading lines dropped because this subscriber was slow.
    pub fn dropped(&self) -> u64 {
        self.sub.queue().dropped
    }

    /// Its id in the hub (in [`Hub::subscribers`]).
    pub fn id(&self) -> u64 {
        self.sub.id
    }

    /// Where answers to a command go for them to reach this subscription.
    pub fn reply_to(&self) -> ReplyTo {
        ReplyTo {
            sub: Arc::downgrade(&self.sub),
        }
    }
}

impl Hub {
    /// From now on the hub keeps what a subscriber registered with
    /// [`Hub::subscribe`]`(_, true)` gets at once: the last STATUS, each
    /// sensor's last CALIBRATION and last accepted one, and the latest
    /// `readings` READING lines (fewer if its reading queue is shorter).
    /// Call it before publishing; later calls change nothing.
    pub fn keep_for_replay(&self, readings: usize) {
        let _ = self.inner.retained.set(Mutex::new(Retained {
            readings_cap: readings,
            ..Retained::default()
        }));
    }

    /// Registers an in-process subscriber. With `replay`, what
    /// [`Hub::keep_for_replay`] kept is queued first, atomically with the
    /// registration: no line is missed or given twice. None once the hub is
    /// closed.
    pub fn subscribe(&self, peer: String, replay: bool) -> Option<Subscription> {
        self.try_subscribe(peer, Origin::Http, replay).ok()
    }

    /// [`Hub::subscribe`] for a subscriber from `origin`, saying why it was
    /// refused: the hub is closed, or [`Policy::max_subscribers`] are
    /// connected.
    pub fn try_subscribe(
        &self,
        peer: String,
        origin: Origin,
        replay: bool,
    ) -> Result<Subscription, SubscribeError> {
        let mut subs = self.inner.write_subs();
        self.admit(&subs, Some(origin))?;
        let sub = Arc::new(self.new_subscriber(peer, Some(origin)));
        if replay && let Some(retained) = self.inner.retained.get() {
            lock(retained).replay_into(&mut sub.queue());
        }
        subs.push(Arc::clone(&sub));
        self.inner.peak.fetch_max(subs.len(), Ordering::Relaxed);
        drop(subs);
        Ok(Subscription {
            sub: Arc::clone(&sub),
            _registration: Some(Registration {
                hub: self.clone(),
                sub,
            }),
        })
    }

    /// A subscription that receives only the replies sent to its
    /// [`Subscription::reply_to`], nothing published: for one request's
    /// answer (the live page's recalibrate button). Not counted as a
    /// subscriber.
    pub fn mailbox(&self, peer: String) -> Subscription {
        Subscription {
            sub: Arc::new(self.new_subscriber(peer, Some(Origin::Http))),
            _registration: None,
        }
    }

    fn new_subscriber(&self, peer: String, origin: Option<Origin>) -> Subscriber {
        let (deadline, _) = watch::channel(None);
        let mut queue = Queue::new(self.inner.reading_cap, self.inner.control_cap);
        // The writer (stdout) is never evicted: its control lines coalesce.
        queue.coalesce = origin.is_none();
        Subscriber {
            id: self.inner.next_id.fetch_add(1, Ordering::Relaxed),
            peer,
            origin,
            queue: Mutex::new(queue),
            wake: Notify::new(),
            deadline,
            counters: Arc::clone(&self.inner.counters),
        }
    }
}

impl Inner {
    fn read_subs(&self) -> RwLockReadGuard<'_, Vec<Arc<Subscriber>>> {
        self.subscribers
            .read()
            .unwrap_or_else(PoisonError::into_inner)
    }

    fn write_subs(&self) -> std::sync::RwLockWriteGuard<'_, Vec<Arc<Subscriber>>> {
        self.subscribers
            .write()
            .unwrap_or_else(PoisonError::into_inner)
    }
}

/// Removes its subscriber from the hub when dropped, so a connection task
/// that is cancelled (not only one that returns) leaves no entry behind.
struct Registration {
    hub: Hub,
    sub: Arc<Subscriber>,
}

impl Drop for Registration {
    fn drop(&mut self) {
        let left = {
            let mut subs = self.hub.inner.write_subs();
            if let Some(i) = subs.iter().position(|s| s.id == self.sub.id) {
                subs.swap_remove(i);
            }
            subs.len()
        };
        self.hub.inner.removed.notify_waiters();
        // A crowd left: give its queues' memory back to the system, at most
        // log2(peak) times while it leaves.
        let peak = self.hub.inner.peak.load(Ordering::Relaxed);
        if peak >= TRIM_PEAK
            && left <= peak / 2
            && self
                .hub
                .inner
                .peak
                .compare_exchange(peak, left, Ordering::Relaxed, Ordering::Relaxed)
                .is_ok()
        {
            release_memory();
        }
    }
}

/// Why a subscriber was not taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SubscribeError {
    #[error("the daemon is shutting down")]
    Closed,
    #[error(
        "too many subscribers ({max}, [outputs] max_subscribers); try again later, or raise \
         [outputs] max_subscribers (and the descriptor limit, LimitNOFILE=)"
    )]
    Full { max: usize },
}

/// Subscribers that count against [`Policy::max_subscribers`]: all but the writer.
fn counted(subs: &[Arc<Subscriber>]) -> usize {
    subs.iter().filter(|s| s.origin.is_some()).count()
}

/// Sends a refused connection its one ERROR line and closes it.
async fn refuse<S: AsyncWrite + Unpin>(stream: &mut S, why: &SubscribeError) {
    tracing::debug!(%why, "subscriber refused");
    let mut line = error_line(&why.to_string()).to_string();
    line.push('\n');
    let _ = tokio::time::timeout(REFUSE_WRITE, async {
        stream.write_all(line.as_bytes()).await?;
        stream.shutdown().await
    })
    .await;
}

struct Subscriber {
    id: u64,
    peer: String,
    /// None for the writer (stdout).
    origin: Option<Origin>,
    queue: Mutex<Queue>,
    /// Wakes the writer: a line was queued, or the queue was closed.
    wake: Notify,
    /// When set, the time by which the writer must be done; interrupts a
    /// write blocked on a client that does not read.
    deadline: watch::Sender<Option<Instant>>,
    counters: Arc<Counters>,
}

impl Subscriber {
    fn queue(&self) -> MutexGuard<'_, Queue> {
        self.queue.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn push(&self, lane: Lane, line: Arc<str>) {
        let pushed = self.queue().push(lane, line);
        self.pushed(pushed);
    }

    /// Counts, logs and wakes the writer after a push.
    fn pushed(&self, pushed: Pushed) {
        match pushed {
            Pushed::Queued => self.wake.notify_one(),
            Pushed::Coalesced(n) => {
                self.counters.coalesced.fetch_add(n, Ordering::Relaxed);
                self.wake.notify_one();
            }
            Pushed::DroppedOldest => {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                self.wake.notify_one();
            }
            Pushed::Overflowed => {
                self.counters.evicted.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(id = self.id, peer = %self.peer,
                    "subscriber disconnected: its control queue overflowed (it does not read)");
                self.deadline.send_replace(Some(Instant::now()));
                self.wake.notify_one();
            }
            Pushed::Refused => {}
        }
    }

    fn begin_close(&self, deadline: Instant) {
        self.queue().close();
        self.deadline.send_if_modified(|d| {
            if d.is_none() {
                *d = Some(deadline);
                true
            } else {
                false
            }
        });
        self.wake.notify_one();
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum QueueState {
    Open,
    /// Takes no more lines; the writer drains what is queued and ends.
    Closing,
    /// Dropped everything; the writer ends now.
    Evicted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pushed {
    Queued,
    /// Queued after this many older control lines were let go (the writer
    /// only), or this line itself was (then nothing new is queued).
    Coalesced(u64),
    DroppedOldest,
    /// The control lane was full: the queue is now evicted.
    Overflowed,
    /// The queue is closing or evicted.
    Refused,
}

/// One subscriber's two lanes: a plain state machine, no I/O.
#[derive(Debug)]
struct Queue {
    readings: VecDeque<(u64, Arc<str>)>,
    control: VecDeque<(u64, Arc<str>)>,
    reading_cap: usize,
    control_cap: usize,
    /// Orders lines across the two lanes.
    next_seq: u64,
    dropped: u64,
    /// READING lines given to this queue, dropped ones included.
    readings_in: u64,
    /// The place of the latest STATUS reply not yet taken: readings before
    /// it are not dropped, so its accounting holds exactly.
    fence: Option<u64>,
    /// Control lines coalesce instead of overflowing (the writer).
    coalesce: bool,
    state: QueueState,
}

/// The class of a control line, as far as coalescing cares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Class {
    Calibration,
    Status,
    /// ERROR, or anything else: may be let go for a slow writer.
    Other,
}

fn class_of(line: &str) -> Class {
    // The daemon writes "class" first; anything else is parsed.
    let class = if let Some(rest) = line.strip_prefix(r#"{"class":""#) {
        rest.split('"').next().map(str::to_owned)
    } else {
        serde_json::from_str::<LineHead>(line).ok().map(|h| h.class)
    };
    match class.as_deref() {
        Some("CALIBRATION") => Class::Calibration,
        Some("STATUS") => Class::Status,
        _ => Class::Other,
    }
}

impl Queue {
    fn new(reading_cap: usize, control_cap: usize) -> Queue {
        Queue {
            readings: VecDeque::new(),
            control: VecDeque::new(),
            reading_cap: reading_cap.max(1),
            control_cap: control_cap.max(1),
            next_seq: 0,
            dropped: 0,
            readings_in: 0,
            fence: None,
            coalesce: false,
            state: QueueState::Open,
        }
    }

    fn push(&mut self, lane: Lane, line: Arc<str>) -> Pushed {
        if self.state != QueueState::Open {
            return Pushed::Refused;
        }
        let seq = self.next_seq;
        self.next_seq += 1;
        match lane {
            Lane::Reading => {
                self.readings_in += 1;
                if self.readings.len() < self.reading_cap {
                    self.readings.push_back((seq, line));
                    return Pushed::Queued;
                }
                self.dropped += 1;
                match self.fence {
                    // The oldest readings are before a queued reply, whose
                    // accounting counts them as delivered: drop the oldest
                    // one after it, or this one.
                    Some(fence) if self.readings.front().is_some_and(|(s, _)| *s < fence) => {
                        let i = self.readings.partition_point(|(s, _)| *s < fence);
                        if i < self.readings.len() {
                            self.readings.remove(i);
                            self.readings.push_back((seq, line));
                        }
                    }
                    _ => {
                        self.readings.pop_front();
                        self.readings.push_back((seq, line));
                    }
                }
                Pushed::DroppedOldest
            }
            Lane::Control if self.coalesce => self.push_coalesced(seq, line),
            Lane::Control => {
                if self.control.len() >= self.control_cap {
                    self.evict();
                    Pushed::Overflowed
                } else {
                    self.control.push_back((seq, line));
                    Pushed::Queued
                }
            }
        }
    }

    /// The writer's control lane: a newer STATUS replaces a queued one;
    /// when full, the oldest ERROR goes (or this one, if it is an ERROR and
    /// none is queued); a CALIBRATION, and the one STATUS, are always
    /// queued, beyond the bound if need be (they are few: see the module).
    fn push_coalesced(&mut self, seq: u64, line: Arc<str>) -> Pushed {
        let class = class_of(&line);
        let mut let_go = 0;
        if class == Class::Status
            && let Some(i) = self
                .control
                .iter()
                .position(|(_, l)| class_of(l) == Class::Status)
        {
            self.control.remove(i);
            let_go += 1;
        }
        if self.control.len() >= self.control_cap {
            match self
                .control
                .iter()
                .position(|(_, l)| class_of(l) == Class::Other)
            {
                Some(i) => {
                    self.control.remove(i);
                    let_go += 1;
                }
                None if class == Class::Other => return Pushed::Coalesced(let_go + 1),
                // A STATUS (at most one is queued) or a CALIBRATION.
                None => {}
            }
        }
        self.control.push_back((seq, line));
        if let_go > 0 {
            Pushed::Coalesced(let_go)
        } else {
            Pushed::Queued
        }
    }

    /// Queues a STATUS reply with this queue's accounting (see
    /// [`ReplyTo::send_status`]) and fences the readings ahead of it.
    fn push_status_reply(&mut self, status: &str, id: u64, peer: &str) -> Pushed {
        if self.state != QueueState::Open {
            return Pushed::Refused;
        }
        let accounting = serde_json::json!({
            "id": id,
            "peer": peer,
            "readings": self.readings_in,
            "dropped": self.dropped,
            "queued": self.readings.len(),
        });
        let status = status.trim_end();
        let line = match status.strip_suffix('}') {
            Some(head) if head.trim_end().ends_with('{') => {
                format!(r#"{head}"subscriber":{accounting}}}"#)
            }
            Some(head) => format!(r#"{head},"subscriber":{accounting}}}"#),
            None => status.to_owned(),
        };
        let seq = self.next_seq;
        let pushed = self.push(Lane::Control, Arc::from(line));
        if matches!(pushed, Pushed::Queued | Pushed::Coalesced(_)) {
            self.fence = Some(seq);
        }
        pushed
    }

    /// Gives back the memory of lanes that grew in a burst, once empty.
    fn shrink_idle(&mut self) {
        if self.readings.is_empty() && self.readings.capacity() > SHRINK_LANE_ABOVE {
            self.readings = VecDeque::new();
        }
        if self.control.is_empty() && self.control.capacity() > SHRINK_LANE_ABOVE {
            self.control = VecDeque::new();
        }
    }

    /// The next line in publish order, from either lane.
    fn pop(&mut self) -> Option<Arc<str>> {
        let control_first = match (self.readings.front(), self.control.front()) {
            (Some((r, _)), Some((c, _))) => c < r,
            (None, Some(_)) => true,
            (_, None) => false,
        };
        let lane = if control_first {
            &mut self.control
        } else {
            &mut self.readings
        };
        let (seq, line) = lane.pop_front()?;
        if control_first && self.fence.is_some_and(|f| seq >= f) {
            self.fence = None;
        }
        Some(line)
    }

    fn len(&self) -> usize {
        self.readings.len() + self.control.len()
    }

    fn close(&mut self) {
        if self.state == QueueState::Open {
            self.state = QueueState::Closing;
        }
    }

    fn evict(&mut self) {
        self.readings = VecDeque::new();
        self.control = VecDeque::new();
        self.state = QueueState::Evicted;
    }
}

/// Why a subscriber's session ended; logged only.
#[derive(Debug, thiserror::Error)]
enum SessionEnd {
    #[error("closed by the hub")]
    Closed,
    #[error("the client hung up")]
    Hangup,
    #[error("evicted: its control queue overflowed")]
    Evicted,
    #[error("cut off: it did not take its lines before the deadline")]
    TimedOut,
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
}

fn log_end(sub: &Subscriber, end: Result<(), SessionEnd>) {
    let reason = match end {
        Ok(()) => SessionEnd::Closed,
        Err(e) => e,
    };
    tracing::debug!(id = sub.id, peer = %sub.peer, %reason, "subscriber left");
}

/// Drains the subscriber's queue into `out` until it is closed (Ok) or
/// evicted, or `out` fails.
async fn write_loop<W: AsyncWrite + Unpin>(
    sub: &Subscriber,
    out: &mut W,
) -> Result<(), SessionEnd> {
    let mut deadline = sub.deadline.subscribe();
    let mut buf: Vec<u8> = Vec::new();
    loop {
        buf.clear();
        let state = {
            let mut q = sub.queue();
            while buf.len() < MAX_BATCH_BYTES {
                let Some(line) = q.pop() else { break };
                buf.extend_from_slice(line.as_bytes());
                buf.push(b'\n');
            }
            if buf.is_empty() {
                q.shrink_idle();
            }
            q.state
        };
        if state == QueueState::Evicted {
            return Err(SessionEnd::Evicted);
        }
        if buf.is_empty() {
            if buf.capacity() > SHRINK_BUF_ABOVE {
                buf = Vec::new();
            }
            if state == QueueState::Closing {
                by_deadline(&mut deadline, out.shutdown()).await??;
                return Ok(());
            }
            sub.wake.notified().await;
            continue;
        }
        by_deadline(&mut deadline, async {
            out.write_all(&buf).await?;
            out.flush().await
        })
        .await??;
    }
}

/// Reads command lines and forwards them until the client hangs up.
///
/// Every line (a bad one too) takes a token from `bucket`; when it is empty
/// nothing more is read until one is there, so a flood is held back by TCP
/// itself. A `recalibrate` not allowed by `access` from `origin` is
/// answered with an ERROR.
async fn read_loop<R: AsyncRead + Unpin>(
    sub: &Arc<Subscriber>,
    rd: &mut R,
    commands: &mpsc::Sender<(ClientCommand, ReplyTo)>,
    origin: Origin,
    access: &Access,
    bucket: &mut Bucket,
) -> Result<(), SessionEnd> {
    let mut lines = LineSplitter::new(MAX_COMMAND_LEN);
    let mut chunk = vec![0u8; 4096];
    loop {
        let n = rd.read(&mut chunk).await?;
        if n == 0 {
            // A half line left in `lines` is dropped: its sender is gone.
            return Err(SessionEnd::Hangup);
        }
        lines.feed(&chunk[..n]);
        while let Some(line) = lines.next_line() {
            bucket.wait().await;
            let parsed = match line {
                Ok(line) if line.iter().all(u8::is_ascii_whitespace) => continue,
                Ok(line) => parse_request(&line).and_then(|r| match &r.command {
                    ClientCommand::Recalibrate { .. } => access
                        .check_recalibrate(origin, r.token.as_deref())
                        .map(|()| r.command)
                        .map_err(CommandError::Refused),
                    ClientCommand::Status => Ok(r.command),
                }),
                Err(LineTooLong { limit }) => Err(CommandError::TooLong { limit }),
            };
            match parsed {
                Ok(command) => {
                    let reply = ReplyTo {
                        sub: Arc::downgrade(sub),
                    };
                    if commands.send((command, reply)).await.is_err() {
                        sub.push(
                            Lane::Control,
                            error_line("the daemon is not taking commands now (shutting down)"),
                        );
                    }
                }
                Err(e) => sub.push(Lane::Control, error_line(&e.to_string())),
            }
        }
    }
}

/// Runs `fut` unless the subscriber's deadline passes first.
async fn by_deadline<F: Future>(
    deadline: &mut watch::Receiver<Option<Instant>>,
    fut: F,
) -> Result<F::Output, SessionEnd> {
    tokio::select! {
        biased;
        out = fut => Ok(out),
        () = deadline_passed(deadline) => Err(SessionEnd::TimedOut),
    }
}

async fn deadline_passed(rx: &mut watch::Receiver<Option<Instant>>) {
    loop {
        let deadline = *rx.borrow_and_update();
        if let Some(deadline) = deadline {
            tokio::time::sleep_until(deadline).await;
            return;
        }
        if rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// Resolves once the flag is true; never, if its sender is gone while false.
async fn turned_true(rx: &mut watch::Receiver<bool>) {
    loop {
        if *rx.borrow_and_update() {
            return;
        }
        if rx.changed().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("line longer than {limit} bytes")]
struct LineTooLong {
    limit: usize,
}

/// Splits a byte stream into lines of at most `max` bytes, sans I/O. A
/// longer line is reported once, as soon as it is known to be too long, and
/// the rest of it is discarded up to the next newline.
#[derive(Debug)]
struct LineSplitter {
    pending: Vec<u8>,
    max: usize,
    discarding: bool,
}

impl LineSplitter {
    fn new(max: usize) -> LineSplitter {
        LineSplitter {
            pending: Vec::new(),
            max,
            discarding: false,
        }
    }

    fn feed(&mut self, data: &[u8]) {
        self.pending.extend_from_slice(data);
    }

    /// The next complete line without its `\n` (or `\r\n`).
    fn next_line(&mut self) -> Option<Result<Vec<u8>, LineTooLong>> {
        let too_long = LineTooLong { limit: self.max };
        loop {
            match self.pending.iter().position(|&b| b == b'\n') {
                Some(end) => {
                    let mut line: Vec<u8> = self.pending.drain(..=end).collect();
                    line.pop();
                    if std::mem::take(&mut self.discarding) {
                        // The tail of a line already reported as too long.
                        continue;
                    }
                    if line.last() == Some(&b'\r') {
                        line.pop();
                    }
                    if line.len() > self.max {
                        return Some(Err(too_long));
                    }
                    return Some(Ok(line));
                }
                None => {
                    if self.discarding {
                        self.pending.clear();
                    } else if self.pending.len() > self.max + 1 {
                        // +1: the line may still end in `\r\n`.
                        self.pending.clear();
                        self.discarding = true;
                        return Some(Err(too_long));
                    }
                    return None;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(s: &str) -> Arc<str> {
        Arc::from(s)
    }

    fn drain(q: &mut Queue) -> Vec<String> {
        std::iter::from_fn(|| q.pop())
            .map(|l| l.to_string())
            .collect()
    }

    #[test]
    fn full_reading_lane_drops_oldest_and_keeps_control_in_order() {
        let mut q = Queue::new(3, 10);
        assert_eq!(q.push(Lane::Reading, line("r0")), Pushed::Queued);
        assert_eq!(q.push(Lane::Control, line("c0")), Pushed::Queued);
        for i in 1..6 {
            q.push(Lane::Reading, line(&format!("r{i}")));
        }
        q.push(Lane::Control, line("c1"));
        q.push(Lane::Reading, line("r6"));
        // Readings 0..=3 were dropped; control lines keep their place.
        assert_eq!(q.dropped, 4);
        assert_eq!(drain(&mut q), ["c0", "r4", "r5", "c1", "r6"]);
    }

    #[test]
    fn control_overflow_evicts_and_closed_queue_refuses() {
        let mut q = Queue::new(3, 2);
        q.push(Lane::Control, line("c0"));
        q.push(Lane::Control, line("c1"));
        assert_eq!(q.push(Lane::Control, line("c2")), Pushed::Overflowed);
        assert_eq!(q.state, QueueState::Evicted);
        assert_eq!(q.len(), 0);
        assert_eq!(q.push(Lane::Reading, line("r")), Pushed::Refused);

        let mut q = Queue::new(3, 2);
        q.push(Lane::Reading, line("r0"));
        q.close();
        assert_eq!(q.push(Lane::Reading, line("r1")), Pushed::Refused);
        assert_eq!(drain(&mut q), ["r0"]);
    }

    #[test]
    fn readings_ahead_of_a_status_reply_are_kept_so_its_accounting_holds() {
        let mut q = Queue::new(3, 10);
        for i in 0..5 {
            q.push(Lane::Reading, line(&format!("r{i}")));
        }
        q.push_status_reply(r#"{"class":"STATUS"}"#, 7, "p");
        // More readings while the reply waits: those after it are dropped,
        // never the three before it.
        for i in 5..9 {
            q.push(Lane::Reading, line(&format!("r{i}")));
        }
        let out = drain(&mut q);
        assert_eq!(out[..3], ["r2", "r3", "r4"]);
        let reply: Value = serde_json::from_str(&out[3]).unwrap_or_default();
        let sub = &reply["subscriber"];
        assert_eq!(
            (sub["readings"].as_u64(), sub["dropped"].as_u64()),
            (Some(5), Some(2))
        );
        assert_eq!(sub["queued"], 3);
        assert_eq!(out.len(), 4, "{out:?}");
        assert_eq!(q.readings_in, 9);
    }

    #[test]
    fn the_writers_control_lines_coalesce_and_keep_every_calibration() {
        let mut q = Queue::new(3, 2);
        q.coalesce = true;
        q.push(Lane::Control, line(r#"{"class":"STATUS","n":1}"#));
        q.push(Lane::Control, line(r#"{"class":"ERROR","n":2}"#));
        q.push(Lane::Control, line(r#"{"class":"STATUS","n":3}"#));
        q.push(Lane::Control, line(r#"{"class":"CALIBRATION","n":4}"#));
        q.push(Lane::Control, line(r#"{"class":"CALIBRATION","n":5}"#));
        q.push(Lane::Control, line(r#"{"class":"ERROR","n":6}"#));
        assert_eq!(q.state, QueueState::Open);
        assert_eq!(
            drain(&mut q),
            [
                r#"{"class":"STATUS","n":3}"#,
                r#"{"class":"CALIBRATION","n":4}"#,
                r#"{"class":"CALIBRATION","n":5}"#,
            ]
        );
    }

    #[test]
    fn splitter_handles_chunks_crlf_and_long_lines() {
        let mut s = LineSplitter::new(8);
        let mut out = Vec::new();
        for chunk in [&b"ab"[..], b"c\r\nde", b"f\n0123456789", b"abc\nok\n"] {
            s.feed(chunk);
            while let Some(l) = s.next_line() {
                out.push(l.map(|v| String::from_utf8(v).unwrap_or_default()));
            }
        }
        assert_eq!(
            out,
            [
                Ok("abc".to_owned()),
                Ok("def".to_owned()),
                Err(LineTooLong { limit: 8 }),
                Ok("ok".to_owned()),
            ]
        );
        // A too-long line that arrives whole, newline included.
        s.feed(b"0123456789\nx\n");
        assert_eq!(s.next_line(), Some(Err(LineTooLong { limit: 8 })));
        assert_eq!(s.next_line(), Some(Ok(b"x".to_vec())));
        assert_eq!(s.next_line(), None);
    }

    #[test]
    fn commands_parse_and_errors_say_what_is_allowed() {
        assert_eq!(
            parse_command(br#"{"command":"recalibrate","sensor":"compass"}"#),
            Ok(ClientCommand::Recalibrate {
                sensor: Some("compass".into())
            })
        );
        assert_eq!(
            parse_command(br#"{"command":"recalibrate"}"#),
            Ok(ClientCommand::Recalibrate { sensor: None })
        );
        assert_eq!(
            parse_command(br#"{"command":"status"}"#),
            Ok(ClientCommand::Status)
        );
        let err = |l: &[u8]| parse_command(l).err();
        assert!(matches!(err(b"hello"), Some(CommandError::NotJson(_))));
        assert_eq!(err(b"[1]"), Some(CommandError::NotObject("array")));
        assert_eq!(err(b"{}"), Some(CommandError::MissingCommand));
        assert_eq!(
            err(br#"{"command":1}"#),
            Some(CommandError::CommandNotString)
        );
        assert_eq!(
            err(br#"{"command":"fly"}"#),
            Some(CommandError::UnknownCommand("fly".into()))
        );
        assert!(matches!(
            err(br#"{"command":"status","sensor":"x"}"#),
            Some(CommandError::UnknownField { .. })
        ));
        assert_eq!(
            err(br#"{"command":"recalibrate","sensor":""}"#),
            Some(CommandError::BadSensor)
        );
        assert_eq!(err(b"\xff"), Some(CommandError::NotUtf8));
        let message = CommandError::UnknownCommand("fly".into()).to_string();
        assert!(message.contains("\"fly\"") && message.contains("recalibrate"));
        let error: Value = serde_json::from_str(&error_line("bad \"x\"")).unwrap_or_default();
        assert_eq!(error["class"], "ERROR");
        assert_eq!(error["message"], "bad \"x\"");
    }
}
