//! The keys of a section whose kinds each take their own (a `[[source]]`,
//! `[outputs]`), read by type at their place in the file.

use super::*;

/// A section's keys as written, before a kind takes its own.
pub(crate) type RawKeys = std::collections::BTreeMap<String, toml::Value>;

/// The keys of one section (a `[[source]]` besides its name, kind and
/// retry_s, or `[outputs]`), with the checker that reports their errors
/// at their place in the file.
pub(crate) struct Keys<'c, 'a> {
    pub(crate) checker: &'c Checker<'a>,
    /// The section's dotted key, such as `source[N]` or `outputs`.
    pub(crate) key: String,
    /// The kind being checked (a source's or an output's).
    pub(crate) kind: &'static str,
    pub(crate) values: &'c RawKeys,
}

impl<'a> Keys<'_, 'a> {
    /// The checker, for the checks that sources share.
    pub fn checker(&self) -> &Checker<'a> {
        self.checker
    }

    /// The dotted key of `name` in this section, such as `source[0].baud`.
    pub fn key(&self, name: &str) -> String {
        format!("{}.{name}", self.key)
    }

    /// The section's own dotted key.
    pub fn section(&self) -> &str {
        &self.key
    }

    /// The raw value of `name`, if given.
    pub fn raw(&self, name: &str) -> Option<&toml::Value> {
        self.values.get(name)
    }

    /// The value of `name` as a `T`, if given; a value of the wrong type is
    /// refused with serde's words, at its place in the file.
    pub fn get<T: serde::de::DeserializeOwned>(
        &self,
        name: &str,
    ) -> Result<Option<T>, ConfigError> {
        let Some(value) = self.values.get(name) else {
            return Ok(None);
        };
        value.clone().try_into::<T>().map(Some).map_err(|e| {
            self.checker
                .error(&self.key(name), e.message().trim_end().to_string())
        })
    }

    /// An error about `name`, at its place in the file.
    pub fn error(&self, name: &str, problem: impl Into<String>) -> ConfigError {
        self.checker.error(&self.key(name), problem)
    }
}

impl Checker<'_> {
    /// The first of `values` (by its place in the file) that is not in
    /// `allowed`, refused in serde's words at the key, as
    /// `deny_unknown_fields` would.
    pub(super) fn refuse_unknown(
        &self,
        section: &str,
        values: &RawKeys,
        allowed: &[&str],
    ) -> Result<(), ConfigError> {
        let unknown = values
            .keys()
            .filter(|name| !allowed.contains(&name.as_str()))
            .map(|name| (self.key_start(&format!("{section}.{name}")), name))
            .min();
        let Some((start, name)) = unknown else {
            return Ok(());
        };
        let expected: Vec<String> = allowed.iter().map(|k| format!("`{k}`")).collect();
        Err(ConfigError::Invalid {
            path: self.path.to_path_buf(),
            key: format!("{section}.{name}"),
            position: start.map(|at| position_of(self.text, at)),
            problem: format!(
                "unknown field `{name}`, expected one of {}",
                expected.join(", ")
            ),
        })
    }
}
