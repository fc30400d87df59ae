//! The live page's connections, bounded: a listener for `axum::serve` that
//! holds at most [`ConnectionLimits::requests`] connections that are not
//! event streams, and closes a connection on which nothing was read or
//! written for [`ConnectionLimits::idle`].
//!
//! Each accepted connection holds a permit. An event stream gives its permit
//! back once the hub has accepted it as a subscriber (from then on the hub's
//! `[outputs] max_subscribers` counts it), so the page's descriptors are the
//! subscribers' plus at most `requests`: the share of
//! [`crate::daemon::publish::RESERVED_DESCRIPTORS`] kept for the page's short
//! requests. While every permit is held, further clients wait in the
//! kernel's accept backlog (no descriptor is used) until a connection ends
//! or goes idle.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};

/// Connections other than event streams the page may hold at once: the 6
/// descriptors [`crate::daemon::publish::RESERVED_DESCRIPTORS`] keeps for them. A
/// browser opens the page with two or three (the page, `/api/config`, the
/// event stream, which gives its permit back).
pub const PAGE_REQUESTS: usize = 6;
/// A connection on which nothing was read or written for this long is
/// closed: hyper's own default for reading a request's headers (30 s),
/// which axum's server does not set. An open event stream writes a
/// keep-alive comment every 15 s, so it is never idle this long.
pub const IDLE: Duration = Duration::from_secs(30);

/// How many connections, and how long one may be idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectionLimits {
    pub requests: usize,
    pub idle: Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        ConnectionLimits {
            requests: PAGE_REQUESTS,
            idle: IDLE,
        }
    }
}

/// Who is connected, and the permit its connection holds: what a handler
/// gets as `ConnectInfo<Peer>`.
#[derive(Debug, Clone)]
pub struct Peer {
    pub addr: SocketAddr,
    permit: Arc<Mutex<Option<OwnedSemaphorePermit>>>,
}

impl Peer {
    /// Gives the connection's permit back: it is now an event stream,
    /// counted by the hub among the subscribers.
    pub fn release(&self) {
        if let Ok(mut permit) = self.permit.lock() {
            permit.take();
        }
    }
}

/// A TCP listener whose connections are bounded by [`ConnectionLimits`].
pub struct BoundedListener {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    idle: Duration,
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
            idle: limits.idle,
        }
    }
}

impl axum::serve::Listener for BoundedListener {
    type Io = BoundedStream;
    type Addr = Peer;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        // The semaphore is never closed, so acquiring only waits.
        let permit = loop {
            if let Ok(p) = self.permits.clone().acquire_owned().await {
                break p;
            }
        };
        let (stream, addr) = axum::serve::Listener::accept(&mut self.inner).await;
        let permit = Arc::new(Mutex::new(Some(permit)));
        let io = BoundedStream {
            stream,
            idle: self.idle,
            deadline: Box::pin(tokio::time::sleep(self.idle)),
            _permit: permit.clone(),
        };
        (io, Peer { addr, permit })
    }

    fn local_addr(&self) -> io::Result<Self::Addr> {
        Ok(Peer {
            addr: self.inner.local_addr()?,
            permit: Arc::new(Mutex::new(None)),
        })
    }
}

/// An accepted connection: its stream, its idle deadline, and its permit
/// (given back when the connection is dropped, unless released earlier).
pub struct BoundedStream {
    stream: TcpStream,
    idle: Duration,
    deadline: Pin<Box<Sleep>>,
    _permit: Arc<Mutex<Option<OwnedSemaphorePermit>>>,
}

impl BoundedStream {
    fn active(&mut self) {
        self.deadline.as_mut().reset(Instant::now() + self.idle);
    }

    fn timed_out(&mut self, cx: &mut Context<'_>) -> bool {
        self.deadline.as_mut().poll(cx).is_ready()
    }

    /// A write's outcome: bytes written are activity; a peer that stopped
    /// reading meets the same idle deadline.
    fn after_write(
        &mut self,
        cx: &mut Context<'_>,
        written: Poll<io::Result<usize>>,
    ) -> Poll<io::Result<usize>> {
        match written {
            Poll::Ready(Ok(n)) => {
                if n > 0 {
                    self.active();
                }
                Poll::Ready(Ok(n))
            }
            Poll::Ready(e) => Poll::Ready(e),
            Poll::Pending if self.timed_out(cx) => Poll::Ready(Err(idle_error(self.idle))),
            Poll::Pending => Poll::Pending,
        }
    }
}

fn idle_error(idle: Duration) -> io::Error {
    io::Error::new(
        io::ErrorKind::TimedOut,
        format!("nothing read or written for {idle:?}: the connection was closed"),
    )
}

impl AsyncRead for BoundedStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let before = buf.filled().len();
        match Pin::new(&mut this.stream).poll_read(cx, buf) {
            Poll::Ready(result) => {
                if buf.filled().len() > before {
                    this.active();
                }
                Poll::Ready(result)
            }
            Poll::Pending if this.timed_out(cx) => Poll::Ready(Err(idle_error(this.idle))),
            Poll::Pending => Poll::Pending,
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
