//! Unit tests of the protocols, chips, I2C buses and mocks that need only the
//! public API, moved out of src/protocol, src/i2c and src/mock: one module a
//! source file, the tests unchanged.

mod i2c_usb_iss {
    use fieldcal::i2c::usb_iss::UsbIssBus;
    use fieldcal::i2c::{I2cBus, I2cError};
    use fieldcal::mock::usb_iss::{MockUsbIss, MockUsbIssPort};
    use fieldcal::protocol::chips::Chip;
    use fieldcal::protocol::usb_iss::I2cSpeed;
    use fieldcal::sample::Reading;
    use std::path::Path;
    use std::time::{Duration, Instant};

    const TIMEOUT: Duration = Duration::from_millis(50);

    fn bus_with(chips: &[Chip]) -> UsbIssBus<MockUsbIssPort> {
        let mut mock = MockUsbIss::new();
        for &chip in chips {
            mock.add_chip(chip);
        }
        UsbIssBus::new(MockUsbIssPort::new(mock), "USB-ISS on test", TIMEOUT)
            .with_discard(MockUsbIssPort::discard_input)
    }

    #[test]
    fn set_mode_and_write_and_read() {
        let mut bus = bus_with(&[Chip::Adxl345]);
        bus.set_mode(I2cSpeed::Khz400).unwrap();
        assert_eq!(bus.get_ref().mock().mode(), Some(0x70));
        bus.write_register(0x53, 0x2D, &[0x08]).unwrap();
        let mut id = [0u8; 1];
        bus.read_registers(0x53, 0x00, &mut id).unwrap();
        assert_eq!(id, [0xE5]);
        assert_eq!(bus.get_ref().mock().register(0x53, 0x2D), Some(0x08));
    }

    #[test]
    fn a_nacked_write_is_an_error_naming_the_address_and_register() {
        let mut bus = bus_with(&[Chip::Adxl345]);
        bus.get_mut().mock_mut().set_nack(0x53, true);
        let err = bus.write_register(0x53, 0x2D, &[0x08]).unwrap_err();
        assert!(matches!(
            err,
            I2cError::Nack {
                address: 0x53,
                register: 0x2D,
                ..
            }
        ));
        let text = err.to_string();
        assert!(text.contains("0x53") && text.contains("0x2D"), "{text}");
        assert!(text.contains("USB-ISS on test"), "{text}");
    }

    #[test]
    fn a_silent_bridge_times_out_cleanly() {
        let mut bus = bus_with(&[Chip::Adxl345]);
        bus.get_mut().mock_mut().set_silent(true);
        let start = Instant::now();
        let mut buf = [0u8; 6];
        let err = bus.read_registers(0x53, 0x32, &mut buf).unwrap_err();
        let waited = start.elapsed();
        assert!(
            matches!(
                err,
                I2cError::Timeout {
                    received: 0,
                    expected: 6,
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.is_bridge_failure());
        assert!(waited >= TIMEOUT && waited < TIMEOUT * 10, "{waited:?}");
    }

    #[test]
    fn a_short_reply_times_out() {
        let mut bus = bus_with(&[]);
        // The bridge sends only 3 of the 6 bytes asked for.
        bus.get_mut().mock_mut().set_silent(true);
        bus.get_mut().inject(&[1, 2, 3]);
        // No discard: the injected bytes stand for a partial reply.
        let mut bus = UsbIssBus::new(bus.into_inner(), "USB-ISS on test", TIMEOUT);
        let mut buf = [0u8; 6];
        let err = bus.read_registers(0x53, 0x32, &mut buf).unwrap_err();
        assert!(
            matches!(
                err,
                I2cError::Timeout {
                    received: 3,
                    expected: 6,
                    ..
                }
            ),
            "{err}"
        );
    }

    /// A reply that arrives after its transaction timed out is dropped
    /// before the next transaction, not read as that one's reply.
    #[test]
    fn a_late_reply_is_not_taken_for_the_next_one() {
        let mut bus = bus_with(&[Chip::Adxl345]);
        bus.get_mut().mock_mut().set_silent(true);
        let mut buf = [0u8; 6];
        assert!(bus.read_registers(0x53, 0x32, &mut buf).is_err());
        // The late reply to the timed-out read shows up now.
        bus.get_mut().inject(&[0xAA; 6]);
        bus.get_mut().mock_mut().set_silent(false);
        bus.get_mut().mock_mut().push_sample(
            0x53,
            Reading {
                accel: Some([1, 2, 3]),
                ..Reading::default()
            },
        );
        bus.read_registers(0x53, 0x32, &mut buf).unwrap();
        assert_eq!(buf, [1, 0, 2, 0, 3, 0]);
    }

    #[test]
    fn oversized_transfers_are_refused_before_sending() {
        let mut bus = bus_with(&[Chip::Adxl345]);
        let mut buf = [0u8; 61];
        let err = bus.read_registers(0x53, 0x00, &mut buf).unwrap_err();
        assert!(matches!(err, I2cError::BadRequest { .. }), "{err}");
        assert!(bus.get_ref().mock().events().is_empty());
    }

    #[test]
    fn opening_a_missing_port_names_it() {
        let err = UsbIssBus::open(Path::new("/dev/fieldcal-no-such-port"), TIMEOUT).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("/dev/fieldcal-no-such-port"), "{text}");
        assert!(matches!(err, I2cError::Open { .. }));
    }
}

mod mock_falcon {
    use fieldcal::mock::falcon::MockFalcon;
    use fieldcal::protocol::falcon::{START_CONTINUOUS, STOP_CONTINUOUS};

