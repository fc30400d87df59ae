//! Writing to stdout.

use std::io::Write;

use anyhow::{Context, Result};

/// Writes to stdout; a closed pipe (`| head`) ends quietly, not with a panic.
pub fn write_stdout(bytes: &[u8]) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(bytes).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other.context("cannot write to stdout")?),
    }
}
