//! A simulated Devantech USB-ISS with I2C chips behind it, sans-IO: feed it
//! the bytes the host wrote, get back the bytes the device would answer.
//!
//! Each chip has a 256-byte register file with its identity registers set.
//! Init writes are stored and ACKed. A burst read that starts at a chip's
//! first data register starts a poll: the next queued sample (or the
//! generator's) is encoded into the chip's registers in its own layout
//! (the LSM303DLHC magnetometer's X, Z, Y order, the accelerometer's
//! left-justified 12 bits), so the host decodes exactly what was queued.
//!
//! It can be told to refuse (NACK) an address or to go silent; it records
//! what it did as [`MockEvent`]s, which a harness drains and timestamps.
//! Timing (delays, timestamps) is the harness's job.

use std::collections::{BTreeMap, VecDeque};
use std::io;
use std::thread;
use std::time::Duration;

use crate::protocol::chips::Chip;
use crate::protocol::chips::lsm303dlhc::accel::AUTO_INCREMENT;
use crate::protocol::usb_iss::{I2C_AD1, I2C_TEST, ISS_MODE, ISS_VERSION, MAX_READ, USB_ISS};
use crate::sample::Reading;

/// Makes the sample for the n-th poll (from 0) of a chip whose queue is empty.
pub type SampleGenerator = Box<dyn FnMut(u64) -> Reading + Send>;

/// What the simulated bridge answers to a read that no chip acknowledges.
/// The real device's behaviour is not documented (see
/// [`crate::protocol::usb_iss`]); both plausible ones can be simulated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NackedRead {
    /// `n` bytes of 0xFF, clocked off an idle bus (the assumed behaviour).
    #[default]
    Ones,
    /// No reply at all: the host times out.
    Nothing,
}

/// One thing the simulated bridge did.
#[derive(Debug, Clone, PartialEq)]
pub enum MockEvent {
    ModeSet {
        mode: u8,
        io: u8,
        accepted: bool,
    },
    Write {
        address: u8,
        register: u8,
        data: Vec<u8>,
        acked: bool,
    },
    Read {
        address: u8,
        register: u8,
        len: usize,
        acked: bool,
        /// The sample loaded into the registers by this read, when it
        /// started a poll and a sample was there to load.
        sample: Option<Reading>,
    },
    Test {
        address: u8,
        present: bool,
    },
    /// A whole command received while silent: nothing was done or answered.
    Unanswered {
        command: Vec<u8>,
    },
    /// A byte that starts no known command, dropped.
    Ignored {
        byte: u8,
    },
}

struct Device {
    chip: Chip,
    registers: [u8; 256],
    queue: VecDeque<Reading>,
    generator: Option<SampleGenerator>,
    polls: u64,
    nack: bool,
    nack_writes: bool,
}

impl Device {
    fn new(chip: Chip) -> Self {
        let mut registers = [0u8; 256];
        for &(register, value) in chip.identity() {
            registers[usize::from(register)] = value;
        }
        if chip == Chip::Lsm303dlhcAccel {
            // Undocumented for the LSM303DLHC but present on the die
            // (LIS3DH-like WHO_AM_I); fieldcal does not check it.
            registers[0x0F] = 0x33;
        }
        Device {
            chip,
            registers,
            queue: VecDeque::new(),
            generator: None,
            polls: 0,
            nack: false,
            nack_writes: false,
        }
    }

    /// Register index of the i-th byte of a transfer starting at `register`:
    /// the LSM303DLHC accelerometer increments only with bit 7 set.
    fn index(&self, register: u8, i: usize) -> usize {
        if self.chip == Chip::Lsm303dlhcAccel {
            let base = usize::from(register & !AUTO_INCREMENT);
            if register & AUTO_INCREMENT != 0 {
                (base + i) & 0xFF
            } else {
                base
            }
        } else {
            (usize::from(register) + i) & 0xFF
        }
    }

    fn store(&mut self, register: u8, data: &[u8]) {
        for (i, &b) in data.iter().enumerate() {
            let at = self.index(register, i);
            self.registers[at] = b;
        }
    }

    /// Loads the next sample into the data registers, if there is one.
    fn next_sample(&mut self) -> Option<Reading> {
        let n = self.polls;
        self.polls += 1;
        let sample = match self.queue.pop_front() {
            Some(s) => s,
            None => (self.generator.as_mut()?)(n),
        };
        let bytes = self.chip.encode(&sample);
        let mut rest = &bytes[..];
        for &(register, len) in self.chip.data_reads() {
            let (part, tail) = rest.split_at(len.min(rest.len()));
            self.store(register, part);
            rest = tail;
        }
        Some(sample)
    }
}

/// A simulated USB-ISS; see the module notes.
pub struct MockUsbIss {
    pending: Vec<u8>,
    mode: Option<u8>,
    devices: BTreeMap<u8, Device>,
    silent: bool,
    nacked_read: NackedRead,
    events: Vec<MockEvent>,
    bytes_ignored: u64,
}

