//! The `fieldcal` command: parses arguments and wires the library together.
//! One module per subcommand; the work itself lives in the library.

mod check;
mod diagnose;
mod fit;
mod heading;
mod output;
mod record;
mod replay;
mod run;
mod signals;
mod simulate;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Args, Parser, Subcommand, ValueEnum};

use fieldcal::io::csv::{Covariates, CsvError, RowsRead};
use fieldcal::model::gyro::{GyroUnits, HeadingReference};
use fieldcal::model::spike::Spike;
use fieldcal::sample::Dataset;

use fieldcal::model::fit::{DEFAULT_MIN_COVERAGE_DEG, Solver};
use fieldcal::model::paper::PAPER_LEARNING_RATE;
use fieldcal::protocol::chips::Chip;
use fieldcal::source::replay::Speed;

#[derive(Debug, Parser)]
#[command(
    name = "fieldcal",
    version,
    about = "Calibrates 2- and 3-axis field sensors (magnetometers, accelerometers): turned (2-D) or tumbled (3-D) in a constant field",
    long_about = None
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Fit the paper's calibration (or the paper's model plus --effects) to a CSV recording of one full turn.
    Fit(FitArgs),
    /// Apply a stored calibration to another recording: does it hold, and which parameter moved?
    Check(CheckArgs),
    /// The tilt-compensated heading of every sample, from a 3-axis magnetometer and accelerometer on one board (true north with a declination or a place).
    Heading(HeadingArgs),
    /// Rank the effects the data supports, add them one by one down to the noise floor.
    Diagnose(DiagnoseArgs),
    /// Write a simulated sensor turned in a constant field: a CSV, or a Falcon-GX capture.
    Simulate(SimulateArgs),
    /// Run the daemon: read the configured sensors, calibrate on a full rotation, publish corrected readings.
    Run(RunArgs),
    /// Capture a device's bytes, exactly as they come off the wire, to a file.
    Record(RecordArgs),
    /// Decode a capture (or a raw dump) and print its samples as JSON lines.
    Replay(ReplayArgs),
}

/// The kind of device on a port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DeviceKind {
    /// A Falcon-GX-style IMU streaming 23-byte frames over RS-232.
    Falcon,
    /// A Devantech USB-ISS I2C bridge with chips behind it, polled.
    UsbIss,
}

#[derive(Debug, Args)]
struct RecordArgs {
    /// Serial port of the device (for example /dev/ttyUSB0).
    #[arg(long, value_name = "PATH")]
    port: PathBuf,
    /// What is on the port.
    #[arg(long, value_enum, default_value_t = DeviceKind::Falcon)]
    device: DeviceKind,
    /// Line speed (Falcon-GX; the USB-ISS ignores it).
    #[arg(long, default_value_t = fieldcal::protocol::falcon::BAUD)]
    baud: u32,
    /// usb-iss: a chip to poll, as NAME or NAME@ADDRESS (7-bit, e.g. mpu6050@0x69); repeat for several.
    #[arg(long, value_name = "CHIP[@ADDR]", value_parser = parse_chip)]
    chip: Vec<(Chip, u8)>,
    /// usb-iss: poll period in milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 30, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    poll_ms: u64,
    /// Stop after this many seconds (default: until Ctrl-C or SIGTERM).
    #[arg(long, value_name = "SECS", value_parser = parse_duration, allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Capture file to write.
    #[arg(long, short, value_name = "FILE")]
    output: PathBuf,
    /// Print a JSON summary on stdout at the end.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct RunArgs {
    /// The daemon's TOML configuration (see config/fieldcal.toml).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
    /// Each sensor's progress on a live line (auto: when stderr is a terminal; otherwise, and with never, log lines at each quarter of the turn and at its end).
    #[arg(long, value_name = "WHEN", default_value = "auto", value_parser = ["never", "auto", "always"])]
    progress: String,
}

