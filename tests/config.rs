//! The daemon's TOML configuration: a full file parses to the right
//! structures, and every kind of mistake is refused with a message naming
//! the file, the key, what was found and what is allowed, at its line.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use fieldcal::capture::{CaptureHeader, CaptureWriter, StreamInfo, StreamKind};
use fieldcal::daemon::config::{
    Axis, ConfigError, Field, GyroChoice, LogFormat, SourceKind, load, parse,
};
use fieldcal::daemon::source_kinds::{Csv, Falcon, Replay, UsbIss};
use fieldcal::model::gyro::GyroUnits;
use fieldcal::protocol::chips::Chip;
use fieldcal::source::replay::Speed;

/// The repository's config directory stands in for the file's place, so
/// `../tests/data/...` reaches the checked-in captures.
fn config_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/test.toml")
}

const SOURCES: &str = r#"
[[source]]
name = "imu"
kind = "falcon"
port = "/dev/ttyUSB0"

[[source]]
name = "bridge"
kind = "usb-iss"
port = "/dev/ttyACM0"
chips = ["mpu6050", "lsm303dlhc-mag@0x1e"]
"#;

const FULL: &str = r#"
[daemon]
state_dir = "/var/lib/fieldcal"
status_interval_s = 0.5
log_format = "json"

[outputs]
stdout = false
tcp = "127.0.0.1:2948"
unix = "/run/fieldcal/fieldcal.sock"
queue = 100

[[source]]
name = "imu"
kind = "falcon"
port = "/dev/ttyUSB0"
baud = 115200
retry_s = 5

[[source]]
name = "bridge"
kind = "usb-iss"
port = "/dev/ttyACM0"
chips = ["mpu6050", "lsm303dlhc-mag@0x1e", "adxl345@83"]
poll_ms = 20
i2c_khz = 400

[[source]]
name = "bench"
kind = "replay"
file = "../tests/data/falcon_turn.fcap"
speed = "max"

[[sensor]]
name = "compass"
source = "bridge"
chip = "lsm303dlhc-mag"
field = "mag"
axes = ["x", "y"]
model = "paper"
[sensor.rotation]
max_gap_deg = 20.0
[sensor.limits]
min_coverage_deg = 350.0

[[sensor]]
name = "tilt"
source = "bridge"
chip = "adxl345"
field = "accel"
axes = ["y", "z"]
model = ["offset", "scale"]

[[sensor]]
name = "imu-mag"
source = "imu"
field = "mag"
axes = ["x", "y"]

[[sensor]]
name = "replayed"
source = "bench"
field = "accel"
axes = ["z", "x"]
model = "offset+scale"
"#;

fn refused(text: &str) -> ConfigError {
    match parse(text, &config_path()) {
        Ok(c) => panic!("accepted: {c:?}"),
        Err(e) => e,
    }
}

/// Asserts the message names the file, the key and each of `words`, and
/// that the error has the expected line.
#[track_caller]
fn assert_refused(text: &str, key: &str, line: Option<usize>, words: &[&str]) {
    let err = refused(text);
    let message = err.to_string();
    assert!(message.contains("test.toml"), "no file in: {message}");
    assert_eq!(err.key(), Some(key), "{message}");
    assert!(message.contains(key), "no key in: {message}");
    for w in words {
        assert!(message.contains(w), "no '{w}' in: {message}");
    }
    if let Some(line) = line {
        let at = err.position().map(|p| p.line);
        assert_eq!(at, Some(line), "{message}");
        assert!(message.contains(&format!("test.toml:{line}:")), "{message}");
    }
}

fn line_of(text: &str, needle: &str) -> usize {
    let at = text
        .find(needle)
        .unwrap_or_else(|| panic!("{needle} not in text"));
    text[..at].matches('\n').count() + 1
}

#[test]
fn a_full_config_parses_to_the_right_structures() {
    let config = parse(FULL, &config_path()).unwrap();
    assert_eq!(config.path, config_path());
    assert_eq!(config.daemon.state_dir, PathBuf::from("/var/lib/fieldcal"));
    assert_eq!(config.daemon.status_interval, Duration::from_millis(500));
    assert_eq!(config.daemon.log_format, LogFormat::Json);
    assert!(!config.outputs.stdout());
    assert_eq!(
        config.outputs.tcp(),
        Some("127.0.0.1:2948".parse::<SocketAddr>().unwrap())
    );
    assert_eq!(
        config.outputs.unix(),
        Some(Path::new("/run/fieldcal/fieldcal.sock"))
    );
    assert_eq!(config.outputs.queue, 100);

    assert_eq!(config.sources.len(), 3);
    assert_eq!(config.sources[0].name, "imu");
    assert_eq!(
        config.sources[0].kind,
        SourceKind::Falcon(Falcon {
            port: "/dev/ttyUSB0".into(),
            baud: 115_200
        })
    );
    assert_eq!(config.sources[0].retry, Duration::from_secs(5));
    assert_eq!(
        config.sources[1].kind,
        SourceKind::UsbIss(UsbIss {
            port: "/dev/ttyACM0".into(),
            chips: vec![
                (Chip::Mpu6050, 0x68),
                (Chip::Lsm303dlhcMag, 0x1E),
                (Chip::Adxl345, 83)
            ],
            poll: Duration::from_millis(20),
            i2c_khz: 400,
        })
    );
    assert_eq!(config.sources[1].retry, Duration::from_secs(2));
    let bridge = config.sources[1].bridge_config().unwrap();
    assert_eq!(bridge.period, Duration::from_millis(20));
    assert!(bridge.validate().is_ok());
    match &config.sources[2].kind {
        SourceKind::Replay(Replay { file, speed }) => {
            // Relative to the configuration's directory.
            assert!(
                file.starts_with(config_path().parent().unwrap()),
                "{file:?}"
            );
            assert!(file.is_file());
            assert_eq!(*speed, Speed::Max);
        }
        other => panic!("{other:?}"),
    }

    let s = &config.sensors;
    assert_eq!(s.len(), 4);
    assert_eq!(s[0].name, "compass");
    assert_eq!(s[0].source, "bridge");
    assert_eq!(s[0].stream, 1);
    assert_eq!(s[0].field, Field::Mag);
    assert_eq!(s[0].plane().unwrap().axes, [Axis::X, Axis::Y]);
    assert_eq!(s[0].effects(), ["offset", "scale"]);
    assert_eq!(s[0].plane().unwrap().rotation.max_gap_deg, 20.0);
    assert_eq!(s[0].plane().unwrap().limits.min_coverage_deg, 350.0);
    assert_eq!(
        s[1].plane().unwrap().rotation,
        fieldcal::daemon::rotation::RotationConfig::default()
    );
    assert_eq!((s[1].stream, s[1].field), (2, Field::Accel));
    assert_eq!(s[1].plane().unwrap().axes, [Axis::Y, Axis::Z]);
    assert_eq!(s[1].effects(), ["offset", "scale"]);
    assert_eq!((s[2].stream, s[2].field), (0, Field::Mag));
    assert_eq!(s[3].stream, 0);
    assert_eq!(s[3].plane().unwrap().axes, [Axis::Z, Axis::X]);
    assert_eq!(s[3].effects(), ["offset", "scale"]);
    assert!(config.source("bench").is_some());
}

