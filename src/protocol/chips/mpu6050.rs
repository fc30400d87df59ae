//! InvenSense MPU-6050 accelerometer, gyroscope and temperature (protocols.md
//! §3; Linux `drivers/iio/imu/inv_mpu6050/`).

use super::Driver;
use crate::sample::Reading;

/// The MPU-6050's entry in the chip table.
pub const DRIVER: Driver = Driver {
    name: "mpu6050",
    default_address: 0x68,
    label: "MPU-6050 accelerometer/gyroscope",
    init_writes: INIT,
    identity: IDENTITY,
    data_reads: DATA_READS,
    gyro_lsb_per_deg_s: Some(GYRO_LSB_PER_DEG_S),
    register_name,
    decode: decode_reading,
    encode: encode_reading,
};

/// Sample rate = 1 kHz / (1 + div) with the low-pass filter on.
pub const SMPLRT_DIV: u8 = 0x19;
/// Bits 2:0 = digital low-pass filter.
pub const CONFIG: u8 = 0x1A;
/// Bits 4:3 = +-250/500/1000/2000 deg/s (131/65.5/32.8/16.4 LSB per deg/s).
pub const GYRO_CONFIG: u8 = 0x1B;
/// Gyro counts per degree/second as [`INIT`] sets it up (GYRO_CONFIG
/// FS_SEL = 0, +-250 deg/s): 131 LSB/(deg/s), MPU-6000/6050 Product
/// Specification rev 3.4, table 6.1.
pub const GYRO_LSB_PER_DEG_S: f64 = 131.0;
/// Bits 4:3 = +-2/4/8/16 g (16384/8192/4096/2048 LSB/g).
pub const ACCEL_CONFIG: u8 = 0x1C;
/// First of 14 data bytes: AX AY AZ TEMP GX GY GZ, big-endian i16.
pub const ACCEL_XOUT_H: u8 = 0x3B;
/// Bit 6 = sleep (set at power-up); bits 2:0 = clock source.
pub const PWR_MGMT_1: u8 = 0x6B;
/// Holds the 7-bit address with AD0 low, whatever AD0 is.
pub const WHO_AM_I: u8 = 0x75;
pub const WHO_AM_I_VALUE: u8 = 0x68;

/// Wake on the gyro X PLL (steadier than the internal oscillator), then 100 Hz
/// (div 9) behind a ~44 Hz low-pass (DLPF 3): above the 33 Hz poll rate, so
/// each poll reads a fresh, filtered sample. Gyro +-250 deg/s, accel +-2 g.
pub const INIT: &[(u8, u8)] = &[
    (PWR_MGMT_1, 0x01),
    (SMPLRT_DIV, 9),
    (CONFIG, 0x03),
    (GYRO_CONFIG, 0x00),
    (ACCEL_CONFIG, 0x00),
];
pub const IDENTITY: &[(u8, u8)] = &[(WHO_AM_I, WHO_AM_I_VALUE)];
pub const DATA_READS: &[(u8, usize)] = &[(ACCEL_XOUT_H, 14)];

pub fn register_name(register: u8) -> Option<&'static str> {
    Some(match register {
        SMPLRT_DIV => "SMPLRT_DIV",
        CONFIG => "CONFIG",
        GYRO_CONFIG => "GYRO_CONFIG",
        ACCEL_CONFIG => "ACCEL_CONFIG",
        ACCEL_XOUT_H => "ACCEL_XOUT_H",
        PWR_MGMT_1 => "PWR_MGMT_1",
        WHO_AM_I => "WHO_AM_I",
        _ => return None,
    })
}

/// Degrees Celsius from the temperature register (datasheet formula).
pub fn temp_c(raw: i16) -> f64 {
    f64::from(raw) / 340.0 + 36.53
}

/// The temperature register for `celsius`, the inverse of [`temp_c`].
pub fn temp_raw(celsius: f64) -> i16 {
    // `as` saturates, which is what an out-of-range simulated value wants.
    ((celsius - 36.53) * 340.0).round() as i16
}

/// Decoded 14-byte burst.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub accel: [i16; 3],
    pub temp_raw: i16,
    pub gyro: [i16; 3],
}

pub fn decode(data: &[u8; 14]) -> Sample {
    let word = |i: usize| i16::from_be_bytes([data[2 * i], data[2 * i + 1]]);
    Sample {
        accel: [word(0), word(1), word(2)],
        temp_raw: word(3),
        gyro: [word(4), word(5), word(6)],
    }
}

/// The inverse of [`decode`], for simulated chips.
pub fn encode(sample: &Sample) -> [u8; 14] {
    let words = [
        sample.accel[0],
        sample.accel[1],
        sample.accel[2],
        sample.temp_raw,
        sample.gyro[0],
        sample.gyro[1],
        sample.gyro[2],
    ];
    let mut out = [0u8; 14];
    for (chunk, word) in out.chunks_exact_mut(2).zip(words) {
        chunk.copy_from_slice(&word.to_be_bytes());
    }
    out
}

/// [`decode`] as a reading, the temperature also in degrees Celsius, or
/// `None` for a wrong length.
fn decode_reading(data: &[u8], time: f64) -> Option<Reading> {
    let sample = decode(data.try_into().ok()?);
    Some(Reading {
        time,
        accel: Some(sample.accel),
        gyro: Some(sample.gyro),
        temp_raw: Some(sample.temp_raw),
        temp_c: Some(temp_c(sample.temp_raw)),
        ..Reading::default()
    })
}

/// [`encode`] of a reading (0 where a field is missing), the temperature
/// from `temp_raw`, else from `temp_c`.
fn encode_reading(reading: &Reading) -> Vec<u8> {
    let zero = [0i16; 3];
    let temp_raw = reading
        .temp_raw
        .or(reading.temp_c.map(temp_raw))
        .unwrap_or(0);
    encode(&Sample {
        accel: reading.accel.unwrap_or(zero),
        temp_raw,
        gyro: reading.gyro.unwrap_or(zero),
    })
    .to_vec()
}