#[derive(Debug, Args)]
struct ReplayArgs {
    /// A capture written by `fieldcal record` or `fieldcal simulate --format falcon`, a raw byte dump of Falcon-GX frames, or (with --config naming a csv source) a CSV recording.
    file: PathBuf,
    /// N times real time (1 = as recorded), or max [default: with --config, the source's configured speed; else 1].
    #[arg(long, value_parser = parse_speed, allow_negative_numbers = true)]
    speed: Option<Speed>,
    /// Print a JSON summary line (class SUMMARY) after the samples.
    #[arg(long)]
    json: bool,
    /// Run the capture through the daemon's pipeline as configured here: print what `fieldcal run` would have published.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// With --config: the source the capture stands in for (default: the first).
    #[arg(long, value_name = "NAME", requires = "config")]
    source: Option<String>,
}

/// A CSV recording and which of its columns hold what.
#[derive(Debug, Args)]
struct CsvInput {
    /// CSV file: a header line, then one sample per line.
    file: PathBuf,
    /// Column holding the x axis [default: x]
    #[arg(long, value_name = "COL")]
    x: Option<String>,
    /// Column holding the y axis [default: y]
    #[arg(long, value_name = "COL")]
    y: Option<String>,
    /// Column holding the z axis: fit in 3-D [default: z, when the file has a `z` column and neither --x nor --y is given]
    #[arg(long, value_name = "COL")]
    z: Option<String>,
    /// Column holding time in seconds [default: the first of t, t_s, time, time_s]
    #[arg(long, value_name = "COL")]
    t: Option<String>,
    /// A gyroscope axis about the turn's axis, as a heading reference: COLUMN of this CSV, or FILE:COLUMN of a second CSV on the same clock (joined by that file's time column t, t_s, time or time_s).
    #[arg(long, value_name = "[FILE:]COLUMN")]
    gyro: Option<String>,
    /// Units of the --gyro column.
    #[arg(long, value_enum, value_name = "UNITS", default_value_t = GyroUnits::DegPerSecond)]
    gyro_units: GyroUnits,
    /// Set by a command that has no use for the times (not an option):
    /// the time column is not parsed ([`fieldcal::io::csv::ColumnSpec::read_time`]).
    #[arg(skip)]
    times_unused: bool,
}

impl CsvInput {
    fn x_column(&self) -> &str {
        self.x.as_deref().unwrap_or("x")
    }

    fn y_column(&self) -> &str {
        self.y.as_deref().unwrap_or("y")
    }

    /// The z column of a 3-axis analysis: --z, or `z` when the file has a
    /// `z` column and --x and --y were left at their defaults. `None`: the
    /// analysis is the 2-axis one.
    fn z_column(&self) -> anyhow::Result<Option<String>> {
        if let Some(z) = &self.z {
            return Ok(Some(z.clone()));
        }
        // Axes named on the command line choose the 2-axis analysis
        // unless --z is given too.
        if self.x.is_some() || self.y.is_some() {
            return Ok(None);
        }
        let header = fieldcal::io::csv::header(&self.file)?;
        Ok(header.iter().any(|h| h == "z").then(|| "z".to_string()))
    }

    /// The 3-axis recording, with its z column from [`Self::z_column`].
    fn read3(
        &self,
        z: &str,
        covariates: &Covariates,
    ) -> anyhow::Result<fieldcal::sample::Dataset3> {
        let spec = self.spec();
        let data = fieldcal::io::csv::read_dataset3_with(&self.file, &spec, z, covariates)?;
        Ok(data)
    }

    fn spec(&self) -> fieldcal::io::csv::ColumnSpec {
        fieldcal::io::csv::ColumnSpec {
            x: self.x_column().to_string(),
            y: self.y_column().to_string(),
            t: self.t.clone(),
            read_time: !self.times_unused,
        }
    }

