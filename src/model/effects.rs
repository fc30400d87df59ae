//! The catalogue of physical effects a model can add to the paper's, by the
//! names that are part of the interface (command line, configuration, JSON).
//!
//! Each effect's facts stand together in one [`EffectInfo`] of
//! [`CATALOGUE`]: its name, the parameters it adds, their physical limits,
//! whether the daemon can apply it to live readings and whether it has a
//! 3-D form. Parsing, naming, the diagnosis's limits, the daemon's list of
//! live effects and the 3-D fit's refusal all read the catalogue; adding an
//! effect is a variant of [`Effect`] and its entry here, plus its
//! mathematics in the fits (`nonlinear`, `ellipsoid_effects`).

use std::fmt;
use std::str::FromStr;

use serde::{Serialize, Serializer};

/// One effect of the catalogue (product.md, "Model insight: the effects").
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// Hard iron, zero-g bias: a constant per axis (in the paper's model).
    Offset,
    /// Per-axis gain mismatch (in the paper's model).
    Scale,
    /// Non-orthogonal axes, soft iron: the off-diagonal coupling term.
    CrossAxis,
    /// A bias that moves during the run (warm-up): offset linear in time.
    Drift,
    /// Offset linear in a logged quantity (temperature, motor current...).
    Covariate(String),
    /// Amplifier or sensor non-linearity near its range: odd cubic term per
    /// axis, about the sensor's zero.
    Cubic,
    /// Non-linearity about the centre of the turn (an accelerometer's proof
    /// mass about its zero-g point, an amplifier centred on the operating
    /// point): odd cubic term per axis about the turn's centre.
    CubicCentred,
    /// Spikes, bumps, bad frames: a robust fit, with the points flagged.
    Outliers,
}

/// The paper's model: `offset+scale`.
pub const PAPER: [Effect; 2] = [Effect::Offset, Effect::Scale];

/// Effects that can be added to the paper's model, but for covariates,
/// which come from the recording's columns.
pub const OPTIONAL: [Effect; 5] = [
    Effect::CrossAxis,
    Effect::Drift,
    Effect::Cubic,
    Effect::CubicCentred,
    Effect::Outliers,
];

/// The largest non-linearity a `cubic` (and `cubic-centred`) may bend the
/// reading by at full scale: 10 %. Datasheets give 0.1–0.5 % of full scale
/// (HMC5883L: ±0.1 % FS at ±2 gauss; MPU-6050: 0.5 % accelerometer
/// non-linearity; ADXL345: ±0.5 % FS); an amplifier near saturation can do
/// more, so the limit is twenty times the worst of them and refuses no real
/// sensor. The fit's k is that fraction at the data's largest reading
/// (nonlinear.rs), so |k| compares with it directly.
pub const MAX_CUBIC: f64 = 0.10;
/// The largest cubic the diagnosis believes when nothing checks what it
/// does to the heading (no gyro, or a 3-D fit): 1 % at full scale, twice
/// the worst datasheet figure above. A fit can bend a hand-turned
/// recording into a few percent of cubic that lowers the rms and turns
/// the heading (a hand-turned MPU-6050 gave kc = −7 %); only a gyro can
/// say whether such a bend is the sensor's, so without one the sensor is
/// held to what its datasheet says it does.
pub const MAX_CUBIC_UNCHECKED: f64 = 0.01;
/// The largest cross-axis coupling, in degrees: 20°. Datasheets give a
/// cross-axis sensitivity of ±2 % (≈ 1.1°; HMC5883L ±0.2 %, MPU-6050 ±2 %,
/// ADXL345 ±1 %); soft iron near the sensor and a tilted mounting add more,
/// so the limit is ten times the worst datasheet figure. ArduPilot's
/// CompassCalibrator accepts off-diagonals up to 1.0 (45°), but as a sanity
/// bound on a whole vehicle's 3-D soft-iron matrix, not a coupling one
/// would believe; PX4's mag calibration checks only that they are finite.
pub const MAX_CROSS_AXIS_DEG: f64 = 20.0;
/// [`MAX_CROSS_AXIS_DEG`] as the model's shear c = tan(angle).
pub const MAX_CROSS_AXIS_SHEAR: f64 = 0.364;

