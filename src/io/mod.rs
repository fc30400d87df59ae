//! Files in and out: CSV recordings, atomic replacement, and the check that
//! an input is a regular file.

pub mod atomic;
pub mod csv;
pub mod regular;

use std::borrow::Cow;

/// Characters of a value from a file that a message repeats; longer ones
/// are cut (a 100 MB field must not be echoed whole to the log).
pub const MAX_ECHO_CHARS: usize = 48;
/// Column names a message lists before it says how many more there are.
pub const MAX_LISTED_NAMES: usize = 24;

/// `text` as a message quotes it: whole when short, else its first
/// [`MAX_ECHO_CHARS`] characters and its length in bytes.
pub fn excerpt(text: &str) -> Cow<'_, str> {
    match text.char_indices().nth(MAX_ECHO_CHARS) {
        None => Cow::Borrowed(text),
        Some((cut, _)) => Cow::Owned(format!("{}… ({} bytes)", &text[..cut], text.len())),
    }
}

/// Column names for a message, comma-separated, each through [`excerpt`],
/// at most [`MAX_LISTED_NAMES`] of them.
pub fn name_list<S: AsRef<str>>(names: &[S]) -> String {
    let mut out = names
        .iter()
        .take(MAX_LISTED_NAMES)
        .map(|n| excerpt(n.as_ref()))
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > MAX_LISTED_NAMES {
        out.push_str(&format!(" … and {} more", names.len() - MAX_LISTED_NAMES));
    }
    out
}