    /// The 2-axis recording with the `covariates` chosen, without the
    /// readings the spike gate refuses (told on stderr).
    fn read(&self, covariates: &Covariates) -> anyhow::Result<fieldcal::sample::Dataset> {
        let spec = self.spec();
        let (data, refused) = read_gated(None, |watch| {
            fieldcal::io::csv::read_dataset_watched(&self.file, &spec, covariates, watch)
        });
        let data = data?;
        let rows = tell_spikes(&self.file, &refused, [&data.x_name, &data.y_name, ""]);
        Ok(data.without_rows(&rows))
    }

    /// [`Self::read3`] for a fit or a check: without the readings the
    /// spike gate refuses (told on stderr).
    fn read3_gated(
        &self,
        z: &str,
        covariates: &Covariates,
    ) -> anyhow::Result<fieldcal::sample::Dataset3> {
        let spec = self.spec();
        let (data, refused) = read_gated(Some(z), |watch| {
            fieldcal::io::csv::read_dataset3_watched(&self.file, &spec, z, covariates, watch)
        });
        let data = data?;
        let rows = tell_spikes(
            &self.file,
            &refused,
            [&data.x_name, &data.y_name, &data.z_name],
        );
        Ok(data.without_rows(&rows))
    }

    /// Whether `--gyro` names a column of the recording's own file (by its
    /// path or by none): that column is then the heading reference and no
    /// covariate.
    fn gyro_in_recording(&self) -> bool {
        let Some(gyro) = &self.gyro else {
            return false;
        };
        match gyro.rsplit_once(':') {
            None => true,
            Some((file, _)) => {
                match (
                    std::fs::canonicalize(file),
                    std::fs::canonicalize(&self.file),
                ) {
                    (Ok(a), Ok(b)) => a == b,
                    _ => false,
                }
            }
        }
    }

    /// The column `--gyro` names when it is the recording's own.
    fn own_gyro_column(&self) -> Option<&str> {
        let gyro = self.gyro.as_deref()?;
        let column = gyro.rsplit_once(':').map_or(gyro, |(_, column)| column);
        self.gyro_in_recording().then_some(column)
    }

    /// The recording with the `covariates` chosen (and the gyro column,
    /// when it is the recording's), and the gyro's heading reference when
    /// --gyro names one. A gyro column of the recording itself is not a
    /// covariate: it is taken out of the dataset's covariates.
    fn read_with_reference(
        &self,
        covariates: &Covariates,
    ) -> anyhow::Result<(Dataset, Option<HeadingReference>)> {
        let Some(gyro) = &self.gyro else {
            return Ok((self.read(covariates)?, None));
        };
        // FILE:COLUMN splits at the last ':' (a path may hold one).
        let (file, column) = match gyro.rsplit_once(':') {
            Some((file, column)) => (Some(PathBuf::from(file)), column),
            None => (None, gyro.as_str()),
        };
        let covariates = match covariates {
            Covariates::Only(names) if self.gyro_in_recording() => {
                Covariates::Only(names.iter().cloned().chain([column.to_string()]).collect())
            }
            chosen => chosen.clone(),
        };
        let mut data = self.read(&covariates)?;
        if column.is_empty() || file.as_ref().is_some_and(|f| f.as_os_str().is_empty()) {
            anyhow::bail!(
                "--gyro '{gyro}': give a column of the recording (--gyro gyro_z) or a file and its column (--gyro imu.csv:gyro_z)"
            );
        }
        let main = self.file.display();
        let Some(sample_t) = data.t.clone() else {
            anyhow::bail!(
                "{main}: the recording has no time column (t, t_s, time or time_s, or choose one with --t), and the gyro '{column}' is integrated over time"
            );
        };
        let other_file = file.filter(|_| !self.gyro_in_recording());
        let reference = match &other_file {
            None => {
                let Some(k) = data.covariates.iter().position(|c| c.name == column) else {
                    // Every numeric column is named: read them all.
                    if covariates != Covariates::All {
                        return self.read_with_reference(&Covariates::All);
                    }
                    let names: Vec<&str> =
                        data.covariates.iter().map(|c| c.name.as_str()).collect();
                    let names = if names.is_empty() {
                        "none".to_string()
                    } else {
                        names.join(", ")
                    };
                    anyhow::bail!(
                        "{main}: no gyro column '{column}' among the numeric columns other than the axes ({}, {}) and time (they are: {names}); name it with --gyro COLUMN, or --gyro FILE:COLUMN for a second file",
                        data.x_name,
                        data.y_name
                    );
                };
                let rate = data.covariates.remove(k).values;
                HeadingReference::from_rates(column, &sample_t, &sample_t, &rate, self.gyro_units)
                    .with_context(|| format!("{main}: gyro '{column}'"))?
            }
            Some(file) => {
                let series = fieldcal::io::csv::read_series(file, column, "the gyro", "--gyro")?;
                HeadingReference::from_rates(
                    column,
                    &sample_t,
                    &series.t,
                    &series.values,
                    self.gyro_units,
                )
                .with_context(|| {
                    format!(
                        "{}: gyro '{column}' against {main} (joined by time: '{}' there)",
                        file.display(),
                        series.time_name
                    )
                })?
            }
        };
        Ok((data, Some(reference)))
    }
}

