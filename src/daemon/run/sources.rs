//! The daemon's running sources. Each kind's start function is in
//! [`crate::daemon::source_kinds`]: each owns its port or file in a task or
//! thread of its own and sends [`SourceEvent`]s into a bounded queue of
//! its own, which the loop reads straight through [`SourceEvents`].

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::DaemonError;
use super::sensors::Sensors;
use crate::daemon::config::{Config, SourceConfig};
use crate::daemon::messages::SourceStatus;
use crate::io::csv::CsvLayout;
use crate::source::{SourceCounters, SourceEvent};

/// A running source, as the loop sees it.
pub(super) struct SourceHandle {
    pub(super) name: String,
    pub(super) counters: Arc<SourceCounters>,
    pub(super) connected: bool,
    task: SourceTask,
    /// A csv source's files and their headers, for sensors a reload binds
    /// to them.
    pub(super) csv_layout: Option<(Vec<PathBuf>, Vec<Arc<CsvLayout>>)>,
}

pub(crate) enum SourceTask {
    Async(tokio::task::JoinHandle<()>),
    Thread(std::thread::JoinHandle<()>),
    /// Asked to stop, and waited for.
    Stopped,
}

/// Every configured source, started, and what stops them.
pub(super) struct Sources {
    pub(super) handles: Vec<SourceHandle>,
    /// Tells the async sources (the Falcon-GX's serial task) to stop.
    stop_tx: watch::Sender<bool>,
    /// Tells the sources that run on threads to stop.
    stop_flag: Arc<AtomicBool>,
}

/// Events a source's queue holds before the source waits (a bridge a
/// millisecond at a time, then skips the polls it missed): a 1 kHz
/// source's 4 s.
const QUEUE: usize = 4096;

/// What a source's start function is given beside its configuration.
pub(crate) struct Start<'a> {
    /// The source's index in the configuration.
    pub(crate) index: usize,
    /// The sensors, for a csv source to bind to its files' headers.
    pub(crate) sensors: &'a mut Sensors,
    /// Where its events go.
    pub(crate) tx: mpsc::Sender<SourceEvent>,
    pub(crate) counters: &'a Arc<SourceCounters>,
    /// Tells an async source to stop.
    pub(crate) stop_rx: &'a watch::Receiver<bool>,
    /// Tells a source on a thread to stop.
    pub(crate) stop_flag: &'a Arc<AtomicBool>,
}

/// A source as its start function leaves it.
pub(crate) struct Started {
    pub(crate) task: SourceTask,
    /// A csv source's files and their headers.
    pub(crate) csv_layout: Option<(Vec<PathBuf>, Vec<Arc<CsvLayout>>)>,
}

impl From<SourceTask> for Started {
    fn from(task: SourceTask) -> Self {
        Started {
            task,
            csv_layout: None,
        }
    }
}

impl Sources {
    /// Starts every source of `config`, in order, each with a bounded
    /// queue of its own for its events.
    pub(super) fn start(
        config: &Config,
        sensors: &mut Sensors,
    ) -> Result<(Sources, SourceEvents), DaemonError> {
        let (stop_tx, stop_rx) = watch::channel(false);
        let stop_flag = Arc::new(AtomicBool::new(false));
        let mut handles = Vec::new();
        let mut queues = Vec::new();
        for (index, source) in config.sources.iter().enumerate() {
            let counters = Arc::new(SourceCounters::default());
            let (tx, rx) = mpsc::channel::<SourceEvent>(QUEUE);
            let start = Start {
                index,
                sensors: &mut *sensors,
                tx,
                counters: &counters,
                stop_rx: &stop_rx,
                stop_flag: &stop_flag,
            };
            let Started { task, csv_layout } = source.kind.spawn(source, start)?;
            queues.push(rx);
            handles.push(SourceHandle {
                name: source.name.clone(),
                counters,
                connected: false,
                task,
                csv_layout,
            });
        }
        let sources = Sources {
            handles,
            stop_tx,
            stop_flag,
        };
        Ok((sources, SourceEvents::new(queues)))
    }

    /// Asks every source to stop (the Falcon source sends its stop
    /// command). The future waits up to 2 s for each; it holds no borrow
    /// of the sources, so the loop can take their last events meanwhile
    /// (a source blocked on a full queue would not see its stop).
    pub(super) fn stop(&mut self) -> impl Future<Output = ()> + 'static {
        let _ = self.stop_tx.send(true);
        self.stop_flag.store(true, Ordering::Relaxed);
        let tasks: Vec<SourceTask> = self
            .handles
            .iter_mut()
            .map(|source| std::mem::replace(&mut source.task, SourceTask::Stopped))
            .collect();
        async move {
            for task in tasks {
                match task {
                    SourceTask::Async(handle) => {
                        let _ = tokio::time::timeout(Duration::from_secs(2), handle).await;
                    }
                    SourceTask::Thread(handle) => {
                        let _ = tokio::time::timeout(
                            Duration::from_secs(2),
                            tokio::task::spawn_blocking(move || handle.join()),
                        )
                        .await;
                    }
                    SourceTask::Stopped => {}
                }
            }
        }
    }

    /// Each source's name, connection and counters, for STATUS.
    pub(super) fn statuses(&self) -> Vec<SourceStatus<&str>> {
        self.handles
            .iter()
            .map(|s| SourceStatus {
                source: s.name.as_str(),
                connected: s.connected,
                counters: s.counters.snapshot(),
            })
            .collect()
    }
}

