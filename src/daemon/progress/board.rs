//! The board of the progress display, pure: sensor snapshots and typed
//! `CALIBRATION` events in, the text of each sensor's line and the
//! milestone messages to log out. No I/O, no clock, no terminal: the
//! [`super`] module draws it and logs its milestones.
//!
//! The rejection reasons come from the rotation buffer
//! ([`crate::daemon::rotation`]), the turn gate and the fit
//! ([`crate::model`]) and the acceptance limits
//! ([`crate::daemon::acceptance`]); [`explain`] makes each say what to do
//! in the daemon's terms.

use crate::daemon::messages::CalibrationEvent;
use crate::daemon::sensor::Sensor;
use crate::model::rotation::Progress;

/// After a rejection, its reason stays on the sensor's line until the new
/// try covers this share of the headings again (the person has evidently
/// turned a quarter more); the log keeps it beyond.
pub const REJECTION_SHOWN_BELOW_PCT: f64 = 25.0;

/// Cells of the text bar.
const BAR_CELLS: usize = 10;

/// How far a sensor's current rotation has got.
#[derive(Debug, Clone, PartialEq)]
pub struct RotationView {
    pub coverage_pct: f64,
    /// Missing headings as [start, end] degrees; end < start wraps through 0°.
    pub missing: Vec<[f64; 2]>,
    pub samples: usize,
    /// A 3-axis sensor's sphere: the missing directions by the axes they
    /// lie toward ("-z", "+x+y"); `None` for a 2-axis sensor's rotation.
    pub sphere: Option<Vec<String>>,
    /// A still-pose sensor: (poses held, poses its model needs).
    pub still: Option<(usize, usize)>,
}

impl RotationView {
    /// "missing 120-200°" of a rotation, "missing -z, +x+y" of a sphere;
    /// empty when nothing is missing.
    fn missing_words(&self) -> String {
        match &self.sphere {
            Some(toward) if !toward.is_empty() => format!("missing {}", toward.join(", ")),
            Some(_) => String::new(),
            None => missing_text(&self.missing),
        }
    }

    /// What the person holding the sensor should do next.
    fn further(&self) -> String {
        match (&self.still, &self.sphere) {
            (Some((held, needed)), _) => format!(
                "{held} of at least {needed} poses held; rest the sensor still (0.5 s) facing \
                 the missing directions"
            ),
            (None, Some(_)) => "tumble further".into(),
            (None, None) => "turn further".into(),
        }
    }
}

impl From<&Progress> for RotationView {
    fn from(p: &Progress) -> Self {
        // A rotation completes when no gap between covered headings is too
        // wide and the readings turned far enough one way: the bar shows
        // the lesser of the two, so it reaches 100 % when the turn does.
        let turned_pct = if p.turn_needed_deg > 0.0 {
            100.0 * p.turned_deg.abs() / p.turn_needed_deg
        } else {
            100.0
        };
        RotationView {
            coverage_pct: p.coverage_pct.min(turned_pct).clamp(0.0, 100.0),
            missing: p.missing_sectors.clone(),
            samples: p.samples,
            sphere: None,
            still: None,
        }
    }
}

/// The heading check of an accepted fit.
#[derive(Debug, Clone, PartialEq)]
pub enum HeadingNote {
    /// The heading's rms error against the integrated gyro, degrees.
    Checked { rms_deg: f64 },
    /// Why no check was possible, as the daemon said it.
    NotChecked(String),
    /// Loaded from the state directory: not checked in this run.
    Unknown,
}

/// The last fit of a sensor.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Accepted {
        id: u64,
        /// Fraction of the field.
        rms: f64,
        heading: HeadingNote,
        /// Loaded from the state directory rather than fitted now.
        stored: bool,
        /// The effect the rotation's residual suggests adding, if any.
        suggested: Option<String>,
    },
    Rejected {
        reason: String,
        /// The effect the rotation's residual suggests adding, if any.
        suggested: Option<String>,
    },
}

/// One sensor's line, as data.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorView {
    pub sensor: String,
    /// The rotation being collected (None once calibrated).
    pub rotation: Option<RotationView>,
    pub outcome: Option<Outcome>,
    /// Why the latest calibrated reading is distrusted, while it is.
    pub distrust: Option<String>,
}

