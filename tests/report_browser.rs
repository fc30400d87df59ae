//! The report as a person sees it: headless Chromium opens index.html with
//! no network, every figure must load and the page must render.
//!
//! CI machines do not ship Chromium; the CI script installs the Debian
//! package `chromium`. Without /usr/bin/chromium this test says so and
//! passes, so a developer's `cargo test` does not need a browser.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use fieldcal::report::plots::{INDEX_FILE, demo_data, write_report};

const CHROMIUM: &str = "/usr/bin/chromium";

/// Runs Chromium headless on `url` with `extra` flags, killing it after a
/// minute so a wedged browser fails the test instead of hanging CI.
fn chromium(profile: &Path, extra: &[String], url: &str) -> Output {
    let mut child = Command::new(CHROMIUM)
        .args(common::CHROMIUM_FLAGS)
        .arg("--virtual-time-budget=5000")
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(url)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start chromium");
    // Drain the pipes on threads so a chatty browser cannot block on a
    // full pipe while we wait.
    let mut stdout = child.stdout.take().expect("stdout");
    let mut stderr = child.stderr.take().expect("stderr");
    let out = std::thread::spawn(move || {
        let mut buf = Vec::new();
        std::io::Read::read_to_end(&mut stdout, &mut buf).ok();
        buf
    });
    let err = std::thread::spawn(move || {
        let mut buf = Vec::new();
        std::io::Read::read_to_end(&mut stderr, &mut buf).ok();
        buf
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for chromium") {
            break status;
        }
        if start.elapsed() > Duration::from_secs(90) {
            child.kill().ok();
            panic!("chromium did not finish within 90 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    Output {
        status,
        stdout: out.join().expect("stdout thread"),
        stderr: err.join().expect("stderr thread"),
    }
}

fn file_url(path: &Path) -> String {
    format!("file://{}", path.display())
}

#[test]
fn report_renders_in_headless_chromium() {
    if !Path::new(CHROMIUM).exists() {
        eprintln!(
            "skipping report_renders_in_headless_chromium: {CHROMIUM} not found \
             (install the Debian package `chromium` to run it)"
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let report = tmp.path().join("report");
    let written = write_report(&report, &demo_data(4000)).unwrap();
    let svgs: Vec<&PathBuf> = written
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "svg"))
        .collect();
    assert!(svgs.len() >= 5);
    let index = report.join(INDEX_FILE);

    // 1. A screenshot of the page, with the browser's log on stderr.
    let shot = tmp.path().join("shot.png");
    let output = chromium(
        &tmp.path().join("profile-shot"),
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1200,3000".into(),
            "--enable-logging=stderr".into(),
            "--v=0".into(),
        ],
        &file_url(&index),
    );
    let log = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "chromium failed: {log}");
    for bad in ["ERR_FILE_NOT_FOUND", "Failed to load", "net::ERR_"] {
        assert!(!log.contains(bad), "{bad} in the browser log:\n{log}");
    }
    let png = std::fs::read(&shot).expect("the screenshot was written");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    // A blank 1200x3000 page compresses to a few KB; plots with text and
    // thousands of points do not.
    assert!(png.len() > 40_000, "screenshot only {} bytes", png.len());
    // FIELDCAL_KEEP_REPORT=DIR keeps the report and the screenshot for a
    // person to look at.
    if let Some(keep) = std::env::var_os("FIELDCAL_KEEP_REPORT").map(PathBuf::from) {
        write_report(&keep, &demo_data(4000)).unwrap();
        std::fs::copy(&shot, keep.join("screenshot.png")).unwrap();
    }

    // 2. The page as the browser parsed it: every figure is there.
    let output = chromium(
        &tmp.path().join("profile-dom"),
        &["--dump-dom".into()],
        &file_url(&index),
    );
    assert!(output.status.success());
    let dom = String::from_utf8_lossy(&output.stdout);
    for svg in &svgs {
        let name = svg.file_name().unwrap().to_string_lossy();
        assert!(
            dom.contains(&format!("<img src=\"{name}\"")),
            "{name} missing from the page"
        );
    }

    // 3. Every figure decodes as an image: a probe page (outside the report,
    // the report itself has no scripts) loads each SVG and writes how many
    // loaded with a non-zero size into its own DOM.
    let probe = tmp.path().join("probe.html");
    let imgs: String = svgs
        .iter()
        .map(|p| format!("<img src=\"{}\">\n", file_url(p)))
        .collect();
    std::fs::write(
        &probe,
        format!(
            "<!DOCTYPE html><html><body>{imgs}<div id=\"result\">pending</div><script>\n\
             window.addEventListener('load', () => {{\n\
               const all = [...document.images];\n\
               const ok = all.filter(i => i.complete && i.naturalWidth > 0).length;\n\
               document.getElementById('result').textContent = `loaded ${{ok}} of ${{all.length}}`;\n\
             }});\n</script></body></html>"
        ),
    )
    .unwrap();
    let output = chromium(
        &tmp.path().join("profile-probe"),
        &["--dump-dom".into(), "--allow-file-access-from-files".into()],
        &file_url(&probe),
    );
    let dom = String::from_utf8_lossy(&output.stdout);
    let expected = format!("loaded {n} of {n}", n = svgs.len());
    assert!(dom.contains(&expected), "expected {expected:?} in:\n{dom}");
}

