//! The keys of a section whose kinds each take their own (a `[[source]]`,
//! `[outputs]`), read by type at their place in the file.

use super::*;

/// A section's keys as written, before a kind takes its own.
pub(crate) type RawKeys = std::collections::BTreeMap<String, toml::Value>;

/// A value as reading the document gives it to serde: a date-time is a
/// table there (so a string key refuses it, as "invalid type: map"), not
/// the text `toml::Value` would hand over.
fn as_read(value: &toml::Value) -> toml::Value {
    match value {
        toml::Value::Datetime(d) => {
            let mut table = toml::Table::new();
            table.insert("datetime".into(), toml::Value::String(d.to_string()));
            toml::Value::Table(table)
        }
        toml::Value::Array(items) => toml::Value::Array(items.iter().map(as_read).collect()),
        other => other.clone(),
    }
}

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
    /// refused with serde's words, at its place in the file (an array's
    /// element at its own, `chips[1]`), as reading the document did.
    pub fn get<T: serde::de::DeserializeOwned>(
        &self,
        name: &str,
    ) -> Result<Option<T>, ConfigError> {
        let Some(value) = self.values.get(name) else {
            return Ok(None);
        };
        let refused = |key: String, e: toml::de::Error| {
            self.checker.error(&key, e.message().trim_end().to_string())
        };
        match as_read(value).try_into::<T>() {
            Ok(v) => Ok(Some(v)),
            Err(e) => {
                if let toml::Value::Array(items) = value {
                    // The first element that is refused alone.
                    for (i, item) in items.iter().enumerate() {
                        let alone = toml::Value::Array(vec![as_read(item)]);
                        if let Err(e) = alone.try_into::<T>() {
                            return Err(refused(self.key(&format!("{name}[{i}]")), e));
                        }
                    }
                }
                Err(refused(self.key(name), e))
            }
        }
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
