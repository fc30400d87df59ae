//! The Devantech USB-ISS command set, sans-IO: encoders that return the bytes
//! to send and checkers for the bytes that come back (protocols.md §2; the
//! reference is `sneakypete81/usb_iss`, `src/usb_iss/{defs,i2c}.py`).
//!
//! Only what fieldcal uses is here: setting the I2C mode and the one-byte
//! register-address transfers (I2C_AD1).
//!
//! A NACKed *read* is not reported by the USB-ISS in any documented way: the
//! reference driver reads back `n` bytes without a status byte. We assume the
//! device still sends `n` bytes, clocked off an idle bus and so 0xFF each;
//! [`crate::protocol::chips::read_chip`] flags an all-0xFF burst as a chip
//! that did not answer. If the device sends fewer bytes instead, the bus
//! reports a timeout ([`crate::i2c::I2cError::Timeout`]). Either way the
//! failure is caught.

use serde::{Deserialize, Serialize};

/// First byte of the I2C transfer with a one-byte register address.
pub const I2C_AD1: u8 = 0x55;
/// First byte of I2C_TEST: `58 <addr<<1>` -> one byte, 0x00 if nothing ACKs.
pub const I2C_TEST: u8 = 0x58;
/// First byte of the module's own commands.
pub const USB_ISS: u8 = 0x5A;
/// USB_ISS sub-command: version (`5A 01` -> module id 7, firmware, mode).
pub const ISS_VERSION: u8 = 0x01;
/// USB_ISS sub-command: set the operating mode.
pub const ISS_MODE: u8 = 0x02;

/// Most bytes one I2C_AD1 read may ask for.
pub const MAX_READ: usize = 60;
/// Most data bytes one I2C_AD1 write may carry.
pub const MAX_WRITE: usize = 60;

/// The I/O byte sent with the I2C mode: I/O1 and I/O2 (the two pins the I2C
/// mode leaves free) as digital inputs, `0b10` each in bits 1:0 and 3:2.
/// Inputs are high impedance, so this is safe whatever those pins are wired
/// to; the I2C pins' bits are ignored by the module.
pub const IO_INPUTS: u8 = 0x0A;

/// Reply to a successful mode change: `FF 00`.
pub const MODE_OK: [u8; 2] = [0xFF, 0x00];

/// I2C clock, using the module's hardware I2C controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum I2cSpeed {
    /// 100 kHz: the default, because it tolerates long leads and weak
    /// pull-ups, and a 14-byte burst still takes under 2 ms.
    #[default]
    Khz100,
    /// 400 kHz: every supported chip runs at it when the wiring allows.
    Khz400,
}

impl I2cSpeed {
    /// The USB-ISS mode byte: 0x60 (100 kHz) or 0x70 (400 kHz).
    pub fn mode_byte(self) -> u8 {
        match self {
            I2cSpeed::Khz100 => 0x60,
            I2cSpeed::Khz400 => 0x70,
        }
    }

    /// The clock in kHz, for messages.
    pub fn khz(self) -> u32 {
        match self {
            I2cSpeed::Khz100 => 100,
            I2cSpeed::Khz400 => 400,
        }
    }
}

/// A request the USB-ISS cannot carry, or a reply that makes no sense.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UsbIssError {
    #[error("I2C address 0x{address:02X} is not a 7-bit address: use 0x00..=0x7F")]
    BadAddress { address: u8 },
    #[error(
        "a USB-ISS read carries at most {MAX_READ} bytes, {len} were asked for: split the read"
    )]
    ReadTooLong { len: usize },
    #[error("a USB-ISS write carries at most {MAX_WRITE} bytes, {len} were given: split the write")]
    WriteTooLong { len: usize },
    #[error(
        "the USB-ISS refused the mode change with error code 0x{code:02X} ({}): \
         check that the device is a USB-ISS with current firmware",
        mode_error_name(*code)
    )]
    ModeRejected { code: u8 },
    #[error(
        "the USB-ISS answered the mode change with {:02X} {:02X}, not FF 00: \
         the device may not be a USB-ISS, or an earlier reply arrived late",
        reply[0],
        reply[1]
    )]
    BadModeReply { reply: [u8; 2] },
}

/// The name of a mode-change error code (defs.py `ModeError`).
pub fn mode_error_name(code: u8) -> &'static str {
    match code {
        0x05 => "unknown command",
        0x06 | 0x07 => "internal error",
        _ => "undocumented code",
    }
}

fn check_address(address: u8) -> Result<(), UsbIssError> {
    if address > 0x7F {
        Err(UsbIssError::BadAddress { address })
    } else {
        Ok(())
    }
}

/// `5A 02 <mode> <io>`: put the module in I2C mode at `speed`, with the
/// spare pins as inputs ([`IO_INPUTS`]). The reply is 2 bytes.
pub fn encode_set_mode(speed: I2cSpeed) -> [u8; 4] {
    [USB_ISS, ISS_MODE, speed.mode_byte(), IO_INPUTS]
}

/// Checks the 2-byte reply to [`encode_set_mode`].
pub fn check_set_mode_reply(reply: [u8; 2]) -> Result<(), UsbIssError> {
    match reply {
        MODE_OK => Ok(()),
        [0x00, code] => Err(UsbIssError::ModeRejected { code }),
        _ => Err(UsbIssError::BadModeReply { reply }),
    }
}

/// `55 <addr<<1|1> <reg> <n>`: read `len` bytes from `register` on. The reply
/// is exactly `len` bytes, with no status (see the module notes on NACKs).
pub fn encode_read(address: u8, register: u8, len: usize) -> Result<[u8; 4], UsbIssError> {
    check_address(address)?;
    if len > MAX_READ {
        return Err(UsbIssError::ReadTooLong { len });
    }
    // `len <= 60` fits a byte.
    Ok([I2C_AD1, (address << 1) | 1, register, len as u8])
}

/// `55 <addr<<1> <reg> <n> <data...>`: write `data` from `register` on. The
/// reply is 1 byte, see [`write_acked`].
pub fn encode_write(address: u8, register: u8, data: &[u8]) -> Result<Vec<u8>, UsbIssError> {
    check_address(address)?;
    if data.len() > MAX_WRITE {
        return Err(UsbIssError::WriteTooLong { len: data.len() });
    }
    let mut bytes = Vec::with_capacity(4 + data.len());
    bytes.extend_from_slice(&[I2C_AD1, address << 1, register, data.len() as u8]);
    bytes.extend_from_slice(data);
    Ok(bytes)
}

/// The 1-byte reply to a write: non-zero is an ACK, 0x00 a NACK.
pub fn write_acked(reply: u8) -> bool {
    reply != 0x00
}

/// `58 <addr<<1>`: does anything ACK at `address`? The reply is 1 byte,
/// 0x00 when nothing answered.
pub fn encode_test(address: u8) -> Result<[u8; 2], UsbIssError> {
    check_address(address)?;
    Ok([I2C_TEST, address << 1])
}
