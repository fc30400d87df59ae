//! Coverage of the sphere of directions: which directions a 3-axis sensor's
//! field (or gravity) took in the sensor frame during a recording.
//!
//! The sphere is cut into [`REGIONS`] regions of equal area (a zonal
//! partition: a cap at each pole and eight collars between them), after the
//! recursive zonal equal-area partition of Leopardi ("A partition of the
//! unit sphere into regions of equal area and small diameter", ETNA 25,
//! 2006), which PJRC MotionCal also follows for its 100 regions (its
//! `quality.c`, "surface gap error"). The counts per collar are derived
//! here, not copied (see [`BANDS`]). ArduPilot's CompassCalibrator shows the
//! same idea as an 80-triangle geodesic mask.
//!
//! A direction is named in the sensor frame by its elevation (angle above
//! the sensor's x–y plane, toward +z) and its azimuth (angle from +x toward
//! +y in that plane). Missing regions that touch are merged into a few
//! ranges a person can act on ("−z: elevation −90° to −60°, every
//! azimuth"): turn the sensor so that this axis points along the field (for
//! an accelerometer at rest: so that it points up).

use std::f64::consts::{PI, TAU};
use std::fmt;

use serde::Serialize;

/// Number of equal-area regions (as PJRC MotionCal's 100).
pub const REGIONS: usize = 100;

/// Regions per band, from +z (north) to −z. Derived from Leopardi's
/// recursive zonal construction for N = 100: a polar cap of area 4π/N
/// (colatitude acos(1 − 2/N) = 11.5°), round((π − 2·11.5°)/sqrt(4π/N)) = 8
/// collars of equal height (19.6°), each given round(its area / (4π/N))
/// regions with the rounding remainder carried to the next collar. The
/// collar boundaries are then moved so that every region has exactly the
/// area 4π/N: sin(elevation) = 1 − 2·(regions above)/N, which gives bands
/// at ±78.5°, ±59.3°, ±39.8°, ±19.9° and 0°.
pub const BANDS: [usize; 10] = [1, 6, 11, 15, 17, 17, 15, 11, 6, 1];

/// Two missing regions belong to one named range when their centres are
/// within this angle: 1.5 × the side of a region, sqrt(4π/N) = 20.3° for
/// N = 100, so that regions sharing an edge or a corner are joined and
/// regions one covered region apart are not. Geometry of the partition,
/// not a tuned value.
pub const NEIGHBOUR_DEG: f64 = 1.5 * 20.3;

/// The bands' bounds, worked out once ([`band_bounds_of`]).
static BAND_BOUNDS: std::sync::LazyLock<[(f64, f64, usize, usize); 10]> =
    std::sync::LazyLock::new(band_bounds_of);

/// The band a region lies in and its index within the band.
fn band_bounds() -> &'static [(f64, f64, usize, usize); 10] {
    &BAND_BOUNDS
}

fn band_bounds_of() -> [(f64, f64, usize, usize); 10] {
    // (elevation low, elevation high, first region, count), radians.
    let mut out = [(0.0, 0.0, 0, 0); 10];
    let mut above = 0usize;
    for (k, &count) in BANDS.iter().enumerate() {
        let top = (1.0 - 2.0 * above as f64 / REGIONS as f64).clamp(-1.0, 1.0);
        let bottom = (1.0 - 2.0 * (above + count) as f64 / REGIONS as f64).clamp(-1.0, 1.0);
        out[k] = (bottom.asin(), top.asin(), above, count);
        above += count;
    }
    out
}

