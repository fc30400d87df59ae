//! True north in the daemon's configuration: `declination_deg` or a
//! `[sensor.location]` (or `[daemon]`'s, the default of every magnetometer
//! of a device source) resolves to the sensor's declination; every
//! mistake is refused naming the key.

use std::path::{Path, PathBuf};

use fieldcal::daemon::config::{Config, ConfigError, parse};

fn config_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/test.toml")
}

const SOURCES: &str = r#"
[[source]]
name = "imu"
kind = "falcon"
port = "/dev/ttyUSB0"
"#;

/// A magnetometer `compass` (2-axis, or 3-axis with `three`) with `extra`
/// lines, and a 3-axis accelerometer `level`, after `head` (a `[daemon]`).
fn text(head: &str, three: bool, extra: &str) -> String {
    let axes = if three {
        r#"["x", "y", "z"]"#
    } else {
        r#"["x", "y"]"#
    };
    format!(
        "{head}\n{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\n\
         axes = {axes}\n{extra}\n\n[[sensor]]\nname = \"level\"\nsource = \"imu\"\n\
         field = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n"
    )
}

fn parsed(text: &str) -> Config {
    parse(text, &config_path()).unwrap_or_else(|e| panic!("{e}"))
}

#[track_caller]
fn refused(text: &str, key: &str, words: &[&str]) {
    let err: ConfigError = match parse(text, &config_path()) {
        Ok(c) => panic!("accepted: {c:?}"),
        Err(e) => e,
    };
    let message = err.to_string();
    assert_eq!(err.key(), Some(key), "{message}");
    assert!(message.contains("test.toml:"), "no line in: {message}");
    for w in words {
        assert!(message.contains(w), "no '{w}' in: {message}");
    }
}

#[test]
fn a_declination_or_a_location_gives_the_sensors_true_north() {
    for three in [false, true] {
        let c = parsed(&text("", three, "declination_deg = -3.5"));
        let north = c.sensors[0].north.as_ref().unwrap();
        assert_eq!(north.declination_deg, -3.5);
        assert_eq!(north.source, "config");
        assert!(c.sensors[1].north.is_none());

        // NOAA's WMM2025 test value (Technical Report Table 6, epoch
        // 2025.0, height 0): 80° S 120° W, D = 68.78°.
        let c = parsed(&text(
            "",
            three,
            "[sensor.location]\nlatitude = -80.0\nlongitude = -120.0\ndate = \"2025-01-01\"",
        ));
        let north = c.sensors[0].north.as_ref().unwrap();
        assert!((north.declination_deg - 68.78).abs() < 0.011, "{north:?}");
        assert_eq!(north.source, "WMM2025 at -80,-120,2025-01-01");
        assert!(!north.date_is_today);
        let model = north.model.as_ref().unwrap();
        assert_eq!(model.altitude_m, 0.0);
        // At 100 km: the table's 68.21°.
        let c = parsed(&text(
            "",
            three,
            "[sensor.location]\nlatitude = -80.0\nlongitude = -120.0\nheight_m = 100000\n\
             date = \"2025-01-01\"",
        ));
        let d = c.sensors[0].north.as_ref().unwrap().declination_deg;
        assert!((d - 68.21).abs() < 0.011, "{d}");
    }
    // Without a date: the host's, said so.
    let c = parsed(&text(
        "",
        false,
        "[sensor.location]\nlatitude = 50.1\nlongitude = 8.7",
    ));
    let north = c.sensors[0].north.as_ref().unwrap();
    assert!(north.date_is_today);
    let today = fieldcal::geomag::CivilDate::today().unwrap().to_string();
    assert!(north.source.ends_with(&today), "{}", north.source);
}

#[test]
fn the_daemons_location_is_every_device_magnetometers_default() {
    let head = "[daemon]\n[daemon.location]\nlatitude = -80.0\nlongitude = -120.0\n\
                date = \"2025-01-01\"\n";
    let c = parsed(&text(head, true, ""));
    let d = c.sensors[0].north.as_ref().unwrap().declination_deg;
    assert!((d - 68.78).abs() < 0.011);
    // Not the accelerometer's.
    assert!(c.sensors[1].north.is_none());
    // A sensor's own key replaces it.
    let c = parsed(&text(head, false, "declination_deg = 2.0"));
    assert_eq!(c.sensors[0].north.as_ref().unwrap().declination_deg, 2.0);
    let c = parsed(&text("[daemon]\ndeclination_deg = 1.5\n", false, ""));
    assert_eq!(c.sensors[0].north.as_ref().unwrap().source, "config");
}