/// Readings a spike warning lists by row at most.
const SPIKES_LISTED: usize = 5;

/// Notes for stderr once the command has done its work (a failed one
/// prints its one error line alone).
static NOTES: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

fn note(text: String) {
    if let Ok(mut notes) = NOTES.lock() {
        notes.push(text);
    }
}

/// Tells on stderr, after the command's output, which readings of `file`
/// the spike gate left out of the analysis (the daemon's gate,
/// [`fieldcal::model::spike`]); their rows.
fn tell_spikes(file: &Path, refused: &[(usize, Spike)], axes: [&str; 3]) -> Vec<usize> {
    let rows = refused.iter().map(|(i, _)| *i).collect();
    if refused.is_empty() {
        return rows;
    }
    let listed: Vec<String> = refused
        .iter()
        .take(SPIKES_LISTED)
        .map(|(i, s)| {
            let axis = axes.get(s.axis).copied().unwrap_or("?");
            format!("row {} after the header: {}", i + 1, s.describe(axis))
        })
        .collect();
    let more = refused.len().saturating_sub(SPIKES_LISTED);
    note(format!(
        "fieldcal: {}: {} left out as spikes (far off the readings around them: a bad frame, EMI, a garbage row, a jolt): {}{}",
        file.display(),
        fieldcal::sample::count(refused.len() as u64, "reading"),
        listed.join("; "),
        if more > 0 {
            format!("; and {more} more")
        } else {
            String::new()
        }
    ));
    rows
}

/// A 3-axis recording without the readings the spike gate refuses (told
/// on stderr).
fn without_spikes3(file: &Path, data: fieldcal::sample::Dataset3) -> fieldcal::sample::Dataset3 {
    let refused = fieldcal::model::spike::refused_rows(data.points.iter().copied());
    let rows = tell_spikes(file, &refused, [&data.x_name, &data.y_name, &data.z_name]);
    data.without_rows(&rows)
}

