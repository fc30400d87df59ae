//! The model's unit tests that need only the public API (`fieldcal::model::...`),
//! moved out of src/model: one module a source file, the tests unchanged.

mod common;

mod calibration {
    use fieldcal::model::calibration::{Calibration, Terms};

    /// A state file written before the centred cubic (terms c, k and
    /// cubic_scale only) loads with no centred term and corrects as before;
    /// one with the centred term corrects with it, and a calibration
    /// without it writes none of its fields.
    #[test]
    fn terms_without_the_centred_cubic_still_load() {
        let old = r#"{"sensor":"s","id":3,"model":"offset+scale+cubic","params":{"a":1.0,"b":-10.0,"d":5.0,"r":100.0},
            "rms":0.01,"coverage_deg":360.0,"n":200,"time":1.0,"terms":{"c":0.0,"k":[0.02,0.01],"cubic_scale":200.0}}"#;
        let cal: Calibration = serde_json::from_str(old).unwrap();
        assert_eq!(cal.terms.kc, [0.0; 2]);
        assert_eq!(cal.terms.turn_radius, [0.0; 2]);
        let (x, y) = (150.0, -40.0);
        let x2 = x + 0.02 * x * x * x / 200.0f64.powi(2);
        let y2 = y + 0.01 * y * y * y / 200.0f64.powi(2);
        assert_eq!(cal.apply(x, y), (x2 - 10.0, y2 + 5.0));
        let json = serde_json::to_string(&cal).unwrap();
        assert!(!json.contains("kc") && !json.contains("centre"), "{json}");

        let centred = Calibration {
            model: "offset+scale+cubic-centred".into(),
            terms: Terms {
                kc: [0.04, -0.03],
                centre: [10.0, -5.0],
                turn_radius: [90.0, 100.0],
                ..Terms::default()
            },
            ..cal
        };
        let back: Calibration =
            serde_json::from_str(&serde_json::to_string(&centred).unwrap()).unwrap();
        assert_eq!(back, centred);
        let (vx, vy) = (x - 10.0, y + 5.0);
        let want = (
            x + 0.04 * vx * vx * vx / 8100.0 - 10.0,
            y - 0.03 * vy * vy * vy / 10_000.0 + 5.0,
        );
        let got = centred.apply(x, y);
        assert!((got.0 - want.0).abs() < 1e-12 && (got.1 - want.1).abs() < 1e-12);
    }
}

mod check {
    use fieldcal::model::check::{
        CheckError, ParamShift, StoredCalibration, StoredSource, check, moved_text,
        moved_threshold, normal_quantile, parse_stored,
    };
    use fieldcal::model::fit::{FitOptions, fit_paper};
    use fieldcal::model::paper::closed_form_se;
    use fieldcal::sample::Dataset;
    use fieldcal::sim::SimSensor;

    #[test]
    fn a_move_too_large_to_count_in_standard_errors_is_said_in_words() {
        let moved = ParamShift::compare("r".into(), (1e308, 1e-12), (1.0, 1e-12), true, 3.29);
        assert!(moved.moved && moved.z.is_infinite());
        let text = moved_text(&[moved], |_| "the field changed".into());
        assert!(
            text.starts_with("r moved far beyond its standard errors (1"),
            "{text}"
        );
        assert!(!text.contains("inf"), "{text}");
        let moved = ParamShift::compare("b".into(), (1.0, 0.1), (2.0, 0.0), true, 3.29);
        let text = moved_text(&[moved], |_| String::new());
        assert!(text.starts_with("b moved by 10.0 SE"), "{text}");
    }

    #[test]
    fn normal_quantile_matches_tables() {
        assert!((normal_quantile(0.975) - 1.959964).abs() < 1e-6);
        assert!((normal_quantile(0.5)).abs() < 1e-12);
        assert!((normal_quantile(0.001) + 3.090232).abs() < 1e-6);
        assert!(normal_quantile(0.0).is_nan());
        // Four parameters at 1 % family-wise.
        assert!((moved_threshold(4) - 3.023).abs() < 1e-3);
    }

    fn sensor(seed: u64, offset_x: f64) -> SimSensor {
        SimSensor {
            gain_x: 1.08,
            offset_x,
            offset_y: -60.0,
            noise: 10.0,
            turns: 2.0,
            turn_seconds: 20.0,
            seed,
            ..SimSensor::default()
        }
    }

    fn stored_from(data: &Dataset) -> StoredCalibration {
        let report = fit_paper(&data.x, &data.y, &FitOptions::default(), &mut |_| {}).unwrap();
        let se = closed_form_se(&data.x, &data.y, &report.theta);
        StoredCalibration {
            source: StoredSource::FitPaper,
            effects: fieldcal::model::effects::PAPER.to_vec(),
            params: fieldcal::model::calibration::paper_parameters(
                &report.calibration,
                se.as_ref(),
            ),
            cubic_scale: None,
            turn_frame: None,
            rms: Some(report.rms),
        }
    }

    #[test]
    fn the_same_sensor_holds_and_a_shifted_offset_is_named() {
        let stored = stored_from(&sensor(1, 150.0).simulate().unwrap());
        let same = check(&sensor(2, 150.0).simulate().unwrap(), &stored, None, 300.0).unwrap();
        assert!(same.holds, "{}", same.verdict);
        assert!(same.verdict.starts_with("holds"), "{}", same.verdict);
        let moved = check(&sensor(2, 180.0).simulate().unwrap(), &stored, None, 300.0).unwrap();
        assert!(!moved.holds);
        let names: Vec<&str> = moved
            .parameters
            .iter()
            .filter(|p| p.moved)
            .map(|p| p.name.as_str())
            .collect();
        assert_eq!(names, ["b"], "{}", moved.verdict);
        assert!(moved.verdict.starts_with("b moved by"), "{}", moved.verdict);
    }

    #[test]
    fn garbage_is_not_a_calibration() {
        for bytes in [
            &b"hello"[..],
            b"[1,2]",
            b"{\"solver\":\"x\",\"params\":{}}",
            b"{}",
        ] {
            let err = parse_stored(bytes).unwrap_err();
            assert!(matches!(err, CheckError::UnknownFormat { .. }), "{err}");
            assert!(err.to_string().contains("fit --json"), "{err}");
        }
        let err =
            parse_stored(br#"{"solver":"lsq","params":{"a":-1,"b":0,"d":0,"r":1}}"#).unwrap_err();
        assert!(matches!(err, CheckError::Invalid { .. }), "{err}");
    }
}

mod diagnose3 {
    use crate::common::fixtures::tumbling;
    use fieldcal::model::diagnose3::diagnose3;
    use fieldcal::model::effects::Effect;
    use fieldcal::sample::Covariate;
    use fieldcal::sample::Dataset3;

    /// A tumble with gains only (the baseline is the right model), 1 %
    /// noise, times at 50 Hz and a temperature that wanders independently.
    fn clean(seed: u64, timed: bool) -> Dataset3 {
        let n = 800;
        let points = tumbling(
            [[1.1, 0.0, 0.0], [0.0, 0.92, 0.0], [0.0, 0.0, 1.0]],
            [0.3, -0.2, 0.1],
            0.5,
            0.005,
            n,
            seed,
        )
        .simulate()
        .unwrap();
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.02).collect();
        let temp = t.iter().map(|s| 20.0 + 3.0 * (s * 0.37).sin()).collect();
        Dataset3 {
            x_name: "x".into(),
            y_name: "y".into(),
            z_name: "z".into(),
            t: timed.then_some(t),
            points,
            covariates: vec![Covariate {
                name: "temp".into(),
                values: temp,
            }],
        }
    }

    #[test]
    fn clean_tumbles_suggest_nothing() {
        let mut fired = Vec::new();
        for seed in 1..=20 {
            let d = diagnose3(&clean(seed, true), &[]).unwrap();
            assert!(d.noise_floor.rms > 0.0);
            if let Some(e) = &d.suggested {
                fired.push((seed, e.to_string()));
            } else {
                assert!(
                    d.verdict.starts_with("what remains is noise"),
                    "{}",
                    d.verdict
                );
            }
        }
        assert!(fired.len() <= 1, "clean tumbles got suggestions: {fired:?}");
    }

    #[test]
    fn drift_without_times_is_not_determined() {
        let d = diagnose3(&clean(3, false), &[]).unwrap();
        let drift = d
            .not_determined
            .iter()
            .find(|n| n.effect == Effect::Drift)
            .expect("drift is not determined without times");
        assert!(drift.reason.contains("no time column"), "{}", drift.reason);
        assert!(d.candidates.iter().all(|c| c.effect != Effect::Drift));
        assert!(
            d.candidates
                .iter()
                .any(|c| c.effect == Effect::Covariate("temp".into()))
        );
    }

    #[test]
    fn six_static_poses_do_not_offer_cross_axis() {
        // Six static poses (each axis up, then down) support offset+scale,
        // not the full W (ellipsoid.rs's rule).
        let mut data = clean(4, true);
        let n = data.points.len();
        for (i, p) in data.points.iter_mut().enumerate() {
            let pose = i * 6 / n;
            let axis = pose / 2;
            let sign = if pose.is_multiple_of(2) { 1.0 } else { -1.0 };
            let mut v = [0.0; 3];
            v[axis] = sign * 0.5;
            let gains = [1.1, 0.92, 1.0];
            let offset = [0.3, -0.2, 0.1];
            for j in 0..3 {
                // Scatter within a pose: 1 % of the tumble's excursion.
                let noise = (p[j] - offset[j]) * 1e-2;
                p[j] = offset[j] + v[j] / gains[j] + noise;
            }
        }
        let d = diagnose3(&data, &[]).unwrap();
        let cross = d
            .not_determined
            .iter()
            .find(|n| n.effect == Effect::CrossAxis)
            .unwrap_or_else(|| panic!("{:?}", d.not_determined));
        assert!(
            cross.reason.contains("too little to determine"),
            "{}",
            cross.reason
        );
        assert!(d.candidates.iter().all(|c| c.effect != Effect::CrossAxis));
    }
}

mod effects {
    use fieldcal::model::effects::{
        CATALOGUE, Effect, MAX_CROSS_AXIS_SHEAR, MAX_CUBIC, limit_of, live, model_name, parse_list,
    };

    #[test]
    fn names_round_trip() {
        for name in [
            "offset",
            "scale",
            "cross-axis",
            "drift",
            "covariate:temp_c",
            "cubic",
            "cubic-centred",
            "outliers",
        ] {
            assert_eq!(name.parse::<Effect>().unwrap().to_string(), name);
        }
        assert!("magic".parse::<Effect>().unwrap_err().contains("catalogue"));
        assert!("covariate:".parse::<Effect>().is_err());
    }

    #[test]
    fn the_catalogue_is_in_the_order_of_the_effects() {
        for (i, info) in CATALOGUE.iter().enumerate() {
            assert!(
                std::ptr::eq(info.effect.info(), &CATALOGUE[i]),
                "{}",
                info.name
            );
        }
        assert_eq!(
            live(),
            [
                Effect::Offset,
                Effect::Scale,
                Effect::CrossAxis,
                Effect::Cubic,
                Effect::CubicCentred,
                Effect::Outliers,
            ]
        );
        assert!(!Effect::CubicCentred.is_in_3d());
        assert_eq!(limit_of("kc").map(|l| l.max_abs), Some(MAX_CUBIC));
        assert_eq!(limit_of("c").map(|l| l.max_abs), Some(MAX_CROSS_AXIS_SHEAR));
    }

    #[test]
    fn lists_always_hold_the_papers_model() {
        let effects = parse_list("drift, cross-axis").unwrap();
        assert_eq!(model_name(&effects), "offset+scale+cross-axis+drift");
        assert_eq!(model_name(&parse_list("paper").unwrap()), "offset+scale");
        assert_eq!(model_name(&parse_list("").unwrap()), "offset+scale");
    }
}

mod ellipsoid {
    #![allow(clippy::needless_range_loop)] // indices pair fit, truth and se
    use fieldcal::model::ellipsoid::{
        Ellipsoid3Error, Ellipsoid3Model, MAX_ITERATIONS, closed_form, fit,
    };
    use fieldcal::sim3::{Motion3, SimSensor3};
    use nalgebra::{Matrix3, Vector3};

    const SOFT_IRON: [[f64; 3]; 3] = [[1.2, 0.15, -0.1], [0.15, 0.85, 0.2], [-0.1, 0.2, 1.05]];