/// What the loop hands the board about one sensor.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorSnapshot {
    pub sensor: String,
    pub rotation: Option<RotationView>,
    /// The calibration correcting now: (id, rms).
    pub calibration: Option<(u64, f64)>,
    /// Why the latest calibrated reading is distrusted, while it is.
    pub distrust: Option<String>,
}

impl SensorSnapshot {
    pub fn of(sensor: &Sensor) -> Self {
        let status = sensor.status();
        SensorSnapshot {
            sensor: sensor.name().to_string(),
            rotation: status
                .rotation
                .as_ref()
                .map(RotationView::from)
                .or_else(|| {
                    // A 3-axis sensor: the bar shows its sphere's coverage.
                    status.sphere.as_ref().map(|p| RotationView {
                        coverage_pct: p.coverage_pct,
                        missing: Vec::new(),
                        samples: p.samples,
                        sphere: Some(p.missing.iter().map(|m| m.toward.clone()).collect()),
                        still: p.still.as_ref().map(|s| (s.poses, s.poses_needed)),
                    })
                }),
            calibration: sensor.calibration().map(|c| (c.id, c.rms)),
            distrust: sensor.distrust_now().map(str::to_string),
        }
    }
}

/// "missing 120-200°, 340-20°"; empty when nothing is missing.
pub fn missing_text(ranges: &[[f64; 2]]) -> String {
    if ranges.is_empty() {
        return String::new();
    }
    let parts: Vec<String> = ranges
        .iter()
        .map(|[a, b]| format!("{a:.0}-{b:.0}°"))
        .collect();
    format!("missing {}", parts.join(", "))
}

/// A reason for a rejection, in the daemon's terms, followed by what to do
/// when it does not already say so. The turn gate's reasons speak of the
/// `fit` command's `--x` and `--y`; the daemon's axes are the sensor's
/// `axes` key. The acceptance limits name their key; each gets its remedy.
pub fn explain(reason: &str) -> String {
    let text = reason
        .replace(
            "choose the two axes that turned with --x and --y",
            "give the two axes that turned in the sensor's axes",
        )
        .replace(
            "or lower the required coverage",
            "or lower limits.min_coverage_deg",
        );
    let mut advice: Vec<&str> = Vec::new();
    for (marker, remedy) in ADVICE {
        if text.contains(marker) && !advice.contains(remedy) {
            advice.push(remedy);
        }
    }
    if advice.is_empty() {
        text
    } else {
        format!("{text}; {}", advice.join("; "))
    }
}

/// Reasons that do not say what to do, by a marker in their text, with
/// the remedy. Every other reason the daemon gives ends with its remedy.
const ADVICE: &[(&str, &str)] = &[
    (
        "(limits.min_coverage_deg)",
        "turn the sensor once all the way round",
    ),
    (
        "(limits.max_rms)",
        "turn it steadily in place and level (a plane that wobbles adds an error no 2-D model removes), away from motors and metal; if the rms stays high, add the suggested effect to the sensor's effects",
    ),
    (
        "(limits.min_radius)",
        "check that the sensor's field and axes are the ones that turned, or correct limits.min_radius",
    ),
    (
        "(limits.max_radius)",
        "check that the sensor's field and axes are the ones that turned, or correct limits.max_radius",
    ),
    (
        "(limits.max_offset_ratio)",
        "mount the sensor away from magnets, motors and batteries, or raise limits.max_offset_ratio",
    ),
    (
        "(limits.max_scale_ratio)",
        "check that the sensor's axes are the two that turned, or raise limits.max_scale_ratio",
    ),
    (
        "the rotation cannot be used",
        "turn the sensor once more, in place and steadily",
    ),
    (
        "fit no ellipse",
        "check that the sensor's axes are the two that turned, and turn it once more in place",
    ),
    (
        "has no real radius",
        "check that the sensor's axes are the two that turned, and turn it once more in place",
    ),
    (
        "the model does not suit these readings",
        "remove the last effect from the sensor's effects, or turn it once more in place",
    ),
];

