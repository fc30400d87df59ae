//! The user's commands end to end, each beside its floor in the same run.
//!
//! Every command is the release binary run as a user runs it, on files
//! written here (`fieldcal simulate`), timed as a whole process (start,
//! reading, work, output) and its peak resident memory taken from the
//! kernel (`wait4`'s `ru_maxrss`). The floor of each is the least any
//! program must do for the same answer, in Rust, in this process: the
//! `csv` crate's `ByteRecord`, `str::parse`, one pass that accumulates the
//! normal equations, and `ryu` for output; for replay, the Falcon-GX
//! decoder and the line replay writes for each calibrated reading,
//! formatted into a reused buffer. Peers (Python with polars, pandas and
//! numpy) run when they are installed, interpreter start included.
//!
//! Run: `cargo bench --bench commands` (sizes: `FIELDCAL_BENCH_ROWS`,
//! default `200000,2000000`; runs of each: `FIELDCAL_BENCH_RUNS`, default
//! 5, the best kept; which paths: `FIELDCAL_BENCH_PATHS`, e.g.
//! `replay,fit 2-D`, default all).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use nalgebra::{DMatrix, DVector};

const BIN: &str = env!("CARGO_BIN_EXE_fieldcal");

/// Wall time and peak resident memory of one process.
#[derive(Clone, Copy)]
struct Measured {
    seconds: f64,
    max_rss_mb: f64,
}

/// Runs `program args` to completion with stdout and stderr discarded.
fn run_once(program: &str, args: &[&str]) -> Option<Measured> {
    let started = Instant::now();
    let child = Command::new(program)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .ok()?;
    let pid = libc::pid_t::try_from(child.id()).ok()?;
    let mut status = 0;
    // SAFETY: rusage is plain data, filled by the kernel.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: waits for our own child, whose pid we hold.
    let reaped = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let seconds = started.elapsed().as_secs_f64();
    if reaped != pid || !libc::WIFEXITED(status) || libc::WEXITSTATUS(status) != 0 {
        eprintln!("commands: {program} {args:?} failed ({status})");
        return None;
    }
    Some(Measured {
        seconds,
        max_rss_mb: usage.ru_maxrss as f64 / 1024.0,
    })
}

/// The best of `runs` runs (least time; the memory of that run).
fn best(runs: usize, program: &str, args: &[&str]) -> Option<Measured> {
    (0..runs)
        .filter_map(|_| run_once(program, args))
        .min_by(|a, b| a.seconds.total_cmp(&b.seconds))
}

