//! ST LSM303DLHC: an accelerometer and a magnetometer at two I2C addresses
//! (protocols.md §3; Linux `drivers/iio/accel/st_accel_core.c`,
//! `drivers/iio/magnetometer/st_magn_core.c`).

/// Accelerometer registers.
pub mod accel {
    use crate::protocol::chips::Driver;

    /// The LSM303DLHC accelerometer's entry in the chip table.
    pub const DRIVER: Driver = Driver {
        name: "lsm303dlhc-accel",
        default_address: 0x19,
        label: "LSM303DLHC accelerometer",
        init_writes: INIT,
        identity: IDENTITY,
        data_reads: DATA_READS,
        gyro_lsb_per_deg_s: None,
        register_name,
        decode: |data, time| crate::protocol::chips::accel_reading(data, time, decode),
        encode: |reading| encode(reading.accel.unwrap_or([0; 3])).to_vec(),
    };

    /// Bits 7:4 = data rate, bit 3 = low power, bits 2:0 = z, y, x enable.
    pub const CTRL_REG1_A: u8 = 0x20;
    /// Bit 7 = block data update, bits 5:4 = range, bit 3 = high resolution.
    pub const CTRL_REG4_A: u8 = 0x23;
    /// First of six data registers: x, y, z little-endian.
    pub const OUT_X_L_A: u8 = 0x28;
    /// Register-address bit that makes a multi-byte read auto-increment;
    /// without it the chip sends the same register again and again.
    pub const AUTO_INCREMENT: u8 = 0x80;

    /// 100 Hz with x, y, z on; block data update (the low and high bytes of
    /// one read belong to one sample) and high resolution (12 bits, 1 mg/LSB
    /// at +-2 g). The chip has no documented identity register.
    pub const INIT: &[(u8, u8)] = &[(CTRL_REG1_A, 0x57), (CTRL_REG4_A, 0x88)];
    pub const IDENTITY: &[(u8, u8)] = &[];
    pub const DATA_READS: &[(u8, usize)] = &[(OUT_X_L_A | AUTO_INCREMENT, 6)];

    pub fn register_name(register: u8) -> Option<&'static str> {
        Some(match register & !AUTO_INCREMENT {
            CTRL_REG1_A => "CTRL_REG1_A",
            CTRL_REG4_A => "CTRL_REG4_A",
            OUT_X_L_A => "OUT_X_L_A",
            _ => return None,
        })
    }

    /// Counts (12-bit, sign-extended) from the 6 data bytes: each value is
    /// little-endian and left-justified in 16 bits.
    pub fn decode(data: &[u8; 6]) -> [i16; 3] {
        let axis = |i: usize| i16::from_le_bytes([data[2 * i], data[2 * i + 1]]) >> 4;
        [axis(0), axis(1), axis(2)]
    }

    /// The inverse of [`decode`], for simulated chips; counts beyond the 12-bit
    /// range are clamped as the chip's own output would be.
    pub fn encode(accel: [i16; 3]) -> [u8; 6] {
        let [x, y, z] = accel.map(|v| (v.clamp(-2048, 2047) << 4).to_le_bytes());
        [x[0], x[1], y[0], y[1], z[0], z[1]]
    }
}

/// Magnetometer registers.
pub mod mag {
    use crate::protocol::chips::Driver;
    use crate::sample::Reading;

    /// The LSM303DLHC magnetometer's entry in the chip table.
    pub const DRIVER: Driver = Driver {
        name: "lsm303dlhc-mag",
        default_address: 0x1E,
        label: "LSM303DLHC magnetometer",
        init_writes: INIT,
        identity: IDENTITY,
        data_reads: DATA_READS,
        gyro_lsb_per_deg_s: None,
        register_name,
        decode: decode_reading,
        encode: encode_reading,
    };