    fn tumble(matrix: [[f64; 3]; 3], noise: f64, n: usize, seed: u64) -> SimSensor3 {
        SimSensor3 {
            matrix,
            offset: [0.3, -0.2, 0.45],
            r: 0.5,
            noise,
            n,
            motion: Motion3::Tumble {
                turns: 20.0,
                axis_path_rad: 10.0,
            },
            seed,
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn noiseless_full_recovers_a_strong_soft_iron() {
        let sim = tumble(SOFT_IRON, 0.0, 600, 7);
        let raw = sim.simulate().unwrap();
        let (o, w, r) = sim.truth();
        for model in [Ellipsoid3Model::Full] {
            let fit = fit(&raw, model).unwrap();
            for i in 0..3 {
                assert!(close(fit.offset[i], o[i], 1e-9), "{fit:?}");
                for j in 0..3 {
                    assert!(close(fit.matrix[i][j], w[i][j], 1e-9), "{fit:?}");
                }
            }
            assert!(close(fit.r, r, 1e-9));
            assert!(fit.rms < 1e-10);
        }
    }

    #[test]
    fn raw_counts_fit_as_gauss_do() {
        // The same readings ×10⁴ + 3·10⁴: the same W, offsets and r scaled.
        let sim = tumble(SOFT_IRON, 0.003, 800, 11);
        let gauss = sim.simulate().unwrap();
        let counts: Vec<[f64; 3]> = gauss.iter().map(|p| p.map(|v| v * 1e4 + 3e4)).collect();
        for model in Ellipsoid3Model::ALL {
            // The closed form alone, before any refinement.
            let (oa, aa) = closed_form(&gauss, model).unwrap();
            let (ob, ab) = closed_form(&counts, model).unwrap();
            for i in 0..3 {
                assert!(
                    close(ob[i], oa[i] * 1e4 + 3e4, 1e-7 * 1e4),
                    "{model}: {ob:?} {oa:?}"
                );
                for j in 0..3 {
                    assert!(close(ab[i][j] * 1e4, aa[i][j], 1e-7 * aa[0][0]), "{model}");
                }
            }
            let a = fit(&gauss, model).unwrap();
            let b = fit(&counts, model).unwrap();
            for i in 0..3 {
                assert!(
                    close(b.offset[i], a.offset[i] * 1e4 + 3e4, 1e-6 * 1e4),
                    "{model}"
                );
                assert!(close(
                    b.se.offset[i],
                    a.se.offset[i] * 1e4,
                    1e-6 * 1e4 * a.se.offset[i].max(1e-6)
                ));
                for j in 0..3 {
                    assert!(close(b.matrix[i][j], a.matrix[i][j], 1e-8), "{model}");
                }
            }
            assert!(close(b.r, a.r * 1e4, 1e-8 * 1e4), "{model}");
            assert!(close(b.rms, a.rms, 1e-10), "{model}");
            assert_eq!(a.coverage.covered, b.coverage.covered);
        }
    }

    /// Over 1000 seeds, the share of fits in which each parameter lies
    /// within 3 reported standard errors of the truth.
    fn within_three_se(model: Ellipsoid3Model, matrix: [[f64; 3]; 3]) -> Vec<(String, f64)> {
        let seeds = 1000;
        let mut hits = vec![0usize; 13];
        let mut names = vec![String::new(); 13];
        for seed in 0..seeds {
            let sim = tumble(matrix, 0.005, 600, 1000 + seed);
            let raw = sim.simulate().unwrap();
            let (o, w, r) = sim.truth();
            let fit = fit(&raw, model).unwrap();
            let mut k = 0;
            let mut check = |name: String, value: f64, truth: f64, se: f64| {
                // A parameter the model fixes (se 0) must equal the truth.
                if (value - truth).abs() <= 3.0 * se || (se == 0.0 && (value - truth).abs() < 1e-12)
                {
                    hits[k] += 1;
                }
                names[k] = name;
                k += 1;
            };
            for i in 0..3 {
                check(format!("o{i}"), fit.offset[i], o[i], fit.se.offset[i]);
            }
            for i in 0..3 {
                for j in 0..3 {
                    check(
                        format!("W{i}{j}"),
                        fit.matrix[i][j],
                        w[i][j],
                        fit.se.matrix[i][j],
                    );
                }
            }
            check("r".into(), fit.r, r, fit.se.r);
        }
        names
            .into_iter()
            .zip(hits)
            .map(|(n, h)| (n, h as f64 / seeds as f64))
            .collect()
    }

    fn assert_within(model: Ellipsoid3Model, matrix: [[f64; 3]; 3]) {
        let fractions = within_three_se(model, matrix);
        println!("{model}: {fractions:?}");
        for (name, f) in &fractions {
            assert!(
                *f >= 0.99,
                "{model}: {name} within 3 SE in only {f}: {fractions:?}"
            );
        }
    }

    #[test]
    fn offset_parameters_lie_within_three_standard_errors() {
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert_within(Ellipsoid3Model::Offset, identity);
    }

    #[test]
    fn offset_scale_parameters_lie_within_three_standard_errors() {
        let diagonal = [[1.2, 0.0, 0.0], [0.0, 0.8, 0.0], [0.0, 0.0, 1.05]];
        assert_within(Ellipsoid3Model::OffsetScale, diagonal);
    }

    #[test]
    fn full_parameters_lie_within_three_standard_errors() {
        assert_within(Ellipsoid3Model::Full, SOFT_IRON);
    }

    fn cap(half_angle_deg: f64, seed: u64) -> Vec<[f64; 3]> {
        SimSensor3 {
            motion: Motion3::Cap { half_angle_deg },
            ..tumble(SOFT_IRON, 0.005, 600, seed)
        }
        .simulate()
        .unwrap()
    }

    #[test]
    fn a_cap_still_gives_an_ellipsoid_in_closed_form() {
        // Li & Griffiths' constraint: a 40° cap of noisy points (noise 4 %
        // of the field) fits an ellipsoid, where an unconstrained quadric
        // fit is most often a hyperboloid or an open surface.
        for seed in 0..20 {
            let raw = SimSensor3 {
                motion: Motion3::Cap {
                    half_angle_deg: 40.0,
                },
                ..tumble(SOFT_IRON, 0.02, 600, seed)
            }
            .simulate()
            .unwrap();
            let (_, a) = closed_form(&raw, Ellipsoid3Model::Full).unwrap();
            let m = Matrix3::from_fn(|i, j| a[i][j]);
            assert!(m.cholesky().is_some(), "seed {seed}: {a:?}");
        }
    }

    #[test]
    fn a_cap_is_refused_and_names_what_is_missing() {
        let raw = cap(40.0, 1);
        for model in Ellipsoid3Model::ALL {
            let err = fit(&raw, model).unwrap_err();
            let Ellipsoid3Error::NotCovered {
                missing,
                percent,
                supported,
                ..
            } = &err
            else {
                panic!("{model}: {err}");
            };
            // 11.7 % of the sphere's area; regions count when a point touches them.
            assert!(*percent < 35.0, "{err}");
            // A cap is no turn: no advice to fit two axes.
            assert!(!err.to_string().contains("two axes"), "{err}");
            assert_eq!(*supported, None, "{err}");
            // Less than a third covered: the text names what is covered.
            assert!(
                missing.contains("covered only") && missing.contains("+z (elevation"),
                "{err}"
            );
        }
    }

    #[test]
    fn a_ring_supports_no_3d_model() {
        let raw = SimSensor3 {
            motion: Motion3::WobblingTurn {
                turns: 2.0,
                inclination_deg: 0.0,
                tilt_deg: 0.0,
            },
            ..tumble(SOFT_IRON, 0.005, 600, 2)
        }
        .simulate()
        .unwrap();
        for model in Ellipsoid3Model::ALL {
            let err = fit(&raw, model).unwrap_err();
            let Ellipsoid3Error::NotCovered {
                missing,
                supported,
                plane,
                ..
            } = &err
            else {
                panic!("{model}: {err}");
            };
            assert_eq!(*supported, None, "{err}");
            let plane = plane
                .as_deref()
                .unwrap_or_else(|| panic!("no plane named: {err}"));
            assert!(plane.contains("about the z axis"), "{err}");
            assert!(err.to_string().contains("fit the two axes"), "{err}");
            // Less than a third covered: the text names what is covered (about
            // a closed-form centre off the ring's plane, a cone of it).
            assert!(
                missing.contains("covered only") && missing.contains("every other direction"),
                "{err}"
            );
        }
    }

    #[test]
    fn a_half_sphere_is_refused_for_the_full_model() {
        let raw = cap(90.0, 3);
        let err = fit(&raw, Ellipsoid3Model::Full).unwrap_err();
        println!("{err}");
        let Ellipsoid3Error::NotCovered {
            missing, percent, ..
        } = &err
        else {
            panic!("{err}");
        };
        assert!((40.0..=60.0).contains(percent), "{err}");
        assert!(missing.starts_with("missing: -z"), "{err}");
    }

    /// Six static poses, each sensor axis up and down in turn (the
    /// six-position calibration of accelerometers), with noise.
    fn six_poses(seed: u64) -> Vec<[f64; 3]> {
        let mut raw = Vec::new();
        for (k, axis) in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .iter()
            .enumerate()
        {
            for sign in [1.0, -1.0] {
                let sim = SimSensor3 {
                    motion: Motion3::Cap {
                        half_angle_deg: 1e-3,
                    },
                    ..tumble(
                        SOFT_IRON,
                        0.002,
                        100,
                        seed + 2 * k as u64 + (sign > 0.0) as u64,
                    )
                };
                let w = Matrix3::from_fn(|i, j| sim.matrix[i][j])
                    .try_inverse()
                    .unwrap();
                let points = sim.simulate().unwrap();
                let along = Vector3::from(*axis) * sign * sim.r;
                let z = w * Vector3::new(0.0, 0.0, sim.r);
                let target = w * along;
                // The same noise, about this pose instead of +z.
                raw.extend(
                    points
                        .iter()
                        .map(|p| [0, 1, 2].map(|i| p[i] - z[i] + target[i])),
                );
            }
        }
        raw
    }

    #[test]
    fn six_static_poses_support_offset_scale_only() {
        let raw = six_poses(40);
        let err = fit(&raw, Ellipsoid3Model::Full).unwrap_err();
        let Ellipsoid3Error::NotCovered { supported, .. } = &err else {
            panic!("{err}");
        };
        assert_eq!(*supported, Some(Ellipsoid3Model::OffsetScale), "{err}");
        assert!(
            err.to_string()
                .contains("still support the offset+scale model"),
            "{err}"
        );
        let f = fit(&raw, Ellipsoid3Model::OffsetScale).unwrap();
        assert!(f.coverage.fraction <= 0.1, "{}", f.coverage.fraction);
        // The offset is found although W's cross terms are ignored.
        assert!(f.rms < 0.1, "{}", f.rms);
        assert!(fit(&raw, Ellipsoid3Model::Offset).is_ok());
    }

    #[test]
    fn a_well_covered_tumble_is_accepted() {
        let raw = tumble(SOFT_IRON, 0.005, 600, 5).simulate().unwrap();
        let fit = fit(&raw, Ellipsoid3Model::Full).unwrap();
        assert!(fit.coverage.fraction >= 0.85, "{:?}", fit.coverage.fraction);
        assert!(fit.iterations < MAX_ITERATIONS);
    }

    #[test]
    fn bad_input_is_refused_with_its_place() {
        let mut raw = tumble(SOFT_IRON, 0.005, 100, 5).simulate().unwrap();
        assert!(matches!(
            fit(&raw[..9], Ellipsoid3Model::Full),
            Err(Ellipsoid3Error::TooFewSamples {
                found: 9,
                needed: 10,
                ..
            })
        ));
        raw[4][1] = f64::NAN;
        assert!(matches!(
            fit(&raw, Ellipsoid3Model::Offset),
            Err(Ellipsoid3Error::NonFinite {
                index: 4,
                axis: "y",
                ..
            })
        ));
        raw[4][1] = 1e200;
        assert!(matches!(
            fit(&raw, Ellipsoid3Model::Offset),
            Err(Ellipsoid3Error::TooLarge {
                index: 4,
                axis: "y",
                ..
            })
        ));
        let same = vec![[1.0, 2.0, 3.0]; 50];
        assert_eq!(
            fit(&same, Ellipsoid3Model::Offset),
            Err(Ellipsoid3Error::Degenerate)
        );
    }

    #[test]
    fn model_names_follow_the_effects() {
        for m in Ellipsoid3Model::ALL {
            assert_eq!(m.name().parse::<Ellipsoid3Model>(), Ok(m));
        }
        assert_eq!("full".parse::<Ellipsoid3Model>(), Ok(Ellipsoid3Model::Full));
        assert!("sphere".parse::<Ellipsoid3Model>().is_err());
    }
}

mod heading {
    use fieldcal::model::heading::{circle_centre, coverage};

    #[test]
    fn full_circle_of_samples_covers_nearly_360() {
        let c = coverage((0..36).map(|i| (i as f64 * 10.0).to_radians()));
        assert!((c.covered_deg - 350.0).abs() < 1e-9, "{c:?}");
    }

    #[test]
    fn half_turn_reports_its_gap() {
        let c = coverage((0..=18).map(|i| (i as f64 * 10.0 - 90.0).to_radians()));
        assert!((c.covered_deg - 180.0).abs() < 1e-9, "{c:?}");
        assert!((c.gap_start_deg - 90.0).abs() < 1e-9, "{c:?}");
        let err = c.require(300.0).unwrap_err().to_string();
        assert!(err.contains("cover only 180.0°"), "{err}");
    }

    #[test]
    fn centre_of_an_arc() {
        let (x, y): (Vec<f64>, Vec<f64>) = (0..20)
            .map(|i| {
                let a = (i as f64 * 4.0).to_radians();
                (100.0 + 50.0 * a.cos(), -30.0 + 50.0 * a.sin())
            })
            .unzip();
        let (cx, cy) = circle_centre(&x, &y).unwrap();
        assert!(
            (cx - 100.0).abs() < 1e-6 && (cy + 30.0).abs() < 1e-6,
            "{cx} {cy}"
        );
    }
}

mod heading_analysis {
    use fieldcal::model::gyro::HeadingDelta;
    use fieldcal::model::heading_analysis::{
        Declination, DeclinationSource, HeadingAnalysisError, HeadingStats, compensation_verdict,
        fusion_verdict,
    };
    use fieldcal::model::tilt::HeadingSeries;

    fn delta(delta_rms_deg: f64, se_deg: f64) -> HeadingDelta {
        HeadingDelta {
            delta_rms_deg,
            se_deg,
        }
    }

    #[test]
    fn compensation_verdicts_follow_the_standard_error() {
        assert!(
            compensation_verdict(delta(2.0, 0.1), true, false)
                .starts_with("tilt compensation removed 2.00°")
        );
        let worse = compensation_verdict(delta(-2.0, 0.1), true, false);
        assert!(
            worse.contains("WORSE by 2.00°") && worse.contains("still poses"),
            "{worse}"
        );
        assert!(compensation_verdict(delta(-2.0, 0.1), false, true).contains("--rates names"));
        assert!(compensation_verdict(delta(0.1, 0.1), false, false).contains("no difference"));
        assert!(compensation_verdict(delta(f64::NAN, 0.1), false, false).starts_with("too few"));
    }

    #[test]
    fn fusion_verdicts_follow_the_standard_error() {
        assert!(fusion_verdict(delta(1.0, 0.1)).starts_with("the gyro removed"));
        assert!(fusion_verdict(delta(-1.0, 0.1)).starts_with("the gyro made the vertical worse"));
        assert!(fusion_verdict(delta(0.0, 0.1)).starts_with("no difference"));
        assert!(fusion_verdict(delta(1.0, f64::NAN)).starts_with("too few"));
    }

    #[test]
    fn declination_prefers_the_model_and_refuses_nonsense() {
        let none = Declination::choose(None, None).unwrap();
        assert_eq!(
            (none.deg, none.source, none.north()),
            (0.0, DeclinationSource::None, "magnetic")
        );
        let given = Declination::choose(None, Some(-3.5)).unwrap();
        assert_eq!(
            (given.deg, given.source.name(), given.north()),
            (-3.5, "given", "true")
        );
        let err = Declination::choose(None, Some(200.0)).unwrap_err();
        assert_eq!(
            err.to_string(),
            "--declination 200: give degrees east of true north, -180 to 180"
        );
    }

    #[test]
    fn stats_refuse_a_series_without_a_heading() {
        let series = HeadingSeries {
            heading_deg: vec![f64::NAN; 3],
            level_deg: vec![f64::NAN; 3],
            tilt_deg: vec![f64::NAN; 3],
            pitch_deg: vec![f64::NAN; 3],
            inclination_deg: vec![f64::NAN; 3],
        };
        assert_eq!(
            HeadingStats::of(&series),
            Err(HeadingAnalysisError::NoHeading)
        );
        let series = HeadingSeries {
            heading_deg: vec![10.0, f64::NAN, 30.0],
            tilt_deg: vec![2.0, 9.0, f64::NAN],
            inclination_deg: vec![60.0, 61.0, 62.0],
            ..series
        };
        let stats = HeadingStats::of(&series).unwrap();
        assert_eq!(stats.n_heading, 2);
        assert_eq!(stats.max_tilt, 9.0);
        assert_eq!(stats.inclination.map(|i| i.median), Some(61.0));
    }
}

mod paper {
    use fieldcal::model::FitError;
    use fieldcal::model::paper::{
        GradientDescentOptions, PaperCalibration, closed_form, closed_form_se, gradient_descent,
    };

    /// The closed form's standard errors match the scatter of its estimates
    /// over 200 noise seeds within 20 % (the scatter of 200 draws is itself
    /// known to ±5 %).
    #[test]
    fn closed_form_se_matches_the_scatter_over_seeds() {
        use fieldcal::sim::SimSensor;
        for (gain_x, offset_x, offset_y, noise) in
            [(1.1, 120.0, -80.0, 8.0), (0.85, -300.0, 40.0, 20.0)]
        {
            let mut estimates: Vec<[f64; 4]> = Vec::new();
            let mut ses: Vec<[f64; 4]> = Vec::new();
            for seed in 0..200 {
                let sensor = SimSensor {
                    gain_x,
                    offset_x,
                    offset_y,
                    noise,
                    period: 0.05,
                    turns: 1.0,
                    turn_seconds: 20.0,
                    seed,
                    ..SimSensor::default()
                };
                let data = sensor.simulate().unwrap();
                let theta = closed_form(&data.x, &data.y).unwrap();
                let c = theta.to_calibration().unwrap();
                let se = closed_form_se(&data.x, &data.y, &theta).unwrap();
                estimates.push([c.a, c.b, c.d, c.r]);
                ses.push([se.a, se.b, se.d, se.r]);
            }
            for (j, name) in ["a", "b", "d", "r"].iter().enumerate() {
                let n = estimates.len() as f64;
                let mean = estimates.iter().map(|e| e[j]).sum::<f64>() / n;
                let sd = (estimates.iter().map(|e| (e[j] - mean).powi(2)).sum::<f64>() / (n - 1.0))
                    .sqrt();
                let se = ses.iter().map(|s| s[j]).sum::<f64>() / n;
                assert!(
                    (se / sd - 1.0).abs() < 0.2,
                    "{name}: se {se} vs scatter {sd} (gain {gain_x}, noise {noise})"
                );
            }
        }
    }

    fn ellipse(cal: &PaperCalibration, n: usize) -> (Vec<f64>, Vec<f64>) {
        (0..n)
            .map(|i| {
                let phi = i as f64 / n as f64 * std::f64::consts::TAU;
                let (sx, sy) = (cal.r * phi.cos(), cal.r * phi.sin());
                ((sx - cal.b) / cal.a, sy - cal.d)
            })
            .unzip()
    }

    #[test]
    fn theta_and_calibration_are_inverse() {
        let cal = PaperCalibration {
            a: 1.3,
            b: -40.0,
            d: 12.5,
            r: 480.0,
        };
        let back = cal.to_theta().to_calibration().unwrap();
        for (u, v) in [
            (back.a, cal.a),
            (back.b, cal.b),
            (back.d, cal.d),
            (back.r, cal.r),
        ] {
            assert!((u - v).abs() <= 1e-12 * v.abs(), "{u} != {v}");
        }
    }

    #[test]
    fn closed_form_is_exact_on_noiseless_raw_counts() {
        // Offsets of tens of thousands of counts: the conditioning case.
        let cal = PaperCalibration {
            a: 0.8,
            b: -24_000.0,
            d: 31_000.0,
            r: 2_000.0,
        };
        let (x, y) = ellipse(&cal, 50);
        let fit = closed_form(&x, &y).unwrap().to_calibration().unwrap();
        assert!((fit.a - cal.a).abs() < 1e-9, "a {}", fit.a);
        assert!((fit.b - cal.b).abs() < 1e-6, "b {}", fit.b);
        assert!((fit.d - cal.d).abs() < 1e-6, "d {}", fit.d);
        assert!((fit.r - cal.r).abs() < 1e-6, "r {}", fit.r);
    }

    #[test]
    fn hyperbola_is_not_an_ellipse() {
        let x: Vec<f64> = (1..40).map(|i| i as f64).collect();
        let y: Vec<f64> = x.iter().map(|x| (x * x + 5.0).sqrt()).collect();
        let err = closed_form(&x, &y).unwrap().to_calibration().unwrap_err();
        assert!(
            matches!(err, FitError::NotAnEllipse { theta1 } if theta1 >= 0.0),
            "{err:?}"
        );
    }

    /// A sensor with small offsets, for the gradient descent (which starts
    /// from no offset).
    const CENTRED: PaperCalibration = PaperCalibration {
        a: 1.1,
        b: 30.0,
        d: -20.0,
        r: 500.0,
    };

    #[test]
    fn gradient_descent_matches_closed_form_on_a_centred_sensor() {
        let cal = CENTRED;
        let (x, y) = ellipse(&cal, 200);
        let gd = gradient_descent(&x, &y, &GradientDescentOptions::default(), &mut |_| {}).unwrap();
        let fit = gd.theta.to_calibration().unwrap();
        assert!(gd.iterations > 10, "{}", gd.iterations);
        assert!((fit.a - cal.a).abs() < 1e-4 * cal.a, "a {}", fit.a);
        assert!((fit.r - cal.r).abs() < 1e-4 * cal.r, "r {}", fit.r);
    }

    #[test]
    fn gradient_descent_stops_at_its_cap() {
        let cal = CENTRED;
        let (x, y) = ellipse(&cal, 100);
        let options = GradientDescentOptions {
            max_iterations: 5,
            ..Default::default()
        };
        let err = gradient_descent(&x, &y, &options, &mut |_| {}).unwrap_err();
        assert!(
            matches!(err, FitError::IterationCap { cap: 5, .. }),
            "{err:?}"
        );
    }
}

mod rotation {
    use fieldcal::model::rotation::{
        DEFAULT_MAX_GAP_DEG, RotationBuffer, RotationConfig, RotationEvent, RotationState,
    };
    use fieldcal::sim::SimSensor;

    /// Deterministic Gaussian noise (xorshift + Box-Muller), so tests need
    /// no generator state from elsewhere.
    struct Noise(u64);
    impl Noise {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        fn gauss(&mut self, sigma: f64) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    /// Samples every `period` s for `seconds` of a circle of radius 1000
    /// around (cx, cy), heading(t) in degrees.
    fn track(
        seconds: f64,
        period: f64,
        centre: (f64, f64),
        noise: f64,
        heading: impl Fn(f64) -> f64,
    ) -> Vec<(f64, f64, f64)> {
        let mut rng = Noise(0x9E37_79B9_7F4A_7C15);
        let n = (seconds / period).round() as usize;
        (0..n)
            .map(|i| {
                let t = i as f64 * period;
                let h = heading(t).to_radians();
                (
                    t,
                    centre.0 + 1000.0 * h.cos() + rng.gauss(noise),
                    centre.1 + 1000.0 * h.sin() + rng.gauss(noise),
                )
            })
            .collect()
    }

    /// Pushes until something other than Collecting; returns its index.
    /// The sample at which a default buffer rejects `samples`, and why;
    /// fails when it completes or goes on collecting.
    fn rejected(samples: &[(f64, f64, f64)]) -> (usize, String) {
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        match run(&mut buffer, samples) {
            Some((i, RotationEvent::Rejected { reason })) => (i, reason),
            other => panic!("{other:?}"),
        }
    }

    fn run(
        buffer: &mut RotationBuffer,
        samples: &[(f64, f64, f64)],
    ) -> Option<(usize, RotationEvent)> {
        for (i, &(t, x, y)) in samples.iter().enumerate() {
            match buffer.push(t, x, y) {
                RotationEvent::Collecting => {}
                event => return Some((i, event)),
            }
        }
        None
    }

    fn sim_samples(sim: &SimSensor) -> Vec<(f64, f64, f64)> {
        let d = sim.simulate().unwrap();
        let t = d.t.clone().unwrap();
        (0..d.len()).map(|i| (t[i], d.x[i], d.y[i])).collect()
    }

    /// One and a half clean turns with noise `noise`, the sensor's default.
    fn turn_and_a_half(noise: f64) -> SimSensor {
        SimSensor {
            turns: 1.5,
            noise,
            ..Default::default()
        }
    }

    /// Fraction of a turn at which the buffer completed.
    fn completes_at(sim: &SimSensor) -> f64 {
        let samples = sim_samples(sim);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).expect("no event");
        assert_eq!(event, RotationEvent::Complete, "{sim:?}");
        i as f64 * sim.period / sim.turn_seconds
    }

    /// What a person watches must not run ahead of the turn and fall back:
    /// on the first short, noisy arc the centre is not yet known, so no
    /// heading counts until the arc bends beyond its noise.
    #[test]
    fn coverage_never_runs_ahead_of_the_turn_nor_falls_back() {
        for (i, start) in [0.0, 33.0, 90.0, 200.0, 311.0].into_iter().enumerate() {
            for noise in [1.0, 3.0, 8.0] {
                let rate = 36.0 + 4.0 * i as f64;
                let samples = track(12.0, 0.05, (-400.0, 250.0), noise, |t| start + rate * t);
                let mut buffer = RotationBuffer::new(RotationConfig::default());
                let mut best: f64 = 0.0;
                for &(t, x, y) in &samples {
                    if buffer.push(t, x, y) != RotationEvent::Collecting {
                        break;
                    }
                    let shown = buffer.progress().coverage_pct;
                    let turned = rate * t / 360.0 * 100.0;
                    // A gap up to max_gap_deg counts as covered.
                    let slack = DEFAULT_MAX_GAP_DEG / 360.0 * 100.0 + 1.0;
                    assert!(
                        shown <= turned + slack,
                        "start {start}, noise {noise}: {shown:.1} % shown at {turned:.1} % turned"
                    );
                    assert!(
                        shown >= best - 5.0,
                        "start {start}, noise {noise}: fell from {best:.1} % to {shown:.1} % at t = {t}"
                    );
                    best = best.max(shown);
                }
                assert!(
                    best > 80.0,
                    "start {start}, noise {noise}: reached {best:.1} %"
                );
            }
        }
    }

    #[test]
    fn a_clean_turn_completes_at_its_end_and_not_before() {
        let sim = turn_and_a_half(2.0);
        let at = completes_at(&sim);
        assert!((0.9..=1.0).contains(&at), "completed at {at} turns");
    }

    #[test]
    fn a_turn_from_any_heading_completes() {
        for start in [0.0, 4.0, 37.0, 90.0, 123.4, 181.0, 269.0, 333.3, 359.0] {
            let mut sim = turn_and_a_half(2.0);
            sim.start_heading_deg = start;
            sim.seed = start as u64 + 7;
            // At worst the last sector needs its samples from the second pass.
            let at = completes_at(&sim);
            assert!((0.9..=1.03).contains(&at), "start {start}: at {at} turns");
        }
    }

    #[test]
    fn a_turn_far_from_the_origin_and_with_unequal_gains_completes() {
        for (gain_x, period) in [(1.0, 0.05), (1.4, 0.05), (0.6, 0.03)] {
            let sim = SimSensor {
                offset_x: 5000.0,
                offset_y: -5000.0,
                gain_x,
                period,
                start_heading_deg: 200.0,
                ..turn_and_a_half(3.0)
            };
            let at = completes_at(&sim);
            // The raw headings of an ellipse of gain ratio a run ahead of or
            // behind the true ones by up to asin((a - 1)/(a + 1)) (9.6° at
            // 1.4), so the raw net of 330° may be a true 311° (0.86 turn);
            // the fit still sees no gap above 30° x 1.4 = 42°.
            assert!(
                (0.85..=1.05).contains(&at),
                "gain {gain_x}: completed at {at} turns"
            );
        }
    }

    #[test]
    fn clockwise_turn_completes() {
        let samples = track(15.0, 0.05, (-300.0, 800.0), 2.0, |t| 50.0 - 36.0 * t);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).unwrap();
        assert_eq!(event, RotationEvent::Complete);
        let at = i as f64 * 0.05 / 10.0;
        assert!((0.9..=1.03).contains(&at), "{at}");
    }

    #[test]
    fn waiting_before_turning_then_turning_completes() {
        // 8 s still, then one turn in 10 s: the wait must not spoil it.
        let samples = track(25.0, 0.05, (2000.0, 0.0), 2.0, |t| {
            if t < 8.0 {
                120.0
            } else {
                120.0 + 36.0 * (t - 8.0)
            }
        });
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).unwrap();
        assert_eq!(event, RotationEvent::Complete);
        let turned = (i as f64 * 0.05 - 8.0) / 10.0;
        assert!((0.9..=1.03).contains(&turned), "{turned}");
        let (t, x, y) = buffer.take();
        assert_eq!((t.len(), x.len(), y.len()), (i + 1, i + 1, i + 1));
        assert_eq!(buffer.progress().state, RotationState::Empty);
    }

