//! The live page's connections, bounded: a listener for `axum::serve` that
//! holds at most [`ConnectionLimits::requests`] connections that are not
//! event streams, gives each request's head [`ConnectionLimits::head`] to
//! arrive whole however its bytes trickle in, and closes a connection on
//! which nothing was written for [`ConnectionLimits::idle`].
//!
//! Each accepted connection holds a permit. An event stream gives its permit
//! back once the hub has accepted it as a subscriber (from then on the hub's
//! `[outputs] max_subscribers` counts it), so the page's descriptors are the
//! subscribers' plus at most `requests`: the share of
//! [`crate::daemon::publish::RESERVED_DESCRIPTORS`] kept for the page's short
//! requests, and one for a connection just accepted. When every permit is
//! held and another client connects, the connection that has been silent
//! longest (at least [`EVICT_AFTER`]: an idle keep-alive, a client that
//! trickles its head) is closed to make room, so a crowd of idle or slow
//! clients cannot lock the page out; when all of them are busy, the new
//! client is closed after [`ROOM_WAIT`].
//!
//! While every permit is held, a new client must show its request first:
//! one whose bytes are there when it is accepted is served (room is made
//! for it); one that sent nothing yet waits, with at most [`WAITING`]
//! others, up to [`FIRST_BYTES`] for them, and is closed if none come (at
//! once, when [`WAITING`] others already wait). So a crowd of connections
//! that send nothing, queued in the kernel's backlog in front of a
//! browser's request, is drained at the speed of `accept`, not one
//! eviction at a time.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::task::{Context, Poll};
use std::time::Duration;

use futures_util::StreamExt;
use futures_util::stream::FuturesUnordered;
use futures_util::task::AtomicWaker;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};

/// Connections other than event streams the page may hold at once: the 6
/// descriptors [`crate::daemon::publish::RESERVED_DESCRIPTORS`] keeps for them. A
/// browser opens the page with two or three (the page, `/api/config`, the
/// event stream, which gives its permit back).
pub const PAGE_REQUESTS: usize = 6;
/// A connection on which nothing was written for this long is closed:
/// hyper's own default for reading a request's headers (30 s), which axum's
/// server does not set. An open event stream writes a keep-alive comment
/// every 15 s, so it is never idle this long.
pub const IDLE: Duration = Duration::from_secs(30);
/// A request's head (request line and headers) must arrive whole within
/// this of its first byte, or of the connection's start: 10 s. Bytes that
/// trickle in do not extend it (Slowloris). A head is a few hundred bytes,
/// one segment on any network a robot's page is opened over; Apache's
/// mod_reqtimeout gives the first byte 20 s and nginx 60 s between reads,
/// for the open Internet.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);
/// A connection silent this long may be closed to make room for a new one
/// when every permit is held: 1 s, far longer than a request on the
/// page's network takes between its bytes.
pub const EVICT_AFTER: Duration = Duration::from_secs(1);
/// How long a new connection waits for room when every held one is busy
/// before it is closed.
pub const ROOM_WAIT: Duration = Duration::from_secs(2);
/// While the page is full, how long a new connection has to send its
/// first bytes before it is closed: 200 ms. A client sends its request
/// as soon as its side of the handshake completes, right behind the
/// handshake's last segment, so it arrives with it or a few ms later on
/// a robot's LAN or Wi-Fi; 200 ms also covers a lost segment's first
/// retransmission on a slow radio link (Linux's minimum RTO).
pub const FIRST_BYTES: Duration = Duration::from_millis(200);
/// New connections that may wait for their first bytes at once while the
/// page is full: as many as the page's own connections
/// ([`PAGE_REQUESTS`]), a browser's worth; their descriptors are kept for
/// them in [`crate::daemon::publish::RESERVED_DESCRIPTORS`]. Beyond them a
/// new connection that sent nothing yet is closed at once.
pub const WAITING: usize = 6;

/// How many connections, and how long a head may take and one may be idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectionLimits {
    pub requests: usize,
    pub idle: Duration,
    pub head: Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        ConnectionLimits {
            requests: PAGE_REQUESTS,
            idle: IDLE,
            head: HEAD_TIMEOUT,
        }
    }
}