#[test]
fn mistakes_in_true_north_are_refused_by_key() {
    refused(
        &text(
            "",
            false,
            "declination_deg = 2.0\n[sensor.location]\nlatitude = 50.0\nlongitude = 8.0",
        ),
        "sensor[0].location",
        &["both declination_deg and [sensor.location]"],
    );
    refused(
        &text("", true, "declination_deg = 200.0"),
        "sensor[0].declination_deg",
        &["-180 to 180"],
    );
    refused(
        &text(
            "",
            false,
            "[sensor.location]\nlatitude = 95.0\nlongitude = 8.0\ndate = \"2026-01-01\"",
        ),
        "sensor[0].location.latitude",
        &["-90 to 90"],
    );
    refused(
        &text(
            "",
            false,
            "[sensor.location]\nlatitude = 50.0\nlongitude = 188.0\ndate = \"2026-01-01\"",
        ),
        "sensor[0].location.longitude",
        &["-180 to 180"],
    );
    refused(
        &text(
            "",
            false,
            "[sensor.location]\nlatitude = 50.0\nlongitude = 8.0\nheight_m = -5000\n\
             date = \"2026-01-01\"",
        ),
        "sensor[0].location.height_m",
        &["metres"],
    );
    // Outside WMM2020-WMM2025's years.
    refused(
        &text(
            "",
            true,
            "[sensor.location]\nlatitude = 50.0\nlongitude = 8.0\ndate = \"2013-06-01\"",
        ),
        "sensor[0].location.date",
        &["2020-01-01", "2029-12-31"],
    );
    refused(
        &text(
            "",
            true,
            "[sensor.location]\nlatitude = 50.0\nlongitude = 8.0\ndate = \"1.6.2026\"",
        ),
        "sensor[0].location.date",
        &["YYYY-MM-DD"],
    );
    refused(
        &text(
            "",
            false,
            "[sensor.location]\nlatitude = 50.0\nlongitude = 8.0\naltitude = 3",
        ),
        "sensor[0].location.altitude",
        &["unknown field", "height_m"],
    );
    refused(
        &text("", false, "[sensor.location]\nlatitude = 50.0"),
        "sensor[0].location.longitude",
        &["missing"],
    );
    // An accelerometer's heading owes nothing to magnetic north.
    let accel = text("", false, "").replace(
        "field = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n",
        "field = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\ndeclination_deg = 3.0\n",
    );
    refused(
        &accel,
        "sensor[1].declination_deg",
        &["magnetometer's", "accel"],
    );
    let accel = text("", false, "").replace(
        "field = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n",
        "field = \"accel\"\naxes = [\"x\", \"y\", \"z\"]\n[sensor.location]\nlatitude = 1.0\n\
         longitude = 2.0\ndate = \"2026-01-01\"\n",
    );
    refused(&accel, "sensor[1].location", &["magnetometer's"]);
    refused(
        &text(
            "[daemon]\ndeclination_deg = 1.0\n[daemon.location]\nlatitude = 1.0\nlongitude = 2.0\n",
            false,
            "",
        ),
        "daemon.location",
        &["both declination_deg and [daemon.location]"],
    );
}

#[test]
fn a_csv_sensor_takes_its_own_declination_and_not_the_daemons() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    std::fs::write(&csv, "t_s,mag_x,mag_z\n0,1,2\n").unwrap();
    let text = |daemon: &str, extra: &str| {
        format!(
            "{daemon}\n[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\n\n\
             [[sensor]]\nname = \"robot\"\nsource = \"log\"\naxes = [\"mag_x\", \"mag_z\"]\n{extra}\n",
            csv.display()
        )
    };
    let c = parsed(&text("", "declination_deg = 4.25"));
    assert_eq!(c.sensors[0].north.as_ref().unwrap().declination_deg, 4.25);
    let c = parsed(&text("[daemon]\ndeclination_deg = 4.25", ""));
    assert!(c.sensors[0].north.is_none());
}

/// A 3-axis csv sensor names its field: true north is refused on its
/// accelerometer, and taken by its magnetometer.
#[test]
fn a_3_axis_csv_accelerometer_takes_no_declination() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("imu.csv");
    std::fs::write(
        &csv,
        "t_s,mag_x,mag_y,mag_z,acc_x,acc_y,acc_z\n0,1,2,3,0,0,1\n",
    )
    .unwrap();
    let text = |field: &str, axes: &str| {
        format!(
            "[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\n\n\
             [[sensor]]\nname = \"s\"\nsource = \"log\"\nfield = \"{field}\"\n\
             axes = {axes}\ndeclination_deg = 4.25\n",
            csv.display()
        )
    };
    refused(
        &text("accel", r#"["acc_x", "acc_y", "acc_z"]"#),
        "sensor[0].declination_deg",
        &["magnetometer's", "accel"],
    );
    let c = parsed(&text("mag", r#"["mag_x", "mag_y", "mag_z"]"#));
    assert_eq!(c.sensors[0].north.as_ref().unwrap().declination_deg, 4.25);
}