/// Every source's events, as the loop takes them: one bounded queue a
/// source, read straight from the loop (no forwarding task a source). Each
/// sweep takes what is waiting in every queue, up to [`TAKE_PER_QUEUE`]
/// from each, starting one queue further round each time, so a busy
/// source cannot keep the others waiting and the queues are looked at
/// once a batch rather than once an event. A queue found empty wakes the
/// loop on its next event.
pub(super) struct SourceEvents {
    queues: Vec<Option<mpsc::Receiver<SourceEvent>>>,
    /// Taken from the queues, not yet handled, in order within a source.
    ready: VecDeque<(usize, SourceEvent)>,
    /// The queue the next sweep starts at.
    first: usize,
    /// One queue's events as a sweep takes them.
    batch: Vec<SourceEvent>,
}

/// Events taken from one queue in one sweep.
const TAKE_PER_QUEUE: usize = 64;

impl SourceEvents {
    fn new(queues: Vec<mpsc::Receiver<SourceEvent>>) -> Self {
        SourceEvents {
            queues: queues.into_iter().map(Some).collect(),
            ready: VecDeque::new(),
            first: 0,
            batch: Vec::with_capacity(TAKE_PER_QUEUE),
        }
    }

    /// The next event and its source's index; `None` once every source has
    /// ended and its queue is empty.
    pub(super) async fn recv(&mut self) -> Option<(usize, SourceEvent)> {
        std::future::poll_fn(|cx| self.poll_recv(cx)).await
    }

    fn poll_recv(&mut self, cx: &mut Context<'_>) -> Poll<Option<(usize, SourceEvent)>> {
        // An event spends the task's budget as a channel's would, so a
        // flood of events still lets the runtime run its other tasks.
        let coop = std::task::ready!(tokio::task::coop::poll_proceed(cx));
        let open = self.ready.is_empty() && self.sweep(cx);
        match self.ready.pop_front() {
            Some(event) => {
                coop.made_progress();
                Poll::Ready(Some(event))
            }
            None if open => Poll::Pending,
            None => Poll::Ready(None),
        }
    }

    /// Takes what waits in every queue, up to [`TAKE_PER_QUEUE`] from
    /// each, starting one queue further round than the last sweep; a queue
    /// found empty wakes this task on its next event. Whether any queue is
    /// still open.
    fn sweep(&mut self, cx: &mut Context<'_>) -> bool {
        let count = self.queues.len();
        let mut open = false;
        for step in 0..count {
            let index = (self.first + step) % count;
            let Some(queue) = &mut self.queues[index] else {
                continue;
            };
            // Unlike `try_recv`, this never parks the thread while a
            // sender is half-way through its send.
            match queue.poll_recv_many(cx, &mut self.batch, TAKE_PER_QUEUE) {
                // Closed, and nothing left in it.
                Poll::Ready(0) => self.queues[index] = None,
                Poll::Ready(_) => {
                    open = true;
                    self.ready
                        .extend(self.batch.drain(..).map(|event| (index, event)));
                }
                Poll::Pending => open = true,
            }
        }
        self.first = (self.first + 1) % count.max(1);
        open
    }

    /// What is waiting now, without waiting: for the last events once the
    /// sources are stopped.
    pub(super) fn try_recv(&mut self) -> Option<(usize, SourceEvent)> {
        if let Some(event) = self.ready.pop_front() {
            return Some(event);
        }
        for (index, queue) in self.queues.iter_mut().enumerate() {
            if let Some(queue) = queue
                && let Ok(event) = queue.try_recv()
            {
                return Some((index, event));
            }
        }
        None
    }
}