/// What `read` reads, and the rows the spike gate refuses, judged on the
/// other core as they are read: the two axes, and the covariate `z` as
/// the third when it is one (a 3-axis recording).
fn read_gated<D>(
    z: Option<&str>,
    read: impl FnOnce(&mut dyn FnMut(RowsRead<'_>)) -> Result<D, CsvError>,
) -> (Result<D, CsvError>, Vec<(usize, Spike)>) {
    // A few blocks in flight: the reader waits rather than queue a file.
    let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<[f64; 3]>>(4);
    std::thread::scope(|s| {
        let gate = s.spawn(move || fieldcal::model::spike::refused_rows(rx.into_iter().flatten()));
        let read = read(&mut |rows: RowsRead<'_>| {
            let third = z.and_then(|z| rows.covariates.iter().find(|c| c.name == z));
            let block = (rows.from..rows.x.len())
                .map(|i| {
                    let z = third.and_then(|c| c.values.get(i)).copied();
                    [rows.x[i], rows.y[i], z.unwrap_or(f64::NAN)]
                })
                .collect();
            // The gate ends early only by a panic, which the join raises.
            let _ = tx.send(block);
        });
        drop(tx);
        let refused = gate.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
        (read, refused)
    })
}

#[derive(Debug, Args)]
struct FitArgs {
    #[command(flatten)]
    input: CsvInput,
    /// Solver: closed-form least squares, or the paper's gradient descent.
    #[arg(long, value_enum, default_value_t = Solver::Lsq)]
    solver: Solver,
    /// Fit the paper's model plus these effects by Levenberg-Marquardt
    /// (comma- or plus-separated: cross-axis, drift, covariate:<column>,
    /// cubic, cubic-centred, outliers; `paper` is offset+scale). With three
    /// axes: the model, offset, offset+scale (paper) or
    /// offset+scale+cross-axis (full, the default).
    #[arg(long, value_name = "LIST", value_parser = parse_effect_list)]
    effects: Option<EffectList>,
    /// Three axes: the unit of the readings, printed with r and the offsets [default: g when the three columns' names start with `acc`, else unknown]
    #[arg(long, value_name = "UNIT")]
    units: Option<String>,
    /// Three axes: fit on the still poses only (an accelerometer at rest in several poses, or the pauses of a tumble), found automatically.
    #[arg(long)]
    still: bool,
    /// With --still: the gyroscope's three rate columns of the recording, as X,Y,Z (in --gyro-units), whose rate must stay under a hand's 5 °/s [default: gyro_x,gyro_y,gyro_z when the recording has them; `none`: the readings alone]
    #[arg(long, value_name = "X,Y,Z", requires = "still")]
    still_gyro: Option<String>,
    /// Print one JSON object on stdout instead of the text report.
    #[arg(long)]
    json: bool,
    /// Write every sample's calibrated x, y (and t when the input has it) to this CSV.
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Heading coverage the turn must reach, in degrees.
    #[arg(long, value_name = "DEG", default_value_t = DEFAULT_MIN_COVERAGE_DEG, value_parser = parse_coverage)]
    min_coverage: f64,
    /// paper-gd: iterations before giving up.
    #[arg(long, value_name = "N", default_value_t = 1_000_000, value_parser = clap::value_parser!(u64).range(1..))]
    max_iterations: u64,
    /// paper-gd: learning rate (the paper's is 0.73).
    #[arg(long, value_name = "ALPHA", default_value_t = PAPER_LEARNING_RATE, value_parser = parse_positive)]
    learning_rate: f64,
}

#[derive(Debug, Args)]
struct HeadingArgs {
    /// The magnetometer: its CSV (the file), its three columns (--x, --y, --z), time (--t), and --gyro as in `fit`.
    #[command(flatten)]
    input: CsvInput,
    /// The magnetometer's 3-D calibration: the JSON of `fieldcal fit --json` on its three columns [default: none, the raw readings]
    #[arg(long, value_name = "FILE")]
    mag_calibration: Option<PathBuf>,
    /// The accelerometer's three columns, X,Y,Z of the magnetometer's CSV, or FILE:X,Y,Z of a second CSV on the same clock (interpolated to the magnetometer's times).
    #[arg(long, value_name = "[FILE:]X,Y,Z")]
    accel: String,
    /// The accelerometer's 3-D calibration (`fieldcal fit --json`) [default: none, the raw readings]
    #[arg(long, value_name = "FILE")]
    accel_calibration: Option<PathBuf>,
    /// How the magnetometer lies on the board (the accelerometer's frame): body x,y,z as signed magnetometer axes (e.g. x,-z,y), or auto: the mapping that keeps the dip most constant while the board tilts.
    #[arg(
        long,
        value_name = "MAP|auto",
        default_value = "x,y,z",
        allow_hyphen_values = true
    )]
    mag_axes: String,
    /// The gyro's three axes in the accelerometer's frame (in --gyro-units; -COLUMN for an axis that points the other way), X,Y,Z of the magnetometer's CSV or FILE:X,Y,Z: the board's vertical is then the accelerometer's steadied by the gyro (a complementary filter), which keeps a hand's accelerations out of it; without --gyro, the heading is checked against the rate about that vertical.
    #[arg(long, value_name = "[FILE:]X,Y,Z", allow_hyphen_values = true)]
    rates: Option<String>,
    /// With --rates: the seconds over which the gyro is trusted before the accelerometer (a gyro bias of b tilts the vertical by about b times this).
    #[arg(long, value_name = "S", default_value_t = fieldcal::model::vertical::DEFAULT_TAU_S, requires = "rates")]
    fusion_tau: f64,
    /// The board's axis whose heading is reported (x, -y, ...).
    #[arg(
        long,
        value_name = "AXIS",
        default_value = "x",
        allow_hyphen_values = true
    )]
    forward: String,
    /// The board's axis that points up when it lies level.
    #[arg(
        long,
        value_name = "AXIS",
        default_value = "z",
        allow_hyphen_values = true
    )]
    up: String,
    /// Magnetic declination, degrees east of true north: heading is then from true north.
    #[arg(
        long,
        value_name = "DEG",
        allow_negative_numbers = true,
        conflicts_with = "latitude"
    )]
    declination: Option<f64>,
    /// Latitude of the recording (WGS 84, degrees north): the World Magnetic Model gives the declination and the field to compare.
    #[arg(
        long,
        value_name = "DEG",
        allow_negative_numbers = true,
        requires = "longitude"
    )]
    latitude: Option<f64>,
    /// Longitude of the recording (WGS 84, degrees east).
    #[arg(
        long,
        value_name = "DEG",
        allow_negative_numbers = true,
        requires = "latitude"
    )]
    longitude: Option<f64>,
    /// Height above the WGS 84 ellipsoid, metres.
    #[arg(
        long,
        value_name = "M",
        default_value_t = 0.0,
        allow_negative_numbers = true,
        requires = "latitude"
    )]
    altitude: f64,
    /// Date of the recording, YYYY-MM-DD [default: today]
    #[arg(long, value_name = "DATE", requires = "latitude")]
    date: Option<String>,
    /// Units of the magnetometer's readings, to compare the field's magnitude with the model's [default: the calibration's units]
    #[arg(long, value_enum, value_name = "UNITS")]
    mag_units: Option<fieldcal::geomag::MagUnits>,
    /// Write every sample's t, heading, level heading, tilt, pitch and inclination to this CSV.
    #[arg(long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Print one JSON object on stdout instead of the text report.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct CheckArgs {
    #[command(flatten)]
    input: CsvInput,
    /// The stored calibration: the JSON of `fieldcal fit --json` (the paper's model or --effects), or a daemon state file.
    #[arg(long, value_name = "FILE")]
    calibration: PathBuf,
    /// Print one JSON object on stdout instead of the text report.
    #[arg(long)]
    json: bool,
    /// Heading coverage the new recording must reach, in degrees.
    #[arg(long, value_name = "DEG", default_value_t = DEFAULT_MIN_COVERAGE_DEG, value_parser = parse_coverage)]
    min_coverage: f64,
    /// Also judge every reading as the daemon's trust monitor does, and list the stretches where the heading could not be trusted, with their reasons (needs the time column; with --gyro, the heading against it too).
    #[arg(long)]
    monitor: bool,
    /// With --monitor: write a report with the field and the distrusted stretches over time into this directory.
    #[arg(long, value_name = "DIR", requires = "monitor")]
    report: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct DiagnoseArgs {
    #[command(flatten)]
    input: CsvInput,
    /// The model to start from, as in `fit --effects` (default: paper, i.e. offset+scale).
    #[arg(long, value_name = "LIST")]
    effects: Option<String>,
    /// Print one JSON object on stdout instead of the text report.
    #[arg(long)]
    json: bool,
    /// Write a report with plots into this directory.
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct SimulateArgs {
    /// Write here instead of stdout (a capture needs a file). An existing file is never replaced without --force.
    #[arg(long, short, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Replace the --output file if it exists.
    #[arg(long, requires = "output")]
    force: bool,
    /// What to write: a CSV of x, y, or a capture of a Falcon-GX-style IMU whose magnetometer turns.
    #[arg(long, value_enum, default_value_t = SimFormat::Csv)]
    format: SimFormat,
    /// falcon: fraction of garbage bytes spliced between frames (0.01 = 1 %).
    #[arg(long, default_value_t = 0.0, value_parser = parse_garbage, allow_negative_numbers = true)]
    garbage: f64,
    /// Print the simulated sensor and its true calibration as JSON on stdout (needs --output).
    #[arg(long)]
    json: bool,
    /// Field magnitude, in counts at unit gain.
    #[arg(long, default_value_t = 1000.0, allow_negative_numbers = true)]
    field: f64,
    /// Gain of the x axis.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    gain_x: f64,
    /// Gain of the y axis.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    gain_y: f64,
    /// Offset of the x axis, in counts.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    offset_x: f64,
    /// Offset of the y axis, in counts.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    offset_y: f64,
    /// Standard deviation of Gaussian noise on each axis, in counts.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    noise: f64,
    /// Sample period in seconds (0.05 for the Falcon-GX, 0.03 for I2C polling).
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    period: f64,
    /// Number of rotations.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    turns: f64,
    /// Seconds one rotation takes.
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true)]
    turn_seconds: f64,
    /// Heading of the first sample, in degrees.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    start_heading: f64,
    /// Seed of the noise generator.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// A hidden effect the paper's model lacks; repeat for several.
    /// cross-axis=DEG: the y axis tilted toward x (3 or 3deg);
    /// drift=X[,Y]: offsets moving in counts per second (one value: both axes);
    /// covariate:temp=X[,Y]: counts per °C of a `temp` column (20 °C, rising by --temp-rise, cooling back after half-way);
    /// covariate:current=X[,Y]: counts per A of a `current` column (a motor switching 0 A / 2 A);
    /// cubic=X[,Y]: the reading falls short by that fraction at full scale;
    /// cubic-centred=X[,Y]: each axis's reading falls short by that fraction at the turn's amplitude, about the turn's centre (one value: both axes);
    /// outliers=F: that fraction of samples hit by spikes of 20 to 50 noise SDs.
    #[arg(long = "effect", value_name = "EFFECT=VALUE", value_parser = simulate::parse_effect, verbatim_doc_comment)]
    effect: Vec<simulate::SimEffectArg>,
    /// covariate:temp: how far the temperature rises, in °C.
    #[arg(
        long,
        value_name = "DEGC",
        default_value_t = 10.0,
        allow_negative_numbers = true
    )]
    temp_rise: f64,
    #[command(flatten)]
    three: simulate::Sim3Args,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum SimFormat {
    /// CSV with columns t, x, y.
    Csv,
    /// A capture of Falcon-GX-style frames with their timing (replay it with `fieldcal replay`).
    Falcon,
    /// The same frames as a plain byte dump with no timing, as `cat /dev/ttyUSB0 > file` gives.
    FalconRaw,
}