    #[test]
    fn half_a_turn_times_out_with_the_missing_headings() {
        // From 5° to 185° in 5 s, then held still at 185°.
        let samples = track(61.0, 0.05, (100.0, 100.0), 2.0, |t| 5.0 + 36.0 * t.min(5.0));
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let mut last = None;
        for &(t, x, y) in &samples {
            match buffer.push(t, x, y) {
                RotationEvent::Collecting => last = Some(buffer.progress()),
                RotationEvent::Complete => panic!("half a turn completed at {t}"),
                RotationEvent::Rejected { reason } => {
                    // The first sample past 60 s.
                    assert!((t - 60.05).abs() < 1e-9, "{t}");
                    assert_eq!(
                        reason,
                        "no full rotation within 60 s: 50 % of headings covered, missing 186° to 5°; turn the sensor once all the way round, steadily"
                    );
                    let p = last.take().unwrap();
                    // Headings 5° to 185° are covered, 186° to 5° missing
                    // (to a 1° bin: this progress is around the centre
                    // before the failure's exact recount).
                    assert!((p.coverage_pct - 50.0).abs() < 0.6, "{p:?}");
                    let [[from, to]] = p.missing_sectors[..] else {
                        panic!("{p:?}");
                    };
                    assert!(
                        (from - 186.0).abs() <= 1.0 && (to - 5.0).abs() <= 1.0,
                        "{p:?}"
                    );
                    assert!((p.turned_deg - 180.0).abs() < 2.0, "{p:?}");
                    assert!((p.largest_gap_deg - 180.0).abs() <= 1.0, "{p:?}");
                    // Restarted with the rejected sample as its first.
                    assert_eq!(buffer.progress().samples, 1);
                    return;
                }
            }
        }
        panic!("no rejection");
    }

    #[test]
    fn a_gap_through_zero_is_one_range() {
        // From 20° to 340° in about 9 s; stop before the timeout.
        let samples = track(9.0, 0.05, (0.0, 0.0), 1.0, |t| {
            20.0 + 36.0 * t.min(320.0 / 36.0)
        });
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        assert_eq!(run(&mut buffer, &samples), None);
        let p = buffer.progress();
        // The first sample fell in the 19° bin (20° less noise).
        assert_eq!(p.missing_sectors, vec![[340.0, 19.0]], "{p:?}");
        assert!(
            (p.coverage_pct - (1.0 - 39.0 / 360.0) * 100.0).abs() < 1e-9,
            "{p:?}"
        );
        assert!((p.turned_deg - 320.0).abs() < 1.0, "{p:?}");
        assert_eq!(p.largest_gap_deg, 40.0);
        assert_eq!(p.samples, samples.len());
        assert!((p.elapsed_s - samples[samples.len() - 1].0).abs() < 1e-12);
        assert_eq!(p.state, RotationState::Collecting);
    }

    #[test]
    fn back_and_forth_is_rejected_as_such() {
        // Swings between 0° and 170°, 6 s per sweep, for over a minute.
        let samples = track(62.0, 0.05, (-4000.0, 2500.0), 2.0, |t| {
            let phase = (t / 6.0).rem_euclid(2.0);
            170.0 * if phase < 1.0 { phase } else { 2.0 - phase }
        });
        let (i, reason) = rejected(&samples);
        assert!((i as f64 * 0.05 - 60.05).abs() < 1e-9, "{i}");
        assert!(
            reason.starts_with("the sensor turned back and forth over 170° and never completed a rotation within 60 s"),
            "{reason}"
        );
        assert!(
            reason.ends_with("turn it once all the way round in one direction"),
            "{reason}"
        );
    }

    #[test]
    fn a_still_sensor_is_rejected_as_not_turning() {
        let samples = track(12.0, 0.05, (700.0, -300.0), 3.0, |_| 40.0);
        let (i, reason) = rejected(&samples);
        // The first sample 10 s after the first.
        assert_eq!(i, 200);
        assert!(
            reason.starts_with("the sensor is not turning: readings spread over only "),
            "{reason}"
        );
        assert!(
            reason.contains("counts in 10.0 s (noise about "),
            "{reason}"
        );
        assert!(reason.ends_with("; turn it a full rotation"), "{reason}");
        // And it never completes on noise, however long it sits.
        let samples = track(300.0, 0.01, (0.0, 0.0), 5.0, |_| 0.0);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        for &(t, x, y) in &samples {
            assert_ne!(buffer.push(t, x, y), RotationEvent::Complete, "at {t}");
        }
    }

    #[test]
    fn memory_stays_bounded() {
        let config = RotationConfig {
            max_samples: 150,
            ..Default::default()
        };
        // A slow turn (a tenth of a turn in 10 s) that is clearly turning.
        let samples = track(20.0, 0.05, (0.0, 0.0), 1.0, |t| 3.6 * t);
        let mut buffer = RotationBuffer::new(config);
        let mut rejected = 0;
        for &(t, x, y) in &samples {
            if let RotationEvent::Rejected { reason } = buffer.push(t, x, y) {
                assert!(reason.contains("within 150 samples"), "{reason}");
                rejected += 1;
            }
            assert!(buffer.progress().samples < 150);
        }
        assert_eq!(rejected, samples.len() / 150);
    }

    #[test]
    fn bad_samples_are_ignored_without_harm() {
        let sim = turn_and_a_half(2.0);
        let clean = sim_samples(&sim);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let mut done = None;
        for (i, &(t, x, y)) in clean.iter().enumerate() {
            for (bt, bx, by) in [
                (t, f64::NAN, y),
                (t, x, f64::INFINITY),
                (f64::NAN, x, y),
                (t, f64::NEG_INFINITY, f64::NAN),
            ] {
                assert_eq!(buffer.push(bt, bx, by), RotationEvent::Collecting);
            }
            if i > 0 {
                // Out of order: earlier than the last sample.
                assert_eq!(buffer.push(t - 1.0, x, y), RotationEvent::Collecting);
            }
            if buffer.push(t, x, y) == RotationEvent::Complete {
                done = Some(i);
                break;
            }
        }
        let i = done.unwrap();
        let at = i as f64 * sim.period / sim.turn_seconds;
        assert!((0.9..=1.0).contains(&at), "{at}");
        let p = buffer.progress();
        assert_eq!(p.samples, i + 1);
        assert_eq!(p.ignored, 5 * i as u64 + 4);
        assert_eq!(p.state, RotationState::Complete);
        assert_eq!(p.coverage_pct, 100.0);
        assert!(p.missing_sectors.is_empty());
        // Frozen until taken.
        assert_eq!(buffer.push(1e6, 0.0, 0.0), RotationEvent::Complete);
        let (t, _, _) = buffer.take();
        assert_eq!(t.len(), i + 1);
        assert_eq!(buffer.progress().samples, 0);
    }

    #[test]
    fn the_samples_of_a_turn_fit() {
        let sim = SimSensor {
            gain_x: 1.2,
            offset_x: 3000.0,
            ..turn_and_a_half(2.0)
        };
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        assert_eq!(
            run(&mut buffer, &sim_samples(&sim)).unwrap().1,
            RotationEvent::Complete
        );
        let (_, x, y) = buffer.take();
        let fit = fieldcal::model::fit::fit_paper(
            &x,
            &y,
            &fieldcal::model::fit::FitOptions::default(),
            &mut |_| {},
        )
        .unwrap();
        assert!(
            fieldcal::daemon::acceptance::check(&fit, &Default::default()).is_ok(),
            "{fit:?}"
        );
        assert!((fit.calibration.a - sim.truth().a).abs() < 0.01, "{fit:?}");
    }

    /// A heading that turns at `speeds[i]` deg/s for `durations[i]` s in
    /// turn (0 for a pause), from `start`.
    fn profile(start: f64, legs: &[(f64, f64)]) -> impl Fn(f64) -> f64 + '_ {
        move |t| {
            let (mut h, mut t0) = (start, 0.0);
            for &(speed, duration) in legs {
                let dt = (t - t0).clamp(0.0, duration);
                h += speed * dt;
                t0 += duration;
            }
            h
        }
    }

    /// Index and turned angle (per the heading function) at completion.
    fn completion(samples: &[(f64, f64, f64)], heading: &dyn Fn(f64) -> f64) -> (usize, f64) {
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, samples).expect("no event");
        assert_eq!(event, RotationEvent::Complete);
        (i, heading(samples[i].0) - heading(0.0))
    }

    #[test]
    fn a_10_hz_robot_turn_with_stops_completes_on_one_turn() {
        // 10 Hz, 9° to 15° a sample (one to two samples per 10° sector,
        // where 36 sectors x 3 samples never fill), two stops of 3 s.
        let legs = [
            (90.0, 1.5),
            (0.0, 3.0),
            (150.0, 0.7),
            (120.0, 0.5),
            (0.0, 3.0),
            (100.0, 0.6),
            (0.0, 5.0),
        ];
        let heading = profile(77.0, &legs);
        assert!((heading(100.0) - 77.0 - 360.0).abs() < 1e-9);
        for direction in [1.0, -1.0] {
            let h = |t: f64| direction * heading(t);
            let samples = track(15.0, 0.1, (2500.0, -4000.0), 5.0, h);
            let (_, turned) = completion(&samples, &h);
            assert!(
                (330.0..=360.0).contains(&turned.abs()),
                "direction {direction}: completed at {turned}°"
            );
        }
    }

    #[test]
    fn a_swing_that_covers_every_heading_never_completes() {
        // Swinging about where the buffer starts: every heading is covered
        // at ±180° and beyond, but the net turn never passes the amplitude.
        for amplitude in [180.0, 200.0] {
            for period in [4.0, 8.0, 13.0] {
                let samples = track(60.0, 0.05, (300.0, 300.0), 3.0, |t: f64| {
                    30.0 + amplitude * (std::f64::consts::TAU * t / period).sin()
                });
                let mut buffer = RotationBuffer::new(RotationConfig::default());
                assert_eq!(
                    run(&mut buffer, &samples),
                    None,
                    "±{amplitude}° every {period} s"
                );
                let p = buffer.progress();
                assert!(p.largest_gap_deg <= 30.0, "{p:?}");
                assert!(p.turned_deg.abs() <= 2.0 * amplitude + 2.0, "{p:?}");
            }
        }
        // Swings narrower than a turn never complete, whatever the phase the
        // buffer restarts at after each timeout.
        for amplitude in [90.0, 150.0] {
            let samples = track(300.0, 0.05, (0.0, 0.0), 3.0, |t: f64| {
                amplitude * (std::f64::consts::TAU * t / 7.0).sin()
            });
            let mut buffer = RotationBuffer::new(RotationConfig::default());
            for &(t, x, y) in &samples {
                assert_ne!(
                    buffer.push(t, x, y),
                    RotationEvent::Complete,
                    "±{amplitude}° at {t}"
                );
            }
        }
    }

    #[test]
    fn a_sensor_that_slides_never_completes() {
        let mut rng = Noise(0x5EED_5EED_5EED_5EED);
        for seed in 0..20 {
            // Along a line, slowly (a sensor carried past iron), or wandering
            // by small steps (a random walk a few noise deviations a step).
            let mut buffer = RotationBuffer::new(RotationConfig::default());
            let (mut x, mut y) = (1200.0, -300.0);
            let angle = rng.uniform() * std::f64::consts::TAU;
            for i in 0..3000 {
                let t = f64::from(i) * 0.04;
                if seed % 2 == 0 {
                    x += 0.5 * angle.cos();
                    y += 0.5 * angle.sin();
                } else {
                    x += rng.gauss(4.0);
                    y += rng.gauss(4.0);
                }
                let event = buffer.push(t, x + rng.gauss(2.0), y + rng.gauss(2.0));
                assert_ne!(event, RotationEvent::Complete, "seed {seed} at {t} s");
            }
        }
    }

    #[test]
    fn the_gyro_confirms_or_holds_back_a_turn() {
        let heading = |t: f64| 10.0 + 36.0 * t;
        let samples = track(15.0, 0.05, (400.0, -900.0), 2.0, heading);
        // Without a gyro, with one that agrees (either sign), or with one
        // that is not used: the same sample completes.
        let mut plain = RotationBuffer::new(RotationConfig::default());
        let (i, _) = run(&mut plain, &samples).unwrap();
        let with_gyro = RotationConfig {
            use_gyro: true,
            ..Default::default()
        };
        for (sign, use_gyro) in [(1.0, true), (-1.0, true), (0.0, false)] {
            let config = RotationConfig {
                use_gyro,
                ..Default::default()
            };
            let mut buffer = RotationBuffer::new(config);
            let done = samples.iter().position(|&(t, x, y)| {
                buffer.push_turned(t, x, y, Some(sign * heading(t) + 1000.0))
                    == RotationEvent::Complete
            });
            assert_eq!(done, Some(i), "sign {sign}");
        }
        // A gyro that saw no turn (a magnet carried round a still sensor)
        // holds it back when used, and the rejection says so.
        let mut buffer = RotationBuffer::new(with_gyro);
        let samples = track(61.0, 0.05, (400.0, -900.0), 2.0, heading);
        for &(t, x, y) in &samples {
            match buffer.push_turned(t, x, y, Some(5.0 + 0.01 * t)) {
                RotationEvent::Collecting => {}
                RotationEvent::Complete => panic!("completed at {t} s"),
                RotationEvent::Rejected { reason } => {
                    assert!(
                        reason.starts_with("no full rotation within 60 s: the readings turned "),
                        "{reason}"
                    );
                    assert!(reason.contains("but the gyro only 1°"), "{reason}");
                    return;
                }
            }
        }
        panic!("no rejection");
    }

    #[test]
    fn progress_reports_the_turn_and_the_gap() {
        let samples = track(5.0, 0.05, (0.0, 0.0), 1.0, |t| 90.0 - 36.0 * t);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        assert_eq!(run(&mut buffer, &samples), None);
        let p = buffer.progress();
        // Clockwise: a negative turn, a bit under 180° (the last sample is
        // at 4.95 s).
        assert!((p.turned_deg + 178.2).abs() < 0.5, "{p:?}");
        assert_eq!(p.turn_needed_deg, 330.0);
        assert!((p.largest_gap_deg - 181.8).abs() <= 1.0, "{p:?}");
        assert_eq!(p.gyro_turned_deg, None);
        let json = serde_json::to_value(&p).unwrap();
        for key in [
            "coverage_pct",
            "missing_sectors",
            "turned_deg",
            "largest_gap_deg",
        ] {
            assert!(json.get(key).is_some(), "{json}");
        }
    }

    #[test]
    fn config_validation_names_the_key() {
        assert_eq!(RotationConfig::default().validate(), Ok(()));
        let bad = RotationConfig {
            max_gap_deg: 90.0,
            ..Default::default()
        };
        assert_eq!(
            bad.validate().unwrap_err(),
            "max_gap_deg must be between 2 and 60 degrees, got 90"
        );
        let with = |set: fn(&mut RotationConfig)| {
            let mut config = RotationConfig::default();
            set(&mut config);
            config
        };
        let cases = [
            (with(|c| c.max_gap_deg = f64::NAN), "max_gap_deg"),
            (with(|c| c.max_samples = 11), "max_samples"),
            (with(|c| c.timeout_s = f64::NAN), "timeout_s"),
            (with(|c| c.still_timeout_s = -1.0), "still_timeout_s"),
            (with(|c| c.still_ratio = 0.5), "still_ratio"),
        ];
        for (config, key) in cases {
            let err = config.validate().unwrap_err();
            assert!(err.starts_with(key), "{err}");
            // An invalid configuration still makes a working buffer.
            let mut buffer = RotationBuffer::new(config);
            buffer.push(0.0, 1.0, 2.0);
            assert_eq!(buffer.progress().samples, 1);
            assert!(buffer.config().validate().is_ok(), "{:?}", buffer.config());
        }
        let c: RotationConfig =
            toml::from_str("max_gap_deg = 20.0\ntimeout_s = 30.0\nuse_gyro = true").unwrap();
        assert_eq!((c.max_gap_deg, c.timeout_s, c.use_gyro), (20.0, 30.0, true));
        assert_eq!(c.turn_needed_deg(), 340.0);
        assert_eq!(c.max_samples, 20_000);
        // The per-sector keys are gone: named, not ignored.
        let err = toml::from_str::<RotationConfig>("sectors = 24").unwrap_err();
        assert!(err.to_string().contains("sectors"), "{err}");
    }
}

mod sphere {
    use fieldcal::model::sphere::{BANDS, REGIONS, coverage, region, region_of};
    use std::f64::consts::PI;

    fn fibonacci(n: usize) -> Vec<[f64; 3]> {
        let golden = PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let rho = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                [rho * phi.cos(), rho * phi.sin(), z]
            })
            .collect()
    }

    #[test]
    fn a_band_is_named_by_what_it_covers() {
        // A ring round y (a turn in the x-z plane), within 10° of the plane.
        let ring: Vec<[f64; 3]> = (0..720)
            .map(|i| {
                let a = (i as f64).to_radians() * 0.5 * 2.0;
                let tilt = (10.0f64).to_radians() * (3.0 * a).sin();
                [a.cos() * tilt.cos(), tilt.sin(), a.sin() * tilt.cos()]
            })
            .collect();
        let c = coverage(ring);
        assert!(c.covered * 3 < c.regions, "{}", c.covered);
        let text = c.missing_text();
        assert!(
            text.starts_with("covered only") && text.contains("the band round the y axis"),
            "{text}"
        );
        // Most of the sphere covered: the missing ranges are named.
        let mut most: Vec<[f64; 3]> = fibonacci(2000)
            .into_iter()
            .filter(|v| v[2] > -0.5)
            .collect();
        most.push([0.0, 0.0, 1.0]);
        let text = coverage(most).missing_text();
        assert!(text.starts_with("missing: -z"), "{text}");
    }

    #[test]
    fn regions_have_equal_area() {
        // Uniform points fall evenly into the regions: each holds 1/N of
        // them within the lattice's discreteness.
        let points = fibonacci(100_000);
        let cov = coverage(points.iter().copied());
        assert_eq!(cov.covered, REGIONS);
        let mut counts = [0usize; REGIONS];
        for &p in &points {
            counts[region_of(p).expect("a unit vector has a region")] += 1;
        }
        for (k, &c) in counts.iter().enumerate() {
            assert!((c as f64 - 1000.0).abs() < 30.0, "region {k} holds {c}");
        }
        assert_eq!(BANDS.iter().sum::<usize>(), REGIONS);
    }

    /// The region without the angles is the region by the angles: on
    /// random directions of every length, and on directions placed on
    /// each band's bound and each sector's edge and a few units in the
    /// last place either side (where only the angles can tell).
    #[test]
    fn the_region_without_the_angles_is_the_region_by_them() {
        use fieldcal::model::sphere::region_of_by_angles;
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut checked = 0usize;
        let mut check = |v: [f64; 3]| {
            assert_eq!(region_of(v), region_of_by_angles(v), "{v:?}");
            checked += 1;
        };
        for i in 0..400_000 {
            let v: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
            let scale = 10f64.powi(i % 61 - 30);
            check(v.map(|c: f64| c * scale));
        }
        let mut above = 0usize;
        for &count in &BANDS {
            // The band's lower bound (as sin(elevation)), and its sectors' edges.
            let bound = 1.0 - 2.0 * (above + count) as f64 / REGIONS as f64;
            above += count;
            for k in 0..=4 * count {
                let azimuth = k as f64 * std::f64::consts::TAU / (4 * count) as f64;
                for z in [bound, bound * 0.5 + 0.25, 0.0] {
                    // Both sides of the bound and of the edge, by a few
                    // units in the last place.
                    let mut z = z.clamp(-1.0, 1.0);
                    for _ in 0..4 {
                        z = z.next_up().min(1.0);
                    }
                    for _ in 0..8 {
                        let rho = (1.0 - z * z).max(0.0).sqrt();
                        let mut a = azimuth;
                        for _ in 0..4 {
                            a = a.next_down();
                        }
                        for _ in 0..8 {
                            check([rho * a.cos(), rho * a.sin(), z]);
                            a = a.next_up();
                        }
                        z = z.next_down();
                    }
                }
                // Where the margins themselves lie: the sine 1e-9 from the
                // bound's, and the azimuth 0.01 rad from an edge (the
                // arctangent's error, up to 0.0038 rad, on either side).
                let z_mid = bound * 0.5 + 0.25;
                let rho_mid = (1.0 - z_mid * z_mid).sqrt();
                for d in [
                    0.002, 0.004, 0.006, 0.008, 0.0095, 0.01, 0.0105, 0.012, 0.014,
                ] {
                    for a in [azimuth - d, azimuth + d] {
                        check([rho_mid * a.cos(), rho_mid * a.sin(), z_mid]);
                    }
                }
                for d in [0.5e-9, 0.9e-9, 1e-9, 1.1e-9, 2e-9] {
                    for z in [bound - d, bound + d] {
                        let rho = (1.0 - z * z).max(0.0).sqrt();
                        check([rho * azimuth.cos(), rho * azimuth.sin(), z.clamp(-1.0, 1.0)]);
                    }
                }
            }
        }
        for v in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [0.0, -0.0, 0.5],
            [1.0, -0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [-1.0, -0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [1e-300, -1e-300, 0.0],
            // x and y square to nothing: a band of several sectors, and
            // no azimuth to approximate.
            [-0.0, 0.0, 3e-162],
            [0.0, -0.0, 3e-162],
            [1e154, -1e154, 1e154],
            [-1e-160, 1e-160, -2e-160],
            [0.0, 0.0, 0.0],
            [f64::NAN, 0.0, 1.0],
            [f64::INFINITY, 0.0, 1.0],
        ] {
            check(v);
        }
        assert!(checked > 400_000);
    }

    #[test]
    fn region_centres_lie_in_their_region() {
        for k in 0..REGIONS {
            assert_eq!(region_of(region(k).centre), Some(k), "region {k}");
        }
    }

    #[test]
    fn upper_half_names_the_lower_half_missing() {
        let points: Vec<[f64; 3]> = fibonacci(5000).into_iter().filter(|p| p[2] > 0.0).collect();
        let cov = coverage(points);
        assert_eq!(cov.covered, 50);
        assert_eq!(cov.missing.len(), 1, "{}", cov.missing_text());
        let m = &cov.missing[0];
        assert_eq!(m.toward, "-z");
        assert_eq!(m.regions, 50);
        assert_eq!(m.azimuth_deg, None);
        assert!((m.elevation_deg.0 + 90.0).abs() < 1e-9 && m.elevation_deg.1.abs() < 1e-9);
        assert!(
            cov.missing_text()
                .contains("-z (elevation -90° to 0°, every azimuth)")
        );
    }

    #[test]
    fn ring_names_both_poles() {
        let points: Vec<[f64; 3]> = (0..360)
            .map(|d| {
                let a = (d as f64).to_radians();
                [a.cos(), a.sin(), 0.0]
            })
            .collect();
        let cov = coverage(points);
        assert_eq!(cov.covered, 17);
        let names: Vec<&str> = cov.missing.iter().map(|m| m.toward.as_str()).collect();
        assert_eq!(cov.missing.len(), 2, "{}", cov.missing_text());
        assert!(names.contains(&"+z") && names.contains(&"-z"), "{names:?}");
    }

    #[test]
    fn a_missing_octant_is_named_by_its_axes() {
        let points: Vec<[f64; 3]> = fibonacci(20_000)
            .into_iter()
            .filter(|p| !(p[0] > 0.0 && p[1] > 0.0 && p[2] < 0.0))
            .collect();
        let cov = coverage(points);
        assert_eq!(cov.missing.len(), 1, "{}", cov.missing_text());
        let m = &cov.missing[0];
        assert_eq!(m.toward, "+x+y-z");
        let (a, b) = m.azimuth_deg.expect("an octant spans a quarter turn");
        assert!(a >= 0.0 && b <= 90.0 && b > a, "{a}..{b}");
    }
}

