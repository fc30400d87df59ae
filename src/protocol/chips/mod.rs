//! I2C sensor chips: their register maps, init sequences, identity checks
//! and burst reads (see ../shared/docs/protocols.md §3).
//!
//! The tables and [`Chip::decode`] are sans-IO. [`init_chip`] and
//! [`read_chip`] run them over any [`I2cBus`]. A poll's data bytes (the
//! bursts of [`Chip::data_reads`], concatenated) are what a capture keeps, so
//! [`Chip::decode`] turns a recording into the same readings as the live run.

pub mod adxl345;
pub mod lsm303dlhc;
pub mod mpu6050;

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::i2c::{Access, I2cBus, I2cError};
use crate::sample::Reading;

/// The chips fieldcal can poll, by the names used on the command line, in
/// configuration and in capture headers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Chip {
    /// Analog Devices ADXL345 accelerometer.
    Adxl345,
    /// InvenSense MPU-6050 accelerometer, gyroscope and temperature.
    Mpu6050,
    /// ST LSM303DLHC accelerometer.
    Lsm303dlhcAccel,
    /// ST LSM303DLHC magnetometer and temperature.
    Lsm303dlhcMag,
}

/// Everything fieldcal knows about one chip: its names, its address, its
/// register map and how its data bytes become a [`Reading`]. Each chip's
/// module holds one `DRIVER` constant; [`Chip::driver`] is the table that
/// maps the command-line names to them. Adding a chip is its module plus a
/// variant and one line in that table.
#[derive(Debug)]
pub struct Driver {
    /// The name used on the command line and in files.
    pub name: &'static str,
    /// The chip's usual 7-bit I2C address.
    pub default_address: u8,
    /// The chip as a person names it, for messages.
    pub label: &'static str,
    /// (register, value) writes that configure the chip, in order.
    pub init_writes: &'static [(u8, u8)],
    /// (register, expected value) pairs that identify the chip.
    pub identity: &'static [(u8, u8)],
    /// (first register, length) of the burst reads of one poll, in order.
    pub data_reads: &'static [(u8, usize)],
    /// Gyro counts per degree/second as the init writes set the chip up,
    /// where the chip has a gyro.
    pub gyro_lsb_per_deg_s: Option<f64>,
    /// The datasheet name of a register, or `None` for one fieldcal does not
    /// use.
    pub register_name: fn(u8) -> Option<&'static str>,
    /// One poll's data bytes as a reading stamped with the given time, or
    /// `None` when the bytes are not one poll's length.
    pub decode: fn(&[u8], f64) -> Option<Reading>,
    /// The data bytes the chip would return for a reading (the inverse of
    /// `decode`); fields the chip does not have are ignored, missing ones
    /// read as 0.
    pub encode: fn(&Reading) -> Vec<u8>,
}

impl Chip {
    /// Every chip, in declaration order.
    pub const ALL: [Chip; 4] = [
        Chip::Adxl345,
        Chip::Mpu6050,
        Chip::Lsm303dlhcAccel,
        Chip::Lsm303dlhcMag,
    ];

    /// The chip's driver: the table of chips.
    pub fn driver(self) -> &'static Driver {
        match self {
            Chip::Adxl345 => &adxl345::DRIVER,
            Chip::Mpu6050 => &mpu6050::DRIVER,
            Chip::Lsm303dlhcAccel => &lsm303dlhc::accel::DRIVER,
            Chip::Lsm303dlhcMag => &lsm303dlhc::mag::DRIVER,
        }
    }

    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        self.driver().name
    }

    /// The chip's usual 7-bit I2C address.
    pub fn default_address(self) -> u8 {
        self.driver().default_address
    }

    /// The chip as a person names it, for messages.
    pub fn label(self) -> &'static str {
        self.driver().label
    }

    /// (register, value) writes that configure the chip, in order, one byte
    /// each.
    pub fn init_writes(self) -> &'static [(u8, u8)] {
        self.driver().init_writes
    }

    /// (register, expected value) pairs that identify the chip, read one
    /// register at a time; empty where the chip has no documented ID
    /// (the LSM303DLHC accelerometer: its init writes still have to be ACKed).
    pub fn identity(self) -> &'static [(u8, u8)] {
        self.driver().identity
    }

    /// (first register, length) of the burst reads of one poll, in order.
    /// The register byte is sent as is (it includes the LSM303DLHC
    /// accelerometer's auto-increment bit).
    pub fn data_reads(self) -> &'static [(u8, usize)] {
        self.driver().data_reads
    }

    /// Bytes of one poll: the sum of the [`Chip::data_reads`] lengths.
    pub fn data_len(self) -> usize {
        self.data_reads().iter().map(|&(_, len)| len).sum()
    }

    /// Gyro counts per degree/second as the chip is set up, where it has a
    /// gyro whose scale fieldcal sets.
    pub fn gyro_lsb_per_deg_s(self) -> Option<f64> {
        self.driver().gyro_lsb_per_deg_s
    }

    /// The datasheet name of `register`, or "register" for one fieldcal
    /// does not use.
    pub fn register_name(self, register: u8) -> &'static str {
        (self.driver().register_name)(register).unwrap_or("register")
    }

    /// Decodes one poll's data bytes (the [`Chip::data_reads`] bursts,
    /// concatenated) into a reading stamped `time`.
    pub fn decode(self, data: &[u8], time: f64) -> Result<Reading, ChipError> {
        (self.driver().decode)(data, time).ok_or(ChipError::DataLength {
            chip: self,
            expected: self.data_len(),
            found: data.len(),
        })
    }

    /// The data bytes a chip would return for `reading`: the inverse of
    /// [`Chip::decode`], for simulated chips and tests. Fields the chip does
    /// not have are ignored; missing ones read as 0. The MPU-6050 takes its
    /// temperature from `temp_raw`, else from `temp_c`.
    pub fn encode(self, reading: &Reading) -> Vec<u8> {
        (self.driver().encode)(reading)
    }
}

