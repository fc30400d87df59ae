//! Where on the circle the samples lie: the coverage of a turn.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::FitError;

/// How much of the circle of headings a set of samples covers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Coverage {
    /// 360° less the largest gap between neighbouring headings.
    pub covered_deg: f64,
    /// The largest gap between neighbouring headings, in degrees.
    pub largest_gap_deg: f64,
    /// Where that gap starts (heading in [0, 360), counter-clockwise).
    pub gap_start_deg: f64,
}

impl Coverage {
    /// Checks the coverage against what a fit needs.
    pub fn require(&self, needed_deg: f64) -> Result<(), FitError> {
        if self.covered_deg + 1e-9 >= needed_deg {
            Ok(())
        } else {
            Err(FitError::InsufficientCoverage {
                found_deg: self.covered_deg,
                needed_deg,
                gap_deg: self.largest_gap_deg,
                gap_start_deg: self.gap_start_deg,
            })
        }
    }
}

/// Coverage of a set of headings given in radians (any range).
pub fn coverage(headings: impl IntoIterator<Item = f64>) -> Coverage {
    let mut deg: Vec<f64> = headings
        .into_iter()
        .map(|h| wrap_degrees(h.to_degrees()))
        .filter(|h| h.is_finite())
        .collect();
    if deg.is_empty() {
        return Coverage {
            covered_deg: 0.0,
            largest_gap_deg: 360.0,
            gap_start_deg: 0.0,
        };
    }
    let largest = largest_gap_by_few_buckets(&deg)
        .or_else(|| largest_gap_by_buckets(&deg))
        .unwrap_or_else(|| largest_gap_by_sorting(&mut deg));
    Coverage {
        covered_deg: 360.0 - largest.0,
        largest_gap_deg: largest.0,
        gap_start_deg: largest.1,
    }
}

/// `deg.rem_euclid(360.0)`, the same to the bit, without the library's
/// `fmod` (a loop over the bits of the quotient) below 2⁵² degrees:
/// - within a turn of zero (an `atan2` in degrees) the remainder is the
///   angle itself, exactly; from one turn to two it is `deg − 360`, also
///   exact (the two are within a factor of two of each other);
/// - beyond (an angle followed over many turns) by one division: see
///   [`wrap_by_division`].
pub fn wrap_degrees(deg: f64) -> f64 {
    if deg.abs() < 360.0 {
        if deg < 0.0 { deg + 360.0 } else { deg }
    } else if (360.0..720.0).contains(&deg) {
        deg - 360.0
    } else if deg.abs() < DIVIDED_BELOW {
        wrap_by_division(deg)
    } else {
        deg.rem_euclid(360.0)
    }
}

/// Magnitudes up to which [`wrap_by_division`] is exact: 2⁵².
const DIVIDED_BELOW: f64 = 4_503_599_627_370_496.0;

/// The remainder of `deg` (at least 360 and below 2⁵² in magnitude) by
/// 360 in [0, 360), exact as `fmod`'s: with q = ⌊deg / 360⌋ (below 2⁴⁴ in
/// magnitude), q·360 is exact, and deg − q·360 is exact too (the two lie
/// within a factor of two of each other, deg being a turn or more from
/// zero). Where the quotient rounds up to the next whole number q is one
/// too many and the difference falls below zero by less than a turn;
/// adding 360 is then exact, the remainder being a multiple of deg's ulp
/// below 512. A zero remainder keeps deg's sign, as `fmod`'s does.
fn wrap_by_division(deg: f64) -> f64 {
    let q = (deg / 360.0).floor();
    let r = deg - q * 360.0;
    if r == 0.0 {
        0.0f64.copysign(deg)
    } else if r < 0.0 {
        r + 360.0
    } else {
        r
    }
}

/// The smallest and the largest of `deg` (by `total_cmp`), in one pass.
fn lowest_and_highest(deg: &[f64]) -> Option<(f64, f64)> {
    let first = *deg.first()?;
    Some(deg.iter().fold((first, first), |(lo, hi), &h| {
        (
            if h.total_cmp(&lo).is_lt() { h } else { lo },
            if h.total_cmp(&hi).is_gt() { h } else { hi },
        )
    }))
}

/// Buckets of the first try: 2¹¹, whose smallest and largest (32 KiB)
/// stay in the first-level cache while the headings are put in them in one pass.
const FEW_BUCKETS: usize = 1 << 11;

