//! A per-sample gate against spikes: one bad frame, a burst of EMI, a
//! loose connector, a garbage row in a recording. Pure and streaming:
//! samples in, each one kept or refused as a spike, in order.
//!
//! A Hampel filter: a sample is a spike when, on some axis, it lies further
//! than [`THRESHOLD_SIGMAS`] σ from what the window centred on it gives
//! ([`HALF_WINDOW`] samples each side): the median of the window's samples
//! with its local slope (the median step) taken out, so a turn's steady
//! change is no distance. σ is the largest of the stream's noise
//! ([`NoiseFloor`], from the samples kept), the spread of the window's
//! steps about their median (1.4826 MAD / √2: a turn's curvature, a
//! shaking hand), and the smallest step the numbers take. Samples are
//! counted, not timed: a gap in the stream is a step like any other.
//!
//! Only a window centred on the sample tells a spike from the start of a
//! turn: causally both are a jump away from the samples before, and only
//! the samples after show whether it comes back. So a sample is judged at
//! once, against its prediction from the samples before it, and kept when
//! it lies within [`PREDICTION_MARGIN`] times the bound there (nearly every
//! sample of a sensor at rest or turning steadily); one that does not, and
//! each of the first [`HALF_WINDOW`] of a stream, is held until the
//! [`HALF_WINDOW`] samples after it arrive and judged then. A held sample
//! delays those after it, so the order is kept; nothing is held longer
//! than [`HALF_WINDOW`] samples, except at the end of a stream, where
//! [`SpikeGate::finish`] judges what is left on the samples there are.
//!
//! Up to [`HALF_WINDOW`] spikes in a row are refused; a longer change is a
//! step of the field (a magnet placed near, a turn), kept.

use std::collections::VecDeque;

/// Samples each side of the one judged: a burst up to this long is a spike.
pub const HALF_WINDOW: usize = 3;
const WINDOW: usize = 2 * HALF_WINDOW + 1;

/// The bound on a sample's distance from what its window gives, in σ. For
/// Gaussian noise a good sample lies beyond it with a probability of about
/// 1e-8 per axis (its distance from the median of 7 has a standard
/// deviation of about 1.1 σ, so the bound is about 5.5 of those): at 20 Hz
/// on three axes, once in 20 days (and it must first have failed its
/// prediction). A spike smaller than this is within what the fit's own
/// noise absorbs.
pub const THRESHOLD_SIGMAS: f64 = 6.0;

/// A new sample is held for the samples after it when it lies beyond
/// this many times the bound from its prediction: the prediction (the
/// last few samples carried along the slope) has a spread of its own,
/// about 1.9 σ with the sample's noise, where the centred median's is
/// about 1 σ.
pub const PREDICTION_MARGIN: f64 = 2.0;

/// 1.4826 MAD estimates σ of Gaussian noise.
const MAD_TO_SIGMA: f64 = 1.4826;

/// Second differences the noise is measured over: 64, enough for the
/// median to settle within about 15 % (its relative spread is about
/// 1.25/√n), few enough to follow a sensor whose noise changes within a
/// few seconds at 20 Hz.
const NOISE_WINDOW: usize = 64;

/// Second differences the noise must have been measured over before it
/// bounds a sample (before, only what the window's own steps say does).
const MIN_SECOND_DIFFS: usize = 8;

/// The median |Δ²| of Gaussian noise of σ is 0.6745 √6 σ.
const SECOND_DIFF_TO_SIGMA: f64 = 1.0 / (0.674_49 * 2.449_49);

/// A sample refused as a spike: the axis that broke the bound most, in σ.
#[derive(Debug, Clone, PartialEq)]
pub struct Spike {
    /// The axis (0, 1, 2: x, y, and the third).
    pub axis: usize,
    pub value: f64,
    /// What the window centred on it gives at its time, on that axis: the
    /// median of the samples with their local slope taken out.
    pub median: f64,
    /// σ on that axis: the window's spread or the noise, the larger.
    pub sigma: f64,
    /// Samples in the window (fewer than `2 HALF_WINDOW + 1` at the start).
    pub window: usize,
}

impl Spike {
    /// Its distance from the median, in σ.
    pub fn sigmas(&self) -> f64 {
        (self.value - self.median).abs() / self.sigma
    }

    /// The sentence a log line or a message gives.
    pub fn describe(&self, axis_name: &str) -> String {
        if !(self.sigma > 0.0) {
            return format!(
                "{axis_name} = {} where the {} samples around it all give {}",
                crate::numfmt::significant(self.value, 4),
                self.window,
                crate::numfmt::significant(self.median, 4),
            );
        }
        format!(
            "{axis_name} = {} is {:.0} σ from the {} the {} samples around it give (limit {THRESHOLD_SIGMAS} σ, σ = {})",
            crate::numfmt::significant(self.value, 4),
            self.sigmas().min(1e12),
            crate::numfmt::significant(self.median, 4),
            self.window,
            crate::numfmt::significant(self.sigma, 2),
        )
    }
}

/// What the gate decided about one sample, in the order samples came.
#[derive(Debug, Clone, PartialEq)]
pub enum Gated<T> {
    Kept(T),
    Refused(T, Spike),
}

/// The sensor's noise on each axis, measured on the stream itself: the
/// median |second difference| of the last [`NOISE_WINDOW`] samples (a
/// steady turn cancels out of it), floored at the smallest step the
/// numbers take (a quantised sensor at rest reads the same count again).
#[derive(Debug, Clone, Default)]
struct NoiseFloor {
    /// The last two samples.
    last: [Option<[f64; 3]>; 2],
    /// The last |Δ²| per axis.
    second_diffs: [Window; 3],
    /// The smallest non-zero |Δ| seen, per axis.
    quantum: [f64; 3],
}

