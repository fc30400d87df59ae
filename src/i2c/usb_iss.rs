//! [`I2cBus`] over a Devantech USB-ISS: the encoders of
//! [`crate::protocol::usb_iss`] plus a port and a reply timeout.
//!
//! The port is any blocking `Read + Write`: a serial port in production, an
//! in-memory double in tests. Its reads must come back within a short time
//! (with bytes, 0 bytes, `TimedOut` or `WouldBlock`) so the bus can watch its
//! own deadline; [`UsbIssBus::open`] sets the serial port up that way.

use std::io::{self, Read, Write};
use std::path::Path;
use std::thread;
use std::time::{Duration, Instant};

use serialport::{ClearBuffer, SerialPort};

use super::{Access, I2cBus, I2cError, open_advice};
use crate::protocol::usb_iss::{self as proto, I2cSpeed};

/// How long one blocking read of the serial port may wait: short, so the bus
/// checks its reply deadline often and never overshoots it by much.
const READ_SLICE: Duration = Duration::from_millis(10);
/// The USB-ISS is a CDC device and ignores the baud rate; any value works.
const BAUD: u32 = 115_200;

/// A USB-ISS in I2C mode, over `port`.
pub struct UsbIssBus<P> {
    port: P,
    description: String,
    timeout: Duration,
    discard: Option<fn(&mut P) -> io::Result<()>>,
}

impl<P> std::fmt::Debug for UsbIssBus<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UsbIssBus")
            .field("description", &self.description)
            .field("timeout", &self.timeout)
            .finish_non_exhaustive()
    }
}

impl UsbIssBus<Box<dyn SerialPort>> {
    /// Opens the USB-ISS at `path` (e.g. `/dev/ttyACM0`). Each reply must
    /// arrive within `timeout`. Stale input is discarded before every
    /// transaction, so a late reply to a timed-out one is never taken for
    /// the next.
    pub fn open(path: &Path, timeout: Duration) -> Result<Self, I2cError> {
        let name = path.to_string_lossy().into_owned();
        let port = serialport::new(name.clone(), BAUD)
            .timeout(timeout.clamp(Duration::from_millis(1), READ_SLICE))
            .open()
            .map_err(|e| {
                let kind = match e.kind {
                    serialport::ErrorKind::Io(kind) => kind,
                    _ => io::ErrorKind::Other,
                };
                I2cError::Open {
                    port: name.clone(),
                    reason: e.description.clone(),
                    advice: open_advice(kind),
                }
            })?;
        let bus = UsbIssBus::new(port, format!("USB-ISS on {name}"), timeout)
            .with_discard(|port| port.clear(ClearBuffer::Input).map_err(io::Error::from));
        Ok(bus)
    }
}

impl<P: Read + Write + Send> UsbIssBus<P> {
    /// A bus over an already open port. `description` names it in messages.
    /// Without [`UsbIssBus::with_discard`] stale input is not discarded.
    pub fn new(port: P, description: impl Into<String>, timeout: Duration) -> Self {
        UsbIssBus {
            port,
            description: description.into(),
            timeout,
            discard: None,
        }
    }

    /// Sets how to drop bytes already waiting on the port (for a serial
    /// port: flush its input queue). Called before every transaction.
    pub fn with_discard(mut self, discard: fn(&mut P) -> io::Result<()>) -> Self {
        self.discard = Some(discard);
        self
    }

    /// Puts the module in I2C mode at `speed` (`5A 02 <mode> 0A` -> `FF 00`).
    pub fn set_mode(&mut self, speed: I2cSpeed) -> Result<(), I2cError> {
        let mut reply = [0u8; 2];
        self.transact(&proto::encode_set_mode(speed), &mut reply, || {
            format!("'set I2C mode, {} kHz'", speed.khz())
        })?;
        proto::check_set_mode_reply(reply).map_err(|source| I2cError::BadReply {
            bus: self.description.clone(),
            source,
        })
    }

    /// The reply timeout.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    pub fn get_ref(&self) -> &P {
        &self.port
    }

    pub fn get_mut(&mut self) -> &mut P {
        &mut self.port
    }

    pub fn into_inner(self) -> P {
        self.port
    }

    fn bad_request(&self, source: proto::UsbIssError) -> I2cError {
        I2cError::BadRequest {
            bus: self.description.clone(),
            source,
        }
    }

    fn io_error(&self, source: io::Error) -> I2cError {
        I2cError::Io {
            bus: self.description.clone(),
            source,
        }
    }

    /// Sends `command` and reads exactly `reply.len()` bytes back before the
    /// deadline. `what` names the command for a timeout message.
    fn transact(
        &mut self,
        command: &[u8],
        reply: &mut [u8],
        what: impl FnOnce() -> String,
    ) -> Result<(), I2cError> {
        if let Some(discard) = self.discard {
            discard(&mut self.port).map_err(|e| self.io_error(e))?;
        }
        let start = Instant::now();
        let deadline = start + self.timeout;
        let expected = reply.len();
        let timeout = |received: usize, bus: &str| I2cError::Timeout {
            bus: bus.to_string(),
            command: what(),
            expected,
            received,
            waited: start.elapsed(),
        };
        if let Err(e) = self
            .port
            .write_all(command)
            .and_then(|()| self.port.flush())
        {
            return Err(match e.kind() {
                io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock => {
                    timeout(0, &self.description)
                }
                _ => self.io_error(e),
            });
        }
        let mut received = 0;
        while received < expected {
            match self.port.read(&mut reply[received..]) {
                Ok(0) => thread::sleep(Duration::from_millis(1)),
                Ok(n) => received += n,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    thread::sleep(Duration::from_millis(1))
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(self.io_error(e)),
            }
            if received < expected && Instant::now() >= deadline {
                return Err(timeout(received, &self.description));
            }
        }
        Ok(())
    }
}

impl<P: Read + Write + Send> I2cBus for UsbIssBus<P> {
    fn write_register(&mut self, address: u8, register: u8, data: &[u8]) -> Result<(), I2cError> {
        let command =
            proto::encode_write(address, register, data).map_err(|e| self.bad_request(e))?;
        let mut reply = [0u8; 1];
        self.transact(&command, &mut reply, || {
            format!(
                "a write of {} bytes to register 0x{register:02X} at 0x{address:02X}",
                data.len()
            )
        })?;
        if proto::write_acked(reply[0]) {
            Ok(())
        } else {
            Err(I2cError::Nack {
                bus: self.description.clone(),
                address,
                register,
                access: Access::Write,
            })
        }
    }

    fn read(&mut self, address: u8, register: u8, buf: &mut [u8]) -> Result<(), I2cError> {
        let command =
            proto::encode_read(address, register, buf.len()).map_err(|e| self.bad_request(e))?;
        let len = buf.len();
        self.transact(&command, buf, || {
            format!("a read of {len} bytes from register 0x{register:02X} at 0x{address:02X}")
        })
    }

    fn describe(&self) -> String {
        self.description.clone()
    }
}