/// What the listener knows of one connection: when it last read or wrote a
/// byte, whether it is an event stream (the hub's to count, not the page's
/// to close), and the flag that closes it.
#[derive(Debug)]
struct Slot {
    /// Milliseconds since the listener's start.
    active_ms: AtomicU64,
    /// When the request's head started arriving (ms), [`NOT_IN_HEAD`] when
    /// none is: a head still coming after [`EVICT_AFTER`] may be closed
    /// however often its bytes trickle in.
    head_ms: AtomicU64,
    /// A request is being answered (its handler runs): never closed to make
    /// room, though it may be silent for seconds (a recalibrate waits for
    /// the daemon's answer).
    busy: AtomicBool,
    streaming: AtomicBool,
    evicted: AtomicBool,
    waker: AtomicWaker,
}

const NOT_IN_HEAD: u64 = u64::MAX;

fn millis(epoch: std::time::Instant) -> u64 {
    u64::try_from(epoch.elapsed().as_millis()).unwrap_or(u64::MAX - 1)
}

impl Slot {
    fn touch(&self, epoch: std::time::Instant) {
        self.active_ms.store(millis(epoch), Ordering::Relaxed);
    }

    /// Since when the connection has made no progress that counts: its
    /// last byte, or the start of a head still arriving, whichever is
    /// older.
    fn idle_since(&self) -> u64 {
        self.active_ms
            .load(Ordering::Relaxed)
            .min(self.head_ms.load(Ordering::Relaxed))
    }
}

/// Who is connected, and the permit its connection holds: what a handler
/// gets as `ConnectInfo<Peer>`.
#[derive(Debug, Clone)]
pub struct Peer {
    pub addr: SocketAddr,
    permit: Arc<Mutex<Option<OwnedSemaphorePermit>>>,
    slot: Option<Arc<Slot>>,
}

impl Peer {
    /// Marks the connection as answering a request (or done with it): a
    /// busy one is never closed to make room.
    pub fn set_busy(&self, busy: bool) {
        if let Some(slot) = &self.slot {
            slot.busy.store(busy, Ordering::Relaxed);
        }
    }

    /// Gives the connection's permit back: it is now an event stream,
    /// counted by the hub among the subscribers, and never closed to make
    /// room for the page's requests.
    pub fn release(&self) {
        if let Some(slot) = &self.slot {
            slot.streaming.store(true, Ordering::Relaxed);
        }
        if let Ok(mut permit) = self.permit.lock() {
            permit.take();
        }
    }
}

/// A new connection that showed its first bytes (or closed) within
/// [`FIRST_BYTES`], or None.
type Newcomer = Pin<Box<dyn Future<Output = Option<(TcpStream, SocketAddr)>> + Send>>;

/// A connection just accepted, and whether its first bytes are already
/// there; None when it is closed already, was reset, or cannot be looked
/// at (it is dropped: nothing to serve).
fn sent_something(stream: TcpStream) -> Option<(TcpStream, bool)> {
    let raw = stream.into_std().ok()?;
    let mut byte = [0u8; 1];
    let sent = match raw.peek(&mut byte) {
        Ok(0) => return None,
        Ok(_) => true,
        Err(e) if e.kind() == io::ErrorKind::WouldBlock => false,
        Err(_) => return None,
    };
    Some((TcpStream::from_std(raw).ok()?, sent))
}

/// A TCP listener whose connections are bounded by [`ConnectionLimits`].
pub struct BoundedListener {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    limits: ConnectionLimits,
    epoch: std::time::Instant,
    slots: Vec<Weak<Slot>>,
    /// New connections accepted while the page was full, waiting for
    /// their first bytes (at most [`WAITING`]).
    waiting: FuturesUnordered<Newcomer>,
}

impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, BoundedListener>>
    for Peer
{
    fn connect_info(stream: axum::serve::IncomingStream<'_, BoundedListener>) -> Self {
        stream.remote_addr().clone()
    }
}

impl BoundedListener {
    pub fn new(inner: TcpListener, limits: ConnectionLimits) -> Self {
        BoundedListener {
            inner,
            permits: Arc::new(Semaphore::new(limits.requests.max(1))),
            limits,
            epoch: std::time::Instant::now(),
            slots: Vec::new(),
            waiting: FuturesUnordered::new(),
        }
    }