/// The last [`NOISE_WINDOW`] values of one axis (magnitudes: finite, +0
/// rather than −0), in the order they came, and a value their median is
/// known to be at least, kept as values come and go by two counts (no
/// heap, nothing sorted per value: the gate's inner loop). Nearly every
/// sample is decided on that bound; the median itself (from a sorted copy
/// brought up to date then, or from a selection when it is asked for
/// seldom) decides the rest.
#[derive(Debug, Clone)]
struct Window {
    /// The values as they came, a ring: the oldest at `head` once full.
    ring: [f64; NOISE_WINDOW],
    head: usize,
    len: usize,
    /// The median is at least `floor` while at least [`Window::middle`]
    /// of the values are: `at_least_floor` counts them.
    floor: f64,
    at_least_floor: usize,
    /// When [`Window::middle`] of the values reach `lift`, the floor is
    /// set anew (most often higher): counted by `at_least_lift`.
    lift: f64,
    at_least_lift: usize,
    /// The values ascending, as they were the last time the median was
    /// asked for (when `sorted_is_last`).
    sorted: Sorted,
    /// The `behind` values that came since, each with the one it pushed
    /// out of a full window, up to [`BEHIND_AT_MOST`].
    came: [(f64, Option<f64>); BEHIND_AT_MOST],
    behind: usize,
    /// Whether the sorted copy holds the values of the last time the
    /// median was asked for.
    sorted_is_last: bool,
    /// Times the floor was set (for the tests).
    #[cfg(test)]
    floors_set: usize,
}

impl Default for Window {
    fn default() -> Self {
        Window {
            ring: [0.0; NOISE_WINDOW],
            head: 0,
            len: 0,
            floor: 0.0,
            at_least_floor: 0,
            lift: f64::MIN_POSITIVE,
            at_least_lift: 0,
            sorted: Sorted::default(),
            came: [(0.0, None); BEHIND_AT_MOST],
            behind: 0,
            sorted_is_last: true,
            #[cfg(test)]
            floors_set: 0,
        }
    }
}

/// The fraction of the value a new floor is set at (see
/// [`Window::set_floor`]): the median of Gaussian noise's |Δ²| may fall by
/// about 40 % before the floor is set anew, and the bound it gives a
/// sample is about 0.6 of the noise's: 7 σ, where the prediction's spread
/// is about 1.9 σ.
const FLOOR_OF_MIDDLE: f64 = 0.75;

/// Ranks between the lower middle value and those the floor and the lift
/// are set from: in a full window the counts must move by more than that
/// many values before either is set anew (a quantised axis whose median
/// sits between two counts would otherwise set them at nearly every
/// value); a short one's ranks are clamped to its ends.
const RANKS_APART: usize = 4;

/// Values the sorted copy may fall behind by and still be brought up to
/// date one at a time (a count over the window and a shift each); a
/// median asked for further apart comes from a selection of the window,
/// which costs about as much as a dozen of those.
const BEHIND_AT_MOST: usize = 16;

impl Window {
    /// The values, in no particular order.
    fn values(&self) -> &[f64] {
        &self.ring[..self.len]
    }

    /// The values oldest first.
    #[cfg(test)]
    fn in_order(&self) -> impl Iterator<Item = f64> + '_ {
        let (start, len) = if self.len == NOISE_WINDOW {
            (self.head, NOISE_WINDOW)
        } else {
            (0, self.len)
        };
        (0..len).map(move |i| self.ring[(start + i) % NOISE_WINDOW])
    }

    /// How many of `len` values must be at least a value for their median
    /// to be: those from the lower middle one up (the median is the
    /// middle one, or the mean of the two middle ones).
    fn middle(len: usize) -> usize {
        len - len.saturating_sub(1) / 2
    }

    /// Takes in `value` (a magnitude), the oldest leaving when the window
    /// is full.
    fn push(&mut self, value: f64) {
        let gone = if self.len < NOISE_WINDOW {
            self.ring[self.len] = value;
            self.len += 1;
            None
        } else {
            let gone = std::mem::replace(&mut self.ring[self.head], value);
            self.head = (self.head + 1) % NOISE_WINDOW;
            self.at_least_floor -= usize::from(gone >= self.floor);
            self.at_least_lift -= usize::from(gone >= self.lift);
            Some(gone)
        };
        if let Some(slot) = self.came.get_mut(self.behind) {
            *slot = (value, gone);
        }
        self.behind = self.behind.saturating_add(1);
        self.at_least_floor += usize::from(value >= self.floor);
        self.at_least_lift += usize::from(value >= self.lift);
        let middle = Window::middle(self.len);
        if self.at_least_floor < middle || self.at_least_lift >= middle {
            self.set_floor();
        }
    }

    /// Sets the floor at [`FLOOR_OF_MIDDLE`] of the value [`RANKS_APART`]
    /// ranks below the lower middle one (so it is at most that one, as
    /// are the values above: enough of them), and the lift above the value
    /// as many ranks above it, and at least at twice the floor.
    fn set_floor(&mut self) {
        #[cfg(test)]
        {
            self.floors_set += 1;
        }
        let n = self.len;
        let Some(lower) = n.checked_sub(1).map(|last| last / 2) else {
            return;
        };
        let mut values = [0.0; NOISE_WINDOW];
        let values = &mut values[..n];
        values.copy_from_slice(self.values());
        let (below, above) = (
            lower.saturating_sub(RANKS_APART),
            (lower + RANKS_APART).min(n - 1),
        );
        let (before, &mut high, _) = values.select_nth_unstable_by(above, f64::total_cmp);
        // (`before` holds the `above` values at or below `high`.)
        let low = if below < above {
            *before.select_nth_unstable_by(below, f64::total_cmp).1
        } else {
            high
        };
        self.floor = FLOOR_OF_MIDDLE * low;
        self.lift = (2.0 * self.floor)
            .max(high.next_up())
            .max(f64::MIN_POSITIVE);
        let (floor, lift) = (self.floor, self.lift);
        (self.at_least_floor, self.at_least_lift) =
            self.values().iter().fold((0, 0), |(f, l), &v| {
                (f + usize::from(v >= floor), l + usize::from(v >= lift))
            });
    }

    /// The values' median, None when there are none. Asked for again
    /// within [`BEHIND_AT_MOST`] values, it comes from the sorted copy,
    /// brought up to date (or sorted anew when it is not the window's of
    /// the last time); asked for seldom, from a selection of the values,
    /// and the copy is left as it was.
    fn median(&mut self) -> Option<f64> {
        let all = &self.ring[..self.len];
        let behind = std::mem::take(&mut self.behind);
        if behind > BEHIND_AT_MOST {
            self.sorted_is_last = false;
            let mut values = [0.0; NOISE_WINDOW];
            let values = &mut values[..all.len()];
            values.copy_from_slice(all);
            return median_of(values);
        }
        let caught_up = self.sorted_is_last
            && self.came[..behind]
                .iter()
                .all(|&(value, gone)| self.sorted.replace(value, gone));
        if !caught_up {
            self.sorted.set(all);
        }
        self.sorted_is_last = true;
        sorted_median(self.sorted.values())
    }

    /// A value the median is at least (0 when there are no values).
    fn median_at_least(&self) -> f64 {
        self.floor
    }
}