/// The model of `fit --effects`: the 2-axis effects, or why the list is
/// none (it names a 3-D model, `full`), and the text for the 3-axis fit.
#[derive(Debug, Clone)]
struct EffectList {
    effects: Result<Vec<fieldcal::model::effects::Effect>, String>,
    text: String,
}

fn parse_effect_list(text: &str) -> Result<EffectList, String> {
    let effects = fieldcal::model::effects::parse_list(text);
    if let Err(e) = &effects
        && fit::parse_effects3(text).is_err()
    {
        return Err(e.clone());
    }
    Ok(EffectList {
        effects,
        text: text.to_string(),
    })
}

fn parse_speed(text: &str) -> Result<Speed, String> {
    text.parse()
}

/// `mpu6050` or `mpu6050@0x69` (or `@105`).
fn parse_chip(text: &str) -> Result<(Chip, u8), String> {
    let (name, address) = match text.split_once('@') {
        Some((name, address)) => (name, Some(address)),
        None => (text, None),
    };
    let chip = Chip::from_str(name, true).map_err(|_| {
        let names: Vec<&str> = Chip::value_variants().iter().map(|c| c.name()).collect();
        format!(
            "'{name}' is not a chip fieldcal knows; choose one of {}",
            names.join(", ")
        )
    })?;
    let address = match address {
        None => chip.default_address(),
        Some(a) => {
            let parsed = match a.strip_prefix("0x").or_else(|| a.strip_prefix("0X")) {
                Some(hex) => u8::from_str_radix(hex, 16),
                None => a.parse::<u8>(),
            };
            match parsed {
                Ok(v) if v <= 0x7F => v,
                _ => return Err(format!("'{a}' is not a 7-bit I2C address (0x00 to 0x7f)")),
            }
        }
    };
    Ok((chip, address))
}