/// The words of an accepted fit: "calibrated #3, rms 0.31 %, heading check 0.4°".
fn accepted_words(
    id: u64,
    rms: f64,
    heading: &HeadingNote,
    stored: bool,
    suggested: Option<&str>,
) -> String {
    let mut words = format!(
        "calibrated #{id}{}, rms {:.2} %",
        if stored { " (stored)" } else { "" },
        rms * 100.0
    );
    match heading {
        HeadingNote::Checked { rms_deg } => {
            words.push_str(&format!(", heading check {rms_deg:.1}°"))
        }
        HeadingNote::NotChecked(why) => {
            words.push_str(", ");
            words.push_str(why);
        }
        HeadingNote::Unknown => {}
    }
    if let Some(effect) = suggested {
        words.push_str(&format!(
            "; the turn suggests adding the effect {effect} to the sensor's effects"
        ));
    }
    words
}

/// The words of a rejection: its reason and what to do, and the effect the
/// turn suggests when it found one.
fn rejected_words(reason: &str, suggested: Option<&str>) -> String {
    let mut words = format!("rejected: {}", explain(reason));
    if let Some(effect) = suggested {
        words.push_str(&format!(
            "; the turn suggests adding the effect {effect} to the sensor's effects"
        ));
    }
    words
}

fn bar(pct: f64) -> String {
    let filled = ((pct.clamp(0.0, 100.0) / 100.0) * BAR_CELLS as f64).round() as usize;
    format!(
        "[{}{}]",
        "#".repeat(filled),
        "-".repeat(BAR_CELLS.saturating_sub(filled))
    )
}

/// The line of one sensor, its name padded to `name_width`:
/// `compass  [######----]  62 %  missing 120-200°, 340-20°  turn further`.
pub fn render_line(view: &SensorView, name_width: usize) -> String {
    let name = format!("{:<name_width$}", view.sensor);
    let rotation_line = |r: &RotationView, words: &str| {
        let mut line = format!("{name}  {} {:>3.0} %", bar(r.coverage_pct), r.coverage_pct);
        let missing = r.missing_words();
        if !missing.is_empty() {
            line.push_str("  ");
            line.push_str(&missing);
        }
        line.push_str("  ");
        line.push_str(words);
        line
    };
    match (&view.rotation, &view.outcome) {
        (Some(r), Some(Outcome::Rejected { reason, suggested }))
            if r.coverage_pct < REJECTION_SHOWN_BELOW_PCT =>
        {
            rotation_line(r, &rejected_words(reason, suggested.as_deref()))
        }
        (Some(r), _) if r.samples == 0 => rotation_line(r, "waiting for readings"),
        (Some(r), _) => rotation_line(r, &r.further()),
        (
            None,
            Some(Outcome::Accepted {
                id,
                rms,
                heading,
                stored,
                suggested,
            }),
        ) => {
            let mut words = accepted_words(*id, *rms, heading, *stored, suggested.as_deref());
            if let Some(why) = &view.distrust {
                words.push_str("  DISTRUSTED: ");
                words.push_str(why);
            }
            if *stored {
                format!("{name}  {words}")
            } else {
                format!("{name}  {} 100 %  {words}", bar(100.0))
            }
        }
        (None, Some(Outcome::Rejected { reason, suggested })) => {
            format!("{name}  {}", rejected_words(reason, suggested.as_deref()))
        }
        (None, None) => format!("{name}  waiting for readings"),
    }
}

#[derive(Debug, Clone)]
struct Track {
    view: SensorView,
    /// A rotation is under way (its start was logged).
    attempt: bool,
    /// Quarters of coverage logged in this attempt (0 to 3).
    quarter: u8,
    /// Samples in the last snapshot, to see a restart.
    samples: usize,
}

/// Every sensor's line and the milestones to log. Pure.
#[derive(Debug, Clone, Default)]
pub struct Board {
    tracks: Vec<Track>,
}

impl Board {
    pub fn new() -> Self {
        Board::default()
    }

    fn track(&mut self, sensor: &str) -> &mut Track {
        let i = match self.tracks.iter().position(|t| t.view.sensor == sensor) {
            Some(i) => i,
            None => {
                self.tracks.push(Track {
                    view: SensorView {
                        sensor: sensor.to_string(),
                        rotation: None,
                        outcome: None,
                        distrust: None,
                    },
                    attempt: false,
                    quarter: 0,
                    samples: 0,
                });
                self.tracks.len() - 1
            }
        };
        &mut self.tracks[i]
    }