    #[test]
    fn waits_for_start_and_obeys_stop_even_when_split() {
        let mut dev = MockFalcon::new(vec![vec![1], vec![2], vec![3]]);
        assert_eq!(dev.tick(), None);
        dev.receive(&[0xAA, 0x10]);
        dev.receive(&[0x00]);
        assert!(!dev.is_streaming());
        dev.receive(&[0x02]);
        assert_eq!(dev.tick(), Some(&[1u8][..]));
        dev.receive(&STOP_CONTINUOUS);
        assert_eq!(dev.tick(), None);
        dev.receive(&START_CONTINUOUS);
        assert_eq!(dev.tick(), Some(&[2u8][..]));
        assert_eq!(dev.commands_seen(), (2, 1));
        assert_eq!(dev.remaining(), 1);
    }
}

mod mock_usb_iss {
    use fieldcal::mock::usb_iss::{MockEvent, MockUsbIss, NackedRead};
    use fieldcal::protocol::chips::Chip;
    use fieldcal::sample::Reading;

    fn sample(accel: [i16; 3]) -> Reading {
        Reading {
            accel: Some(accel),
            ..Reading::default()
        }
    }

    #[test]
    fn mode_set_is_acknowledged() {
        let mut mock = MockUsbIss::new();
        assert_eq!(mock.feed(&[0x5A, 0x02, 0x70, 0x0A]), vec![0xFF, 0x00]);
        assert_eq!(mock.mode(), Some(0x70));
        assert_eq!(mock.feed(&[0x5A, 0x02, 0x91, 0x00]), vec![0x00, 0x05]);
        assert_eq!(mock.mode(), Some(0x70));
    }

