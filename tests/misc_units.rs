//! Unit tests of the simulators, geomag, records, samples, number formatting,
//! file I/O and reports that need only the public API, moved out of src: one
//! module a source file, the tests unchanged.

mod geomag {
    use fieldcal::geomag::{CivilDate, GeomagError, ModelField, Place, compare_field, model_field};
    use fieldcal::model::tilt::RobustSpread;

    fn at(lat: f64, lon: f64, alt_m: f64, date: &str) -> ModelField {
        model_field(&Place {
            latitude_deg: lat,
            longitude_deg: lon,
            altitude_m: alt_m,
            date: CivilDate::parse(date).unwrap(),
        })
        .unwrap()
    }

    /// NOAA's published test values for WMM2025 (the WMM2025 Technical
    /// Report, Table 6, epoch 2025.0): (height km, lat, lon) → D, I, H, F.
    #[test]
    fn wmm2025_gives_noaas_test_values() {
        let cases = [
            (0.0, 80.0, 0.0, 1.28, 83.21, 6523.2, 55178.5),
            (0.0, 0.0, 120.0, -0.16, -14.93, 39677.9, 41064.3),
            (0.0, -80.0, -120.0, 68.78, -72.00, 16898.1, 54698.2),
            (100.0, 80.0, 0.0, 0.85, 83.26, 6216.7, 52964.9),
            (100.0, 0.0, 120.0, -0.15, -15.08, 37688.7, 39032.1),
            (100.0, -80.0, -120.0, 68.21, -72.19, 15917.1, 52035.0),
        ];
        for (h_km, lat, lon, d, i, h, f) in cases {
            let m = at(lat, lon, h_km * 1000.0, "2025-01-01");
            // The table's rounding (0.01°, 0.1 nT) and f32 arithmetic.
            assert!((m.declination_deg - d).abs() < 0.011, "{lat},{lon}: {m:?}");
            assert!((m.inclination_deg - i).abs() < 0.011, "{lat},{lon}: {m:?}");
            assert!((m.horizontal_intensity_nt - h).abs() < 1.0, "{m:?}");
            assert!((m.total_intensity_nt - f).abs() < 1.0, "{m:?}");
        }
    }

    #[test]
    fn dates_parse_and_bad_ones_are_refused() {
        assert_eq!(
            CivilDate::parse("2026-03-15").unwrap(),
            CivilDate {
                year: 2026,
                month: 3,
                day: 15
            }
        );
        for bad in ["2026-02-30", "2026-3-15", "15.03.2026", "", "2026-13-01"] {
            assert!(CivilDate::parse(bad).is_err(), "{bad}");
        }
        assert_eq!(
            CivilDate::from_unix_days(0).unwrap().to_string(),
            "1970-01-01"
        );
        assert_eq!(
            CivilDate::from_unix_days(20_454).unwrap().to_string(),
            "2026-01-01"
        );
    }

    #[test]
    fn outside_the_model_is_an_error_naming_the_range() {
        let err = model_field(&Place {
            latitude_deg: 50.0,
            longitude_deg: 8.0,
            altitude_m: 0.0,
            date: CivilDate::parse("2013-06-01").unwrap(),
        })
        .unwrap_err();
        assert!(err.to_string().contains("2020-01-01"), "{err}");
        let err = model_field(&Place {
            latitude_deg: 95.0,
            longitude_deg: 8.0,
            altitude_m: 0.0,
            date: CivilDate::parse("2026-06-01").unwrap(),
        })
        .unwrap_err();
        assert!(matches!(err, GeomagError::Model { .. }), "{err}");
    }

    #[test]
    fn a_field_within_the_allowances_agrees_and_one_beyond_does_not() {
        let model = at(50.0, 8.0, 100.0, "2026-06-01");
        let incl = |median: f64| RobustSpread {
            median,
            spread: 1.0,
            n: 1000,
        };
        let c = compare_field(
            &incl(model.inclination_deg + 1.0),
            Some(model.total_intensity_nt * 1.03),
            &model,
        );
        assert!(
            c.inclination_agrees && c.intensity_agrees == Some(true),
            "{c:?}"
        );
        let c = compare_field(
            &incl(model.inclination_deg + 5.0),
            Some(model.total_intensity_nt),
            &model,
        );
        assert!(!c.inclination_agrees, "{c:?}");
        assert!(c.verdict.contains("disturbed"), "{}", c.verdict);
        let c = compare_field(
            &incl(model.inclination_deg),
            Some(model.total_intensity_nt * 1.10),
            &model,
        );
        assert_eq!(c.intensity_agrees, Some(false), "{c:?}");
        let c = compare_field(
            &incl(-model.inclination_deg),
            Some(model.total_intensity_nt),
            &model,
        );
        assert!(!c.inclination_agrees, "{c:?}");
        assert!(c.verdict.contains("mirrored"), "{}", c.verdict);
        let c = compare_field(&incl(model.inclination_deg), None, &model);
        assert_eq!(c.intensity_agrees, None);
        assert!(c.verdict.contains("--mag-units"));
    }
}

