//! Stores accepted calibrations off the event loop. A state write ends in
//! two fsyncs, which take milliseconds on a PC's disk and can take hundreds
//! on an SD card; readings must not wait for them. A thread of its own
//! takes calibrations in the order they were accepted, writes each, and
//! reports failures back to the loop, which logs and publishes them.

use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

use tokio::sync::mpsc as tokio_mpsc;

use super::Calibration;

/// A save that did not happen; the stored file is the one from before.
#[derive(Debug, Clone, PartialEq)]
pub struct SaveFailure {
    pub sensor: String,
    /// Names the file and says what to do (see [`super::state::StateError`]).
    pub message: String,
}

/// The writer thread's handle: [`StateWriter::save`] queues, never blocks.
#[derive(Debug)]
pub struct StateWriter {
    queue: Option<mpsc::Sender<Calibration>>,
    thread: Option<JoinHandle<()>>,
}

impl StateWriter {
    /// Starts the thread. `save` does the write (normally
    /// [`super::state::StateStore::save`]); its failures go to `failures`.
    pub fn spawn(
        mut save: impl FnMut(&Calibration) -> Result<(), String> + Send + 'static,
        failures: tokio_mpsc::UnboundedSender<SaveFailure>,
    ) -> std::io::Result<StateWriter> {
        let (queue, calibrations) = mpsc::channel::<Calibration>();
        let thread = std::thread::Builder::new()
            .name("fieldcal-state".to_string())
            .spawn(move || {
                for calibration in calibrations {
                    if let Err(message) = save(&calibration) {
                        // The loop may be gone at shutdown; the log has it then.
                        if failures
                            .send(SaveFailure {
                                sensor: calibration.sensor.clone(),
                                message: message.clone(),
                            })
                            .is_err()
                        {
                            tracing::error!("{message}");
                        }
                    }
                }
            })?;
        Ok(StateWriter {
            queue: Some(queue),
            thread: Some(thread),
        })
    }

    /// Queues `calibration` to be stored after those queued before it.
    pub fn save(&self, calibration: &Calibration) {
        let queued = self
            .queue
            .as_ref()
            .is_some_and(|q| q.send(calibration.clone()).is_ok());
        if !queued {
            // Only if the thread died: say so rather than lose it silently.
            tracing::error!(
                sensor = calibration.sensor,
                id = calibration.id,
                "the state writer has stopped: calibration not stored"
            );
        }
    }

    /// Lets the queued writes finish, waiting at most `limit`. Returns false
    /// when writes were still running at the limit (a hung disk): they go
    /// on in the background until the process exits.
    pub async fn finish(mut self, limit: Duration) -> bool {
        drop(self.queue.take());
        let Some(thread) = self.thread.take() else {
            return true;
        };
        let joined = tokio::task::spawn_blocking(move || thread.join());
        matches!(tokio::time::timeout(limit, joined).await, Ok(Ok(Ok(()))))
    }
}