/// A window's values ascending (no heap: a fixed array).
#[derive(Debug, Clone)]
struct Sorted {
    values: [f64; NOISE_WINDOW],
    len: usize,
}

impl Default for Sorted {
    fn default() -> Self {
        Sorted {
            values: [0.0; NOISE_WINDOW],
            len: 0,
        }
    }
}

impl Sorted {
    fn values(&self) -> &[f64] {
        &self.values[..self.len]
    }

    /// `values`, sorted.
    fn set(&mut self, values: &[f64]) {
        self.len = values.len().min(NOISE_WINDOW);
        self.values[..self.len].copy_from_slice(&values[..self.len]);
        self.values[..self.len].sort_unstable_by(f64::total_cmp);
    }

    /// Takes in `value` for `gone` (None: nothing left, the window was not
    /// full). `false`, changing nothing, when the values cannot be those
    /// of such a window (`gone` not among them, or no room for `value`):
    /// not reached, and the caller sorts the window anew rather than give
    /// a wrong median.
    fn replace(&mut self, value: f64, gone: Option<f64>) -> bool {
        let Some(gone) = gone else {
            // A value that pushes none out comes only to a window not full.
            debug_assert!(
                self.len < NOISE_WINDOW,
                "a full copy took {value} for nothing"
            );
            if self.len == NOISE_WINDOW {
                return false;
            }
            let (at, _) = below(self.values(), value, f64::NAN);
            self.values.copy_within(at..self.len, at + 1);
            self.values[at] = value;
            self.len += 1;
            return true;
        };
        // Where the new value goes in, and where the oldest is: one count
        // of both, over the whole (fixed) window: a value leaves only a
        // full one.
        let sorted = &mut self.values;
        let (at, out) = below(sorted, value, gone);
        let found = self.len == NOISE_WINDOW && sorted.get(out) == Some(&gone);
        // Every value that leaves a full window came in, with the same
        // bits: tests fail here should that ever not hold.
        debug_assert!(found, "{gone} left the noise window but was not in it");
        if !found {
            return false;
        }
        if at <= out {
            // The oldest leaves where the new one comes in: one shift of
            // the values between.
            sorted.copy_within(at..out, at + 1);
            sorted[at] = value;
        } else {
            sorted.copy_within(out + 1..at, out);
            sorted[at - 1] = value;
        }
        true
    }
}

/// How many of the ascending `sorted` lie below `value`, and below
/// `other` (none below NaN): where `value` goes in, and the place of the
/// first value equal to `other`. The values are magnitudes (finite, and +0
/// rather than −0), so `<` orders them as `total_cmp` does. A count over
/// the window's 64 values, not a binary search: no chain of loads that
/// each wait for the one before.
fn below(sorted: &[f64], value: f64, other: f64) -> (usize, usize) {
    sorted.iter().fold((0, 0), |(a, b), &v| {
        (a + usize::from(v < value), b + usize::from(v < other))
    })
}

impl NoiseFloor {
    fn observe(&mut self, raw: [f64; 3]) {
        if let Some(prev) = self.last[1] {
            for axis in 0..3 {
                let step = (raw[axis] - prev[axis]).abs();
                if step > 0.0 && step.is_finite() {
                    let q = &mut self.quantum[axis];
                    *q = if *q > 0.0 { q.min(step) } else { step };
                }
                if let Some(before) = self.last[0] {
                    let d2 = (raw[axis] - 2.0 * prev[axis] + before[axis]).abs();
                    if d2.is_finite() {
                        self.second_diffs[axis].push(d2);
                    }
                }
            }
        }
        self.last = [self.last[1], Some(raw)];
    }

    /// Whether enough is known of `axis`'s noise to bound a sample by it.
    fn known(&self, axis: usize) -> bool {
        self.second_diffs[axis].len >= MIN_SECOND_DIFFS
    }

    /// σ of the noise on `axis`; 0 before anything is known.
    fn sigma(&mut self, axis: usize) -> f64 {
        let measured = self.second_diffs[axis]
            .median()
            .map_or(0.0, |m| m * SECOND_DIFF_TO_SIGMA);
        measured.max(self.quantum[axis])
    }

    /// A value [`NoiseFloor::sigma`] is at least, at once: what the floor
    /// under the median gives (rounding keeps the order of the products).
    fn sigma_at_least(&self, axis: usize) -> f64 {
        (self.second_diffs[axis].median_at_least() * SECOND_DIFF_TO_SIGMA).max(self.quantum[axis])
    }
}

/// Sorts six finite values ascending: a network of 12 compare-exchanges,
/// written out (a loop over the pairs kept each exchange in memory behind
/// an index check: half the time of the gate's causal test). Each takes
/// the lower and the higher by one comparison ([`lower`], [`higher`]):
/// `f64::min` and `max` also pick the number beside a NaN, four times the
/// instructions, and there is none here.
fn sort6(v: &mut [f64; 6]) {
    macro_rules! exchange {
        ($($i:literal $j:literal),*) => {$(
            let (low, high) = (lower(v[$i], v[$j]), higher(v[$i], v[$j]));
            v[$i] = low;
            v[$j] = high;
        )*};
    }
    exchange!(0 5, 1 3, 2 4, 1 2, 3 4, 0 3, 2 5, 0 1, 2 3, 4 5, 1 2, 3 4);
}