#[test]
fn defaults_fill_what_is_left_out() {
    let text = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(config.daemon.status_interval, Duration::from_secs(1));
    assert_eq!(config.daemon.log_format, LogFormat::Text);
    assert!(config.outputs.stdout());
    assert_eq!(config.outputs.tcp(), None);
    assert_eq!(config.outputs.queue, 4096);
    assert_eq!(
        config.sources[0].kind,
        SourceKind::Falcon(Falcon {
            port: "/dev/ttyUSB0".into(),
            baud: 38_400
        })
    );
    match &config.sources[1].kind {
        SourceKind::UsbIss(UsbIss { poll, i2c_khz, .. }) => {
            assert_eq!(*poll, Duration::from_millis(30));
            assert_eq!(*i2c_khz, 100);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(config.sensors[0].effects(), ["offset", "scale"]);
}

#[test]
fn load_reads_the_file_and_names_a_missing_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fieldcal.toml");
    std::fs::write(
        &path,
        format!("{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"),
    )
    .unwrap();
    assert_eq!(load(&path).unwrap().sensors.len(), 1);
    let missing = dir.path().join("nope.toml");
    let err = load(&missing).unwrap_err();
    assert!(matches!(err, ConfigError::Read { .. }));
    assert!(err.to_string().contains("nope.toml"), "{err}");
}

fn sensor(extra: &str) -> String {
    format!("{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"bridge\"\n{extra}\n")
}

#[test]
fn a_syntax_error_has_its_line() {
    let text = "[daemon]\nstate_dir = \"/x\n";
    let err = refused(text);
    assert!(matches!(err, ConfigError::Syntax { .. }), "{err}");
    assert_eq!(err.position().map(|p| p.line), Some(2), "{err}");
    assert!(err.to_string().contains("test.toml:2:"), "{err}");
}

#[test]
fn an_unknown_key_is_named_with_the_allowed_ones() {
    let text = format!("{SOURCES}\nbud = 9600\n").replace(
        "port = \"/dev/ttyUSB0\"\n",
        "port = \"/dev/ttyUSB0\"\nbuad = 9600\n",
    );
    assert_refused(
        &text,
        "source[0].buad",
        Some(line_of(&text, "buad")),
        &["unknown field `buad`", "baud"],
    );
    let text = "[deamon]\n";
    assert_refused(text, "deamon", Some(1), &["unknown field", "daemon"]);
    let text =
        sensor("chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\nmodle = \"paper\"");
    assert_refused(
        &text,
        "sensor[0].modle",
        Some(line_of(&text, "modle")),
        &["model"],
    );
}

#[test]
fn a_wrong_type_is_named_with_what_was_found() {
    let text = SOURCES.replace(
        "port = \"/dev/ttyUSB0\"",
        "port = \"/dev/ttyUSB0\"\nbaud = \"fast\"",
    );
    assert_refused(
        &text,
        "source[0].baud",
        Some(line_of(&text, "\"fast\"")),
        &["fast", "u32"],
    );
    let text = format!("[outputs]\nqueue = -3\n{SOURCES}");
    assert_refused(&text, "outputs.queue", Some(2), &["-3"]);
    let text = "[daemon]\nlog_format = \"xml\"\n";
    assert_refused(text, "daemon.log_format", Some(2), &["xml", "text", "json"]);
}

#[test]
fn an_unknown_source_kind_lists_the_kinds() {
    let text = SOURCES.replace("kind = \"falcon\"", "kind = \"gps\"");
    assert_refused(
        &text,
        "source[0].kind",
        Some(line_of(&text, "\"gps\"")),
        &["gps", "falcon", "usb-iss", "replay"],
    );
}

#[test]
fn a_missing_port_or_a_key_of_another_kind_is_refused() {
    let text = SOURCES.replace("port = \"/dev/ttyUSB0\"\n", "");
    assert_refused(
        &text,
        "source[0].port",
        Some(line_of(&text, "[[source]]")),
        &["needs `port`"],
    );
    let text = SOURCES.replace(
        "kind = \"falcon\"",
        "kind = \"falcon\"\nchips = [\"mpu6050\"]",
    );
    assert_refused(
        &text,
        "source[0].chips",
        Some(line_of(&text, "[\"mpu6050\"]")),
        &["falcon", "no `chips`", "baud"],
    );
    let text = "[[source]]\nkind = \"falcon\"\nport = \"/dev/x\"\n";
    assert_refused(text, "source[0].name", Some(1), &["missing field `name`"]);
}

#[test]
fn a_bad_chip_name_or_address_is_refused() {
    let text = SOURCES.replace("\"mpu6050\"", "\"mpu9250\"");
    assert_refused(
        &text,
        "source[1].chips[0]",
        Some(line_of(&text, "mpu9250")),
        &["mpu9250", "adxl345", "lsm303dlhc-mag"],
    );
    for bad in ["0x80", "0xzz", "300", ""] {
        let text = SOURCES.replace("@0x1e", &format!("@{bad}"));
        assert_refused(
            &text,
            "source[1].chips[1]",
            Some(line_of(&text, "lsm303dlhc-mag@")),
            &["7-bit"],
        );
    }
    let text = SOURCES.replace("\"mpu6050\"", "\"mpu6050@0x1e\"");
    assert_refused(&text, "source[1].chips[1]", None, &["both at 0x1e"]);
    let text = SOURCES.replace(
        "chips = [\"mpu6050\", \"lsm303dlhc-mag@0x1e\"]",
        "chips = []",
    );
    assert_refused(&text, "source[1].chips", None, &["needs `chips`"]);
}

#[test]
fn equal_or_too_many_axes_are_refused() {
    let text = sensor("chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"x\"]");
    assert_refused(
        &text,
        "sensor[0].axes",
        Some(line_of(&text, "axes")),
        &["both axes are \"x\"", "two different"],
    );
    // Three axes make a 3-axis sensor (tests/daemon3.rs); four are refused.
    let text = sensor("chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\", \"z\", \"x\"]");
    assert_refused(
        &text,
        "sensor[0].axes",
        Some(line_of(&text, "axes")),
        &["4 axes"],
    );
    let text = sensor("chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"w\"]");
    assert_refused(
        &text,
        "sensor[0].axes[1]",
        Some(line_of(&text, "axes")),
        &["w", "x", "y", "z"],
    );
}

#[test]
fn effects_are_checked_against_the_catalogue() {
    let text = sensor(
        "chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\nmodel = [\"offset\", \"scale\", \"wobble\"]",
    );
    assert_refused(
        &text,
        "sensor[0].model[2]",
        Some(line_of(&text, "model")),
        &["'wobble' is not an effect", "offset", "cross-axis"],
    );
    // Effects that need the time base or a logged column cannot correct
    // live readings.
    for offline in ["drift", "covariate:temp_c"] {
        let text = sensor(&format!(
            "chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\nmodel = [\"paper\", \"{offline}\"]"
        ));
        assert_refused(
            &text,
            "sensor[0].model[1]",
            Some(line_of(&text, "model")),
            &[offline, "cannot correct live readings", "fieldcal diagnose"],
        );
    }
    // Those that depend on the reading alone are accepted, in catalogue order.
    let text = sensor(
        "chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\nmodel = [\"outliers\", \"paper\", \"cubic\", \"cross-axis\"]",
    );
    let config =
        fieldcal::daemon::config::parse(&text, std::path::Path::new("/tmp/fieldcal.toml")).unwrap();
    assert_eq!(
        config.sensors[0].effects(),
        ["offset", "scale", "cross-axis", "cubic", "outliers"]
    );
    let text =
        sensor("chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\nmodel = \"offset\"");
    assert_refused(
        &text,
        "sensor[0].model",
        Some(line_of(&text, "model")),
        &["lacks scale"],
    );
    let text = sensor("chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\nmodel = 3");
    assert_refused(
        &text,
        "sensor[0].model",
        Some(line_of(&text, "model")),
        &["an integer", "paper"],
    );
}

#[test]
fn duplicate_names_are_refused() {
    let text = SOURCES.replace("name = \"bridge\"", "name = \"imu\"");
    assert_refused(
        &text,
        "source[1].name",
        Some(line_of(&text, "name = \"imu\"\nkind = \"usb")),
        &["already the name of source[0]"],
    );
    let one =
        "[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";
    let text = format!("{SOURCES}\n{one}{one}");
    assert_refused(
        &text,
        "sensor[1].name",
        Some(text.matches('\n').count() - 3),
        &["already the name of sensor[0]"],
    );
}

#[test]
fn bad_names_are_refused() {
    for bad in ["", "../etc", "a b", "compass.json"] {
        let text = format!(
            "{SOURCES}\n[[sensor]]\nname = \"{bad}\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
        );
        assert_refused(&text, "sensor[0].name", None, &["letters, digits"]);
    }
}

#[test]
fn a_sensor_must_name_an_existing_source_and_chip() {
    let text = sensor("field = \"mag\"\naxes = [\"x\", \"y\"]")
        .replace("source = \"bridge\"\n\n", "source = \"brige\"\n\n");
    let text = text.replacen("source = \"bridge\"\nfield", "source = \"brige\"\nfield", 1);
    assert_refused(
        &text,
        "sensor[0].source",
        Some(line_of(&text, "\"brige\"")),
        &["no source named 'brige'", "imu, bridge"],
    );

    let text = sensor("chip = \"adxl345\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]");
    assert_refused(
        &text,
        "sensor[0].chip",
        Some(line_of(&text, "\"adxl345\"")),
        &[
            "not on source 'bridge'",
            "mpu6050@0x68",
            "lsm303dlhc-mag@0x1e",
        ],
    );

    let text = sensor("field = \"accel\"\naxes = [\"x\", \"y\"]");
    assert_refused(
        &text,
        "sensor[0].chip",
        None,
        &["several streams", "chip ="],
    );

    let text = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nchip = \"mpu6050\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    assert_refused(&text, "sensor[0].chip", None, &["no chips"]);

    let text = sensor("chip = \"mpu6050\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]");
    assert_refused(
        &text,
        "sensor[0].field",
        Some(line_of(&text, "\"mag\"")),
        &["not measured", "accel, gyro"],
    );
}

#[test]
fn a_missing_replay_file_is_named() {
    let text = format!(
        "{SOURCES}\n[[source]]\nname = \"r\"\nkind = \"replay\"\nfile = \"no/such.fcap\"\n\n\
         [[sensor]]\nname = \"c\"\nsource = \"r\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    assert_refused(
        &text,
        "source[2].file",
        Some(line_of(&text, "no/such")),
        &["no/such.fcap", "relative"],
    );
    let text = text.replace("file = \"no/such.fcap\"\n", "");
    assert_refused(&text, "source[2].file", None, &["needs `file`"]);
}

#[test]
fn a_replayed_bridge_capture_resolves_chips_to_stream_ids() {
    let dir = tempfile::tempdir().unwrap();
    let header = CaptureHeader {
        version: 1,
        streams: vec![
            StreamInfo {
                id: 0,
                kind: StreamKind::Chip {
                    chip: Chip::Mpu6050,
                    address: 0x68,
                },
            },
            StreamInfo {
                id: 3,
                kind: StreamKind::Chip {
                    chip: Chip::Lsm303dlhcMag,
                    address: 0x1E,
                },
            },
        ],
        port: None,
        baud: None,
        started_unix: 0.0,
        nominal_period_s: 0.03,
        note: None,
    };
    let file = std::fs::File::create(dir.path().join("bridge.fcap")).unwrap();
    CaptureWriter::new(file, &header).unwrap();
    let path = dir.path().join("fieldcal.toml");
    let text = "[[source]]\nname = \"r\"\nkind = \"replay\"\nfile = \"bridge.fcap\"\nspeed = 4\n\n\
                [[sensor]]\nname = \"c\"\nsource = \"r\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";
    std::fs::write(&path, text).unwrap();
    let config = load(&path).unwrap();
    assert_eq!(config.sensors[0].stream, 3);
    match &config.sources[0].kind {
        SourceKind::Replay(Replay { file, speed }) => {
            assert_eq!(file, &dir.path().join("bridge.fcap"));
            assert_eq!(*speed, Speed::Times(4.0));
        }
        other => panic!("{other:?}"),
    }
    std::fs::write(&path, text.replace("speed = 4", "speed = -1")).unwrap();
    let err = load(&path).unwrap_err();
    assert_eq!(err.key(), Some("source[0].speed"), "{err}");
}

#[test]
fn no_sensors_is_refused() {
    assert_refused(SOURCES, "sensor", None, &["no [[sensor]]"]);
    assert_refused("", "sensor", None, &["no [[sensor]]"]);
}

#[test]
fn a_public_tcp_address_needs_tcp_public() {
    let base = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    let text = format!("[outputs]\ntcp = \"0.0.0.0:2948\"\n{base}");
    assert_refused(
        &text,
        "outputs.tcp",
        Some(2),
        &["0.0.0.0:2948", "not a loopback", "tcp_public = true"],
    );
    let text = format!("[outputs]\ntcp = \"0.0.0.0:2948\"\ntcp_public = true\n{base}");
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(config.outputs.tcp(), Some("0.0.0.0:2948".parse().unwrap()));
    let text = format!("[outputs]\ntcp = \"[::1]:2948\"\n{base}");
    assert!(parse(&text, &config_path()).is_ok());
    let text = format!("[outputs]\ntcp = \"localhost:2948\"\n{base}");
    assert_refused(
        &text,
        "outputs.tcp",
        Some(2),
        &["not a socket address", "IP:PORT"],
    );
}

#[test]
fn a_public_http_address_needs_http_public() {
    let base = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    let config = parse(&base, &config_path()).unwrap();
    assert_eq!(config.outputs.http(), None);
    let text = format!("[outputs]\nhttp = \"127.0.0.1:8080\"\n{base}");
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(
        config.outputs.http(),
        Some("127.0.0.1:8080".parse().unwrap())
    );
    let text = format!("[outputs]\nhttp = \"0.0.0.0:8080\"\n{base}");
    assert_refused(
        &text,
        "outputs.http",
        Some(2),
        &["0.0.0.0:8080", "not a loopback", "http_public = true"],
    );
    // tcp_public does not open the page to the network.
    let text = format!("[outputs]\nhttp = \"0.0.0.0:8080\"\ntcp_public = true\n{base}");
    assert_refused(&text, "outputs.http", Some(2), &["http_public = true"]);
    let text = format!("[outputs]\nhttp = \"0.0.0.0:8080\"\nhttp_public = true\n{base}");
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(config.outputs.http(), Some("0.0.0.0:8080".parse().unwrap()));
    let text = format!("[outputs]\nhttp = \"localhost:8080\"\n{base}");
    assert_refused(
        &text,
        "outputs.http",
        Some(2),
        &["not a socket address", "127.0.0.1:8080"],
    );
}

#[test]
fn bad_numbers_are_refused_with_the_allowed_range() {
    let base = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    let text = base.replace("chips =", "i2c_khz = 250\nchips =");
    assert_refused(
        &text,
        "source[1].i2c_khz",
        Some(line_of(&text, "250")),
        &["100 or 400"],
    );
    let text = base.replace("chips =", "poll_ms = 0\nchips =");
    assert_refused(
        &text,
        "source[1].poll_ms",
        Some(line_of(&text, "poll_ms")),
        &["1 to 60000"],
    );
    let text = base.replace(
        "port = \"/dev/ttyUSB0\"",
        "port = \"/dev/ttyUSB0\"\nretry_s = nan",
    );
    assert_refused(
        &text,
        "source[0].retry_s",
        Some(line_of(&text, "nan")),
        &["from 0.05 to 3600"],
    );
    let text = format!("[daemon]\nstatus_interval_s = 0\n{base}");
    assert_refused(
        &text,
        "daemon.status_interval_s",
        Some(2),
        &["from 0.05 to 86400"],
    );
}

/// Issue 12: an interval that makes the loop drown, or a retry that spins,
/// is refused naming the key; the floors themselves are taken.
#[test]
fn intervals_below_their_floor_are_refused_naming_the_key() {
    let base = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    for value in ["0.000001", "0.049", "1e-300", "86401"] {
        let text = format!("[daemon]\nstatus_interval_s = {value}\n{base}");
        assert_refused(
            &text,
            "daemon.status_interval_s",
            Some(2),
            &["from 0.05 to 86400"],
        );
    }
    let text = format!("[daemon]\nstatus_interval_s = 0.05\n{base}");
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(
        config.daemon.status_interval,
        std::time::Duration::from_millis(50)
    );
    let text = base.replace(
        "port = \"/dev/ttyUSB0\"",
        "port = \"/dev/ttyUSB0\"\nretry_s = 0.000001",
    );
    assert_refused(
        &text,
        "source[0].retry_s",
        Some(line_of(&text, "0.000001")),
        &["from 0.05 to 3600"],
    );
}

/// Issue 12: `speed = 1e-300` passed the check and the replay thread
/// panicked converting it to a Duration; every speed now has a range.
#[test]
fn replay_speeds_out_of_range_are_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let header = CaptureHeader {
        version: 1,
        streams: vec![StreamInfo {
            id: 0,
            kind: StreamKind::Chip {
                chip: Chip::Lsm303dlhcMag,
                address: 0x1E,
            },
        }],
        port: None,
        baud: None,
        started_unix: 0.0,
        nominal_period_s: 0.03,
        note: None,
    };
    let file = std::fs::File::create(dir.path().join("r.fcap")).unwrap();
    CaptureWriter::new(file, &header).unwrap();
    let path = dir.path().join("fieldcal.toml");
    let text = "[[source]]\nname = \"r\"\nkind = \"replay\"\nfile = \"r.fcap\"\nspeed = SPEED\n\n\
                [[sensor]]\nname = \"c\"\nsource = \"r\"\nchip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n";
    for speed in ["1e-300", "1e-9", "0", "-1", "nan", "1e7", "1000001"] {
        std::fs::write(&path, text.replace("SPEED", speed)).unwrap();
        let err = load(&path).unwrap_err();
        let message = err.to_string();
        assert_eq!(err.key(), Some("source[0].speed"), "{message}");
        assert!(message.contains("source[0].speed"), "{message}");
        assert!(message.contains("from 0.001 to 1e6"), "{message}");
    }
    for (speed, factor) in [("0.001", 1e-3), ("1e6", 1e6), ("4", 4.0)] {
        std::fs::write(&path, text.replace("SPEED", speed)).unwrap();
        let config = load(&path).unwrap();
        match &config.sources[0].kind {
            SourceKind::Replay(Replay { speed, .. }) => assert_eq!(*speed, Speed::Times(factor)),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn the_heading_gyro_defaults_to_the_axis_the_sensor_turns_about() {
    use fieldcal::daemon::config::GyroChoice;
    let text = format!(
        "{SOURCES}
[[sensor]]
name = \"falcon\"
source = \"imu\"
field = \"mag\"
axes = [\"x\", \"y\"]

[[sensor]]
name = \"tilt\"
source = \"bridge\"
chip = \"mpu6050\"
field = \"accel\"
axes = [\"z\", \"x\"]

[[sensor]]
name = \"compass\"
source = \"bridge\"
chip = \"lsm303dlhc-mag\"
field = \"mag\"
axes = [\"x\", \"y\"]

[[sensor]]
name = \"joined\"
source = \"bridge\"
chip = \"lsm303dlhc-mag\"
field = \"mag\"
axes = [\"x\", \"z\"]
gyro_chip = \"mpu6050\"
gyro = \"z\"

[[sensor]]
name = \"off\"
source = \"imu\"
field = \"mag\"
axes = [\"x\", \"y\"]
gyro = \"none\"

[[sensor]]
name = \"scaled\"
source = \"imu\"
field = \"accel\"
axes = [\"y\", \"z\"]
gyro_lsb_per_deg_s = 57.3
"
    );
    let config = parse(&text, &config_path()).unwrap();
    let gyro: Vec<&GyroChoice> = config
        .sensors
        .iter()
        .map(|s| &s.plane().unwrap().gyro)
        .collect();
    // The Falcon-GX frame's own gyro at the frame's scale, about z.
    assert_eq!(
        *gyro[0],
        GyroChoice::Rate {
            stream: 0,
            axis: Axis::Z,
            lsb_per_deg_s: 10.0
        }
    );
    // The MPU-6050's gyro at +-250 deg/s: 131 counts per deg/s.
    assert_eq!(
        *gyro[1],
        GyroChoice::Rate {
            stream: 0,
            axis: Axis::Y,
            lsb_per_deg_s: 131.0
        }
    );
    assert_eq!(
        *gyro[2],
        GyroChoice::Off(
            "no heading check: lsm303dlhc-mag@0x1e of source 'bridge' has no gyro (give \
             gyro_chip for another chip's)"
                .into()
        )
    );
    // Another chip's gyro, on its own stream, about the axis given.
    assert_eq!(
        *gyro[3],
        GyroChoice::Rate {
            stream: 0,
            axis: Axis::Z,
            lsb_per_deg_s: 131.0
        }
    );
    assert_eq!(config.sensors[3].stream, 1);
    assert_eq!(
        *gyro[4],
        GyroChoice::Off("no heading check: gyro = \"none\" in the configuration".into())
    );
    assert_eq!(
        *gyro[5],
        GyroChoice::Rate {
            stream: 0,
            axis: Axis::X,
            lsb_per_deg_s: 57.3
        }
    );
}

#[test]
fn heading_gyro_mistakes_are_named_at_their_line() {
    let falcon = |extra: &str| {
        format!(
            "{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n{extra}\n"
        )
    };
    let text = falcon("gyro = \"w\"");
    assert_refused(
        &text,
        "sensor[0].gyro",
        Some(line_of(&text, "gyro =")),
        &["\"w\" is not a gyro axis", "\"none\""],
    );
    let text = falcon("gyro = \"x\"");
    assert_refused(
        &text,
        "sensor[0].gyro",
        Some(line_of(&text, "gyro =")),
        &["one of the two axes that turn (x, y)"],
    );
    let text = falcon("gyro_chip = \"mpu6050\"\ngyro = \"z\"");
    assert_refused(
        &text,
        "sensor[0].gyro_chip",
        Some(line_of(&text, "gyro_chip")),
        &["Falcon-GX frames", "leave gyro_chip out"],
    );
    let text = falcon("gyro_lsb_per_deg_s = 0.0");
    assert_refused(
        &text,
        "sensor[0].gyro_lsb_per_deg_s",
        Some(line_of(&text, "gyro_lsb")),
        &["above 0"],
    );
    let text = falcon("gyro_axis = \"z\"");
    assert_refused(
        &text,
        "sensor[0].gyro_axis",
        Some(line_of(&text, "gyro_axis")),
        &[
            "unknown field `gyro_axis`",
            "`gyro_chip`",
            "`gyro_lsb_per_deg_s`",
        ],
    );

    let mag = |extra: &str| {
        sensor(&format!(
            "chip = \"lsm303dlhc-mag\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n{extra}"
        ))
    };
    let text = mag("gyro = \"z\"");
    assert_refused(
        &text,
        "sensor[0].gyro",
        Some(line_of(&text, "gyro =")),
        &[
            "lsm303dlhc-mag@0x1e of source 'bridge' has no gyro",
            "gyro_chip",
        ],
    );
    let text = mag("gyro_chip = \"mpu6050\"");
    assert_refused(
        &text,
        "sensor[0].gyro",
        None,
        &["missing", "chips are not always mounted alike"],
    );
    let text = mag("gyro_chip = \"lsm303dlhc-mag\"\ngyro = \"z\"");
    assert_refused(
        &text,
        "sensor[0].gyro_chip",
        Some(line_of(&text, "gyro_chip")),
        &["lsm303dlhc-mag@0x1e has no gyro"],
    );
    let text = mag("gyro_chip = \"adxl345\"\ngyro = \"z\"");
    assert_refused(
        &text,
        "sensor[0].gyro_chip",
        Some(line_of(&text, "gyro_chip")),
        &["'adxl345' is not on source 'bridge'", "mpu6050@0x68"],
    );
    let text = mag("gyro_chip = \"mpu6050\"\ngyro = \"none\"");
    assert_refused(
        &text,
        "sensor[0].gyro_chip",
        Some(line_of(&text, "gyro_chip")),
        &["gyro = \"none\""],
    );
}

/// A CSV recording in a temporary directory, and a configuration text with
/// a csv source `log` playing it (with `source_extra`) and a sensor on it
/// (with `sensor` lines).
fn csv_source(header: &str, source_extra: &str, sensor: &str) -> (tempfile::TempDir, String) {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("robot.csv");
    std::fs::write(&csv, format!("{header}\n0,1,2,3,4\n")).unwrap();
    let text = format!(
        "[[source]]\nname = \"log\"\nkind = \"csv\"\nfile = \"{}\"\n{source_extra}\n\n\
         [[sensor]]\nname = \"robot\"\nsource = \"log\"\n{sensor}\n",
        csv.display()
    );
    (dir, text)
}

const ROBOT: &str = "t_s,mag_x_lsb,mag_z_lsb,gyro_y,temp_c";

#[test]
fn a_csv_source_names_its_columns() {
    let (dir, text) = csv_source(
        ROBOT,
        "speed = \"max\"",
        "axes = [\"mag_x_lsb\", \"mag_z_lsb\"]\ngyro = \"gyro_y\"\ngyro_units = \"rad/s\"",
    );
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(
        config.sources[0].kind,
        SourceKind::Csv(Csv {
            files: vec![dir.path().join("robot.csv")],
            speed: Speed::Max,
            time_column: None,
            period_s: None,
        })
    );
    assert_eq!(config.sources[0].kind.speed(), Some(Speed::Max));
    let s = &config.sensors[0];
    assert_eq!(
        s.plane().unwrap().columns,
        Some(["mag_x_lsb".to_string(), "mag_z_lsb".to_string()])
    );
    assert_eq!(
        s.plane().unwrap().gyro,
        GyroChoice::Column {
            name: "gyro_y".into(),
            units: GyroUnits::RadPerSecond
        }
    );
    // Without a gyro column, no heading check, and the CALIBRATION says
    // how to get one.
    let (_dir, text) = csv_source(ROBOT, "", "axes = [\"mag_x_lsb\", \"mag_z_lsb\"]");
    let config = parse(&text, &config_path()).unwrap();
    assert_eq!(config.sources[0].kind.speed(), Some(Speed::Times(1.0)));
    match &config.sensors[0].plane().unwrap().gyro {
        GyroChoice::Off(why) => assert!(why.contains("gyro = \"COLUMN\""), "{why}"),
        other => panic!("{other:?}"),
    }
    // A named time column and a period (for a file without one).
    let (_dir, text) = csv_source("a,b,c,d,e", "time_column = \"c\"", "axes = [\"a\", \"b\"]");
    let config = parse(&text, &config_path()).unwrap();
    assert!(matches!(
        &config.sources[0].kind,
        SourceKind::Csv(Csv { time_column: Some(c), period_s: None, .. }) if c == "c"
    ));
    let (_dir, text) = csv_source("a,b,c,d,e", "period_s = 0.1", "axes = [\"a\", \"b\"]");
    let config = parse(&text, &config_path()).unwrap();
    assert!(matches!(
        &config.sources[0].kind,
        SourceKind::Csv(Csv { period_s: Some(p), .. }) if *p == 0.1
    ));
}

#[test]
fn a_csv_sensor_is_told_the_form_its_source_wants() {
    let axes = "axes = [\"mag_x_lsb\", \"mag_z_lsb\"]";
    // Device axes on a csv source: the columns it has are listed.
    let (_dir, text) = csv_source(ROBOT, "", "axes = [\"x\", \"y\"]");
    assert_refused(
        &text,
        "sensor[0].axes[0]",
        Some(line_of(&text, "axes")),
        &[
            "robot.csv:1: no column 'x' in the header",
            "columns: t_s, mag_x_lsb, mag_z_lsb, gyro_y, temp_c",
            "not the x, y, z",
        ],
    );
    // Column names on a device's source.
    let text = format!(
        "{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"mag_z\"]\n"
    );
    assert_refused(
        &text,
        "sensor[0].axes[1]",
        Some(line_of(&text, "axes")),
        &["\"mag_z\" is not an axis", "falcon", "kind = \"csv\""],
    );
    // The keys of a device's sensor on a csv source.
    for (key, line) in [
        ("field", "field = \"mag\""),
        ("chip", "chip = \"mpu6050\""),
        ("gyro_lsb_per_deg_s", "gyro_lsb_per_deg_s = 131.0"),
    ] {
        let (_dir, text) = csv_source(ROBOT, "", &format!("{axes}\n{line}"));
        assert_refused(
            &text,
            &format!("sensor[0].{key}"),
            Some(line_of(&text, line)),
            &["csv source 'log' has no", "names two columns"],
        );
    }
    // A device's sensor needs its field.
    let text =
        format!("{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\naxes = [\"x\", \"y\"]\n");
    assert_refused(&text, "sensor[0].field", None, &["missing", "\"mag\""]);
    // The time column is not an axis; the gyro is not one of the axes.
    let (_dir, text) = csv_source(ROBOT, "", "axes = [\"t_s\", \"mag_z_lsb\"]");
    assert_refused(&text, "sensor[0].axes[0]", None, &["the time column"]);
    let (_dir, text) = csv_source(ROBOT, "", &format!("{axes}\ngyro = \"mag_z_lsb\""));
    assert_refused(
        &text,
        "sensor[0].gyro",
        Some(line_of(&text, "gyro =")),
        &["one of the two axes"],
    );
    let (_dir, text) = csv_source(ROBOT, "", &format!("{axes}\ngyro = \"gyro_q\""));
    assert_refused(
        &text,
        "sensor[0].gyro",
        None,
        &["no column 'gyro_q'", "gyro_y"],
    );
    // Units: known ones, and only with a gyro column.
    let (_dir, text) = csv_source(
        ROBOT,
        "",
        &format!("{axes}\ngyro = \"gyro_y\"\ngyro_units = \"rpm\""),
    );
    assert_refused(&text, "sensor[0].gyro_units", None, &["\"rpm\"", "rad/s"]);
    let (_dir, text) = csv_source(ROBOT, "", &format!("{axes}\ngyro_units = \"rad/s\""));
    assert_refused(
        &text,
        "sensor[0].gyro_units",
        None,
        &["without a gyro column"],
    );
    let text = sensor(
        "chip = \"mpu6050\"\nfield = \"accel\"\naxes = [\"x\", \"y\"]\ngyro_units = \"rad/s\"",
    );
    assert_refused(&text, "sensor[0].gyro_units", None, &["gyro_lsb_per_deg_s"]);
    // Two axes, different.
    let (_dir, text) = csv_source(ROBOT, "", "axes = [\"mag_x_lsb\", \"mag_x_lsb\"]");
    assert_refused(
        &text,
        "sensor[0].axes",
        None,
        &["both axes are \"mag_x_lsb\""],
    );
}

#[test]
fn a_csv_file_is_checked_before_anything_starts() {
    let axes = "axes = [\"mag_x_lsb\", \"mag_z_lsb\"]";
    let (dir, text) = csv_source(ROBOT, "", axes);
    let csv = dir.path().join("robot.csv").display().to_string();
    // Missing, and not a regular file.
    let missing = text.replace(&csv, &format!("{csv}.gone"));
    assert_refused(
        &missing,
        "source[0].file",
        Some(line_of(&missing, "file =")),
        &["robot.csv.gone", "relative paths are relative to"],
    );
    let folder = text.replace(&csv, &dir.path().display().to_string());
    assert_refused(&folder, "source[0].file", None, &["is not a regular file"]);
    // No header, a duplicate column.
    std::fs::write(dir.path().join("robot.csv"), "").unwrap();
    assert_refused(
        &text,
        "source[0].file",
        None,
        &["robot.csv: the file is empty", "header"],
    );
    std::fs::write(dir.path().join("robot.csv"), "# only a comment\n\nt,a,a\n").unwrap();
    assert_refused(
        &text,
        "source[0].file",
        None,
        &["robot.csv:3: column 'a' appears twice", "rename one"],
    );
    // Time column against period_s.
    std::fs::write(dir.path().join("robot.csv"), format!("{ROBOT}\n")).unwrap();
    let both = text.replace("kind = \"csv\"", "kind = \"csv\"\nperiod_s = 0.1");
    assert_refused(
        &both,
        "source[0].period_s",
        Some(line_of(&both, "period_s")),
        &[
            "robot.csv:1: the header has time column 't_s'",
            "remove period_s",
        ],
    );
    let bad_period = text.replace("kind = \"csv\"", "kind = \"csv\"\nperiod_s = -1");
    assert_refused(&bad_period, "source[0].period_s", None, &["above 0"]);
    let named = text.replace("kind = \"csv\"", "kind = \"csv\"\ntime_column = \"when\"");
    assert_refused(
        &named,
        "source[0].time_column",
        Some(line_of(&named, "time_column")),
        &["no column 'when' for time", "t_s, mag_x_lsb"],
    );
    std::fs::write(dir.path().join("robot.csv"), "mag_x_lsb,mag_z_lsb\n").unwrap();
    assert_refused(
        &text,
        "source[0].period_s",
        None,
        &["robot.csv:1: no time column", "give period_s"],
    );
    // Keys of other kinds are refused, naming the csv source's.
    let text = text.replace("kind = \"csv\"", "kind = \"csv\"\nport = \"/dev/ttyUSB0\"");
    assert_refused(
        &text,
        "source[0].port",
        None,
        &["file, files, speed, time_column, period_s"],
    );
}

#[test]
fn a_wrong_element_is_named_at_its_index_and_a_date_is_no_path() {
    let text = format!("{SOURCES}\n").replace(
        "chips = [\"mpu6050\", \"lsm303dlhc-mag@0x1e\"]",
        "chips = [\"mpu6050\", 5]",
    );
    assert_refused(
        &text,
        "source[1].chips[1]",
        Some(line_of(&text, "chips")),
        &["invalid type: integer `5`, expected a string"],
    );
    let text = format!("{SOURCES}\n").replace("port = \"/dev/ttyUSB0\"", "port = 1979-05-27");
    assert_refused(
        &text,
        "source[0].port",
        Some(line_of(&text, "1979-05-27")),
        &["invalid type: map, expected path string"],
    );
    let text = "[outputs]\nrecalibrate_from = [\"unix\", 5]\n";
    assert_refused(
        text,
        "outputs.recalibrate_from[1]",
        Some(2),
        &["expected a string"],
    );
}

#[test]
fn learn_and_on_stale_are_read_for_a_plane_and_on_stale_for_a_sphere() {
    use fieldcal::daemon::config::{OnStale, WatchSettings};
    let plane = format!(
        "{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\nlearn = true\non_stale = \"replace\"\n"
    );
    let config = parse(&plane, &config_path()).unwrap();
    assert_eq!(
        config.sensors[0].plane().map(|p| p.watch),
        Some(WatchSettings {
            learn: true,
            on_stale: OnStale::Replace
        })
    );
    let default = plane.replace("learn = true\non_stale = \"replace\"\n", "");
    let config = parse(&default, &config_path()).unwrap();
    assert_eq!(
        config.sensors[0].plane().map(|p| p.watch),
        Some(WatchSettings {
            learn: false,
            on_stale: OnStale::Warn
        })
    );
    let wrong = plane.replace("on_stale = \"replace\"", "on_stale = \"ignore\"");
    let message = refused(&wrong).to_string();
    assert!(
        message.contains("unknown variant `ignore`, expected `warn` or `replace`"),
        "{message}"
    );
    let sphere = format!(
        "{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\nlearn = true\n"
    );
    assert_refused(
        &sphere,
        "sensor[0].learn",
        None,
        &[
            "3-axis",
            "watched (`on_stale`) but not merged",
            "remove the key",
        ],
    );
    // A sphere's on_stale is read; warn by default.
    let sphere = sphere.replace("learn = true\n", "on_stale = \"replace\"\n");
    let config = parse(&sphere, &config_path()).unwrap();
    assert_eq!(
        config.sensors[0].sphere().map(|s| s.on_stale),
        Some(OnStale::Replace)
    );
    let config = parse(
        &sphere.replace("on_stale = \"replace\"\n", ""),
        &config_path(),
    )
    .unwrap();
    assert_eq!(
        config.sensors[0].sphere().map(|s| s.on_stale),
        Some(OnStale::Warn)
    );
}

/// `out_of_plane` names the axis across a 2-axis sensor's turn: a third
/// axis of its field, never one that turns; a 3-axis sensor has none.
#[test]
fn out_of_plane_is_the_third_axis_of_a_plane() {
    use fieldcal::daemon::config::{Axis, OutOfPlane};
    let plane = |extra: &str| {
        format!(
            "{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n{extra}"
        )
    };
    let config = parse(&plane("out_of_plane = \"z\"\n"), &config_path()).unwrap();
    assert_eq!(
        config.sensors[0].plane().unwrap().out_of_plane,
        Some(OutOfPlane::Axis(Axis::Z))
    );
    let config = parse(&plane(""), &config_path()).unwrap();
    assert_eq!(config.sensors[0].plane().unwrap().out_of_plane, None);
    for bad in ["x", "w"] {
        assert_refused(
            &plane(&format!("out_of_plane = \"{bad}\"\n")),
            "sensor[0].out_of_plane",
            None,
            &[&format!(
                "\"{bad}\" is not the axis across the turn: give \"z\""
            )],
        );
    }
    let sphere = format!(
        "{SOURCES}\n[[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\", \"z\"]\nout_of_plane = \"z\"\n"
    );
    assert_refused(&sphere, "sensor[0].out_of_plane", None, &["2-axis"]);
}

/// Issue 23, finding 8: a path is shown as written, not as `././state`
/// (a relative file beside a configuration given as `./fieldcal.toml`).
#[test]
fn relative_paths_are_resolved_without_dot_components() {
    let text = format!(
        "[daemon]\nstate_dir = \"./state\"\n{SOURCES}\n[[sensor]]\nname = \"c\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n"
    );
    for config in ["./fieldcal.toml", "fieldcal.toml", "./etc/./fieldcal.toml"] {
        let parsed = parse(&text, Path::new(config)).unwrap();
        let want = if config.contains("etc") {
            PathBuf::from("etc/state")
        } else {
            PathBuf::from("state")
        };
        assert_eq!(parsed.daemon.state_dir, want, "{config}");
    }
}
