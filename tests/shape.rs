//! The code's shape, held to the limits in docs/layout.md: no source file
//! over 1,000 lines before its unit tests, and no function over 150 lines.
//! A file or function that grows past them is split by responsibility
//! (docs/layout.md says where things go), not exempted here.
//!
//! `cargo test --test shape -- --nocapture` prints the figures.

use std::fs;
use std::path::{Path, PathBuf};

/// Lines of a source file before its unit tests, at most.
const MAX_FILE_LINES: usize = 1_000;
/// Lines of one function, at most.
const MAX_FUNCTION_LINES: usize = 150;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The lines before `#[cfg(test)] mod tests` (the whole file if none).
fn code_lines(text: &str) -> Vec<&str> {
    let lines: Vec<&str> = text.lines().collect();
    let end = lines
        .windows(2)
        .position(|w| {
            w[0].starts_with("#[cfg(test)]")
                && w[1]
                    .trim_start()
                    .trim_start_matches("pub ")
                    .starts_with("mod ")
        })
        .unwrap_or(lines.len());
    lines[..end].to_vec()
}

/// A line with string and char literals and `//` comments blanked, so
/// their braces are not counted.
fn braces_of(line: &str) -> (usize, usize) {
    let (mut open, mut close) = (0, 0);
    let mut chars = line.chars().peekable();
    let mut in_string = false;
    while let Some(c) = chars.next() {
        match c {
            '\\' if in_string => {
                chars.next();
            }
            '"' => in_string = !in_string,
            '/' if !in_string && chars.peek() == Some(&'/') => break,
            '\'' if !in_string => {
                // A char literal such as '{' or '\n'; a lifetime has no
                // closing quote within three characters.
                let ahead: Vec<char> = chars.clone().take(3).collect();
                if ahead.get(1) == Some(&'\'') {
                    chars.nth(1);
                } else if ahead.first() == Some(&'\\') && ahead.get(2) == Some(&'\'') {
                    chars.nth(2);
                }
            }
            '{' if !in_string => open += 1,
            '}' if !in_string => close += 1,
            _ => {}
        }
    }
    (open, close)
}

fn is_fn_start(line: &str) -> Option<&str> {
    let mut rest = line.trim_start();
    for prefix in [
        "pub(crate) ",
        "pub(super) ",
        "pub ",
        "const ",
        "async ",
        "unsafe ",
    ] {
        rest = rest.strip_prefix(prefix).unwrap_or(rest);
    }
    let rest = rest.strip_prefix("fn ")?;
    Some(rest.split(['(', '<']).next().unwrap_or(rest))
}

/// Every function of `lines` with its length in lines.
fn functions<'a>(lines: &[&'a str]) -> Vec<(&'a str, usize, usize)> {
    let mut found = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        if let Some(name) = is_fn_start(lines[i]) {
            let (mut depth, mut started) = (0usize, false);
            let mut j = i;
            while j < lines.len() {
                let (open, close) = braces_of(lines[j]);
                if open > 0 {
                    started = true;
                }
                depth = (depth + open).saturating_sub(close);
                if (started && depth == 0) || (!started && lines[j].trim_end().ends_with(';')) {
                    break;
                }
                j += 1;
            }
            found.push((name, i + 1, j - i + 1));
        }
        i += 1;
    }
    found
}

#[test]
fn no_file_or_function_outgrows_its_limit() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    let (mut total, mut too_long) = (0, Vec::new());
    let mut longest = (String::new(), String::new(), 0);
    let mut largest = (String::new(), 0);
    for file in &files {
        let text = fs::read_to_string(file).expect("source file");
        let name = file
            .strip_prefix(&root)
            .unwrap_or(file)
            .display()
            .to_string();
        total += text.lines().count();
        let code = code_lines(&text);
        if code.len() > largest.1 {
            largest = (name.clone(), code.len());
        }
        if code.len() > MAX_FILE_LINES {
            too_long.push(format!("{name}: {} lines before its tests", code.len()));
        }
        for (function, line, length) in functions(&code) {
            if length > longest.2 {
                longest = (function.to_string(), format!("{name}:{line}"), length);
            }
            if length > MAX_FUNCTION_LINES {
                too_long.push(format!("{name}:{line}: fn {function} has {length} lines"));
            }
        }
    }
    println!(
        "src/: {total} lines in {} files; largest {} ({} lines before its tests); longest fn {} at {} ({} lines)",
        files.len(),
        largest.0,
        largest.1,
        longest.0,
        longest.1,
        longest.2
    );
    assert!(
        too_long.is_empty(),
        "over the limits of docs/layout.md ({MAX_FILE_LINES} lines a file, {MAX_FUNCTION_LINES} a function):\n{}",
        too_long.join("\n")
    );
}

#[test]
fn the_measure_counts_what_it_should() {
    let text = "fn a() {\n    let s = \"}\";\n    let c = '{';\n    // }\n}\n\
                pub(crate) fn b<T>(x: T) -> T {\n    x\n}\n\
                fn decl();\n\
                #[cfg(test)]\nmod tests {\n    fn c() {}\n}\n";
    let code = code_lines(text);
    assert_eq!(code.len(), 9);
    assert_eq!(
        functions(&code),
        vec![("a", 1, 5), ("b", 6, 3), ("decl", 9, 1)]
    );
}