    #[test]
    fn commands_split_across_feeds() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Adxl345]);
        mock.push_sample(0x53, sample([1, -2, 3]));
        let all = [0x5A, 0x02, 0x60, 0x0A, 0x55, 0xA7, 0x32, 0x06];
        let mut reply = Vec::new();
        for byte in all {
            reply.extend(mock.feed(&[byte]));
        }
        assert_eq!(reply, vec![0xFF, 0x00, 1, 0, 0xFE, 0xFF, 3, 0]);
        // A write split inside its data.
        assert!(mock.feed(&[0x55, 0xA6, 0x2C, 0x02, 0x0A]).is_empty());
        assert_eq!(mock.feed(&[0x08]), vec![0xFF]);
        assert_eq!(mock.register(0x53, 0x2C), Some(0x0A));
        assert_eq!(mock.register(0x53, 0x2D), Some(0x08));
    }

    #[test]
    fn samples_are_served_in_order_then_the_last_one_stays() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Adxl345]);
        mock.push_sample(0x53, sample([1, 1, 1]));
        mock.push_sample(0x53, sample([2, 2, 2]));
        let read = [0x55, 0xA7, 0x32, 0x06];
        assert_eq!(mock.feed(&read), vec![1, 0, 1, 0, 1, 0]);
        assert_eq!(mock.feed(&read), vec![2, 0, 2, 0, 2, 0]);
        assert_eq!(mock.feed(&read), vec![2, 0, 2, 0, 2, 0]);
        assert_eq!(mock.reads_served(0x53), 3);
        let served: Vec<_> = mock
            .take_events()
            .into_iter()
            .filter_map(|e| match e {
                MockEvent::Read { sample, .. } => Some(sample.and_then(|s| s.accel)),
                _ => None,
            })
            .collect();
        assert_eq!(served, vec![Some([1, 1, 1]), Some([2, 2, 2]), None]);
    }

    #[test]
    fn generator_fills_an_empty_queue() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Adxl345]);
        mock.set_generator(0x53, Box::new(|n| sample([n as i16, 0, 0])));
        mock.push_sample(0x53, sample([100, 0, 0]));
        let read = [0x55, 0xA7, 0x32, 0x06];
        assert_eq!(mock.feed(&read)[0], 100);
        assert_eq!(mock.feed(&read)[0], 1);
        assert_eq!(mock.feed(&read)[0], 2);
    }

    #[test]
    fn mag_registers_hold_x_z_y() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Lsm303dlhcMag]);
        mock.push_sample(
            0x1E,
            Reading {
                mag: Some([0x0102, 0x0304, 0x0506]),
                temp_raw: Some(25),
                ..Reading::default()
            },
        );
        assert_eq!(
            mock.feed(&[0x55, 0x3D, 0x03, 0x06]),
            vec![0x01, 0x02, 0x05, 0x06, 0x03, 0x04]
        );
        assert_eq!(mock.feed(&[0x55, 0x3D, 0x31, 0x02]), vec![0x01, 0x90]);
        // Identity.
        assert_eq!(mock.feed(&[0x55, 0x3D, 0x0A, 0x03]), b"H43".to_vec());
    }

    #[test]
    fn lsm303_accel_increments_only_with_bit_7() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Lsm303dlhcAccel]);
        mock.push_sample(0x19, sample([1000, -1, 0]));
        assert_eq!(
            mock.feed(&[0x55, 0x33, 0xA8, 0x06]),
            vec![0x80, 0x3E, 0xF0, 0xFF, 0x00, 0x00]
        );
        assert_eq!(mock.feed(&[0x55, 0x33, 0x28, 0x03]), vec![0x80, 0x80, 0x80]);
    }

    #[test]
    fn nack_and_silence() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Mpu6050]);
        mock.set_nack(0x68, true);
        assert_eq!(mock.feed(&[0x55, 0xD0, 0x6B, 0x01, 0x01]), vec![0x00]);
        assert_eq!(mock.feed(&[0x55, 0xD1, 0x75, 0x01]), vec![0xFF]);
        mock.set_nacked_read(NackedRead::Nothing);
        assert!(mock.feed(&[0x55, 0xD1, 0x75, 0x01]).is_empty());
        assert_eq!(mock.feed(&[0x58, 0xD0]), vec![0x00]);
        mock.set_nack(0x68, false);
        assert_eq!(mock.feed(&[0x55, 0xD1, 0x75, 0x01]), vec![0x68]);
        assert_eq!(mock.feed(&[0x58, 0xD0]), vec![0xFF]);

        mock.set_silent(true);
        assert!(mock.feed(&[0x55, 0xD0, 0x6B, 0x01, 0x01]).is_empty());
        assert!(mock.feed(&[0x5A, 0x02, 0x60, 0x0A]).is_empty());
        assert_eq!(mock.mode(), None);
        mock.set_silent(false);
        assert_eq!(mock.feed(&[0x5A, 0x02, 0x60, 0x0A]), vec![0xFF, 0x00]);
    }

    #[test]
    fn unknown_bytes_are_skipped() {
        let mut mock = MockUsbIss::with_chips(&[Chip::Mpu6050]);
        assert_eq!(mock.feed(&[0x00, 0x13, 0x55, 0xD1, 0x75, 0x01]), vec![0x68]);
        assert_eq!(mock.bytes_ignored(), 2);
    }
}

mod adxl345 {
    use fieldcal::protocol::chips::adxl345::{decode, encode};

    #[test]
    fn decode_hand_computed() {
        // x = 0x0100 = 256 (1 g), y = 0xFFF6 = -10, z = 0x8000 = -32768.
        let data = [0x00, 0x01, 0xF6, 0xFF, 0x00, 0x80];
        assert_eq!(decode(&data), [256, -10, -32768]);
        assert_eq!(encode([256, -10, -32768]), data);
    }
}

mod lsm303dlhc {
    use fieldcal::protocol::chips::lsm303dlhc::{accel, mag};

    #[test]
    fn accel_decode_hand_computed() {
        // x: 0x3E80 = 16000 -> >> 4 = 1000 (1 g at 1 mg/LSB)
        // y: 0xFFF0 = -16 -> -1
        // z: 0x8000 = -32768 -> -2048
        let data = [0x80, 0x3E, 0xF0, 0xFF, 0x00, 0x80];
        assert_eq!(accel::decode(&data), [1000, -1, -2048]);
        assert_eq!(accel::encode([1000, -1, -2048]), data);
        // The low nibble carries no data.
        assert_eq!(accel::decode(&[0x8F, 0x3E, 0, 0, 0, 0])[0], 1000);
    }

    #[test]
    fn mag_decode_is_x_z_y() {
        // X = 0x0102 = 258, Z = 0xFF00 = -256, Y = 0x0304 = 772,
        // TEMP = 0x0190 -> >> 4 = 25 (3.1 deg C above the unknown offset).
        let data = [0x01, 0x02, 0xFF, 0x00, 0x03, 0x04, 0x01, 0x90];
        let (field, temp) = mag::decode(&data);
        assert_eq!(field, [258, 772, -256]);
        assert_eq!(temp, 25);
        assert_eq!(mag::encode([258, 772, -256], 25), data);
        // A negative temperature: 0xFF80 -> -8 (-1 deg C).
        assert_eq!(mag::decode(&[0, 0, 0, 0, 0, 0, 0xFF, 0x80]).1, -8);
    }

