//! One subscriber's queue, sans I/O: the two [`Lane`]s, dropping the
//! oldest readings for a slow subscriber, evicting one whose control lane
//! overflows, and coalescing the writer's control lines instead.

use std::collections::VecDeque;
use std::sync::Arc;

/// Above this many entries an idle lane gives its memory back.
const SHRINK_LANE_ABOVE: usize = 256;

/// Which lane a line travels in; decides what may be dropped for slowness.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lane {
    /// READING lines: the oldest are dropped (and counted) for a slow subscriber.
    Reading,
    /// CALIBRATION, STATUS, ERROR: never dropped; a subscriber that lets
    /// [`CONTROL_QUEUE_LEN`](super::CONTROL_QUEUE_LEN) of them pile up is
    /// disconnected instead.
    Control,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum QueueState {
    Open,
    /// Takes no more lines; the writer drains what is queued and ends.
    Closing,
    /// Dropped everything; the writer ends now.
    Evicted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Pushed {
    Queued,
    /// Queued after this many older control lines were let go (the writer
    /// only), or this line itself was (then nothing new is queued).
    Coalesced(u64),
    DroppedOldest,
    /// The control lane was full: the queue is now evicted.
    Overflowed,
    /// The queue is closing or evicted.
    Refused,
}

/// One subscriber's two lanes: a plain state machine, no I/O.
#[derive(Debug)]
pub(super) struct Queue {
    readings: VecDeque<(u64, Arc<str>)>,
    control: VecDeque<(u64, Arc<str>)>,
    pub(super) reading_cap: usize,
    control_cap: usize,
    /// Orders lines across the two lanes.
    next_seq: u64,
    pub(super) dropped: u64,
    /// READING lines given to this queue, dropped ones included.
    readings_in: u64,
    /// The place of the latest STATUS reply not yet taken: readings before
    /// it are not dropped, so its accounting holds exactly.
    fence: Option<u64>,
    /// Control lines coalesce instead of overflowing (the writer).
    pub(super) coalesce: bool,
    pub(super) state: QueueState,
}

/// The class of a control line, as far as coalescing cares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Class {
    Calibration,
    Status,
    /// ERROR, or anything else: may be let go for a slow writer.
    Other,
}

/// The head of a control line, all that coalescing and retention look at.
#[derive(serde::Deserialize)]
pub(super) struct LineHead {
    pub(super) class: String,
    #[serde(default)]
    pub(super) sensor: Option<String>,
    #[serde(default)]
    pub(super) accepted: Option<bool>,
}

fn class_of(line: &str) -> Class {
    // The daemon writes "class" first; anything else is parsed.
    let class = if let Some(rest) = line.strip_prefix(r#"{"class":""#) {
        rest.split('"').next().map(str::to_owned)
    } else {
        serde_json::from_str::<LineHead>(line).ok().map(|h| h.class)
    };
    match class.as_deref() {
        Some("CALIBRATION") => Class::Calibration,
        Some("STATUS") => Class::Status,
        _ => Class::Other,
    }
}

impl Queue {
    pub(super) fn new(reading_cap: usize, control_cap: usize) -> Queue {
        Queue {
            readings: VecDeque::new(),
            control: VecDeque::new(),
            reading_cap: reading_cap.max(1),
            control_cap: control_cap.max(1),
            next_seq: 0,
            dropped: 0,
            readings_in: 0,
            fence: None,
            coalesce: false,
            state: QueueState::Open,
        }
    }

