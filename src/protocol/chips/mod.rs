//! I2C sensor chips: their register maps, init sequences, identity checks
//! and burst reads (see ../shared/docs/protocols.md §3).

use serde::{Deserialize, Serialize};

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

impl Chip {
    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Chip::Adxl345 => "adxl345",
            Chip::Mpu6050 => "mpu6050",
            Chip::Lsm303dlhcAccel => "lsm303dlhc-accel",
            Chip::Lsm303dlhcMag => "lsm303dlhc-mag",
        }
    }

    /// The chip's usual 7-bit I2C address.
    pub fn default_address(self) -> u8 {
        match self {
            Chip::Adxl345 => 0x53,
            Chip::Mpu6050 => 0x68,
            Chip::Lsm303dlhcAccel => 0x19,
            Chip::Lsm303dlhcMag => 0x1E,
        }
    }
}
