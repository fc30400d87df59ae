//! A simulated Falcon-GX-style IMU, sans-IO: it listens for the start and
//! stop commands and, while started, hands out one chunk of bytes per frame
//! period. The harness that owns the port decides when a period has passed.

use crate::protocol::falcon::{START_CONTINUOUS, STOP_CONTINUOUS};

/// The device's state: what it has been told, and what it has left to send.
#[derive(Debug, Clone)]
pub struct MockFalcon {
    /// What the device sends, one chunk per period (a frame, or whatever a
    /// capture recorded: garbage and split frames included).
    chunks: Vec<Vec<u8>>,
    next: usize,
    streaming: bool,
    /// The last bytes received, to find a command split across reads.
    command: Vec<u8>,
    starts: u32,
    stops: u32,
}

impl MockFalcon {
    pub fn new(chunks: Vec<Vec<u8>>) -> Self {
        MockFalcon {
            chunks,
            next: 0,
            streaming: false,
            command: Vec::new(),
            starts: 0,
            stops: 0,
        }
    }

    /// Takes bytes the host wrote; recognises start and stop commands even
    /// when they arrive split across writes.
    pub fn receive(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.command.push(b);
            if self.command.len() > START_CONTINUOUS.len() {
                self.command.remove(0);
            }
            if self.command == START_CONTINUOUS {
                self.streaming = true;
                self.starts += 1;
                self.command.clear();
            } else if self.command == STOP_CONTINUOUS {
                self.streaming = false;
                self.stops += 1;
                self.command.clear();
            }
        }
    }

    /// The bytes to send for this period, if the device is streaming and has
    /// any left.
    pub fn tick(&mut self) -> Option<&[u8]> {
        if !self.streaming {
            return None;
        }
        let chunk = self.chunks.get(self.next)?;
        self.next += 1;
        Some(chunk)
    }

    /// The device lost power (cable pulled): it forgets it was started, and
    /// waits for a new start command, as a real device does.
    pub fn power_cycle(&mut self) {
        self.streaming = false;
        self.command.clear();
    }

    pub fn is_streaming(&self) -> bool {
        self.streaming
    }

    /// Chunks sent so far.
    pub fn sent(&self) -> usize {
        self.next
    }

    pub fn remaining(&self) -> usize {
        self.chunks.len() - self.next
    }

    /// How many start and stop commands the device has seen.
    pub fn commands_seen(&self) -> (u32, u32) {
        (self.starts, self.stops)
    }
}