/// A physical limit on one fitted parameter, by the parameter's name.
#[derive(Debug, Clone, Copy)]
pub struct ParamLimit {
    pub param: &'static str,
    /// The largest |value| a physical cause of that name produces.
    pub max_abs: f64,
    /// What the value means, for the evidence: `describe(value)`.
    pub describe: fn(f64) -> String,
    /// Where the limit comes from.
    pub source: &'static str,
    /// The limit and its source when no gyro checks the heading, if it is
    /// tighter then.
    pub unchecked: Option<(f64, &'static str)>,
}

fn bends(k: f64) -> String {
    format!(
        "bends the reading by {:.1} % at full scale",
        k.abs() * 100.0
    )
}

fn couples(c: f64) -> String {
    format!("couples the axes by {:.1}°", c.atan().to_degrees().abs())
}

const CUBIC_SOURCE: &str =
    "limit 10 % at full scale; datasheets give 0.1–0.5 % (HMC5883L, MPU-6050, ADXL345)";

/// Where [`MAX_CUBIC_UNCHECKED`] comes from, as the evidence says it.
pub const CUBIC_UNCHECKED_SOURCE: &str = "limit 1 % at full scale with no gyro to check the heading: twice the worst datasheet figure, 0.1–0.5 % (HMC5883L, MPU-6050, ADXL345); with a gyro that checks the heading (--gyro) the limit is 10 %, what an amplifier near saturation can do";

/// The limit of a cubic term ([`MAX_CUBIC`]) on the parameter `param`.
const fn cubic_limit(param: &'static str) -> ParamLimit {
    ParamLimit {
        param,
        max_abs: MAX_CUBIC,
        describe: bends,
        source: CUBIC_SOURCE,
        unchecked: Some((MAX_CUBIC_UNCHECKED, CUBIC_UNCHECKED_SOURCE)),
    }
}

/// The limit of the cross-axis shear `c` ([`MAX_CROSS_AXIS_SHEAR`]).
const CROSS_AXIS_LIMIT: ParamLimit = ParamLimit {
    param: "c",
    max_abs: MAX_CROSS_AXIS_SHEAR,
    describe: couples,
    source: "limit 20°; datasheets give ±2 % cross-axis sensitivity (≈ 1°), ArduPilot accepts off-diagonals below 1.0",
    unchecked: None,
};

/// The facts of one effect of the catalogue.
#[derive(Debug)]
pub struct EffectInfo {
    /// The effect (a covariate's with an empty column).
    pub effect: Effect,
    /// The name on the command line, in configuration and in JSON; a
    /// covariate's is `covariate:<column>`.
    pub name: &'static str,
    /// The parameters the effect adds to the 2-D model, by name
    /// (`<column>` stands for a covariate's column); the paper's own
    /// effects and `outliers` add none.
    pub params: &'static [&'static str],
    /// The physical limits on those parameters (a parameter with none has no
    /// size limit beyond its standard error).
    pub limits: &'static [ParamLimit],
    /// Whether the effect is part of the paper's model.
    pub paper: bool,
    /// Whether the daemon can fit it and apply it to live readings: those
    /// that depend on the reading alone (drift needs the time base and
    /// covariates a logged column at correction time).
    pub live: bool,
    /// Whether the 3-D fit (the ellipsoid with effects) has it.
    pub in_3d: bool,
}

impl EffectInfo {
    /// One of the paper's own effects: no parameters beyond the paper's,
    /// live and in 3-D.
    const fn paper(effect: Effect, name: &'static str) -> Self {
        EffectInfo {
            effect,
            name,
            params: &[],
            limits: &[],
            paper: true,
            live: true,
            in_3d: true,
        }
    }
}

/// The catalogue, in the order of [`Effect`] (the order models list their
/// effects in).
pub static CATALOGUE: [EffectInfo; 8] = [
    EffectInfo::paper(Effect::Offset, "offset"),
    EffectInfo::paper(Effect::Scale, "scale"),
    EffectInfo {
        effect: Effect::CrossAxis,
        name: "cross-axis",
        params: &["c"],
        limits: &[CROSS_AXIS_LIMIT],
        paper: false,
        live: true,
        in_3d: true,
    },
    EffectInfo {
        effect: Effect::Drift,
        name: "drift",
        params: &["drift_x", "drift_y"],
        limits: &[],
        paper: false,
        live: false,
        in_3d: true,
    },
    EffectInfo {
        effect: Effect::Covariate(String::new()),
        name: "covariate:<column>",
        params: &["<column>_x", "<column>_y"],
        limits: &[],
        paper: false,
        live: false,
        in_3d: true,
    },
    EffectInfo {
        effect: Effect::Cubic,
        name: "cubic",
        params: &["k_x", "k_y"],
        limits: &[cubic_limit("k_x"), cubic_limit("k_y")],
        paper: false,
        live: true,
        in_3d: true,
    },
    EffectInfo {
        effect: Effect::CubicCentred,
        name: "cubic-centred",
        // kc, or kc_x and kc_y where a gyro pins their difference
        // (model/centred_split.rs): one unknown more, counted by the fit.
        params: &["kc"],
        limits: &[cubic_limit("kc"), cubic_limit("kc_x"), cubic_limit("kc_y")],
        paper: false,
        live: true,
        in_3d: false,
    },
    EffectInfo {
        effect: Effect::Outliers,
        name: "outliers",
        params: &[],
        limits: &[],
        paper: false,
        live: true,
        in_3d: true,
    },
];

