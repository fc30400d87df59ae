//! The hub itself: the list of subscribers, [`Hub::publish`] that queues a
//! line for each, registering and admitting subscribers (within
//! [`Policy::max_subscribers`]), the counters, and [`Hub::close`].

use std::fmt;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock, RwLockReadGuard};
use std::time::Duration;

use serde::Serialize;
use tokio::sync::{Notify, watch};
use tokio::time::Instant;

use super::access::{Origin, Policy};
use super::queue::{Lane, Queue};
use super::retained::Retained;
use super::subscriber::Subscriber;

/// Readings a subscriber may have queued by default before its oldest are
/// dropped: a few seconds of a fast sensor.
pub const DEFAULT_QUEUE_LEN: usize = 4096;
/// Control lines (CALIBRATION, STATUS, ERROR) a subscriber may have queued
/// before it is disconnected as hopelessly behind.
pub const CONTROL_QUEUE_LEN: usize = 1024;

/// How long [`Hub::close`] (and a shut-down [`Hub::serve_writer`]) lets
/// subscribers flush what is queued.
pub const CLOSE_GRACE: Duration = Duration::from_secs(1);

/// Free memory back to the system (malloc_trim) when the subscriber count
/// falls to half its peak, once the peak was at least this.
const TRIM_PEAK: usize = 8;

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

/// The publisher hub. Cheap to clone; all clones share the subscribers.
#[derive(Clone)]
pub struct Hub {
    pub(super) inner: Arc<Inner>,
}

/// What every clone of a [`Hub`] shares.
pub(super) struct Inner {
    reading_cap: usize,
    control_cap: usize,
    pub(super) policy: Policy,
    /// The most subscribers since memory was last given back.
    peak: AtomicUsize,
    subscribers: RwLock<Vec<Arc<Subscriber>>>,
    pub(super) counters: Arc<Counters>,
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

/// The counters behind [`HubStats`], shared with each subscriber.
#[derive(Default)]
pub(super) struct Counters {
    pub(super) published: AtomicU64,
    pub(super) dropped: AtomicU64,
    pub(super) evicted: AtomicU64,
    pub(super) coalesced: AtomicU64,
    pub(super) refused: AtomicU64,
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

    /// From now on the hub keeps what a subscriber registered with
    /// [`Hub::subscribe`]`(_, true)` gets at once: the last STATUS, each
    /// sensor's last CALIBRATION and last accepted one, and the latest
    /// `readings` READING lines (fewer if its reading queue is shorter).
    /// Call it before publishing; later calls change nothing.
    pub fn keep_for_replay(&self, readings: usize) {
        let _ = self.inner.retained.set(Mutex::new(Retained::new(readings)));
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
    /// refused for the limit nor evicted. With `replay`, what
    /// [`Hub::keep_for_replay`] kept is queued first, under the same lock as
    /// the registration: no line is missed or given twice.
    pub(super) fn register(
        &self,
        peer: String,
        origin: Option<Origin>,
        replay: bool,
    ) -> Result<Registration, SubscribeError> {
        let mut subs = self.inner.write_subs();
        self.admit(&subs, origin)?;
        let sub = Arc::new(self.new_subscriber(peer, origin));
        if replay && let Some(retained) = self.inner.retained.get() {
            lock(retained).replay_into(&mut sub.queue());
        }
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

    /// A subscriber of this hub, not yet in its list.
    pub(super) fn new_subscriber(&self, peer: String, origin: Option<Origin>) -> Subscriber {
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
pub(super) struct Registration {
    hub: Hub,
    pub(super) sub: Arc<Subscriber>,
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

/// Gives freed memory back to the system (glibc keeps it otherwise).
fn release_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only walks the allocator's own free lists.
    unsafe {
        libc::malloc_trim(0);
    }
}

pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}