    pub(super) fn push(&mut self, lane: Lane, line: Arc<str>) -> Pushed {
        if self.state != QueueState::Open {
            return Pushed::Refused;
        }
        let seq = self.next_seq;
        self.next_seq += 1;
        match lane {
            Lane::Reading => {
                self.readings_in += 1;
                if self.readings.len() < self.reading_cap {
                    self.readings.push_back((seq, line));
                    return Pushed::Queued;
                }
                self.dropped += 1;
                match self.fence {
                    // The oldest readings are before a queued reply, whose
                    // accounting counts them as delivered: drop the oldest
                    // one after it, or this one.
                    Some(fence) if self.readings.front().is_some_and(|(s, _)| *s < fence) => {
                        let i = self.readings.partition_point(|(s, _)| *s < fence);
                        if i < self.readings.len() {
                            self.readings.remove(i);
                            self.readings.push_back((seq, line));
                        }
                    }
                    _ => {
                        self.readings.pop_front();
                        self.readings.push_back((seq, line));
                    }
                }
                Pushed::DroppedOldest
            }
            Lane::Control if self.coalesce => self.push_coalesced(seq, line),
            Lane::Control => {
                if self.control.len() >= self.control_cap {
                    self.evict();
                    Pushed::Overflowed
                } else {
                    self.control.push_back((seq, line));
                    Pushed::Queued
                }
            }
        }
    }

    /// The writer's control lane: a newer STATUS replaces a queued one;
    /// when full, the oldest ERROR goes (or this one, if it is an ERROR and
    /// none is queued); a CALIBRATION, and the one STATUS, are always
    /// queued, beyond the bound if need be (they are few: see
    /// [the publish module's stdout section](super#stdout)).
    fn push_coalesced(&mut self, seq: u64, line: Arc<str>) -> Pushed {
        let class = class_of(&line);
        let mut let_go = 0;
        if class == Class::Status
            && let Some(i) = self
                .control
                .iter()
                .position(|(_, l)| class_of(l) == Class::Status)
        {
            self.control.remove(i);
            let_go += 1;
        }
        if self.control.len() >= self.control_cap {
            match self
                .control
                .iter()
                .position(|(_, l)| class_of(l) == Class::Other)
            {
                Some(i) => {
                    self.control.remove(i);
                    let_go += 1;
                }
                None if class == Class::Other => return Pushed::Coalesced(let_go + 1),
                // A STATUS (at most one is queued) or a CALIBRATION.
                None => {}
            }
        }
        self.control.push_back((seq, line));
        if let_go > 0 {
            Pushed::Coalesced(let_go)
        } else {
            Pushed::Queued
        }
    }