mod atomic {
    use fieldcal::io::atomic::AtomicFile;
    use std::io::Write;
    use std::{fs, io};

    #[test]
    fn replaces_only_on_commit() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.csv");
        fs::write(&target, "old").unwrap();
        {
            let mut f = AtomicFile::create(&target).unwrap();
            f.as_file_mut().write_all(b"new").unwrap();
            // dropped without commit
        }
        assert_eq!(fs::read_to_string(&target).unwrap(), "old");
        assert_eq!(
            fs::read_dir(dir.path()).unwrap().count(),
            1,
            "temp file left behind"
        );
        let mut f = AtomicFile::create(&target).unwrap();
        f.as_file_mut().write_all(b"new").unwrap();
        f.commit().unwrap();
        assert_eq!(fs::read_to_string(&target).unwrap(), "new");
    }

    #[test]
    fn replacing_keeps_the_mode_of_the_old_file() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("cal.json");
        fs::write(&target, "old").unwrap();
        fs::set_permissions(&target, fs::Permissions::from_mode(0o600)).unwrap();
        let mut f = AtomicFile::create(&target).unwrap();
        f.as_file_mut().write_all(b"new").unwrap();
        f.commit().unwrap();
        assert_eq!(fs::read_to_string(&target).unwrap(), "new");
        let mode = fs::metadata(&target).unwrap().permissions().mode() & 0o7777;
        assert_eq!(mode, 0o600);
    }

    #[test]
    fn commit_new_never_replaces_and_leaves_no_temp_file() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.csv");
        let mut f = AtomicFile::create(&target).unwrap();
        f.as_file_mut().write_all(b"first").unwrap();
        f.commit_new().unwrap();
        assert_eq!(fs::read_to_string(&target).unwrap(), "first");

        // Created after this writer started: still not replaced.
        let mut f = AtomicFile::create(&target).unwrap();
        f.as_file_mut().write_all(b"second").unwrap();
        let err = f.commit_new().unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::AlreadyExists);
        assert_eq!(fs::read_to_string(&target).unwrap(), "first");
        let names: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.csv")]);
    }
}

#[cfg(target_os = "linux")]
mod atomic_unnamed {
    use fieldcal::io::atomic::AtomicFile;
    use std::fs;
    use std::io::Write;

    /// While it is being written, the new content has no name in the
    /// directory: a writer killed at this point leaves nothing behind.
    #[test]
    fn the_content_has_no_name_until_commit() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("big.fcap");
        let mut f = AtomicFile::create(&target).unwrap();
        f.as_file_mut().write_all(&[0u8; 4096]).unwrap();
        let names = || -> Vec<_> {
            fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().file_name())
                .collect()
        };
        assert!(names().is_empty(), "named while written: {:?}", names());
        f.commit_new().unwrap();
        assert_eq!(names(), vec![std::ffi::OsString::from("big.fcap")]);
        assert_eq!(fs::metadata(&target).unwrap().len(), 4096);

        let mut f = AtomicFile::create(&target).unwrap();
        f.as_file_mut().write_all(b"short").unwrap();
        assert_eq!(names().len(), 1);
        f.commit().unwrap();
        assert_eq!(names(), vec![std::ffi::OsString::from("big.fcap")]);
        assert_eq!(fs::read_to_string(&target).unwrap(), "short");
    }
}

mod io {
    use fieldcal::io::{MAX_ECHO_CHARS, excerpt, name_list};