/// The region (0..REGIONS) of a direction, or `None` for a zero or
/// non-finite vector.
///
/// The region is the one the direction's elevation (`asin`) and azimuth
/// (`atan2`) put it in ([`region_of_by_angles`]), found without either
/// for nearly every direction: the band by comparing the sine of the
/// elevation with the sines of the band's bounds, the sector by an
/// approximate azimuth ([`approximate_azimuth`]). Only a direction within
/// [`BAND_MARGIN`] of a band's bound, or within [`AZIMUTH_MARGIN`] of a
/// sector's edge, takes the functions themselves, so the region is the
/// very same (the coverage of millions of samples is worked out several
/// times by a 3-D fit: the functions were most of its cost).
pub fn region_of(v: [f64; 3]) -> Option<usize> {
    let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(norm > 0.0) || !norm.is_finite() {
        return None;
    }
    let sine = (v[2] / norm).clamp(-1.0, 1.0);
    let bands = band_bounds();
    let sines = band_sines();
    // The first band whose lower bound the elevation reaches: asin grows
    // at least as fast as its argument, so a sine further than the margin
    // from the bound's sine lies on the same side of it in angle.
    let mut elevation = None;
    let band = (0..bands.len())
        .find(|&k| {
            if sine >= sines[k] + BAND_MARGIN {
                true
            } else if sine <= sines[k] - BAND_MARGIN {
                false
            } else {
                *elevation.get_or_insert_with(|| sine.asin()) >= bands[k].0
            }
        })
        .unwrap_or(bands.len() - 1);
    let (_, _, first, count) = bands[band];
    if count == 1 {
        return Some(first);
    }
    let sectors = count as f64;
    let approximate = approximate_azimuth(v[1], v[0]) / TAU * sectors;
    if approximate.is_finite() {
        // In [0, sectors]: the conversion to an integer is its floor (no
        // call to the library's `floor` or `round`, which a baseline
        // x86-64 makes). The nearer of the distances to the edges below
        // and above is exact (Sterbenz; the farther may round when the
        // floor is 0, but is then at least 0.5 and not the nearer): it is
        // |approximate − round(approximate)|.
        let below = approximate as usize;
        let floor = below as f64;
        let nearest = (approximate - floor).min(floor + 1.0 - approximate);
        if nearest > AZIMUTH_MARGIN / TAU * sectors {
            return Some(first + below.min(count - 1));
        }
    }
    let azimuth = v[1].atan2(v[0]).rem_euclid(TAU);
    Some(first + ((azimuth / TAU * sectors) as usize).min(count - 1))
}

/// A sine within this of a band bound's sine is compared in angle. The
/// sines of the bounds and `asin` are each within a few units in the last
/// place (1e-16): the margin leaves 1e7 of those.
const BAND_MARGIN: f64 = 1e-9;

/// An approximate azimuth within this (radians) of a sector's edge is
/// worked out exactly: [`approximate_azimuth`] is within 0.0039 rad of the
/// true azimuth, and this is 2.5 times that. About 5 % of the directions
/// of the bands of 17 sectors take `atan2`.
const AZIMUTH_MARGIN: f64 = 0.01;

/// The sines of the bands' lower bounds.
static BAND_SINES: std::sync::LazyLock<[f64; 10]> =
    std::sync::LazyLock::new(|| band_bounds().map(|(low, _, _, _)| low.sin()));

fn band_sines() -> &'static [f64; 10] {
    &BAND_SINES
}

/// atan2(y, x) in [0, 2π] within 0.0039 rad: atan on [0, 1] as
/// π/4·t + 0.273·t·(1 − t) (its largest error, 0.00376 rad at t ≈ 0.645,
/// is checked by this file's test round the whole circle), carried to the
/// other octants by the symmetries of the angle. NaN for x = y = 0.
fn approximate_azimuth(y: f64, x: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    let t = ax.min(ay) / ax.max(ay);
    let mut angle = std::f64::consts::FRAC_PI_4 * t + 0.273 * t * (1.0 - t);
    if ay > ax {
        angle = std::f64::consts::FRAC_PI_2 - angle;
    }
    if x < 0.0 {
        angle = PI - angle;
    }
    if y < 0.0 {
        angle = TAU - angle;
    }
    angle
}

/// [`region_of`] by the angles themselves: the definition it keeps to.
pub fn region_of_by_angles(v: [f64; 3]) -> Option<usize> {
    let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(norm > 0.0) || !norm.is_finite() {
        return None;
    }
    let elevation = (v[2] / norm).clamp(-1.0, 1.0).asin();
    let azimuth = v[1].atan2(v[0]).rem_euclid(TAU);
    let bands = band_bounds();
    let (_, _, first, count) = bands
        .iter()
        .copied()
        .find(|&(low, _, _, _)| elevation >= low)
        .unwrap_or(bands[bands.len() - 1]);
    let index = ((azimuth / TAU * count as f64) as usize).min(count - 1);
    Some(first + index)
}