    /// Queues a STATUS reply with this queue's accounting (see
    /// [`ReplyTo::send_status`](super::ReplyTo::send_status)) and fences the
    /// readings ahead of it.
    pub(super) fn push_status_reply(&mut self, status: &str, id: u64, peer: &str) -> Pushed {
        if self.state != QueueState::Open {
            return Pushed::Refused;
        }
        let accounting = serde_json::json!({
            "id": id,
            "peer": peer,
            "readings": self.readings_in,
            "dropped": self.dropped,
            "queued": self.readings.len(),
        });
        let status = status.trim_end();
        let line = match status.strip_suffix('}') {
            Some(head) if head.trim_end().ends_with('{') => {
                format!(r#"{head}"subscriber":{accounting}}}"#)
            }
            Some(head) => format!(r#"{head},"subscriber":{accounting}}}"#),
            None => status.to_owned(),
        };
        let seq = self.next_seq;
        let pushed = self.push(Lane::Control, Arc::from(line));
        if matches!(pushed, Pushed::Queued | Pushed::Coalesced(_)) {
            self.fence = Some(seq);
        }
        pushed
    }

    /// Gives back the memory of lanes that grew in a burst, once empty.
    pub(super) fn shrink_idle(&mut self) {
        if self.readings.is_empty() && self.readings.capacity() > SHRINK_LANE_ABOVE {
            self.readings = VecDeque::new();
        }
        if self.control.is_empty() && self.control.capacity() > SHRINK_LANE_ABOVE {
            self.control = VecDeque::new();
        }
    }

    /// The next line in publish order, from either lane.
    pub(super) fn pop(&mut self) -> Option<Arc<str>> {
        let control_first = match (self.readings.front(), self.control.front()) {
            (Some((r, _)), Some((c, _))) => c < r,
            (None, Some(_)) => true,
            (_, None) => false,
        };
        let lane = if control_first {
            &mut self.control
        } else {
            &mut self.readings
        };
        let (seq, line) = lane.pop_front()?;
        if control_first && self.fence.is_some_and(|f| seq >= f) {
            self.fence = None;
        }
        Some(line)
    }

    pub(super) fn len(&self) -> usize {
        self.readings.len() + self.control.len()
    }

    pub(super) fn close(&mut self) {
        if self.state == QueueState::Open {
            self.state = QueueState::Closing;
        }
    }

    fn evict(&mut self) {
        self.readings = VecDeque::new();
        self.control = VecDeque::new();
        self.state = QueueState::Evicted;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    fn line(s: &str) -> Arc<str> {
        Arc::from(s)
    }

    fn drain(q: &mut Queue) -> Vec<String> {
        std::iter::from_fn(|| q.pop())
            .map(|l| l.to_string())
            .collect()
    }

    #[test]
    fn full_reading_lane_drops_oldest_and_keeps_control_in_order() {
        let mut q = Queue::new(3, 10);
        assert_eq!(q.push(Lane::Reading, line("r0")), Pushed::Queued);
        assert_eq!(q.push(Lane::Control, line("c0")), Pushed::Queued);
        for i in 1..6 {
            q.push(Lane::Reading, line(&format!("r{i}")));
        }
        q.push(Lane::Control, line("c1"));
        q.push(Lane::Reading, line("r6"));
        // Readings 0..=3 were dropped; control lines keep their place.
        assert_eq!(q.dropped, 4);
        assert_eq!(drain(&mut q), ["c0", "r4", "r5", "c1", "r6"]);
    }

    #[test]
    fn control_overflow_evicts_and_closed_queue_refuses() {
        let mut q = Queue::new(3, 2);
        q.push(Lane::Control, line("c0"));
        q.push(Lane::Control, line("c1"));
        assert_eq!(q.push(Lane::Control, line("c2")), Pushed::Overflowed);
        assert_eq!(q.state, QueueState::Evicted);
        assert_eq!(q.len(), 0);
        assert_eq!(q.push(Lane::Reading, line("r")), Pushed::Refused);

        let mut q = Queue::new(3, 2);
        q.push(Lane::Reading, line("r0"));
        q.close();
        assert_eq!(q.push(Lane::Reading, line("r1")), Pushed::Refused);
        assert_eq!(drain(&mut q), ["r0"]);
    }

    #[test]
    fn readings_ahead_of_a_status_reply_are_kept_so_its_accounting_holds() {
        let mut q = Queue::new(3, 10);
        for i in 0..5 {
            q.push(Lane::Reading, line(&format!("r{i}")));
        }
        q.push_status_reply(r#"{"class":"STATUS"}"#, 7, "p");
        // More readings while the reply waits: those after it are dropped,
        // never the three before it.
        for i in 5..9 {
            q.push(Lane::Reading, line(&format!("r{i}")));
        }
        let out = drain(&mut q);
        assert_eq!(out[..3], ["r2", "r3", "r4"]);
        let reply: Value = serde_json::from_str(&out[3]).unwrap_or_default();
        let sub = &reply["subscriber"];
        assert_eq!(
            (sub["readings"].as_u64(), sub["dropped"].as_u64()),
            (Some(5), Some(2))
        );
        assert_eq!(sub["queued"], 3);
        assert_eq!(out.len(), 4, "{out:?}");
        assert_eq!(q.readings_in, 9);
    }

    #[test]
    fn the_writers_control_lines_coalesce_and_keep_every_calibration() {
        let mut q = Queue::new(3, 2);
        q.coalesce = true;
        q.push(Lane::Control, line(r#"{"class":"STATUS","n":1}"#));
        q.push(Lane::Control, line(r#"{"class":"ERROR","n":2}"#));
        q.push(Lane::Control, line(r#"{"class":"STATUS","n":3}"#));
        q.push(Lane::Control, line(r#"{"class":"CALIBRATION","n":4}"#));
        q.push(Lane::Control, line(r#"{"class":"CALIBRATION","n":5}"#));
        q.push(Lane::Control, line(r#"{"class":"ERROR","n":6}"#));
        assert_eq!(q.state, QueueState::Open);
        assert_eq!(
            drain(&mut q),
            [
                r#"{"class":"STATUS","n":3}"#,
                r#"{"class":"CALIBRATION","n":4}"#,
                r#"{"class":"CALIBRATION","n":5}"#,
            ]
        );
    }
}