    #[test]
    fn a_long_value_is_cut_and_its_length_given() {
        let long = "9".repeat(100_000_000 / 1000);
        let shown = excerpt(&long);
        assert!(shown.len() < 100, "{shown}");
        assert!(shown.ends_with("… (100000 bytes)"), "{shown}");
        assert_eq!(excerpt("12.5x"), "12.5x");
        // Cut on a character boundary.
        let accents = "é".repeat(60);
        assert_eq!(
            excerpt(&accents).chars().filter(|&c| c == 'é').count(),
            MAX_ECHO_CHARS
        );
    }

    #[test]
    fn a_long_list_of_names_is_capped() {
        let names: Vec<String> = (0..1000).map(|i| format!("c{i}")).collect();
        let shown = name_list(&names);
        assert!(shown.ends_with("c23 … and 976 more"), "{shown}");
        assert_eq!(name_list(&["t", "x"]), "t, x");
    }
}

mod regular {
    use fieldcal::io::regular::{SpecialKind, not_regular_kind, open_regular, read_regular};
    use std::io;
    use std::path::Path;
    use std::time::{Duration, Instant};

    fn mkfifo(path: &Path) {
        let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates a node.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    #[test]
    fn refuses_special_files_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        mkfifo(&fifo);
        let started = Instant::now();
        let err = open_regular(&fifo).unwrap_err();
        assert_eq!(not_regular_kind(&err), Some(SpecialKind::Fifo));
        assert!(err.to_string().contains("FIFO"), "{err}");
        let err = read_regular(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert_eq!(not_regular_kind(&err), Some(SpecialKind::CharDevice));
        let err = open_regular(dir.path()).unwrap_err();
        assert_eq!(not_regular_kind(&err), Some(SpecialKind::Directory));
        assert!(started.elapsed() < Duration::from_secs(2));
        let missing = open_regular(&dir.path().join("missing")).unwrap_err();
        assert_eq!(missing.kind(), io::ErrorKind::NotFound);
        assert_eq!(not_regular_kind(&missing), None);
    }

    #[test]
    fn follows_links_to_files_and_caps_the_size() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.json");
        std::fs::write(&file, b"0123456789").unwrap();
        let link = dir.path().join("link.json");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        assert_eq!(read_regular(&link, 10).unwrap(), b"0123456789");
        let err = read_regular(&file, 9).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidData);
        assert!(err.to_string().contains("more than 9 bytes"), "{err}");
        let fifo_link = dir.path().join("fifo-link");
        mkfifo(&dir.path().join("pipe"));
        std::os::unix::fs::symlink(dir.path().join("pipe"), &fifo_link).unwrap();
        let err = open_regular(&fifo_link).unwrap_err();
        assert_eq!(not_regular_kind(&err), Some(SpecialKind::Fifo));
    }
}

mod numfmt {
    use fieldcal::numfmt::significant;

    #[test]
    fn significant_digits() {
        assert_eq!(significant(1.234567891, 6), "1.23457");
        assert_eq!(significant(-24000.123456, 6), "-24000.1");
        assert_eq!(significant(0.000123456789, 4), "0.0001235");
        assert_eq!(significant(0.0, 6), "0");
        assert_eq!(significant(1.5e-9, 3), "1.50e-9");
    }
}

mod record {
    use fieldcal::record::{NothingRecorded, RecordSummary};
    use std::time::Duration;

    const SECS: Duration = Duration::from_secs(3);

    #[test]
    fn a_recording_with_bytes_is_accepted_whatever_the_port_does_now() {
        let summary = RecordSummary {
            chunks: 1,
            bytes: 23,
            ..Default::default()
        };
        assert_eq!(summary.check_recorded("/dev/ttyUSB0", false, SECS), Ok(()));
    }

    #[test]
    fn an_empty_recording_says_why_from_what_the_source_saw() {
        let empty = RecordSummary::default();
        let port = "/dev/ttyUSB0".to_string();
        assert_eq!(
            empty.check_recorded(&port, false, SECS),
            Err(NothingRecorded::NoSuchDevice {
                port: port.clone(),
                seconds: 3.0
            })
        );
        assert_eq!(
            empty.check_recorded(&port, true, SECS),
            Err(NothingRecorded::NeverReady {
                port: port.clone(),
                seconds: 3.0
            })
        );
        let silent = RecordSummary {
            connects: 1,
            ..Default::default()
        };
        let err = silent.check_recorded(&port, true, SECS).unwrap_err();
        assert_eq!(
            err,
            NothingRecorded::NoBytes {
                port: port.clone(),
                seconds: 3.0
            }
        );
        let text = err.to_string();
        assert!(text.starts_with("/dev/ttyUSB0: "), "{text}");
        assert!(text.contains("sent no bytes in 3.0 s"), "{text}");
    }
}