/// Where a region lies: elevation range, azimuth range, and its centre, in
/// degrees (azimuth in [0, 360)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Region {
    pub elevation_deg: (f64, f64),
    pub azimuth_deg: (f64, f64),
    pub centre: [f64; 3],
}

/// The geometry of region `index` (< REGIONS).
pub fn region(index: usize) -> Region {
    let bands = band_bounds();
    let (low, high, first, count) = bands
        .iter()
        .copied()
        .find(|&(_, _, first, count)| index < first + count)
        .unwrap_or(bands[bands.len() - 1]);
    let j = index.saturating_sub(first).min(count - 1);
    let width = TAU / count as f64;
    let (az0, az1) = (j as f64 * width, (j + 1) as f64 * width);
    // Centre: mid-azimuth, and the elevation that halves the band's area.
    let elevation = if count == 1 {
        if high > 0.0 { PI / 2.0 } else { -PI / 2.0 }
    } else {
        ((low.sin() + high.sin()) / 2.0).asin()
    };
    let azimuth = (az0 + az1) / 2.0;
    Region {
        elevation_deg: (low.to_degrees(), high.to_degrees()),
        azimuth_deg: (az0.to_degrees(), az1.to_degrees()),
        centre: [
            elevation.cos() * azimuth.cos(),
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
        ],
    }
}

/// A connected range of missing directions, in words and numbers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MissingDirections {
    /// The sensor axis, or combination of axes, the range is centred on:
    /// "+z", "-x+y", "+x-y-z".
    pub toward: String,
    /// Unit vector of the range's mean direction, in the sensor frame.
    pub direction: [f64; 3],
    /// How many regions of the partition are missing in this range.
    pub regions: usize,
    /// Elevation range, degrees, low to high.
    pub elevation_deg: (f64, f64),
    /// Azimuth range, degrees, from the first to the last going
    /// counter-clockwise (from +x toward +y); `None` when the range goes all
    /// the way round (or is a polar cap).
    pub azimuth_deg: Option<(f64, f64)>,
}

impl fmt::Display for MissingDirections {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (lo, hi) = self.elevation_deg;
        write!(
            f,
            "{} (elevation {:.0}° to {:.0}°, ",
            self.toward,
            lo.round(),
            hi.round()
        )?;
        match self.azimuth_deg {
            Some((a, b)) => write!(f, "azimuth {:.0}° to {:.0}°)", a.round(), b.round()),
            None => write!(f, "every azimuth)"),
        }
    }
}

/// The share of the sphere a set of directions reaches.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SphereCoverage {
    /// Regions of the partition ([`REGIONS`]).
    pub regions: usize,
    /// Regions holding at least one direction.
    pub covered: usize,
    /// `covered / regions`.
    pub fraction: f64,
    /// Whether a region holds a direction, by region index.
    #[serde(skip)]
    pub reached: [bool; REGIONS],
    /// The missing regions merged into ranges, largest first.
    pub missing: Vec<MissingDirections>,
}

impl SphereCoverage {
    /// "missing: -z (elevation -90° to -59°, every azimuth); +x+y (...)", or
    /// "nothing missing".
    ///
    /// When less than a third of the sphere is covered, the missing ranges
    /// are most of it and would be named coarsely: the text names what is
    /// covered instead, "covered only 10 of 100 regions: the band round the
    /// y axis (...); every other direction is missing".
    pub fn missing_text(&self) -> String {
        if self.missing.is_empty() {
            return "nothing missing".to_string();
        }
        if self.covered * 3 < self.regions {
            let covered: Vec<usize> = (0..REGIONS).filter(|&k| self.reached[k]).collect();
            if covered.is_empty() {
                return "no direction covered".to_string();
            }
            let parts: Vec<String> = merge(&covered).iter().map(|m| m.to_string()).collect();
            return format!(
                "covered only {} of {} regions: {}; every other direction is missing",
                self.covered,
                self.regions,
                parts.join("; ")
            );
        }
        let parts: Vec<String> = self.missing.iter().map(|m| m.to_string()).collect();
        format!("missing: {}", parts.join("; "))
    }
}

