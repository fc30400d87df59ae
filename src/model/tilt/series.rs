//! The heading of every sample of a recording, and the figures beside
//! it, worked out on every core.

use nalgebra::Vector3;

use super::{level_heading, tilt_heading};

/// Every sample's heading and the field's geometry (NaN where a sample
/// has none: no accelerometer reading, a field too near the vertical).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HeadingSeries {
    /// Tilt-compensated, clockwise from north (true north when a
    /// declination was added), degrees in [0, 360).
    pub heading_deg: Vec<f64>,
    /// What a level compass reads (no tilt compensation), same north.
    pub level_deg: Vec<f64>,
    pub tilt_deg: Vec<f64>,
    pub pitch_deg: Vec<f64>,
    pub inclination_deg: Vec<f64>,
}

/// Why the board's axes cannot give a heading.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "the forward axis ({forward:?}) and the up axis ({up:?}) must be two different axes of the board, at right angles (for example --forward x --up z)"
)]
pub struct BoardAxesError {
    pub forward: [f64; 3],
    pub up: [f64; 3],
}

/// Samples each thread of [`heading_series`] is given at least (a series
/// shorter than twice this is worked out on one core): a thread costs
/// about what this many samples' trigonometry does.
const SERIES_ROWS_PER_THREAD: usize = 1 << 16;

/// The heading of every sample from calibrated fields `mag` and specific
/// forces `accel` in the body frame, paired sample by sample (NaN: none),
/// for a board whose `forward` and `up` axes are given; `declination_deg`
/// (east positive) is added to give true north. Each sample is a pure
/// function of its pair, so a long series is worked out in parts on up to
/// as many threads as there are cores, each part written where one thread
/// would have written it.
pub fn heading_series(
    mag: &[[f64; 3]],
    accel: &[[f64; 3]],
    forward: [f64; 3],
    up: [f64; 3],
    declination_deg: f64,
) -> Result<HeadingSeries, BoardAxesError> {
    let (f, u) = (Vector3::from(forward), Vector3::from(up));
    if !(f.norm() > 0.0 && u.norm() > 0.0) || f.dot(&u).abs() > 1e-9 * f.norm() * u.norm() {
        return Err(BoardAxesError { forward, up });
    }
    let right = f.cross(&u);
    let right = [right.x, right.y, right.z];
    let turn = |h: f64| {
        let t = (h + declination_deg).rem_euclid(360.0);
        if t >= 360.0 { 0.0 } else { t }
    };
    // One part: its samples' five figures into their places.
    let fill = |mag: &[[f64; 3]], accel: &[[f64; 3]], out: [&mut [f64]; 5]| {
        let [heading, level, tilt, pitch, inclination] = out;
        let places = heading
            .iter_mut()
            .zip(level.iter_mut())
            .zip(tilt.iter_mut().zip(pitch.iter_mut()))
            .zip(inclination.iter_mut());
        for ((m, a), (((h, l), (t, p)), i)) in mag.iter().zip(accel).zip(places) {
            let found = tilt_heading(*m, *a, forward, up);
            *h = found.map_or(f64::NAN, |t| turn(t.heading_deg));
            *t = found.map_or(f64::NAN, |t| t.tilt_deg);
            *p = found.map_or(f64::NAN, |t| t.pitch_deg);
            *i = found.map_or(f64::NAN, |t| t.inclination_deg);
            *l = level_heading(*m, forward, right).map_or(f64::NAN, turn);
        }
    };
    let n = mag.len().min(accel.len());
    let mut out = HeadingSeries {
        heading_deg: vec![f64::NAN; n],
        level_deg: vec![f64::NAN; n],
        tilt_deg: vec![f64::NAN; n],
        pitch_deg: vec![f64::NAN; n],
        inclination_deg: vec![f64::NAN; n],
    };
    let threads = crate::parallel::cores()
        .min(n / SERIES_ROWS_PER_THREAD)
        .max(1);
    let part = n.div_ceil(threads).max(1);
    let HeadingSeries {
        heading_deg,
        level_deg,
        tilt_deg,
        pitch_deg,
        inclination_deg,
    } = &mut out;
    let parts: Vec<_> = heading_deg
        .chunks_mut(part)
        .zip(level_deg.chunks_mut(part))
        .zip(tilt_deg.chunks_mut(part))
        .zip(pitch_deg.chunks_mut(part))
        .zip(inclination_deg.chunks_mut(part))
        .zip(mag.chunks(part).zip(accel.chunks(part)))
        .map(|(((((h, l), t), p), i), (m, a))| (m, a, [h, l, t, p, i]))
        .collect();
    // Each thread takes the next part until none is left: a thread that
    // cannot be started leaves its parts to the others.
    let queue = std::sync::Mutex::new(parts);
    let work = || {
        loop {
            let next = queue
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .pop();
            let Some((m, a, out)) = next else { break };
            fill(m, a, out);
        }
    };
    std::thread::scope(|scope| {
        for _ in 1..threads {
            let _ = std::thread::Builder::new().spawn_scoped(scope, work);
        }
        work();
    });
    Ok(out)
}
