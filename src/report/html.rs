//! The report page (`index.html`): the diagnosis text, then every figure.
//!
//! Self-contained on purpose: inline CSS, no scripts, no fonts or styles
//! from the network, so it opens the same on an air-gapped bench machine.

use super::plots::{Figure, ReportData};

/// Escapes text for HTML element content and double-quoted attributes.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Text as the terminal shows it (a diagnosis), escaped, in a `<pre>` of
/// one block per line: a line too long for the page wraps with a hanging
/// indent, so a wrapped row stays distinguishable from the next.
pub fn preformatted(text: &str) -> String {
    let lines: String = text
        .lines()
        .map(|line| format!("<span class=\"line\">{}</span>", escape(line)))
        .collect();
    format!("<pre>{lines}</pre>")
}

/// Escapes a file name for use as a relative URL in `src`: characters that
/// would change its meaning in a URL are percent-encoded, then the result is
/// attribute-escaped.
fn url(file: &str) -> String {
    let mut out = String::with_capacity(file.len());
    for b in file.bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' => out.push(char::from(b)),
            b => out.push_str(&format!("%{b:02X}")),
        }
    }
    escape(&out)
}

/// Nothing may run off the right edge at any width: the summary's lines
/// (the diagnosis as the terminal shows it, up to several hundred
/// characters) wrap inside the box, and a long token with no place to
/// break (a file name) breaks anywhere rather than widening the page.
const STYLE: &str = "\
body { font-family: sans-serif; margin: 2em auto; max-width: 1040px; padding: 0 1em; color: #222; overflow-wrap: anywhere; }
h1 { font-size: 1.5em; }
h2 { font-size: 1.15em; margin-top: 2em; }
.summary { background: #f6f6f6; border-left: 4px solid #1f77b4; padding: 0.5em 1em; max-width: 100%; box-sizing: border-box; }
.summary pre { white-space: pre-wrap; overflow-wrap: anywhere; font-size: 0.85em; line-height: 1.35; margin: 0.5em 0; }
.summary pre .line { display: block; min-height: 1.35em; padding-left: 4ch; text-indent: -4ch; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { color: #444; font-size: 0.95em; margin-top: 0.4em; }
footer { color: #777; font-size: 0.85em; margin-top: 3em; }
";

/// The 3-D report's page (`fit --z`, `diagnose --z`): wider, for the
/// ellipsoid's three views side by side.
const STYLE3: &str = "\
body { font-family: sans-serif; margin: 2em auto; max-width: 1240px; padding: 0 1em; color: #222; overflow-wrap: anywhere; }
.summary { background: #f6f6f6; border-left: 4px solid #1f77b4; padding: 0.5em 1em; }
.summary pre { white-space: pre-wrap; overflow-wrap: anywhere; font-size: 0.85em; }
.summary pre .line { display: block; min-height: 1.35em; padding-left: 4ch; text-indent: -4ch; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { color: #444; font-size: 0.95em; }
";

/// What sets one report page apart from another: its style sheet and the
/// words of its footer. The skeleton is [`render_page`]'s.
#[derive(Debug, Clone, Copy)]
pub struct PageKind {
    /// The CSS, one rule a line, each ending in a newline.
    pub style: &'static str,
    /// The footer's text (HTML, inserted as is).
    pub footer: &'static str,
}

/// The 2-D report's page (`fit`, `diagnose`): residuals shown in %.
pub const PAGE2: PageKind = PageKind {
    style: STYLE,
    footer: "Written by fieldcal. Residuals are |s|/r − 1, the magnitude error of a \
             calibrated sample as a fraction of the field, shown in %.",
};

/// The 3-D report's page (`fit --z`, `diagnose --z`).
pub const PAGE3: PageKind = PageKind {
    style: STYLE3,
    footer: "Written by fieldcal. Residuals are |s|/r − 1, the magnitude error of a \
             calibrated sample as a fraction of the field.",
};

/// Renders a report page of `kind`: the title, the summary, then every
/// figure under its title with its caption. `summary_html` is inserted as
/// is (the caller escapes it); every other text is escaped here.
pub fn render_page(kind: &PageKind, title: &str, summary_html: &str, figures: &[Figure]) -> String {
    let title = escape(title);
    let mut html = String::new();
    html.push_str("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n");
    html.push_str(&format!("<title>fieldcal report: {title}</title>\n"));
    html.push_str(&format!(
        "<style>\n{}</style>\n</head>\n<body>\n",
        kind.style
    ));
    html.push_str(&format!("<h1>fieldcal report: {title}</h1>\n"));
    html.push_str("<section class=\"summary\">\n");
    html.push_str(summary_html);
    html.push_str("\n</section>\n");
    for figure in figures {
        let id = figure.file.trim_end_matches(".svg");
        html.push_str(&format!(
            "<h2 id=\"{}\">{}</h2>\n<figure>\n<img src=\"{}\" alt=\"{}\">\n<figcaption>{}</figcaption>\n</figure>\n",
            escape(id),
            escape(&figure.title),
            url(&figure.file),
            escape(&figure.title),
            escape(&figure.caption),
        ));
    }
    html.push_str(&format!(
        "<footer>{}</footer>\n</body>\n</html>\n",
        kind.footer
    ));
    html
}

/// Renders the 2-D report's page.
pub fn render_index(data: &ReportData, figures: &[Figure]) -> String {
    render_page(&PAGE2, &data.title, &data.summary_html, figures)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup_and_quotes() {
        assert_eq!(
            escape("a<b>&\"c\"'d'"),
            "a&lt;b&gt;&amp;&quot;c&quot;&#39;d&#39;"
        );
        assert_eq!(url("a b\".svg"), "a%20b%22.svg");
    }

    #[test]
    fn preformatted_text_is_one_escaped_block_per_line() {
        assert_eq!(
            preformatted("a <b>\n\n  c"),
            "<pre><span class=\"line\">a &lt;b&gt;</span><span class=\"line\"></span>\
             <span class=\"line\">  c</span></pre>"
        );
    }

    /// The rules that keep the summary box inside the page (the browser
    /// test, tests/report_browser.rs, measures the layout where Chromium
    /// is installed).
    #[test]
    fn the_summary_wraps_inside_its_box() {
        let rule = |selector: &str| {
            STYLE
                .lines()
                .find(|l| l.starts_with(&format!("{selector} {{")))
                .unwrap_or_else(|| panic!("no rule for {selector}"))
        };
        let summary = rule(".summary");
        assert!(summary.contains("max-width: 100%;"), "{summary}");
        assert!(summary.contains("box-sizing: border-box;"), "{summary}");
        let pre = rule(".summary pre");
        assert!(pre.contains("white-space: pre-wrap;"), "{pre}");
        assert!(pre.contains("overflow-wrap: anywhere;"), "{pre}");
        assert!(rule("body").contains("overflow-wrap: anywhere;"));
    }
}