/// The lower of two finite values (one `minsd`). Of +0 and −0 either
/// may come: the gate's sums and products of them differ only in a
/// zero's sign, and it decides by comparisons of magnitudes.
fn lower(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}

/// The higher of two finite values (one `maxsd`); see [`lower`].
fn higher(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

/// The middle one of three finite values.
fn median3(a: f64, b: f64, c: f64) -> f64 {
    higher(lower(a, b), lower(higher(a, b), c))
}

/// Values up to which [`median_of`] sorts (a window's).
const SMALL: usize = 2 * WINDOW;

/// The median of values in ascending order (as [`median_of`] gives it),
/// None when empty.
fn sorted_median(sorted: &[f64]) -> Option<f64> {
    let n = sorted.len();
    let upper = *sorted.get(n / 2)?;
    if n % 2 == 1 {
        return Some(upper);
    }
    Some(0.5 * (sorted[n / 2 - 1] + upper))
}

/// The median of `values` (reordered), None when empty.
fn median_of(values: &mut [f64]) -> Option<f64> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    if n <= SMALL {
        // A window's few values: sorted in place, cheaper than selection.
        for i in 1..n {
            let mut j = i;
            while j > 0 && values[j - 1].total_cmp(&values[j]).is_gt() {
                values.swap(j - 1, j);
                j -= 1;
            }
        }
        return sorted_median(values);
    }
    let (_, &mut upper, _) = values.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        return Some(upper);
    }
    let lower = values[..n / 2]
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    Some(0.5 * (lower + upper))
}

/// The last [`WINDOW`] samples, oldest first, in one array (a new one
/// shifts the others down: a few vector moves, where a ring's every look-up
/// works out where its index wraps).
#[derive(Debug, Clone, Default)]
struct Recent {
    samples: [[f64; 3]; WINDOW],
    len: usize,
}

impl Recent {
    fn push(&mut self, raw: [f64; 3]) {
        if self.len == WINDOW {
            self.samples.copy_within(1.., 0);
            self.samples[WINDOW - 1] = raw;
        } else {
            self.samples[self.len] = raw;
            self.len += 1;
        }
    }

    fn as_slice(&self) -> &[[f64; 3]] {
        &self.samples[..self.len]
    }
}

/// The gate of one sensor's stream of samples (`T`: what travels with
/// each; `raw` gives its axes, NaN for one it does not have).
#[derive(Debug, Clone)]
pub struct SpikeGate<T> {
    /// The last samples kept, up to a window, oldest first: the left half
    /// of a centred window, and what a new sample is predicted from.
    kept: Recent,
    /// Samples not yet decided, oldest first (at most `HALF_WINDOW + 1`).
    held: VecDeque<(T, [f64; 3])>,
    /// Whether the oldest held sample broke the bound of its prediction:
    /// only its centred window decides it then.
    suspect: bool,
    /// Decisions not yet taken by [`SpikeGate::decided`].
    out: VecDeque<Gated<T>>,
    noise: NoiseFloor,
    refused: u64,
    scratch: Vec<f64>,
    /// The window being judged (kept here to be reused).
    window: Vec<[f64; 3]>,
}

impl<T> Default for SpikeGate<T> {
    fn default() -> Self {
        SpikeGate {
            kept: Recent::default(),
            held: VecDeque::with_capacity(HALF_WINDOW + 1),
            suspect: false,
            out: VecDeque::with_capacity(HALF_WINDOW + 1),
            noise: NoiseFloor::default(),
            refused: 0,
            scratch: Vec::with_capacity(WINDOW),
            window: Vec::with_capacity(WINDOW + 1),
        }
    }
}

impl<T> SpikeGate<T> {
    /// Spikes refused so far.
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// Feeds one sample; its decision, and those of any held before it it
    /// settles, come out of [`SpikeGate::decided`] in order.
    pub fn feed(&mut self, item: T, raw: [f64; 3]) {
        if let Some(item) = self.feed_at_once(item, raw) {
            self.out.push_back(Gated::Kept(item));
        }
    }

    /// [`SpikeGate::feed`], giving the sample straight back when it is
    /// kept at once: nothing held or waiting in [`SpikeGate::decided`]
    /// before it, and within the bound of its prediction (nearly every
    /// sample). It is then the next decision in order, and queues nothing;
    /// otherwise `None`, and its decision comes out of
    /// [`SpikeGate::decided`] as after [`SpikeGate::feed`].
    pub fn feed_at_once(&mut self, item: T, raw: [f64; 3]) -> Option<T> {
        // What `settle` decides of a lone held sample, without holding it.
        if self.held.is_empty()
            && self.out.is_empty()
            && !self.suspect
            && self.surely_within_prediction(raw)
        {
            self.remember(raw);
            return Some(item);
        }
        self.held.push_back((item, raw));
        self.settle(false);
        None
    }

    /// The stream has ended: what is still held is judged on the samples
    /// there are (a window short on its right).
    pub fn finish(&mut self) {
        self.settle(true);
    }

    /// The next decision, in the order the samples came.
    pub fn decided(&mut self) -> Option<Gated<T>> {
        self.out.pop_front()
    }

    /// Drops the samples held undecided, and the decisions not yet taken
    /// (a new rotation starts: they belong to the one before), keeping
    /// what the gate has learnt of the stream.
    pub fn drop_held(&mut self) {
        self.held.clear();
        self.out.clear();
        self.suspect = false;
    }

    /// A sample kept: the next ones are predicted from it, and the noise
    /// is measured on the samples kept (a spike's own jump never widens
    /// the bound it is judged by).
    fn remember(&mut self, raw: [f64; 3]) {
        self.noise.observe(raw);
        self.kept.push(raw);
    }