mod still {
    use crate::common::fixtures::tumbling;
    use fieldcal::model::still::{StillError, find_still};
    use nalgebra::{Matrix3, Vector3};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal, Uniform};

    /// Static poses joined by turns, at `rate_hz`: raw = W⁻¹ r u + o +
    /// noise; the truth is the number of poses and their mean readings.
    pub(crate) struct Poses {
        pub points: Vec<[f64; 3]>,
        pub t: Vec<f64>,
        pub gyro: Vec<[f64; 3]>,
        pub truth: Vec<[f64; 3]>,
        pub pose_ranges: Vec<(usize, usize)>,
    }

    fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
        loop {
            let v = Vector3::new(
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
            );
            if v.norm() > 1e-6 {
                return v.normalize();
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub(crate) fn poses(
        directions: &[Vector3<f64>],
        hold_s: f64,
        turn_deg_s: f64,
        noise: f64,
        rate_hz: f64,
        matrix: [[f64; 3]; 3],
        offset: [f64; 3],
        seed: u64,
    ) -> Poses {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let winv = Matrix3::from_fn(|i, j| matrix[i][j]).try_inverse().unwrap();
        let o = Vector3::from(offset);
        let r = 1.0;
        let dt = 1.0 / rate_hz;
        let mut out = Poses {
            points: vec![],
            t: vec![],
            gyro: vec![],
            truth: vec![],
            pose_ranges: vec![],
        };
        let push = |out: &mut Poses, u: Vector3<f64>, rate: f64, rng: &mut ChaCha8Rng| {
            let g = Vector3::new(
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
            );
            let p = winv * (u * r) + o + g * noise;
            out.t.push(out.points.len() as f64 * dt);
            out.points.push(p.into());
            out.gyro.push([rate + 3.0, -2.0, 1.5]);
        };
        for (k, &u) in directions.iter().enumerate() {
            let start = out.points.len();
            for _ in 0..(hold_s * rate_hz) as usize {
                push(&mut out, u, 0.0, &mut rng);
            }
            out.pose_ranges.push((start, out.points.len()));
            out.truth.push((winv * (u * r) + o).into());
            if let Some(&next) = directions.get(k + 1) {
                // Turn along the great circle to the next pose.
                let angle = u.dot(&next).clamp(-1.0, 1.0).acos();
                let steps = ((angle.to_degrees() / turn_deg_s) * rate_hz)
                    .ceil()
                    .max(1.0) as usize;
                let axis = u.cross(&next);
                let axis = if axis.norm() > 1e-9 {
                    axis.normalize()
                } else {
                    random_unit(&mut rng).cross(&u).normalize()
                };
                for s in 1..steps {
                    let a = angle * s as f64 / steps as f64;
                    let rot = nalgebra::Rotation3::from_axis_angle(
                        &nalgebra::Unit::new_normalize(axis),
                        a,
                    );
                    push(&mut out, rot * u, turn_deg_s, &mut rng);
                }
            }
        }
        out
    }

    const SOFT: [[f64; 3]; 3] = [[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]];

    fn six() -> Vec<Vector3<f64>> {
        vec![
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ]
    }

    #[test]
    fn six_positions_give_six_poses() {
        let p = poses(
            &six(),
            2.0,
            90.0,
            0.005,
            100.0,
            SOFT,
            [0.04, -0.02, 0.03],
            1,
        );
        let found = find_still(&p.points, Some(&p.t), None).unwrap();
        assert_eq!(found.window, 50);
        assert_eq!(found.segments.len(), 6, "{:?}", found.segments);
        for (seg, truth) in found.segments.iter().zip(&p.truth) {
            for j in 0..3 {
                assert!((seg.mean[j] - truth[j]).abs() < 0.005, "{seg:?} {truth:?}");
            }
        }
    }

    /// Randomised sweep: 6 to 14 poses in random directions (at least 30°
    /// apart), held 0.8 to 3 s, joined by turns at 30 to 180 °/s, noise
    /// 0.1 % to 1.1 % of the field (the MPU-6050's at its widest
    /// bandwidth), 50 to 400 Hz: the pose count is found exactly, and each
    /// pose's mean within 5 noise SDs of the truth.
    #[test]
    fn randomised_poses_are_found_exactly() {
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        for seed in 0..200 {
            let count = Uniform::new_inclusive(6usize, 14).unwrap().sample(&mut rng);
            let mut dirs: Vec<Vector3<f64>> = Vec::new();
            while dirs.len() < count {
                let u = random_unit(&mut rng);
                if dirs.iter().all(|d| d.dot(&u) < 30f64.to_radians().cos()) {
                    dirs.push(u);
                }
            }
            let hold = Uniform::new(0.8, 3.0).unwrap().sample(&mut rng);
            let turn = Uniform::new(30.0, 180.0).unwrap().sample(&mut rng);
            let noise = Uniform::new(0.001, 0.011).unwrap().sample(&mut rng) / 3f64.sqrt();
            let rate = Uniform::new(50.0, 400.0).unwrap().sample(&mut rng);
            let offset = [0.05, -0.03, 0.02];
            let p = poses(&dirs, hold, turn, noise, rate, SOFT, offset, seed);
            for gyro in [None, Some(&p.gyro[..])] {
                let found = find_still(&p.points, Some(&p.t), gyro).unwrap();
                assert_eq!(
                    found.segments.len(),
                    count,
                    "seed {seed}: hold {hold} turn {turn} noise {noise} rate {rate}: {:?}",
                    found.segments
                );
                for (seg, truth) in found.segments.iter().zip(&p.truth) {
                    let tol = 5.0 * noise + 0.01;
                    for j in 0..3 {
                        assert!(
                            (seg.mean[j] - truth[j]).abs() < tol,
                            "seed {seed}: {seg:?} {truth:?}"
                        );
                    }
                }
                if gyro.is_some() {
                    let bias = found.gyro_bias_deg_s.unwrap();
                    assert!((bias[0] - 3.0).abs() < 1e-9, "{bias:?}");
                }
            }
        }
    }

    #[test]
    fn a_continuous_tumble_never_holds_still() {
        for seed in 0..50 {
            let raw = tumbling(SOFT, [0.1, 0.0, -0.1], 1.0, 0.005, 3000, seed)
                .simulate()
                .unwrap();
            // 30 s at 100 Hz: 20 turns, 240 °/s on average.
            let t: Vec<f64> = (0..raw.len()).map(|i| i as f64 * 0.01).collect();
            let err = find_still(&raw, Some(&t), None).unwrap_err();
            assert!(matches!(err, StillError::NeverStill { .. }), "{err}");
        }
    }

    #[test]
    fn the_gyro_rejects_a_slow_turn_the_readings_miss() {
        // Two poses joined by a slow turn at 15 °/s with a noisy sensor:
        // the readings of the turn spread less than the threshold over a
        // short window, the gyro does not.
        let dirs = [Vector3::z(), Vector3::x()];
        let p = poses(&dirs, 3.0, 15.0, 0.015, 100.0, SOFT, [0.0; 3], 5);
        let found = find_still(&p.points, Some(&p.t), Some(&p.gyro)).unwrap();
        assert_eq!(found.segments.len(), 2, "{:?}", found.segments);
        // Every still sample belongs to a pose.
        for i in found.indices() {
            assert!(
                p.pose_ranges.iter().any(|&(a, b)| (a..b).contains(&i)),
                "sample {i} is in the turn"
            );
        }
    }

    #[test]
    fn bad_input_is_refused() {
        let p = [[0.0, 0.0, 1.0]; 5];
        assert!(matches!(
            find_still(&p, None, None),
            Err(StillError::TooFew { found: 5, .. })
        ));
        let p = vec![[0.0, 0.0, 1.0]; 100];
        let g = vec![[0.0; 3]; 99];
        assert!(matches!(
            find_still(&p, None, Some(&g)),
            Err(StillError::GyroLength { .. })
        ));
    }
}

mod still_stream {
    use crate::common::fixtures::{Samples, six_faces};
    use fieldcal::model::still_stream::{POSE_SAMPLES, StillStream};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// Six faces in g with cross-axis terms and offsets of tens of mg.
    fn six_poses(hold_s: f64, noise: f64, rate_hz: f64, seed: u64) -> (Samples, Vec<[f64; 3]>) {
        let w = [[1.05, 0.02, 0.0], [0.02, 0.97, 0.01], [0.0, 0.01, 1.02]];
        six_faces(hold_s, rate_hz, (w, [0.04, -0.03, 0.06], 1.0, noise), seed)
    }

    #[test]
    fn six_poses_are_found_with_their_means_over_many_seeds() {
        for seed in 0..20 {
            for rate in [50.0, 100.0] {
                let noise = 0.003;
                let (samples, truth) = six_poses(2.0, noise, rate, seed);
                let mut s = StillStream::new(None);
                let mut ended = 0;
                for &(t, p) in &samples {
                    if let Some(p) = s.push(t, p) {
                        ended += 1;
                        eprintln!(
                            "pose {:.2}-{:.2} n {} spread {:.5} state {:?}",
                            p.start,
                            p.end,
                            p.count,
                            p.spread,
                            s.state()
                        );
                    }
                }
                let poses = s.poses();
                // The last pose is still being held: it counts once it
                // spans a window.
                assert_eq!(ended, 5, "seed {seed} at {rate} Hz");
                assert_eq!(poses.len(), 6, "seed {seed} at {rate} Hz: {poses:?}");
                for (p, t) in poses.iter().zip(&truth) {
                    let e = (0..3)
                        .map(|k| (p.mean[k] - t[k]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    // The mean of ≥ 1.5 s of samples: noise/√75 per axis.
                    assert!(
                        e < 5.0 * noise / 75f64.sqrt() * 3f64.sqrt(),
                        "seed {seed}: {e}"
                    );
                    assert!(
                        p.samples.len() <= 2 * POSE_SAMPLES && p.samples.len() >= POSE_SAMPLES / 2
                    );
                    // The first pose counts from the 20th window (the
                    // noise is not known before), the others from the
                    // first still window.
                    assert!(
                        p.count as f64 >= 1.2 * rate,
                        "seed {seed} at {rate} Hz: {} in {:?}",
                        p.count,
                        poses.iter().map(|p| (p.start, p.count)).collect::<Vec<_>>()
                    );
                }
            }
        }
    }

    #[test]
    fn a_sensor_that_never_rests_gives_no_pose() {
        // Turning at 60 °/s about a tilted axis, with 2 % of the field in
        // hand accelerations: no window is quiet.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut s = StillStream::new(None);
        for i in 0..3000 {
            let t = i as f64 * 0.01;
            let a = (60.0 * t).to_radians();
            let b = (23.0 * t).to_radians();
            let u = [a.cos() * b.cos(), a.sin() * b.cos(), b.sin()];
            let p = u.map(|v| {
                let g: f64 = StandardNormal.sample(&mut rng);
                v + 0.02 * g
            });
            assert!(s.push(t, p).is_none());
        }
        assert!(s.poses().is_empty());
        assert!(s.state().never_still, "{:?}", s.state());
    }

    #[test]
    fn a_gap_or_a_time_that_goes_back_ends_the_pose_and_bad_values_are_ignored() {
        let (samples, _) = six_poses(2.0, 0.003, 50.0, 1);
        let mut s = StillStream::new(None);
        // The first pose (2 s at 50 Hz), held.
        for &(t, p) in &samples[..100] {
            assert!(s.push(t, p).is_none());
        }
        assert!(s.state().still_now, "{:?}", s.state());
        assert!(s.push(f64::NAN, [0.0; 3]).is_none());
        assert!(s.push(3.0, [f64::INFINITY, 0.0, 0.0]).is_none());
        assert!(s.state().still_now, "a bad value changed nothing");
        // 2 s of silence: the pose ends there, with its samples.
        let (t, p) = samples[99];
        let pose = s.push(t + 2.0, p).expect("the gap ends the pose");
        assert!(pose.count >= 50 && pose.end <= t, "{pose:?}");
        // A new pose, then a time that goes back: it ends too.
        for k in 0..60 {
            s.push(t + 2.0 + f64::from(k) * 0.02, p);
        }
        assert!(
            s.push(t, p).is_some(),
            "a time that goes back ends the pose"
        );
        assert_eq!(s.poses().len(), 2);
        assert_eq!(s.pose_count(), 2);
        s.clear_poses();
        assert!(s.poses().is_empty());
        // A 4 kHz sensor: its window is find_still's cap of 1000 samples
        // (0.25 s), and a pose is still found.
        let mut fast = StillStream::new(Some(1.0));
        for i in 0..20_000 {
            let wobble = if i % 2 == 0 { 0.001 } else { -0.001 };
            fast.push(f64::from(i) / 4000.0, [wobble, 0.0, 1.0]);
        }
        assert_eq!(fast.pose_count(), 1);
        // Raw counts in the tens of thousands: the same poses.
        let mut big = StillStream::new(Some(16384.0));
        let mut ended = 0;
        for &(t, p) in &samples {
            ended += usize::from(big.push(t, p.map(|v| v * 16384.0 + 20000.0)).is_some());
        }
        assert_eq!(ended, 5);
        assert_eq!(big.poses().len(), 6);
    }
}

mod turn {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    use fieldcal::model::FitError;
    use fieldcal::model::turn::{CentreFrom, RADIUS_OVER_NOISE, check_turn, check_turn_of};
    use fieldcal::sample::Dataset;

    fn ring(n: usize, arc_deg: f64, r: f64, noise: f64, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let g = Normal::new(0.0, 1.0).unwrap();
        (0..n)
            .map(|i| {
                let h = (i as f64 / n as f64 * arc_deg).to_radians();
                (
                    1.2 * r * h.cos() + 300.0 + noise * g.sample(&mut rng),
                    r * h.sin() - 100.0 + noise * g.sample(&mut rng),
                )
            })
            .unzip()
    }

    fn cloud(n: usize, noise: f64, quantum: f64, seed: u64) -> (Vec<f64>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let g = Normal::new(0.0, noise).unwrap();
        let q = |v: f64| {
            if quantum > 0.0 {
                (v / quantum).round() * quantum
            } else {
                v
            }
        };
        (0..n)
            .map(|_| {
                (
                    q(-120.0 + g.sample(&mut rng)),
                    q(455.0 + g.sample(&mut rng)),
                )
            })
            .unzip()
    }

    #[test]
    fn a_noisy_ring_passes_with_its_figures() {
        let (x, y) = ring(400, 360.0, 1000.0, 10.0, 1);
        let c = check_turn(&x, &y, 300.0).unwrap();
        assert_eq!(c.centre_from, CentreFrom::Paper);
        assert!((c.centre[0] - 300.0).abs() < 5.0 && (c.centre[1] + 100.0).abs() < 5.0);
        assert!((c.noise - 10.0).abs() < 2.0, "{c:?}");
        assert!(c.spread_over_noise > 80.0, "{c:?}");
        assert_eq!(c.hole_fraction, 0.0);
        assert!(c.coverage.covered_deg > 355.0, "{c:?}");
    }

    #[test]
    fn still_clouds_are_refused_at_every_size_and_quantum() {
        for (i, n) in [12, 13, 20, 50, 200, 1000, 20_000].into_iter().enumerate() {
            for seed in 0..20 {
                for quantum in [0.0, 0.5, 2.0, 10.0] {
                    let (x, y) = cloud(n, 1.0, quantum, seed * 31 + i as u64);
                    match check_turn(&x, &y, 300.0) {
                        Err(FitError::NotTurning { ratio, .. }) => {
                            assert!(ratio < RADIUS_OVER_NOISE, "n {n} q {quantum}: {ratio}")
                        }
                        other => panic!("n {n} seed {seed} q {quantum}: {other:?}"),
                    }
                }
            }
        }
    }

    #[test]
    fn a_cloud_message_gives_its_size_centre_and_ratio() {
        let (x, y) = cloud(300, 0.2, 0.0, 3);
        let msg = check_turn(&x, &y, 300.0).unwrap_err().to_string();
        assert!(msg.starts_with("the readings form a cloud 0."), "{msg}");
        assert!(msg.contains("around (-120.0, 455.0)"), "{msg}");
        assert!(msg.contains("the sensor did not turn"), "{msg}");
        // Constant readings: no spread at all.
        let msg = check_turn(&[5.0; 20], &[7.0; 20], 300.0)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("across around (5.000, 7.000)"), "{msg}");
        assert!(msg.contains("the sensor did not turn"), "{msg}");
    }

    #[test]
    fn a_filled_disc_is_not_a_ring() {
        // A spiral that fills the disc evenly and moves smoothly, as a
        // tumble does from one sample to the next.
        let (x, y): (Vec<f64>, Vec<f64>) = (0..2000)
            .map(|i| {
                let r = 500.0 * (i as f64 / 2000.0).sqrt();
                let h = i as f64 * 0.05;
                (r * h.cos() + 40.0, r * h.sin())
            })
            .unzip();
        let data = Dataset::new("mag_x", "mag_y", None, x, y, vec![]).unwrap();
        let err = check_turn_of(&data, 300.0).unwrap_err();
        let FitError::DiscNotRing { percent, .. } = err else {
            panic!("{err:?}")
        };
        assert!((8.0..16.0).contains(&percent), "{percent}");
        let msg = err.to_string();
        assert!(msg.contains("plane of mag_x and mag_y"), "{msg}");
    }

    #[test]
    fn arcs_lines_and_few_samples_are_refused() {
        let (x, y) = ring(200, 120.0, 1000.0, 5.0, 2);
        match check_turn(&x, &y, 300.0) {
            Err(FitError::NoFullTurn { covered_deg, .. }) => {
                assert!((covered_deg - 120.0).abs() < 5.0, "{covered_deg}")
            }
            other => panic!("{other:?}"),
        }
        // The user may lower the coverage on purpose.
        assert!(check_turn(&x, &y, 100.0).is_ok());
        // A line with noise across it.
        let (x, y) = (
            (0..300).map(|i| i as f64).collect::<Vec<_>>(),
            (0..300)
                .map(|i| 0.5 * i as f64 + (i % 3) as f64)
                .collect::<Vec<_>>(),
        );
        assert!(check_turn(&x, &y, 300.0).is_err());
        let (x, y) = ring(11, 360.0, 1000.0, 0.0, 0);
        assert_eq!(
            check_turn(&x, &y, 300.0).unwrap_err(),
            FitError::TooFewToTurn {
                found: 11,
                needed: 12
            }
        );
    }

    #[test]
    fn extreme_and_non_finite_values_end_in_an_answer() {
        let (x, y) = ring(50, 360.0, 1e307, 0.0, 0);
        let x: Vec<f64> = x.iter().map(|v| v.clamp(-1.7e308, 1.7e308)).collect();
        // Finite, but their squares overflow: refused with that reason
        // (the fits after the gate square them), naming the column.
        assert!(matches!(
            check_turn(&x, &y, 300.0),
            Err(FitError::TooLarge { ref column, index: 0, .. }) if column == "x"
        ));
        // Up to the limit, the gate's own scaling still sees a turn.
        let (x, y) = ring(50, 360.0, 1e149, 0.0, 0);
        assert!(check_turn(&x, &y, 300.0).is_ok());
        let (mut x, y) = ring(50, 360.0, 1.0, 0.0, 0);
        x[7] = f64::NAN;
        assert!(matches!(
            check_turn(&x, &y, 300.0),
            Err(FitError::NonFiniteReading { index: 7, .. })
        ));
    }
}

mod vertical {
    use fieldcal::model::vertical::{
        DEFAULT_TAU_S, VerticalError, fuse_vertical, rate_about_vertical,
    };
    use nalgebra::Vector3;
    use nalgebra::{Rotation3, Unit};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Uniform};

    /// A hand-held board turning about the vertical while it wobbles by
    /// up to `wobble_deg`, its accelerometer reading gravity (1 g up) plus
    /// the hand's accelerations (`hand_g` at 1.5 Hz and 4 Hz) and noise,
    /// its gyro the true body rates plus `bias_deg_s` and noise. Returns
    /// the times, accel, rates (rad/s) and the true vertical in the body.
    #[allow(clippy::type_complexity)]
    fn hand_turn(
        seed: u64,
        wobble_deg: f64,
        hand_g: f64,
        bias_deg_s: [f64; 3],
    ) -> (Vec<f64>, Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (dt, n) = (0.01, 2000);
        let phase: Vec<f64> = (0..6)
            .map(|_| uniform(&mut rng, std::f64::consts::TAU))
            .collect();
        let attitude = |t: f64| {
            let yaw = 0.6 * t; // rad/s: a turn in ~10 s
            let roll = wobble_deg.to_radians() * (0.7 * t + phase[0]).sin();
            let pitch = wobble_deg.to_radians() * (0.45 * t + phase[1]).cos();
            Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
                * Rotation3::from_axis_angle(&Vector3::y_axis(), pitch)
                * Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
        };
        let (mut ts, mut acc, mut rates, mut truth) = (vec![], vec![], vec![], vec![]);
        for k in 0..n {
            let t = k as f64 * dt;
            let r = attitude(t);
            // Body rates from the attitude's change over a small step.
            let h = 1e-5;
            let dr = r.inverse() * attitude(t + h);
            let w = dr.scaled_axis() / h;
            let up_body = r.inverse() * Vector3::z();
            let hand_world = Vector3::new(
                (2.0 * std::f64::consts::PI * 1.5 * t + phase[2]).sin(),
                (2.0 * std::f64::consts::PI * 4.0 * t + phase[3]).sin(),
                0.5 * (2.0 * std::f64::consts::PI * 1.5 * t + phase[4]).cos(),
            ) * hand_g;
            let f = up_body + r.inverse() * hand_world;
            let noise = |rng: &mut ChaCha8Rng, s: f64| {
                Vector3::new(
                    uniform(rng, s) * 2.0 - s,
                    uniform(rng, s) * 2.0 - s,
                    uniform(rng, s) * 2.0 - s,
                )
            };
            let f = f + noise(&mut rng, 0.005);
            let w = w + Vector3::from(bias_deg_s).map(f64::to_radians) + noise(&mut rng, 0.002);
            ts.push(t);
            acc.push([f.x, f.y, f.z]);
            rates.push([w.x, w.y, w.z]);
            truth.push([up_body.x, up_body.y, up_body.z]);
        }
        (ts, acc, rates, truth)
    }

    /// Uniform on [0, top).
    fn uniform(rng: &mut ChaCha8Rng, top: f64) -> f64 {
        Uniform::new(0.0, top).unwrap().sample(rng)
    }

    fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
        let (a, b) = (Vector3::from(a), Vector3::from(b));
        a.angle(&b).to_degrees()
    }

    fn rms(v: &[f64]) -> f64 {
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    }

    /// After the first 3 τ (the filter's start-up), the fused vertical's
    /// rms error and the accelerometer's own.
    fn errors(seed: u64, hand_g: f64, bias: [f64; 3], tau: f64) -> (f64, f64) {
        let (t, acc, rates, truth) = hand_turn(seed, 15.0, hand_g, bias);
        let up = fuse_vertical(&t, &acc, &rates, tau).unwrap();
        let skip = (3.0 * tau / 0.01) as usize;
        let fused: Vec<f64> = (skip..t.len())
            .map(|i| angle_deg(up[i], truth[i]))
            .collect();
        let alone: Vec<f64> = (skip..t.len())
            .map(|i| angle_deg(acc[i], truth[i]))
            .collect();
        (rms(&fused), rms(&alone))
    }

    #[test]
    fn the_gyro_removes_the_hands_accelerations_from_the_vertical() {
        // A hand's 0.1 g tilts the accelerometer's vertical by several
        // degrees; the fused one stays within a degree, over many seeds.
        for seed in 0..30 {
            let (fused, alone) = errors(seed, 0.1, [0.0; 3], DEFAULT_TAU_S);
            assert!(alone > 3.0, "seed {seed}: accelerometer alone {alone:.2}°");
            assert!(
                fused < 1.0,
                "seed {seed}: fused {fused:.2}° (alone {alone:.2}°)"
            );
        }
    }

    #[test]
    fn a_gyro_bias_tilts_the_vertical_by_about_bias_times_tau() {
        // 1 °/s on x and y: the vertical's error stays within b·τ·√2 and
        // the bound grows with τ, as the module's text says.
        for seed in 0..20 {
            for tau in [0.5, 1.0, 2.0] {
                let (fused, _) = errors(seed, 0.0, [1.0, 1.0, 0.0], tau);
                let bound = 1.0 * tau * 2f64.sqrt();
                assert!(
                    fused <= bound * 1.1 + 0.3,
                    "seed {seed} τ {tau}: {fused:.2}° > {bound:.2}°"
                );
            }
        }
    }

    #[test]
    fn a_still_board_gives_the_accelerometers_vertical() {
        let n = 500;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.02).collect();
        let g = [0.1, -0.2, 0.97];
        let up = fuse_vertical(&t, &vec![g; n], &vec![[0.0; 3]; n], 1.0).unwrap();
        let expect = Vector3::from(g).normalize();
        for u in &up {
            assert!((Vector3::from(*u) - expect).norm() < 1e-12);
        }
    }

    #[test]
    fn missing_readings_gaps_and_bad_time_restart_or_carry() {
        let n = 100;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.01).collect();
        let mut acc = vec![[0.0, 0.0, 1.0]; n];
        let mut rates = vec![[0.0; 3]; n];
        acc[0] = [f64::NAN; 3]; // no vertical yet
        acc[10] = [0.0; 3]; // carried by the gyro
        rates[20] = [f64::NAN, 0.0, 0.0]; // restart from the accelerometer
        let up = fuse_vertical(&t, &acc, &rates, 1.0).unwrap();
        assert!(up[0].iter().all(|v| v.is_nan()));
        for u in &up[1..] {
            assert!((Vector3::from(*u) - Vector3::z()).norm() < 1e-12);
        }
        // A gap longer than τ: the gyro's angle is unknown, the vertical
        // restarts from the accelerometer.
        let t = vec![0.0, 0.01, 5.0];
        let acc = vec![[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
        let up = fuse_vertical(&t, &acc, &[[0.0, 3.0, 0.0]; 3], 1.0).unwrap();
        assert_eq!(up[2], [1.0, 0.0, 0.0]);
        // Time that goes back restarts too.
        let t = vec![0.0, 0.01, 0.005];
        let up = fuse_vertical(&t, &acc, &[[0.0, 0.0, 0.0]; 3], 1.0).unwrap();
        assert_eq!(up[2], [1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_gyro_turns_the_vertical_between_readings() {
        // A board rolling at 90 °/s about x with its accelerometer silent
        // (zero): after one second the vertical has turned by 90°.
        let n = 1001;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.001).collect();
        let mut acc = vec![[0.0; 3]; n];
        acc[0] = [0.0, 0.0, 1.0];
        let w = [std::f64::consts::FRAC_PI_2, 0.0, 0.0];
        let up = fuse_vertical(&t, &acc, &vec![w; n], 1.0).unwrap();
        let expect = Rotation3::from_axis_angle(
            &Unit::new_normalize(Vector3::x()),
            -std::f64::consts::FRAC_PI_2,
        ) * Vector3::z();
        assert!(
            (Vector3::from(up[n - 1]) - expect).norm() < 1e-3,
            "{:?} vs {expect:?}",
            up[n - 1]
        );
    }

    #[test]
    fn bad_arguments_are_refused() {
        assert!(matches!(
            fuse_vertical(&[0.0], &[[0.0, 0.0, 1.0]], &[[0.0; 3]], 0.0),
            Err(VerticalError::Tau { .. })
        ));
        assert!(matches!(
            fuse_vertical(&[0.0], &[[0.0, 0.0, 1.0]], &[[0.0; 3]], f64::NAN),
            Err(VerticalError::Tau { .. })
        ));
        assert!(matches!(
            fuse_vertical(&[0.0, 1.0], &[[0.0, 0.0, 1.0]], &[[0.0; 3]], 1.0),
            Err(VerticalError::Lengths { .. })
        ));
    }

    #[test]
    fn the_rate_about_the_vertical_is_the_dot_product() {
        let r = rate_about_vertical(
            &[[1.0, 2.0, 3.0], [1.0, 0.0, 0.0]],
            &[[0.0, 0.0, 1.0], [f64::NAN; 3]],
        );
        assert_eq!(r[0], 3.0);
        assert!(r[1].is_nan());
    }
}

mod trust {
    use fieldcal::model::trust::*;

    const RATE_HZ: f64 = 20.0;

    /// The limits of a calibration of rms `noise` whose heading check found
    /// a gyro of scale 1 and no bias.
    fn gyro_limits(noise: f64) -> TrustLimits {
        TrustLimits::from_rms(
            noise,
            None,
            Some(GyroModel {
                scale: 1.0,
                bias_deg_s: 0.0,
            }),
        )
    }

    /// A sensor turning at `deg_s` with a gyro that reads it, its heading
    /// and field disturbed by `disturb(t) -> (field factor, heading offset)`.
    fn run(
        seconds: f64,
        deg_s: f64,
        noise: f64,
        disturb: impl Fn(f64) -> (f64, f64),
    ) -> Vec<(f64, Verdict)> {
        let limits = gyro_limits(noise);
        let mut monitor = TrustMonitor::new(limits);
        let n = (seconds * RATE_HZ) as usize;
        (0..n)
            .map(|k| {
                let t = k as f64 / RATE_HZ;
                // Deterministic noise of about `noise` rms.
                let wobble = noise * 1.2 * ((k as f64) * 2.39).sin();
                let (factor, offset) = disturb(t);
                let obs = Observation {
                    time: t,
                    field_ratio: (1.0 + wobble) * factor,
                    heading_deg: (deg_s * t + offset + wobble.to_degrees()).rem_euclid(360.0),
                    gyro_deg_s: Some(deg_s),
                    dip_deg: None,
                    across: None,
                    tilt_deg: None,
                };
                (t, monitor.check(obs))
            })
            .collect()
    }

    fn distrusted_in(v: &[(f64, Verdict)], from: f64, to: f64) -> (usize, usize) {
        let inside: Vec<_> = v.iter().filter(|(t, _)| *t >= from && *t < to).collect();
        let bad = inside.iter().filter(|(_, v)| !v.trusted).count();
        (bad, inside.len())
    }

    #[test]
    fn a_quiet_sensor_turning_or_still_is_always_trusted() {
        for deg_s in [0.0, 18.0, -90.0] {
            let v = run(120.0, deg_s, 0.005, |_| (1.0, 0.0));
            assert_eq!(distrusted_in(&v, 0.0, 1e9).0, 0, "{deg_s} °/s");
        }
    }

    #[test]
    fn a_field_five_percent_low_is_distrusted_at_once_and_trusted_after() {
        let v = run(60.0, 18.0, 0.005, |t| {
            if (20.0..35.0).contains(&t) {
                (0.95, 0.0)
            } else {
                (1.0, 0.0)
            }
        });
        let (bad, all) = distrusted_in(&v, 20.0, 35.0);
        assert_eq!(bad, all, "every disturbed reading is distrusted");
        assert_eq!(distrusted_in(&v, 35.2, 60.0).0, 0);
        assert_eq!(distrusted_in(&v, 0.0, 20.0).0, 0);
        let reason = &v.iter().find(|(t, _)| *t >= 20.0).unwrap().1.reasons[0];
        assert!(
            reason.contains("% below the calibration's r (limit 2.5 %: 5 σ"),
            "{reason}"
        );
    }

    #[test]
    fn a_heading_swing_the_gyro_did_not_see_is_distrusted_while_it_lasts() {
        // 160° of swing for 15 s, the field unchanged.
        let v = run(60.0, 0.0, 0.005, |t| {
            if (20.0..35.0).contains(&t) {
                (1.0, 160.0)
            } else {
                (1.0, 0.0)
            }
        });
        let (bad, all) = distrusted_in(&v, 20.0, 35.0);
        assert_eq!(bad, all);
        assert_eq!(distrusted_in(&v, 35.0, 60.0).0, 0);
        assert_eq!(distrusted_in(&v, 0.0, 20.0).0, 0);
    }

    /// A reading the gyro cannot check (no rate: a 3-axis compass pitched
    /// too far, a stale gyro) in a swing the gyro caught does not end its
    /// distrust: the gyro's reference is lost, and trust returns only once
    /// the heading has agreed with the gyro for a whole window again. A
    /// gap while trusted changes nothing.
    #[test]
    fn a_reading_without_a_rate_does_not_end_a_distrust_the_gyro_found() {
        let limits = gyro_limits(0.005);
        let mut m = TrustMonitor::new(limits);
        let mut verdicts = Vec::new();
        for k in 0..(40.0 * RATE_HZ) as usize {
            let t = k as f64 / RATE_HZ;
            let swing = if (20.0..35.0).contains(&t) { 60.0 } else { 0.0 };
            // No rate at 10 s and at 25 s.
            let gap = k == 200 || k == 500;
            let v = m.check(Observation {
                time: t,
                field_ratio: 1.0,
                heading_deg: swing,
                gyro_deg_s: (!gap).then_some(0.0),
                dip_deg: None,
                across: None,
                tilt_deg: None,
            });
            verdicts.push((t, v));
        }
        assert_eq!(distrusted_in(&verdicts, 0.0, 20.0).0, 0);
        // Through the gap and the 2 s of agreement after it.
        assert_eq!(distrusted_in(&verdicts, 20.0, 27.0), (140, 140));
        let (gap, after) = (&verdicts[500].1, &verdicts[521].1);
        assert!(
            gap.reasons[0]
                .starts_with("the heading cannot be checked against the gyro at this reading"),
            "{gap:?}"
        );
        assert!(
            after.reasons[0].starts_with(
                "the heading was off the gyro's when the gyro lost it, and has agreed with it again for 1.0 s of the 2 s"
            ),
            "{after:?}"
        );
        // Then the swing, steady, is beyond what the gyro can tell.
        assert_eq!(distrusted_in(&verdicts, 27.1, 35.0).0, 0);
    }

    #[test]
    fn a_twenty_degree_swing_while_turning_is_flagged_within_a_reading() {
        let v = run(40.0, 30.0, 0.005, |t| {
            if (10.0..12.0).contains(&t) {
                (1.0, 20.0)
            } else {
                (1.0, 0.0)
            }
        });
        let (bad, all) = distrusted_in(&v, 10.0, 12.0);
        assert!(bad * 100 >= all * 99, "{bad} of {all}");
        assert_eq!(distrusted_in(&v, 12.0, 40.0).0, 0);
    }

    #[test]
    fn a_still_sensor_whose_gyro_warms_is_followed_not_flagged() {
        // The gyro's bias walks from 0 to 3 °/s over ten minutes.
        let limits = gyro_limits(0.005);
        let mut m = TrustMonitor::new(limits);
        for k in 0..(600 * 20) {
            let t = k as f64 / RATE_HZ;
            let v = m.check(Observation {
                time: t,
                field_ratio: 1.0,
                heading_deg: 42.0,
                gyro_deg_s: Some(3.0 * t / 600.0),
                dip_deg: None,
                across: None,
                tilt_deg: None,
            });
            assert!(v.trusted, "{t}: {:?}", v.reasons);
        }
    }

    #[test]
    fn counts_and_the_longest_stretch_are_kept() {
        let limits = TrustLimits::from_rms(0.005, None, None);
        let mut m = TrustMonitor::new(limits);
        for k in 0..100 {
            let t = k as f64 * 0.05;
            let ratio = if (20..60).contains(&k) { 1.2 } else { 1.0 };
            m.check(Observation {
                time: t,
                field_ratio: ratio,
                heading_deg: 10.0,
                gyro_deg_s: None,
                dip_deg: None,
                across: None,
                tilt_deg: None,
            });
        }
        let c = m.counts();
        assert_eq!((c.trusted, c.distrusted), (60, 40));
        assert!((c.longest_distrusted_s - 39.0 * 0.05).abs() < 1e-9);
    }

    /// The dip against the calibration's, 1° spread: distrusted beyond
    /// 5 σ, trusted again within 3 σ, and left out for a limit that is not
    /// a dip.
    #[test]
    fn the_dip_is_distrusted_beyond_five_sigma_and_trusted_again_within_three() {
        let limits = TrustLimits::from_rms(0.001, None, None).with_dip(60.0, 1.0);
        let mut m = TrustMonitor::new(limits);
        let at = |t: f64, dip: f64| Observation {
            time: t,
            field_ratio: 1.0,
            heading_deg: 0.0,
            gyro_deg_s: None,
            dip_deg: Some(dip),
            across: None,
            tilt_deg: None,
        };
        assert!(m.check(at(0.0, 64.9)).trusted);
        assert!(m.check(at(0.1, 55.1)).trusted);
        let v = m.check(at(0.2, 65.1));
        assert!(!v.trusted);
        assert_eq!(
            v.reasons,
            [
                "the dip is 65.1° where the calibration measured 60.0° (+5.1°, limit 5.0°: 5 σ of its spread)"
            ]
        );
        let v = m.check(at(0.3, 63.5));
        assert!(!v.trusted, "within 5 σ but not 3 σ: still distrusted");
        assert!(
            v.reasons[0].ends_with("3 σ of its spread, trusted again within it)"),
            "{v:?}"
        );
        assert!(m.check(at(0.4, 62.9)).trusted);
        // No dip this reading (no fresh accelerometer): not checked.
        assert!(
            m.check(Observation {
                dip_deg: None,
                across: None,
                tilt_deg: None,
                ..at(0.5, 0.0)
            })
            .trusted
        );
        // The spread is held to what the field's noise gives (2 % rms:
        // 1.15°), and a limit that is not a dip is left out.
        let l = TrustLimits::from_rms(0.02, None, None).with_dip(60.0, 0.0);
        assert!((l.dip.unwrap().sigma - 0.02f64.to_degrees()).abs() < 1e-12);
        for (median, spread) in [
            (f64::NAN, 1.0),
            (95.0, 1.0),
            (60.0, f64::INFINITY),
            (60.0, -1.0),
        ] {
            assert_eq!(
                TrustLimits::from_rms(0.01, None, None)
                    .with_dip(median, spread)
                    .dip,
                None
            );
        }
    }

    /// A 2-axis compass's tilt against its calibration's attitude: beyond
    /// 5 σ of the rotation's spread (held to the accelerometer's noise)
    /// distrusted, trusted again within 3 σ; with the WMM's dip, the limit
    /// widens to the tilt at which the heading errs 5 σ, and only then.
    #[test]
    fn a_tilt_beyond_five_sigma_is_distrusted_and_the_dip_widens_the_limit_where_the_heading_allows()
     {
        use fieldcal::model::trust::{MIN_TILT_SIGMA_DEG, TiltLimit};
        // A level turntable: the spread is the accelerometer's floor.
        let floor = TrustLimits::from_rms(0.001, None, None).with_tilt(0.02, None);
        assert_eq!(
            floor.tilt,
            Some(TiltLimit {
                sigma_deg: MIN_TILT_SIGMA_DEG,
                dip_deg: None
            })
        );
        // A quiet compass (heading σ 0.115°): 5 σ of heading at a dip of
        // 65° tolerate asin(tan 0.573° / tan 65°) = 0.267° of tilt, less
        // than the rotation's own 5 × 0.3°: the spread stays the limit.
        let quiet = TrustLimits::from_rms(0.002, None, None).with_tilt(0.3, Some(65.0));
        assert_eq!(
            quiet.tilt.map(|t| (t.sigma_deg, t.dip_deg)),
            Some((0.3, None))
        );
        // A noisy one (heading σ 1.146°): asin(tan 5.73° / tan 65°) = 2.681°.
        let noisy = TrustLimits::from_rms(0.02, None, None).with_tilt(0.3, Some(65.0));
        let t = noisy.tilt.unwrap();
        assert!((t.sigma_deg - 2.681 / 5.0).abs() < 1e-3, "{t:?}");
        assert_eq!(t.dip_deg, Some(65.0));
        // Not finite: no check.
        assert_eq!(quiet.with_tilt(f64::NAN, None).tilt, None);

        let mut m = TrustMonitor::new(floor);
        let at = |t: f64, tilt: f64| Observation {
            time: t,
            field_ratio: 1.0,
            heading_deg: 0.0,
            gyro_deg_s: None,
            dip_deg: None,
            across: None,
            tilt_deg: Some(tilt),
        };
        assert!(m.check(at(0.0, 0.49)).trusted);
        let v = m.check(at(0.1, 2.0));
        assert_eq!(
            v.reasons,
            [
                "the compass is tilted 2.0° from the attitude it was calibrated in (limit 0.5°: 5 σ of its tilt over the calibration's rotation)"
            ]
        );
        let v = m.check(at(0.2, 0.4));
        assert!(!v.trusted, "within 5 σ but not 3 σ: still distrusted");
        assert!(v.reasons[0].ends_with("trusted again within it)"), "{v:?}");
        assert!(m.check(at(0.3, 0.29)).trusted);
        let mut wide = TrustMonitor::new(noisy);
        let v = wide.check(at(0.0, 3.0));
        assert_eq!(
            v.reasons,
            [
                "the compass is tilted 3.0° from the attitude it was calibrated in (limit 2.7°: the tilt at which its heading errs 5 σ of its noise at the WMM's dip of 65.0°)"
            ]
        );
    }

    /// The attitude of a rotation: the vertical of its accelerometer's
    /// readings, and the tilt's spread about it along one axis (a
    /// constant 1° tilt all round is a median tilt of 1°).
    #[test]
    fn the_level_of_a_rotation_is_its_median_vertical_and_its_tilt_spread() {
        use fieldcal::model::level::{RAYLEIGH_MEDIAN, level_of};
        let tilt = 1f64.to_radians();
        let mut accels: Vec<[f64; 3]> = (0..36)
            .map(|k| {
                let a = f64::from(k) * 10f64.to_radians();
                // 0.98 g: the size does not matter, only the direction.
                [
                    0.98 * tilt.sin() * a.cos(),
                    0.98 * tilt.sin() * a.sin(),
                    0.98 * tilt.cos(),
                ]
            })
            .collect();
        // A jerk of the hand throws one far off; a dropped row is zero.
        accels.push([1.0, 0.0, 0.0]);
        accels.push([0.0, 0.0, 0.0]);
        let level = level_of(&accels).unwrap();
        assert!((level.up[2] - 1.0).abs() < 1e-4, "{level:?}");
        assert_eq!(level.n, 37);
        assert!(
            (level.tilt_sd_deg - 1.0 / RAYLEIGH_MEDIAN).abs() < 1e-3,
            "{level:?}"
        );
        assert_eq!(level_of(&[]), None);
        assert_eq!(level_of(&[[0.0; 3], [f64::NAN, 1.0, 0.0]]), None);
    }

    #[test]
    fn a_reading_out_of_order_or_not_finite_is_distrusted() {
        let mut m = TrustMonitor::new(TrustLimits::from_rms(0.01, None, None));
        let ok = Observation {
            time: 1.0,
            field_ratio: 1.0,
            heading_deg: 0.0,
            gyro_deg_s: None,
            dip_deg: None,
            across: None,
            tilt_deg: None,
        };
        assert!(m.check(ok).trusted);
        assert!(!m.check(Observation { time: 0.5, ..ok }).trusted);
        assert!(
            !m.check(Observation {
                field_ratio: f64::NAN,
                ..ok
            })
            .trusted
        );
        assert!(m.check(Observation { time: 1.05, ..ok }).trusted);
    }

    /// A 2-axis reading's field ratio for the check, from the squares on
    /// nearly every reading, gives every verdict and message that
    /// `hypot`'s ratio gives: across sizes from 1e-3 to 1e6, at ratios
    /// about each bound to a few ulp, trusted and distrusted; and it is
    /// `hypot`'s own near a bound, beyond it, and where the squares leave
    /// f64's range.
    #[test]
    fn the_plane_field_ratio_decides_as_hypot_does() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let trusting = TrustMonitor::new(TrustLimits::from_rms(0.01, None, None));
        let mut distrusting = trusting.clone();
        let far = Observation {
            time: 0.0,
            field_ratio: 1.5,
            heading_deg: 0.0,
            gyro_deg_s: None,
            dip_deg: None,
            across: None,
            tilt_deg: None,
        };
        assert!(!distrusting.check(far).trusted);
        let mut near_a_bound = 0;
        for k in 0..200_000 {
            let (monitor, bound) = if k % 2 == 0 {
                (&trusting, ENTER_SIGMAS * 0.01)
            } else {
                (&distrusting, LEAVE_SIGMAS * 0.01)
            };
            let r = 10f64.powf(rng.random_range(-3.0..6.0));
            let e = match k % 4 {
                0 | 1 => bound * (1.0 + f64::from(rng.random_range(-8i32..=8)) * 1e-15),
                _ => rng.random_range(-2.0 * bound..2.0 * bound),
            } * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let (x, y) = (r * (1.0 + e) * angle.cos(), r * (1.0 + e) * angle.sin());
            let exact = x.hypot(y) / r;
            let ratio = monitor.plane_field_ratio([x, y], r);
            if ((exact - 1.0).abs() - bound).abs() < 1e-13 || (exact - 1.0).abs() > bound {
                near_a_bound += 1;
                assert_eq!(ratio.to_bits(), exact.to_bits(), "{x}, {y}, r {r}");
            }
            let obs = |field_ratio| Observation {
                time: 1.0,
                field_ratio,
                ..far
            };
            let (mut a, mut b) = (monitor.clone(), monitor.clone());
            assert_eq!(a.check(obs(ratio)), b.check(obs(exact)), "{x}, {y}, r {r}");
        }
        assert!(near_a_bound > 100_000, "{near_a_bound}");
        // Squares that underflow (true ratio 10, beyond a bound of 1.5):
        // √(x² + y²) would be 0, within it. (Both range checks keep it
        // from the squares: r is below theirs too.)
        let wide = TrustMonitor::new(TrustLimits::from_rms(0.3, None, None));
        let (x, r) = (1e-170, 1e-171);
        assert_eq!(wide.plane_field_ratio([x, 0.0], r), x.hypot(0.0) / r);
        // Squares that overflow: hypot's ratio, within its bound.
        assert_eq!(
            wide.plane_field_ratio([1e200, 1e200], 1.5e200),
            1e200f64.hypot(1e200) / 1.5e200
        );
    }
}

/// The trust monitor's thresholds on randomised sensors: quiet ones are
/// not flagged, disturbed ones are, over a sweep of noise, gyro and motion.
mod trust_sweep {
    use fieldcal::model::trust::{GyroModel, Observation, TrustLimits, TrustMonitor};

    /// xorshift64*: deterministic, so the sweep is the same on every run.
    pub(super) struct Rng(pub(super) u64);
    impl Rng {
        pub(super) fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }
        pub(super) fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.next()
        }
        /// A standard normal draw (Box–Muller).
        pub(super) fn normal(&mut self) -> f64 {
            let u = self.next().max(1e-300);
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * self.next()).cos()
        }
    }

    struct Scenario {
        noise: f64,
        scale: f64,
        rate_deg_s: f64,
        gyro_noise: f64,
        bias_error: f64,
    }

    fn scenario(rng: &mut Rng, max_noise: f64) -> Scenario {
        Scenario {
            // |corrected|/r noise: 0.1 % to `max_noise` (a good HMC5883L
            // turn is about 0.3 %, a hand-held one 3 %).
            noise: rng.uniform(0.001, max_noise),
            scale: if rng.next() < 0.5 { 1.0 } else { -1.0 },
            rate_deg_s: if rng.next() < 0.3 {
                0.0
            } else {
                rng.uniform(-90.0, 90.0)
            },
            // MPU-6050 rate noise: 0.005 °/s/√Hz, about 0.02–0.1 °/s at 20 Hz.
            gyro_noise: rng.uniform(0.01, 0.1),
            // What the heading check's bias missed, and a slow walk on top.
            bias_error: rng.uniform(-0.05, 0.05),
        }
    }

    /// Runs `s` for `seconds` at 20 Hz; `disturb(t) -> (field factor,
    /// heading swing)`. Returns each reading's time and whether it was
    /// trusted.
    fn run(
        s: &Scenario,
        rng: &mut Rng,
        seconds: f64,
        disturb: &dyn Fn(f64) -> (f64, f64),
    ) -> Vec<(f64, bool)> {
        let gyro = GyroModel {
            scale: s.scale,
            bias_deg_s: 0.0,
        };
        let limits = TrustLimits::from_rms(s.noise, Some(s.noise.to_degrees()), Some(gyro));
        let mut monitor = TrustMonitor::new(limits);
        let n = (seconds * 20.0) as usize;
        (0..n)
            .map(|k| {
                let t = k as f64 / 20.0;
                let (factor, swing) = disturb(t);
                let heading = s.rate_deg_s * t + swing + s.noise.to_degrees() * rng.normal();
                let walk = 0.02 * (t / 60.0).sin();
                let obs = Observation {
                    time: t,
                    field_ratio: factor * (1.0 + s.noise * rng.normal()),
                    heading_deg: heading.rem_euclid(360.0),
                    gyro_deg_s: Some(
                        s.rate_deg_s / s.scale + s.bias_error + walk + s.gyro_noise * rng.normal(),
                    ),
                    dip_deg: None,
                    across: None,
                    tilt_deg: None,
                };
                (t, monitor.check(obs).trusted)
            })
            .collect()
    }

    #[test]
    fn quiet_sensors_are_not_flagged_over_a_randomised_sweep() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let (mut readings, mut flagged) = (0usize, 0usize);
        for _ in 0..200 {
            let s = scenario(&mut rng, 0.03);
            let v = run(&s, &mut rng, 120.0, &|_| (1.0, 0.0));
            readings += v.len();
            let bad = v.iter().filter(|(_, ok)| !ok).count();
            assert!(
                bad <= 1,
                "{bad} flagged at noise {}, rate {}",
                s.noise,
                s.rate_deg_s
            );
            flagged += bad;
        }
        // 5 σ: about 6e-7 of Gaussian readings; allow ten times that.
        assert!(
            (flagged as f64) < 6e-6 * readings as f64 + 1.0,
            "{flagged} of {readings}"
        );
    }

    #[test]
    fn a_magnet_of_five_percent_or_a_twenty_degree_swing_is_flagged_at_once() {
        let mut rng = Rng(0x2545_f491_4f6c_dd1d);
        for case in 0..200 {
            // 5 σ of the noise must stay below the 5 % to be found: noise
            // up to 0.8 %.
            let s = scenario(&mut rng, 0.008);
            let (field, swing) = if case % 2 == 0 {
                (1.0 + if rng.next() < 0.5 { -0.05 } else { 0.05 }, 0.0)
            } else {
                (1.0, if rng.next() < 0.5 { -20.0 } else { 20.0 })
            };
            let from = rng.uniform(30.0, 60.0);
            let v = run(&s, &mut rng, 90.0, &|t| {
                if (from..from + 5.0).contains(&t) {
                    (field, swing)
                } else {
                    (1.0, 0.0)
                }
            });
            let inside: Vec<bool> = v
                .iter()
                .filter(|(t, _)| (from..from + 5.0).contains(t))
                .map(|&(_, ok)| ok)
                .collect();
            let caught = inside.iter().filter(|ok| !**ok).count();
            assert!(
                caught * 100 >= inside.len() * 99,
                "case {case}: {caught} of {} flagged (noise {}, field {field}, swing {swing})",
                inside.len(),
                s.noise
            );
            // Within 0.2 s: one of the first four readings at 20 Hz.
            assert!(
                inside.iter().take(4).any(|ok| !ok),
                "case {case}: not flagged within 0.2 s"
            );
        }
    }
}