    /// Takes the loop's snapshot; returns the milestones it crossed, as
    /// log messages: a rotation started, each quarter of coverage.
    pub fn update(&mut self, snapshots: &[SensorSnapshot]) -> Vec<String> {
        let mut logs = Vec::new();
        for s in snapshots {
            let track = self.track(&s.sensor);
            track.view.rotation = s.rotation.clone();
            match (&track.view.distrust, &s.distrust) {
                (None, Some(why)) => logs.push(format!("{}: readings distrusted: {why}", s.sensor)),
                (Some(_), None) => logs.push(format!("{}: readings trusted again", s.sensor)),
                _ => {}
            }
            track.view.distrust = s.distrust.clone();
            if track.view.outcome.is_none()
                && let Some((id, rms)) = s.calibration
            {
                track.view.outcome = Some(Outcome::Accepted {
                    id,
                    rms,
                    heading: HeadingNote::Unknown,
                    stored: true,
                    suggested: None,
                });
            }
            let Some(r) = &s.rotation else {
                track.attempt = false;
                track.samples = 0;
                continue;
            };
            // The buffer restarted without a CALIBRATION line (a client's
            // recalibrate): a new attempt.
            if r.samples < track.samples {
                track.attempt = false;
            }
            track.samples = r.samples;
            if r.samples == 0 {
                continue;
            }
            if !track.attempt {
                track.attempt = true;
                track.quarter = 0;
                logs.push(if r.still.is_some() {
                    format!(
                        "{}: collecting still poses; rest the sensor still (0.5 s) in each pose, \
                         facing every direction in turn (as on the faces of a box)",
                        s.sensor
                    )
                } else if r.sphere.is_some() {
                    format!(
                        "{}: collecting the sphere; tumble the sensor through every direction",
                        s.sensor
                    )
                } else {
                    format!(
                        "{}: rotation started; turn the sensor a full rotation",
                        s.sensor
                    )
                });
            }
            let quarter = (r.coverage_pct / 25.0).floor().clamp(0.0, 3.0) as u8;
            if quarter > track.quarter {
                track.quarter = quarter;
                let missing = r.missing_words();
                logs.push(format!(
                    "{}: {:.0} % of {} covered{}; {}",
                    s.sensor,
                    r.coverage_pct,
                    if r.sphere.is_some() {
                        "the sphere"
                    } else {
                        "headings"
                    },
                    if missing.is_empty() {
                        String::new()
                    } else {
                        format!(", {missing}")
                    },
                    r.further()
                ));
            }
        }
        logs
    }

    /// Takes a `CALIBRATION` the daemon published, which sets the
    /// sensor's outcome. Returns the milestones as log messages: a rotation
    /// complete, and the fit accepted or rejected, in the live line's words.
    pub fn on_calibration(&mut self, c: &CalibrationEvent) -> Vec<String> {
        let mut logs = Vec::new();
        let track = self.track(&c.sensor);
        let stored = c.stored;
        let outcome = match (c.accepted, c.id, c.rms) {
            (true, Some(id), Some(rms)) => {
                let heading = match (c.heading_rms_deg, &c.heading_check) {
                    (Some(rms_deg), _) => HeadingNote::Checked { rms_deg },
                    (None, Some(why)) => HeadingNote::NotChecked(why.clone()),
                    (None, None) => HeadingNote::Unknown,
                };
                Outcome::Accepted {
                    id,
                    rms,
                    heading,
                    stored,
                    suggested: c.suggested.clone(),
                }
            }
            _ => Outcome::Rejected {
                reason: c
                    .reason
                    .clone()
                    .unwrap_or_else(|| "the fit was not accepted".into()),
                suggested: c.suggested.clone(),
            },
        };
        if let (false, Some(poses)) = (stored, c.poses) {
            logs.push(format!(
                "{}: {} held still, {}",
                c.sensor,
                crate::sample::count(poses as u64, "pose"),
                crate::sample::count(c.n as u64, "sample")
            ));
        } else if !stored && c.n > 0 && c.axes == 3 {
            logs.push(format!(
                "{}: sphere covered, {}",
                c.sensor,
                crate::sample::count(c.n as u64, "sample")
            ));
        } else if !stored && c.n > 0 {
            logs.push(format!(
                "{}: rotation complete, {} over {:.0}°",
                c.sensor,
                crate::sample::count(c.n as u64, "sample"),
                c.coverage_deg
            ));
        }
        match &outcome {
            Outcome::Accepted {
                id,
                rms,
                heading,
                suggested,
                ..
            } => {
                // Calibrated: the sensor collects no more until asked to.
                track.view.rotation = None;
                if !stored {
                    logs.push(format!(
                        "{}: {}",
                        c.sensor,
                        accepted_words(*id, *rms, heading, false, suggested.as_deref())
                    ));
                }
            }
            Outcome::Rejected { reason, suggested } => {
                // The buffer has restarted: the next snapshot shows the new try.
                if let Some(r) = &mut track.view.rotation {
                    r.coverage_pct = 0.0;
                    r.missing = vec![[0.0, 360.0]];
                    r.samples = 0;
                }
                logs.push(format!(
                    "{}: {}",
                    c.sensor,
                    rejected_words(reason, suggested.as_deref())
                ));
            }
        }
        track.attempt = false;
        track.quarter = 0;
        track.samples = 0;
        track.view.outcome = Some(outcome);
        logs
    }