    /// The next connection to serve: one just accepted while a permit is
    /// free, or one that showed its first bytes while the page was full.
    /// One accepted while the page is full waits for its bytes beside the
    /// others, so the backlog behind it keeps draining.
    async fn next_client(&mut self) -> (TcpStream, SocketAddr) {
        loop {
            let accepting = self.waiting.len() < WAITING;
            tokio::select! {
                biased;
                Some(ready) = self.waiting.next(), if !self.waiting.is_empty() => {
                    if let Some(client) = ready {
                        return client;
                    }
                }
                (stream, addr) = axum::serve::Listener::accept(&mut self.inner) => {
                    if self.permits.available_permits() > 0 {
                        return (stream, addr);
                    }
                    let Some(stream) = sent_something(stream) else {
                        continue;
                    };
                    if stream.1 {
                        return (stream.0, addr);
                    }
                    if !accepting {
                        tracing::debug!(%addr, "the live page is full: a new connection that sent nothing yet was closed");
                        continue;
                    }
                    let stream = stream.0;
                    self.waiting.push(Box::pin(async move {
                        match tokio::time::timeout(FIRST_BYTES, stream.readable()).await {
                            Ok(Ok(())) => Some((stream, addr)),
                            _ => {
                                tracing::debug!(%addr, "the live page is full: a new connection that sent nothing was closed");
                                None
                            }
                        }
                    }));
                }
            }
        }
    }

    /// Closes the connection silent longest, if one has been silent
    /// [`EVICT_AFTER`] and is not an event stream; forgets ended ones.
    fn evict_oldest(&mut self) {
        self.slots.retain(|w| w.strong_count() > 0);
        let live: Vec<Arc<Slot>> = self.slots.iter().filter_map(Weak::upgrade).collect();
        // One closing at a time: one already told to close makes the room.
        if live.iter().any(|s| s.evicted.load(Ordering::Relaxed)) {
            return;
        }
        let now_ms = millis(self.epoch);
        let after_ms = u64::try_from(EVICT_AFTER.as_millis()).unwrap_or(u64::MAX);
        let oldest = live
            .iter()
            .filter(|s| !s.streaming.load(Ordering::Relaxed) && !s.busy.load(Ordering::Relaxed))
            .filter(|s| now_ms.saturating_sub(s.idle_since()) >= after_ms)
            .min_by_key(|s| s.idle_since());
        if let Some(slot) = oldest {
            slot.evicted.store(true, Ordering::Relaxed);
            slot.waker.wake();
            tracing::debug!("the live page closed its longest-silent connection to make room");
        }
    }

    /// A permit for a connection just accepted: at once when one is free,
    /// else once the longest-silent connection is closed for it, within
    /// [`ROOM_WAIT`]; None when every connection stayed busy that long.
    async fn room(&mut self) -> Option<OwnedSemaphorePermit> {
        let until = Instant::now() + ROOM_WAIT;
        loop {
            if let Ok(p) = self.permits.clone().try_acquire_owned() {
                return Some(p);
            }
            self.evict_oldest();
            let left = until.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            let wait = left.min(EVICT_AFTER / 4);
            if let Ok(Ok(p)) =
                tokio::time::timeout(wait, self.permits.clone().acquire_owned()).await
            {
                return Some(p);
            }
        }
    }
}

impl axum::serve::Listener for BoundedListener {
    type Io = BoundedStream;
    type Addr = Peer;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        loop {
            // Accepted first, so a client waiting for room is known to
            // exist before an idle one is closed for it.
            let (stream, addr) = self.next_client().await;
            let Some(permit) = self.room().await else {
                tracing::debug!(%addr, "the live page is busy: a new connection was closed");
                drop(stream);
                continue;
            };
            let slot = Arc::new(Slot {
                active_ms: AtomicU64::new(0),
                head_ms: AtomicU64::new(millis(self.epoch)),
                busy: AtomicBool::new(false),
                streaming: AtomicBool::new(false),
                evicted: AtomicBool::new(false),
                waker: AtomicWaker::new(),
            });
            slot.touch(self.epoch);
            // Ended connections are forgotten at every accept, so the list
            // holds at most the connections open now.
            self.slots.retain(|w| w.strong_count() > 0);
            self.slots.push(Arc::downgrade(&slot));
            let permit = Arc::new(Mutex::new(Some(permit)));
            let io = BoundedStream {
                stream,
                limits: self.limits,
                in_head: true,
                deadline: Box::pin(tokio::time::sleep(self.limits.head)),
                epoch: self.epoch,
                slot: slot.clone(),
                _permit: permit.clone(),
            };
            return (
                io,
                Peer {
                    addr,
                    permit,
                    slot: Some(slot),
                },
            );
        }
    }

    fn local_addr(&self) -> io::Result<Self::Addr> {
        Ok(Peer {
            addr: self.inner.local_addr()?,
            permit: Arc::new(Mutex::new(None)),
            slot: None,
        })
    }
}