/// The watch's thresholds on a randomised sweep: two rotations of the same
/// sensor are never called stale; a permanent magnet of 5 % of the field
/// between them is, on the second.
mod watch_sweep {
    use fieldcal::model::calibration::Calibration;
    use fieldcal::model::fit::{FitOptions, fit_paper};
    use fieldcal::model::watch::{self, Refit};

    use super::trust_sweep::Rng;

    struct Sensor {
        gain: f64,
        offset: [f64; 2],
        field: f64,
        noise: f64,
        samples: usize,
    }

    /// One turn of `s` with `extra` added to its offset.
    fn rotation(s: &Sensor, extra: [f64; 2], rng: &mut Rng) -> (Vec<f64>, Vec<f64>) {
        let phase = rng.uniform(0.0, 360.0);
        (0..s.samples)
            .map(|k| {
                let h = (phase + 360.0 * k as f64 / s.samples as f64).to_radians();
                (
                    s.offset[0]
                        + extra[0]
                        + s.gain * s.field * h.cos()
                        + s.noise * s.field * rng.normal(),
                    s.offset[1] + extra[1] + s.field * h.sin() + s.noise * s.field * rng.normal(),
                )
            })
            .unzip()
    }

    fn fitted(x: &[f64], y: &[f64]) -> (Calibration, Refit) {
        let report = fit_paper(x, y, &FitOptions::default(), &mut |_| {}).unwrap();
        let refit = watch::paper_refit(x, y, &report);
        let calibration = Calibration {
            sensor: "compass".into(),
            id: 1,
            model: "offset+scale".into(),
            params: report.calibration,
            rms: report.rms,
            coverage_deg: report.coverage.covered_deg,
            n: report.n,
            time: 0.0,
            terms: Default::default(),
            ellipsoid: None,
            se: watch::se_map(&refit.params),
            parent: None,
            history: Vec::new(),
            gyro: None,
            dip: None,
            across: None,
            level: None,
        };
        (calibration, refit)
    }