    #[test]
    fn identity_is_h43() {
        assert_eq!(mag::IDENTITY, &[(0x0A, 0x48), (0x0B, 0x34), (0x0C, 0x33)]);
    }
}

mod chips {
    use fieldcal::i2c::usb_iss::UsbIssBus;
    use fieldcal::mock::usb_iss::{MockUsbIss, MockUsbIssPort};
    use fieldcal::protocol::chips::{Chip, ChipError, init_chip, read_chip};
    use fieldcal::sample::Reading;
    use std::time::Duration;

    fn bus(mock: MockUsbIss) -> UsbIssBus<MockUsbIssPort> {
        UsbIssBus::new(
            MockUsbIssPort::new(mock),
            "USB-ISS on test",
            Duration::from_millis(50),
        )
    }

    #[test]
    fn data_len_matches_the_reads() {
        assert_eq!(Chip::Adxl345.data_len(), 6);
        assert_eq!(Chip::Mpu6050.data_len(), 14);
        assert_eq!(Chip::Lsm303dlhcAccel.data_len(), 6);
        assert_eq!(Chip::Lsm303dlhcMag.data_len(), 8);
    }

    #[test]
    fn decode_fills_the_chip_fields() {
        let r = Chip::Adxl345
            .decode(&[0x00, 0x01, 0xF6, 0xFF, 0x00, 0x80], 1.5)
            .unwrap();
        assert_eq!(
            r,
            Reading {
                time: 1.5,
                accel: Some([256, -10, -32768]),
                ..Reading::default()
            }
        );

        let mut mpu = [0u8; 14];
        mpu[6..8].copy_from_slice(&(-3556i16).to_be_bytes());
        mpu[8..10].copy_from_slice(&131i16.to_be_bytes());
        let r = Chip::Mpu6050.decode(&mpu, 2.0).unwrap();
        assert_eq!(r.accel, Some([0, 0, 0]));
        assert_eq!(r.gyro, Some([131, 0, 0]));
        assert_eq!(r.temp_raw, Some(-3556));
        assert!((r.temp_c.unwrap() - 26.071_176).abs() < 1e-5);
        assert_eq!(r.mag, None);

        let r = Chip::Lsm303dlhcAccel
            .decode(&[0x80, 0x3E, 0xF0, 0xFF, 0x00, 0x80], 0.0)
            .unwrap();
        assert_eq!(r.accel, Some([1000, -1, -2048]));

        let r = Chip::Lsm303dlhcMag
            .decode(&[0x01, 0x02, 0xFF, 0x00, 0x03, 0x04, 0x01, 0x90], 0.0)
            .unwrap();
        assert_eq!(r.mag, Some([258, 772, -256]));
        assert_eq!(r.temp_raw, Some(25));
        assert_eq!(r.temp_c, None);
        assert_eq!(r.accel, None);
    }

    #[test]
    fn decode_rejects_a_wrong_length_naming_the_chip() {
        let err = Chip::Lsm303dlhcMag.decode(&[0; 6], 0.0).unwrap_err();
        assert!(matches!(
            err,
            ChipError::DataLength {
                expected: 8,
                found: 6,
                ..
            }
        ));
        assert!(err.to_string().contains("LSM303DLHC magnetometer"), "{err}");
    }

    #[test]
    fn encode_inverts_decode() {
        let reading = Reading {
            time: 0.0,
            mag: Some([-300, 120, 4000]),
            accel: Some([-1000, 2, 1500]),
            gyro: Some([7, -8, 9]),
            temp_raw: Some(-40),
            temp_c: None,
            timer: None,
            stream: 0,
        };
        for chip in Chip::ALL {
            let bytes = chip.encode(&reading);
            assert_eq!(bytes.len(), chip.data_len(), "{chip:?}");
            let back = chip.decode(&bytes, 0.0).unwrap();
            match chip {
                Chip::Adxl345 | Chip::Lsm303dlhcAccel => assert_eq!(back.accel, reading.accel),
                Chip::Mpu6050 => {
                    assert_eq!(back.accel, reading.accel);
                    assert_eq!(back.gyro, reading.gyro);
                    assert_eq!(back.temp_raw, reading.temp_raw);
                }
                Chip::Lsm303dlhcMag => {
                    assert_eq!(back.mag, reading.mag);
                    assert_eq!(back.temp_raw, reading.temp_raw);
                }
            }
        }
    }

