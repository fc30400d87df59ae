//! The columns a csv source's sensor names, found in its files' headers:
//! errors name the key, the file and the columns there are.

use super::*;

/// A csv source's files and their headers, as its sensors' columns are
/// looked up in them.
pub(super) struct Columns<'c> {
    pub(super) checker: &'c Checker<'c>,
    pub(super) layouts: &'c [CsvLayout],
    pub(super) paths: &'c [PathBuf],
    /// The files' names, "a.csv or b.csv", for messages.
    pub(super) file: String,
}

impl Columns<'_> {
    /// Where column `name` is: (file index, name); errors name the key `k`
    /// and say what the column should hold (`what`).
    pub(super) fn find(
        &self,
        k: String,
        name: &str,
        what: &str,
    ) -> Result<(usize, String), ConfigError> {
        let file = &self.file;
        let name = name.trim();
        let mut hit: Option<usize> = None;
        for (f, layout) in self.layouts.iter().enumerate() {
            let Some(i) = layout.index(name) else {
                continue;
            };
            let this = self.name_of(f);
            if Some(i) == layout.time_index() {
                return Err(self.checker.error(
                    &k,
                    format!("'{name}' is the time column of {this}: give a column of {what}"),
                ));
            }
            if let Some(first) = hit {
                let that = self.name_of(first);
                return Err(self.checker.error(
                    &k,
                    format!(
                        "'{name}' is a column of both {that} and {this}: the files of one \
                         source must not share a column a sensor reads (rename it in one of \
                         them)"
                    ),
                ));
            }
            hit = Some(f);
        }
        if let Some(f) = hit {
            return Ok((f, name.to_string()));
        }
        let device = matches!(name, "x" | "y" | "z")
            .then_some(
                " (a csv source's sensors name columns of the file, not the x, y, z \
                 of a device)",
            )
            .unwrap_or_default();
        Err(self.checker.error(
            &k,
            match self.layouts {
                [layout] => format!(
                    "{file}:{}: no column '{name}' in the header (columns: {}): give a \
                     column of {what}{device}",
                    layout.header_line,
                    layout.available()
                ),
                _ => format!(
                    "no column '{name}' in the headers of {file} (columns: {}): give a \
                     column of {what}{device}",
                    self.layouts
                        .iter()
                        .zip(self.paths)
                        .map(|(l, p)| format!("{} in {}", l.available(), p.display()))
                        .collect::<Vec<_>>()
                        .join("; ")
                ),
            },
        ))
    }

    /// The name of file `f`, for messages.
    pub(super) fn name_of(&self, f: usize) -> String {
        self.paths
            .get(f)
            .map(|p| p.display().to_string())
            .unwrap_or_default()
    }

    /// Every column of one sensor from one file: `found[0]`'s.
    pub(super) fn one_file(
        &self,
        found: &[(usize, String)],
        keys: &[String],
    ) -> Result<usize, ConfigError> {
        let first = found.first().map_or(0, |f| f.0);
        for ((f, name), k) in found.iter().zip(keys) {
            if *f != first {
                let of = |f: usize| self.name_of(f);
                return Err(self.checker.error(
                    k,
                    format!(
                        "'{name}' is a column of {}, but '{}' is of {}: a row carries only \
                         its own file's columns, so a sensor's columns must all come from \
                         one file",
                        of(*f),
                        found[0].1,
                        of(first)
                    ),
                ));
            }
        }
        Ok(first)
    }
}