/// The report of a real recording, whose summary has lines of 200 to 700
/// characters and, here, a file name of 150 characters with no place to
/// break: at common widths nothing may run off the right edge of the page,
/// and nothing may be hidden inside the summary box either. A copy of the
/// page (the report itself has no scripts) measures its own layout.
#[test]
fn the_summary_box_fits_the_page_at_common_widths() {
    if !Path::new(CHROMIUM).exists() {
        eprintln!(
            "skipping the_summary_box_fits_the_page_at_common_widths: {CHROMIUM} not found \
             (install the Debian package `chromium` to run it)"
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let real = Path::new(env!("CARGO_MANIFEST_DIR")).join(
        "../shared/data/real/sunsided-set-1/rotate-360ccw-around-z-pointing-up/hmc5883l_mag.csv",
    );
    assert!(real.exists(), "{} is missing", real.display());
    // A link, not a copy: the real recording is read in place.
    let long_name = format!("{}.csv", "robot_compass_run_".repeat(8));
    let recording = tmp.path().join(&long_name);
    std::os::unix::fs::symlink(&real, &recording).unwrap();
    let report = tmp.path().join("report");
    let out = Command::new(env!("CARGO_BIN_EXE_fieldcal"))
        .arg("diagnose")
        .arg(&recording)
        .args(["--x", "mag_x", "--y", "mag_z", "--report"])
        .arg(&report)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary = String::from_utf8_lossy(&out.stdout);
    let longest = summary
        .lines()
        .map(|l| l.chars().count())
        .max()
        .unwrap_or(0);
    assert!(longest > 200, "the summary's longest line is {longest}");

    let page = std::fs::read_to_string(report.join(INDEX_FILE)).unwrap();
    let script = "<div id=\"layout-result\">pending</div><script>\n\
        window.addEventListener('load', () => {\n\
          const doc = document.documentElement;\n\
          const box = document.querySelector('.summary');\n\
          const pre = box.querySelector('pre');\n\
          const view = doc.clientWidth;\n\
          const over = [...document.body.querySelectorAll('*')]\n\
            .filter(e => e.id !== 'layout-result' && e.getBoundingClientRect().right > view + 0.5)\n\
            .map(e => e.tagName.toLowerCase() + (e.className ? '.' + e.className : ''));\n\
          const r = {view, page: doc.scrollWidth, box_right: box.getBoundingClientRect().right,\n\
            box_scroll: box.scrollWidth, box_client: box.clientWidth,\n\
            pre_scroll: pre.scrollWidth, pre_client: pre.clientWidth, over};\n\
          document.getElementById('layout-result').textContent = 'LAYOUT ' + JSON.stringify(r) + ' END';\n\
        });\n</script>\n</body>";
    let probe = report.join("layout-probe.html");
    std::fs::write(&probe, page.replace("</body>", script)).unwrap();

    for width in [1280, 800] {
        let output = chromium(
            &tmp.path().join(format!("profile-{width}")),
            &["--dump-dom".into(), format!("--window-size={width},2000")],
            &file_url(&probe),
        );
        assert!(output.status.success());
        let dom = String::from_utf8_lossy(&output.stdout);
        let json = dom
            .split_once("LAYOUT ")
            .and_then(|(_, rest)| rest.split_once(" END"))
            .map(|(json, _)| json.replace("&quot;", "\""))
            .unwrap_or_else(|| panic!("no layout result at {width} px in:\n{dom}"));
        let r: serde_json::Value = serde_json::from_str(&json).unwrap();
        let num = |key: &str| r[key].as_f64().unwrap_or_else(|| panic!("{key} in {r}"));
        assert_eq!(num("view"), f64::from(width), "{r}");
        assert!(
            num("page") <= num("view"),
            "the page scrolls sideways at {width} px: {r}"
        );
        assert!(
            num("box_right") <= num("view"),
            "the box runs off at {width} px: {r}"
        );
        assert!(
            num("box_scroll") <= num("box_client") && num("pre_scroll") <= num("pre_client"),
            "the summary is cut or scrolls inside its box at {width} px: {r}"
        );
        assert_eq!(r["over"], serde_json::json!([]), "at {width} px: {r}");
    }
}
