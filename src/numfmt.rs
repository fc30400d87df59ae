//! Number formatting shared by the models' texts and the reports: a value
//! with a given number of significant digits. Here, below both `model` and
//! `report`, so the models need not reach up into the reports for it.

/// Formats a number with `digits` significant digits, without exponent for
/// the magnitudes sensor readings take, so columns of raw counts and unit
/// fractions both read naturally.
pub fn significant(value: f64, digits: usize) -> String {
    if value == 0.0 || !value.is_finite() {
        return format!("{value}");
    }
    let magnitude = value.abs().log10().floor() as i32;
    if !(-5..=12).contains(&magnitude) {
        return format!("{:.*e}", digits.saturating_sub(1), value);
    }
    let decimals = (digits as i32 - 1 - magnitude).max(0) as usize;
    format!("{value:.decimals$}")
}
