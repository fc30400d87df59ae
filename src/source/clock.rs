//! The clock of live messages: the host's Unix clock, except that it never
//! goes back.
//!
//! Everything downstream keys on reading times in order: the rotation
//! buffer and the gyro's track leave out a sample older than the one
//! before, and the trust monitor distrusts it. A wall clock stepped back
//! (NTP correcting a real-time clock that ran ahead, an operator's `date
//! -s`) would make every reading older than the last for as long as the
//! step, so for an hour's step an hour of readings would be distrusted
//! and no rotation collected. Stepped forward (NTP setting a clock that
//! booted behind), the clock is followed: a gap in time, as after a
//! device that was unplugged, which the rotation buffer and the monitor
//! already take.
//!
//! So a stamp is the wall clock's reading, unless that is earlier than
//! the stamps going on from the last one at a rate 500 ppm slower than the
//! monotonic clock (as `adjtime` slews); then it is that, until the wall
//! clock catches up with them (a wall clock stepped forward meanwhile is
//! followed once it passes them). While slewing, stamps never go back and
//! never run faster than real time; after a step back of `s` seconds they
//! are on the wall clock again after `s / 0.0005` seconds (a 0.2 s step in
//! 400 s, an hour's in about 83 days; a restart puts them on the wall
//! clock at once).
//!
//! One clock serves the whole process ([`live_now`]): every source's
//! readings and the daemon's STATUS lines, so that a source plugged in
//! after a step is on the same clock as one that was reading through it.

use std::sync::Mutex;
use std::time::Instant;

/// How much slower than the monotonic clock stamps run while they are
/// ahead of a wall clock that stepped back: `adjtime`'s largest slew,
/// 500 ppm.
pub const SLEW: f64 = 0.0005;

/// A step back of the wall clock smaller than this (against the monotonic
/// clock, between two stamps) is not logged; each larger one is, once.
pub const WARN_STEP_S: f64 = 0.1;

/// The process's live clock.
static LIVE: Mutex<LiveClock> = Mutex::new(LiveClock::new());

/// The stamp for a message made now, on the process's one live clock, and
/// the monotonic instant it was taken at.
pub fn live_now() -> (f64, Instant) {
    let (stamp, at, step) = {
        // A panic while holding the lock leaves a clock that is still
        // whole (`stamp` does not panic part-way): use it.
        let mut clock = LIVE.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        // Both clocks read under the lock, so stamps are made in the order
        // of their instants.
        let (wall, at) = wall_and_instant();
        let stamp = clock.stamp(wall, at);
        (stamp, at, clock.take_step())
    };
    // Logged after the lock is let go: a slow log must not hold up every
    // source.
    if let Some(step) = step {
        tracing::warn!(
            "the wall clock went back by {:.3} s: readings keep their order, stamped on from the last one {:.0} ppm slower than real time until the wall clock catches up (in {}); a restart puts them on the wall clock at once",
            step.back,
            SLEW * 1e6,
            duration_words(step.lead / SLEW)
        );
    }
    (stamp, at)
}

/// The wall clock (seconds since the Unix epoch; NaN when it is set before
/// the epoch) and the monotonic instant it was read at. A thread held up
/// between the two reads (a paused VM, a stopped process) would pair a
/// wall time with a later instant, and the gap would look like a step
/// back: the wall clock is read between two instants, again (at most 4
/// times) while they are more than 1 ms apart.
fn wall_and_instant() -> (f64, Instant) {
    let mut pair = (f64::NAN, Instant::now());
    for _ in 0..4 {
        let before = Instant::now();
        let wall = unix_time().unwrap_or(f64::NAN);
        let after = Instant::now();
        pair = (wall, before);
        if after.duration_since(before) <= std::time::Duration::from_millis(1) {
            break;
        }
    }
    pair
}

/// The wall clock in seconds since the Unix epoch; none when it is set
/// before the epoch.
pub fn unix_time() -> Option<f64> {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .ok()
        .map(|d| d.as_secs_f64())
}

/// A step back of the wall clock, for the log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepBack {
    /// How far the wall clock went back, seconds.
    pub back: f64,
    /// How far the stamps are ahead of it now, seconds.
    pub lead: f64,
}

