//! What the hub keeps for a subscriber that connects late (the live page):
//! the last STATUS, each sensor's last CALIBRATION and last accepted one,
//! and the latest readings, replayed in publish order.

use std::collections::VecDeque;
use std::sync::Arc;

use super::queue::{Lane, LineHead, Queue};

/// The state a late subscriber needs: the last STATUS, each sensor's last
/// CALIBRATION and last accepted one, and the latest readings; each with
/// its place in publish order, in which they are replayed.
#[derive(Debug, Default)]
pub(super) struct Retained {
    readings_cap: usize,
    next: u64,
    readings: VecDeque<(u64, Arc<str>)>,
    status: Option<(u64, Arc<str>)>,
    /// In order of first appearance, at most [`MAX_RETAINED_SENSORS`].
    calibrations: Vec<RetainedSensor>,
}

#[derive(Debug)]
struct RetainedSensor {
    sensor: String,
    last: (u64, Arc<str>),
    last_accepted: Option<(u64, Arc<str>)>,
}

/// Sensors whose calibrations are retained: sensors come from the
/// configuration, so this only bounds memory against a bug.
const MAX_RETAINED_SENSORS: usize = 1024;

impl Retained {
    /// Nothing kept yet; at most `readings_cap` readings will be.
    pub(super) fn new(readings_cap: usize) -> Retained {
        Retained {
            readings_cap,
            ..Retained::default()
        }
    }

    pub(super) fn keep(&mut self, lane: Lane, line: &Arc<str>) {
        let seq = self.next;
        self.next += 1;
        let entry = (seq, Arc::clone(line));
        if lane == Lane::Reading {
            if self.readings_cap == 0 {
                return;
            }
            if self.readings.len() >= self.readings_cap {
                self.readings.pop_front();
            }
            self.readings.push_back(entry);
            return;
        }
        // Control lines are rare: parsing their head costs nothing that matters.
        let Ok(head) = serde_json::from_str::<LineHead>(line) else {
            return;
        };
        match (head.class.as_str(), head.sensor) {
            ("STATUS", _) => self.status = Some(entry),
            ("CALIBRATION", Some(sensor)) => {
                let accepted = head.accepted == Some(true);
                let full = self.calibrations.len() >= MAX_RETAINED_SENSORS;
                match self.calibrations.iter_mut().find(|s| s.sensor == sensor) {
                    Some(s) => {
                        if accepted {
                            s.last_accepted = Some(entry.clone());
                        }
                        s.last = entry;
                    }
                    None if !full => {
                        self.calibrations.push(RetainedSensor {
                            sensor,
                            last_accepted: accepted.then(|| entry.clone()),
                            last: entry,
                        });
                    }
                    None => {}
                }
            }
            _ => {}
        }
    }

    /// Queues the retained lines for a new subscriber in the order they
    /// were published: each sensor's last accepted calibration and its last
    /// (when another), the readings that fit its queue, the last STATUS.
    pub(super) fn replay_into(&self, queue: &mut Queue) {
        let mut lines: Vec<(u64, Lane, &Arc<str>)> = Vec::new();
        for s in &self.calibrations {
            if let Some((seq, line)) = &s.last_accepted {
                lines.push((*seq, Lane::Control, line));
            }
            if s.last_accepted.as_ref().is_none_or(|a| a.0 != s.last.0) {
                lines.push((s.last.0, Lane::Control, &s.last.1));
            }
        }
        let skip = self.readings.len().saturating_sub(queue.reading_cap);
        for (seq, line) in self.readings.iter().skip(skip) {
            lines.push((*seq, Lane::Reading, line));
        }
        if let Some((seq, line)) = &self.status {
            lines.push((*seq, Lane::Control, line));
        }
        lines.sort_unstable_by_key(|(seq, _, _)| *seq);
        for (_, lane, line) in lines {
            queue.push(lane, Arc::clone(line));
        }
    }
}
