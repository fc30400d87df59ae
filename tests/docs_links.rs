//! The README and the documents under docs/ link to each other and to files
//! of the repository by relative paths: every such link must lead to a file
//! that exists, and a `#fragment` into a markdown file to one of its
//! headings (as GitHub makes anchors of them). Links inside code and inside
//! HTML comments (placeholders) are not links.

use std::fs;
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The markdown files whose links are checked.
fn documents() -> Vec<PathBuf> {
    let root = repo();
    let mut files = vec![
        root.join("README.md"),
        root.join("tests/data/README.md"),
        root.join("config/README.md"),
    ];
    let mut docs: Vec<PathBuf> = fs::read_dir(root.join("docs"))
        .expect("docs/ exists")
        .map(|e| e.expect("docs/ entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

/// The text outside fenced code blocks, with inline code and HTML comments
/// removed.
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if !fenced {
            out.push_str(line);
            out.push('\n');
        }
    }
    let out = strip_between(&out, "<!--", "-->");
    strip_between(&out, "`", "`")
}

fn strip_between(text: &str, open: &str, close: &str) -> String {
    let mut out = String::new();
    let mut rest = text;
    while let Some(start) = rest.find(open) {
        out.push_str(&rest[..start]);
        match rest[start + open.len()..].find(close) {
            Some(end) => rest = &rest[start + open.len() + end + close.len()..],
            None => {
                rest = "";
            }
        }
    }
    out.push_str(rest);
    out
}

/// Targets of `[text](target)` links.
fn links(prose: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = prose;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        let end = after
            .find(|c: char| c == ')' || c.is_whitespace())
            .unwrap_or(after.len());
        out.push(after[..end].to_string());
        rest = &after[end..];
    }
    out
}

/// GitHub's anchor of a heading: lower case, punctuation dropped, spaces
/// to hyphens.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == '-' || *c == ' ' || *c == '_')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

fn anchors(file: &Path) -> Vec<String> {
    let text = fs::read_to_string(file).expect("linked markdown file reads");
    let mut fenced = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced && line.starts_with('#') {
            out.push(slug(line.trim_start_matches('#').replace('`', "").as_str()));
        }
    }
    out
}

/// Every broken relative link of one file, as "file: target: why".
fn broken(file: &Path) -> (usize, Vec<String>) {
    let text = fs::read_to_string(file).expect("document reads");
    let dir = file.parent().expect("a file has a directory");
    let mut checked = 0;
    let mut bad = Vec::new();
    for target in links(&prose(&text)) {
        if target.contains("://") || target.starts_with("mailto:") {
            continue;
        }
        checked += 1;
        let (path, fragment) = match target.split_once('#') {
            Some((p, f)) => (p, Some(f)),
            None => (target.as_str(), None),
        };
        let full = if path.is_empty() {
            file.to_path_buf()
        } else {
            dir.join(path)
        };
        if !full.exists() {
            bad.push(format!("{}: {target}: no such file", file.display()));
        } else if let Some(fragment) = fragment
            && full.extension().is_some_and(|e| e == "md")
            && !anchors(&full).iter().any(|a| a == fragment)
        {
            bad.push(format!(
                "{}: {target}: no heading #{fragment} in {}",
                file.display(),
                full.display()
            ));
        }
    }
    (checked, bad)
}

#[test]
fn relative_links_of_the_readme_and_docs_lead_somewhere() {
    let mut checked = 0;
    let mut bad = Vec::new();
    for file in documents() {
        let (n, b) = broken(&file);
        checked += n;
        bad.extend(b);
    }
    assert!(
        bad.is_empty(),
        "broken links ({} of {checked}):\n{}",
        bad.len(),
        bad.join("\n")
    );
    // The README alone links to docs/ and config/ more than a dozen times:
    // a checker that finds none is broken itself.
    assert!(checked > 20, "only {checked} links found");
}

#[test]
fn the_checker_finds_a_missing_file_and_a_missing_heading() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let doc = dir.path().join("doc.md");
    fs::write(
        &doc,
        "# Title\n## `fieldcal run` here\n[a](missing.md) [b](doc.md#fieldcal-run-here) \
         [c](doc.md#nowhere) `[d](in-code.md)` <!-- [e](comment.md) -->\n\
         ```\n[f](fenced.md)\n```\n[g](https://example.org/x)\n",
    )
    .expect("write");
    let (checked, bad) = broken(&doc);
    assert_eq!(checked, 3, "{bad:?}");
    assert_eq!(bad.len(), 2, "{bad:?}");
    assert!(bad[0].ends_with("missing.md: no such file"), "{bad:?}");
    assert!(bad[1].contains("no heading #nowhere"), "{bad:?}");
}
