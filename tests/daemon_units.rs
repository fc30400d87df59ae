//! Unit tests of the daemon's parts that need only the public API, moved out
//! of src/daemon: one module a source file, the tests unchanged.

mod common;

mod acceptance {
    use std::time::Duration;

    use fieldcal::daemon::acceptance::{Limits, check};
    use fieldcal::model::fit::{FitReport, Solver};
    use fieldcal::model::heading::Coverage;
    use fieldcal::model::paper::PaperCalibration;

    fn report(a: f64, b: f64, d: f64, r: f64, rms: f64, covered_deg: f64) -> FitReport {
        let calibration = PaperCalibration { a, b, d, r };
        FitReport {
            solver: Solver::Lsq,
            calibration,
            theta: calibration.to_theta(),
            rms,
            n: 200,
            iterations: None,
            coverage: Coverage {
                covered_deg,
                largest_gap_deg: 360.0 - covered_deg,
                gap_start_deg: 0.0,
            },
            elapsed: Duration::ZERO,
        }
    }

    fn good() -> FitReport {
        report(1.1, -200.0, 300.0, 1000.0, 0.01, 358.0)
    }

    #[test]
    fn accepts_a_good_fit() {
        assert_eq!(check(&good(), &Limits::default()), Ok(()));
        // On the limits is still accepted: limits are inclusive.
        let edge = report(2.0, 4000.0, 3000.0, 1000.0, 0.05, 300.0);
        assert_eq!(check(&edge, &Limits::default()), Ok(()));
    }

    #[test]
    fn accepts_a_real_fit_of_a_simulated_turn() {
        let sim = fieldcal::sim::SimSensor {
            gain_x: 1.2,
            offset_x: 2500.0,
            offset_y: -4000.0,
            noise: 3.0,
            ..Default::default()
        };
        let data = sim.simulate().unwrap();
        let fit = fieldcal::model::fit::fit_paper(
            &data.x,
            &data.y,
            &fieldcal::model::fit::FitOptions::default(),
            &mut |_| {},
        )
        .unwrap();
        assert_eq!(check(&fit, &Limits::default()), Ok(()));
    }

    #[test]
    fn rejects_rms_with_its_key() {
        let r = report(1.1, -200.0, 300.0, 1000.0, 0.073, 358.0);
        assert_eq!(
            check(&r, &Limits::default()).unwrap_err(),
            "rms 7.3 % of the field exceeds the limit of 5.0 % (limits.max_rms)"
        );
    }

    #[test]
    fn rejects_coverage_with_its_key() {
        let r = report(1.1, -200.0, 300.0, 1000.0, 0.01, 250.0);
        assert_eq!(
            check(&r, &Limits::default()).unwrap_err(),
            "heading coverage 250.0° is below the limit of 300.0° (limits.min_coverage_deg)"
        );
    }

    #[test]
    fn rejects_radius_outside_known_bounds() {
        let limits = Limits {
            min_radius: Some(1200.0),
            ..Default::default()
        };
        let err = check(&good(), &limits).unwrap_err();
        assert!(
            err.contains(
                "field radius 1000.0 counts is below the limit of 1200 counts (limits.min_radius)"
            ),
            "{err}"
        );
        let limits = Limits {
            max_radius: Some(800.0),
            ..Default::default()
        };
        let err = check(&good(), &limits).unwrap_err();
        assert!(
            err.contains("exceeds the limit of 800 counts (limits.max_radius)"),
            "{err}"
        );
        let limits = Limits {
            min_radius: Some(900.0),
            max_radius: Some(1100.0),
            ..Default::default()
        };
        assert_eq!(check(&good(), &limits), Ok(()));
    }

    #[test]
    fn rejects_offset_with_its_key_and_raw_offsets() {
        // |(b, d)| = 6000 = 6 r; raw x offset -b/a = -6000/1.5.
        let r = report(1.5, 6000.0, 0.0, 1000.0, 0.01, 358.0);
        let err = check(&r, &Limits::default()).unwrap_err();
        assert!(
            err.starts_with("offset 6.00 times the field radius (raw x -4000.0, y 0.0 counts"),
            "{err}"
        );
        assert!(
            err.ends_with("exceeds the limit of 5 (limits.max_offset_ratio)"),
            "{err}"
        );
    }

    #[test]
    fn rejects_scale_either_way_with_its_key() {
        for a in [2.5, 0.4] {
            let err = check(
                &report(a, 0.0, 0.0, 1000.0, 0.01, 358.0),
                &Limits::default(),
            )
            .unwrap_err();
            assert!(err.starts_with("axis gain ratio 2.500"), "{err}");
            assert!(err.ends_with("(limits.max_scale_ratio)"), "{err}");
        }
    }

    #[test]
    fn names_every_failure_at_once() {
        let r = report(3.0, 0.0, 0.0, 1000.0, 0.2, 100.0);
        let err = check(&r, &Limits::default()).unwrap_err();
        for key in ["min_coverage_deg", "max_rms", "max_scale_ratio"] {
            assert!(err.contains(&format!("(limits.{key})")), "{err}");
        }
        assert_eq!(err.matches("; ").count(), 2, "{err}");
    }

    #[test]
    fn refuses_non_finite_parameters() {
        let r = report(1.0, f64::NAN, 0.0, 1000.0, 0.01, 358.0);
        let err = check(&r, &Limits::default()).unwrap_err();
        assert!(err.contains("non-finite b"), "{err}");
        let r = report(1.0, 0.0, 0.0, 1000.0, f64::INFINITY, 358.0);
        assert!(
            check(&r, &Limits::default())
                .unwrap_err()
                .contains("non-finite rms")
        );
    }

