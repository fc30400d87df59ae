//! What a person beside the sensor sees while it turns: one line per
//! sensor with the turned fraction, the headings still missing and what to
//! do, redrawn live on a terminal; or, when stderr is not a terminal
//! (systemd, a pipe), a log line at the moments that matter.
//!
//! The [`Board`] (`board`) is pure: sensor snapshots and typed
//! `CALIBRATION` events in, line text and milestone messages out. The
//! daemon's loop feeds it through a [`ProgressFeed`] (a snapshot at most
//! every [`REDRAW`], so the readings' path does not pay for it), which logs
//! the milestones when nothing is drawn live; the terminal side
//! (`terminal`): [`Live`] redraws it from its own thread with indicatif,
//! and [`LogWriter`] keeps log lines from garbling the live ones.

mod board;
mod terminal;

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

pub use board::{
    Board, HeadingNote, Outcome, REJECTION_SHOWN_BELOW_PCT, RotationView, SensorSnapshot,
    SensorView, explain, missing_text, render_line,
};
pub use terminal::{Live, LogWriter, StdoutAbove, draw_target};

use super::messages::CalibrationEvent;
use super::sensor::Sensor;

/// How often the live lines are redrawn, and the least time between the
/// loop's snapshots (it takes one on its next wake-up after this; when
/// nothing wakes it, after half as long again where the lines are drawn
/// live, and within a second of the last snapshot where milestones are
/// only logged): ten times a second is as fast as a person reads a
/// changing number.
pub const REDRAW: Duration = Duration::from_millis(100);

/// Most milestone messages kept between two drains (a log that nobody
/// drains must not grow without bound).
const MAX_PENDING: usize = 256;

/// `--progress`: when to show the live lines.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressMode {
    /// Never: log lines at the moments that matter instead.
    Never,
    /// Live lines when stderr is a terminal, log lines otherwise.
    Auto,
    /// Live lines even when stderr is not a terminal (a terminal recorder).
    Always,
}

impl ProgressMode {
    /// Whether the lines are drawn live, given whether stderr is a terminal.
    pub fn live(self, stderr_is_terminal: bool) -> bool {
        match self {
            ProgressMode::Never => false,
            ProgressMode::Auto => stderr_is_terminal,
            ProgressMode::Always => true,
        }
    }
}

impl std::str::FromStr for ProgressMode {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "never" => Ok(ProgressMode::Never),
            "auto" => Ok(ProgressMode::Auto),
            "always" => Ok(ProgressMode::Always),
            other => Err(format!(
                "'{other}' is not a progress mode: give never, auto or always"
            )),
        }
    }
}

#[derive(Debug, Default)]
struct Shared {
    board: Board,
    /// Milestones not yet logged (log mode only).
    pending: Vec<String>,
}

/// The daemon's handle on the board: cheap to clone, shared between the
/// loop (which feeds it) and the display (which reads it).
#[derive(Debug, Clone)]
pub struct ProgressFeed {
    shared: Arc<Mutex<Shared>>,
    /// Log the milestones (when nothing is drawn live).
    log: bool,
    /// The live lines stdout's lines must be printed above, when stdout is
    /// the same terminal.
    above: Option<indicatif::MultiProgress>,
}

impl ProgressFeed {
    /// A feed whose milestones are logged at info level when `log`.
    pub fn new(log: bool) -> Self {
        ProgressFeed {
            shared: Arc::default(),
            log,
            above: None,
        }
    }

    /// Whether the lines are drawn live (else the milestones are logged).
    pub fn is_live(&self) -> bool {
        !self.log
    }

    /// Lines the daemon publishes on stdout are printed above the live
    /// lines of `multi` (for a stdout on the same terminal).
    pub fn with_stdout_above(self, multi: indicatif::MultiProgress) -> Self {
        ProgressFeed {
            above: Some(multi),
            ..self
        }
    }

    /// The writer for `[outputs] stdout`, when it must keep clear of the
    /// live lines.
    pub fn stdout_above(&self) -> Option<StdoutAbove> {
        self.above.clone().map(|multi| StdoutAbove { multi })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Shared> {
        self.shared.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn keep(&self, shared: &mut Shared, logs: Vec<String>) {
        if !self.log {
            return;
        }
        shared.pending.extend(logs);
        let excess = shared.pending.len().saturating_sub(MAX_PENDING);
        shared.pending.drain(..excess);
    }

    /// The loop's snapshot of its sensors. O(sensors × sectors).
    pub fn update<'a>(&self, sensors: impl IntoIterator<Item = &'a Sensor>) {
        let snapshots: Vec<SensorSnapshot> = sensors.into_iter().map(SensorSnapshot::of).collect();
        let mut shared = self.lock();
        let logs = shared.board.update(&snapshots);
        self.keep(&mut shared, logs);
        drop(shared);
        self.flush_logs();
    }

    /// The last snapshot, at shutdown: the lines show it, nothing is logged
    /// (a rotation "started" by the last readings would only mislead).
    pub fn settle<'a>(&self, sensors: impl IntoIterator<Item = &'a Sensor>) {
        let snapshots: Vec<SensorSnapshot> = sensors.into_iter().map(SensorSnapshot::of).collect();
        let mut shared = self.lock();
        shared.board.update(&snapshots);
        drop(shared);
        self.flush_logs();
    }

    /// A `CALIBRATION` the daemon published.
    pub fn calibration(&self, event: &CalibrationEvent) {
        let mut shared = self.lock();
        let logs = shared.board.on_calibration(event);
        self.keep(&mut shared, logs);
        drop(shared);
        self.flush_logs();
    }

    /// Logs the pending milestones at info level.
    pub fn flush_logs(&self) {
        if !self.log {
            return;
        }
        let pending = std::mem::take(&mut self.lock().pending);
        for message in pending {
            tracing::info!("{message}");
        }
    }

    pub fn lines(&self) -> Vec<String> {
        self.lock().board.lines()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_modes() {
        assert_eq!("auto".parse(), Ok(ProgressMode::Auto));
        assert!("sometimes".parse::<ProgressMode>().is_err());
        assert!(!ProgressMode::Auto.live(false));
        assert!(ProgressMode::Auto.live(true));
        assert!(!ProgressMode::Never.live(true));
        assert!(ProgressMode::Always.live(false));
    }
}