mod fit3 {
    use fieldcal::report::fit3::infer_units;

    #[test]
    fn accelerometer_columns_are_in_g() {
        assert_eq!(infer_units(["acc_x", "acc_y", "acc_z"]), Some("g"));
        assert_eq!(infer_units(["AccX", "accel_y", "acc_z"]), Some("g"));
        assert_eq!(infer_units(["acc_x", "acc_y", "mag_z"]), None);
        assert_eq!(infer_units(["mag_x", "mag_y", "mag_z"]), None);
    }
}

mod plots {
    use fieldcal::report::plots::{
        INDEX_FILE, MAX_POINTS, ReportData, ReportError, demo_data, render_figures, write_report,
    };
    use std::path::PathBuf;

    fn svg_files(written: &[PathBuf]) -> Vec<&PathBuf> {
        written
            .iter()
            .filter(|p| p.extension().is_some_and(|e| e == "svg"))
            .collect()
    }

    #[test]
    fn writes_every_figure_and_the_page() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("report");
        let data = demo_data(3000);
        let written = write_report(&out, &data).unwrap();
        let names: Vec<String> = written
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            [
                "raw_ellipse.svg",
                "calibrated.svg",
                "residual_heading.svg",
                "residual_time.svg",
                "residual_covariate_1.svg",
                "ladder.svg",
                "index.html"
            ]
        );
        let index = std::fs::read_to_string(out.join(INDEX_FILE)).unwrap();
        for path in svg_files(&written) {
            assert!(path.exists(), "{}", path.display());
            let svg = std::fs::read_to_string(path).unwrap();
            assert!(svg.starts_with("<svg"), "{}", path.display());
            assert!(svg.trim_end().ends_with("</svg>"), "{}", path.display());
            assert!(svg.contains("<text"), "{} has no text", path.display());
            assert!(svg.contains("font-family=\"sans-serif\""));
            assert_no_urls(&svg);
            let name = path.file_name().unwrap().to_string_lossy();
            assert!(
                index.contains(&format!("<img src=\"{name}\"")),
                "index.html does not show {name}"
            );
        }
        assert_no_urls(&index);
        // The title is escaped, the summary inserted as given.
        assert!(index.contains("mag_y &lt;&amp;&gt;"));
        assert!(index.contains("<code>cross-axis</code>"));
        // Axis labels with units and the noise floor are drawn.
        let heading = std::fs::read_to_string(out.join("residual_heading.svg")).unwrap();
        assert!(heading.contains("heading (°)"));
        assert!(heading.contains("noise floor ±0.20%"));
        let ladder = std::fs::read_to_string(out.join("ladder.svg")).unwrap();
        assert!(ladder.contains("+cross-axis+drift"));
    }

    #[test]
    fn a_spike_is_drawn_at_the_edge_and_counted() {
        let dir = tempfile::tempdir().unwrap();
        let mut data = demo_data(400);
        data.residual_before[10] = 5.0;
        data.residual_after[10] = 4.0;
        data.residual_before[20] = -6.0;
        write_report(dir.path(), &data).unwrap();
        let heading = std::fs::read_to_string(dir.path().join("residual_heading.svg")).unwrap();
        assert!(
            heading.contains("2 samples beyond the scale, at its edge"),
            "no edge note in the heading plot"
        );
        // The spikes (500 % and -600 %) do not set the scale.
        let largest_tick = svg_texts(&heading)
            .iter()
            .filter(|(tag, _)| tag.contains("text-anchor=\"end\""))
            .filter_map(|(_, t)| t.parse::<f64>().ok())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(largest_tick > 0.0 && largest_tick < 50.0, "{largest_tick}");
        let clean = demo_data(400);
        write_report(dir.path(), &clean).unwrap();
        let heading = std::fs::read_to_string(dir.path().join("residual_heading.svg")).unwrap();
        assert!(!heading.contains("beyond the scale"));
    }

    /// The opening tag and the contents of every `<text>` element of an SVG
    /// written by plotters (which puts the contents on a line of their own).
    /// Y-axis tick labels are the right-aligned ones (`text-anchor="end"`).
    fn svg_texts(svg: &str) -> Vec<(String, String)> {
        let mut texts = Vec::new();
        let mut lines = svg.lines();
        while let Some(line) = lines.next() {
            if line.starts_with("<text")
                && let Some(content) = lines.next()
            {
                texts.push((line.to_string(), content.trim().to_string()));
            }
        }
        texts
    }

    fn assert_no_urls(text: &str) {
        let stripped = text.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
        assert!(!stripped.contains("http://"), "a URL in {stripped:.200}");
        assert!(!stripped.contains("https://"), "a URL in {stripped:.200}");
    }

    #[test]
    fn large_inputs_are_thinned_and_say_so() {
        let data = demo_data(50_000);
        let figures = render_figures(&data).unwrap();
        let heading = figures
            .iter()
            .find(|f| f.file == "residual_heading.svg")
            .unwrap();
        assert!(heading.title.contains("1 in 10 of 50000 samples shown"));
        assert!(heading.caption.contains("every 10th"));
        assert!(heading.svg.matches("<circle").count() <= 2 * MAX_POINTS + 10);
        for f in &figures {
            assert!(
                f.svg.len() < 1_500_000,
                "{} is {} bytes",
                f.file,
                f.svg.len()
            );
        }
    }

    #[test]
    fn optional_parts_may_be_missing() {
        let mut data = demo_data(100);
        data.time = None;
        data.covariates.clear();
        data.ladder.clear();
        data.ellipse.clear();
        data.calibrated_after.clear();
        data.residual_after.clear();
        data.noise_floor = f64::NAN;
        data.residual_before[3] = f64::NAN;
        data.raw.0[5] = f64::INFINITY;
        let figures = render_figures(&data).unwrap();
        let files: Vec<&str> = figures.iter().map(|f| f.file.as_str()).collect();
        assert_eq!(
            files,
            ["raw_ellipse.svg", "calibrated.svg", "residual_heading.svg"]
        );
        assert!(figures.iter().all(|f| !f.svg.contains("NaN")));
    }

    #[test]
    fn degenerate_values_do_not_panic() {
        let mut data = demo_data(10);
        data.raw = (vec![1.0; 10], vec![1.0; 10]);
        data.residual_before = vec![0.0; 10];
        data.heading_deg = vec![f64::NAN; 10];
        data.ladder = vec![("paper".into(), f64::NAN)];
        render_figures(&data).unwrap();
    }

    #[test]
    fn empty_or_inconsistent_data_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let err = write_report(dir.path(), &ReportData::default()).unwrap_err();
        assert!(matches!(err, ReportError::Empty { .. }), "{err}");
        let mut data = demo_data(20);
        data.heading_deg.pop();
        let err = write_report(dir.path(), &data).unwrap_err();
        assert!(
            err.to_string()
                .contains("heading_deg has 19 values, expected 20")
        );
        let mut data = demo_data(20);
        data.covariates[0].1.push(1.0);
        assert!(write_report(dir.path(), &data).is_err());
    }

    #[test]
    fn unwritable_directory_names_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a-file");
        std::fs::write(&file, "x").unwrap();
        let target = file.join("report");
        let err = write_report(&target, &demo_data(20)).unwrap_err();
        let text = err.to_string();
        assert!(matches!(err, ReportError::CreateDir { .. }), "{text}");
        assert!(text.contains(&target.display().to_string()), "{text}");
        assert!(text.contains("choose another directory"), "{text}");
    }
}