    /// Decides what can be decided: the oldest held sample once the
    /// samples after it fill its centred window; each sample within the
    /// bound of its prediction from the samples before it, when nothing is
    /// held before it.
    fn settle(&mut self, ended: bool) {
        while let Some(&(_, raw)) = self.held.front() {
            let mut window = std::mem::take(&mut self.window);
            window.clear();
            let verdict = if self.held.len() > HALF_WINDOW || ended {
                // Centred: the last HALF_WINDOW kept, it, and the
                // HALF_WINDOW after it (fewer at an end).
                let kept = self.kept.as_slice();
                window.extend_from_slice(&kept[kept.len().saturating_sub(HALF_WINDOW)..]);
                let before = window.len();
                window.extend(self.held.iter().take(HALF_WINDOW + 1).map(|(_, r)| *r));
                let all = 0..window.len();
                Ok(self.judge(&window, all.clone(), all, before, None))
            } else if self.suspect || self.kept.len < HALF_WINDOW {
                // Waits for the samples after it (the first ones of a
                // stream have nothing before them to be predicted from).
                Err(())
            } else if self.surely_within_prediction(raw) {
                // Causal: kept at once when within the bound of its
                // prediction; else held for the samples after it.
                Ok(None)
            } else {
                window.extend_from_slice(self.kept.as_slice());
                let at = window.len();
                window.push(raw);
                let prediction = at - HALF_WINDOW..at;
                match self.judge(&window, 0..at, prediction, at, Some(PREDICTION_MARGIN)) {
                    None => Ok(None),
                    Some(_) => Err(()),
                }
            };
            self.window = window;
            let Ok(verdict) = verdict else {
                self.suspect = true;
                return;
            };
            self.suspect = false;
            let Some((item, raw)) = self.held.pop_front() else {
                return;
            };
            match verdict {
                None => {
                    self.remember(raw);
                    self.out.push_back(Gated::Kept(item));
                }
                Some(spike) => {
                    self.refused = self.refused.saturating_add(1);
                    self.out.push_back(Gated::Refused(item, spike));
                }
            }
        }
    }

    /// Whether `raw`, the next sample, lies within the bound of its causal
    /// prediction on every axis: what [`SpikeGate::judge`] decides from a
    /// full window of kept samples, computed without its scratch copies
    /// (the medians of six steps and of three values by sorting networks,
    /// the same values a sort gives). `false`: not decided here (a window
    /// not yet full, an axis whose noise is not yet known, a value that is
    /// not finite, or a sample beyond its bound): judge it.
    fn surely_within_prediction(&mut self, raw: [f64; 3]) -> bool {
        let Ok(kept) = <&[[f64; 3]; WINDOW]>::try_from(self.kept.as_slice()) else {
            return false;
        };
        let at = WINDOW as f64;
        for (axis, &value) in raw.iter().enumerate() {
            if !value.is_finite() {
                continue;
            }
            if !self.noise.known(axis) {
                return false;
            }
            let k: [f64; WINDOW] = std::array::from_fn(|i| kept[i][axis]);
            let mut steps: [f64; WINDOW - 1] = std::array::from_fn(|i| k[i + 1] - k[i]);
            if !steps.iter().all(|d| d.is_finite()) {
                return false;
            }
            sort6(&mut steps);
            let slope = 0.5 * (steps[2] + steps[3]);
            let [a, b, c] = [4, 5, 6].map(|j| k[j] - (j as f64 - at) * slope);
            // (`judge` leaves out a value that is not finite.)
            if ![a, b, c].iter().all(|v| v.is_finite()) {
                return false;
            }
            let off = (value - median3(a, b, c)).abs();
            let within = |sigma: f64| off <= THRESHOLD_SIGMAS * PREDICTION_MARGIN * sigma;
            // The bound under σ decides nearly every sample; σ itself the
            // rest (a sample within the first is within the second).
            if !(within(self.noise.sigma_at_least(axis)) || within(self.noise.sigma(axis))) {
                return false;
            }
        }
        true
    }

    /// Whether the sample of `window` at `at` breaks its bound on some
    /// axis: the axis it breaks most, in σ. The slope is the median step
    /// between the samples of `steps`; the reference, the median of the
    /// samples of `reference` carried along that slope to `at`, so a
    /// turn's steady change is no distance, and a spike in the window moves
    /// neither. σ is the largest of the stream's noise, the spread of the
    /// steps about their median (a turn's curvature, a shaking hand: for a
    /// centred window, `margin` 1), and the smallest step the numbers
    /// take; the bound is [`THRESHOLD_SIGMAS`] σ, times the prediction's
    /// `margin` when it is one.
    fn judge(
        &mut self,
        window: &[[f64; 3]],
        steps: std::ops::Range<usize>,
        reference: std::ops::Range<usize>,
        at: usize,
        prediction: Option<f64>,
    ) -> Option<Spike> {
        let mut worst: Option<Spike> = None;
        for axis in 0..3 {
            let value = window[at][axis];
            if !value.is_finite() {
                continue;
            }
            let floor = self.noise.sigma(axis);
            // The steps between the samples used (not into the one judged
            // causally: it is the one in question).
            self.scratch.clear();
            self.scratch.extend(
                window[steps.clone()]
                    .windows(2)
                    .map(|w| w[1][axis] - w[0][axis])
                    .filter(|d| d.is_finite()),
            );
            let slope = median_of(&mut self.scratch).unwrap_or(0.0);
            // A prediction from a few steps is judged against the stream's
            // noise alone (their spread is too uncertain to widen a bound
            // that only decides whether to wait for the samples after).
            let known = self.noise.known(axis);
            let (local, margin) = match prediction {
                None => {
                    for d in &mut self.scratch {
                        *d = (*d - slope).abs();
                    }
                    let step_spread = median_of(&mut self.scratch).unwrap_or(0.0);
                    (MAD_TO_SIGMA * step_spread / std::f64::consts::SQRT_2, 1.0)
                }
                Some(margin) => (0.0, margin),
            };
            // Nothing known of the noise yet (the first samples of a
            // stream): only what the steps themselves say bounds a sample,
            // so only a gross spike is refused there.
            let first_steps = if known {
                0.0
            } else {
                self.scratch.clear();
                self.scratch.extend(
                    window[steps.clone()]
                        .windows(2)
                        .map(|w| (w[1][axis] - w[0][axis]).abs())
                        .filter(|d| d.is_finite()),
                );
                MAD_TO_SIGMA * median_of(&mut self.scratch).unwrap_or(0.0)
                    / std::f64::consts::SQRT_2
            };
            let sigma = floor.max(local).max(first_steps);
            if !known && !(sigma > 0.0) {
                continue;
            }
            self.scratch.clear();
            self.scratch.extend(
                window[reference.clone()]
                    .iter()
                    .zip(reference.clone())
                    .map(|(r, j)| r[axis] - (j as f64 - at as f64) * slope)
                    .filter(|v| v.is_finite()),
            );
            let Some(reference) = median_of(&mut self.scratch) else {
                continue;
            };
            let n = self.scratch.len();
            let off = (value - reference).abs();
            // σ 0: the samples around it do not vary at all, and any
            // difference from them is beyond the bound.
            if off <= THRESHOLD_SIGMAS * margin * sigma {
                continue;
            }
            let spike = Spike {
                axis,
                value,
                median: reference,
                sigma,
                window: n,
            };
            if worst.as_ref().is_none_or(|w| spike.sigmas() > w.sigmas()) {
                worst = Some(spike);
            }
        }
        worst
    }
}

