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
//!
//! # Modules
//! - `access`: rates, origins, the token and who may recalibrate, the
//!   subscriber limit;
//! - `commands`: command lines, parsed and answered;
//! - `hub`: the subscriber list, publishing, registering, closing;
//! - `subscriber`: one subscriber, in-process subscriptions, replies;
//! - `queue`: a subscriber's two lanes, sans I/O;
//! - `retained`: what a late subscriber is given at once;
//! - `session`: a connection's writer and reader, the accept loop;
//! - the transports: `tcp`, [`unix`] (and its socket file), `writer`
//!   (stdout), [`http`] (the live page).

mod access;
mod commands;
pub mod http;
mod hub;
mod queue;
mod retained;
mod session;
mod subscriber;
mod tcp;
pub mod unix;
mod writer;

pub use access::{
    ACCEPT_RATE, Access, COMMAND_RATE, DEFAULT_MAX_SUBSCRIBERS, MIN_TOKEN_BYTES, Origin, Policy,
    RESERVED_DESCRIPTORS, Rate, Token, check_max_subscribers, default_max_subscribers,
    descriptor_limit,
};
pub use commands::{
    ClientCommand, CommandError, MAX_COMMAND_LEN, Request, error_line, parse_command, parse_request,
};
pub use hub::{
    CLOSE_GRACE, CONTROL_QUEUE_LEN, DEFAULT_QUEUE_LEN, Hub, HubStats, SubscribeError,
    SubscriberStats,
};
pub use queue::Lane;
pub use subscriber::{ReplyTo, Subscription};