    /// Whether the second turn shows the first's calibration stale.
    fn stale(first: (&[f64], &[f64]), second: (&[f64], &[f64])) -> bool {
        let (stored, _) = fitted(first.0, first.1);
        let (now, refit) = fitted(second.0, second.1);
        let error = watch::heading_error_deg(
            |x, y| stored.apply(x, y),
            |x, y| now.apply(x, y),
            second.0,
            second.1,
        );
        watch::compare(&stored, &refit, error).stale()
    }

    #[test]
    fn the_same_sensor_is_never_stale_and_a_magnet_always_is() {
        let mut rng = Rng(0x5eed_cafe_f00d_0001);
        let (mut false_alarms, mut missed) = (0, 0);
        for _ in 0..300 {
            let field = rng.uniform(0.2, 2000.0);
            let s = Sensor {
                gain: rng.uniform(0.7, 1.4),
                offset: [
                    rng.uniform(-2.0, 2.0) * field,
                    rng.uniform(-2.0, 2.0) * field,
                ],
                field,
                // 0.1 % (a good sensor) to 1 % of the field.
                noise: rng.uniform(0.001, 0.01),
                samples: rng.uniform(60.0, 800.0) as usize,
            };
            let (x1, y1) = rotation(&s, [0.0; 2], &mut rng);
            let (x2, y2) = rotation(&s, [0.0; 2], &mut rng);
            false_alarms += usize::from(stale((&x1, &y1), (&x2, &y2)));
            let angle = rng.uniform(0.0, std::f64::consts::TAU);
            let magnet = [0.05 * field * angle.cos(), 0.05 * field * angle.sin()];
            let (x3, y3) = rotation(&s, magnet, &mut rng);
            missed += usize::from(!stale((&x1, &y1), (&x3, &y3)));
        }
        eprintln!("watch sweep: {false_alarms} false alarms, {missed} missed of 300");
        assert_eq!(false_alarms, 0, "the same sensor called stale");
        assert!(missed <= 3, "{missed} of 300 magnets missed");
    }

    /// The heading error two corrections disagree by, the largest over a
    /// rotation, is that of both `atan2`s at every sample, to the bit:
    /// corrections that differ by a little (a later rotation's refit) and
    /// by more than 90°, at sizes from 1e-3 to 1e6, with samples that are
    /// not finite.
    #[test]
    fn the_heading_error_is_the_largest_of_every_samples_to_the_bit() {
        // Both headings at every sample, their difference wrapped to
        // ±180°, the largest finite one.
        fn every_sample(
            a: impl Fn(f64, f64) -> (f64, f64),
            b: impl Fn(f64, f64) -> (f64, f64),
            x: &[f64],
            y: &[f64],
        ) -> f64 {
            let heading = |(u, v): (f64, f64)| v.atan2(u);
            x.iter()
                .zip(y)
                .map(|(&x, &y)| (heading(a(x, y)) - heading(b(x, y))).to_degrees())
                .map(|d| (d + 180.0).rem_euclid(360.0) - 180.0)
                .filter(|d| d.is_finite())
                .fold(0.0f64, |worst, d| worst.max(d.abs()))
        }
        let mut rng = Rng(0x5eed_0000_a7a2_0001);
        let mut wide = 0;
        for case in 0..3000 {
            let size = 10f64.powf(rng.uniform(-3.0, 6.0));
            let n = rng.uniform(20.0, 500.0) as usize;
            let (x, y): (Vec<f64>, Vec<f64>) = (0..n)
                .map(|k| {
                    let t = std::f64::consts::TAU * k as f64 / n as f64;
                    let r = size * (1.0 + 0.01 * rng.normal());
                    if case % 7 == 0 && k == n / 3 {
                        (f64::NAN, r * t.sin())
                    } else {
                        (r * t.cos() + 0.3 * size, r * t.sin() - 0.2 * size)
                    }
                })
                .unzip();
            // A correction, and another off it by a little or by a lot.
            let g = [rng.uniform(0.8, 1.25), rng.uniform(0.8, 1.25)];
            let offset = [0.3 * size, -0.2 * size];
            let turn = if case % 3 == 0 {
                rng.uniform(-180.0, 180.0)
            } else {
                rng.uniform(-2.0, 2.0) * 10f64.powf(rng.uniform(-6.0, 0.0))
            }
            .to_radians();
            let small = [rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05)];
            let a = |x: f64, y: f64| (g[0] * (x - offset[0]), g[1] * (y - offset[1]));
            let b = |x: f64, y: f64| {
                let (u, v) = a(x, y);
                let (u, v) = (u * (1.0 + small[0]), v * (1.0 + small[1]));
                (
                    u * turn.cos() - v * turn.sin(),
                    u * turn.sin() + v * turn.cos(),
                )
            };
            let fast = watch::heading_error_deg(a, b, &x, &y);
            let slow = every_sample(a, b, &x, &y);
            assert_eq!(
                fast.to_bits(),
                slow.to_bits(),
                "case {case}: {fast} against {slow}"
            );
            wide += usize::from(slow > 90.0);
        }
        assert!(wide > 300, "{wide} cases beyond 90°");
    }
}

/// The sphere watch over random 3-axis sensors: a later sphere of the same
/// sensor is never stale; one with a magnet fixed beside it (a hard iron of
/// 5 % of the field in a random direction) always is.
mod watch_sweep3 {
    use fieldcal::model::calibration::{Calibration, Ellipsoid3Params};
    use fieldcal::model::ellipsoid::{self, Ellipsoid3Model};
    use fieldcal::model::paper::PaperCalibration;
    use fieldcal::model::watch;
    use fieldcal::sim3::{Motion3, SimSensor3};

    use super::trust_sweep::Rng;

    fn calibration(fit: &ellipsoid::Ellipsoid3Fit, refit: &watch::Refit) -> Calibration {
        Calibration {
            sensor: "compass".into(),
            id: 1,
            model: fit.model.name().into(),
            params: PaperCalibration {
                a: 1.0,
                b: 0.0,
                d: 0.0,
                r: fit.r,
            },
            rms: fit.rms,
            coverage_deg: 0.0,
            n: fit.n,
            time: 0.0,
            terms: Default::default(),
            ellipsoid: Some(Ellipsoid3Params {
                offset: fit.offset,
                matrix: fit.matrix,
                r: fit.r,
                coverage: fit.coverage.fraction,
            }),
            se: watch::se_map(&refit.params),
            parent: None,
            history: Vec::new(),
            gyro: None,
            dip: None,
            across: None,
            level: None,
        }
    }

    /// Whether the second sphere shows the first's calibration stale.
    fn stale(first: &[[f64; 3]], second: &[[f64; 3]]) -> bool {
        let model = Ellipsoid3Model::Full;
        let fitted = |points: &[[f64; 3]]| {
            let fit = ellipsoid::fit(points, model).unwrap();
            let residuals: Vec<f64> = points.iter().map(|p| fit.magnitude_error(*p)).collect();
            let refit = watch::sphere_refit(&fit, &residuals);
            (calibration(&fit, &refit), refit)
        };
        let (stored, _) = fitted(first);
        let (now, refit) = fitted(second);
        let error = watch::direction_error_deg(
            stored.ellipsoid.as_ref().unwrap(),
            now.ellipsoid.as_ref().unwrap(),
            second,
        );
        watch::compare(&stored, &refit, error).stale()
    }

    #[test]
    fn the_same_sphere_is_never_stale_and_a_magnet_always_is() {
        let mut rng = Rng(0x5eed_cafe_f00d_0003);
        let (mut false_alarms, mut missed) = (0, 0);
        let cases = 100;
        for case in 0..cases {
            let r = rng.uniform(0.5, 2000.0);
            let g = |rng: &mut Rng| rng.uniform(0.85, 1.15);
            let c = |rng: &mut Rng| rng.uniform(-0.05, 0.05);
            let (xy, xz, yz) = (c(&mut rng), c(&mut rng), c(&mut rng));
            let matrix = [
                [g(&mut rng), xy, xz],
                [xy, g(&mut rng), yz],
                [xz, yz, g(&mut rng)],
            ];
            let offset = [0, 1, 2].map(|_| rng.uniform(-1.0, 1.0) * r);
            let sensor = |offset: [f64; 3], seed: u64, n: usize| SimSensor3 {
                matrix,
                offset,
                r,
                // 0.1 % to 1 % of the field per axis.
                noise: r * [0.001, 0.003, 0.01][case % 3],
                n,
                motion: Motion3::Tumble {
                    turns: 20.0,
                    axis_path_rad: 10.0,
                },
                seed,
            };
            let n = rng.uniform(300.0, 3000.0) as usize;
            let first = sensor(offset, 2 * case as u64 + 1, n).simulate().unwrap();
            let second = sensor(offset, 2 * case as u64 + 2, n).simulate().unwrap();
            false_alarms += usize::from(stale(&first, &second));
            let (a, b) = (
                rng.uniform(0.0, std::f64::consts::TAU),
                rng.uniform(-1.0, 1.0),
            );
            let k = (1.0 - b * b).sqrt();
            let magnet = [k * a.cos(), k * a.sin(), b].map(|u| 0.05 * r * u);
            let moved = [0, 1, 2].map(|i| offset[i] + magnet[i]);
            let third = sensor(moved, 2 * case as u64 + 2, n).simulate().unwrap();
            missed += usize::from(!stale(&first, &third));
        }
        eprintln!("sphere watch sweep: {false_alarms} false alarms, {missed} missed of {cases}");
        assert_eq!(false_alarms, 0, "the same sensor called stale");
        assert!(missed <= 1, "{missed} of {cases} magnets missed");
    }
}

