//! One subscriber as the hub holds it ([`Subscriber`]: its queue, the
//! writer's wake-up and deadline), an in-process one ([`Subscription`]),
//! and where the answer to its command goes ([`ReplyTo`]).

use std::fmt;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard, Weak};

use tokio::sync::{Notify, watch};
use tokio::time::Instant;

use super::access::Origin;
use super::hub::{Counters, Hub, Registration, SubscribeError, lock};
use super::queue::{Lane, Pushed, Queue, QueueState};

pub(super) struct Subscriber {
    pub(super) id: u64,
    pub(super) peer: String,
    /// None for the writer (stdout).
    pub(super) origin: Option<Origin>,
    pub(super) queue: Mutex<Queue>,
    /// Wakes the writer: a line was queued, or the queue was closed.
    pub(super) wake: Notify,
    /// When set, the time by which the writer must be done; interrupts a
    /// write blocked on a client that does not read.
    pub(super) deadline: watch::Sender<Option<Instant>>,
    pub(super) counters: Arc<Counters>,
}

impl Subscriber {
    pub(super) fn queue(&self) -> MutexGuard<'_, Queue> {
        lock(&self.queue)
    }

    pub(super) fn push(&self, lane: Lane, line: Arc<str>) {
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

    pub(super) fn begin_close(&self, deadline: Instant) {
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
        ReplyTo::to(&self.sub)
    }
}

impl Hub {
    /// Registers an in-process subscriber. With `replay`, what
    /// [`Hub::keep_for_replay`] kept is queued first, atomically with the
    /// registration: no line is missed or given twice. None once the hub is
    /// closed.
    pub fn subscribe(&self, peer: String, replay: bool) -> Option<Subscription> {
        self.try_subscribe(peer, Origin::Http, replay).ok()
    }

    /// [`Hub::subscribe`] for a subscriber from `origin`, saying why it was
    /// refused: the hub is closed, or
    /// [`Policy::max_subscribers`](super::Policy::max_subscribers) are
    /// connected.
    pub fn try_subscribe(
        &self,
        peer: String,
        origin: Origin,
        replay: bool,
    ) -> Result<Subscription, SubscribeError> {
        let reg = self.register(peer, Some(origin), replay)?;
        Ok(Subscription {
            sub: Arc::clone(&reg.sub),
            _registration: Some(reg),
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
    /// Answers go to `sub`, while it exists.
    pub(super) fn to(sub: &Arc<Subscriber>) -> ReplyTo {
        ReplyTo {
            sub: Arc::downgrade(sub),
        }
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