/// The prefix of a covariate's name.
const COVARIATE_PREFIX: &str = "covariate:";

/// The physical limit on a parameter, if it has one.
pub fn limit_of(param: &str) -> Option<&'static ParamLimit> {
    CATALOGUE
        .iter()
        .flat_map(|info| info.limits)
        .find(|l| l.param == param)
}

/// The physical limit on a parameter as the diagnosis applies it:
/// `heading_checked` when a gyro checks what the candidate does to the
/// heading; without one, the tighter limit of [`ParamLimit::unchecked`]
/// where there is one.
pub fn limit_for(param: &str, heading_checked: bool) -> Option<ParamLimit> {
    let limit = *limit_of(param)?;
    Some(match limit.unchecked {
        Some((max_abs, source)) if !heading_checked => ParamLimit {
            max_abs,
            source,
            ..limit
        },
        _ => limit,
    })
}

/// The effects the daemon can fit and apply to live readings, in catalogue
/// order.
pub fn live() -> Vec<Effect> {
    CATALOGUE
        .iter()
        .filter(|info| info.live)
        .map(|info| info.effect.clone())
        .collect()
}

impl Effect {
    /// The effect's entry in the [`CATALOGUE`].
    pub fn info(&self) -> &'static EffectInfo {
        &CATALOGUE[match self {
            Effect::Offset => 0,
            Effect::Scale => 1,
            Effect::CrossAxis => 2,
            Effect::Drift => 3,
            Effect::Covariate(_) => 4,
            Effect::Cubic => 5,
            Effect::CubicCentred => 6,
            Effect::Outliers => 7,
        }]
    }

    /// Unknowns the effect adds to the model (the paper's four are a, b, d, r).
    pub fn unknowns(&self) -> usize {
        self.info().params.len()
    }

    /// Whether the effect is part of the paper's model.
    pub fn is_paper(&self) -> bool {
        self.info().paper
    }

    /// Whether the daemon can fit it and apply it to live readings.
    pub fn is_live(&self) -> bool {
        self.info().live
    }

    /// Whether the 3-D fit has it.
    pub fn is_in_3d(&self) -> bool {
        self.info().in_3d
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Effect::Covariate(column) => write!(f, "{COVARIATE_PREFIX}{column}"),
            other => f.write_str(other.info().name),
        }
    }
}

impl Serialize for Effect {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl FromStr for Effect {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let text = text.trim();
        if let Some(column) = text.strip_prefix(COVARIATE_PREFIX) {
            if column.is_empty() {
                return Err("'covariate:' needs a column name, as in covariate:temp".into());
            }
            return Ok(Effect::Covariate(column.to_string()));
        }
        match CATALOGUE.iter().find(|info| info.name == text) {
            Some(info) => Ok(info.effect.clone()),
            None => {
                let names: Vec<&str> = CATALOGUE.iter().map(|info| info.name).collect();
                Err(format!(
                    "'{text}' is not an effect; the catalogue is {}",
                    names.join(", ")
                ))
            }
        }
    }
}

/// Parses a comma- or plus-separated list (`cross-axis,drift` or
/// `offset+scale+cubic`) into the paper's model plus those effects, sorted
/// and without repeats. `paper` stands for `offset+scale`.
pub fn parse_list(text: &str) -> Result<Vec<Effect>, String> {
    let mut effects: Vec<Effect> = PAPER.to_vec();
    for part in text
        .split([',', '+'])
        .map(str::trim)
        .filter(|p| !p.is_empty())
    {
        if part == "paper" {
            continue;
        }
        let effect: Effect = part.parse()?;
        if !effects.contains(&effect) {
            effects.push(effect);
        }
    }
    effects.sort();
    Ok(effects)
}

/// The model's name: its effects joined by `+` (the paper's: `offset+scale`).
pub fn model_name(effects: &[Effect]) -> String {
    effects
        .iter()
        .map(Effect::to_string)
        .collect::<Vec<_>>()
        .join("+")
}