impl std::fmt::Debug for MockUsbIss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MockUsbIss")
            .field("mode", &self.mode)
            .field(
                "devices",
                &self
                    .devices
                    .iter()
                    .map(|(a, d)| (*a, d.chip))
                    .collect::<Vec<_>>(),
            )
            .field("silent", &self.silent)
            .finish_non_exhaustive()
    }
}

impl Default for MockUsbIss {
    fn default() -> Self {
        Self::new()
    }
}

impl MockUsbIss {
    /// A bridge with nothing on its bus, not yet in I2C mode.
    pub fn new() -> Self {
        MockUsbIss {
            pending: Vec::new(),
            mode: None,
            devices: BTreeMap::new(),
            silent: false,
            nacked_read: NackedRead::default(),
            events: Vec::new(),
            bytes_ignored: 0,
        }
    }

    /// A bridge with these chips at their default addresses.
    pub fn with_chips(chips: &[Chip]) -> Self {
        let mut mock = Self::new();
        for &chip in chips {
            mock.add_chip(chip);
        }
        mock
    }

    /// Puts `chip` on the bus at its default address.
    pub fn add_chip(&mut self, chip: Chip) {
        self.add_chip_at(chip, chip.default_address());
    }

    /// Puts `chip` on the bus at `address` (replacing whatever was there).
    pub fn add_chip_at(&mut self, chip: Chip, address: u8) {
        self.devices.insert(address, Device::new(chip));
    }

    /// Queues a sample for the chip at `address`: it is served by the next
    /// poll that finds the queue non-empty. Ignored if no chip is there.
    pub fn push_sample(&mut self, address: u8, sample: Reading) {
        if let Some(d) = self.devices.get_mut(&address) {
            d.queue.push_back(sample);
        }
    }

    /// Makes samples for the chip at `address` whenever its queue is empty.
    /// Without one, an empty queue leaves the last sample in the registers.
    pub fn set_generator(&mut self, address: u8, generator: SampleGenerator) {
        if let Some(d) = self.devices.get_mut(&address) {
            d.generator = Some(generator);
        }
    }

    /// Samples still queued for `address`.
    pub fn queued(&self, address: u8) -> usize {
        self.devices.get(&address).map_or(0, |d| d.queue.len())
    }

    /// Makes the chip at `address` refuse every transfer (or accept them
    /// again): as if it were unplugged.
    pub fn set_nack(&mut self, address: u8, nack: bool) {
        if let Some(d) = self.devices.get_mut(&address) {
            d.nack = nack;
        }
    }

    /// Makes the chip at `address` refuse writes only.
    pub fn set_nack_writes(&mut self, address: u8, nack: bool) {
        if let Some(d) = self.devices.get_mut(&address) {
            d.nack_writes = nack;
        }
    }

    /// A silent bridge takes commands and neither acts on them nor answers.
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    pub fn set_nacked_read(&mut self, behaviour: NackedRead) {
        self.nacked_read = behaviour;
    }

    /// The mode byte last set, if any.
    pub fn mode(&self) -> Option<u8> {
        self.mode
    }

    /// A register of the chip at `address`.
    pub fn register(&self, address: u8, register: u8) -> Option<u8> {
        self.devices
            .get(&address)
            .map(|d| d.registers[usize::from(register)])
    }

    /// Polls served to the chip at `address`: burst reads that started at
    /// its first data register while it answered.
    pub fn reads_served(&self, address: u8) -> u64 {
        self.devices.get(&address).map_or(0, |d| d.polls)
    }

    /// Bytes dropped because they started no known command.
    pub fn bytes_ignored(&self) -> u64 {
        self.bytes_ignored
    }

    /// Events since the last [`MockUsbIss::take_events`].
    pub fn events(&self) -> &[MockEvent] {
        &self.events
    }

    /// Drains the events; a long-running harness should call it after each
    /// feed so they do not pile up.
    pub fn take_events(&mut self) -> Vec<MockEvent> {
        std::mem::take(&mut self.events)
    }

