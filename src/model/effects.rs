//! The catalogue of physical effects a model can add to the paper's, by the
//! names that are part of the interface (command line, configuration, JSON).

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

impl Effect {
    /// Unknowns the effect adds to the model (the paper's four are a, b, d, r).
    pub fn unknowns(&self) -> usize {
        match self {
            Effect::Offset | Effect::Scale | Effect::Outliers => 0,
            Effect::CrossAxis => 1,
            Effect::CubicCentred => 1,
            Effect::Drift | Effect::Covariate(_) | Effect::Cubic => 2,
        }
    }

    /// Whether the effect is part of the paper's model.
    pub fn is_paper(&self) -> bool {
        matches!(self, Effect::Offset | Effect::Scale)
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Effect::Offset => f.write_str("offset"),
            Effect::Scale => f.write_str("scale"),
            Effect::CrossAxis => f.write_str("cross-axis"),
            Effect::Drift => f.write_str("drift"),
            Effect::Covariate(column) => write!(f, "covariate:{column}"),
            Effect::Cubic => f.write_str("cubic"),
            Effect::CubicCentred => f.write_str("cubic-centred"),
            Effect::Outliers => f.write_str("outliers"),
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
        Ok(match text.trim() {
            "offset" => Effect::Offset,
            "scale" => Effect::Scale,
            "cross-axis" => Effect::CrossAxis,
            "drift" => Effect::Drift,
            "cubic" => Effect::Cubic,
            "cubic-centred" => Effect::CubicCentred,
            "outliers" => Effect::Outliers,
            other => match other.strip_prefix("covariate:") {
                Some(column) if !column.is_empty() => Effect::Covariate(column.to_string()),
                Some(_) => {
                    return Err("'covariate:' needs a column name, as in covariate:temp".into());
                }
                None => {
                    return Err(format!(
                        "'{other}' is not an effect; the catalogue is offset, scale, cross-axis, drift, covariate:<column>, cubic, cubic-centred, outliers"
                    ));
                }
            },
        })
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for name in [
            "offset",
            "scale",
            "cross-axis",
            "drift",
            "covariate:temp_c",
            "cubic",
            "cubic-centred",
            "outliers",
        ] {
            assert_eq!(name.parse::<Effect>().unwrap().to_string(), name);
        }
        assert!("magic".parse::<Effect>().unwrap_err().contains("catalogue"));
        assert!("covariate:".parse::<Effect>().is_err());
    }

    #[test]
    fn lists_always_hold_the_papers_model() {
        let effects = parse_list("drift, cross-axis").unwrap();
        assert_eq!(model_name(&effects), "offset+scale+cross-axis+drift");
        assert_eq!(model_name(&parse_list("paper").unwrap()), "offset+scale");
        assert_eq!(model_name(&parse_list("").unwrap()), "offset+scale");
    }
}
