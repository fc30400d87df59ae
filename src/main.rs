//! The `fieldcal` command: parses arguments and wires the library together.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};

use fieldcal::io::csv::{ColumnSpec, read_dataset, write_calibrated, write_calibrated_to};
use fieldcal::model::fit::{DEFAULT_MIN_COVERAGE_DEG, FitOptions, Solver, fit_paper};
use fieldcal::model::paper::{
    GradientDescentOptions, GradientDescentProgress, PAPER_LEARNING_RATE,
};
use fieldcal::report::fit::{FitJson, FitSource, render_text};
use fieldcal::sim::SimSensor;

#[derive(Debug, Parser)]
#[command(
    name = "fieldcal",
    version,
    about = "Calibrates 2-axis field sensors (magnetometers, accelerometers) turned in a constant field",
    long_about = None
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Fit the paper's calibration to a CSV recording of one full turn.
    Fit(FitArgs),
    /// Write a CSV of a simulated sensor turned in a constant field.
    Simulate(SimulateArgs),
}

#[derive(Debug, Args)]
struct FitArgs {
    /// CSV file: a header line, then one sample per line.
    file: PathBuf,
    /// Column holding the x axis.
    #[arg(long, default_value = "x", value_name = "COL")]
    x: String,
    /// Column holding the y axis.
    #[arg(long, default_value = "y", value_name = "COL")]
    y: String,
    /// Column holding time in seconds [default: the first of t, t_s, time, time_s]
    #[arg(long, value_name = "COL")]
    t: Option<String>,
    /// Solver: closed-form least squares, or the paper's gradient descent.
    #[arg(long, value_enum, default_value_t = Solver::Lsq)]
    solver: Solver,
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
struct SimulateArgs {
    /// Write the CSV here instead of stdout.
    #[arg(long, short, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Print the simulated sensor and its true calibration as JSON on stdout (needs --output).
    #[arg(long)]
    json: bool,
    /// Field magnitude, in counts at unit gain.
    #[arg(long, default_value_t = 1000.0)]
    field: f64,
    /// Gain of the x axis.
    #[arg(long, default_value_t = 1.0)]
    gain_x: f64,
    /// Gain of the y axis.
    #[arg(long, default_value_t = 1.0)]
    gain_y: f64,
    /// Offset of the x axis, in counts.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    offset_x: f64,
    /// Offset of the y axis, in counts.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    offset_y: f64,
    /// Standard deviation of Gaussian noise on each axis, in counts.
    #[arg(long, default_value_t = 0.0)]
    noise: f64,
    /// Sample period in seconds (0.05 for the Falcon-GX, 0.03 for I2C polling).
    #[arg(long, default_value_t = 0.05)]
    period: f64,
    /// Number of rotations.
    #[arg(long, default_value_t = 1.0)]
    turns: f64,
    /// Seconds one rotation takes.
    #[arg(long, default_value_t = 10.0)]
    turn_seconds: f64,
    /// Heading of the first sample, in degrees.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    start_heading: f64,
    /// Seed of the noise generator.
    #[arg(long, default_value_t = 1)]
    seed: u64,
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
    let result = match cli.command {
        Command::Fit(args) => fit(args),
        Command::Simulate(args) => simulate(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            let mut message = format!("fieldcal: error: {err}");
            for cause in err.chain().skip(1) {
                message.push_str(&format!(": {cause}"));
            }
            eprintln!("{message}");
            ExitCode::FAILURE
        }
    }
}

fn fit(args: FitArgs) -> Result<()> {
    let spec = ColumnSpec {
        x: args.x,
        y: args.y,
        t: args.t,
    };
    let data = read_dataset(&args.file, &spec)?;
    let options = FitOptions {
        solver: args.solver,
        gradient_descent: GradientDescentOptions {
            learning_rate: args.learning_rate,
            max_iterations: args.max_iterations,
            ..Default::default()
        },
        min_coverage_deg: args.min_coverage,
    };
    let file = args.file.display().to_string();
    let mut progress = progress_printer();
    let report = fit_paper(&data.x, &data.y, &options, &mut progress);
    finish_progress();
    let report = report.with_context(|| format!("{file}: no calibration"))?;

    if let Some(output) = &args.output {
        let (cx, cy): (Vec<f64>, Vec<f64>) = data
            .x
            .iter()
            .zip(&data.y)
            .map(|(&x, &y)| report.calibration.apply(x, y))
            .unzip();
        write_calibrated(output, data.t.as_deref(), &cx, &cy).with_context(|| {
            format!(
                "cannot write the calibrated samples to {}",
                output.display()
            )
        })?;
    }

    let source = FitSource {
        file: &file,
        x_column: &data.x_name,
        y_column: &data.y_name,
    };
    let text = if args.json {
        serde_json::to_string(&FitJson::new(&report, source))? + "\n"
    } else {
        render_text(&report, source)
    };
    write_stdout(text.as_bytes())
}

/// Reports gradient-descent progress on a terminal; silent otherwise.
fn progress_printer() -> impl FnMut(GradientDescentProgress) {
    let terminal = std::io::stderr().is_terminal();
    move |p: GradientDescentProgress| {
        if terminal {
            eprint!(
                "\rgradient descent: iteration {:>9}, step {:.2e}   ",
                p.iteration, p.step
            );
        }
    }
}

fn finish_progress() {
    if std::io::stderr().is_terminal() {
        eprint!("\r{:60}\r", "");
    }
}

fn simulate(args: SimulateArgs) -> Result<()> {
    let sensor = SimSensor {
        field: args.field,
        gain_x: args.gain_x,
        gain_y: args.gain_y,
        offset_x: args.offset_x,
        offset_y: args.offset_y,
        noise: args.noise,
        period: args.period,
        turns: args.turns,
        turn_seconds: args.turn_seconds,
        start_heading_deg: args.start_heading,
        seed: args.seed,
    };
    if args.json && args.output.is_none() {
        bail!("--json prints the true calibration on stdout, so the CSV needs --output FILE");
    }
    let data = sensor.simulate()?;
    match &args.output {
        Some(path) => write_calibrated(path, data.t.as_deref(), &data.x, &data.y)
            .with_context(|| format!("cannot write {}", path.display()))?,
        None => {
            let mut buffer = Vec::with_capacity(data.len() * 40);
            write_calibrated_to(&mut buffer, data.t.as_deref(), &data.x, &data.y)?;
            write_stdout(&buffer)?;
        }
    }
    let truth = sensor.truth();
    if args.json {
        let json = serde_json::json!({
            "file": args.output.as_deref().map(Path::display).map(|d| d.to_string()),
            "n": data.len(),
            "sensor": sensor,
            "truth": truth,
        });
        write_stdout(format!("{json}\n").as_bytes())?;
    } else if let Some(path) = &args.output {
        eprintln!(
            "wrote {} samples to {}; true calibration: a = {}, b = {}, d = {}, r = {}",
            data.len(),
            path.display(),
            truth.a,
            truth.b,
            truth.d,
            truth.r
        );
    }
    Ok(())
}

/// Writes to stdout; a closed pipe (`| head`) ends quietly, not with a panic.
fn write_stdout(bytes: &[u8]) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(bytes).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other.context("cannot write to stdout")?),
    }
}