    /// Takes bytes the host wrote (any split across calls) and returns the
    /// bytes the bridge answers to the commands they complete.
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut input = std::mem::take(&mut self.pending);
        input.extend_from_slice(bytes);
        let mut reply = Vec::new();
        let mut at = 0;
        while let Some(used) = self.step(&input[at..], &mut reply) {
            at += used;
        }
        input.drain(..at);
        self.pending = input;
        reply
    }

    /// Handles the command at the start of `input`: returns the bytes it
    /// used, or None if it is incomplete.
    fn step(&mut self, input: &[u8], reply: &mut Vec<u8>) -> Option<usize> {
        let &first = input.first()?;
        let len = match first {
            USB_ISS => match *input.get(1)? {
                ISS_MODE => 4,
                _ => 2,
            },
            I2C_AD1 => {
                let address8 = *input.get(1)?;
                let n = usize::from(*input.get(3)?);
                if address8 & 1 == 1 { 4 } else { 4 + n }
            }
            I2C_TEST => 2,
            byte => {
                self.bytes_ignored += 1;
                self.events.push(MockEvent::Ignored { byte });
                return Some(1);
            }
        };
        let command = input.get(..len)?;
        if self.silent {
            self.events.push(MockEvent::Unanswered {
                command: command.to_vec(),
            });
        } else {
            self.execute(command, reply);
        }
        Some(len)
    }

    fn execute(&mut self, command: &[u8], reply: &mut Vec<u8>) {
        match command {
            [USB_ISS, ISS_MODE, mode, io] => {
                // Only the I2C modes are modelled: software 20 kHz up to
                // hardware 1 MHz (0x20..=0x80).
                let accepted = (0x20..=0x80).contains(mode) && mode & 0x0F == 0;
                if accepted {
                    self.mode = Some(*mode);
                    reply.extend_from_slice(&[0xFF, 0x00]);
                } else {
                    reply.extend_from_slice(&[0x00, 0x05]);
                }
                self.events.push(MockEvent::ModeSet {
                    mode: *mode,
                    io: *io,
                    accepted,
                });
            }
            [USB_ISS, ISS_VERSION] => {
                reply.extend_from_slice(&[0x07, 0x07, self.mode.unwrap_or(0)])
            }
            [USB_ISS, byte] => {
                self.bytes_ignored += 2;
                self.events.push(MockEvent::Ignored { byte: *byte });
            }
            [I2C_TEST, address8] => {
                let address = address8 >> 1;
                let present = self.devices.get(&address).is_some_and(|d| !d.nack);
                reply.push(if present { 0xFF } else { 0x00 });
                self.events.push(MockEvent::Test { address, present });
            }
            [I2C_AD1, address8, register, n, data @ ..] => {
                let (address, register, n) = (address8 >> 1, *register, usize::from(*n));
                if address8 & 1 == 1 {
                    self.read(address, register, n, reply);
                } else {
                    self.write(address, register, data, reply);
                }
            }
            _ => {}
        }
    }

    fn read(&mut self, address: u8, register: u8, n: usize, reply: &mut Vec<u8>) {
        let device = self.devices.get_mut(&address).filter(|d| !d.nack);
        let Some(device) = device else {
            if n <= MAX_READ && self.nacked_read == NackedRead::Ones {
                reply.resize(reply.len() + n, 0xFF);
            }
            self.events.push(MockEvent::Read {
                address,
                register,
                len: n,
                acked: false,
                sample: None,
            });
            return;
        };
        if n == 0 || n > MAX_READ {
            // Not a transfer the real device makes; answer nothing.
            self.events.push(MockEvent::Ignored { byte: I2C_AD1 });
            return;
        }
        let starts_poll = device.chip.data_reads().first().map(|&(r, _)| r) == Some(register);
        let sample = if starts_poll {
            device.next_sample()
        } else {
            None
        };
        reply.extend((0..n).map(|i| device.registers[device.index(register, i)]));
        self.events.push(MockEvent::Read {
            address,
            register,
            len: n,
            acked: true,
            sample,
        });
    }

    fn write(&mut self, address: u8, register: u8, data: &[u8], reply: &mut Vec<u8>) {
        let device = self
            .devices
            .get_mut(&address)
            .filter(|d| !d.nack && !d.nack_writes);
        let acked = match device {
            Some(device) => {
                device.store(register, data);
                true
            }
            None => false,
        };
        reply.push(if acked { 0xFF } else { 0x00 });
        self.events.push(MockEvent::Write {
            address,
            register,
            data: data.to_vec(),
            acked,
        });
    }
}

/// An in-memory port with a [`MockUsbIss`] on the other end: writes are fed
/// to the mock at once and its replies wait to be read. For tests of the bus
/// and the chip drivers without a pty.
#[derive(Debug)]
pub struct MockUsbIssPort {
    mock: MockUsbIss,
    output: VecDeque<u8>,
}

impl MockUsbIssPort {
    pub fn new(mock: MockUsbIss) -> Self {
        MockUsbIssPort {
            mock,
            output: VecDeque::new(),
        }
    }

    pub fn mock(&self) -> &MockUsbIss {
        &self.mock
    }

    pub fn mock_mut(&mut self) -> &mut MockUsbIss {
        &mut self.mock
    }

    /// Puts bytes in the port's input, as if the bridge had sent them
    /// (a late reply, line noise).
    pub fn inject(&mut self, bytes: &[u8]) {
        self.output.extend(bytes);
    }

    /// Drops unread input: the discard hook for
    /// [`crate::i2c::usb_iss::UsbIssBus::with_discard`].
    pub fn discard_input(&mut self) -> io::Result<()> {
        self.output.clear();
        Ok(())
    }
}

impl io::Read for MockUsbIssPort {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.output.is_empty() {
            // Like a serial port's read timeout: wait a little, then say so.
            thread::sleep(Duration::from_millis(1));
            return Err(io::ErrorKind::TimedOut.into());
        }
        let n = buf.len().min(self.output.len());
        for (slot, byte) in buf.iter_mut().zip(self.output.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }
}

impl io::Write for MockUsbIssPort {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let reply = self.mock.feed(buf);
        self.output.extend(reply);
        Ok(buf.len())
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}
