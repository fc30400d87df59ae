//! Analog Devices ADXL345 accelerometer (protocols.md §3; Linux
//! `drivers/iio/accel/adxl345_core.c`).

use super::Driver;

/// The ADXL345's entry in the chip table.
pub const DRIVER: Driver = Driver {
    name: "adxl345",
    default_address: 0x53,
    label: "ADXL345 accelerometer",
    init_writes: INIT,
    identity: IDENTITY,
    data_reads: DATA_READS,
    gyro_lsb_per_deg_s: None,
    register_name,
    decode: |data, time| super::accel_reading(data, time, decode),
    encode: |reading| encode(reading.accel.unwrap_or([0; 3])).to_vec(),
};

/// Device ID register, and the value every ADXL345 holds there.
pub const DEVID: u8 = 0x00;
pub const DEVID_VALUE: u8 = 0xE5;
/// Output data rate: 0.09765625 Hz * 2^code.
pub const BW_RATE: u8 = 0x2C;
/// Bit 3 = measure (the chip powers up in standby).
pub const POWER_CTL: u8 = 0x2D;
/// Bit 3 = full resolution (~3.9 mg/LSB at every range); bits 1:0 = range.
pub const DATA_FORMAT: u8 = 0x31;
/// First of six data registers: x, y, z little-endian i16.
pub const DATAX0: u8 = 0x32;

/// Configure before measuring: full resolution at +-2 g, 100 Hz, measure.
pub const INIT: &[(u8, u8)] = &[(DATA_FORMAT, 0x08), (BW_RATE, 0x0A), (POWER_CTL, 0x08)];
pub const IDENTITY: &[(u8, u8)] = &[(DEVID, DEVID_VALUE)];
pub const DATA_READS: &[(u8, usize)] = &[(DATAX0, 6)];

pub fn register_name(register: u8) -> Option<&'static str> {
    Some(match register {
        DEVID => "DEVID",
        BW_RATE => "BW_RATE",
        POWER_CTL => "POWER_CTL",
        DATA_FORMAT => "DATA_FORMAT",
        DATAX0 => "DATAX0",
        _ => return None,
    })
}

/// Accelerometer x, y, z counts from the 6 data bytes.
pub fn decode(data: &[u8; 6]) -> [i16; 3] {
    [
        i16::from_le_bytes([data[0], data[1]]),
        i16::from_le_bytes([data[2], data[3]]),
        i16::from_le_bytes([data[4], data[5]]),
    ]
}

/// The inverse of [`decode`], for simulated chips.
pub fn encode(accel: [i16; 3]) -> [u8; 6] {
    let [x, y, z] = accel.map(i16::to_le_bytes);
    [x[0], x[1], y[0], y[1], z[0], z[1]]
}