fn parse_coverage(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    if (0.0..=360.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} is not between 0 and 360 degrees"))
    }
}

/// `--garbage`: a fraction from 0 to [`fieldcal::sim::MAX_GARBAGE`].
fn parse_garbage(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    let max = fieldcal::sim::MAX_GARBAGE;
    if (0.0..=max).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{text} is not a garbage fraction: give one from 0 to {max} (at {max}, nine bytes in ten are garbage)"
        ))
    }
}

/// Longest `record --duration`: a year. Longer is a typing mistake, and
/// 1e300 seconds overflowed the conversion to a `Duration`.
const MAX_DURATION_S: f64 = 365.0 * 86_400.0;

fn parse_duration(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    if v > 0.0 && v <= MAX_DURATION_S {
        Ok(v)
    } else {
        Err(format!(
            "{text} is not a duration: give a number of seconds above 0 and at most {MAX_DURATION_S} (a year)"
        ))
    }
}

fn parse_positive(text: &str) -> Result<f64, String> {
    let v: f64 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a number"))?;
    if v > 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{v} must be a positive number"))
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // The daemon chooses its log format in its configuration.
    if !matches!(cli.command, Command::Run(_)) {
        init_logging(false);
    }
    let result = match cli.command {
        Command::Run(args) => run::run(args),
        Command::Fit(args) => fit::fit(args),
        Command::Diagnose(args) => diagnose::diagnose(args),
        Command::Check(args) => check::check(args),
        Command::Heading(args) => heading::heading(args),
        Command::Simulate(args) => simulate::simulate(args),
        Command::Record(args) => record::record(args),
        Command::Replay(args) => replay::replay(args),
    };
    match result {
        Ok(()) => {
            for text in NOTES.lock().map(|n| n.clone()).unwrap_or_default() {
                eprintln!("{text}");
            }
            ExitCode::SUCCESS
        }
        Err(err) => {
            // Library errors often name their cause in their own text; a
            // cause already said is not said twice.
            let mut message = format!("fieldcal: error: {err}");
            for cause in err.chain().skip(1) {
                let cause = cause.to_string();
                if !message.contains(&cause) {
                    message.push_str(": ");
                    message.push_str(&cause);
                }
            }
            eprintln!("{message}");
            ExitCode::FAILURE
        }
    }
}

/// Logs go to stderr, filtered by RUST_LOG (default: info), as text or
/// as one JSON object per line.
fn init_logging(json: bool) {
    init_logging_to(json, None);
}

/// [`init_logging`], printing above the live progress lines when given.
fn init_logging_to(json: bool, live: Option<indicatif::MultiProgress>) {
    use tracing_subscriber::fmt::writer::BoxMakeWriter;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let writer = match live {
        Some(multi) => BoxMakeWriter::new(fieldcal::daemon::progress::LogWriter::new(multi)),
        None => BoxMakeWriter::new(std::io::stderr),
    };
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(writer)
        .with_target(false);
    let _ = if json {
        builder.json().try_init()
    } else {
        builder
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .try_init()
    };
}