/// The least time of `runs` calls of `work`.
fn best_in_process(runs: usize, mut work: impl FnMut()) -> f64 {
    (0..runs)
        .map(|_| {
            let started = Instant::now();
            work();
            started.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Columns `names` of a CSV, parsed, in one pass: the floor's reading.
fn for_each_row(path: &Path, names: &[&str], mut each: impl FnMut(&[f64])) {
    let file = std::fs::File::open(path).expect("bench file");
    let mut csv =
        csv::ReaderBuilder::new().from_reader(std::io::BufReader::with_capacity(1 << 16, file));
    let header = csv.byte_headers().expect("header").clone();
    let index: Vec<usize> = names
        .iter()
        .map(|n| {
            header
                .iter()
                .position(|h| h == n.as_bytes())
                .expect("column")
        })
        .collect();
    let mut record = csv::ByteRecord::new();
    let mut values = vec![0.0; names.len()];
    while csv.read_byte_record(&mut record).expect("record") {
        for (v, &i) in values.iter_mut().zip(&index) {
            *v = std::str::from_utf8(&record[i])
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(f64::NAN);
        }
        each(&values);
    }
}

/// Solves the normal equations `ata · p = atb` and prints `p` with ryu.
fn solve_and_print(ata: DMatrix<f64>, atb: DVector<f64>, out: &mut Vec<u8>) {
    let p = ata
        .lu()
        .solve(&atb)
        .unwrap_or_else(|| DVector::zeros(atb.len()));
    let mut buffer = ryu::Buffer::new();
    for v in p.iter() {
        out.extend_from_slice(buffer.format(*v).as_bytes());
        out.push(b' ');
    }
}

/// The floor of `fit` in 2-D: the paper's closed form (eq. 6,
/// `y² = θ1 x² + θ2 x + θ3 y + θ4`) by its normal equations.
fn floor_fit2(path: &Path) {
    floor_normal_equations(path, &["x", "y"], |v| {
        let (x, y) = (v[0], v[1]);
        ([x * x, x, y, 1.0], y * y)
    });
}

/// The floor of `fit` in 3-D: the algebraic ellipsoid (nine terms and the
/// constant) by its normal equations.
fn floor_fit3(path: &Path) {
    floor_normal_equations(path, &["x", "y", "z"], |v| {
        let (x, y, z) = (v[0], v[1], v[2]);
        ([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z], 1.0)
    });
}

/// Least squares of the rows' targets on their design rows (`term` gives
/// both from a row's `columns`), by the normal equations in one pass.
fn floor_normal_equations<const K: usize>(
    path: &Path,
    columns: &[&str],
    term: impl Fn(&[f64]) -> ([f64; K], f64),
) {
    let mut ata = DMatrix::<f64>::zeros(K, K);
    let mut atb = DVector::<f64>::zeros(K);
    for_each_row(path, columns, |v| {
        let (row, target) = term(v);
        for i in 0..K {
            atb[i] += row[i] * target;
            for j in 0..K {
                ata[(i, j)] += row[i] * row[j];
            }
        }
    });
    let mut out = Vec::new();
    solve_and_print(ata, atb, &mut out);
    std::hint::black_box(out);
}

/// The floor of `heading`: each row's tilt-compensated heading from the
/// magnetometer and the accelerometer, and their median.
fn floor_heading(path: &Path) {
    let mut headings = Vec::new();
    for_each_row(path, &["x", "y", "z", "ax", "ay", "az"], |v| {
        let (roll, pitch) = (v[4].atan2(v[5]), (-v[3]).atan2(v[4].hypot(v[5])));
        let (sr, cr, sp, cp) = (roll.sin(), roll.cos(), pitch.sin(), pitch.cos());
        let bx = v[0] * cp + v[1] * sr * sp + v[2] * cr * sp;
        let by = v[1] * cr - v[2] * sr;
        headings.push((-by).atan2(bx).to_degrees());
    });
    let middle = headings.len() / 2;
    if !headings.is_empty() {
        headings.select_nth_unstable_by(middle, f64::total_cmp);
    }
    let mut buffer = ryu::Buffer::new();
    std::hint::black_box(
        buffer
            .format(headings.get(middle).copied().unwrap_or(0.0))
            .len(),
    );
}

/// The floor of `replay`: the capture read, its frames decoded, and for
/// each the line `replay --config` writes for a calibrated reading (the
/// raw axes, the corrected ones, the heading, the calibration's id and the
/// flags), formatted into a reused buffer with serde_json's own formatters.
/// `raw_only`: the floor before 2026-11-29, as it was (the time and the
/// three raw axes, with ryu and itoa), kept for comparison.
fn floor_replay(path: &Path, raw_only: bool) -> u64 {
    use fieldcal::capture::{Playable, open_capture};
    use fieldcal::protocol::falcon::FalconDecoder;
    let Ok(Playable::Stream(mut stream)) = open_capture(path) else {
        return 0;
    };
    let mut decoder = FalconDecoder::new();
    let mut line = Vec::with_capacity(256);
    let mut sink = std::io::sink();
    let (mut floats, mut ints) = (zmij::Buffer::new(), itoa::Buffer::new());
    let mut ryu = ryu::Buffer::new();
    let (a, b, d) = (1.000_018, 0.010_25, -0.002_07);
    let mut readings = 0;
    while let Some(chunk) = stream.next_chunk() {
        let time = chunk.time;
        decoder.decode(chunk.bytes, |frame| {
            line.clear();
            if raw_only {
                line.extend_from_slice(b"{\"class\":\"READING\",\"time\":");
                line.extend_from_slice(ryu.format(time).as_bytes());
                line.extend_from_slice(b",\"raw\":[");
                for (k, v) in frame.mag.iter().enumerate() {
                    if k > 0 {
                        line.push(b',');
                    }
                    line.extend_from_slice(ints.format(*v).as_bytes());
                }
                line.extend_from_slice(b"]}\n");
            } else {
                let [x, y] = [f64::from(frame.mag[0]), f64::from(frame.mag[1])];
                let (cx, cy) = (a * x + b, y + d);
                let heading = cy.atan2(cx).to_degrees().rem_euclid(360.0);
                let texts: [(&[u8], f64); 6] = [
                    (
                        b"{\"class\":\"READING\",\"sensor\":\"compass\",\"time\":",
                        time,
                    ),
                    (b",\"raw\":[", x),
                    (b",", y),
                    (b"],\"corrected\":[", cx),
                    (b",", cy),
                    (b"],\"heading_deg\":", heading),
                ];
                for (text, value) in texts {
                    line.extend_from_slice(text);
                    line.extend_from_slice(floats.format(value).as_bytes());
                }
                line.extend_from_slice(b",\"calibration\":");
                line.extend_from_slice(ints.format(1u64).as_bytes());
                line.extend_from_slice(b",\"calibrated\":true,\"trusted\":true}\n");
            }
            let _ = sink.write_all(&line);
            readings += 1;
        });
    }
    readings
}

/// A Python peer's script, run when its modules import.
fn peer(script: &str, file: &Path, runs: usize) -> Option<f64> {
    let path = file.display().to_string();
    let check = Command::new("python3")
        .args(["-c", "import polars, pandas, numpy"])
        .stderr(Stdio::null())
        .status()
        .ok()?;
    if !check.success() {
        return None;
    }
    best(runs, "python3", &["-c", script, &path]).map(|m| m.seconds)
}

const POLARS_FIT2: &str = "import sys, numpy as np, polars as pl
d = pl.read_csv(sys.argv[1], columns=['x', 'y'])
x, y = d['x'].to_numpy(), d['y'].to_numpy()
A = np.column_stack([x * x, x, y, np.ones_like(x)])
print(np.linalg.lstsq(A, y * y, rcond=None)[0])";

const PANDAS_FIT2: &str = "import sys, numpy as np, pandas as pd
d = pd.read_csv(sys.argv[1], usecols=['x', 'y'])
x, y = d['x'].to_numpy(), d['y'].to_numpy()
A = np.column_stack([x * x, x, y, np.ones_like(x)])
print(np.linalg.lstsq(A, y * y, rcond=None)[0])";

const POLARS_FIT3: &str = "import sys, numpy as np, polars as pl
d = pl.read_csv(sys.argv[1], columns=['x', 'y', 'z'])
x, y, z = d['x'].to_numpy(), d['y'].to_numpy(), d['z'].to_numpy()
A = np.column_stack([x*x, y*y, z*z, x*y, x*z, y*z, x, y, z])
print(np.linalg.lstsq(A, np.ones_like(x), rcond=None)[0])";

const PANDAS_FIT3: &str = "import sys, numpy as np, pandas as pd
d = pd.read_csv(sys.argv[1], usecols=['x', 'y', 'z'])
x, y, z = d['x'].to_numpy(), d['y'].to_numpy(), d['z'].to_numpy()
A = np.column_stack([x*x, y*y, z*z, x*y, x*z, y*z, x, y, z])
print(np.linalg.lstsq(A, np.ones_like(x), rcond=None)[0])";

const POLARS_HEADING: &str = "import sys, numpy as np, polars as pl
d = pl.read_csv(sys.argv[1], columns=['x', 'y', 'z', 'ax', 'ay', 'az'])
x, y, z, ax, ay, az = (d[c].to_numpy() for c in ['x', 'y', 'z', 'ax', 'ay', 'az'])
roll = np.arctan2(ay, az); pitch = np.arctan2(-ax, np.hypot(ay, az))
bx = x*np.cos(pitch) + y*np.sin(roll)*np.sin(pitch) + z*np.cos(roll)*np.sin(pitch)
by = y*np.cos(roll) - z*np.sin(roll)
print(np.median(np.degrees(np.arctan2(-by, bx))))";

/// One line of the table.
struct Line {
    path: String,
    rows: String,
    ours: Measured,
    floor: f64,
    peers: Vec<(&'static str, Option<f64>)>,
    command: String,
}

fn simulate(dir: &Path, name: &str, args: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let path = out.display().to_string();
    let mut all = vec!["simulate", "--seed", "1", "--noise", "2", "-o", &path];
    all.extend_from_slice(args);
    let done = Command::new(BIN)
        .args(&all)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .expect("fieldcal simulate");
    assert!(done.success(), "fieldcal {all:?}");
    out
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        println!("commands: run with `cargo bench --bench commands`");
        return;
    }
    let rows: Vec<usize> = std::env::var("FIELDCAL_BENCH_ROWS")
        .unwrap_or_else(|_| "200000,2000000".into())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let runs: usize = std::env::var("FIELDCAL_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5)
        .max(1);
    // Which paths to measure (`FIELDCAL_BENCH_PATHS`, names begun as in the
    // table, comma-separated, e.g. `replay,fit 2-D`); default all.
    let only: Vec<String> = std::env::var("FIELDCAL_BENCH_PATHS")
        .map(|s| {
            s.split(',')
                .map(|p| p.trim().to_owned())
                .filter(|p| !p.is_empty())
                .collect()
        })
        .unwrap_or_default();
    let wanted = |path: &str| only.is_empty() || only.iter().any(|p| path.starts_with(p.as_str()));
    let dir = tempfile::tempdir().expect("tempdir");
    let mut lines = Vec::new();
    let mut raw_floor = None;
    for &n in &rows {
        if !["fit 2-D", "fit 3-D", "diagnose 2-D", "heading --json"]
            .iter()
            .any(|p| wanted(p))
        {
            continue;
        }
        // 200 samples a turn.
        let turns = (n / 200).max(1).to_string();
        let two = simulate(
            dir.path(),
            &format!("plane{n}.csv"),
            &[
                "--turns",
                &turns,
                "--gain-x",
                "1.2",
                "--offset-x",
                "30",
                "--offset-y",
                "-20",
            ],
        );
        let three = simulate(
            dir.path(),
            &format!("tumble{n}.csv"),
            &[
                "--axes",
                "3",
                "--motion",
                "tumble",
                "--turns",
                &turns,
                "--offset-x",
                "30",
            ],
        );
        let (two_s, three_s) = (two.display().to_string(), three.display().to_string());
        for (path, file, args, floor, peers) in [
            (
                "fit 2-D",
                &two,
                vec!["fit", two_s.as_str(), "--json"],
                floor_fit2 as fn(&Path),
                vec![("polars", POLARS_FIT2), ("pandas", PANDAS_FIT2)],
            ),
            (
                "fit 3-D",
                &three,
                vec!["fit", three_s.as_str(), "--json"],
                floor_fit3,
                vec![("polars", POLARS_FIT3), ("pandas", PANDAS_FIT3)],
            ),
            (
                "diagnose 2-D",
                &two,
                vec!["diagnose", two_s.as_str(), "--json"],
                floor_fit2,
                vec![],
            ),
            (
                "heading --json",
                &three,
                vec!["heading", three_s.as_str(), "--accel", "ax,ay,az", "--json"],
                floor_heading,
                vec![("polars+numpy", POLARS_HEADING)],
            ),
        ] {
            if !wanted(path) {
                continue;
            }
            let Some(ours) = best(runs, BIN, &args) else {
                continue;
            };
            let floor = best_in_process(runs, || floor(file));
            let peers = peers
                .into_iter()
                .map(|(name, script)| (name, peer(script, file, runs)))
                .collect();
            lines.push(Line {
                path: path.into(),
                rows: n.to_string(),
                ours,
                floor,
                peers,
                command: format!("fieldcal {}", args.join(" ")),
            });
        }
    }
    // Replay: a capture of as many frames as the largest size, five times.
    if let Some(&n) = rows.iter().max().filter(|_| wanted("replay --config")) {
        let frames = 5 * n;
        let turns = (frames / 200).max(1).to_string();
        let capture = simulate(
            dir.path(),
            "long.fcap",
            &["--format", "falcon", "--turns", &turns],
        );
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/demo.toml");
        let (c, f) = (config.display().to_string(), capture.display().to_string());
        let args = [
            "replay",
            "--config",
            c.as_str(),
            "--speed",
            "max",
            f.as_str(),
        ];
        if let Some(ours) = best(runs.min(3), BIN, &args) {
            let floor = best_in_process(runs.min(3), || {
                std::hint::black_box(floor_replay(&capture, false));
            });
            let raw_only = best_in_process(runs.min(3), || {
                std::hint::black_box(floor_replay(&capture, true));
            });
            raw_floor = Some((frames, raw_only));
            lines.push(Line {
                path: "replay --config".into(),
                rows: format!("{frames} frames"),
                ours,
                floor,
                peers: vec![],
                command: format!("fieldcal {}", args.join(" ")),
            });
        }
    }
    println!(
        "| path | rows | fieldcal | floor | fieldcal / floor | peers | peak memory | command |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for line in &lines {
        let peers: Vec<String> = line
            .peers
            .iter()
            .map(|(name, s)| match s {
                Some(s) => format!("{name} {s:.3} s"),
                None => format!("{name}: not installed"),
            })
            .collect();
        println!(
            "| {} | {} | {:.3} s | {:.3} s | {:.2}× | {} | {:.1} MB | `{}` |",
            line.path,
            line.rows,
            line.ours.seconds,
            line.floor,
            line.ours.seconds / line.floor,
            if peers.is_empty() {
                "–".into()
            } else {
                peers.join(", ")
            },
            line.ours.max_rss_mb,
            line.command
                .replace(&dir.path().display().to_string(), "DIR"),
        );
    }
    if let Some((frames, seconds)) = raw_floor {
        println!(
            "\nreplay's floor with lines of the time and raw axes alone (the floor before 2026-11-29), {frames} frames: {seconds:.3} s"
        );
    }
}
