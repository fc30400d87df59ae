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

use std::collections::VecDeque;
use std::fmt;
use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
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

const ALLOWED: &str = r#"allowed: {"command":"recalibrate"} with an optional "sensor":"<name>", and {"command":"status"}, one JSON object a line"#;

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
}

/// Parses one command line (without its newline).
pub fn parse_command(line: &[u8]) -> Result<ClientCommand, CommandError> {
    let text = std::str::from_utf8(line).map_err(|_| CommandError::NotUtf8)?;
    let value: Value =
        serde_json::from_str(text).map_err(|e| CommandError::NotJson(e.to_string()))?;
    let map = match value {
        Value::Object(map) => map,
        Value::Null => return Err(CommandError::NotObject("null")),
        Value::Bool(_) => return Err(CommandError::NotObject("boolean")),
        Value::Number(_) => return Err(CommandError::NotObject("number")),
        Value::String(_) => return Err(CommandError::NotObject("string")),
        Value::Array(_) => return Err(CommandError::NotObject("array")),
    };
    let command = match map.get("command") {
        None => return Err(CommandError::MissingCommand),
        Some(Value::String(s)) => s.as_str(),
        Some(_) => return Err(CommandError::CommandNotString),
    };
    let fields: &[&str] = match command {
        "recalibrate" => &["command", "sensor"],
        "status" => &["command"],
        other => return Err(CommandError::UnknownCommand(other.to_owned())),
    };
    if let Some(field) = map.keys().find(|k| !fields.contains(&k.as_str())) {
        return Err(CommandError::UnknownField {
            command: command.to_owned(),
            field: field.clone(),
        });
    }
    if command == "status" {
        return Ok(ClientCommand::Status);
    }
    let sensor = match map.get("sensor") {
        None => None,
        Some(Value::String(s)) if !s.is_empty() => Some(s.clone()),
        Some(_) => return Err(CommandError::BadSensor),
    };
    Ok(ClientCommand::Recalibrate { sensor })
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
        Hub {
            inner: Arc::new(Inner {
                reading_cap: queue_len.max(1),
                control_cap: control_len.max(1),
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
        }
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
        let Some(reg) = self.register(peer) else {
            tracing::debug!("subscriber refused: the hub is closed");
            return;
        };
        let sub = &reg.sub;
        tracing::debug!(id = sub.id, peer = %sub.peer, "subscriber connected");
        let (mut rd, mut wr) = tokio::io::split(stream);
        let end = tokio::select! {
            end = write_loop(sub, &mut wr) => end,
            end = read_loop(sub, &mut rd, &commands) => end,
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
        self.accept_loop("TCP", accept, commands, shutdown).await;
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
        self.accept_loop("Unix-socket", accept, commands, shutdown)
            .await;
    }

    /// The accept loop both listeners share: each connection gets its own
    /// task; a failed accept (out of descriptors, say) is retried after a
    /// pause instead of spinning.
    async fn accept_loop<S, F, Fut>(
        &self,
        kind: &str,
        mut accept: F,
        commands: mpsc::Sender<(ClientCommand, ReplyTo)>,
        mut shutdown: watch::Receiver<bool>,
    ) where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
        F: FnMut() -> Fut,
        Fut: Future<Output = std::io::Result<(S, String)>>,
    {
        loop {
            let accepted = tokio::select! {
                accepted = accept() => accepted,
                () = turned_true(&mut shutdown) => break,
            };
            match accepted {
                Ok((stream, peer)) => {
                    let hub = self.clone();
                    let commands = commands.clone();
                    tokio::spawn(async move {
                        hub.serve_connection(stream, peer, commands).await;
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
        let reg = self.register("writer".to_owned());
        async move {
            let Some(reg) = reg else {
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

    fn register(&self, peer: String) -> Option<Registration> {
        let mut subs = self.inner.write_subs();
        if self.inner.closed.load(Ordering::SeqCst) {
            return None;
        }
        let (deadline, _) = watch::channel(None);
        let sub = Arc::new(Subscriber {
            id: self.inner.next_id.fetch_add(1, Ordering::Relaxed),
            peer,
            queue: Mutex::new(Queue::new(self.inner.reading_cap, self.inner.control_cap)),
            wake: Notify::new(),
            deadline,
            counters: Arc::clone(&self.inner.counters),
        });
        subs.push(Arc::clone(&sub));
        Some(Registration {
            hub: self.clone(),
            sub,
        })
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
        let mut subs = self.inner.write_subs();
        if self.inner.closed.load(Ordering::SeqCst) {
            return None;
        }
        let sub = Arc::new(self.new_subscriber(peer));
        if replay && let Some(retained) = self.inner.retained.get() {
            lock(retained).replay_into(&mut sub.queue());
        }
        subs.push(Arc::clone(&sub));
        drop(subs);
        Some(Subscription {
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
            sub: Arc::new(self.new_subscriber(peer)),
            _registration: None,
        }
    }

    fn new_subscriber(&self, peer: String) -> Subscriber {
        let (deadline, _) = watch::channel(None);
        Subscriber {
            id: self.inner.next_id.fetch_add(1, Ordering::Relaxed),
            peer,
            queue: Mutex::new(Queue::new(self.inner.reading_cap, self.inner.control_cap)),
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
        {
            let mut subs = self.hub.inner.write_subs();
            if let Some(i) = subs.iter().position(|s| s.id == self.sub.id) {
                subs.swap_remove(i);
            }
        }
        self.hub.inner.removed.notify_waiters();
    }
}

struct Subscriber {
    id: u64,
    peer: String,
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
        match pushed {
            Pushed::Queued => self.wake.notify_one(),
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
    state: QueueState,
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
                let full = self.readings.len() >= self.reading_cap;
                if full {
                    self.readings.pop_front();
                    self.dropped += 1;
                }
                self.readings.push_back((seq, line));
                if full {
                    Pushed::DroppedOldest
                } else {
                    Pushed::Queued
                }
            }
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
        lane.pop_front().map(|(_, line)| line)
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
            q.state
        };
        if state == QueueState::Evicted {
            return Err(SessionEnd::Evicted);
        }
        if buf.is_empty() {
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
async fn read_loop<R: AsyncRead + Unpin>(
    sub: &Arc<Subscriber>,
    rd: &mut R,
    commands: &mpsc::Sender<(ClientCommand, ReplyTo)>,
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
            let parsed = match line {
                Ok(line) if line.iter().all(u8::is_ascii_whitespace) => continue,
                Ok(line) => parse_command(&line),
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