    #[test]
    fn init_and_read_every_chip_through_the_mock() {
        let mut mock = MockUsbIss::new();
        for chip in Chip::ALL {
            mock.add_chip(chip);
        }
        let mut bus = bus(mock);
        let mut buf = Vec::new();
        for chip in Chip::ALL {
            let address = chip.default_address();
            init_chip(&mut bus, chip, address).unwrap();
            for &(register, value) in chip.init_writes() {
                let stored = bus
                    .get_ref()
                    .mock()
                    .register(address, register & 0x7F)
                    .unwrap();
                assert_eq!(stored, value, "{chip:?} register 0x{register:02X}");
            }
            let sample = Reading {
                accel: Some([100, -200, 300]),
                mag: Some([-5, 6, -7]),
                gyro: Some([1, 2, 3]),
                temp_raw: Some(12),
                ..Reading::default()
            };
            bus.get_mut().mock_mut().push_sample(address, sample);
            read_chip(&mut bus, chip, address, &mut buf).unwrap();
            assert_eq!(buf, chip.encode(&sample), "{chip:?}");
        }
    }

    #[test]
    fn a_missing_chip_is_reported_by_name_and_address() {
        let mut bus = bus(MockUsbIss::new());
        let err = init_chip(&mut bus, Chip::Lsm303dlhcAccel, 0x19).unwrap_err();
        assert_eq!(
            err.to_string(),
            "LSM303DLHC accelerometer at 0x19: no ACK writing CTRL_REG1_A (0x20): \
             check the wiring and the address"
        );
        let err = init_chip(&mut bus, Chip::Lsm303dlhcMag, 0x1E).unwrap_err();
        assert!(matches!(err, ChipError::NotAnswering { .. }), "{err}");
        assert!(
            err.to_string()
                .starts_with("LSM303DLHC magnetometer at 0x1E: IRA_REG_M (0x0A)"),
            "{err}"
        );
        let mut buf = Vec::new();
        let err = read_chip(&mut bus, Chip::Mpu6050, 0x68, &mut buf).unwrap_err();
        assert!(matches!(err, ChipError::NotAnswering { .. }), "{err}");
    }

    #[test]
    fn a_nacked_mag_write_names_the_register() {
        let mut mock = MockUsbIss::new();
        mock.add_chip(Chip::Lsm303dlhcMag);
        let mut bus = bus(mock);
        // The identity reads pass; then the chip stops acknowledging.
        bus.get_mut().mock_mut().set_nack_writes(0x1E, true);
        let err = init_chip(&mut bus, Chip::Lsm303dlhcMag, 0x1E).unwrap_err();
        assert_eq!(
            err.to_string(),
            "LSM303DLHC magnetometer at 0x1E: no ACK writing CRA_REG_M (0x00): \
             check the wiring and the address"
        );
    }

    #[test]
    fn another_chip_at_the_address_is_a_wrong_identity() {
        let mut mock = MockUsbIss::new();
        mock.add_chip_at(Chip::Adxl345, 0x68);
        let mut bus = bus(mock);
        let err = init_chip(&mut bus, Chip::Mpu6050, 0x68).unwrap_err();
        assert!(matches!(
            err,
            ChipError::WrongIdentity {
                register: 0x75,
                expected: 0x68,
                ..
            }
        ));
        assert!(err.to_string().contains("WHO_AM_I (0x75)"), "{err}");
    }

    #[test]
    fn a_silent_bridge_is_a_timeout_naming_the_chip() {
        let mut mock = MockUsbIss::new();
        mock.add_chip(Chip::Adxl345);
        mock.set_silent(true);
        let mut bus = bus(mock);
        let mut buf = Vec::new();
        let err = read_chip(&mut bus, Chip::Adxl345, 0x53, &mut buf).unwrap_err();
        assert!(matches!(err, ChipError::Timeout { .. }), "{err}");
        let text = err.to_string();
        assert!(
            text.starts_with("ADXL345 accelerometer at 0x53: USB-ISS on test did not answer"),
            "{text}"
        );
    }
}

mod mpu6050 {
    use fieldcal::protocol::chips::mpu6050::{decode, encode, temp_c, temp_raw};

    #[test]
    fn decode_hand_computed() {
        let data = [
            0x40, 0x00, // AX = 16384 (1 g at +-2 g)
            0xFF, 0xFE, // AY = -2
            0x80, 0x00, // AZ = -32768
            0xF2, 0x1C, // TEMP = -3556 -> 36.53 - 10.4588 = 26.0712 C
            0x00, 0x83, // GX = 131 (1 deg/s)
            0x7F, 0xFF, // GY = 32767
            0xFF, 0x7D, // GZ = -131
        ];
        let s = decode(&data);
        assert_eq!(s.accel, [16384, -2, -32768]);
        assert_eq!(s.temp_raw, -3556);
        assert_eq!(s.gyro, [131, 32767, -131]);
        assert!((temp_c(s.temp_raw) - 26.071_176).abs() < 1e-5);
        assert_eq!(encode(&s), data);
    }

