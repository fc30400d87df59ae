//! What a person sees while the sensor turns: `fieldcal run` with stderr
//! on a pseudo-terminal draws one live line per sensor; with stderr on a
//! pipe it logs the moments that matter instead. The shipped one-turn
//! capture is replayed four or five times faster than real time (a turn
//! of 2 to 2.5 s).

use std::io::Read;
use std::os::fd::{FromRawFd, OwnedFd};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A daemon configuration replaying `falcon_turn.fcap` (one turn in 10 s)
/// at `speed`, with its state in `dir`, publishing on stdout when `stdout`.
fn config(dir: &Path, speed: &str, stdout: bool) -> std::path::PathBuf {
    let capture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/falcon_turn.fcap");
    let text = format!(
        "[daemon]\nstate_dir = {state:?}\n\n[outputs]\nstdout = {stdout}\n\n\
         [[source]]\nname = \"imu\"\nkind = \"replay\"\nfile = {capture:?}\nspeed = {speed}\n\n\
         [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n",
        state = dir.join("state").display().to_string(),
        capture = capture.display().to_string(),
    );
    let path = dir.join("run.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Runs `fieldcal run` with stderr (and stdout when `stdout`) on a fresh
/// pseudo-terminal of `cols` columns; returns every byte written to it.
fn run_on_pty(config: &Path, extra: &[&str], cols: u16, stdout: bool) -> Vec<u8> {
    let (mut master, mut slave) = (0, 0);
    let size = libc::winsize {
        ws_row: 40,
        ws_col: cols,
        ws_xpixel: 0,
        ws_ypixel: 0,
    };
    // SAFETY: openpty writes two descriptors into the given integers; the
    // name buffer is null (not wanted) and the termios is null (defaults).
    let rc = unsafe {
        libc::openpty(
            &mut master,
            &mut slave,
            std::ptr::null_mut(),
            std::ptr::null(),
            &size,
        )
    };
    assert_eq!(rc, 0, "openpty failed: {}", std::io::Error::last_os_error());
    // SAFETY: both descriptors were just opened by openpty and are owned here.
    let (master, slave) = unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
    let mut child = Command::new(env!("CARGO_BIN_EXE_fieldcal"))
        .args(["run", "--config"])
        .arg(config)
        .args(extra)
        .env("TERM", "xterm-256color")
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .stdout(if stdout {
            Stdio::from(slave.try_clone().unwrap())
        } else {
            Stdio::null()
        })
        .stderr(Stdio::from(slave))
        .spawn()
        .unwrap();
    // The child holds the only slave descriptor now: reading the master
    // ends (EIO) once it exits. Read while it runs, so it never blocks on
    // a full terminal.
    let reader = std::thread::spawn(move || {
        let mut master = std::fs::File::from(master);
        let mut out = Vec::new();
        let mut buf = [0u8; 4096];
        loop {
            match master.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => out.extend_from_slice(&buf[..n]),
            }
        }
        out
    });
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("fieldcal run did not end within 60 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = reader.join().unwrap();
    assert!(
        status.success(),
        "{status}: {}",
        String::from_utf8_lossy(&out)
    );
    out
}

/// A small terminal: applies the bytes to a screen and keeps every state a
/// row showed before it was cleared, in order.
struct Screen {
    rows: Vec<Vec<char>>,
    row: usize,
    col: usize,
    /// Each row's content whenever it was about to be cleared, then the
    /// final screen's rows.
    history: Vec<String>,
}

impl Screen {
    fn play(bytes: &[u8]) -> Screen {
        let text = String::from_utf8_lossy(bytes);
        let mut s = Screen {
            rows: vec![Vec::new()],
            row: 0,
            col: 0,
            history: Vec::new(),
        };
        let mut chars = text.chars().peekable();
        while let Some(c) = chars.next() {
            match c {
                '\x1b' => {
                    if chars.peek() != Some(&'[') {
                        continue;
                    }
                    chars.next();
                    let mut params = String::new();
                    let mut end = ' ';
                    for p in chars.by_ref() {
                        if p.is_ascii_alphabetic() {
                            end = p;
                            break;
                        }
                        params.push(p);
                    }
                    let n: usize = params.parse().unwrap_or(1);
                    match (end, params.as_str()) {
                        ('A', _) => s.row = s.row.saturating_sub(n),
                        ('B', _) => s.down(n),
                        ('C', _) => s.col += n,
                        ('D', _) => s.col = s.col.saturating_sub(n),
                        ('K', "2") => s.clear(0),
                        ('K', _) => s.clear(s.col),
                        ('J', _) => {
                            s.clear(s.col);
                            for r in s.row + 1..s.rows.len() {
                                let old: String =
                                    std::mem::take(&mut s.rows[r]).into_iter().collect();
                                s.keep(old);
                            }
                        }
                        _ => {} // colours, cursor show/hide
                    }
                }
                '\r' => s.col = 0,
                '\n' => s.down(1),
                c => {
                    let row = &mut s.rows[s.row];
                    while row.len() < s.col {
                        row.push(' ');
                    }
                    if s.col < row.len() {
                        row[s.col] = c;
                    } else {
                        row.push(c);
                    }
                    s.col += 1;
                }
            }
        }
        let rows: Vec<String> = s.rows.iter().map(|r| r.iter().collect()).collect();
        for row in rows {
            s.keep(row);
        }
        s
    }

    fn keep(&mut self, row: String) {
        if !row.trim().is_empty() {
            self.history.push(row.trim_end().to_string());
        }
    }

    fn down(&mut self, n: usize) {
        self.row += n;
        while self.rows.len() <= self.row {
            self.rows.push(Vec::new());
        }
    }

    /// Clears the row from column `from` (0: all of it).
    fn clear(&mut self, from: usize) {
        let row = &mut self.rows[self.row];
        if from < row.len() {
            let old: String = row.iter().collect();
            row.truncate(from);
            self.keep(old);
        }
    }

    /// The final screen's non-empty rows.
    fn visible(&self) -> Vec<String> {
        self.rows
            .iter()
            .map(|r| r.iter().collect::<String>().trim_end().to_string())
            .filter(|r| !r.is_empty())
            .collect()
    }
}

/// The coverage a progress line shows, e.g. 62 from "compass  [...]  62 %".
fn coverage(line: &str) -> Option<u32> {
    let after = line.strip_prefix("compass  [")?;
    let (_, rest) = after.split_once(']')?;
    rest.trim_start().split_once(" %")?.0.trim().parse().ok()
}

#[test]
fn a_person_at_the_terminal_watches_the_turn_fill_and_the_calibration_arrive() {
    let dir = tempfile::tempdir().unwrap();
    // The daemon publishes its JSON lines on the same terminal, as the
    // shipped demo does.
    let config = config(dir.path(), "4.0", true);
    let bytes = run_on_pty(&config, &[], 160, true);
    let screen = Screen::play(&bytes);
    let lines: Vec<&str> = screen
        .history
        .iter()
        .map(String::as_str)
        .filter(|l| l.starts_with("compass  ["))
        .collect();
    assert!(
        !lines.is_empty(),
        "no progress line among {:#?}",
        screen.history
    );
    // The coverage rises to 100 %, through several states a person can
    // see (the redraw runs ten times a second; the turn takes 2.5 s).
    let shown: Vec<u32> = lines.iter().filter_map(|l| coverage(l)).collect();
    let distinct: std::collections::BTreeSet<u32> = shown.iter().copied().collect();
    assert!(distinct.len() >= 4, "{distinct:?} from {lines:#?}");
    assert!(shown.first().is_some_and(|&c| c < 50), "{shown:?}");
    assert!(distinct.iter().any(|&c| c > 0 && c < 100), "{distinct:?}");
    assert_eq!(shown.last(), Some(&100), "{lines:#?}");
    // While it turns: the missing headings and "turn further".
    assert!(
        lines
            .iter()
            .any(|l| l.contains(" %  missing ") && l.ends_with("°  turn further")),
        "{lines:#?}"
    );
    // At the end, on the screen: the calibration, with its rms and the
    // heading check against the capture's gyro.
    let visible = screen.visible();
    let last = visible
        .iter()
        .rev()
        .find(|l| l.starts_with("compass  ["))
        .unwrap();
    assert!(
        last.starts_with("compass  [##########] 100 %  calibrated #1, rms 0."),
        "{visible:#?}"
    );
    let heading = last.split_once(" %, heading check ").unwrap().1;
    let deg: f64 = heading.strip_suffix('°').unwrap().parse().unwrap();
    assert!((0.0..1.0).contains(&deg), "{last}");
    // Log lines printed above the live line, never into it.
    assert!(
        visible
            .iter()
            .any(|l| l.contains("INFO") && l.contains("calibration accepted")),
        "{visible:#?}"
    );
    assert!(
        screen
            .history
            .iter()
            .all(|l| !(l.contains("INFO") && l.contains("compass  ["))),
        "{:#?}",
        screen.history
    );
}

#[test]
fn without_a_terminal_the_log_has_the_milestones_and_no_live_lines() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "5.0", false);
    let out = Command::new(env!("CARGO_BIN_EXE_fieldcal"))
        .args(["run", "--config"])
        .arg(&config)
        .env_remove("RUST_LOG")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(out.status.success());
    let log = String::from_utf8(out.stderr).unwrap();
    assert!(!log.contains('\x1b') && !log.contains("[#"), "{log}");
    assert!(!log.contains('\r'), "{log}");
    let info: Vec<&str> = log
        .lines()
        .filter(|l| l.contains(" INFO compass: "))
        .map(|l| l.split_once(" INFO ").unwrap().1)
        .collect();
    assert_eq!(
        info.first(),
        Some(&"compass: rotation started; turn the sensor a full rotation"),
        "{log}"
    );
    // One line per quarter of coverage, in order, and never one per reading.
    let quarters: Vec<u32> = info
        .iter()
        .filter_map(|l| l.strip_prefix("compass: "))
        .filter_map(|l| l.split_once(" % of headings covered"))
        .map(|(pct, _)| pct.parse().unwrap())
        .collect();
    assert_eq!(quarters.len(), 3, "{log}");
    for (i, pct) in quarters.iter().enumerate() {
        let floor = 25 * (i as u32 + 1);
        assert!((floor..floor + 25).contains(pct), "{quarters:?}");
    }
    assert!(info.len() <= 8, "{log}");
    let complete = info
        .iter()
        .position(|l| l.starts_with("compass: rotation complete, "))
        .expect(&log);
    assert!(
        info[complete + 1].starts_with("compass: calibrated #1, rms 0.")
            && info[complete + 1].contains(" %, heading check "),
        "{log}"
    );
}