/// Stamps that follow the wall clock and never go back.
#[derive(Debug, Default)]
pub struct LiveClock {
    /// The last stamp, the wall clock's reading then, and the monotonic
    /// instant (the latest seen).
    last: Option<Last>,
    /// While the stamps are ahead of the wall clock: the stamp and the
    /// instant the slewing started from (each stamp is measured from
    /// there, one rounding, so slewing does not gather rounding errors).
    slewing: Option<(f64, Instant)>,
    /// How many times the wall clock stepped back by more than
    /// [`WARN_STEP_S`].
    steps_back: u64,
    /// The last such step, until [`LiveClock::take_step`].
    step: Option<StepBack>,
}

#[derive(Debug, Clone, Copy)]
struct Last {
    stamp: f64,
    wall: f64,
    at: Instant,
}

impl LiveClock {
    pub const fn new() -> Self {
        LiveClock {
            last: None,
            slewing: None,
            steps_back: 0,
            step: None,
        }
    }

    /// How many steps back of the wall clock (each more than
    /// [`WARN_STEP_S`]) the stamps have gone on through.
    pub fn steps_back(&self) -> u64 {
        self.steps_back
    }

    /// The step back the last stamp found, if any, once.
    pub fn take_step(&mut self) -> Option<StepBack> {
        self.step.take()
    }

    /// The stamp for a message made at monotonic instant `at` while the
    /// wall clock read `wall` (seconds since the Unix epoch).
    pub fn stamp(&mut self, wall: f64, at: Instant) -> f64 {
        let Some(last) = self.last else {
            let stamp = if wall.is_finite() { wall } else { 0.0 };
            self.last = Some(Last {
                stamp,
                wall: stamp,
                at,
            });
            return stamp;
        };
        // An instant before the last one (not from `Instant::now()` in
        // order) counts as no time passed, and the later one is kept.
        let at = at.max(last.at);
        let elapsed = at.duration_since(last.at).as_secs_f64();
        let (from, since) = *self.slewing.get_or_insert((last.stamp, last.at));
        let slewed = from + at.duration_since(since).as_secs_f64() * (1.0 - SLEW);
        let stamp = if wall.is_finite() && wall >= slewed {
            self.slewing = None;
            wall
        } else {
            slewed.max(last.stamp)
        };
        let back = last.wall + elapsed - wall;
        if wall.is_finite() && back > WARN_STEP_S {
            self.steps_back += 1;
            self.step = Some(StepBack {
                back,
                lead: stamp - wall,
            });
        }
        self.last = Some(Last {
            stamp,
            wall: if wall.is_finite() {
                wall
            } else {
                last.wall + elapsed
            },
            at,
        });
        stamp
    }
}