/// Moved from `src/model/diagnose.rs`: the diagnosis on simulated recordings.
mod diagnose_data {
    use fieldcal::model::diagnose::*;
    use fieldcal::model::effects::Effect;
    use fieldcal::sample::Dataset;
    use fieldcal::sim::SimSensor;

    fn clean(seed: u64) -> Dataset {
        SimSensor {
            offset_x: 30.0,
            offset_y: -20.0,
            gain_x: 1.05,
            noise: 3.0,
            seed,
            ..Default::default()
        }
        .simulate()
        .unwrap()
    }

    #[test]
    fn clean_recordings_suggest_nothing() {
        let mut fired = 0;
        for seed in 1..=40 {
            let d = diagnose(&clean(seed), &[], None).unwrap();
            assert!(d.baseline.rms.is_finite() && d.noise_floor.rms > 0.0);
            if d.suggested.is_some() {
                fired += 1;
            }
        }
        assert!(
            fired <= 2,
            "{fired} of 40 clean recordings got a suggestion"
        );
    }

    /// A strongly coupled sensor turned once: drift, with time following
    /// heading, could fold the turn onto a 150° arc of a larger circle and
    /// reach a lower relative rms than the true effect. It is refused, and
    /// cross-axis is suggested.
    #[test]
    fn a_fit_that_folds_the_turn_is_not_an_effect() {
        let data = SimSensor {
            gain_x: 1.471,
            gain_y: 1.179,
            offset_x: 325.7,
            offset_y: 1731.7,
            noise: 5.0,
            period: 0.03,
            turn_seconds: 5.0,
            seed: 155_379,
            effects: fieldcal::sim::SimEffects {
                cross_axis_deg: 10.0,
                ..Default::default()
            },
            ..Default::default()
        }
        .simulate()
        .unwrap();
        let d = diagnose(&data, &[], None).unwrap();
        assert_eq!(d.suggested, Some(Effect::CrossAxis), "{:?}", d.candidates);
        let drift = d.candidates.iter().find(|c| c.effect == Effect::Drift);
        let drift = drift.expect("drift is a candidate");
        assert!(!drift.supported, "{drift:?}");
        assert!(
            drift.evidence.contains("folds the turn"),
            "{}",
            drift.evidence
        );
        // What is left is the simulated noise, 5 counts on about 1180.
        let last = d.ladder.last().unwrap();
        assert!(last.rms > 0.003 && last.rms < 0.0045, "{last:?}");
        // Nothing else comes close.
        assert_eq!(d.close_second, None);
    }

    /// Through a single turn, a temperature that warms and cools follows
    /// heading, and cross-axis coupling explains its effect about as well:
    /// the suggestion names both rather than pretend to know.
    #[test]
    fn a_cause_that_follows_heading_is_named_with_its_rival() {
        let data = SimSensor {
            gain_x: 1.536,
            gain_y: 1.035,
            offset_x: -1058.0,
            offset_y: -1723.0,
            noise: 10.0,
            period: 0.2,
            start_heading_deg: 17.5,
            seed: 14_685_220_468_055_014_633,
            effects: fieldcal::sim::SimEffects {
                temp_per_c: Some([0.0, 17.1]),
                ..Default::default()
            },
            ..Default::default()
        }
        .simulate()
        .unwrap();
        let d = diagnose(&data, &[], None).unwrap();
        let temp = Effect::Covariate("temp".into());
        let pair = [d.suggested.clone(), d.close_second.clone()];
        assert!(
            pair.contains(&Some(temp)) && pair.contains(&Some(Effect::CrossAxis)),
            "{pair:?}"
        );
    }
}

/// Moved from `src/model/gyro.rs`.
mod gyro_moved {
    use fieldcal::model::gyro::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A hand turn: two turns at a varying rate over 40 s, the gyro (scale
    /// `sign`, a bias) sampled on its own clock at 190 Hz, the sensor at 75 Hz
    /// starting a little later.
    struct Turn {
        sample_t: Vec<f64>,
        truth_rad: Vec<f64>,
        gyro_t: Vec<f64>,
        rate: Vec<f64>,
    }

    impl Turn {
        /// The true headings with errors that follow heading (a slow
        /// 3rd harmonic of 2°, plus `distortion`, in degrees, of each
        /// heading) and white `noise` (radians).
        fn noisy_headings(
            &self,
            rng: &mut rand_chacha::ChaCha8Rng,
            noise: &Normal<f64>,
            distortion: impl Fn(f64) -> f64,
        ) -> Vec<f64> {
            self.truth_rad
                .iter()
                .map(|&h| {
                    h + (2.0 * (3.0 * h).sin() + distortion(h)).to_radians() + noise.sample(rng)
                })
                .collect()
        }
    }

    fn heading_at(t: f64) -> f64 {
        // Degrees: 720° over 40 s with a wobble in rate.
        18.0 * t + 20.0 * (t * 0.4).sin() + 10.0
    }

    fn turn(sign: f64, bias: f64) -> Turn {
        let gyro_t: Vec<f64> = (0..(40.0 * 190.0) as usize)
            .map(|i| i as f64 / 190.0)
            .collect();
        let rate: Vec<f64> = gyro_t
            .iter()
            .map(|&t| sign * (18.0 + 8.0 * (t * 0.4).cos()) + bias)
            .collect();
        let sample_t: Vec<f64> = (0..(39.0 * 75.0) as usize)
            .map(|i| 0.3 + i as f64 / 75.0)
            .collect();
        let truth_rad = sample_t
            .iter()
            .map(|&t| heading_at(t).to_radians())
            .collect();
        Turn {
            sample_t,
            truth_rad,
            gyro_t,
            rate,
        }
    }

    /// The reference of a gyro `column` that reads `share` of the turn's
    /// rate (one tilted from the turn's axis).
    fn reading_a_share(turn: &Turn, column: &str, share: f64) -> HeadingReference {
        let rate: Vec<f64> = turn.rate.iter().map(|r| share * r).collect();
        HeadingReference::from_rates(
            column,
            &turn.sample_t,
            &turn.gyro_t,
            &rate,
            GyroUnits::DegPerSecond,
        )
        .unwrap()
    }

    fn reference(turn: &Turn) -> HeadingReference {
        HeadingReference::from_rates(
            "gyro_z",
            &turn.sample_t,
            &turn.gyro_t,
            &turn.rate,
            GyroUnits::DegPerSecond,
        )
        .unwrap()
    }

    #[test]
    fn a_true_heading_has_no_error_whatever_the_gyro_sign_and_bias() {
        let t = turn(-1.0, 1.7);
        let check = reference(&t).check(&t.truth_rad, &[]).unwrap();
        assert!(check.rms_deg < 0.01, "{check:?}");
        assert!((check.gyro_scale + 1.0).abs() < 1e-3, "{check:?}");
        assert!((check.gyro_bias_deg_s - 1.7).abs() < 1e-3, "{check:?}");
        assert_eq!(check.n, t.sample_t.len());
    }

    #[test]
    fn rad_per_second_is_converted() {
        let t = turn(1.0, 0.0);
        let rad: Vec<f64> = t.rate.iter().map(|r| r.to_radians()).collect();
        let r = HeadingReference::from_rates(
            "g",
            &t.sample_t,
            &t.gyro_t,
            &rad,
            GyroUnits::RadPerSecond,
        )
        .unwrap();
        let check = r.check(&t.truth_rad, &[]).unwrap();
        assert!((check.gyro_scale - 1.0).abs() < 1e-3, "{check:?}");
        assert!(check.rms_deg < 0.01, "{check:?}");
    }

    #[test]
    fn a_second_harmonic_distortion_gives_its_rms() {
        let t = turn(1.0, -0.8);
        let amp = 3.0_f64;
        let h: Vec<f64> = t
            .truth_rad
            .iter()
            .map(|&h| h + (amp * (2.0 * h).sin()).to_radians())
            .collect();
        let check = reference(&t).check(&h, &[]).unwrap();
        let check = HeadingCheck {
            errors_deg: vec![],
            ..check
        };
        // The distortion's own rms over these samples (amp/√2 over whole
        // turns at an even rate).
        let expected = (t
            .truth_rad
            .iter()
            .map(|&h| (amp * (2.0 * h).sin()).powi(2))
            .sum::<f64>()
            / h.len() as f64)
            .sqrt();
        assert!((expected - amp / 2f64.sqrt()).abs() < 0.1);
        assert!(
            (check.rms_deg - expected).abs() < 0.05 * expected,
            "{} vs {expected}",
            check.rms_deg
        );
        // Over turns that are not whole, the fitted scale takes a little of
        // the harmonic; the peak-to-peak stays near twice the amplitude.
        let p2p = check.peak_to_peak_deg;
        assert!(p2p > 1.9 * amp && p2p < 2.3 * amp, "{p2p}");
    }

    #[test]
    fn skipped_samples_are_not_checked() {
        let t = turn(1.0, 0.0);
        let mut h = t.truth_rad.clone();
        h[100] += 1.0;
        h[200] += 1.0;
        let r = reference(&t);
        let check = r.check(&h, &[100, 200]).unwrap();
        assert!(check.rms_deg < 0.01, "{check:?}");
        assert!(check.errors_deg[100].is_nan());
        assert_eq!(check.n, t.sample_t.len() - 2);
        assert!(r.check(&h, &[]).unwrap().rms_deg > 1.0);
    }

    #[test]
    fn worse_by_is_zero_within_its_se_for_copies_and_positive_for_a_distortion() {
        let t = turn(1.0, 0.5);
        let r = reference(&t);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 1.0_f64.to_radians()).unwrap();
        // Heading errors follow heading: a slow error common to both, plus
        // white noise of each.
        let noisy = |rng: &mut rand_chacha::ChaCha8Rng, extra: f64| {
            t.noisy_headings(rng, &noise, |h| extra * (2.0 * h).sin())
        };
        let a = r.check(&noisy(&mut rng, 0.0), &[]).unwrap();
        let b = r.check(&noisy(&mut rng, 0.0), &[]).unwrap();
        let same = a.worse_by(&b);
        assert!(same.se_deg > 0.0, "{same:?}");
        assert!(same.delta_rms_deg.abs() < 3.0 * same.se_deg, "{same:?}");
        let c = r.check(&noisy(&mut rng, 4.0), &[]).unwrap();
        let worse = a.worse_by(&c);
        assert!(worse.delta_rms_deg > 3.0 * worse.se_deg, "{worse:?}");
        assert!(
            (worse.delta_rms_deg - (c.rms_deg - a.rms_deg)).abs() < 1e-9,
            "{worse:?}"
        );
        // Antisymmetric.
        let better = c.worse_by(&a);
        assert!((better.delta_rms_deg + worse.delta_rms_deg).abs() < 1e-12);
    }

    /// A small distortion locked to heading (a 2nd harmonic of 0.8°, as a
    /// wrong cross-axis term gives) on top of a larger common one and
    /// white noise: the same on both turns, so it is a systematic
    /// difference, told from chance. With the heading pattern left in the
    /// batches, its standard error swelled to the size of the difference
    /// itself (measured: +0.094° ± 0.096°; with it out, ± 0.026°), so no distortion of
    /// that size could ever be refused.
    #[test]
    fn a_distortion_locked_to_heading_is_told_from_chance() {
        let t = turn(1.0, 0.5);
        let r = reference(&t);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, 0.5_f64.to_radians()).unwrap();
        let noisy = |rng: &mut rand_chacha::ChaCha8Rng, extra: f64| {
            t.noisy_headings(rng, &noise, |h| extra * (2.0 * h + 0.4).sin())
        };
        let a = r.check(&noisy(&mut rng, 0.0), &[]).unwrap();
        let b = r.check(&noisy(&mut rng, 0.8), &[]).unwrap();
        let worse = a.worse_by(&b);
        assert!(worse.delta_rms_deg > 0.05, "{worse:?}");
        assert!(worse.delta_rms_deg > 3.0 * worse.se_deg, "{worse:?}");
        // Two noisy copies still come out within their uncertainty.
        let c = r.check(&noisy(&mut rng, 0.0), &[]).unwrap();
        let same = a.worse_by(&c);
        assert!(same.delta_rms_deg.abs() < 3.0 * same.se_deg, "{same:?}");
    }

    #[test]
    fn a_gyro_about_another_axis_is_refused() {
        let t = turn(1.0, 0.0);
        // A tilted gyro: 0.3 of the rate (72° off the turn's axis).
        let r = reading_a_share(&t, "gyro_x", 0.3);
        let err = r.check(&t.truth_rad, &[]).unwrap_err();
        assert!(matches!(err, GyroError::WrongAxis { .. }), "{err}");
        assert!(err.to_string().contains("gyro_x"), "{err}");
        // One that barely turns: 0.05 of the rate spans 36°.
        let r = reading_a_share(&t, "gyro_y", 0.05);
        let err = r.check(&t.truth_rad, &[]).unwrap_err();
        assert!(matches!(err, GyroError::NoTurnSeen { .. }), "{err}");
    }

    #[test]
    fn a_tilt_within_the_bound_is_accepted() {
        let t = turn(1.0, 0.0);
        // 40° off the turn's axis reads cos 40° = 0.77 of the rate.
        let r = reading_a_share(&t, "g", 40f64.to_radians().cos());
        let check = r.check(&t.truth_rad, &[]).unwrap();
        assert!((check.gyro_scale - 1.0 / 40f64.to_radians().cos()).abs() < 1e-3);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let t = turn(1.0, 0.0);
        let f = |s: &[f64], gt: &[f64], r: &[f64]| {
            HeadingReference::from_rates("g", s, gt, r, GyroUnits::DegPerSecond)
        };
        assert!(matches!(
            f(&t.sample_t, &t.gyro_t, &t.rate[1..]),
            Err(GyroError::LengthMismatch { .. })
        ));
        assert!(matches!(
            f(&t.sample_t, &[], &[]),
            Err(GyroError::TooFewGyroSamples { .. })
        ));
        let mut rate = t.rate.clone();
        rate[5] = f64::NAN;
        assert!(matches!(
            f(&t.sample_t, &t.gyro_t, &rate),
            Err(GyroError::NotFinite { index: 6, .. })
        ));
        let mut gt = t.gyro_t.clone();
        gt.swap(3, 4);
        assert!(matches!(
            f(&t.sample_t, &gt, &t.rate),
            Err(GyroError::NotMonotonic { index: 5, .. })
        ));
        let mut st = t.sample_t.clone();
        st[2] = f64::NAN;
        assert!(matches!(
            f(&st, &t.gyro_t, &t.rate),
            Err(GyroError::NotFinite { .. })
        ));
        // Clocks that do not overlap.
        let late: Vec<f64> = t.sample_t.iter().map(|s| s + 1000.0).collect();
        let err = f(&late, &t.gyro_t, &t.rate).unwrap_err();
        assert!(matches!(err, GyroError::NoOverlap { .. }), "{err}");
        assert!(f(&[], &t.gyro_t, &t.rate).is_err());
        let r = reference(&t);
        assert!(matches!(
            r.check(&t.truth_rad[1..], &[]),
            Err(GyroError::HeadingCount { .. })
        ));
        let nan = vec![f64::NAN; t.sample_t.len()];
        assert!(matches!(
            r.check(&nan, &[]),
            Err(GyroError::TooFewChecked { .. })
        ));
        // A skip list out of range or unsorted does not panic.
        assert!(r.check(&t.truth_rad, &[usize::MAX, 3, 1]).is_ok());
        // Comparing checks of different lengths or with nothing in common.
        let empty = HeadingCheck {
            errors_deg: vec![],
            ..r.check(&t.truth_rad, &[]).unwrap()
        };
        assert!(empty.worse_by(&empty).delta_rms_deg.is_nan());
    }
}

/// Moved from `src/model/tilt.rs`.
mod tilt_moved {
    use fieldcal::model::tilt::*;
    use nalgebra::Rotation3;
    use nalgebra::Vector3;

    const FORWARD: [f64; 3] = [1.0, 0.0, 0.0];
    const UP: [f64; 3] = [0.0, 0.0, 1.0];
    const RIGHT: [f64; 3] = [0.0, -1.0, 0.0];