    /// Bit 7 = temperature sensor on, bits 4:2 = data rate.
    pub const CRA_REG_M: u8 = 0x00;
    /// Bits 7:5 = gain.
    pub const CRB_REG_M: u8 = 0x01;
    /// Bits 1:0 = mode (0 = continuous).
    pub const MR_REG_M: u8 = 0x02;
    /// First of six data registers, big-endian, in the order X, Z, Y.
    pub const OUT_X_H_M: u8 = 0x03;
    /// Identification registers: 'H', '4', '3' (0x48, 0x34, 0x33), as on the
    /// Honeywell HMC5843/5883 the design follows. IRA = 0x48 is confirmed by
    /// public driver code and teaching material; IRB and IRC are from the
    /// datasheet's register map.
    pub const IRA_REG_M: u8 = 0x0A;
    pub const IRB_REG_M: u8 = 0x0B;
    pub const IRC_REG_M: u8 = 0x0C;
    /// Temperature, 12-bit left-justified, big-endian, 8 LSB per deg C.
    pub const TEMP_OUT_H_M: u8 = 0x31;
    pub const TEMP_OUT_L_M: u8 = 0x32;

    /// 30 Hz with the temperature sensor on; +-1.3 gauss (1100 LSB/gauss on
    /// x and y, 980 on z); continuous conversion.
    pub const INIT: &[(u8, u8)] = &[(CRA_REG_M, 0x94), (CRB_REG_M, 0x20), (MR_REG_M, 0x00)];
    pub const IDENTITY: &[(u8, u8)] = &[(IRA_REG_M, b'H'), (IRB_REG_M, b'4'), (IRC_REG_M, b'3')];
    /// The field, then the temperature: two bursts (the magnetometer's
    /// address pointer auto-increments with no flag bit).
    pub const DATA_READS: &[(u8, usize)] = &[(OUT_X_H_M, 6), (TEMP_OUT_H_M, 2)];

    pub fn register_name(register: u8) -> Option<&'static str> {
        Some(match register {
            CRA_REG_M => "CRA_REG_M",
            CRB_REG_M => "CRB_REG_M",
            MR_REG_M => "MR_REG_M",
            OUT_X_H_M => "OUT_X_H_M",
            IRA_REG_M => "IRA_REG_M",
            IRB_REG_M => "IRB_REG_M",
            IRC_REG_M => "IRC_REG_M",
            TEMP_OUT_H_M => "TEMP_OUT_H_M",
            TEMP_OUT_L_M => "TEMP_OUT_L_M",
            _ => return None,
        })
    }

    /// Field x, y, z and the temperature register (12-bit, sign-extended)
    /// from the 8 data bytes: X_H X_L Z_H Z_L Y_H Y_L TEMP_H TEMP_L. The
    /// chip's overflow marker (-4096) is passed on as it is. The temperature's
    /// absolute offset is not documented, so only the raw value is given.
    pub fn decode(data: &[u8; 8]) -> ([i16; 3], i16) {
        let word = |i: usize| i16::from_be_bytes([data[2 * i], data[2 * i + 1]]);
        ([word(0), word(2), word(1)], word(3) >> 4)
    }

    /// The inverse of [`decode`], for simulated chips; the temperature is
    /// clamped to 12 bits.
    pub fn encode(field: [i16; 3], temp_raw: i16) -> [u8; 8] {
        let [x, y, z] = field.map(i16::to_be_bytes);
        let t = (temp_raw.clamp(-2048, 2047) << 4).to_be_bytes();
        [x[0], x[1], z[0], z[1], y[0], y[1], t[0], t[1]]
    }

    /// [`decode`] as a reading (field and raw temperature), or `None` for a
    /// wrong length.
    fn decode_reading(data: &[u8], time: f64) -> Option<Reading> {
        let (field, temp_raw) = decode(data.try_into().ok()?);
        Some(Reading {
            time,
            mag: Some(field),
            temp_raw: Some(temp_raw),
            ..Reading::default()
        })
    }

    /// [`encode`] of a reading's field and raw temperature (0 where missing).
    fn encode_reading(reading: &Reading) -> Vec<u8> {
        encode(reading.mag.unwrap_or([0; 3]), reading.temp_raw.unwrap_or(0)).to_vec()
    }
}