/// [`largest_gap_by_buckets`] with at most [`FEW_BUCKETS`] buckets: the
/// same rule (a bucket's span below the largest gap between buckets
/// decides it, the same result to the bit) in one pass over the headings,
/// for any number of them. A turn's largest gap, a degree or more, is
/// several times a bucket's 0.18°; headings so dense that it is not are left to
/// the bucket per heading (`None`).
fn largest_gap_by_few_buckets(deg: &[f64]) -> Option<(f64, f64)> {
    let n = deg.len();
    if n < BUCKETS_FROM {
        return None;
    }
    let buckets = n.min(FEW_BUCKETS);
    let (lo, hi) = lowest_and_highest(deg)?;
    let per_degree = (buckets - 1) as f64 / (hi - lo);
    if !(per_degree.is_finite() && per_degree > 0.0) {
        return None;
    }
    // Smallest and largest heading of each bucket (NaN: empty).
    let mut bucket = vec![[f64::NAN; 2]; buckets];
    for &h in deg {
        widen(
            &mut bucket[(((h - lo) * per_degree) as usize).min(buckets - 1)],
            h,
        );
    }
    let mut walk = GapWalk::new(lo, hi);
    walk.along(&bucket);
    walk.decided()
}

/// Widens `bucket` (its smallest and largest heading; NaN: empty) to hold `h`.
fn widen(bucket: &mut [f64; 2], h: f64) {
    if bucket[0].is_nan() {
        *bucket = [h, h];
    } else if h.total_cmp(&bucket[0]).is_lt() {
        bucket[0] = h;
    } else if h.total_cmp(&bucket[1]).is_gt() {
        bucket[1] = h;
    }
}

/// The buckets of headings in order, walked for the largest gap between
/// neighbouring ones (from the wrap-around gap) and the widest bucket.
struct GapWalk {
    largest: (f64, f64),
    widest_bucket: f64,
    previous_top: Option<f64>,
}

impl GapWalk {
    /// Before the first bucket: the gap from the highest heading `hi` round
    /// to the lowest `lo`.
    fn new(lo: f64, hi: f64) -> GapWalk {
        GapWalk {
            largest: (lo + 360.0 - hi, hi),
            widest_bucket: 0.0,
            previous_top: None,
        }
    }

    /// The next buckets in order (NaN: empty, skipped).
    fn along(&mut self, buckets: &[[f64; 2]]) {
        for b in buckets.iter().filter(|b| !b[0].is_nan()) {
            if let Some(top) = self.previous_top {
                let gap = b[0] - top;
                if gap > self.largest.0 {
                    self.largest = (gap, top);
                }
            }
            self.widest_bucket = self.widest_bucket.max(b[1] - b[0]);
            self.previous_top = Some(b[1]);
        }
    }

    /// The largest gap and where it starts, when no bucket is as wide.
    fn decided(&self) -> Option<(f64, f64)> {
        (self.widest_bucket < self.largest.0).then_some(self.largest)
    }
}

/// The largest gap between neighbouring headings (degrees in [0, 360],
/// at least one) and the heading it starts at: the wrap-around gap from
/// the last heading back to the first, unless a gap between neighbours is
/// larger (the first such, in order of heading).
fn largest_gap_by_sorting(deg: &mut [f64]) -> (f64, f64) {
    deg.sort_unstable_by(f64::total_cmp);
    let last = deg[deg.len() - 1];
    let mut largest = (deg[0] + 360.0 - last, last);
    for pair in deg.windows(2) {
        let gap = pair[1] - pair[0];
        if gap > largest.0 {
            largest = (gap, pair[0]);
        }
    }
    largest
}

/// Fewest headings for which the buckets are worth their set-up.
const BUCKETS_FROM: usize = 64;
/// Buckets filled at a time: 32 KiB of them, which stay in the cache.
const BUCKET_BLOCK: usize = 2048;

/// [`largest_gap_by_sorting`] in linear time, the same result to the bit:
/// the headings go into as many buckets as there are headings, by a
/// mapping that keeps their order, so neighbours in different buckets are
/// the largest of one and the smallest of the next non-empty one. A gap
/// inside a bucket is at most the bucket's span: when every span is below
/// the largest gap between buckets, no gap inside one can be the largest,
/// nor tie with it. `None` when that does not hold (the caller sorts).
fn largest_gap_by_buckets(deg: &[f64]) -> Option<(f64, f64)> {
    let n = deg.len();
    if n < BUCKETS_FROM {
        return None;
    }
    let (lo, hi) = lowest_and_highest(deg)?;
    let per_degree = (n - 1) as f64 / (hi - lo);
    if !(per_degree.is_finite() && per_degree > 0.0) {
        return None;
    }
    let fine = |h: f64| (((h - lo) * per_degree) as usize).min(n - 1);
    // The buckets are filled a block of them at a time, so that a block's
    // buckets stay in the cache: the headings are first put in the order
    // of their blocks (a counting sort), then each block's go into its
    // buckets. A bucket's smallest and largest do not depend on the order
    // its headings come in, so this is the one-pass result to the bit.
    let blocks = n.div_ceil(BUCKET_BLOCK);
    let mut start = vec![0usize; blocks + 1];
    for &h in deg {
        start[fine(h) / BUCKET_BLOCK + 1] += 1;
    }
    for k in 1..=blocks {
        start[k] += start[k - 1];
    }
    let mut next = start.clone();
    let mut by_block = vec![0.0; n];
    for &h in deg {
        let k = fine(h) / BUCKET_BLOCK;
        by_block[next[k]] = h;
        next[k] += 1;
    }
    let mut walk = GapWalk::new(lo, hi);
    // Smallest and largest heading of each bucket of a block (NaN: empty).
    let mut bucket = [[f64::NAN; 2]; BUCKET_BLOCK];
    for k in 0..blocks {
        bucket.fill([f64::NAN; 2]);
        let first = k * BUCKET_BLOCK;
        for &h in &by_block[start[k]..start[k + 1]] {
            widen(&mut bucket[fine(h) - first], h);
        }
        walk.along(&bucket);
    }
    walk.decided()
}

