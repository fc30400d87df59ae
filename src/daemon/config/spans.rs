//! Where a key is in the file: dotted keys (`sensor[1].axes`) looked up
//! in the spanned TOML document, and positions (line, column) for errors.

use super::*;

impl Checker<'_> {
    /// The span of the value at a dotted key such as `sensor[1].axes`, or
    /// of the nearest enclosing one that is in the file.
    pub(super) fn span_of(&self, key: &str) -> Option<Range<usize>> {
        self.lookup(key).0
    }

    /// The span of the value at a dotted key or of the nearest enclosing
    /// one that is in the file, and the value itself when it is.
    fn lookup(&self, key: &str) -> (Option<Range<usize>>, Option<&Spanned<DeValue<'_>>>) {
        let mut best: Option<Range<usize>> = None;
        let mut table: &DeTable = self.doc.get_ref();
        let mut value: Option<&Spanned<DeValue>> = None;
        for part in key.split('.').filter(|p| !p.is_empty()) {
            let (name, index) = match part.split_once('[') {
                Some((name, rest)) => (name, rest.trim_end_matches(']').parse::<usize>().ok()),
                None => (part, None),
            };
            if let Some(v) = value {
                match v.get_ref() {
                    DeValue::Table(t) => table = t,
                    _ => return (best, None),
                }
            }
            let Some(v) = table.get(name) else {
                return (best, None);
            };
            best = Some(v.span());
            value = Some(v);
            if let Some(i) = index {
                let DeValue::Array(items) = v.get_ref() else {
                    return (best, None);
                };
                let Some(item) = items.get(i) else {
                    return (best, None);
                };
                best = Some(item.span());
                value = Some(item);
            }
        }
        (best, value)
    }

    /// Where the key (not its value) of a dotted key such as
    /// `source[0].buad` starts, if it is in the file.
    pub(super) fn key_start(&self, key: &str) -> Option<usize> {
        let (table, name) = key.rsplit_once('.')?;
        let DeValue::Table(t) = self.lookup(table).1?.get_ref() else {
            return None;
        };
        t.iter()
            .find(|(k, _)| k.get_ref() == name)
            .map(|(k, _)| k.span().start)
    }
}

pub(super) fn located(path: &Path, position: &Option<Position>) -> String {
    match position {
        Some(p) => format!("{}:{p}", path.display()),
        None => path.display().to_string(),
    }
}

pub(super) fn type_name(value: &toml::Value) -> &'static str {
    match value {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date-time",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

/// 1-based line and column (in characters) of a byte offset.
pub(super) fn position_of(text: &str, offset: usize) -> Position {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = text[line_start..offset].chars().count() + 1;
    Position { line, column }
}

/// The dotted key whose key or value span holds byte `pos`: the smallest
/// such span wins, so an error inside `axes = ["x", "w"]` is `axes[1]`.
pub(super) fn path_at(doc: &Spanned<DeTable>, pos: usize) -> Option<String> {
    let mut best: Option<(usize, String)> = None;
    let mut path = String::new();
    walk_table(doc.get_ref(), &mut path, pos, &mut best);
    best.map(|(_, p)| p)
}

pub(super) fn contains(span: &Range<usize>, pos: usize) -> bool {
    span.contains(&pos) || (span.is_empty() && span.start == pos)
}

pub(super) fn consider(
    best: &mut Option<(usize, String)>,
    span: Range<usize>,
    path: &str,
    pos: usize,
) {
    if !contains(&span, pos) {
        return;
    }
    let len = span.len();
    // Ties go to the later (deeper) candidate.
    if best.as_ref().is_none_or(|(l, _)| len <= *l) {
        *best = Some((len, path.to_string()));
    }
}

pub(super) fn walk_table(
    table: &DeTable,
    path: &mut String,
    pos: usize,
    best: &mut Option<(usize, String)>,
) {
    for (key, value) in table.iter() {
        let saved = path.len();
        if !path.is_empty() {
            path.push('.');
        }
        path.push_str(key.get_ref());
        consider(best, key.span(), path, pos);
        walk_value(value, path, pos, best);
        path.truncate(saved);
    }
}

pub(super) fn walk_value(
    value: &Spanned<DeValue>,
    path: &mut String,
    pos: usize,
    best: &mut Option<(usize, String)>,
) {
    match value.get_ref() {
        DeValue::Table(t) => {
            // A table's own span (a header, or an inline table) loses to
            // any of its keys that also holds the position.
            consider(best, value.span(), path, pos);
            walk_table(t, path, pos, best);
        }
        DeValue::Array(items) => {
            consider(best, value.span(), path, pos);
            for (i, item) in items.iter().enumerate() {
                let saved = path.len();
                path.push_str(&format!("[{i}]"));
                walk_value(item, path, pos, best);
                path.truncate(saved);
            }
        }
        _ => consider(best, value.span(), path, pos),
    }
}
