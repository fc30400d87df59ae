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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::paper::PaperCalibration;
    use std::sync::{Arc, Mutex};
    use std::time::Instant;

    fn calibration(sensor: &str, id: u64) -> Calibration {
        Calibration {
            sensor: sensor.to_string(),
            id,
            model: "offset+scale".to_string(),
            params: PaperCalibration {
                a: 1.0,
                b: 0.0,
                d: 0.0,
                r: 1.0,
            },
            rms: 0.01,
            coverage_deg: 360.0,
            n: 100,
            time: 1.0,
            terms: Default::default(),
            ellipsoid: None,
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_held_write_does_not_hold_the_caller_and_order_is_kept() {
        let written = Arc::new(Mutex::new(Vec::new()));
        // Each write waits for a token: a disk that answers only when the
        // test says so (or after 10 s, if the test is wrong).
        let (release, gate) = mpsc::channel::<()>();
        let (failures_tx, mut failures) = tokio_mpsc::unbounded_channel();
        let writer = StateWriter::spawn(
            {
                let written = written.clone();
                move |c: &Calibration| {
                    let _ = gate.recv_timeout(Duration::from_secs(10));
                    written.lock().unwrap().push((c.sensor.clone(), c.id));
                    Ok(())
                }
            },
            failures_tx,
        )
        .unwrap();
        for id in 1..=3 {
            writer.save(&calibration("compass", id));
        }
        writer.save(&calibration("level", 1));
        // Had save() waited for its write, the first would be on disk.
        assert!(written.lock().unwrap().is_empty());
        for _ in 0..4 {
            release.send(()).unwrap();
        }
        assert!(writer.finish(Duration::from_secs(10)).await);
        assert_eq!(
            *written.lock().unwrap(),
            [
                ("compass".to_string(), 1),
                ("compass".to_string(), 2),
                ("compass".to_string(), 3),
                ("level".to_string(), 1)
            ]
        );
        assert!(failures.try_recv().is_err(), "no failure expected");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn failures_come_back_with_the_sensor_and_message() {
        let (failures_tx, mut failures) = tokio_mpsc::unbounded_channel();
        let writer = StateWriter::spawn(
            |c: &Calibration| {
                if c.id == 2 {
                    Err(format!("cannot write /state/{}.json: disk full", c.sensor))
                } else {
                    Ok(())
                }
            },
            failures_tx,
        )
        .unwrap();
        for id in 1..=3 {
            writer.save(&calibration("compass", id));
        }
        assert!(writer.finish(Duration::from_secs(10)).await);
        assert_eq!(
            failures.recv().await,
            Some(SaveFailure {
                sensor: "compass".to_string(),
                message: "cannot write /state/compass.json: disk full".to_string(),
            })
        );
        assert_eq!(failures.recv().await, None, "one failure only");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_hung_write_is_reported_at_the_limit() {
        let (failures_tx, _failures) = tokio_mpsc::unbounded_channel();
        let writer = StateWriter::spawn(
            |_: &Calibration| {
                std::thread::sleep(Duration::from_millis(1500));
                Ok(())
            },
            failures_tx,
        )
        .unwrap();
        writer.save(&calibration("compass", 1));
        let started = Instant::now();
        assert!(!writer.finish(Duration::from_millis(200)).await);
        assert!(started.elapsed() < Duration::from_millis(1200));
    }
}