/// Most sweeps of the SVD in [`circle_centre`]. Golub-Kahan SVD converges
/// in a few sweeps per singular value on finite input (a 3-column design
/// takes well under 100); 1000 only ends a run that will never converge
/// (non-finite or pathological input) with an error instead of a hang.
/// Same cap as the residual fit's SVD in `residuals.rs`.
pub const SVD_MAX_ITERATIONS: usize = 1000;

/// Centre of the circle that best fits the points (Kåsa's algebraic fit).
/// Used to judge the coverage of points that no ellipse of the paper's family
/// fits: a partial arc still has a well-defined centre of curvature.
pub fn circle_centre(x: &[f64], y: &[f64]) -> Result<(f64, f64), FitError> {
    let n = x.len();
    if n < 3 {
        return Err(FitError::TooFewSamples {
            found: n,
            unknowns: 3,
            needed: 3,
        });
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n as f64;
    let (mx, my) = (mean(x), mean(y));
    let spread = x
        .iter()
        .zip(y)
        .map(|(x, y)| (x - mx).hypot(y - my))
        .fold(0.0, f64::max);
    if !(spread > 0.0) {
        return Err(FitError::Degenerate);
    }
    // u^2 + v^2 = 2*cu*u + 2*cv*v + c, in centred, scaled coordinates.
    let scaled = |i: usize| ((x[i] - mx) / spread, (y[i] - my) / spread);
    let design = DMatrix::from_fn(n, 3, |i, j| {
        let (u, v) = scaled(i);
        [2.0 * u, 2.0 * v, 1.0][j]
    });
    let target = DVector::from_fn(n, |i, _| {
        let (u, v) = scaled(i);
        u * u + v * v
    });
    if !(design.iter().all(|v| v.is_finite()) && target.iter().all(|v| v.is_finite())) {
        // Readings whose mean or spread overflows: refused before the SVD,
        // which would iterate on non-finite entries.
        return Err(FitError::Degenerate);
    }
    let p = design
        .try_svd(true, true, f64::EPSILON, SVD_MAX_ITERATIONS)
        .ok_or(FitError::NoConvergence {
            iterations: SVD_MAX_ITERATIONS,
            what: "the SVD of the circle fit did not converge",
        })?
        .solve(&target, 1e-12)
        .map_err(|_| FitError::Degenerate)?;
    if !p.iter().all(|v| v.is_finite()) {
        return Err(FitError::Degenerate);
    }
    Ok((mx + p[0] * spread, my + p[1] * spread))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Headings in [0, 360]: spread, bunched on a few values (repeats, a
    /// quantised sensor), or both.
    fn headings() -> impl Strategy<Value = Vec<f64>> {
        // Up to three blocks of buckets ([`BUCKET_BLOCK`]).
        let spread = proptest::collection::vec(0.0f64..360.0, 1..3000);
        let bunched =
            proptest::collection::vec((0u32..40).prop_map(|k| f64::from(k) * 9.0), 1..3000);
        let mixed = (spread.clone(), bunched.clone()).prop_map(|(mut a, b)| {
            a.extend(b);
            a
        });
        prop_oneof![spread, bunched, mixed]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

        /// The buckets give the sort's gap and start to the bit, or
        /// leave it to the sort.
        #[test]
        fn buckets_find_the_largest_gap_the_sort_finds(deg in headings()) {
            let sorted = largest_gap_by_sorting(&mut deg.clone());
            for found in [largest_gap_by_buckets(&deg), largest_gap_by_few_buckets(&deg)].into_iter().flatten() {
                prop_assert_eq!(found.0.to_bits(), sorted.0.to_bits());
                prop_assert_eq!(found.1.to_bits(), sorted.1.to_bits());
            }
        }

        /// The wrap without `fmod` is `rem_euclid`'s, to the bit.
        #[test]
        fn headings_wrap_as_rem_euclid_wraps_them(
            deg in prop_oneof![
                -400.0f64..400.0,
                300.0f64..800.0,
                -1e6f64..1e6,
                // Every magnitude, to 2⁶⁰ (past the division's bound).
                (-60.0f64..60.0, any::<bool>()).prop_map(|(e, neg)| if neg { -(2f64.powf(e)) } else { 2f64.powf(e) }),
                // Whole turns and their neighbours, each side of zero.
                (-(1i64 << 40)..(1i64 << 40), -2i32..=2).prop_map(|(k, ulps)| {
                    let mut d = k as f64 * 360.0;
                    for _ in 0..ulps.abs() {
                        d = if ulps > 0 { d.next_up() } else { d.next_down() };
                    }
                    d
                }),
                Just(-0.0), Just(-360.0), Just(360.0), Just(-180.0), Just(720.0), Just(-720.0),
                Just(720.0f64.next_down()), Just(360.0f64.next_down()),
                Just(4_503_599_627_370_496.0), Just(4_503_599_627_370_496.0f64.next_down()),
                Just(-4_503_599_627_370_496.0f64.next_down()),
            ]
        ) {
            prop_assert_eq!(wrap_degrees(deg).to_bits(), deg.rem_euclid(360.0).to_bits());
        }
    }

    /// The wrap by one division is `rem_euclid`'s to the bit on a million
    /// angles of every size up to 2⁶⁰ (random mantissas), and next to
    /// whole turns (where the quotient rounds to the next whole number).
    #[test]
    fn the_division_wraps_as_fmod_does_at_every_size() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..1_000_000 {
            let bits = next();
            // Exponents 2⁸ .. 2⁶⁰, either sign, any mantissa.
            let exponent = 1023 + 8 + (bits >> 52) % 53;
            let deg =
                f64::from_bits((bits & (1 << 63)) | (exponent << 52) | (bits & ((1 << 52) - 1)));
            assert_eq!(
                wrap_degrees(deg).to_bits(),
                deg.rem_euclid(360.0).to_bits(),
                "{deg:e}"
            );
            let turn = (next() % (1 << 43)) as f64 * 360.0;
            for d in [
                turn,
                turn.next_up(),
                turn.next_down(),
                -turn,
                (-turn).next_up(),
                (-turn).next_down(),
            ] {
                assert_eq!(
                    wrap_degrees(d).to_bits(),
                    d.rem_euclid(360.0).to_bits(),
                    "{d:e}"
                );
            }
        }
    }

    /// A turn's headings take the linear path (the sort is the exception).
    #[test]
    fn a_turn_is_covered_without_sorting() {
        let n = 5000;
        let deg: Vec<f64> = (0..n)
            .map(|i| (i as f64 * 0.0731 + (i as f64 * 1.7).sin()).rem_euclid(1.0) * 300.0)
            .collect();
        let found = largest_gap_by_buckets(&deg).expect("the buckets decide a turn");
        let sorted = largest_gap_by_sorting(&mut deg.clone());
        assert_eq!(found, sorted);
        assert!((found.0 - 60.0).abs() < 0.5, "{found:?}");
        let few = largest_gap_by_few_buckets(&deg).expect("a few buckets decide a turn");
        assert_eq!(few, sorted);
    }

    /// Past [`FEW_BUCKETS`] headings the few buckets decide a turn alone,
    /// to the bit; headings spread too evenly for them go on to a bucket
    /// per heading, which decides them.
    #[test]
    fn a_few_buckets_decide_a_long_turn_and_leave_an_even_spread() {
        let n = 3 * FEW_BUCKETS + 17;
        let turn: Vec<f64> = (0..n)
            .map(|i| wrap_degrees((i as f64 * 0.0173 + (i as f64 * 0.37).sin()) % 355.0))
            .collect();
        let sorted = largest_gap_by_sorting(&mut turn.clone());
        assert_eq!(largest_gap_by_few_buckets(&turn), Some(sorted));
        // Evenly spaced but for one gap a little wider than the spacing:
        // within a coarse bucket's span, not within a fine one's.
        let step = 360.0 / n as f64;
        let even: Vec<f64> = (0..n)
            .map(|i| i as f64 * step + if i > n / 2 { 0.5 * step } else { 0.0 })
            .filter(|&h| h < 360.0)
            .collect();
        assert_eq!(largest_gap_by_few_buckets(&even), None);
        let sorted = largest_gap_by_sorting(&mut even.clone());
        assert_eq!(largest_gap_by_buckets(&even), Some(sorted));
    }
}