    /// The Earth's field and gravity's specific force in a world frame of
    /// east, north, up, seen from a board at `heading` (clockwise from
    /// north), pitched up by `pitch` and rolled right by `roll` (degrees).
    fn seen(heading: f64, pitch: f64, roll: f64, dip: f64) -> ([f64; 3], [f64; 3]) {
        let d = dip.to_radians();
        let field_enu = Vector3::new(0.0, d.cos(), -d.sin()) * 0.5;
        let up_enu = Vector3::new(0.0, 0.0, 9.81);
        // Body axes in the world: yaw (clockwise from north about −up),
        // then pitch about the body's right axis, then roll about forward.
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), -heading.to_radians());
        // A body at heading 0 has x north, y west, z up.
        let base = nalgebra::Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let pitch_r = Rotation3::from_axis_angle(&Vector3::y_axis(), -pitch.to_radians());
        let roll_r = Rotation3::from_axis_angle(&Vector3::x_axis(), roll.to_radians());
        // body->world = yaw * base * pitch * roll
        let body_to_world = yaw.matrix() * base * pitch_r.matrix() * roll_r.matrix();
        let w2b = body_to_world.transpose();
        let m = w2b * field_enu;
        let a = w2b * up_enu;
        ([m.x, m.y, m.z], [a.x, a.y, a.z])
    }

    #[test]
    fn level_board_reads_its_heading_both_ways() {
        for h in [0.0, 30.0, 90.0, 181.0, 270.0, 359.0] {
            let (m, a) = seen(h, 0.0, 0.0, 60.0);
            let t = tilt_heading(m, a, FORWARD, UP).unwrap();
            assert!(
                heading_difference(t.heading_deg, h).abs() < 1e-9,
                "{h}: {t:?}"
            );
            assert!((t.inclination_deg - 60.0).abs() < 1e-9);
            assert!(t.tilt_deg.abs() < 1e-6);
            let l = level_heading(m, FORWARD, RIGHT).unwrap();
            assert!(heading_difference(l, h).abs() < 1e-9, "{h}: level {l}");
        }
    }

    #[test]
    fn tilt_is_compensated_and_the_level_compass_is_not() {
        for (h, p, r) in [(40.0, 20.0, 0.0), (200.0, -15.0, 25.0), (300.0, 0.0, -30.0)] {
            let (m, a) = seen(h, p, r, 65.0);
            let t = tilt_heading(m, a, FORWARD, UP).unwrap();
            assert!(heading_difference(t.heading_deg, h).abs() < 1e-9, "{t:?}");
            assert!((t.pitch_deg - p).abs() < 1e-9, "{t:?}");
            assert!((t.inclination_deg - 65.0).abs() < 1e-9);
            let l = level_heading(m, FORWARD, RIGHT).unwrap();
            assert!(heading_difference(l, h).abs() > 5.0, "level {l} vs {h}");
        }
    }

    #[test]
    fn no_heading_without_a_horizontal_field_or_with_bad_input() {
        let (m, a) = seen(10.0, 0.0, 0.0, 89.0);
        assert!(tilt_heading(m, a, FORWARD, UP).is_none());
        match tilt_heading_or_why(m, a, FORWARD, UP) {
            Err(NoHeading::FieldVertical { angle_deg }) => {
                assert!((angle_deg - 1.0).abs() < 1e-9, "{angle_deg}")
            }
            other => panic!("{other:?}"),
        }
        // 6° from the vertical still has a heading.
        let (m6, a6) = seen(10.0, 0.0, 0.0, 84.0);
        assert!(tilt_heading(m6, a6, FORWARD, UP).is_some());
        assert_eq!(
            tilt_heading_or_why([0.0; 3], a, FORWARD, UP),
            Err(NoHeading::Zero)
        );
        assert_eq!(
            tilt_heading_or_why(m, [f64::NAN, 0.0, 1.0], FORWARD, UP),
            Err(NoHeading::NotFinite)
        );
        // The forward axis pointing straight up.
        let (m, a) = seen(10.0, 90.0, 0.0, 60.0);
        let why = tilt_heading_or_why(m, a, FORWARD, UP).unwrap_err();
        assert!(
            matches!(why, NoHeading::ForwardVertical { angle_deg } if angle_deg < 1e-6),
            "{why:?}"
        );
        assert!(why.to_string().contains("forward axis"), "{why}");
    }

    #[test]
    fn differences_wrap() {
        assert_eq!(heading_difference(1.0, 359.0), 2.0);
        assert_eq!(heading_difference(359.0, 1.0), -2.0);
        assert_eq!(heading_difference(180.0, 0.0), 180.0);
    }

    /// A board at a known attitude with noise on both sensors.
    struct NoisyBoard {
        rng: rand_chacha::ChaCha8Rng,
        mag_sigma: f64,
        acc_sigma: f64,
    }

    impl NoisyBoard {
        fn new(seed: u64, mag_sigma: f64, acc_sigma: f64) -> Self {
            use rand::SeedableRng;
            NoisyBoard {
                rng: rand_chacha::ChaCha8Rng::seed_from_u64(seed),
                mag_sigma,
                acc_sigma,
            }
        }
        fn read(&mut self, h: f64, p: f64, r: f64, dip: f64) -> ([f64; 3], [f64; 3]) {
            use rand_distr::{Distribution, Normal};
            let (m, a) = board_reading(h, p, r, dip);
            let nm = Normal::new(0.0, self.mag_sigma).unwrap();
            let na = Normal::new(0.0, self.acc_sigma).unwrap();
            (
                m.map(|v| v + nm.sample(&mut self.rng)),
                a.map(|v| v + na.sample(&mut self.rng)),
            )
        }
        fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
            use rand::RngExt as _;
            lo + (hi - lo) * self.rng.random::<f64>()
        }
    }

    fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
        v.sort_by(|a, b| a.total_cmp(b));
        v[((v.len() - 1) as f64 * p).round() as usize]
    }

    /// At tilts up to 30° with noise on the field and on gravity, the
    /// tilt-compensated heading is within what the noise gives: σ_h ≈
    /// σ_m/(|B| cos I) (the horizontal field's direction) + σ_a/g · tan I
    /// (a tilt error moves the vertical field into the horizontal), and
    /// the 99th percentile of |error| stays under 3.5 σ_h (2.58 σ for a
    /// normal error). The level compass's error grows with tilt.
    #[test]
    fn the_compensated_heading_is_within_the_noise_at_tilts_up_to_30_degrees() {
        for (seed, dip) in [(1, 65.0), (2, 30.0), (3, -50.0)] {
            let (sm, sa) = (0.005, 0.004);
            let mut board = NoisyBoard::new(seed, sm, sa);
            let d = f64::to_radians(dip);
            let sigma_h = (sm / d.cos() + sa * d.tan().abs()).to_degrees();
            let mut errors = Vec::new();
            let mut level_by_tilt = [Vec::new(), Vec::new(), Vec::new()];
            for _ in 0..3000 {
                let h = board.uniform(0.0, 360.0);
                let p = board.uniform(-30.0, 30.0);
                let r = board.uniform(-30.0, 30.0);
                let (m, a) = board.read(h, p, r, dip);
                let t = tilt_heading(m, a, FORWARD, UP).unwrap();
                assert!(t.tilt_deg <= 42.0 + 1.0, "{t:?}");
                errors.push(heading_difference(t.heading_deg, h).abs());
                let l = level_heading(m, FORWARD, RIGHT).unwrap();
                let bin = ((t.tilt_deg / 15.0) as usize).min(2);
                level_by_tilt[bin].push(heading_difference(l, h).abs());
            }
            let p99 = percentile(errors.clone(), 0.99);
            assert!(p99 < 3.5 * sigma_h, "dip {dip}: p99 {p99}° vs σ {sigma_h}°");
            // It is noise, not a bias the bound hides: the median error is
            // of the order of σ (0.67 σ for a normal error).
            let median = percentile(errors, 0.5);
            assert!(median < 1.5 * sigma_h, "dip {dip}: median {median}");
            let rms = |v: &Vec<f64>| (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt();
            let (l0, l1, l2) = (
                rms(&level_by_tilt[0]),
                rms(&level_by_tilt[1]),
                rms(&level_by_tilt[2]),
            );
            assert!(l0 < l1 && l1 < l2, "dip {dip}: level {l0} {l1} {l2}");
            assert!(l2 > 5.0 * sigma_h, "dip {dip}: level {l2} vs σ {sigma_h}");
        }
    }

    #[test]
    fn axis_maps_parse_print_and_apply() {
        let m: AxisMap = "x,-z,y".parse().unwrap();
        assert_eq!(m.to_string(), "x,-z,y");
        assert_eq!(m.apply([1.0, 2.0, 3.0]), [1.0, -3.0, 2.0]);
        assert_eq!(m.determinant(), 1.0);
        assert_eq!(m.mirrored().to_string(), "-x,z,-y");
        assert_eq!(m.mirrored().determinant(), -1.0);
        for bad in ["x,x,y", "x,y", "x,y,w", "", "x,y,z,x", "--x,y,z"] {
            assert!(bad.parse::<AxisMap>().is_err(), "{bad}");
        }
        let all = AxisMap::all();
        assert_eq!(all.len(), 48);
        assert_eq!(all.iter().filter(|m| m.determinant() > 0.0).count(), 24);
        assert_eq!(parse_axis("-y"), Some([0.0, -1.0, 0.0]));
        assert_eq!(parse_axis("w"), None);
    }

    /// A magnetometer mounted as `truth` on a board tumbled through tilts
    /// up to 60°: auto finds the mapping; on a flat turn it refuses.
    #[test]
    fn auto_finds_the_mounting_on_a_tumble_and_refuses_on_a_flat_turn() {
        for (seed, truth) in [(5, "x,-z,y"), (6, "-y,x,z"), (7, "z,y,-x")] {
            let truth: AxisMap = truth.parse().unwrap();
            let mut board = NoisyBoard::new(seed, 0.01, 0.01);
            let (mut mag, mut acc) = (Vec::new(), Vec::new());
            for _ in 0..600 {
                let (h, p, r) = (
                    board.uniform(0.0, 360.0),
                    board.uniform(-60.0, 60.0),
                    board.uniform(-60.0, 60.0),
                );
                let (m, a) = board.read(h, p, r, 60.0);
                // The chip reads such that truth.apply(chip) = body.
                let chip: [f64; 3] = [0, 1, 2].map(|i| {
                    let probe = [0, 1, 2].map(|k| if k == i { 1.0 } else { 0.0 });
                    let body_of_axis = truth.apply(probe);
                    (0..3).map(|k| body_of_axis[k] * m[k]).sum()
                });
                assert!((0..3).all(|k| (truth.apply(chip)[k] - m[k]).abs() < 1e-12));
                mag.push(chip);
                acc.push(a);
            }
            let choice = choose_axis_map(&mag, &acc, None).unwrap();
            assert_eq!(choice.chosen.map, truth, "{choice:?}");
            assert!((choice.chosen.inclination.median - 60.0).abs() < 1.0);
            assert!(choice.runner_up.inclination.spread > 5.0 * choice.chosen.inclination.spread);
            // The mirror is chosen when the model's dip says so.
            let other = choose_axis_map(&mag, &acc, Some(-60.0)).unwrap();
            assert_eq!(other.chosen.map, truth.mirrored());
            // The daemon's check of a configured mapping: the truth and,
            // with no place, its mirror pass; any other is named wrong with
            // the truth to set; with the model's dip, the mirror is wrong.
            assert_eq!(mounting_problem(&mag, &acc, truth, None), None);
            assert_eq!(mounting_problem(&mag, &acc, truth, Some(60.0)), None);
            assert_eq!(mounting_problem(&mag, &acc, truth.mirrored(), None), None);
            let mirror = mounting_problem(&mag, &acc, truth.mirrored(), Some(60.0)).unwrap();
            assert!(
                mirror.contains("mirrored, so every heading is 180° off"),
                "{mirror}"
            );
            assert!(
                mirror.ends_with(&format!("set mag_axes = \"{truth}\"")),
                "{mirror}"
            );
            for wrong in AxisMap::all() {
                if wrong == truth || wrong == truth.mirrored() {
                    continue;
                }
                let why = mounting_problem(&mag, &acc, wrong, Some(60.0))
                    .unwrap_or_else(|| panic!("{wrong} passed for {truth}"));
                assert!(why.starts_with("the dip wanders"), "{why}");
                assert!(
                    why.ends_with(&format!("set mag_axes = \"{truth}\"")),
                    "{why}"
                );
            }
        }
        // A flat turn: z stays vertical.
        let mut board = NoisyBoard::new(8, 0.01, 0.01);
        let (mut mag, mut acc) = (Vec::new(), Vec::new());
        for k in 0..600 {
            let (m, a) = board.read(k as f64 * 1.2, 0.0, 0.0, 60.0);
            mag.push(m);
            acc.push(a);
        }
        let err = choose_axis_map(&mag, &acc, None).unwrap_err();
        assert!(matches!(err, AxisChoiceError::Ambiguous { .. }), "{err}");
        // A flat turn cannot tell a mapping wrong: nothing is said.
        assert_eq!(
            mounting_problem(&mag, &acc, "y,x,-z".parse().unwrap(), Some(60.0)),
            None
        );
        assert!(err.to_string().contains("--mag-axes"), "{err}");
        let err = choose_axis_map(&mag[..10], &acc[..10], None).unwrap_err();
        assert!(matches!(err, AxisChoiceError::TooFew { .. }), "{err}");
    }

    #[test]
    fn resampling_interpolates_within_gaps_and_refuses_disjoint_clocks() {
        let times: Vec<f64> = (0..100)
            .map(|i| i as f64 * 0.01)
            .filter(|t| !(0.5..0.6).contains(t))
            .collect();
        let values: Vec<[f64; 3]> = times.iter().map(|&t| [t, 2.0 * t, -t]).collect();
        let at = [0.005, 0.25, 0.55, 0.985, 2.0];
        let r = resample("accel", &times, &values, &at).unwrap();
        assert!((r.values[0][1] - 0.01).abs() < 1e-12, "{r:?}");
        assert!((r.values[1][2] + 0.25).abs() < 1e-12);
        assert!(r.values[2][0].is_nan(), "a gap of 0.11 s is not bridged");
        assert!((r.values[3][0] - 0.985).abs() < 1e-12);
        assert!(r.values[4][0].is_nan());
        assert_eq!((r.outside, r.in_gaps), (1, 1));
        assert!((r.period - 0.01).abs() < 1e-12);
        let late: Vec<f64> = at.iter().map(|t| t + 100.0).collect();
        let err = resample("accel", &times, &values, &late).unwrap_err();
        assert!(matches!(err, ResampleError::NoOverlap { .. }), "{err}");
        let err = resample("accel", &[0.0, 0.0], &values[..2], &at).unwrap_err();
        assert!(
            matches!(err, ResampleError::BadTimes { row: 2, .. }),
            "{err}"
        );
        assert!(resample("accel", &times[..3], &values, &at).is_err());
    }

    #[test]
    fn robust_spread_is_the_sd_for_normal_values_and_ignores_a_few_wild_ones() {
        let mut v: Vec<f64> = (1..=999)
            .map(|i| {
                // Normal quantiles by the inverse error function's series
                // would do; a symmetric triangle of known MAD is simpler.
                i as f64 / 1000.0 - 0.5
            })
            .collect();
        let s = robust_spread(&v).unwrap();
        assert!(s.median.abs() < 1e-12);
        assert!((s.spread - 0.25 * MAD_TO_SIGMA).abs() < 1e-3, "{s:?}");
        v.extend([1e6, -1e6, f64::NAN]);
        let s2 = robust_spread(&v).unwrap();
        assert!((s2.spread - s.spread).abs() < 0.01, "{s2:?}");
        assert!(robust_spread(&[f64::NAN]).is_none());
    }

    #[test]
    fn a_stored_3d_calibration_is_read_and_others_are_refused() {
        let json = r#"{"axes": 3, "x_column": "mx", "y_column": "my", "z_column": "mz",
            "params": {"offset": [1, 2, 3], "matrix": [[2, 0, 0], [0, 1, 0], [0, 0, 0.5]], "r": 0.5},
            "units": "gauss"}"#;
        let c = Calibration3::from_json(json).unwrap();
        assert_eq!(c.columns, ["mx", "my", "mz"].map(String::from));
        assert_eq!(c.apply([2.0, 3.0, 5.0]), [2.0, 1.0, 1.0]);
        assert_eq!(c.units.as_deref(), Some("gauss"));
        let two_d = r#"{"params": {"a": 1, "b": 0, "d": 0, "r": 1}}"#;
        assert!(matches!(
            Calibration3::from_json(two_d),
            Err(Calibration3Error::NotThreeAxes { .. })
        ));
        let short = json.replace("[1, 2, 3]", "[1, 2]");
        let err = Calibration3::from_json(&short).unwrap_err();
        assert!(err.to_string().contains("params.offset"), "{err}");
        let bad_r = json.replace("\"r\": 0.5", "\"r\": -1");
        assert!(Calibration3::from_json(&bad_r).is_err());
        assert!(matches!(
            Calibration3::from_json("not json"),
            Err(Calibration3Error::NotJson { .. })
        ));
        // A model with a drift (`fit --effects full+drift --json`): its
        // offset moves with time, which the heading cannot apply.
        let drift = json.replace(
            "\"r\": 0.5}",
            "\"r\": 0.5, \"extra\": {\"drift_x\": 1e-4, \"drift_y\": 0, \"drift_z\": 0}}, \"model\": \"offset+scale+cross-axis+drift\", \"base_model\": \"offset+scale+cross-axis\"",
        );
        let err = Calibration3::from_json(&drift).unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("offset+scale+cross-axis+drift: drift_x, drift_y, drift_z")
                && text.contains("--effects offset+scale+cross-axis --json"),
            "{text}"
        );
        // An empty extra (the base model, or outliers alone) is read.
        let empty = json.replace("\"r\": 0.5}", "\"r\": 0.5, \"extra\": {}}");
        assert!(Calibration3::from_json(&empty).is_ok());
    }

    #[test]
    fn the_series_adds_the_declination_and_refuses_parallel_axes() {
        let (m, a) = board_reading(100.0, 10.0, -20.0, 60.0);
        let s = heading_series(&[m, [f64::NAN; 3]], &[a, a], FORWARD, UP, -7.5).unwrap();
        assert!((s.heading_deg[0] - 92.5).abs() < 1e-9, "{s:?}");
        assert!((s.pitch_deg[0] - 10.0).abs() < 1e-9);
        assert!((s.inclination_deg[0] - 60.0).abs() < 1e-9);
        assert!(s.heading_deg[1].is_nan() && s.level_deg[1].is_nan());
        assert!(heading_series(&[m], &[a], UP, UP, 0.0).is_err());
        assert!(heading_series(&[m], &[a], FORWARD, [1.0, 0.0, 1.0], 0.0).is_err());
    }

    /// A long series is worked out in parts on several cores: each
    /// sample's figures are still its own, in its own place and column, to
    /// the bit (NaN where a sample has none), whatever the part it fell
    /// in; a magnetometer longer than the accelerometer gives as many
    /// samples as the shorter has, as the pairs always did.
    #[test]
    fn a_long_series_in_parts_gives_each_sample_its_own_figures() {
        let (n_mag, n): (usize, usize) = (300_001, 250_003);
        let mag: Vec<[f64; 3]> = (0..n_mag)
            .map(|k| {
                let t = k as f64;
                if k.is_multiple_of(1_009) {
                    [f64::NAN; 3]
                } else {
                    [
                        400.0 * (t * 1e-3).cos(),
                        380.0 * (t * 1e-3).sin(),
                        300.0 + (k % 7) as f64,
                    ]
                }
            })
            .collect();
        let accel: Vec<[f64; 3]> = (0..n)
            .map(|k| {
                let t = k as f64;
                if k.is_multiple_of(2_003) {
                    [0.0; 3]
                } else {
                    [1000.0 * (t * 3e-4).sin(), 500.0 * (t * 7e-4).cos(), 4000.0]
                }
            })
            .collect();
        let declination = 4.25;
        let s = heading_series(&mag, &accel, FORWARD, UP, declination).unwrap();
        for column in [
            &s.heading_deg,
            &s.level_deg,
            &s.tilt_deg,
            &s.pitch_deg,
            &s.inclination_deg,
        ] {
            assert_eq!(column.len(), n);
        }
        // Each figure as the one-sample functions give it.
        let turn = |h: f64| {
            let t = (h + declination).rem_euclid(360.0);
            if t >= 360.0 { 0.0 } else { t }
        };
        let right = [
            FORWARD[1] * UP[2] - FORWARD[2] * UP[1],
            FORWARD[2] * UP[0] - FORWARD[0] * UP[2],
            FORWARD[0] * UP[1] - FORWARD[1] * UP[0],
        ];
        let bits = |v: f64| if v.is_nan() { u64::MAX } else { v.to_bits() };
        let mut checked = 0;
        for k in (0..n)
            .step_by(101)
            .chain([n / 2 - 1, n / 2, n / 2 + 1, n - 1])
        {
            let t = tilt_heading(mag[k], accel[k], FORWARD, UP);
            let level = level_heading(mag[k], FORWARD, right).map_or(f64::NAN, turn);
            for (name, long, alone) in [
                (
                    "heading",
                    s.heading_deg[k],
                    t.map_or(f64::NAN, |t| turn(t.heading_deg)),
                ),
                ("level", s.level_deg[k], level),
                ("tilt", s.tilt_deg[k], t.map_or(f64::NAN, |t| t.tilt_deg)),
                ("pitch", s.pitch_deg[k], t.map_or(f64::NAN, |t| t.pitch_deg)),
                (
                    "inclination",
                    s.inclination_deg[k],
                    t.map_or(f64::NAN, |t| t.inclination_deg),
                ),
            ] {
                assert_eq!(bits(long), bits(alone), "{name} of sample {k}");
            }
            checked += 1;
        }
        assert!(checked > 2_400);
        // NaN where a sample has no field or no vertical, and only there.
        assert!(s.heading_deg[1_009].is_nan() && s.heading_deg[2_003 * 3].is_nan());
        assert!(
            s.level_deg[2_003 * 3].is_finite(),
            "a level heading needs no vertical"
        );
        assert!(s.heading_deg[1_010].is_finite());
    }
}

mod gyro3 {
    use fieldcal::model::gyro3::{GyroSample, fit_gyro3, heading_rate};
    use fieldcal::model::tilt::tilt_heading;
    use nalgebra::{Rotation3, Vector3};

    /// A board tumbling for `seconds` at 50 Hz (yaw, pitch and roll at
    /// rates that do not divide one another), its tilt-compensated heading
    /// from a field of dip 65°, and its gyro in the accelerometer's axes
    /// with `bias`, each axis of it read through `axes` (index, sign).
    fn tumble(seconds: f64, bias: [f64; 3], axes: [(usize, f64); 3]) -> Vec<GyroSample> {
        let dip = 65f64.to_radians();
        let field = Vector3::new(dip.cos(), 0.0, dip.sin());
        let rates = [0.53, 0.31, 0.17];
        (0..(seconds * 50.0) as usize)
            .filter_map(|k| {
                let t = k as f64 / 50.0;
                let a = Rotation3::from_axis_angle(&Vector3::z_axis(), rates[0] * t);
                let b = Rotation3::from_axis_angle(&Vector3::y_axis(), rates[1] * t);
                let c = Rotation3::from_axis_angle(&Vector3::x_axis(), rates[2] * t);
                let to_body = (a * b * c).inverse();
                let m = to_body * field;
                let up = to_body * Vector3::new(0.0, 0.0, -1.0);
                let omega = c.inverse() * (b.inverse() * Vector3::new(0.0, 0.0, rates[0]))
                    + c.inverse() * Vector3::new(0.0, rates[1], 0.0)
                    + Vector3::new(rates[2], 0.0, 0.0);
                let omega = omega.map(f64::to_degrees);
                let h = tilt_heading(m.into(), up.into(), [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])?;
                Some(GyroSample {
                    time: t,
                    heading_deg: h.heading_deg,
                    up: up.into(),
                    gyro_deg_s: axes.map(|(i, sign)| sign * omega[i] + bias[i]),
                })
            })
            .collect()
    }

    const TRUE_AXES: [(usize, f64); 3] = [(0, 1.0), (1, 1.0), (2, 1.0)];

    /// The fit finds the gyro's scale (±1: the frames' handedness) and its
    /// bias on the axes that turn the heading; the heading's rate it then
    /// gives is the heading's own.
    #[test]
    fn a_tumble_gives_the_gyros_scale_and_the_bias_that_turns_the_heading() {
        let bias = [1.5, -2.0, 0.8];
        let samples = tumble(60.0, bias, TRUE_AXES);
        let fit = fit_gyro3(&samples).unwrap();
        assert!((fit.scale.abs() - 1.0).abs() < 0.01, "{fit:?}");
        // A roll about the forward axis turns no heading: its bias is 0.
        assert_eq!(fit.bias_deg_s[0], 0.0);
        assert!((fit.bias_deg_s[1] - bias[1]).abs() < 0.05, "{fit:?}");
        assert!((fit.bias_deg_s[2] - bias[2]).abs() < 0.05, "{fit:?}");
        assert!(fit.heading_sd_deg < 0.1, "{fit:?}");
        // Between two readings pitched within the limit, the rate the gyro
        // gives carries the heading from one to the other.
        let (a, b) = (samples[100], samples[101]);
        let rate = |s: GyroSample| heading_rate(s.gyro_deg_s, fit.bias_deg_s, s.up);
        let (ra, rb) = (rate(a).unwrap(), rate(b).unwrap());
        let turned = fit.scale * 0.5 * (ra + rb) * (b.time - a.time);
        let moved = (b.heading_deg - a.heading_deg + 540.0).rem_euclid(360.0) - 180.0;
        assert!((turned - moved).abs() < 0.01, "{turned} {moved}");
    }

    /// A gyro whose columns are not the accelerometer's axes is refused
    /// with the reason, and so is a tumble too short to fit.
    #[test]
    fn a_gyro_in_other_axes_or_too_short_a_tumble_gives_no_fit_and_says_why() {
        let swapped = tumble(60.0, [0.0; 3], [(0, 1.0), (2, 1.0), (1, 1.0)]);
        let why = fit_gyro3(&swapped).unwrap_err();
        assert!(why.contains("does not follow the heading"), "{why}");
        let short = tumble(5.0, [0.0; 3], TRUE_AXES);
        let why = fit_gyro3(&short).unwrap_err();
        assert!(why.contains("of 20 needed"), "{why}");
        assert!(fit_gyro3(&[]).is_err());
    }
}
