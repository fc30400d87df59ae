//! The kinds of output, listed once as the source kinds are: each is a
//! module here with its settings, the `[outputs]` keys it takes and their
//! checks, and its start function (the [`Kind`] trait). [`kinds!`]'s one
//! invocation below lists them, in the order they start: listeners first,
//! so a bad address stops the start before anything is written. Adding an
//! output is a module and its line in that list.

use tokio::sync::{mpsc, watch};

use crate::daemon::config::{Config, ConfigError, Keys};
use crate::daemon::progress::ProgressFeed;
use crate::daemon::publish::http::PageConfig;
use crate::daemon::publish::{ClientCommand, Hub, ReplyTo};
use crate::daemon::run::DaemonError;

/// The commands subscribers send, and where their replies go.
pub(crate) type Commands = mpsc::Sender<(ClientCommand, ReplyTo)>;

/// What a kind of output provides.
pub(crate) trait Kind: Sized {
    /// Its name, as in a reload's message (`[outputs] tcp`).
    const NAME: &'static str;
    /// The `[outputs]` keys it takes.
    const KEYS: &'static [&'static str];
    /// What a reload's message says when it is not configured.
    const OFF: &'static str = "none";

    /// Its settings from `[outputs]`, checked; `None` when the keys leave
    /// it off (its other keys are checked all the same).
    fn check(keys: &Keys<'_, '_>) -> Result<Option<Self>, ConfigError>;

    /// What a reload's message names it by: its address or path.
    fn describe(&self) -> String;

    /// Starts it on the hub.
    async fn start(&self, start: &Start<'_>) -> Result<Running, DaemonError>;
}

/// What an output's start function is given.
pub(crate) struct Start<'a> {
    pub(crate) config: &'a Config,
    pub(crate) hub: &'a Hub,
    /// Where its clients' commands go.
    pub(crate) commands: &'a Commands,
    /// Turns true when the outputs stop.
    pub(crate) stop: &'a watch::Receiver<bool>,
    /// The terminal's progress lines, which stdout writes above.
    pub(crate) progress: Option<&'a ProgressFeed>,
}

/// A started output, as the stop needs it.
#[derive(Default)]
pub(crate) struct Running {
    /// A task given 1 s to finish writing what it holds.
    pub(crate) finish: Option<tokio::task::JoinHandle<()>>,
    /// What to undo after the tasks finish (a socket file to remove).
    pub(crate) undo: Option<Box<dyn FnOnce() + Send>>,
    /// The live page's configuration, which a reload updates.
    pub(crate) page: Option<PageConfig>,
}

/// Lists the kinds: each `Variant(module::Settings)` is a variant of
/// [`Output`], and every method of [`Output`] dispatches to it.
macro_rules! kinds {
    ($($variant:ident($module:ident::$settings:ident)),* $(,)?) => {
        $(pub mod $module;)*
        $(pub use $module::$settings;)*

        /// One configured output, with the settings of its kind.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Output {
            $($variant($settings),)*
        }

        /// The kinds' names, keys and what a reload says when one is off,
        /// in the list's order.
        pub(crate) const TABLE: &[(&str, &[&str], &str)] =
            &[$(($settings::NAME, $settings::KEYS, $settings::OFF)),*];

        impl Output {
            /// Its kind's name.
            pub fn name(&self) -> &'static str {
                match self {
                    $(Output::$variant(_) => $settings::NAME,)*
                }
            }

            /// Its address or path.
            pub fn describe(&self) -> String {
                match self {
                    $(Output::$variant(o) => o.describe(),)*
                }
            }

            /// Starts it.
            pub(crate) async fn start(&self, start: &Start<'_>) -> Result<Running, DaemonError> {
                match self {
                    $(Output::$variant(o) => o.start(start).await,)*
                }
            }

            /// Every output the keys of `[outputs]` configure, in the
            /// list's order.
            pub(crate) fn check_all(
                keys: &mut Keys<'_, '_>,
            ) -> Result<Vec<Output>, ConfigError> {
                let mut outputs = Vec::new();
                $(
                    keys.kind = $settings::NAME;
                    if let Some(o) = $settings::check(keys)? {
                        outputs.push(Output::$variant(o));
                    }
                )*
                Ok(outputs)
            }
        }
    };
}

kinds! {
    Tcp(tcp::Tcp),
    Unix(unix::Unix),
    Http(http::Http),
    Stdout(stdout::Stdout),
}