    #[test]
    fn validate_names_the_key() {
        assert_eq!(Limits::default().validate(), Ok(()));
        let cases: [(Limits, &str); 6] = [
            (
                Limits {
                    max_rms: 0.0,
                    ..Default::default()
                },
                "max_rms",
            ),
            (
                Limits {
                    max_rms: f64::NAN,
                    ..Default::default()
                },
                "max_rms",
            ),
            (
                Limits {
                    min_radius: Some(-1.0),
                    ..Default::default()
                },
                "min_radius",
            ),
            (
                Limits {
                    min_radius: Some(10.0),
                    max_radius: Some(5.0),
                    ..Default::default()
                },
                "min_radius (10) must not exceed max_radius (5)",
            ),
            (
                Limits {
                    max_scale_ratio: 0.5,
                    ..Default::default()
                },
                "max_scale_ratio",
            ),
            (
                Limits {
                    min_coverage_deg: 400.0,
                    ..Default::default()
                },
                "min_coverage_deg",
            ),
        ];
        for (limits, key) in cases {
            let err = limits.validate().unwrap_err();
            assert!(err.starts_with(key), "{err}");
        }
        let err = Limits {
            max_offset_ratio: f64::INFINITY,
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert!(err.starts_with("max_offset_ratio"), "{err}");
    }

    #[test]
    fn limits_deserialize_with_defaults_and_refuse_unknown_keys() {
        let l: Limits = toml::from_str("max_rms = 0.02\nmin_radius = 300.0").unwrap();
        assert_eq!(l.max_rms, 0.02);
        assert_eq!(l.min_radius, Some(300.0));
        assert_eq!(l.max_scale_ratio, Limits::default().max_scale_ratio);
        assert!(toml::from_str::<Limits>("max_rsm = 0.02").is_err());
    }
}

mod north {
    use fieldcal::daemon::north::{LocationKeys, MeasuredDip, North, earth};
    use fieldcal::geomag::CivilDate;
    use fieldcal::model::tilt::RobustSpread;

    fn place(lat: f64, lon: f64, date: &str) -> LocationKeys {
        LocationKeys {
            latitude: lat,
            longitude: lon,
            height_m: 0.0,
            date: Some(date.into()),
        }
    }

    /// NOAA's WMM2025 test value (Technical Report, Table 6, epoch 2025.0,
    /// height 0, 80° S 120° W): D = 68.78°, I = -72.00°, F = 54698.2 nT.
    #[test]
    fn a_location_gives_the_wmm_declination_and_names_its_source() {
        let north = North::location(&place(-80.0, -120.0, "2025-01-01"), None).unwrap();
        assert!((north.declination_deg - 68.78).abs() < 0.011, "{north:?}");
        assert_eq!(north.source, "WMM2025 at -80,-120,2025-01-01");
        assert!(!north.date_is_today);
        let m = north.model.unwrap();
        assert!((m.inclination_deg + 72.00).abs() < 0.011);
        assert!((m.total_intensity_nt - 54698.2).abs() < 1.0);
        // Before 2025 the crate evaluates WMM2020.
        let north = North::location(&place(50.0, 8.0, "2024-12-31"), None).unwrap();
        assert!(
            north.source.starts_with("WMM2020 at 50,8,"),
            "{}",
            north.source
        );
    }

    #[test]
    fn the_date_defaults_to_today_and_ranges_are_refused_by_key() {
        let today = CivilDate::parse("2026-11-23").unwrap();
        let keys = LocationKeys {
            date: None,
            ..place(50.0, 8.0, "")
        };
        let north = North::location(&keys, Some(today)).unwrap();
        assert!(north.date_is_today);
        assert!(north.source.ends_with(",2026-11-23"), "{}", north.source);
        assert!(north.describe().contains("the host's today"));
        let key = |k: LocationKeys, today| North::location(&k, today).unwrap_err().key;
        assert_eq!(key(place(91.0, 8.0, "2026-01-01"), None), "latitude");
        assert_eq!(key(place(50.0, -181.0, "2026-01-01"), None), "longitude");
        assert_eq!(
            key(
                LocationKeys {
                    height_m: 900_000.0,
                    ..place(50.0, 8.0, "2026-01-01")
                },
                None
            ),
            "height_m"
        );
        assert_eq!(key(place(50.0, 8.0, "2026-02-30"), None), "date");
        let e = North::location(&place(50.0, 8.0, "2019-12-31"), None).unwrap_err();
        assert_eq!(e.key, "date");
        assert!(e.problem.contains("2020-01-01"), "{}", e.problem);
        let late = CivilDate::parse("2030-01-02").unwrap();
        let e = North::location(&keys, Some(late)).unwrap_err();
        assert!(e.problem.contains("no date given"), "{}", e.problem);
        assert!(North::declination(180.5).is_err());
        assert!(North::declination(f64::NAN).is_err());
    }

    #[test]
    fn the_true_heading_wraps_into_0_to_360() {
        let n = North::declination(-3.5).unwrap();
        assert_eq!(n.true_heading(1.0), 357.5);
        assert_eq!(n.true_heading(3.5), 0.0);
        assert_eq!(n.true_heading(-1e-17 + 3.5), 0.0);
        let n = North::declination(10.0).unwrap();
        assert_eq!(n.true_heading(355.0), 5.0);
    }