/// Coverage of the sphere by a set of direction vectors (need not be unit;
/// zero or non-finite ones are skipped). Once every region holds one,
/// nothing more can change it: the rest are not looked at (a tumble of
/// millions of samples reaches them all within its first thousands).
pub fn coverage(directions: impl IntoIterator<Item = [f64; 3]>) -> SphereCoverage {
    let mut reached = [false; REGIONS];
    let mut covered = 0;
    for v in directions {
        if let Some(k) = region_of(v)
            && !reached[k]
        {
            reached[k] = true;
            covered += 1;
            if covered == REGIONS {
                break;
            }
        }
    }
    let missing_regions: Vec<usize> = (0..REGIONS).filter(|&k| !reached[k]).collect();
    SphereCoverage {
        regions: REGIONS,
        covered,
        fraction: covered as f64 / REGIONS as f64,
        reached,
        missing: merge(&missing_regions),
    }
}

fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    dot.clamp(-1.0, 1.0).acos().to_degrees()
}

/// Joins missing regions whose centres are within [`NEIGHBOUR_DEG`] into
/// connected ranges and names each.
fn merge(missing: &[usize]) -> Vec<MissingDirections> {
    let geometry: Vec<Region> = missing.iter().map(|&k| region(k)).collect();
    let mut group = vec![usize::MAX; missing.len()];
    let mut groups = 0;
    for start in 0..missing.len() {
        if group[start] != usize::MAX {
            continue;
        }
        group[start] = groups;
        let mut stack = vec![start];
        while let Some(i) = stack.pop() {
            for j in 0..missing.len() {
                if group[j] == usize::MAX
                    && angle_deg(geometry[i].centre, geometry[j].centre) <= NEIGHBOUR_DEG
                {
                    group[j] = groups;
                    stack.push(j);
                }
            }
        }
        groups += 1;
    }
    let mut out: Vec<MissingDirections> = (0..groups)
        .map(|g| {
            let members: Vec<&Region> = geometry
                .iter()
                .zip(&group)
                .filter(|&(_, &gi)| gi == g)
                .map(|(r, _)| r)
                .collect();
            describe(&members)
        })
        .collect();
    out.sort_by_key(|m| std::cmp::Reverse(m.regions));
    out
}

fn describe(members: &[&Region]) -> MissingDirections {
    let mut sum = [0.0; 3];
    for r in members {
        for (s, c) in sum.iter_mut().zip(r.centre) {
            *s += c;
        }
    }
    let norm = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
    // Regions all round an axis (a band, a ring) have no direction they
    // lean toward: name the band by its axis.
    let band = (members.len() >= 6 && norm < WRAPS * members.len() as f64)
        .then(|| band_axis(members))
        .filter(|axis| {
            // A band hugs its plane: its centres stay within 20° of it on
            // rms (sin 20° = 0.34); a cap larger than a hemisphere also
            // averages to little, but spreads far from any plane (an
            // 82 % cap: 0.5).
            let ms = members
                .iter()
                .map(|r| {
                    let d = r.centre[0] * axis[0] + r.centre[1] * axis[1] + r.centre[2] * axis[2];
                    d * d
                })
                .sum::<f64>()
                / members.len() as f64;
            ms.sqrt() < 0.34
        });
    if let Some(axis) = band {
        let name = axis_name(axis);
        let name = name.strip_prefix(['+', '-']).unwrap_or(&name).to_string();
        let (low, high) = elevation_range(members);
        return MissingDirections {
            toward: format!("the band round the {name} axis"),
            direction: axis,
            regions: members.len(),
            elevation_deg: (low, high),
            azimuth_deg: azimuth_span(members),
        };
    }
    let direction = if norm > 1e-9 {
        [sum[0] / norm, sum[1] / norm, sum[2] / norm]
    } else {
        members.first().map_or([0.0, 0.0, 1.0], |r| r.centre)
    };
    let (low, high) = elevation_range(members);
    MissingDirections {
        toward: axis_name(direction),
        direction,
        regions: members.len(),
        elevation_deg: (low, high),
        azimuth_deg: azimuth_span(members),
    }
}

/// A group whose mean direction is shorter than this fraction of a unit
/// vector goes all round: the centres of an even band about any axis
/// average to almost nothing, those of a cap of up to a hemisphere to at
/// least half a unit vector.
const WRAPS: f64 = 0.3;