/// An accelerometer's poll as a reading, through its `decode`, or `None`
/// when `data` is not one poll's length: the driver's `decode` for chips
/// that measure acceleration alone.
fn accel_reading<const N: usize>(
    data: &[u8],
    time: f64,
    decode: fn(&[u8; N]) -> [i16; 3],
) -> Option<Reading> {
    Some(Reading {
        time,
        accel: Some(decode(data.try_into().ok()?)),
        ..Reading::default()
    })
}

/// Why a chip could not be set up or read. Every message names the chip and
/// its address and says what to check.
#[derive(Debug, thiserror::Error)]
pub enum ChipError {
    #[error(
        "{} at 0x{address:02X}: no ACK {access} {} (0x{register:02X}): \
         check the wiring and the address",
        chip.label(),
        chip.register_name(*register)
    )]
    Nack {
        chip: Chip,
        address: u8,
        register: u8,
        access: Access,
    },
    #[error(
        "{} at 0x{address:02X}: {bus} did not answer {access} {} (0x{register:02X}) \
         within {} ms: check that the bridge is plugged in and powered",
        chip.label(),
        chip.register_name(*register),
        waited.as_millis()
    )]
    Timeout {
        chip: Chip,
        address: u8,
        register: u8,
        access: Access,
        bus: String,
        waited: Duration,
    },
    #[error(
        "{} at 0x{address:02X}: {access} {} (0x{register:02X}) failed: {source}",
        chip.label(),
        chip.register_name(*register)
    )]
    Bus {
        chip: Chip,
        address: u8,
        register: u8,
        access: Access,
        #[source]
        source: I2cError,
    },
    #[error(
        "{} at 0x{address:02X}: {} (0x{register:02X}) reads 0x{found:02X}, expected \
         0x{expected:02X}: another chip answers at this address; check the chip type and the address",
        chip.label(),
        chip.register_name(*register)
    )]
    WrongIdentity {
        chip: Chip,
        address: u8,
        register: u8,
        expected: u8,
        found: u8,
    },
    #[error(
        "{} at 0x{address:02X}: {} (0x{register:02X}) reads only 0xFF bytes, so the chip is \
         probably not answering (a bridge does not report a refused read): \
         check the wiring and the address",
        chip.label(),
        chip.register_name(*register)
    )]
    NotAnswering {
        chip: Chip,
        address: u8,
        register: u8,
    },
    #[error(
        "{}: {found} data bytes where a poll has {expected}: \
         the recording does not match this chip",
        chip.label()
    )]
    DataLength {
        chip: Chip,
        expected: usize,
        found: usize,
    },
}

impl ChipError {
    /// Wraps a bus error with the chip and register it happened on.
    pub fn from_bus(
        chip: Chip,
        address: u8,
        register: u8,
        access: Access,
        error: I2cError,
    ) -> Self {
        match error {
            I2cError::Nack { .. } => ChipError::Nack {
                chip,
                address,
                register,
                access,
            },
            I2cError::Timeout { bus, waited, .. } => ChipError::Timeout {
                chip,
                address,
                register,
                access,
                bus,
                waited,
            },
            source => ChipError::Bus {
                chip,
                address,
                register,
                access,
                source,
            },
        }
    }
}

/// Checks the chip's identity registers, then writes its configuration,
/// each write ACKed. A chip that reads 0xFF where its ID should be is
/// reported as not answering rather than as another chip.
pub fn init_chip(bus: &mut dyn I2cBus, chip: Chip, address: u8) -> Result<(), ChipError> {
    for &(register, expected) in chip.identity() {
        let mut found = [0u8; 1];
        bus.read_registers(address, register, &mut found)
            .map_err(|e| ChipError::from_bus(chip, address, register, Access::Read, e))?;
        let [found] = found;
        if found == expected {
            continue;
        }
        return Err(if found == 0xFF {
            ChipError::NotAnswering {
                chip,
                address,
                register,
            }
        } else {
            ChipError::WrongIdentity {
                chip,
                address,
                register,
                expected,
                found,
            }
        });
    }
    for &(register, value) in chip.init_writes() {
        bus.write_register(address, register, &[value])
            .map_err(|e| ChipError::from_bus(chip, address, register, Access::Write, e))?;
    }
    Ok(())
}

/// Runs one poll's burst reads and puts the data bytes in `buf` (cleared
/// first), ready for [`Chip::decode`].
///
/// A poll of nothing but 0xFF bytes is an error: it is what a bridge returns
/// when no chip drives the bus, and no supported chip produces it while
/// powered (it would be -1 count on every axis at once, gravity included).
pub fn read_chip(
    bus: &mut dyn I2cBus,
    chip: Chip,
    address: u8,
    buf: &mut Vec<u8>,
) -> Result<(), ChipError> {
    buf.clear();
    for &(register, len) in chip.data_reads() {
        let start = buf.len();
        buf.resize(start + len, 0);
        bus.read_registers(address, register, &mut buf[start..])
            .map_err(|e| ChipError::from_bus(chip, address, register, Access::Read, e))?;
    }
    if !buf.is_empty() && buf.iter().all(|&b| b == 0xFF) {
        return Err(ChipError::NotAnswering {
            chip,
            address,
            register: chip
                .data_reads()
                .first()
                .map_or(0, |&(register, _)| register),
        });
    }
    Ok(())
}
