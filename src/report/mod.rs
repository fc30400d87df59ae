//! What fieldcal tells a person (text) or a program (JSON) about its work.

mod chart;
pub mod diagnosis;
pub mod diagnosis3;
pub mod fit;
pub mod fit3;
pub mod heading;
pub mod html;
pub mod plots;
pub mod plots3;
mod scale;

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

#[cfg(test)]
mod tests {
    use super::significant;

    #[test]
    fn significant_digits() {
        assert_eq!(significant(1.234567891, 6), "1.23457");
        assert_eq!(significant(-24000.123456, 6), "-24000.1");
        assert_eq!(significant(0.000123456789, 4), "0.0001235");
        assert_eq!(significant(0.0, 6), "0");
        assert_eq!(significant(1.5e-9, 3), "1.50e-9");
    }
}