    #[test]
    fn temperature_round_trips() {
        assert_eq!(temp_raw(36.53), 0);
        assert_eq!(temp_raw(temp_c(-3556)), -3556);
    }
}

mod falcon {
    use fieldcal::protocol::falcon::{
        BAUD, FRAME_LEN, FalconDecoder, FalconFrame, FrameError, HEADER, NOMINAL_PERIOD,
        START_CONTINUOUS, STOP_CONTINUOUS, checksum,
    };
    use std::time::Duration;

    fn frame(seed: i16, timer: u16) -> FalconFrame {
        FalconFrame {
            mag: [seed, seed.wrapping_mul(3), -seed],
            accel: [100, -200, seed.wrapping_add(7)],
            rate: [-1, 0, seed.wrapping_mul(-5)],
            timer,
        }
    }

    fn decode_all(dec: &mut FalconDecoder, bytes: &[u8]) -> Vec<FalconFrame> {
        let mut out = Vec::new();
        dec.decode(bytes, |f| out.push(f));
        out
    }

    fn timers(dec: &mut FalconDecoder, ts: &[u16]) {
        for &t in ts {
            let bytes = frame(5, t).encode();
            assert_eq!(decode_all(dec, &bytes).len(), 1, "timer {t}");
        }
    }

    #[test]
    fn encode_decode_identity() {
        let f = FalconFrame {
            mag: [i16::MIN, -1, i16::MAX],
            accel: [0, 1, -2],
            rate: [0x0202, 0x0002, 0x0200],
            timer: 0xFFFF,
        };
        let bytes = f.encode();
        assert_eq!(FalconFrame::parse(&bytes), Ok(f));
        let mut dec = FalconDecoder::new();
        assert_eq!(decode_all(&mut dec, &bytes), vec![f]);
        assert_eq!(dec.pending(), 0);
        assert_eq!(dec.counters().frames_good, 1);
        assert_eq!(dec.counters().bytes_skipped, 0);
    }

    #[test]
    fn checksum_of_known_frame() {
        let f = FalconFrame {
            mag: [1, 2, 3],
            accel: [-1, 0x0100, 0x1234],
            rate: [0, 0, 0x7FFF],
            timer: 0xFFFF,
        };
        // By hand: 0x02 + 1 + 2 + 3 = 0x0008; + 0xFFFF = 0x1_0007;
        // + 0x0100 = 0x1_0107; + 0x1234 = 0x1_133B; + 0 + 0;
        // + 0x7FFF = 0x1_933A; + 0xFFFF = 0x2_9339; mod 65536 = 0x9339.
        let expected: [u8; FRAME_LEN] = [
            0x02, 0x00, 0x01, 0x00, 0x02, 0x00, 0x03, 0xFF, 0xFF, 0x01, 0x00, 0x12, 0x34, 0x00,
            0x00, 0x00, 0x00, 0x7F, 0xFF, 0xFF, 0xFF, 0x93, 0x39,
        ];
        assert_eq!(f.encode(), expected);
        assert_eq!(checksum(&expected[..21]), 0x9339);
        // Odd tails count as a high byte; empty sums to 0.
        assert_eq!(checksum(&[0x02, 0x01]), 0x0102);
        assert_eq!(checksum(&[]), 0);
    }

    #[test]
    fn parse_reports_errors() {
        let mut bytes = frame(1, 2).encode();
        bytes[22] ^= 1;
        assert!(matches!(
            FalconFrame::parse(&bytes),
            Err(FrameError::BadChecksum { .. })
        ));
        bytes[0] = 0x03;
        assert_eq!(FalconFrame::parse(&bytes), Err(FrameError::BadHeader(0x03)));
    }

    #[test]
    fn bad_checksum_then_good_frame() {
        let good = frame(9, 10);
        let mut bad = frame(4, 9).encode();
        assert!(!bad[1..].contains(&HEADER));
        bad[22] ^= 0x40;
        let mut stream = bad.to_vec();
        stream.extend_from_slice(&good.encode());
        let mut dec = FalconDecoder::new();
        assert_eq!(decode_all(&mut dec, &stream), vec![good]);
        let c = dec.counters();
        assert_eq!(c.frames_bad, 1);
        assert_eq!(c.bytes_skipped, FRAME_LEN as u64);
        assert_eq!(c.frames_good, 1);
    }