fn elevation_range(members: &[&Region]) -> (f64, f64) {
    let low = members
        .iter()
        .map(|r| r.elevation_deg.0)
        .fold(f64::INFINITY, f64::min);
    let high = members
        .iter()
        .map(|r| r.elevation_deg.1)
        .fold(f64::NEG_INFINITY, f64::max);
    (low, high)
}

/// The axis a band of regions goes round: the direction of least spread
/// of their centres.
fn band_axis(members: &[&Region]) -> [f64; 3] {
    let mut s = nalgebra::Matrix3::<f64>::zeros();
    for r in members {
        let c = nalgebra::Vector3::from(r.centre);
        s += c * c.transpose();
    }
    let eig = nalgebra::SymmetricEigen::new(s);
    let k = eig.eigenvalues.imin();
    let v = eig.eigenvectors.column(k);
    // Point it toward the positive side of its largest component.
    let sign = if v[v.iamax()] < 0.0 { -1.0 } else { 1.0 };
    [v[0] * sign, v[1] * sign, v[2] * sign]
}

/// The smallest arc holding every member's azimuth range, or `None` when
/// the members go all the way round or include a polar cap.
fn azimuth_span(members: &[&Region]) -> Option<(f64, f64)> {
    if members
        .iter()
        .any(|r| r.azimuth_deg.1 - r.azimuth_deg.0 >= 359.0)
    {
        return None;
    }
    // Mark 1° steps covered by any member, then find the largest free gap.
    let mut taken = [false; 360];
    for r in members {
        let (a, b) = r.azimuth_deg;
        let mut d = a.floor() as i64;
        while (d as f64) < b && d < a.floor() as i64 + 360 {
            taken[d.rem_euclid(360) as usize] = true;
            d += 1;
        }
    }
    let free = taken.iter().filter(|t| !**t).count();
    if free == 0 {
        return None;
    }
    // The largest run of free degrees (circular): the span is its complement.
    let (mut best_start, mut best_len) = (0usize, 0usize);
    for start in 0..360 {
        if taken[start] || !taken[(start + 359) % 360] {
            continue;
        }
        let mut len = 0;
        while len < 360 && !taken[(start + len) % 360] {
            len += 1;
        }
        if len > best_len {
            best_len = len;
            best_start = start;
        }
    }
    let from = (best_start + best_len) % 360;
    let to = (best_start + 360 - 1) % 360 + 1;
    Some((from as f64, to as f64))
}

/// "+x", "-x+y", "+x-y-z": the axes a unit vector leans toward, keeping a
/// component when it is at least half the largest (so 26.6° off an axis
/// still names the axis alone, 45° names the pair).
fn axis_name(d: [f64; 3]) -> String {
    let largest = d.iter().map(|c| c.abs()).fold(0.0, f64::max);
    let mut name = String::new();
    for (c, axis) in d.iter().zip(["x", "y", "z"]) {
        if c.abs() >= 0.5 * largest && largest > 0.0 {
            name.push(if *c >= 0.0 { '+' } else { '-' });
            name.push_str(axis);
        }
    }
    name
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bound [`AZIMUTH_MARGIN`] rests on: the approximate azimuth is
    /// within 0.0039 rad of atan2's round the whole circle, and the margin
    /// is more than twice that.
    #[test]
    fn the_approximate_azimuth_is_within_its_bound_round_the_circle() {
        let steps = 1_000_000;
        let mut worst = 0.0f64;
        for k in 0..steps {
            let angle = k as f64 * TAU / steps as f64;
            for r in [1.0, 3e-7, 4e12] {
                let (y, x) = (r * angle.sin(), r * angle.cos());
                let exact = y.atan2(x).rem_euclid(TAU);
                let off = (approximate_azimuth(y, x) - exact).abs();
                // 0 and 2π are one direction.
                worst = worst.max(off.min(TAU - off));
            }
        }
        assert!(worst < 0.0039, "{worst}");
        // The formula's own error, not a slack bound: 0.00376 rad.
        assert!(worst > 0.0037, "{worst}");
        const { assert!(AZIMUTH_MARGIN > 2.0 * 0.0039) };
        assert!(approximate_azimuth(0.0, 0.0).is_nan());
    }
}