/// The rows of a whole recording the gate refuses, ascending, each with
/// why: the daemon's gate run over it, the last rows judged on the
/// samples before them ([`SpikeGate::finish`]).
pub fn refused_rows(points: impl IntoIterator<Item = [f64; 3]>) -> Vec<(usize, Spike)> {
    let mut gate = SpikeGate::default();
    let mut refused = Vec::new();
    for (i, raw) in points.into_iter().enumerate() {
        if gate.feed_at_once(i, raw).is_some() {
            continue;
        }
        while let Some(decided) = gate.decided() {
            if let Gated::Refused(i, spike) = decided {
                refused.push((i, spike));
            }
        }
    }
    gate.finish();
    while let Some(decided) = gate.decided() {
        if let Gated::Refused(i, spike) = decided {
            refused.push((i, spike));
        }
    }
    refused
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feeds every sample, returns the indices refused and the order kept.
    fn run(samples: &[[f64; 3]]) -> (Vec<usize>, Vec<usize>) {
        let mut gate = SpikeGate::default();
        let (mut refused, mut kept) = (Vec::new(), Vec::new());
        for (i, &raw) in samples.iter().enumerate() {
            gate.feed(i, raw);
            while let Some(g) = gate.decided() {
                match g {
                    Gated::Kept(i) => kept.push(i),
                    Gated::Refused(i, _) => refused.push(i),
                }
            }
        }
        (refused, kept)
    }

    /// A turn at `deg_per_sample`, radius 1000 counts, rounded to counts,
    /// with a deterministic ±2-count jitter.
    fn turn(n: usize, deg_per_sample: f64) -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| {
                let h = (i as f64 * deg_per_sample).to_radians();
                let jitter = ((i * 7919) % 5) as f64 - 2.0;
                [
                    (300.0 + 1000.0 * h.cos() + jitter).round(),
                    (-200.0 + 1000.0 * h.sin() - jitter).round(),
                    f64::NAN,
                ]
            })
            .collect()
    }

    #[test]
    fn single_spikes_and_short_bursts_are_refused_and_the_rest_kept_in_order() {
        let mut samples = turn(400, 1.8);
        samples[100][0] = 65535.0;
        samples[200][1] = -4096.0;
        for s in &mut samples[300..303] {
            s[0] = 5000.0;
        }
        let (refused, kept) = run(&samples);
        assert_eq!(refused, vec![100, 200, 300, 301, 302]);
        // Every other sample is kept, in order (the last HALF_WINDOW may
        // still be held).
        assert!(kept.windows(2).all(|w| w[0] < w[1]));
        assert!(
            kept.len() + refused.len() >= 400 - HALF_WINDOW,
            "{}",
            kept.len()
        );
    }

    #[test]
    fn a_turn_that_starts_or_stops_at_once_and_a_step_of_the_field_are_kept() {
        // At rest, then at once 18° per sample (360°/s at 20 Hz), then at
        // rest again; then the field steps by 30 % and stays.
        let mut samples = vec![[1300.0, -200.0, f64::NAN]; 50];
        samples.extend(turn(40, 18.0).into_iter().skip(1));
        let last = *samples.last().unwrap();
        samples.extend(std::iter::repeat_n(last, 50));
        samples.extend(std::iter::repeat_n(
            [last[0] + 300.0, last[1], f64::NAN],
            50,
        ));
        let (refused, kept) = run(&samples);
        assert!(refused.is_empty(), "{refused:?}");
        assert!(kept.len() >= samples.len() - HALF_WINDOW, "{}", kept.len());
        assert!(kept.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn gaussian_noise_at_rest_and_turning_is_never_refused() {
        let mut normal = normals(0x2545_f491_4f6c_dd1d);
        let samples: Vec<[f64; 3]> = (0..100_000)
            .map(|i| {
                // Turning at 0.5° a sample, then at 9°.
                let h = (i as f64 * if i < 50_000 { 0.5 } else { 9.0 }).to_radians();
                [
                    50.0 * h.cos() + 0.5 * normal(),
                    50.0 * h.sin() + 0.5 * normal(),
                    20.0 + 0.5 * normal(),
                ]
            })
            .collect();
        let (refused, _) = run(&samples);
        assert!(refused.is_empty(), "{refused:?}");
    }

    /// A deterministic normal generator (Box-Muller on an LCG).
    fn normals(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            let mut uniform = || {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (u, v) = (uniform(), uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        }
    }

    #[test]
    fn spikes_of_twenty_noise_sds_are_refused_while_turning_fast_or_slowly() {
        // Radius 1000 counts, noise 2; 0.9° a sample (a turn in 4 s at
        // 100 Hz): a spike of 20 to 50 noise SDs on one axis every 37
        // samples. At 4.5° a sample (a turn in 4 s at 20 Hz) the turn's
        // curvature (6 counts a step) widens σ: spikes of 20 to 50 times
        // 6 counts. Smaller ones there are within what the local line
        // through the window can tell from the turn.
        for (step_deg, sd) in [(0.9, 2.0), (4.5, 6.0)] {
            let mut normal = normals(7);
            let mut samples: Vec<[f64; 3]> = (0..4000)
                .map(|i| {
                    let h = (i as f64 * step_deg).to_radians();
                    [
                        150.0 + 1100.0 * h.cos() + 2.0 * normal(),
                        -80.0 + 1000.0 * h.sin() + 2.0 * normal(),
                        f64::NAN,
                    ]
                })
                .collect();
            let mut spoilt = Vec::new();
            for i in (20..4000).step_by(37) {
                let size = sd * (20.0 + (i % 31) as f64);
                let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                samples[i][i % 2] += sign * size;
                spoilt.push(i);
            }
            let (refused, kept) = run(&samples);
            assert_eq!(refused, spoilt, "{step_deg}° a sample");
            assert!(kept.len() + refused.len() >= 4000 - HALF_WINDOW);
        }
    }

    #[test]
    fn spikes_at_either_end_and_on_a_constant_axis_are_refused() {
        // A garbage first row (a partial line as logging starts), a
        // garbage last row (a torn tail), and a spike on an axis that
        // otherwise never changes (the field across a flat turn).
        let mut samples = turn(200, 1.8);
        for s in &mut samples {
            s[2] = 250.0;
        }
        samples[0][0] = 65535.0;
        samples[199][1] = -4096.0;
        samples[120][2] = 4000.0;
        let refused: Vec<usize> = refused_rows(samples.iter().copied())
            .into_iter()
            .map(|(i, _)| i)
            .collect();
        assert_eq!(refused, vec![0, 120, 199]);
        // The constant axis's spike is said without a σ of 0.
        let (_, spike) = refused_rows(samples.iter().copied())
            .into_iter()
            .find(|(i, _)| *i == 120)
            .unwrap();
        assert_eq!(
            spike.describe("z"),
            "z = 4000 where the 7 samples around it all give 250.0"
        );
    }

    #[test]
    fn nothing_waits_longer_than_half_a_window_and_held_samples_can_be_dropped() {
        let mut gate = SpikeGate::default();
        for i in 0..20 {
            gate.feed(i, [f64::from(i % 2), 0.0, f64::NAN]);
        }
        let mut decided = 0;
        while gate.decided().is_some() {
            decided += 1;
        }
        assert!(decided >= 20 - HALF_WINDOW);
        gate.feed(20, [1e9, 0.0, f64::NAN]);
        gate.drop_held();
        gate.feed(21, [0.0, 0.0, f64::NAN]);
        assert!(matches!(gate.decided(), Some(Gated::Kept(21))));
        // Decisions not yet taken go with a restart too.
        gate.feed(22, [1.0, 0.0, f64::NAN]);
        gate.drop_held();
        assert!(gate.decided().is_none());
    }

    /// Checks `floor`'s windows against the last [`NOISE_WINDOW`] |Δ²| of
    /// `fed` (the samples it observed): their order, the floor at most
    /// their median, and (`ask`) the median to the bit and the sorted copy.
    fn check_noise_floor(floor: &mut NoiseFloor, fed: &[[f64; 3]], ask: bool, at: &str) {
        for axis in 0..3 {
            // The last NOISE_WINDOW second differences need the last
            // NOISE_WINDOW + 2 samples.
            let from = fed.len().saturating_sub(NOISE_WINDOW + 2);
            let mut window: Vec<f64> = fed[from..]
                .windows(3)
                .map(|w| (w[2][axis] - 2.0 * w[1][axis] + w[0][axis]).abs())
                .collect();
            let held: Vec<f64> = floor.second_diffs[axis].in_order().collect();
            assert_eq!(held, window, "{at}, axis {axis}");
            window.sort_unstable_by(f64::total_cmp);
            let expected = sorted_median(&window);
            let under = floor.second_diffs[axis].median_at_least();
            assert!(
                under <= expected.unwrap_or(0.0),
                "{at}, axis {axis}: floor {under} above the median {expected:?}"
            );
            if ask {
                let behind = floor.second_diffs[axis].behind;
                let found = floor.second_diffs[axis].median();
                assert_eq!(
                    found.map(f64::to_bits),
                    expected.map(f64::to_bits),
                    "{at}, axis {axis}"
                );
                // The copy is kept only when asked for often.
                let kept = &floor.second_diffs[axis];
                assert_eq!(kept.sorted_is_last, behind <= BEHIND_AT_MOST, "{at}");
                if kept.sorted_is_last {
                    assert_eq!(kept.sorted.values(), &window[..], "{at}, axis {axis}");
                }
                // (On a clone: σ asks for the median again.)
                assert!(floor.sigma_at_least(axis) <= floor.clone().sigma(axis));
            }
        }
    }

    /// The noise window holds the last [`NOISE_WINDOW`] |Δ²| of each axis
    /// (counted here from the samples fed), in order; its median is
    /// theirs to the bit, asked for after every value or only after
    /// several (from its sorted copy, brought up to date one value at a
    /// time or sorted anew, or from a selection), and its floor is never
    /// above it, as values come and
    /// go (repeats, a quantised axis, a constant stretch and a noise that
    /// grows and shrinks tenfold among them).
    #[test]
    fn the_noise_floor_keeps_its_window_and_a_floor_under_its_median() {
        let mut noise = normals(7);
        let mut floor = NoiseFloor::default();
        let mut fed: Vec<[f64; 3]> = Vec::new();
        for i in 0..6000 {
            let x = noise() * if (i / 700) % 2 == 0 { 3.0 } else { 30.0 };
            let quantised = (x * 0.5).round();
            let constant = if i % 500 < 200 { 1.0 } else { x };
            floor.observe([x, quantised, constant]);
            fed.push([x, quantised, constant]);
            // The median asked for after every value, or after more than
            // the sorted copy keeps up with one by one.
            let every = [5, BEHIND_AT_MOST + 1, 2, 40, BEHIND_AT_MOST, 1][(i / 1000) % 6];
            check_noise_floor(&mut floor, &fed, i % every == 0, &format!("sample {i}"));
        }
        // The floor follows the noise down and up, and is not set anew at
        // every value (then it would save nothing).
        for (axis, window) in floor.second_diffs.iter().enumerate() {
            assert!(
                (8..300).contains(&window.floors_set),
                "axis {axis}: the floor was set {} times",
                window.floors_set
            );
        }
        // A window still filling, its median first asked for after 1 to
        // 40 samples, and then every so many: the copy takes in values
        // that push none out, one by one or sorted anew, after a selection
        // or not.
        for first in [1, 3, 17, 30, 40] {
            for every in [1, 4, 16, 17, 23] {
                let mut floor = NoiseFloor::default();
                let mut fed: Vec<[f64; 3]> = Vec::new();
                for i in 0..150 {
                    let x = noise();
                    floor.observe([x, x.round(), 1.0]);
                    fed.push([x, x.round(), 1.0]);
                    let ask = i + 1 >= first && (i + 1 - first) % every == 0;
                    check_noise_floor(&mut floor, &fed, ask, &format!("{first}/{every}: {i}"));
                }
            }
        }
    }

    /// A quantised axis whose median |Δ²| sits between two counts (half
    /// its second differences 0) does not set its floor anew at every
    /// value.
    #[test]
    fn a_median_between_two_counts_keeps_its_floor() {
        let mut noise = normals(3);
        let mut floor = NoiseFloor::default();
        for _ in 0..5000 {
            let x = (0.4 * noise()).round();
            floor.observe([x, 0.0, 0.0]);
        }
        let set = floor.second_diffs[0].floors_set;
        assert!(set < 50, "the floor was set {set} times in 5000 values");
    }

    /// The network sorts every order of six values (0-1 principle: every
    /// 0/1 input, and random ones), and the median of three is the middle.
    #[test]
    fn the_sorting_networks_sort() {
        for bits in 0u32..64 {
            let mut v: [f64; 6] = std::array::from_fn(|i| f64::from((bits >> i) & 1));
            sort6(&mut v);
            assert!(v.windows(2).all(|w| w[0] <= w[1]), "{bits:06b}: {v:?}");
        }
        let mut noise = normals(3);
        for _ in 0..1000 {
            let mut v: [f64; 6] = std::array::from_fn(|_| noise());
            let mut sorted = v;
            sorted.sort_unstable_by(f64::total_cmp);
            sort6(&mut v);
            assert_eq!(v, sorted);
            let [a, b, c] = [noise(), noise(), noise()];
            let mut three = [a, b, c];
            assert_eq!(median3(a, b, c), median_of(&mut three).unwrap_or(f64::NAN));
        }
    }

    /// Whatever the sorting networks keep at once, the full judgement
    /// keeps too: the same decision on every sample of turns fast and
    /// slow, at rest, quantised, with spikes and steps.
    #[test]
    fn the_quick_causal_check_keeps_only_what_the_judgement_keeps() {
        let mut noise = normals(11);
        let (mut quick, mut agreed) = (0, 0);
        for (case, deg) in [0.0, 0.5, 4.0, 15.0].into_iter().enumerate() {
            let mut gate: SpikeGate<usize> = SpikeGate::default();
            for (i, mut raw) in turn(3000, deg).into_iter().enumerate() {
                for v in raw.iter_mut().take(2) {
                    *v += noise() * 2.0;
                    if case == 3 {
                        *v = v.round();
                    }
                }
                if i % 97 == 0 {
                    raw[i % 2] += 400.0;
                }
                if i == 1500 {
                    raw[1] += 50.0;
                }
                if gate.held.is_empty() && !gate.suspect && gate.kept.len == WINDOW {
                    let mut window: Vec<[f64; 3]> = gate.kept.as_slice().to_vec();
                    let at = window.len();
                    window.push(raw);
                    let prediction = at - HALF_WINDOW..at;
                    let judged =
                        gate.judge(&window, 0..at, prediction, at, Some(PREDICTION_MARGIN));
                    if gate.surely_within_prediction(raw) {
                        quick += 1;
                        assert!(judged.is_none(), "case {case}, sample {i}: {judged:?}");
                    } else {
                        agreed += usize::from(judged.is_some());
                    }
                }
                gate.feed(i, raw);
                while gate.decided().is_some() {}
            }
        }
        // Nearly every sample is decided quickly; the rest are what the
        // judgement holds.
        assert!(quick > 6_000, "{quick}");
        assert!(agreed > 100, "{agreed}");
    }

    #[test]
    fn samples_kept_at_once_come_in_order_with_the_others() {
        // Spikes and bursts in a noisy turn; decisions taken after every
        // sample, or only every few (so that some wait in the queue when
        // the next is fed).
        let mut noise = normals(11);
        let samples: Vec<[f64; 3]> = turn(4000, 1.5)
            .into_iter()
            .enumerate()
            .map(|(i, mut raw)| {
                raw[0] += 2.0 * noise();
                if i % 53 < 1 + i % 3 {
                    raw[i % 2] += 500.0;
                }
                raw
            })
            .collect();
        // Every sample held and settled, as the gate did before it kept
        // any at once; or by `feed`.
        let by_feed = |every: usize, held: bool| {
            let mut gate = SpikeGate::default();
            let mut order = Vec::new();
            for (i, &raw) in samples.iter().enumerate() {
                if held {
                    gate.held.push_back((i, raw));
                    gate.settle(false);
                } else {
                    gate.feed(i, raw);
                }
                if i % every == 0 {
                    while let Some(g) = gate.decided() {
                        order.push(g);
                    }
                }
            }
            gate.finish();
            order.extend(std::iter::from_fn(|| gate.decided()));
            order
        };
        let want = by_feed(1, true);
        assert!(
            want.iter()
                .filter(|g| matches!(g, Gated::Refused(..)))
                .count()
                > 100
        );
        for every in [1, 2, 5] {
            assert_eq!(by_feed(every, false), want, "decided every {every}");
            let mut gate = SpikeGate::default();
            let (mut order, mut at_once) = (Vec::new(), 0);
            for (i, &raw) in samples.iter().enumerate() {
                if let Some(i) = gate.feed_at_once(i, raw) {
                    order.push(Gated::Kept(i));
                    at_once += 1;
                }
                if i % every == 0 {
                    order.extend(std::iter::from_fn(|| gate.decided()));
                }
            }
            gate.finish();
            order.extend(std::iter::from_fn(|| gate.decided()));
            assert_eq!(order, want, "decided every {every}");
            assert!(at_once > 3000, "{at_once}");
        }
    }
}