    #[test]
    fn the_earth_comparison_says_what_disagrees_and_why() {
        let north = North::location(&place(-80.0, -120.0, "2025-01-01"), None).unwrap();
        let m = north.model.unwrap();
        let lsb = 2000.0;
        let r_right = m.total_intensity_nt / 1e5 * lsb;
        let incl = |median| {
            Ok(MeasuredDip {
                spread: RobustSpread {
                    median,
                    spread: 1.0,
                    n: 1000,
                },
                accelerometer_calibrated: true,
            })
        };
        let e = earth(&north, r_right * 1.01, Some(lsb), incl(-71.5)).unwrap();
        assert_eq!(e.magnitude_agrees, Some(true), "{e:?}");
        assert_eq!(e.inclination_agrees, Some(true), "{e:?}");
        assert!((e.ratio.unwrap() - 1.01).abs() < 1e-9);
        assert!(
            e.verdict.starts_with("the measured field agrees"),
            "{}",
            e.verdict
        );
        // Wrong units: r/F far from 1.
        let e = earth(&north, r_right * 0.77, Some(lsb), incl(-72.0)).unwrap();
        assert_eq!(e.magnitude_agrees, Some(false));
        assert!(e.verdict.contains("r/F = 0.770"), "{}", e.verdict);
        assert!(e.verdict.contains("lsb_per_gauss"), "{}", e.verdict);
        // Mirrored axes.
        let e = earth(&north, r_right, Some(lsb), incl(72.0)).unwrap();
        assert_eq!(e.inclination_agrees, Some(false));
        assert!(e.verdict.contains("mirrored"), "{}", e.verdict);
        assert_eq!(e.measured_inclination_accelerometer, Some("calibrated"));
        assert!(!e.verdict.contains("raw"), "{}", e.verdict);
        // The same dip, off by 4°, measured with a raw accelerometer: said
        // beside the figure and among the causes.
        let raw = |median| {
            incl(median).map(|d| MeasuredDip {
                accelerometer_calibrated: false,
                ..d
            })
        };
        let e = earth(&north, r_right, Some(lsb), raw(-68.0)).unwrap();
        assert_eq!(e.inclination_agrees, Some(false), "{e:?}");
        assert_eq!(e.measured_inclination_accelerometer, Some("raw"));
        assert!(
            e.verdict.contains("raw, uncalibrated accelerometer"),
            "{}",
            e.verdict
        );
        assert!(e.verdict.contains("not calibrated yet"), "{}", e.verdict);
        let e = earth(&north, r_right, Some(lsb), raw(-71.5)).unwrap();
        assert!(
            e.verdict.contains("agrees") && e.verdict.contains("raw"),
            "{}",
            e.verdict
        );
        // No units, no tilt.
        let e = earth(&north, r_right, None, Err("no tilt".into())).unwrap();
        assert_eq!(e.ratio, None);
        assert!(e.verdict.contains("cannot be compared"), "{}", e.verdict);
        assert!(e.verdict.contains("no tilt"), "{}", e.verdict);
        // A declination without a location compares nothing.
        assert!(earth(&North::declination(1.0).unwrap(), 1.0, Some(lsb), incl(0.0)).is_none());
    }
}

mod sensor3 {
    use fieldcal::daemon::config::Field;
    use fieldcal::daemon::config::parse;
    use fieldcal::daemon::messages::SensorState;
    use fieldcal::daemon::reload::{RunningSource, apply};
    use fieldcal::daemon::sensor::Sensor;
    use fieldcal::daemon::sensor3::check_limits;
    use fieldcal::model::ellipsoid;
    use fieldcal::sample::Reading;
    use fieldcal::sim3::{ImuMotion, Motion3, SimAxes3, SimImu3, SimSensor3};

    const TEXT: &str = "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
        [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\ntilt = \"level\"\n\
        [[sensor]]\nname = \"level\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n";

    const SOURCES: [RunningSource<'static>; 1] = [RunningSource {
        name: "imu",
        csv: None,
    }];

    fn config(text: &str) -> fieldcal::daemon::config::Config {
        parse(text, std::path::Path::new("t.toml")).unwrap()
    }

    /// The shipped capture's IMU (tests/data/README.md), as readings.
    fn tumble() -> Vec<Reading> {
        let imu = SimImu3 {
            field: 1000.0,
            inclination_deg: 60.0,
            gravity: 4096.0,
            mag: SimAxes3 {
                matrix: [[1.08, 0.04, -0.02], [0.04, 0.95, 0.03], [-0.02, 0.03, 1.0]],
                offset: [150.0, -80.0, 60.0],
                noise: 3.0,
            },
            accel: SimAxes3 {
                matrix: [[1.01, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.0]],
                offset: [40.0, -25.0, 60.0],
                noise: 8.0,
            },
            gyro_noise: 0.0,
            period: 0.05,
            n: 2880,
            motion: ImuMotion::Tumble {
                turns: 24.0,
                axis_path_rad: 12.0,
            },
            seed: 7,
        };
        let round = |v: [f64; 3]| v.map(|x| x.round() as i16);
        imu.simulate()
            .unwrap()
            .into_iter()
            .map(|s| Reading {
                time: s.t,
                mag: Some(round(s.mag)),
                accel: Some(round(s.accel)),
                ..Reading::default()
            })
            .collect()
    }

    fn feed(sensors: &mut [(usize, Sensor)], readings: &[Reading]) -> Vec<String> {
        let mut lines = Vec::new();
        for r in readings {
            for (_, s) in sensors.iter_mut() {
                if s.wants(r.stream) {
                    s.on_reading(r, &mut |_, l| lines.push(l));
                }
            }
            // As the daemon's Sensors::link_tilts does on an acceptance.
            let level = sensors[1].1.calibration().cloned();
            if let Some(three) = sensors[0].1.three_mut() {
                three.set_tilt(level.as_ref());
            }
        }
        lines
    }

