//! The time a live source stamps on its readings: the host's Unix clock,
//! except that it never goes back.
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
//! the last stamp plus the monotonic time since it; then the stamps go on
//! from the last at a rate 500 ppm slower than the monotonic clock (as
//! `adjtime` slews), until the wall clock catches up with them: never
//! back, never faster than real time, back on the wall clock after a step
//! of `s` seconds in `s / 0.0005` (a 0.2 s step in under 7 minutes, an
//! hour's in 83 days; a restart puts the stamps on the wall clock at once).

use std::time::Instant;

/// How much slower than the monotonic clock stamps run while they are
/// ahead of a wall clock that stepped back: `adjtime`'s largest slew,
/// 500 ppm.
pub const SLEW: f64 = 0.0005;

/// A step back smaller than this is not worth a warning (a slewing
/// clock's jitter); larger ones are logged once each.
const WARN_STEP_S: f64 = 0.1;

/// The stamps of one live source.
#[derive(Debug, Default)]
pub struct LiveClock {
    /// The last stamp and the monotonic instant it was made at.
    last: Option<(f64, Instant)>,
    /// Whether the stamps are ahead of the wall clock (slewing back to it).
    ahead: bool,
}

impl LiveClock {
    pub fn new() -> Self {
        LiveClock::default()
    }

    /// The stamp for a reading that arrives now.
    pub fn now(&mut self) -> f64 {
        self.stamp(super::serial::unix_now(), Instant::now())
    }

    /// The stamp for a reading that arrived at monotonic instant `at` while
    /// the wall clock read `wall` (seconds since the Unix epoch).
    pub fn stamp(&mut self, wall: f64, at: Instant) -> f64 {
        let time = match self.last {
            Some((last, then)) => {
                let elapsed = at.saturating_duration_since(then).as_secs_f64();
                let slewed = last + elapsed * (1.0 - SLEW);
                if wall >= slewed {
                    self.ahead = false;
                    wall
                } else {
                    let behind = last + elapsed - wall;
                    if !self.ahead && behind > WARN_STEP_S {
                        tracing::warn!(
                            "the wall clock went back by {behind:.3} s: readings keep their order, stamped on from the last and slewed back to the wall clock at 500 ppm ({:.0} s); restart the daemon to put them on the wall clock at once",
                            behind / SLEW
                        );
                    }
                    self.ahead = true;
                    slewed
                }
            }
            None => wall,
        };
        self.last = Some((time, at));
        time
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    const T0: f64 = 1_700_000_000.0;

    /// Stamps for reads 50 ms apart on the monotonic clock, with the wall
    /// clock `wall(i)` at read `i`.
    fn stamps(n: u32, wall: impl Fn(u32) -> f64) -> Vec<f64> {
        let start = Instant::now();
        let mut clock = LiveClock::new();
        (0..n)
            .map(|i| clock.stamp(wall(i), start + Duration::from_millis(50 * u64::from(i))))
            .collect()
    }

    #[test]
    fn a_steady_wall_clock_is_followed_exactly() {
        let times = stamps(100, |i| T0 + 0.05 * f64::from(i));
        for (i, t) in times.iter().enumerate() {
            assert_eq!(*t, T0 + 0.05 * i as f64);
        }
    }

    #[test]
    fn a_wall_clock_stepped_forward_is_followed() {
        let times = stamps(10, |i| {
            T0 + 0.05 * f64::from(i) + if i >= 5 { 3600.0 } else { 0.0 }
        });
        assert_eq!(times[4], T0 + 0.2);
        assert_eq!(times[5], T0 + 0.25 + 3600.0);
    }

    #[test]
    fn a_wall_clock_stepped_back_an_hour_never_sends_the_stamps_back() {
        let wall = |i: u32| T0 + 0.05 * f64::from(i) - if i >= 5 { 3600.0 } else { 0.0 };
        let times = stamps(2000, wall);
        for pair in times.windows(2) {
            let step = pair[1] - pair[0];
            // 50 ms apart, 500 ppm slower: never back, never faster (to
            // within a stamp's rounding, 2.4e-7 s at this epoch).
            assert!(
                step > 0.05 * (1.0 - SLEW) - 1e-6 && step <= 0.05 + 1e-6,
                "{step}"
            );
        }
        // Still ahead of the wall clock by about the hour, slewing back.
        let last = times[1999];
        let ahead = last - wall(1999);
        let slewed = 0.05 * 1995.0 * SLEW;
        assert!((ahead - (3600.0 - slewed)).abs() < 1e-3, "{ahead}");
    }

    #[test]
    fn a_small_step_back_is_slewed_out_and_the_wall_clock_followed_again() {
        // 0.2 s back at read 5: 400 s of slewing at 500 ppm.
        let wall = |i: u32| T0 + 0.05 * f64::from(i) - if i >= 5 { 0.2 } else { 0.0 };
        let times = stamps(10_000, wall);
        assert!(times.windows(2).all(|p| p[1] > p[0]));
        // After 0.2 / 0.0005 = 400 s (8,000 reads) the wall clock again.
        assert!(
            times[8_010] == wall(8_010),
            "{} {}",
            times[8_010],
            wall(8_010)
        );
        assert!(times[7_900] > wall(7_900));
    }
}