/// "400 s", "2.5 h", "83 days".
fn duration_words(seconds: f64) -> String {
    if seconds < 3600.0 {
        format!("{seconds:.0} s")
    } else if seconds < 2.0 * 86_400.0 {
        format!("{:.1} h", seconds / 3600.0)
    } else {
        format!("{:.0} days", seconds / 86_400.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    const T0: f64 = 1_700_000_000.0;

    /// Stamps for reads 50 ms apart on the monotonic clock, with the wall
    /// clock `wall(i)` at read `i`, and the clock after them.
    fn stamps(n: u32, wall: impl Fn(u32) -> f64) -> (Vec<f64>, LiveClock) {
        let start = Instant::now();
        let mut clock = LiveClock::new();
        let times = (0..n)
            .map(|i| clock.stamp(wall(i), start + Duration::from_millis(50 * u64::from(i))))
            .collect();
        (times, clock)
    }

    /// Consecutive stamps 50 ms apart on the monotonic clock: never back,
    /// never faster than real time, at most 500 ppm slower (to within a
    /// stamp's rounding, 2.4e-7 s at this epoch).
    fn slewing_steps(times: &[f64]) {
        for pair in times.windows(2) {
            let step = pair[1] - pair[0];
            assert!(
                step > 0.05 * (1.0 - SLEW) - 1e-6 && step <= 0.05 + 1e-6,
                "{step}"
            );
        }
    }

    #[test]
    fn a_steady_wall_clock_is_followed_exactly() {
        let (times, clock) = stamps(100, |i| T0 + 0.05 * f64::from(i));
        for (i, t) in times.iter().enumerate() {
            assert_eq!(*t, T0 + 0.05 * i as f64);
        }
        assert_eq!(clock.steps_back(), 0);
    }

    #[test]
    fn a_wall_clock_stepped_forward_is_followed() {
        let (times, clock) = stamps(10, |i| {
            T0 + 0.05 * f64::from(i) + if i >= 5 { 3600.0 } else { 0.0 }
        });
        assert_eq!(times[4], T0 + 0.2);
        assert_eq!(times[5], T0 + 0.25 + 3600.0);
        assert_eq!(clock.steps_back(), 0);
    }

    #[test]
    fn a_wall_clock_stepped_back_an_hour_never_sends_the_stamps_back() {
        let wall = |i: u32| T0 + 0.05 * f64::from(i) - if i >= 5 { 3600.0 } else { 0.0 };
        let (times, clock) = stamps(2000, wall);
        slewing_steps(&times);
        // Still ahead of the wall clock by about the hour, slewing back.
        let ahead = times[1999] - wall(1999);
        let slewed = 0.05 * 1995.0 * SLEW;
        assert!((ahead - (3600.0 - slewed)).abs() < 1e-5, "{ahead}");
        assert_eq!(clock.steps_back(), 1);
    }

    #[test]
    fn a_small_step_back_is_slewed_out_and_the_wall_clock_followed_again() {
        // 0.2 s back at read 5: 400 s (8,000 reads) of slewing at 500 ppm.
        let wall = |i: u32| T0 + 0.05 * f64::from(i) - if i >= 5 { 0.2 } else { 0.0 };
        let (times, clock) = stamps(10_000, wall);
        slewing_steps(&times);
        let ahead = |i: usize| times[i] - wall(i as u32);
        assert!(
            (ahead(5) - (0.2 - 0.05 * SLEW)).abs() < 1e-6,
            "{}",
            ahead(5)
        );
        assert!(ahead(7_990) > 0.0, "{}", ahead(7_990));
        assert_eq!(times[8_010], wall(8_010));
        assert_eq!(clock.steps_back(), 1);
    }

    #[test]
    fn every_step_back_is_counted_once_even_while_slewing() {
        // An hour back at read 5, then a minute more at read 100 (while
        // the first is still slewed out); a 50 ms step at 200 is jitter.
        let wall = |i: u32| {
            T0 + 0.05 * f64::from(i)
                - if i >= 5 { 3600.0 } else { 0.0 }
                - if i >= 100 { 60.0 } else { 0.0 }
                - if i >= 200 { 0.05 } else { 0.0 }
        };
        let (times, mut clock) = stamps(300, wall);
        slewing_steps(&times);
        assert_eq!(clock.steps_back(), 2);
        // The log's figures are the second step's: a minute back, the
        // whole lead (an hour and a minute, less what was slewed) ahead.
        let step = clock
            .take_step()
            .expect("the last step is kept for the log");
        assert!((step.back - 60.0).abs() < 1e-5, "{step:?}");
        assert!(
            (step.lead - (3660.0 - 0.05 * 96.0 * SLEW)).abs() < 1e-5,
            "{step:?}"
        );
        assert_eq!(clock.take_step(), None);
    }

    #[test]
    fn an_instant_out_of_order_or_a_wall_clock_not_a_number_moves_nothing_back() {
        let start = Instant::now() + Duration::from_secs(1);
        let mut clock = LiveClock::new();
        assert_eq!(clock.stamp(f64::NAN, start), 0.0);
        let mut clock = LiveClock::new();
        assert_eq!(clock.stamp(T0, start), T0);
        // 10 ms before the last instant: no time passed.
        let early = clock.stamp(T0 + 0.1, start - Duration::from_millis(10));
        assert_eq!(early, T0 + 0.1);
        // A wall clock that is not a number: the stamps go on, slewed.
        let later = start + Duration::from_millis(50);
        let nan = clock.stamp(f64::NAN, later);
        assert!(nan >= early && nan <= early + 0.05 + 1e-6, "{nan}");
        let inf = clock.stamp(f64::INFINITY, later + Duration::from_millis(50));
        assert!(inf.is_finite() && inf >= nan, "{inf}");
        assert_eq!(clock.steps_back(), 0);
    }
}