mod sample {
    use fieldcal::sample::{Dataset, DatasetError};

    #[test]
    fn new_rejects_ragged_columns() {
        let err = Dataset::new(
            "x",
            "y",
            Some(vec![0.0]),
            vec![1.0, 2.0],
            vec![1.0, 2.0],
            vec![],
        )
        .unwrap_err();
        assert_eq!(
            err,
            DatasetError::LengthMismatch {
                name: "t".into(),
                found: 1,
                reference: "x".into(),
                expected: 2
            }
        );
    }

    #[test]
    fn new_rejects_nan() {
        let err = Dataset::from_xy(vec![1.0, f64::NAN], vec![1.0, 2.0]).unwrap_err();
        assert!(matches!(err, DatasetError::NonFinite { row: 1, .. }));
    }
}

mod sim {
    use fieldcal::sim::SimSensor;

    #[test]
    fn same_seed_same_data_other_seed_other_noise() {
        let s = SimSensor {
            noise: 2.0,
            ..Default::default()
        };
        let a = s.simulate().unwrap();
        assert_eq!(a, s.simulate().unwrap());
        let b = SimSensor { seed: 2, ..s }.simulate().unwrap();
        assert_ne!(a.x, b.x);
        assert_eq!(a.len(), 200);
    }

    #[test]
    fn truth_calibrates_noiseless_samples_onto_the_circle() {
        let s = SimSensor {
            gain_x: 1.4,
            gain_y: 0.9,
            offset_x: 300.0,
            offset_y: -120.0,
            ..Default::default()
        };
        let d = s.simulate().unwrap();
        let truth = s.truth();
        assert!(truth.rms(&d.x, &d.y) < 1e-12);
    }