/// An accepted connection: its stream, its deadline (the head's while a
/// request arrives, the idle one after a write), its slot, and its permit
/// (given back when the connection is dropped, unless released earlier).
pub struct BoundedStream {
    stream: TcpStream,
    limits: ConnectionLimits,
    /// A request's head is arriving: reads do not move the deadline.
    in_head: bool,
    deadline: Pin<Box<Sleep>>,
    epoch: std::time::Instant,
    slot: Arc<Slot>,
    _permit: Arc<Mutex<Option<OwnedSemaphorePermit>>>,
}

impl BoundedStream {
    /// Bytes read: the first of a request starts its head's deadline;
    /// later ones move nothing.
    fn read_some(&mut self) {
        self.slot.touch(self.epoch);
        if !self.in_head {
            self.in_head = true;
            self.slot
                .head_ms
                .store(millis(self.epoch), Ordering::Relaxed);
            self.deadline
                .as_mut()
                .reset(Instant::now() + self.limits.head);
        }
    }

    /// Bytes written: the request was answered; the idle deadline runs.
    fn wrote_some(&mut self) {
        self.slot.touch(self.epoch);
        self.slot.head_ms.store(NOT_IN_HEAD, Ordering::Relaxed);
        self.in_head = false;
        self.deadline
            .as_mut()
            .reset(Instant::now() + self.limits.idle);
    }

    /// Why the connection must close now, if it must: its deadline passed,
    /// or the listener closed it to make room.
    fn closing(&mut self, cx: &mut Context<'_>) -> Option<io::Error> {
        self.slot.waker.register(cx.waker());
        if self.slot.evicted.load(Ordering::Relaxed) {
            return Some(io::Error::new(
                io::ErrorKind::ConnectionAborted,
                "closed to make room for a new client: every connection the live page keeps was taken",
            ));
        }
        if self.deadline.as_mut().poll(cx).is_ready() {
            return Some(if self.in_head {
                io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "the request's head did not arrive within {:?}: the connection was closed",
                        self.limits.head
                    ),
                )
            } else {
                io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "nothing written for {:?}: the connection was closed",
                        self.limits.idle
                    ),
                )
            });
        }
        None
    }

    /// A write's outcome: bytes written are progress; a peer that stopped
    /// reading meets the same deadline.
    fn after_write(
        &mut self,
        cx: &mut Context<'_>,
        written: Poll<io::Result<usize>>,
    ) -> Poll<io::Result<usize>> {
        match written {
            Poll::Ready(Ok(n)) => {
                if n > 0 {
                    self.wrote_some();
                }
                Poll::Ready(Ok(n))
            }
            Poll::Ready(e) => Poll::Ready(e),
            Poll::Pending => match self.closing(cx) {
                Some(e) => Poll::Ready(Err(e)),
                None => Poll::Pending,
            },
        }
    }
}

impl AsyncRead for BoundedStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        if this.slot.evicted.load(Ordering::Relaxed)
            && let Some(e) = this.closing(cx)
        {
            return Poll::Ready(Err(e));
        }
        let before = buf.filled().len();
        match Pin::new(&mut this.stream).poll_read(cx, buf) {
            Poll::Ready(result) => {
                if buf.filled().len() > before {
                    this.read_some();
                }
                Poll::Ready(result)
            }
            Poll::Pending => match this.closing(cx) {
                Some(e) => Poll::Ready(Err(e)),
                None => Poll::Pending,
            },
        }
    }
}

impl AsyncWrite for BoundedStream {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let written = Pin::new(&mut this.stream).poll_write(cx, buf);
        this.after_write(cx, written)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let written = Pin::new(&mut this.stream).poll_write_vectored(cx, bufs);
        this.after_write(cx, written)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_shutdown(cx)
    }
}