    /// The live lines, one per sensor, names aligned.
    pub fn lines(&self) -> Vec<String> {
        let width = self
            .tracks
            .iter()
            .map(|t| t.view.sensor.chars().count())
            .max()
            .unwrap_or(0);
        self.tracks
            .iter()
            .map(|t| render_line(&t.view, width))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    fn collecting(pct: f64, missing: Vec<[f64; 2]>, samples: usize) -> RotationView {
        RotationView {
            coverage_pct: pct,
            missing,
            samples,
            sphere: None,
            still: None,
        }
    }

    #[test]
    fn a_distrusted_reading_is_logged_shown_and_cleared() {
        let mut board = Board::new();
        let snapshot = |distrust: Option<&str>| SensorSnapshot {
            sensor: "compass".into(),
            rotation: None,
            calibration: Some((3, 0.004)),
            distrust: distrust.map(str::to_string),
        };
        assert!(board.update(&[snapshot(None)]).is_empty());
        let why = "the field is 5.1 % below the calibration's r (limit 0.6 %: 5 σ of its noise)";
        assert_eq!(
            board.update(&[snapshot(Some(why))]),
            [format!("compass: readings distrusted: {why}")]
        );
        let line = render_line(&board.tracks[0].view, 7);
        assert!(line.ends_with(&format!("DISTRUSTED: {why}")), "{line}");
        assert!(board.update(&[snapshot(Some(why))]).is_empty());
        assert_eq!(
            board.update(&[snapshot(None)]),
            ["compass: readings trusted again"]
        );
        let line = render_line(&board.tracks[0].view, 7);
        assert!(!line.contains("DISTRUSTED"), "{line}");
    }

    #[test]
    fn a_sphere_is_tumbled_not_turned() {
        let r = RotationView {
            coverage_pct: 62.0,
            missing: Vec::new(),
            samples: 400,
            sphere: Some(vec!["-z".into(), "+x+y".into()]),
            still: None,
        };
        let line = render_line(&view(Some(r.clone()), None), 7);
        assert!(
            line.ends_with("62 %  missing -z, +x+y  tumble further"),
            "{line}"
        );
        let mut board = Board::default();
        let logs = board.update(&[SensorSnapshot {
            sensor: "compass".into(),
            rotation: Some(r),
            calibration: None,
            distrust: None,
        }]);
        assert_eq!(
            logs,
            [
                "compass: collecting the sphere; tumble the sensor through every direction",
                "compass: 62 % of the sphere covered, missing -z, +x+y; tumble further"
            ]
        );
    }

    fn view(rotation: Option<RotationView>, outcome: Option<Outcome>) -> SensorView {
        SensorView {
            sensor: "compass".into(),
            rotation,
            outcome,
            distrust: None,
        }
    }

    #[test]
    fn collecting_shows_coverage_missing_headings_and_turn_further() {
        let v = view(Some(collecting(62.5, vec![[120.0, 200.0]], 140)), None);
        assert_eq!(
            render_line(&v, 9),
            "compass    [######----]  62 %  missing 120-200°  turn further"
        );
    }

    #[test]
    fn a_missing_range_through_zero_reads_across_it() {
        let v = view(
            Some(collecting(50.0, vec![[120.0, 200.0], [340.0, 20.0]], 90)),
            None,
        );
        assert_eq!(
            render_line(&v, 7),
            "compass  [#####-----]  50 %  missing 120-200°, 340-20°  turn further"
        );
        assert_eq!(missing_text(&[]), "");
        assert_eq!(missing_text(&[[0.0, 360.0]]), "missing 0-360°");
    }

    #[test]
    fn before_the_first_reading_it_waits() {
        let v = view(Some(collecting(0.0, vec![[0.0, 360.0]], 0)), None);
        assert_eq!(
            render_line(&v, 7),
            "compass  [----------]   0 %  missing 0-360°  waiting for readings"
        );
        assert_eq!(
            render_line(&view(None, None), 7),
            "compass  waiting for readings"
        );
    }

    #[test]
    fn calibrated_shows_id_rms_and_heading_check() {
        let accepted = |heading| Outcome::Accepted {
            id: 3,
            rms: 0.0031,
            heading,
            stored: false,
            suggested: None,
        };
        assert_eq!(
            render_line(
                &view(None, Some(accepted(HeadingNote::Checked { rms_deg: 0.4 }))),
                7
            ),
            "compass  [##########] 100 %  calibrated #3, rms 0.31 %, heading check 0.4°"
        );
        let why = "no heading check: gyro = \"none\" in the configuration";
        assert_eq!(
            render_line(
                &view(None, Some(accepted(HeadingNote::NotChecked(why.into())))),
                7
            ),
            format!("compass  [##########] 100 %  calibrated #3, rms 0.31 %, {why}")
        );
        let stored = Outcome::Accepted {
            id: 2,
            rms: 0.012,
            heading: HeadingNote::Unknown,
            stored: true,
            suggested: Some("cubic".into()),
        };
        assert_eq!(
            render_line(&view(None, Some(stored)), 7),
            "compass  calibrated #2 (stored), rms 1.20 %; the turn suggests adding the effect cubic to the sensor's effects"
        );
    }

    #[test]
    fn a_rejection_shows_its_reason_and_what_to_do_until_the_next_try_turns() {
        let reason = "rms 7.3 % of the field exceeds the limit of 5.0 % (limits.max_rms)";
        let rejected = Some(Outcome::Rejected {
            reason: reason.into(),
            suggested: None,
        });
        let line = render_line(
            &view(
                Some(collecting(0.0, vec![[0.0, 360.0]], 4)),
                rejected.clone(),
            ),
            7,
        );
        assert_eq!(
            line,
            format!(
                "compass  [----------]   0 %  missing 0-360°  rejected: {reason}; turn it steadily in place and level (a plane that wobbles adds an error no 2-D model removes), away from motors and metal; if the rms stays high, add the suggested effect to the sensor's effects"
            )
        );
        // A quarter turned again: back to the turn.
        let line = render_line(
            &view(Some(collecting(25.0, vec![[90.0, 360.0]], 60)), rejected),
            7,
        );
        assert_eq!(
            line,
            "compass  [###-------]  25 %  missing 90-360°  turn further"
        );
    }

    #[test]
    fn every_reason_says_what_to_do_in_the_daemons_terms() {
        // The turn gate's reason speaks of the fit command's flags.
        let gate = "the readings go only 200° round their centre (the largest gap runs 160° from 10°), and a fit needs 300°: the sensor did not turn a full rotation in the plane of x and y; turn it a full rotation in a constant field, choose the two axes that turned with --x and --y, or lower the required coverage";
        let explained = explain(gate);
        assert!(!explained.contains("--x"), "{explained}");
        assert!(explained.ends_with(
            "give the two axes that turned in the sensor's axes, or lower limits.min_coverage_deg"
        ));
        // Two limits failed: both remedies, once each.
        let two = "heading coverage 250.0° is below the limit of 300.0° (limits.min_coverage_deg); axis gain ratio 2.500 (a = 0.4000) exceeds the limit of 2 (limits.max_scale_ratio)";
        assert_eq!(
            explain(two),
            format!(
                "{two}; turn the sensor once all the way round; check that the sensor's axes are the two that turned, or raise limits.max_scale_ratio"
            )
        );
        // A reason with its remedy already is left as it is.
        let buffer = "no full rotation within 60 s: 89 % of headings covered, missing 40° to 80°; turn the sensor once all the way round, steadily";
        assert_eq!(explain(buffer), buffer);
    }

    /// Every reason acceptance::check can give gets a remedy.
    #[test]
    fn every_acceptance_limit_has_a_remedy() {
        use crate::daemon::acceptance::{Limits, check};
        use crate::model::fit::{FitReport, Solver};
        use crate::model::heading::coverage;
        use crate::model::paper::PaperCalibration;
        let report = |a: f64, b: f64, r: f64, rms: f64, covered: f64| {
            let calibration = PaperCalibration { a, b, d: 0.0, r };
            let headings = (0..=360)
                .map(|d| f64::from(d).to_radians())
                .filter(|h| h.to_degrees() <= covered);
            FitReport {
                solver: Solver::Lsq,
                calibration,
                theta: calibration.to_theta(),
                rms,
                n: 400,
                iterations: None,
                coverage: coverage(headings),
                elapsed: Duration::ZERO,
            }
        };
        let defaults = Limits::default();
        let min_radius = Limits {
            min_radius: Some(2000.0),
            ..Limits::default()
        };
        let max_radius = Limits {
            max_radius: Some(10.0),
            ..Limits::default()
        };
        let cases = [
            (report(1.0, 0.0, 1000.0, 0.2, 360.0), &defaults),
            (report(1.0, 0.0, 1000.0, 0.01, 200.0), &defaults),
            (report(1.0, 1e5, 1000.0, 0.01, 360.0), &defaults),
            (report(5.0, 0.0, 1000.0, 0.01, 360.0), &defaults),
            (report(1.0, 0.0, 1000.0, 0.01, 360.0), &min_radius),
            (report(1.0, 0.0, 1000.0, 0.01, 360.0), &max_radius),
            (report(1.0, 0.0, f64::NAN, 0.01, 360.0), &defaults),
            (report(-1.0, 0.0, 1000.0, 0.01, 360.0), &defaults),
        ];
        let mut keys = std::collections::BTreeSet::new();
        for (r, l) in cases {
            let reason = check(&r, l).unwrap_err();
            // Each limit the reason names has its own remedy.
            let named: Vec<&str> = reason
                .match_indices("(limits.")
                .filter_map(|(at, _)| {
                    reason[at..]
                        .split_once(')')
                        .map(|(key, _)| &reason[at..=at + key.len()])
                })
                .collect();
            for key in &named {
                assert!(
                    ADVICE.iter().any(|(marker, _)| marker == key),
                    "no remedy for {key} in: {reason}"
                );
                keys.insert(key.to_string());
            }
            assert!(
                explain(&reason).len() > reason.len(),
                "no remedy for: {reason}"
            );
        }
        // Every limit was tried.
        assert_eq!(keys.len(), 6, "{keys:?}");
    }

    fn snapshot(pct: f64, missing: Vec<[f64; 2]>, samples: usize) -> Vec<SensorSnapshot> {
        vec![SensorSnapshot {
            sensor: "compass".into(),
            rotation: Some(collecting(pct, missing, samples)),
            calibration: None,
            distrust: None,
        }]
    }

    /// A fit of the compass's rotation, with nothing but its verdict.
    fn fitted(accepted: bool) -> CalibrationEvent {
        CalibrationEvent {
            sensor: "compass".into(),
            accepted,
            id: None,
            reason: None,
            rms: None,
            coverage_deg: 0.0,
            n: 0,
            stored: false,
            suggested: None,
            heading_rms_deg: None,
            heading_check: None,
            poses: None,
            axes: 2,
        }
    }

    #[test]
    fn a_sphere_or_still_poses_complete_in_their_own_words() {
        let mut board = Board::new();
        let sphere = CalibrationEvent {
            id: Some(2),
            rms: Some(0.01),
            n: 500,
            axes: 3,
            ..fitted(true)
        };
        assert_eq!(
            board.on_calibration(&sphere),
            [
                "compass: sphere covered, 500 samples",
                "compass: calibrated #2, rms 1.00 %"
            ]
        );
        let poses = CalibrationEvent {
            poses: Some(6),
            ..sphere
        };
        assert_eq!(
            board.on_calibration(&poses)[0],
            "compass: 6 poses held still, 500 samples"
        );
    }

    #[test]
    fn the_board_logs_the_moments_that_matter_and_no_more() {
        let mut board = Board::new();
        assert!(
            board
                .update(&snapshot(0.0, vec![[0.0, 360.0]], 0))
                .is_empty()
        );
        assert_eq!(
            board.update(&snapshot(0.0, vec![[0.0, 360.0]], 3)),
            ["compass: rotation started; turn the sensor a full rotation"]
        );
        assert!(
            board
                .update(&snapshot(10.0, vec![[40.0, 360.0]], 20))
                .is_empty()
        );
        // 20 % to 55 %: one line, at the coverage reached.
        assert_eq!(
            board.update(&snapshot(55.0, vec![[200.0, 360.0]], 80)),
            ["compass: 55 % of headings covered, missing 200-360°; turn further"]
        );
        assert!(
            board
                .update(&snapshot(60.0, vec![[220.0, 360.0]], 90))
                .is_empty()
        );
        assert_eq!(
            board
                .update(&snapshot(80.0, vec![[290.0, 10.0]], 120))
                .len(),
            1
        );
        let accepted = CalibrationEvent {
            id: Some(1),
            rms: Some(0.0031),
            coverage_deg: 360.0,
            n: 412,
            heading_rms_deg: Some(0.43),
            ..fitted(true)
        };
        assert_eq!(
            board.on_calibration(&accepted),
            [
                "compass: rotation complete, 412 samples over 360°",
                "compass: calibrated #1, rms 0.31 %, heading check 0.4°"
            ]
        );
        assert_eq!(
            board.lines(),
            ["compass  [##########] 100 %  calibrated #1, rms 0.31 %, heading check 0.4°"]
        );
        let rejected = CalibrationEvent {
            reason: Some("the sensor is not turning: readings spread over only 3.0 counts in 10.0 s (noise about 1.0 counts); turn it a full rotation".into()),
            ..fitted(false)
        };
        assert_eq!(
            board.on_calibration(&rejected),
            [
                "compass: rejected: the sensor is not turning: readings spread over only 3.0 counts in 10.0 s (noise about 1.0 counts); turn it a full rotation"
            ]
        );
    }

    #[test]
    fn a_fit_outside_the_limits_shows_its_numbers_reason_and_suggestion() {
        let mut board = Board::new();
        board.update(&snapshot(90.0, vec![[330.0, 360.0]], 180));
        let rejected = CalibrationEvent {
            reason: Some(
                "rms 7.3 % of the field exceeds the limit of 5.0 % (limits.max_rms)".into(),
            ),
            rms: Some(0.073),
            coverage_deg: 358.0,
            n: 200,
            suggested: Some("cubic".into()),
            ..fitted(false)
        };
        let words = "rejected: rms 7.3 % of the field exceeds the limit of 5.0 % (limits.max_rms); turn it steadily in place and level (a plane that wobbles adds an error no 2-D model removes), away from motors and metal; if the rms stays high, add the suggested effect to the sensor's effects; the turn suggests adding the effect cubic to the sensor's effects";
        assert_eq!(
            board.on_calibration(&rejected),
            [
                "compass: rotation complete, 200 samples over 358°".to_string(),
                format!("compass: {words}")
            ]
        );
        // The buffer restarted: the line shows the new, empty try and why.
        assert_eq!(
            board.lines(),
            [format!(
                "compass  [----------]   0 %  missing 0-360°  {words}"
            )]
        );
    }

    #[test]
    fn a_stored_calibration_shows_until_a_fit_replaces_it() {
        let mut board = Board::new();
        let logs = board.update(&[SensorSnapshot {
            sensor: "compass".into(),
            rotation: None,
            calibration: Some((4, 0.002)),
            distrust: None,
        }]);
        assert!(logs.is_empty());
        assert_eq!(
            board.lines(),
            ["compass  calibrated #4 (stored), rms 0.20 %"]
        );
    }
}