    #[test]
    fn real_frame_inside_a_false_one() {
        let good = frame(11, 300);
        let enc = good.encode();
        // A false header, with another 0x02 inside it, then the real frame
        // starting three bytes into the false one's 23.
        let mut stream = vec![HEADER, 0x55, HEADER, 0x13];
        stream.extend_from_slice(&enc);
        for at in [0, 2] {
            let block: &[u8; FRAME_LEN] = stream[at..at + FRAME_LEN].try_into().unwrap();
            assert!(FalconFrame::parse(block).is_err(), "false frame at {at}");
        }
        for chunk in [1, 5, stream.len()] {
            let mut dec = FalconDecoder::new();
            let mut out = Vec::new();
            for c in stream.chunks(chunk) {
                dec.decode(c, |f| out.push(f));
            }
            assert_eq!(out, vec![good], "chunk {chunk}");
            let c = dec.counters();
            assert_eq!(c.frames_bad, 2);
            assert_eq!(c.bytes_skipped, 4);
            assert_eq!(dec.pending(), 0);
        }
    }

    #[test]
    fn truncated_frame_stays_pending() {
        let f = frame(3, 1);
        let enc = f.encode();
        let mut dec = FalconDecoder::new();
        assert!(decode_all(&mut dec, &enc[..20]).is_empty());
        assert_eq!(dec.pending(), 20);
        assert_eq!(decode_all(&mut dec, &enc[20..]), vec![f]);
        assert_eq!(dec.pending(), 0);
        assert_eq!(dec.counters().frames_bad, 0);
    }

    #[test]
    fn lost_frames_with_learned_step() {
        let mut dec = FalconDecoder::new();
        // 8 deltas of 10 teach the step.
        timers(&mut dec, &[0, 10, 20, 30, 40, 50, 60, 70, 80]);
        assert_eq!(dec.ticks_per_frame(), Some(10));
        assert_eq!(dec.counters().frames_lost, 0);
        // 80 -> 110: k = 3, two lost; 120 -> 171: k = round(5.1) = 5, four lost.
        timers(&mut dec, &[110, 120, 171]);
        assert_eq!(dec.counters().frames_lost, 6);
        assert_eq!(dec.counters().timer_resets, 0);
    }

    #[test]
    fn gaps_while_learning_are_counted_once_learned() {
        let mut dec = FalconDecoder::new();
        // Deltas 10, 30, 10, 10, 20, 10, 10: not yet 8.
        timers(&mut dec, &[0, 10, 40, 50, 60, 80, 90, 100]);
        assert_eq!(dec.ticks_per_frame(), None);
        assert_eq!(dec.counters().frames_lost, 0);
        timers(&mut dec, &[110]);
        assert_eq!(dec.ticks_per_frame(), Some(10));
        assert_eq!(dec.counters().frames_lost, 3);
    }

    #[test]
    fn lost_frames_with_given_step() {
        let mut dec = FalconDecoder::with_ticks_per_frame(10);
        assert_eq!(dec.ticks_per_frame(), Some(10));
        timers(&mut dec, &[0, 30, 40, 50]);
        assert_eq!(dec.counters().frames_lost, 2);
        assert_eq!(
            FalconDecoder::with_ticks_per_frame(0).ticks_per_frame(),
            None
        );
    }

    #[test]
    fn timer_wrap_is_not_a_loss() {
        let mut dec = FalconDecoder::with_ticks_per_frame(1);
        timers(&mut dec, &[65534, 65535, 0, 1]);
        assert_eq!(dec.counters().frames_lost, 0);
        assert_eq!(dec.counters().timer_resets, 0);

        let mut dec = FalconDecoder::new();
        let ts: Vec<u16> = (0..12u16).map(|i| 65_490u16.wrapping_add(10 * i)).collect();
        assert!(ts.contains(&4));
        timers(&mut dec, &ts);
        assert_eq!(dec.ticks_per_frame(), Some(10));
        assert_eq!(dec.counters().frames_lost, 0);
        assert_eq!(dec.counters().timer_resets, 0);
    }

    #[test]
    fn timer_reset_restarts_counting() {
        let mut dec = FalconDecoder::with_ticks_per_frame(1);
        // Backwards (5000 -> 10), then an absurd jump (11 -> 3000, 2989 steps).
        timers(&mut dec, &[5000, 5001, 10, 11, 3000]);
        let c = dec.counters();
        assert_eq!(c.frames_lost, 0);
        assert_eq!(c.timer_resets, 2);
        // Counting goes on from the new base: 3000 -> 3003 loses two.
        timers(&mut dec, &[3003]);
        assert_eq!(dec.counters().frames_lost, 2);
        // Standing still is a reset too.
        timers(&mut dec, &[3003]);
        assert_eq!(dec.counters().timer_resets, 3);
        // Exactly MAX_GAP_STEPS steps is still a gap.
        timers(&mut dec, &[3003 + 1000]);
        assert_eq!(dec.counters().frames_lost, 2 + 999);
    }