    #[test]
    fn refuses_nonsense() {
        let s = SimSensor {
            period: 0.0,
            ..Default::default()
        };
        assert_eq!(
            s.simulate().unwrap_err().to_string(),
            "--period must be a positive number of seconds, got 0"
        );
    }
}

mod sim3 {
    use fieldcal::sim3::{
        ImuMotion, MAX_SAMPLES, Motion3, Sim3Error, SimAxes3, SimImu3, SimSensor3, Wire3Error,
    };

    #[test]
    fn noiseless_readings_calibrate_onto_the_sphere() {
        let sim = SimSensor3 {
            matrix: [[1.1, 0.1, -0.05], [0.1, 0.9, 0.15], [-0.05, 0.15, 1.0]],
            offset: [100.0, -50.0, 20.0],
            r: 400.0,
            noise: 0.0,
            n: 500,
            motion: Motion3::Tumble {
                turns: 12.0,
                axis_path_rad: 6.0,
            },
            seed: 3,
        };
        let raw = sim.simulate().unwrap();
        let (o, w, r) = sim.truth();
        for p in raw {
            let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
            let c: Vec<f64> = (0..3)
                .map(|i| w[i][0] * d[0] + w[i][1] * d[1] + w[i][2] * d[2])
                .collect();
            let m = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
            assert!((m / r - 1.0).abs() < 1e-12, "{m} vs {r}");
        }
    }

    #[test]
    fn a_tumble_covers_the_sphere_and_a_ring_does_not() {
        let tumble = SimSensor3 {
            matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            offset: [0.0; 3],
            r: 1.0,
            noise: 0.0,
            n: 2000,
            motion: Motion3::Tumble {
                turns: 12.0,
                axis_path_rad: 6.0,
            },
            seed: 1,
        };
        let cov = fieldcal::model::sphere::coverage(tumble.directions().unwrap());
        assert!(cov.fraction >= 0.9, "{}", cov.fraction);
        let ring = SimSensor3 {
            motion: Motion3::WobblingTurn {
                turns: 2.0,
                inclination_deg: 0.0,
                tilt_deg: 0.0,
            },
            ..tumble
        };
        let cov = fieldcal::model::sphere::coverage(ring.directions().unwrap());
        assert!(cov.fraction <= 0.2, "{}", cov.fraction);
    }