#[test]
fn progress_never_on_a_terminal_logs_instead() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "\"max\"", false);
    let bytes = run_on_pty(&config, &["--progress", "never"], 160, false);
    let screen = Screen::play(&bytes);
    assert!(
        screen.history.iter().all(|l| !l.starts_with("compass  [")),
        "{:#?}",
        screen.history
    );
    assert!(
        screen
            .history
            .iter()
            .any(|l| l.contains("compass: calibrated #1, rms 0.")),
        "{:#?}",
        screen.history
    );
}

#[test]
fn progress_always_draws_even_into_a_pipe() {
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path(), "\"max\"", false);
    let out = Command::new(env!("CARGO_BIN_EXE_fieldcal"))
        .args(["run", "--config"])
        .arg(&config)
        .args(["--progress", "always"])
        .env_remove("RUST_LOG")
        .env("COLUMNS", "160")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(out.status.success());
    let screen = Screen::play(&out.stderr);
    let visible = screen.visible();
    assert_eq!(
        visible
            .iter()
            .filter(|l| l.starts_with("compass  ["))
            .count(),
        1,
        "{visible:#?}"
    );
    assert!(
        visible
            .iter()
            .any(|l| l.starts_with("compass  [##########] 100 %  calibrated #1, rms 0.")),
        "{visible:#?}"
    );
    // The milestones are not logged when the lines are drawn.
    assert!(
        !screen.history.iter().any(|l| l.contains("INFO compass: ")),
        "{:#?}",
        screen.history
    );
}