    #[test]
    fn a_reload_keeps_an_unchanged_3_axis_sensor_and_carries_a_changed_ones_calibration() {
        let mut running = config(TEXT);
        let mut sensors: Vec<(usize, Sensor)> = running
            .sensors
            .iter()
            .map(|s| (0, Sensor::new(s.clone(), None)))
            .collect();
        let readings = tumble();
        let lines = feed(&mut sensors, &readings);
        assert_eq!(
            lines
                .iter()
                .filter(|l| l.contains("\"CALIBRATION\"") && l.contains("\"accepted\":true"))
                .count(),
            2
        );
        assert!(lines.iter().any(|l| l.contains("\"heading_deg\"")));
        sensors[0].1.recalibrate();
        feed(&mut sensors, &readings[..100]);
        let sphere = |s: &Sensor| s.status().sphere.map(|p| p.samples);
        assert_eq!(sphere(&sensors[0].1), Some(100));

        // The same file: both sensors as they were.
        let out = apply(Ok(config(TEXT)), &mut running, &mut sensors, &SOURCES, None);
        assert!(out.lines[0].contains("no change"), "{:?}", out.lines);
        assert_eq!(sphere(&sensors[0].1), Some(100));
        assert_eq!(sensors[0].1.status().state, SensorState::Recalibrating);
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        assert_eq!(sensors[1].1.calibration().map(|c| c.id), Some(1));

        // compass's model changes: it keeps correcting with #1, collects
        // afresh, and its next calibration is #2.
        let new = TEXT.replace(
            "tilt = \"level\"\n",
            "tilt = \"level\"\nmodel = \"offset+scale\"\n",
        );
        let out = apply(Ok(config(&new)), &mut running, &mut sensors, &SOURCES, None);
        assert!(
            out.lines.iter().any(|l| l.contains("compass")),
            "{:?}",
            out.lines
        );
        assert_eq!(sphere(&sensors[0].1), Some(0));
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        assert_eq!(sensors[1].1.calibration().map(|c| c.id), Some(1));
        let lines = feed(&mut sensors, &readings);
        let accepted: Vec<&String> = lines
            .iter()
            .filter(|l| l.contains("\"CALIBRATION\"") && l.contains("\"sensor\":\"compass\""))
            .collect();
        assert!(
            accepted[0].contains("\"id\":2") && accepted[0].contains("\"model\":\"offset+scale\"")
        );

        // Back to two axes: a 2-axis sensor never corrects with a 3-D
        // calibration; it collects a rotation.
        let two = new.replace(
            "axes = [\"x\", \"y\", \"z\"]\ntilt = \"level\"\nmodel = \"offset+scale\"\n",
            "axes = [\"x\", \"y\"]\n",
        );
        apply(Ok(config(&two)), &mut running, &mut sensors, &SOURCES, None);
        assert!(sensors[0].1.three().is_none());
        assert!(sensors[0].1.calibration().is_none());
        assert!(sensors[0].1.status().rotation.is_some());
    }

    /// ArduPilot's limits in its units: an offset beyond COMPASS_OFFS_MAX
    /// (1800 mG) or a field outside 150-950 mG is refused, naming it.
    #[test]
    fn the_limits_are_ardupilots_in_milligauss() {
        let fit_of = |offset: [f64; 3], r: f64| {
            let sim = SimSensor3 {
                matrix: [[1.05, 0.02, 0.0], [0.02, 0.97, 0.0], [0.0, 0.0, 1.0]],
                offset,
                r,
                noise: 1.0,
                n: 1500,
                motion: Motion3::Tumble {
                    turns: 12.0,
                    axis_path_rad: 6.0,
                },
                seed: 5,
            };
            ellipsoid::fit(&sim.simulate().unwrap(), ellipsoid::Ellipsoid3Model::Full).unwrap()
        };
        // 2000 counts per gauss: 1000 counts = 500 mG.
        let good = fit_of([1000.0, -500.0, 200.0], 1000.0);
        assert_eq!(check_limits(&good, Field::Mag, Some(2000.0), None), Ok(()));
        let far = fit_of([3700.0, 0.0, 0.0], 1000.0);
        let e = check_limits(&far, Field::Mag, Some(2000.0), None).unwrap_err();
        assert!(
            e.contains("offset x 18") && e.contains("COMPASS_OFFS_MAX"),
            "{e}"
        );
        // Without units the offset is judged against the field: 3.7 r is fine.
        assert_eq!(check_limits(&far, Field::Mag, None, None), Ok(()));
        let strong = fit_of([0.0; 3], 2000.0);
        let e = check_limits(&strong, Field::Mag, Some(2000.0), None).unwrap_err();
        assert!(e.contains("FIELD_RADIUS"), "{e}");
        // The fitness: 1 count of noise on 1000 is 0.5 mG; a tighter max_rms
        // than the fit's rms refuses it.
        let e = check_limits(&good, Field::Mag, Some(2000.0), Some(good.rms / 2.0)).unwrap_err();
        assert!(e.contains("sphere.max_rms"), "{e}");
        // An accelerometer: gravity must read 0.8-1.2 g.
        let e = check_limits(&good, Field::Accel, Some(4096.0), None).unwrap_err();
        assert!(e.contains("gravity reads 0.24"), "{e}");
    }