    #[test]
    fn refuses_a_matrix_that_is_not_spd() {
        let sim = SimSensor3 {
            matrix: [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
            offset: [0.0; 3],
            r: 1.0,
            noise: 0.0,
            n: 10,
            motion: Motion3::Cap {
                half_angle_deg: 180.0,
            },
            seed: 1,
        };
        assert_eq!(sim.simulate(), Err(Sim3Error::NotSpd));
    }

    fn imu(motion: ImuMotion) -> SimImu3 {
        SimImu3 {
            field: 500.0,
            inclination_deg: 60.0,
            gravity: 4096.0,
            mag: SimAxes3 {
                matrix: [[1.1, 0.05, 0.0], [0.05, 0.95, -0.03], [0.0, -0.03, 1.0]],
                offset: [120.0, -80.0, 40.0],
                noise: 0.0,
            },
            accel: SimAxes3 {
                matrix: [[1.01, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.0]],
                offset: [30.0, -20.0, 50.0],
                noise: 0.0,
            },
            gyro_noise: 0.0,
            period: 0.05,
            n: 1000,
            motion,
            seed: 4,
        }
    }

    /// Noiseless readings calibrate back to the field and gravity, and the
    /// tilt-compensated heading of the calibrated pair is the true one.
    #[test]
    fn an_imu_gives_the_field_gravity_and_the_true_heading() {
        for motion in [
            ImuMotion::Tumble {
                turns: 6.0,
                axis_path_rad: 3.0,
            },
            ImuMotion::WobblingTurn {
                turns: 2.0,
                tilt_deg: 30.0,
            },
            ImuMotion::Static { poses: 8 },
        ] {
            let sim = imu(motion);
            let samples = sim.simulate().unwrap();
            let (mo, mw, mr) = sim.mag_truth();
            let (ao, aw, ar) = sim.accel_truth();
            let cal = |o: [f64; 3], w: [[f64; 3]; 3], p: [f64; 3]| {
                let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
                [0, 1, 2].map(|i| w[i][0] * d[0] + w[i][1] * d[1] + w[i][2] * d[2])
            };
            let mut max_tilt: f64 = 0.0;
            for s in &samples {
                let m = cal(mo, mw, s.mag);
                let a = cal(ao, aw, s.accel);
                let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!((norm(m) / mr - 1.0).abs() < 1e-9);
                assert!((norm(a) / ar - 1.0).abs() < 1e-9);
                let h = fieldcal::model::tilt::tilt_heading(m, a, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
                    .unwrap();
                // W (det 1) is the true one up to a scale: directions hold.
                let d = fieldcal::model::tilt::heading_difference(h.heading_deg, s.heading_deg);
                assert!(
                    d.abs() < 1e-6,
                    "{motion:?}: {} vs {}",
                    h.heading_deg,
                    s.heading_deg
                );
                assert!((h.tilt_deg - s.tilt_deg).abs() < 1e-6);
                assert!((h.inclination_deg - 60.0).abs() < 1e-6);
                max_tilt = max_tilt.max(s.tilt_deg);
            }
            if let ImuMotion::WobblingTurn { .. } = motion {
                assert!(max_tilt > 25.0 && max_tilt < 43.0, "{max_tilt}");
            }
        }
    }

    /// The gyro is the body rate: integrated about body z over a level
    /// turn, it gives the turn (clockwise seen from above is −z).
    #[test]
    fn the_gyro_integrates_to_the_turn() {
        let sim = imu(ImuMotion::WobblingTurn {
            turns: 2.0,
            tilt_deg: 0.0,
        });
        let samples = sim.simulate().unwrap();
        let total: f64 = samples.iter().map(|s| s.gyro[2] * sim.period).sum();
        assert!((total + 720.0).abs() < 1.0, "{total}");
        // A tumble covers the sphere of field directions.
        let sim = imu(ImuMotion::Tumble {
            turns: 12.0,
            axis_path_rad: 6.0,
        });
        let sim = SimImu3 { n: 2000, ..sim };
        let samples = sim.simulate().unwrap();
        let (o, w, _) = sim.mag_truth();
        let dirs = samples.iter().map(|s| {
            let d = [s.mag[0] - o[0], s.mag[1] - o[1], s.mag[2] - o[2]];
            [0, 1, 2].map(|i| w[i][0] * d[0] + w[i][1] * d[1] + w[i][2] * d[2])
        });
        let cov = fieldcal::model::sphere::coverage(dirs);
        assert!(cov.fraction >= 0.9, "{}", cov.fraction);
    }

    #[test]
    fn an_imu_refuses_bad_settings_and_oversized_captures() {
        let sim = imu(ImuMotion::Static { poses: 6 });
        let bad = SimImu3 {
            inclination_deg: 95.0,
            ..sim.clone()
        };
        assert!(bad.simulate().is_err());
        let bad = SimImu3 {
            mag: SimAxes3 {
                matrix: [[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                ..sim.mag
            },
            ..sim.clone()
        };
        assert_eq!(bad.simulate(), Err(Sim3Error::NotSpd));
        let big = SimImu3 {
            n: MAX_SAMPLES,
            ..sim.clone()
        };
        assert!(matches!(
            big.check_capture(0.9),
            Err(Wire3Error::TooLarge { .. })
        ));
        assert!(matches!(
            sim.check_capture(0.95),
            Err(Wire3Error::Garbage(_))
        ));
        let loud = SimImu3 {
            field: 40_000.0,
            ..sim
        };
        assert!(matches!(
            loud.falcon_capture(0.0, 50),
            Err(Wire3Error::OutOfRange { .. })
        ));
    }
}