    #[test]
    fn discard_partial_drops_held_bytes() {
        let a = frame(4, 9).encode();
        assert!(!a[1..].contains(&HEADER));
        let b = frame(6, 8);
        let mut dec = FalconDecoder::new();
        assert!(decode_all(&mut dec, &a[..10]).is_empty());
        assert_eq!(dec.pending(), 10);
        assert_eq!(dec.discard_partial(), 10);
        assert_eq!(dec.pending(), 0);
        assert_eq!(dec.discard_partial(), 0);
        // The rest of the abandoned frame is garbage now; the next is found.
        let mut rest = a[10..].to_vec();
        rest.extend_from_slice(&b.encode());
        assert_eq!(decode_all(&mut dec, &rest), vec![b]);
        let c = dec.counters();
        assert_eq!(c.bytes_skipped, FRAME_LEN as u64);
        assert_eq!(c.frames_bad, 0);
    }

    #[test]
    fn to_reading_maps_fields() {
        let f = frame(8, 42);
        let r = f.to_reading(1.5);
        assert_eq!(r.time, 1.5);
        assert_eq!(r.mag, Some(f.mag));
        assert_eq!(r.accel, Some(f.accel));
        assert_eq!(r.gyro, Some(f.rate));
        assert_eq!(r.timer, Some(42));
        assert_eq!(r.temp_raw, None);
        assert_eq!(r.temp_c, None);
    }

    #[test]
    fn constants_match_the_protocol() {
        assert_eq!(START_CONTINUOUS, [0x10, 0x00, 0x02]);
        assert_eq!(STOP_CONTINUOUS, [0x10, 0x00, 0x00]);
        assert_eq!(NOMINAL_PERIOD, Duration::from_millis(50));
        assert_eq!(BAUD, 38_400);
    }
}

mod usb_iss {
    use fieldcal::protocol::usb_iss::{
        I2cSpeed, UsbIssError, check_set_mode_reply, encode_read, encode_set_mode, encode_test,
        encode_write, write_acked,
    };

    #[test]
    fn set_mode_bytes() {
        assert_eq!(encode_set_mode(I2cSpeed::Khz100), [0x5A, 0x02, 0x60, 0x0A]);
        assert_eq!(encode_set_mode(I2cSpeed::Khz400), [0x5A, 0x02, 0x70, 0x0A]);
    }

    #[test]
    fn set_mode_replies() {
        assert_eq!(check_set_mode_reply([0xFF, 0x00]), Ok(()));
        let err = check_set_mode_reply([0x00, 0x05]).unwrap_err();
        assert_eq!(err, UsbIssError::ModeRejected { code: 0x05 });
        assert!(err.to_string().contains("unknown command"), "{err}");
        assert_eq!(
            check_set_mode_reply([0x12, 0x34]),
            Err(UsbIssError::BadModeReply {
                reply: [0x12, 0x34]
            })
        );
    }

    /// The four reads of protocols.md §2, byte for byte.
    #[test]
    fn read_bytes_match_the_documented_table() {
        assert_eq!(encode_read(0x68, 0x3B, 14), Ok([0x55, 0xD1, 0x3B, 0x0E]));
        assert_eq!(encode_read(0x53, 0x32, 6), Ok([0x55, 0xA7, 0x32, 0x06]));
        assert_eq!(encode_read(0x19, 0xA8, 6), Ok([0x55, 0x33, 0xA8, 0x06]));
        assert_eq!(encode_read(0x1E, 0x03, 6), Ok([0x55, 0x3D, 0x03, 0x06]));
    }

    #[test]
    fn read_limits() {
        assert!(encode_read(0x1E, 0x00, 60).is_ok());
        assert_eq!(
            encode_read(0x1E, 0x00, 61),
            Err(UsbIssError::ReadTooLong { len: 61 })
        );
        assert_eq!(
            encode_read(0x80, 0x00, 1),
            Err(UsbIssError::BadAddress { address: 0x80 })
        );
    }

    #[test]
    fn write_bytes() {
        assert_eq!(
            encode_write(0x1E, 0x00, &[0x94]),
            Ok(vec![0x55, 0x3C, 0x00, 0x01, 0x94])
        );
        assert_eq!(
            encode_write(0x53, 0x2C, &[0x0A, 0x08]),
            Ok(vec![0x55, 0xA6, 0x2C, 0x02, 0x0A, 0x08])
        );
        assert_eq!(
            encode_write(0x53, 0x00, &[0; 61]),
            Err(UsbIssError::WriteTooLong { len: 61 })
        );
        assert_eq!(
            encode_write(0xFF, 0x00, &[1]),
            Err(UsbIssError::BadAddress { address: 0xFF })
        );
    }

    #[test]
    fn write_ack_is_any_non_zero_byte() {
        assert!(write_acked(0xFF));
        assert!(write_acked(0x01));
        assert!(!write_acked(0x00));
    }

    #[test]
    fn test_command() {
        assert_eq!(encode_test(0x68), Ok([0x58, 0xD0]));
    }
}
