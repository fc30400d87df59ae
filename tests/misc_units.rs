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

    /// Record times are the monotonic intervals from the recording's start
    /// to each chunk's arrival, not the wall clock's (which NTP may step
    /// during a recording), to the nanosecond and in order.
    #[test]
    fn record_times_are_the_monotonic_intervals_from_the_start() {
        use fieldcal::capture::{
            CaptureFile, CaptureHeader, CaptureWriter, StreamInfo, StreamKind, VERSION,
            parse_capture,
        };
        use fieldcal::source::SourceEvent;
        use std::time::Instant;
        use tokio::sync::{mpsc, watch};

        let header = CaptureHeader {
            version: VERSION,
            streams: vec![StreamInfo {
                id: 0,
                kind: StreamKind::Falcon,
            }],
            port: None,
            baud: None,
            started_unix: 1_700_000_000.0,
            nominal_period_s: 0.05,
            note: None,
        };
        let started = Instant::now();
        let arrivals = [0.05, 0.100_000_001, 0.15, 3.0];
        let (tx, rx) = mpsc::channel(8);
        for (i, &after) in arrivals.iter().enumerate() {
            tx.try_send(SourceEvent::Raw {
                at: started + Duration::from_secs_f64(after),
                stream: 0,
                bytes: vec![i as u8; 3],
            })
            .unwrap();
        }
        drop(tx);
        let (_stop_tx, stop_rx) = watch::channel(false);
        let mut writer = CaptureWriter::new(Vec::new(), &header).unwrap();
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let summary = runtime
            .block_on(fieldcal::record::record(
                rx,
                &mut writer,
                started,
                None,
                stop_rx,
            ))
            .unwrap();
        assert_eq!(summary.chunks, 4);
        let bytes = writer.into_inner().unwrap();
        let Ok(CaptureFile::Capture { chunks, .. }) = parse_capture(&bytes, "test") else {
            panic!("the recording reads back as a capture");
        };
        let times: Vec<f64> = chunks.iter().map(|c| c.time).collect();
        assert_eq!(times, arrivals);
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

mod capture {
    use std::io::{self, Write};

    use fieldcal::capture::*;
    use fieldcal::protocol::chips::Chip;

    fn header() -> CaptureHeader {
        CaptureHeader {
            version: VERSION,
            streams: vec![
                StreamInfo {
                    id: 0,
                    kind: StreamKind::Falcon,
                },
                StreamInfo {
                    id: 3,
                    kind: StreamKind::Chip {
                        chip: Chip::Mpu6050,
                        address: 0x68,
                    },
                },
            ],
            port: Some("/dev/ttyUSB0".into()),
            baud: Some(38400),
            started_unix: 1_700_000_000.25,
            nominal_period_s: 0.05,
            note: Some("bench, turned by hand".into()),
        }
    }

    fn chunks() -> Vec<Chunk> {
        vec![
            Chunk {
                time: nanos_to_seconds(0),
                stream: 0,
                bytes: vec![0x02, 0xFF, 0x00],
            },
            Chunk {
                time: nanos_to_seconds(1_234_567_891),
                stream: 3,
                bytes: (0..14).collect(),
            },
            Chunk {
                time: nanos_to_seconds(1_234_567_891),
                stream: 0,
                bytes: vec![],
            },
            Chunk {
                time: nanos_to_seconds(86_400_000_000_001),
                stream: 0,
                bytes: vec![0x10; 23],
            },
        ]
    }

    fn write(header: &CaptureHeader, chunks: &[Chunk]) -> Vec<u8> {
        let mut w = CaptureWriter::new(Vec::new(), header).unwrap();
        for c in chunks {
            w.write_chunk(c.time, c.stream, &c.bytes).unwrap();
        }
        w.into_inner().unwrap()
    }

    /// Where each record starts, and the end of the file.
    fn record_starts(header: &CaptureHeader, chunks: &[Chunk]) -> Vec<usize> {
        let json = serde_json::to_vec(header).unwrap();
        let mut at = MAGIC.len() + 4 + json.len();
        let mut starts = vec![at];
        for c in chunks {
            at += RECORD_OVERHEAD + c.bytes.len();
            starts.push(at);
        }
        starts
    }

    /// A record with a correct CRC, whatever its stream.
    fn record(time_ns: u64, stream: u8, data: &[u8]) -> Vec<u8> {
        let mut r = time_ns.to_le_bytes().to_vec();
        r.push(stream);
        r.extend_from_slice(&(data.len() as u32).to_le_bytes());
        r.extend_from_slice(data);
        let crc = crc32(&r);
        r.extend_from_slice(&crc.to_le_bytes());
        r
    }

    fn with_header_json(json: &str) -> Vec<u8> {
        let mut f = MAGIC.to_vec();
        f.extend_from_slice(&(json.len() as u32).to_le_bytes());
        f.extend_from_slice(json.as_bytes());
        f
    }

    fn capture(file: CaptureFile) -> (CaptureHeader, Vec<Chunk>, Option<Truncation>) {
        match file {
            CaptureFile::Capture {
                header,
                chunks,
                truncated,
            } => (header, chunks, truncated),
            CaptureFile::Raw { .. } => panic!("read as a raw dump"),
        }
    }

    #[test]
    fn crc32_matches_the_standard_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    #[test]
    fn header_json_has_the_documented_shape() {
        let json = serde_json::to_string(&header()).unwrap();
        assert_eq!(
            json,
            r#"{"version":1,"streams":[{"id":0,"kind":"falcon"},{"id":3,"kind":"chip","chip":"mpu6050","address":104}],"port":"/dev/ttyUSB0","baud":38400,"started_unix":1700000000.25,"nominal_period_s":0.05,"note":"bench, turned by hand"}"#
        );
        let bare = CaptureHeader {
            port: None,
            baud: None,
            note: None,
            ..header()
        };
        let json = serde_json::to_string(&bare).unwrap();
        assert!(!json.contains("port") && !json.contains("null"), "{json}");
    }

    #[test]
    fn round_trip_keeps_header_bytes_and_nanoseconds() {
        let file = write(&header(), &chunks());
        assert!(file.starts_with(MAGIC));
        assert_eq!(
            file.len(),
            *record_starts(&header(), &chunks()).last().unwrap()
        );
        let (h, c, t) = capture(parse_capture(&file, "rt.cap").unwrap());
        assert_eq!(h, header());
        assert_eq!(c, chunks());
        assert_eq!(t, None);
        assert_eq!(seconds_to_nanos(c[3].time), Some(86_400_000_000_001));
    }

    #[test]
    fn write_chunk_ns_is_exact_and_counts() {
        let mut w = CaptureWriter::new(Vec::new(), &header()).unwrap();
        w.write_chunk_ns(u64::MAX, 3, b"x").unwrap();
        w.write_chunk_ns(7, 0, b"y").unwrap();
        assert_eq!(w.chunks_written(), 2);
        let file = w.into_inner().unwrap();
        let (_, c, _) = capture(parse_capture(&file, "ns.cap").unwrap());
        assert_eq!(c[0].time, nanos_to_seconds(u64::MAX));
        assert_eq!(c[1].time, 7e-9);
    }

    #[test]
    fn a_capture_with_no_chunks_is_valid() {
        let file = write(&header(), &[]);
        let (h, c, t) = capture(parse_capture(&file, "none.cap").unwrap());
        assert_eq!((h, c.len(), t), (header(), 0, None));
    }

    #[test]
    fn header_times_read_back_exactly() {
        // serde_json alone reads these one unit in the last place off.
        for started_unix in [1_609_942_654.659_391_9, 195_678_736.821_979_46, -4.0e-7] {
            let h = CaptureHeader {
                started_unix,
                nominal_period_s: 0.030_000_000_000_000_002,
                ..header()
            };
            let (back, _, _) = capture(parse_capture(&write(&h, &[]), "t.cap").unwrap());
            assert_eq!(back, h);
        }
        // A look-alike key elsewhere does not change the value.
        let json = r#"{"version":1,"streams":[{"id":0,"kind":"falcon","started_unix":5}],"started_unix":1609942654.6593919,"nominal_period_s":0.05}"#;
        let (h, _, _) = capture(parse_capture(&with_header_json(json), "k.cap").unwrap());
        assert_eq!(h.started_unix, 1_609_942_654.659_391_9);
    }

    #[test]
    fn seconds_to_nanos_rounds_and_rejects_non_times() {
        assert_eq!(seconds_to_nanos(0.0), Some(0));
        assert_eq!(seconds_to_nanos(1.5e-9), Some(2));
        assert_eq!(seconds_to_nanos(0.05), Some(50_000_000));
        assert_eq!(seconds_to_nanos(-1e-12), None);
        assert_eq!(seconds_to_nanos(f64::NAN), None);
        assert_eq!(seconds_to_nanos(f64::INFINITY), None);
        assert_eq!(seconds_to_nanos(1.9e10), None);
    }

    #[test]
    fn other_files_are_raw_dumps() {
        for bytes in [
            &b"\x02\x00\x01garbage"[..],
            b"x",
            b"FIELDCAL-CAPTURX and more",
            b"fieldcal-capture",
        ] {
            match parse_capture(bytes, "dump.bin").unwrap() {
                CaptureFile::Raw { bytes: b } => assert_eq!(b, bytes),
                other => panic!("{other:?}"),
            }
        }
    }

    #[test]
    fn empty_file_is_an_error_naming_it() {
        let err = parse_capture(b"", "empty.cap").unwrap_err();
        assert!(matches!(err, CaptureError::Empty { .. }));
        let msg = err.to_string();
        assert!(
            msg.starts_with("empty.cap: ") && msg.contains("nothing to replay"),
            "{msg}"
        );
    }

    #[test]
    fn bad_header_json_names_file_and_offset() {
        let json = "{\"version\": 1,";
        let err = parse_capture(&with_header_json(json), "bad.cap").unwrap_err();
        // Where serde_json noticed: at the end of the text.
        assert!(
            matches!(err, CaptureError::BadHeader { offset: 33, .. }),
            "{err:?}"
        );
        let msg = err.to_string();
        assert!(
            msg.starts_with("bad.cap: byte 33: ") && msg.contains("not valid JSON"),
            "{msg}"
        );
        assert!(msg.contains("record again"), "{msg}");
    }

    #[test]
    fn damaged_headers_are_errors() {
        let cases: &[(&str, &str)] = &[
            ("[1, 2]", "not a JSON object"),
            ("{}", "no `version`"),
            (r#"{"version": "1"}"#, "not a whole number"),
            (r#"{"version": 1}"#, "missing field `streams`"),
            (
                r#"{"version":1,"streams":[],"started_unix":0,"nominal_period_s":0.05}"#,
                "no streams",
            ),
            (
                r#"{"version":1,"streams":[{"id":0,"kind":"falcon"},{"id":0,"kind":"falcon"}],"started_unix":0,"nominal_period_s":0.05}"#,
                "stream 0 twice",
            ),
            (
                r#"{"version":1,"streams":[{"id":0,"kind":"telepathy"}],"started_unix":0,"nominal_period_s":0.05}"#,
                "telepathy",
            ),
            (
                r#"{"version":1,"streams":[{"id":1,"kind":"chip","chip":"bmp280","address":118}],"started_unix":0,"nominal_period_s":0.05}"#,
                "bmp280",
            ),
            (
                r#"{"version":1,"streams":[{"id":1,"kind":"chip","chip":"adxl345","address":166}],"started_unix":0,"nominal_period_s":0.05}"#,
                "not a 7-bit",
            ),
            (
                r#"{"version":1,"streams":[{"id":0,"kind":"falcon"}],"started_unix":0,"nominal_period_s":0}"#,
                "not a positive",
            ),
            (
                r#"{"version":1,"streams":[{"id":0,"kind":"falcon"}],"started_unix":null,"nominal_period_s":0.05}"#,
                "expected f64",
            ),
        ];
        for (json, expected) in cases {
            let err = parse_capture(&with_header_json(json), "h.cap").unwrap_err();
            let msg = err.to_string();
            let CaptureError::BadHeader { offset, .. } = err else {
                panic!("{json}: {err:?}");
            };
            assert!(msg.contains(expected), "{json}: {msg}");
            assert!((20..=20 + json.len() as u64).contains(&offset), "{msg}");
            assert!(msg.starts_with(&format!("h.cap: byte {offset}: ")), "{msg}");
        }
        // A misfit field is located: here just after the `null`.
        let json = r#"{"version":1,"streams":[{"id":0,"kind":"falcon"}],"started_unix":null,"nominal_period_s":0.05}"#;
        let null_end = 20 + json.find("null").unwrap() + 4;
        match parse_capture(&with_header_json(json), "h.cap") {
            Err(CaptureError::BadHeader { offset, .. }) => {
                assert!(
                    offset.abs_diff(null_end as u64) <= 1,
                    "{offset} vs {null_end}"
                )
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn header_length_over_the_limit_is_damage_not_a_cut() {
        let mut file = MAGIC.to_vec();
        file.extend_from_slice(&u32::MAX.to_le_bytes());
        file.extend_from_slice(b"{}");
        let err = parse_capture(&file, "len.cap").unwrap_err();
        assert!(
            matches!(err, CaptureError::BadHeader { offset: 16, .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("4294967295"), "{err}");
    }

    #[test]
    fn unknown_version_is_reported_as_such() {
        // Even when the rest of the header no longer fits version 1.
        for json in [
            r#"{"version":2,"streams":[{"id":0,"kind":"falcon"}],"started_unix":0,"nominal_period_s":0.05}"#,
            r#"{"version":2,"channels":{}}"#,
        ] {
            let err = parse_capture(&with_header_json(json), "v2.cap").unwrap_err();
            assert!(
                matches!(
                    err,
                    CaptureError::UnsupportedVersion {
                        offset: 20,
                        found: 2,
                        supported: 1,
                        ..
                    }
                ),
                "{err:?}"
            );
            let msg = err.to_string();
            assert!(
                msg.starts_with("v2.cap: byte 20: ") && msg.contains("version 2"),
                "{msg}"
            );
        }
    }

    #[test]
    fn undeclared_stream_is_an_error_at_its_record() {
        let mut file = write(&header(), &chunks()[..1]);
        let at = file.len();
        file.extend(record(5, 7, b"abc"));
        file.extend(record(6, 0, b"def"));
        let err = parse_capture(&file, "u.cap").unwrap_err();
        match &err {
            CaptureError::UndeclaredStream {
                offset,
                index,
                stream,
                declared,
                ..
            } => {
                assert_eq!((*offset, *index, *stream), (at as u64, 1, 7));
                assert_eq!(declared, "0, 3");
            }
            other => panic!("{other:?}"),
        }
        assert!(err.to_string().starts_with(&format!("u.cap: byte {at}: ")));
    }

    #[test]
    fn undeclared_stream_in_a_torn_tail_is_only_truncation() {
        let mut file = write(&header(), &chunks()[..1]);
        let mut bad = record(5, 7, b"abc");
        bad.pop();
        file.extend(bad);
        let (_, c, t) = capture(parse_capture(&file, "t.cap").unwrap());
        assert_eq!(c.len(), 1);
        assert_eq!(t.unwrap().reason, TruncationReason::Torn);
    }

    /// The writer killed at any byte: each prefix either is an error about
    /// the header (cut inside the magic or header) or reads back every
    /// complete record, and reports a torn tail exactly when there is one.
    #[test]
    fn every_prefix_reads_back_its_complete_records() {
        let file = write(&header(), &chunks());
        let starts = record_starts(&header(), &chunks());
        let records_at = starts[0];
        for cut in 0..=file.len() {
            let result = parse_capture(&file[..cut], "cut.cap");
            if cut == 0 {
                assert!(matches!(result, Err(CaptureError::Empty { .. })));
                continue;
            }
            if cut < records_at {
                let part = match result {
                    Err(CaptureError::TruncatedHeader {
                        offset,
                        part,
                        needed,
                        present,
                        ..
                    }) => {
                        assert_eq!(offset, cut as u64);
                        assert!(present < needed);
                        part
                    }
                    other => panic!("cut at {cut}: {other:?}"),
                };
                let expected = if cut < 16 {
                    "magic"
                } else if cut < 20 {
                    "header length"
                } else {
                    "header"
                };
                assert_eq!(part, expected, "cut at {cut}");
                let msg = parse_capture(&file[..cut], "cut.cap")
                    .unwrap_err()
                    .to_string();
                assert!(msg.starts_with(&format!("cut.cap: byte {cut}: ")), "{msg}");
                continue;
            }
            let (h, c, t) = capture(result.unwrap_or_else(|e| panic!("cut at {cut}: {e}")));
            assert_eq!(h, header());
            let complete = starts.iter().filter(|&&s| s <= cut).count() - 1;
            assert_eq!(c, chunks()[..complete], "cut at {cut}");
            if starts.contains(&cut) {
                assert_eq!(t, None, "cut at {cut}");
            } else {
                let start = starts[complete];
                assert_eq!(
                    t,
                    Some(Truncation {
                        offset: start as u64,
                        chunks_intact: complete,
                        bytes_dropped: (cut - start) as u64,
                        reason: TruncationReason::Torn,
                    }),
                    "cut at {cut}"
                );
            }
        }
    }

    #[test]
    fn zero_filled_tail_fails_its_checksum() {
        // What a power cut can leave: the file grew, its last blocks did not land.
        let mut file = write(&header(), &chunks());
        let end = file.len();
        file.extend([0u8; 40]);
        let (_, c, t) = capture(parse_capture(&file, "z.cap").unwrap());
        assert_eq!(c, chunks());
        assert_eq!(
            t,
            Some(Truncation {
                offset: end as u64,
                chunks_intact: 4,
                bytes_dropped: 40,
                reason: TruncationReason::BadChecksum,
            })
        );
    }

    #[test]
    fn a_damaged_record_ends_the_read_there() {
        let mut file = write(&header(), &chunks());
        let starts = record_starts(&header(), &chunks());
        // One flipped bit in the data of the second record.
        file[starts[1] + 13 + 5] ^= 0x10;
        let (_, c, t) = capture(parse_capture(&file, "flip.cap").unwrap());
        assert_eq!(c, chunks()[..1]);
        let t = t.unwrap();
        assert_eq!((t.offset, t.chunks_intact), (starts[1] as u64, 1));
        assert_eq!(t.bytes_dropped, (file.len() - starts[1]) as u64);
        assert_eq!(t.reason, TruncationReason::BadChecksum);
        // A damaged length that runs past the end reads as a torn record.
        let mut file = write(&header(), &chunks());
        file[starts[1] + 12] = 0x7F;
        let (_, c, t) = capture(parse_capture(&file, "len.cap").unwrap());
        assert_eq!((c.len(), t.unwrap().reason), (1, TruncationReason::Torn));
    }

    #[test]
    fn truncation_message_says_where_and_what_is_kept() {
        let t = Truncation {
            offset: 1234,
            chunks_intact: 56,
            bytes_dropped: 7,
            reason: TruncationReason::Torn,
        };
        let msg = t.to_string();
        assert!(
            msg.contains("byte 1234") && msg.contains("56 chunks") && msg.contains("killed"),
            "{msg}"
        );
        let msg = Truncation {
            reason: TruncationReason::BadChecksum,
            ..t
        }
        .to_string();
        assert!(
            msg.contains("byte 1234") && msg.contains("checksum"),
            "{msg}"
        );
    }

    #[test]
    fn writer_rejects_what_it_could_not_read_back_and_stays_usable() {
        for bad in [
            CaptureHeader {
                version: 2,
                ..header()
            },
            CaptureHeader {
                streams: vec![],
                ..header()
            },
            CaptureHeader {
                nominal_period_s: f64::NAN,
                ..header()
            },
            CaptureHeader {
                started_unix: f64::INFINITY,
                ..header()
            },
        ] {
            let err = CaptureWriter::new(Vec::new(), &bad).unwrap_err();
            assert_eq!(err.kind(), io::ErrorKind::InvalidInput, "{bad:?}");
        }
        let mut w = CaptureWriter::new(Vec::new(), &header()).unwrap();
        let before = w.get_ref().len();
        for (time, stream) in [(0.0, 1), (-0.001, 0), (f64::NAN, 0), (f64::INFINITY, 3)] {
            let err = w.write_chunk(time, stream, b"abc").unwrap_err();
            assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
        }
        assert_eq!(w.get_ref().len(), before);
        w.write_chunk(0.5, 3, b"ok").unwrap();
        let (_, c, t) = capture(parse_capture(&w.into_inner().unwrap(), "w.cap").unwrap());
        assert_eq!((c.len(), t), (1, None));
    }

    /// A disk that fills up after `room` bytes: it takes what fits, then fails.
    struct FullDisk {
        data: Vec<u8>,
        room: usize,
    }

    impl Write for FullDisk {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            let n = buf.len().min(self.room - self.data.len());
            if n == 0 && !buf.is_empty() {
                return Err(io::Error::new(io::ErrorKind::StorageFull, "disk full"));
            }
            self.data.extend_from_slice(&buf[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    /// The recorder's way of writing (through a `BufWriter`, flushing now and
    /// then) on a disk that fills up at any byte: what landed reads back.
    #[test]
    fn disk_full_at_any_byte_leaves_a_readable_capture() {
        let full = write(&header(), &chunks());
        let records_at = record_starts(&header(), &chunks())[0];
        for room in 0..=full.len() {
            let disk = FullDisk {
                data: Vec::new(),
                room,
            };
            let Ok(mut w) = CaptureWriter::new(io::BufWriter::with_capacity(16, disk), &header())
            else {
                assert!(room < records_at, "room {room}");
                continue;
            };
            let mut failed = false;
            for (i, c) in chunks().iter().enumerate() {
                let result = w
                    .write_chunk(c.time, c.stream, &c.bytes)
                    .and_then(|()| if i % 2 == 1 { w.flush() } else { Ok(()) });
                if failed {
                    assert!(result.is_err(), "a write after a failure must fail too");
                }
                failed |= result.is_err();
            }
            let _ = w.flush();
            let landed = &w.get_ref().get_ref().data;
            assert!(full.starts_with(landed));
            let (_, c, _) = capture(parse_capture(landed, "full.cap").unwrap());
            assert_eq!(c, chunks()[..c.len()]);
        }
    }

    #[test]
    fn read_capture_reads_files_and_names_missing_ones() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bench.cap");
        std::fs::write(&path, write(&header(), &chunks())).unwrap();
        let (h, c, _) = capture(read_capture(&path).unwrap());
        assert_eq!((h, c), (header(), chunks()));

        let raw = dir.path().join("dump.bin");
        std::fs::write(&raw, b"\x02\x00").unwrap();
        assert_eq!(
            read_capture(&raw).unwrap(),
            CaptureFile::Raw {
                bytes: b"\x02\x00".to_vec()
            }
        );

        let missing = dir.path().join("missing.cap");
        let err = read_capture(&missing).unwrap_err();
        assert!(matches!(err, CaptureError::Io { .. }));
        assert!(err.to_string().contains("missing.cap"), "{err}");
    }

    fn hex_lines(bytes: &[u8]) -> String {
        bytes
            .chunks(16)
            .map(|line| {
                line.iter()
                    .map(|b| format!("{b:02x}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            })
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// The worked example of docs/capture-format.md is what the writer writes.
    #[test]
    fn documented_example_matches_the_writer() {
        let header = CaptureHeader {
            version: 1,
            streams: vec![StreamInfo {
                id: 0,
                kind: StreamKind::Falcon,
            }],
            port: Some("/dev/ttyUSB0".into()),
            baud: Some(38400),
            started_unix: 1_700_000_000.25,
            nominal_period_s: 0.05,
            note: None,
        };
        let mut w = CaptureWriter::new(Vec::new(), &header).unwrap();
        w.write_chunk_ns(1_500_000, 0, &[0x02, 0x01, 0x2C]).unwrap();
        let file = w.into_inner().unwrap();
        let doc = include_str!("../docs/capture-format.md");
        let hex = hex_lines(&file);
        assert!(
            doc.contains(&hex),
            "the example in the doc should read:\n{hex}"
        );
    }
}