    /// A sensor that never moves fills no more than max_samples, however
    /// long it collects.
    #[test]
    fn the_buffer_stays_bounded() {
        let text = "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
            [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\n\
            [sensor.sphere]\nmin_samples = 100\nmax_samples = 400\n";
        let c = config(text);
        let mut sensor = Sensor::new(c.sensors[0].clone(), None);
        let readings = tumble();
        for i in 0..20_000usize {
            // A still sensor, then the first 500 samples of the tumble.
            let r = if i < 19_500 {
                Reading {
                    time: i as f64 * 0.05,
                    mag: Some([500 + (i % 7) as i16, -300, 200]),
                    ..Reading::default()
                }
            } else {
                Reading {
                    time: i as f64 * 0.05,
                    ..readings[i - 19_500]
                }
            };
            sensor.on_reading(&r, &mut |_, _| {});
            let held = sensor.three().unwrap().points().len();
            assert!(held <= 400, "{held} at {i}");
        }
    }

    /// The real tumble of sunsided-set-1 (HMC5883L in gauss = counts/1090,
    /// MPU-6050 in g = counts/16384 at ±2 g, one clock), as the chips'
    /// counts on two streams of one bridge: the compass calibrates with
    /// the field within the Earth's 250-650 mG; the accelerometer, moved by
    /// hand, reads the hand's acceleration besides gravity and is refused
    /// for its rms (a still-pose calibration is what ArduPilot asks of an
    /// accelerometer), so the headings use its raw readings and say so.
    #[test]
    fn the_real_tilt_sphere_calibrates_the_compass_and_refuses_a_moving_accelerometer() {
        let dir = std::path::Path::new("../shared/data/real/sunsided-set-1/tilt-sphere");
        let read = |name: &str, scale: f64| -> Vec<(f64, [i16; 3])> {
            let text = std::fs::read_to_string(dir.join(name)).unwrap();
            text.lines()
                .skip(1)
                .map(|l| {
                    let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
                    (v[0], [1, 2, 3].map(|i| (v[i] * scale).round() as i16))
                })
                .collect()
        };
        let mut readings: Vec<Reading> = read("hmc5883l_mag.csv", 1090.0)
            .into_iter()
            .map(|(t, m)| Reading {
                time: t,
                stream: 0,
                mag: Some(m),
                ..Reading::default()
            })
            .chain(
                read("mpu6050.csv", 16384.0)
                    .into_iter()
                    .map(|(t, a)| Reading {
                        time: t,
                        stream: 1,
                        accel: Some(a),
                        ..Reading::default()
                    }),
            )
            .collect();
        readings.sort_by(|a, b| a.time.total_cmp(&b.time));
        let text = "[[source]]\nname = \"imu\"\nkind = \"usb-iss\"\nport = \"/dev/null\"\nchips = [\"lsm303dlhc-mag\", \"mpu6050\"]\n\
            [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\nlsb_per_gauss = 1090\ntilt = \"level\"\n\
            [[sensor]]\nname = \"level\"\nsource = \"imu\"\nchip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\nlsb_per_g = 16384\n";
        let c = config(text);
        let mut sensors: Vec<(usize, Sensor)> = c
            .sensors
            .iter()
            .map(|s| (0, Sensor::new(s.clone(), None)))
            .collect();
        let lines = feed(&mut sensors, &readings);
        for l in lines.iter().filter(|l| l.contains("\"CALIBRATION\"")) {
            println!("{l}");
        }
        let compass = sensors[0].1.calibration().expect("the compass calibrates");
        let gauss = compass.ellipsoid.unwrap().r / 1090.0;
        assert!((0.25..0.65).contains(&gauss), "field {gauss} G");
        assert!(sensors[1].1.calibration().is_none());
        let refusals: Vec<&String> = lines
            .iter()
            .filter(|l| l.contains("\"sensor\":\"level\"") && l.contains("\"accepted\":false"))
            .collect();
        assert!(!refusals.is_empty());
        assert!(
            refusals
                .iter()
                .all(|l| l.contains("% of the field exceeds")),
            "{refusals:?}"
        );
        let headings = lines
            .iter()
            .filter(|l| {
                l.contains("\"heading_deg\"") && l.contains("\"calibrated\":false,\"tilt_deg\"")
            })
            .count();
        println!(
            "compass rms {:.3} %, {headings} headings from the raw accelerometer",
            compass.rms * 100.0
        );
        assert!(headings > 100, "{headings}");
    }

    /// An accelerometer (4096 counts per g, 8 counts of noise) rested on
    /// its six faces for `hold_s` each, turned between them at 90 °/s, at
    /// 50 Hz.
    fn six_faces(hold_s: f64, seed: u64) -> (Vec<Reading>, [f64; 3], [[f64; 3]; 3]) {
        let w = [[1.03, 0.0, 0.0], [0.0, 0.97, 0.0], [0.0, 0.0, 1.01]];
        let offset = [60.0, -45.0, 90.0];
        let (samples, _) =
            crate::common::fixtures::six_faces(hold_s, 50.0, (w, offset, 4096.0, 8.0), seed);
        let readings = samples
            .into_iter()
            .map(|(time, p)| Reading {
                time,
                accel: Some(p.map(|v| v.round() as i16)),
                ..Reading::default()
            })
            .collect();
        (readings, offset, w)
    }

    const STILL: &str = "[[source]]\nname = \"imu\"\nkind = \"falcon\"\nport = \"/dev/null\"\n\
        [[sensor]]\nname = \"level\"\nsource = \"imu\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n\
        lsb_per_g = 4096\nmodel = \"offset+scale\"\n[sensor.sphere]\nstill = true\n";

    #[test]
    fn an_accelerometer_rested_on_its_six_faces_is_calibrated_from_the_poses() {
        for seed in 0..5 {
            let (readings, offset, w) = six_faces(2.0, seed);
            let c = config(STILL);
            let mut sensor = Sensor::new(c.sensors[0].clone(), None);
            let mut lines = Vec::new();
            let mut poses_seen = Vec::new();
            for r in &readings {
                sensor.on_reading(r, &mut |_, l| lines.push(l));
                if let Some(p) = sensor.status().sphere.and_then(|p| p.still) {
                    poses_seen.push(p.poses);
                }
            }
            let cals: Vec<&String> = lines
                .iter()
                .filter(|l| l.contains("\"CALIBRATION\""))
                .collect();
            assert_eq!(cals.len(), 1, "seed {seed}: {cals:?}");
            assert!(cals[0].contains("\"accepted\":true"), "{}", cals[0]);
            let cal = sensor.calibration().unwrap();
            let p = cal.ellipsoid.as_ref().unwrap();
            // 8 counts of noise over 6 poses of ~80 samples: the offsets
            // within a few counts, the gains within 0.2 %.
            for k in 0..3 {
                assert!(
                    (p.offset[k] - offset[k]).abs() < 4.0,
                    "seed {seed}: {:?}",
                    p.offset
                );
                // det W = 1: W·(raw − o) has magnitude r, 4096 counts per g.
                let gain = p.matrix[k][k] * 4096.0 / p.r;
                assert!(
                    (gain - w[k][k]).abs() < 2e-3,
                    "seed {seed}: {:?} r {}",
                    p.matrix,
                    p.r
                );
            }
            assert!((p.r / 4096.0 - 1.0).abs() < 0.01, "r {}", p.r);
            // STATUS counted the poses up to 5; the sixth, once it spans
            // a window, completes the model's six unknowns and is fitted.
            assert_eq!(poses_seen.iter().max(), Some(&5));
            assert!(poses_seen.windows(2).all(|w| w[0] <= w[1]));
            assert!(cals[0].contains("\"n\":"), "{}", cals[0]);
        }
    }

    #[test]
    fn a_still_pose_accelerometer_that_never_rests_is_not_calibrated_and_says_so() {
        let c = config(&STILL.replace("model = \"offset+scale\"\n", ""));
        let mut sensor = Sensor::new(c.sensors[0].clone(), None);
        let mut lines = Vec::new();
        for r in tumble() {
            sensor.on_reading(&r, &mut |_, l| lines.push(l));
        }
        assert!(!lines.iter().any(|l| l.contains("\"CALIBRATION\"")));
        let still = sensor.status().sphere.and_then(|p| p.still).unwrap();
        assert_eq!(still.poses, 0);
        assert!(still.state.never_still, "{still:?}");
        let status = serde_json::to_value(sensor.status().sphere.unwrap()).unwrap();
        assert_eq!(status["still"]["never_still"], true, "{status}");
        assert_eq!(status["still"]["poses_needed"], 9, "{status}");
    }

    #[test]
    fn still_poses_are_refused_for_a_magnetometer() {
        let text = STILL
            .replace("field = \"accel\"", "field = \"mag\"")
            .replace("lsb_per_g", "lsb_per_gauss");
        let e = parse(&text, std::path::Path::new("t.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("sphere.still") && e.contains("accelerometer"),
            "{e}"
        );
    }
}

mod state_writer {
    use fieldcal::daemon::Calibration;
    use fieldcal::daemon::state_writer::{SaveFailure, StateWriter};
    use fieldcal::model::paper::PaperCalibration;
    use std::sync::mpsc;
    use std::sync::{Arc, Mutex};
    use std::time::Duration;
    use std::time::Instant;
    use tokio::sync::mpsc as tokio_mpsc;

    fn calibration(sensor: &str, id: u64) -> Calibration {
        Calibration {
            sensor: sensor.to_string(),
            id,
            model: "offset+scale".to_string(),
            params: PaperCalibration {
                a: 1.0,
                b: 0.0,
                d: 0.0,
                r: 1.0,
            },
            rms: 0.01,
            coverage_deg: 360.0,
            n: 100,
            time: 1.0,
            terms: Default::default(),
            ellipsoid: None,
            se: Default::default(),
            parent: None,
            history: Vec::new(),
            gyro: None,
            dip: None,
            across: None,
            level: None,
        }
    }

    /// A calibration returned to by `rollback` is a kept one, as one loaded
    /// at start: the progress board logs no rotation for it.
    #[test]
    fn a_rolled_back_calibration_is_a_stored_one_for_the_progress_board() {
        use fieldcal::daemon::messages::CalibrationMessage;
        let c = calibration("compass", 3);
        let stored = |origin: &'static str| {
            CalibrationMessage {
                origin,
                ..CalibrationMessage::loaded(&c)
            }
            .event()
            .unwrap()
            .stored
        };
        assert!(stored("state"));
        assert!(stored("rollback"));
        for fitted in ["rotation", "refined", "replaced"] {
            assert!(!stored(fitted), "{fitted}");
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_held_write_does_not_hold_the_caller_and_order_is_kept() {
        let written = Arc::new(Mutex::new(Vec::new()));
        // Each write waits for a token: a disk that answers only when the
        // test says so (or after 10 s, if the test is wrong).
        let (release, gate) = mpsc::channel::<()>();
        let (failures_tx, mut failures) = tokio_mpsc::unbounded_channel();
        let writer = StateWriter::spawn(
            {
                let written = written.clone();
                move |c: &Calibration| {
                    let _ = gate.recv_timeout(Duration::from_secs(10));
                    written.lock().unwrap().push((c.sensor.clone(), c.id));
                    Ok(())
                }
            },
            failures_tx,
        )
        .unwrap();
        for id in 1..=3 {
            writer.save(&calibration("compass", id));
        }
        writer.save(&calibration("level", 1));
        // Had save() waited for its write, the first would be on disk.
        assert!(written.lock().unwrap().is_empty());
        for _ in 0..4 {
            release.send(()).unwrap();
        }
        assert!(writer.finish(Duration::from_secs(10)).await);
        assert_eq!(
            *written.lock().unwrap(),
            [
                ("compass".to_string(), 1),
                ("compass".to_string(), 2),
                ("compass".to_string(), 3),
                ("level".to_string(), 1)
            ]
        );
        assert!(failures.try_recv().is_err(), "no failure expected");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn failures_come_back_with_the_sensor_and_message() {
        let (failures_tx, mut failures) = tokio_mpsc::unbounded_channel();
        let writer = StateWriter::spawn(
            |c: &Calibration| {
                if c.id == 2 {
                    Err(format!("cannot write /state/{}.json: disk full", c.sensor))
                } else {
                    Ok(())
                }
            },
            failures_tx,
        )
        .unwrap();
        for id in 1..=3 {
            writer.save(&calibration("compass", id));
        }
        assert!(writer.finish(Duration::from_secs(10)).await);
        assert_eq!(
            failures.recv().await,
            Some(SaveFailure {
                sensor: "compass".to_string(),
                message: "cannot write /state/compass.json: disk full".to_string(),
            })
        );
        assert_eq!(failures.recv().await, None, "one failure only");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_hung_write_is_reported_at_the_limit() {
        let (failures_tx, _failures) = tokio_mpsc::unbounded_channel();
        let writer = StateWriter::spawn(
            |_: &Calibration| {
                std::thread::sleep(Duration::from_millis(1500));
                Ok(())
            },
            failures_tx,
        )
        .unwrap();
        writer.save(&calibration("compass", 1));
        let started = Instant::now();
        assert!(!writer.finish(Duration::from_millis(200)).await);
        assert!(started.elapsed() < Duration::from_millis(1200));
    }
}

mod reload {
    use std::path::Path;
    use std::time::Duration;

    use fieldcal::daemon::config::{self, *};
    use fieldcal::daemon::messages::SensorState;
    use fieldcal::daemon::reload::*;
    use fieldcal::daemon::sensor::Sensor;
    use fieldcal::sample::Reading;

    const BASE: &str = r#"
[daemon]
state_dir = "/tmp/fieldcal-reload-unit"
status_interval_s = 1.0

[outputs]
stdout = true
tcp = "127.0.0.1:2947"

[[source]]
name = "imu"
kind = "falcon"
port = "/dev/null"

[[sensor]]
name = "compass"
source = "imu"
field = "mag"
axes = ["x", "y"]

[[sensor]]
name = "tilt"
source = "imu"
field = "accel"
axes = ["x", "y"]
"#;

    fn parse(text: &str) -> Config {
        config::parse(text, Path::new("/etc/fieldcal/fieldcal.toml")).unwrap()
    }

    #[test]
    fn the_same_file_plans_nothing() {
        let p = plan(&parse(BASE), &parse(BASE));
        assert!(p.is_empty(), "{p:?}");
        assert_eq!(
            p.sensors,
            [
                SensorPlan::Unchanged("compass".into()),
                SensorPlan::Unchanged("tilt".into())
            ]
        );
    }

    #[test]
    fn a_sensor_section_change_names_its_keys() {
        let new = BASE.replacen(
            "axes = [\"x\", \"y\"]\n",
            "axes = [\"x\", \"y\"]\nmodel = [\"paper\", \"cross-axis\"]\n[sensor.limits]\nmax_rms = 0.04\n",
            1,
        );
        let p = plan(&parse(BASE), &parse(&new));
        assert_eq!(
            p.sensors,
            [
                SensorPlan::Changed {
                    name: "compass".into(),
                    keys: vec!["model", "limits"]
                },
                SensorPlan::Unchanged("tilt".into())
            ]
        );
        assert!(p.restart.is_empty() && p.status_interval.is_none());
    }

    #[test]
    fn outputs_sources_and_state_dir_need_a_restart_and_say_what_is_kept() {
        let new = BASE
            .replace("127.0.0.1:2947", "127.0.0.1:2950")
            .replace("/tmp/fieldcal-reload-unit", "/tmp/elsewhere")
            .replace("status_interval_s = 1.0", "status_interval_s = 0.5")
            .replace(
                "port = \"/dev/null\"",
                "port = \"/dev/null\"\nbaud = 115200",
            );
        let p = plan(&parse(BASE), &parse(&new));
        assert_eq!(p.status_interval, Some(Duration::from_millis(500)));
        assert_eq!(
            p.restart,
            [
                "[daemon] state_dir changed to /tmp/elsewhere: restart fieldcal to apply; kept /tmp/fieldcal-reload-unit",
                "[outputs] tcp changed to 127.0.0.1:2950: restart fieldcal to apply; kept 127.0.0.1:2947",
                "[[source]] imu changed (baud): restart fieldcal to apply; it keeps running as it started",
            ]
        );
        // Sensors whose sections did not change are unchanged, though
        // their source changed: they keep running on it.
        assert!(
            p.sensors
                .iter()
                .all(|s| matches!(s, SensorPlan::Unchanged(_)))
        );
    }

    #[test]
    fn sensors_added_removed_and_held_for_a_new_source() {
        let new = BASE.replace("name = \"tilt\"", "name = \"level\"")
            + "\n[[source]]\nname = \"bench\"\nkind = \"falcon\"\nport = \"/dev/zero\"\n\n\
               [[sensor]]\nname = \"bench-compass\"\nsource = \"bench\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";
        let p = plan(&parse(BASE), &parse(&new));
        assert_eq!(
            p.sensors,
            [
                SensorPlan::Unchanged("compass".into()),
                SensorPlan::Added("level".into()),
                SensorPlan::Held {
                    name: "bench-compass".into(),
                    source: "bench".into(),
                    added: true
                },
                SensorPlan::Removed("tilt".into()),
            ]
        );
        assert_eq!(
            p.restart,
            ["[[source]] bench added: restart fieldcal to start it"]
        );
    }

    #[test]
    fn a_changed_declination_applies_live_keeping_the_rotation_and_calibration() {
        let (mut config, mut sensors) = running(BASE);
        turn(&mut sensors[0].1, 0, 201);
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        sensors[0].1.recalibrate();
        turn(&mut sensors[0].1, 201, 100);
        let new = BASE.replacen(
            "field = \"mag\"\naxes = [\"x\", \"y\"]",
            "field = \"mag\"\naxes = [\"x\", \"y\"]\ndeclination_deg = 10.0",
            1,
        );
        assert_eq!(
            plan(&parse(BASE), &parse(&new)).sensors[0],
            SensorPlan::North("compass".into())
        );
        let out = apply(Ok(parse(&new)), &mut config, &mut sensors, &SOURCES, None);
        assert!(
            out.lines[0].contains(
                "sensor 'compass': no declination -> declination +10.00° (config): applied; its \
                 calibration and rotation are kept"
            ),
            "{:?}",
            out.lines
        );
        let status = sensors[0].1.status();
        assert_eq!(status.rotation.unwrap().samples, 100);
        assert_eq!(status.calibration, Some(1));
        let lines = turn(&mut sensors[0].1, 301, 1);
        let v: serde_json::Value = serde_json::from_str(&lines[0]).unwrap();
        let (h, t) = (
            v["heading_deg"].as_f64().unwrap(),
            v["true_heading_deg"].as_f64().unwrap(),
        );
        assert!(((h + 10.0) % 360.0 - t).abs() < 1e-9, "{v}");
        // A declination change beside another change: a new rotation.
        let new2 = new.replace(
            "declination_deg = 10.0",
            "declination_deg = 5.0\nmodel = [\"paper\", \"cross-axis\"]",
        );
        let p = plan(&parse(&new), &parse(&new2));
        assert!(
            matches!(&p.sensors[0], SensorPlan::Changed { keys, .. } if keys.contains(&"declination or location")),
            "{p:?}"
        );
    }

    /// Readings of a compass turning at 36°/s around (300, -200), radius
    /// 1000, every 50 ms from `from` for `n` readings.
    fn turn(sensor: &mut Sensor, from: usize, n: usize) -> Vec<String> {
        let mut lines = Vec::new();
        for i in from..from + n {
            let t = i as f64 * 0.05;
            let h = (36.0 * t).to_radians();
            let r = Reading {
                time: t,
                mag: Some([
                    (300.0 + 1000.0 * h.cos()).round() as i16,
                    (-200.0 + 1000.0 * h.sin()).round() as i16,
                    0,
                ]),
                accel: Some([0, 0, 4096]),
                ..Reading::default()
            };
            sensor.on_reading(&r, &mut |_, line| lines.push(line));
        }
        lines
    }

    fn running(text: &str) -> (Config, Vec<(usize, Sensor)>) {
        let config = parse(text);
        let sensors = config
            .sensors
            .iter()
            .map(|s| (0, Sensor::new(s.clone(), None)))
            .collect();
        (config, sensors)
    }

    const SOURCES: [RunningSource<'static>; 1] = [RunningSource {
        name: "imu",
        csv: None,
    }];

    #[test]
    fn unchanged_sensors_keep_their_rotation_and_calibration_a_changed_one_starts_anew() {
        let (mut config, mut sensors) = running(BASE);
        // compass: calibrated (#1), then asked to recalibrate and halfway
        // through its next turn; tilt: collecting, never calibrated.
        let lines = turn(&mut sensors[0].1, 0, 201);
        assert!(lines.iter().any(|l| l.contains("\"accepted\":true")));
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        sensors[0].1.recalibrate();
        turn(&mut sensors[0].1, 201, 100);
        let held = sensors[0].1.status().rotation.unwrap().samples;
        assert_eq!(held, 100);

        // The same file: nothing moves.
        let out = apply(Ok(parse(BASE)), &mut config, &mut sensors, &SOURCES, None);
        assert_eq!(out.lines.len(), 1, "{:?}", out.lines);
        assert!(out.lines[0].contains("no change"), "{:?}", out.lines);
        let status = sensors[0].1.status();
        assert_eq!(status.rotation.unwrap().samples, 100);
        assert_eq!(status.calibration, Some(1));
        assert_eq!(status.state, SensorState::Recalibrating);

        // tilt's model changes: compass keeps its half turn, tilt starts
        // afresh under the new model.
        let new = BASE.replace(
            "field = \"accel\"\naxes = [\"x\", \"y\"]",
            "field = \"accel\"\naxes = [\"x\", \"y\"]\nmodel = [\"paper\", \"cubic\"]",
        );
        let out = apply(Ok(parse(&new)), &mut config, &mut sensors, &SOURCES, None);
        assert_eq!(out.lines.len(), 2, "{:?}", out.lines);
        assert!(
            out.lines[0].contains("sensor 'tilt': model offset+scale -> offset+scale+cubic"),
            "{:?}",
            out.lines
        );
        assert_eq!(sensors[0].1.status().rotation.unwrap().samples, 100);
        assert_eq!(sensors[0].1.calibration().map(|c| c.id), Some(1));
        assert_eq!(config.sensors[1].effects(), ["offset", "scale", "cubic"]);

        // compass's model changes mid-turn: a new rotation under the new
        // model, and calibration #1 (the paper's) corrects meanwhile.
        let new2 = new.replacen(
            "field = \"mag\"\naxes = [\"x\", \"y\"]",
            "field = \"mag\"\naxes = [\"x\", \"y\"]\nmodel = [\"paper\", \"cross-axis\"]",
            1,
        );
        let out = apply(Ok(parse(&new2)), &mut config, &mut sensors, &SOURCES, None);
        assert!(
            out.lines[0].contains("calibration #1 (offset+scale) keeps correcting"),
            "{:?}",
            out.lines
        );
        let status = sensors[0].1.status();
        assert_eq!(status.rotation.unwrap().samples, 0);
        assert_eq!(status.calibration, Some(1));
        assert_eq!(status.state, SensorState::Recalibrating);
        assert_eq!(status.readings, 301);
        let lines = turn(&mut sensors[0].1, 400, 201);
        assert!(
            lines[0].contains("\"calibration\":1"),
            "corrected by #1 meanwhile: {}",
            lines[0]
        );
        let accepted: Vec<&String> = lines
            .iter()
            .filter(|l| l.contains("\"accepted\":true"))
            .collect();
        assert_eq!(accepted.len(), 1, "{lines:?}");
        assert!(
            accepted[0].contains("\"id\":2") && accepted[0].contains("offset+scale+cross-axis"),
            "{}",
            accepted[0]
        );
    }

    #[test]
    fn a_refused_file_changes_nothing() {
        let (mut config, mut sensors) = running(BASE);
        turn(&mut sensors[0].1, 0, 50);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fieldcal.toml");
        std::fs::write(
            &path,
            BASE.replace(
                "axes = [\"x\", \"y\"]\n\n[[sensor]]",
                "axes = [\"x\", \"y\"]\nmodle = \"paper\"\n\n[[sensor]]",
            ),
        )
        .unwrap();
        let out = apply(check(&path), &mut config, &mut sensors, &SOURCES, None);
        assert_eq!(out.lines.len(), 1);
        let line: serde_json::Value = serde_json::from_str(&out.lines[0]).unwrap();
        assert_eq!(line["class"], "ERROR");
        assert_eq!(line["key"], "sensor[0].modle");
        assert_eq!(line["line"], 20);
        let message = line["message"].as_str().unwrap();
        assert!(
            message.starts_with("reload of /etc/fieldcal/fieldcal.toml refused: "),
            "{message}"
        );
        assert!(
            message.ends_with("; the running configuration is kept"),
            "{message}"
        );
        assert_eq!(sensors.len(), 2);
        assert_eq!(sensors[0].1.status().rotation.unwrap().samples, 50);
        assert_eq!(config.sensors.len(), 2);
    }
}
