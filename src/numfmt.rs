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

/// A fraction as a percentage with two decimals ("0.52 %"); one beyond a
/// million percent (a reading off by orders of magnitude) in exponent
/// form ("1.00e151 %"), not as 150 digits.
pub fn percent(fraction: f64) -> String {
    let p = fraction * 100.0;
    if p.abs() < 1e6 || !p.is_finite() {
        format!("{p:.2} %")
    } else {
        format!("{p:.2e} %")
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_percentage_never_runs_to_hundreds_of_digits() {
        assert_eq!(super::percent(0.0052), "0.52 %");
        assert_eq!(super::percent(1e149), "1.00e151 %");
        assert_eq!(super::percent(-2e10), "-2.00e12 %");
    }
}