/// A source whose thread could not be started.
pub(crate) fn cannot_start(source: &SourceConfig, e: std::io::Error) -> DaemonError {
    DaemonError::Source {
        name: source.name.clone(),
        source: e,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn connected(device: &str) -> SourceEvent {
        SourceEvent::Connected {
            device: device.into(),
        }
    }

    fn device(event: &SourceEvent) -> &str {
        match event {
            SourceEvent::Connected { device } => device,
            other => panic!("not a Connected: {other:?}"),
        }
    }

    #[tokio::test]
    async fn a_busy_source_does_not_keep_the_others_waiting_and_each_keeps_its_order() {
        let (busy_tx, busy_rx) = mpsc::channel(QUEUE);
        let (quiet_tx, quiet_rx) = mpsc::channel(QUEUE);
        for k in 0..1000 {
            busy_tx.send(connected(&format!("busy{k}"))).await.unwrap();
        }
        quiet_tx.send(connected("quiet0")).await.unwrap();
        quiet_tx.send(connected("quiet1")).await.unwrap();
        let mut events = SourceEvents::new(vec![busy_rx, quiet_rx]);

        let mut seen = Vec::new();
        for _ in 0..(TAKE_PER_QUEUE + 2) {
            let (index, event) = events.recv().await.unwrap();
            seen.push((index, device(&event).to_owned()));
        }
        // The quiet source's two events come within the busy one's first
        // batch, not after its thousand.
        let quiet: Vec<_> = seen.iter().filter(|(i, _)| *i == 1).collect();
        assert_eq!(quiet.len(), 2, "{seen:?}");
        assert_eq!(quiet[0].1, "quiet0");
        assert_eq!(quiet[1].1, "quiet1");
        let busy: Vec<_> = seen
            .iter()
            .filter(|(i, _)| *i == 0)
            .map(|(_, d)| d.clone())
            .collect();
        let expected: Vec<_> = (0..TAKE_PER_QUEUE).map(|k| format!("busy{k}")).collect();
        assert_eq!(busy, expected);

        // The rest, in order, then nothing once every source has ended.
        drop((busy_tx, quiet_tx));
        let mut rest = 0;
        while let Some((index, event)) = events.recv().await {
            assert_eq!(index, 0);
            assert_eq!(device(&event), format!("busy{}", TAKE_PER_QUEUE + rest));
            rest += 1;
        }
        assert_eq!(rest, 1000 - TAKE_PER_QUEUE);
    }

    #[tokio::test]
    async fn each_sweep_starts_one_queue_further_round() {
        let (first_tx, first_rx) = mpsc::channel(QUEUE);
        let (second_tx, second_rx) = mpsc::channel(QUEUE);
        for k in 0..200 {
            first_tx.try_send(connected(&format!("a{k}"))).unwrap();
            second_tx.try_send(connected(&format!("b{k}"))).unwrap();
        }
        let mut events = SourceEvents::new(vec![first_rx, second_rx]);
        let mut order = Vec::new();
        for _ in 0..(4 * TAKE_PER_QUEUE) {
            order.push(events.recv().await.unwrap().0);
        }
        let batches: Vec<usize> = order.chunks(TAKE_PER_QUEUE).map(|c| c[0]).collect();
        assert!(
            order
                .chunks(TAKE_PER_QUEUE)
                .all(|c| c.iter().all(|&i| i == c[0])),
            "{order:?}"
        );
        // The second sweep starts at the second queue.
        assert_eq!(batches, [0, 1, 1, 0]);
    }

    #[tokio::test]
    async fn the_loop_waits_for_a_quiet_source_and_wakes_for_its_event() {
        let (first_tx, first_rx) = mpsc::channel(QUEUE);
        let (second_tx, second_rx) = mpsc::channel(QUEUE);
        let mut events = SourceEvents::new(vec![first_rx, second_rx]);
        drop(first_tx);
        let waiting = tokio::time::timeout(Duration::from_millis(50), events.recv()).await;
        assert!(
            waiting.is_err(),
            "an open source's empty queue is waited on"
        );
        let sent = std::time::Instant::now();
        tokio::spawn(async move {
            tokio::time::sleep(Duration::from_millis(20)).await;
            second_tx.send(connected("late")).await.unwrap();
        });
        let (index, event) = tokio::time::timeout(Duration::from_secs(5), events.recv())
            .await
            .expect("woken by the late event")
            .unwrap();
        assert_eq!((index, device(&event)), (1, "late"));
        // Woken by the event, not found when the timeout gave up.
        assert!(
            sent.elapsed() < Duration::from_secs(2),
            "{:?}",
            sent.elapsed()
        );
        assert!(events.recv().await.is_none(), "both sources have ended");
    }

    #[tokio::test]
    async fn what_is_left_at_stop_is_taken_without_waiting_in_order() {
        let (first_tx, first_rx) = mpsc::channel(QUEUE);
        let (second_tx, second_rx) = mpsc::channel(QUEUE);
        let mut events = SourceEvents::new(vec![first_rx, second_rx]);
        assert!(events.try_recv().is_none());
        first_tx.try_send(connected("a")).unwrap();
        second_tx.try_send(connected("b")).unwrap();
        first_tx.try_send(connected("c")).unwrap();
        // The loop took one; the sweep left the others taken, not handled.
        let (index, event) = events.recv().await.unwrap();
        assert_eq!((index, device(&event)), (0, "a"));
        first_tx.try_send(connected("d")).unwrap();
        let mut left = Vec::new();
        while let Some((index, event)) = events.try_recv() {
            left.push((index, device(&event).to_owned()));
        }
        assert_eq!(
            left,
            [
                (0, "c".to_owned()),
                (1, "b".to_owned()),
                (0, "d".to_owned())
            ]
        );
    }
}
