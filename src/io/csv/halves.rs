//! A recording read on two cores: the calling thread reads the first half
//! of the file while another thread reads the rest, and the rows are joined
//! in file order, as one reader would have read them.
//!
//! The file is cut just after a newline near its middle. Such a newline
//! ends a record, unless it is inside a quoted field. So a quote (`"`)
//! anywhere in the file cancels the cut: the thread that sees one tells
//! the other to stop, and the calling thread reads on to the end alone.
//! The second half's lines are counted from the cut; its messages are
//! moved down by the first half's lines. When both halves have an error,
//! the first half's is the one reported, as one reader would have met it
//! first.

use std::fs::File;
use std::io::{self, Read};
use std::os::unix::fs::FileExt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::Scope;

use super::{Columns, CsvError, MAX_LINE_BYTES};

/// Files from this size are read on two cores. Starting and joining a
/// thread costs about 50 µs; one core reads about 100 MB of CSV a second,
/// so the half of 1 MiB read meanwhile saves about 5 ms, a hundred times
/// that.
const SPLIT_FROM_BYTES: u64 = 1 << 20;

#[cfg(test)]
thread_local! {
    /// Cuts taken on this thread (the other core's rows joined): for the
    /// tests to see that the second core really read.
    static CUTS_TAKEN: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// UTF-8's byte-order mark.
const BOM: &[u8] = b"\xEF\xBB\xBF";

/// Where the second half of a file of `size` bytes begins when it is read
/// on two cores: just after the first newline from its middle. `None` for
/// a small file, for one core, or when no newline comes within
/// [`MAX_LINE_BYTES`] of the middle.
pub(super) fn cut(file: &File, size: u64) -> Option<u64> {
    if size < SPLIT_FROM_BYTES || crate::parallel::cores() < 2 {
        return None;
    }
    cut_after(file, size / 2)
}

/// Just after the first newline at or after byte `from`, within
/// [`MAX_LINE_BYTES`].
pub(super) fn cut_after(file: &File, from: u64) -> Option<u64> {
    // Three bytes more than the newline is looked for in: the whole of a
    // byte-order mark just after it.
    let mut buf = vec![0; MAX_LINE_BYTES + BOM.len()];
    let n = file.read_at(&mut buf, from).ok()?;
    let newline = buf[..n.min(MAX_LINE_BYTES)]
        .iter()
        .position(|&b| b == b'\n')?;
    // A new reader would strip a byte-order mark there; one reader keeps
    // it (and refuses the field): leave such a file to one reader.
    if buf[newline + 1..n].starts_with(BOM) {
        return None;
    }
    Some(from + newline as u64 + 1)
}

/// A file read by position (no offset shared with another reader of it),
/// from `pos` up to `end` (`None`: to its end), noting whether its bytes
/// held a quote. A reader given `stop` ends when it is set.
pub(super) struct Positional<'f> {
    file: &'f File,
    pos: u64,
    end: Option<u64>,
    quoted: bool,
    stop: Option<Arc<AtomicBool>>,
}

impl Positional<'_> {
    /// The byte it reads next.
    pub(super) fn position(&self) -> u64 {
        self.pos
    }

    /// Whether a quote was among the bytes read.
    pub(super) fn quoted(&self) -> bool {
        self.quoted
    }
}

impl Read for Positional<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self
            .stop
            .as_ref()
            .is_some_and(|s| s.load(Ordering::Relaxed))
        {
            return Ok(0);
        }
        let room = match self.end {
            Some(end) => usize::try_from(end.saturating_sub(self.pos))
                .map_or(buf.len(), |left| left.min(buf.len())),
            None => buf.len(),
        };
        let n = self.file.read_at(&mut buf[..room], self.pos)?;
        self.pos += n as u64;
        self.quoted |= buf[..n].contains(&b'"');
        Ok(n)
    }
}

/// What the other core hands back: its rows (or its first error), and
/// whether it met a quote.
pub(super) struct Back {
    /// Its first error's line is counted from the cut (its line 1).
    pub rows: Result<Columns, CsvError>,
    pub quoted: bool,
}

/// Where the calling thread is with the cut.
enum Cut {
    /// Read to the end (a stream, a small file, a quote met).
    None,
    /// Stop here if another core takes the rest (none has yet).
    At(u64),
    /// Another core reads from here; its rows come through `back`.
    Handed { back: mpsc::Receiver<Back> },
    /// Stopped at the cut: the other core's rows, taken once.
    Stopped(Option<Back>),
}

/// What the calling thread reads: a stream, or a file, whole or up to the
/// cut while another core reads the rest.
pub(super) struct Front<'a> {
    source: Source<'a>,
    cut: Cut,
    /// Set when the other core's rows will not be used: it stops early.
    stop: Arc<AtomicBool>,
}

enum Source<'a> {
    Stream(Box<dyn Read + 'a>),
    File(Positional<'a>),
}

impl<'a> Front<'a> {
    /// Any reader, read whole on this thread.
    pub(super) fn stream(reader: impl Read + 'a) -> Self {
        Front {
            source: Source::Stream(Box::new(reader)),
            cut: Cut::None,
            stop: Arc::default(),
        }
    }

    /// A file, whose rest another core may read from `cut` (see
    /// [`Front::hand_over`]).
    pub(super) fn file(file: &'a File, cut: Option<u64>) -> Self {
        Front {
            source: Source::File(Positional {
                file,
                pos: 0,
                end: cut,
                quoted: false,
                stop: None,
            }),
            cut: cut.map_or(Cut::None, Cut::At),
            stop: Arc::default(),
        }
    }

    /// Starts `read` on another core over the file from the cut, when
    /// there is one and this thread has not passed it: then this thread
    /// stops at the cut, and [`Front::take_back`] gives the other core's
    /// rows. A thread that cannot be started leaves the rest to this one.
    pub(super) fn hand_over<'s>(
        &mut self,
        scope: &'s Scope<'s, '_>,
        read: impl FnOnce(Positional<'a>) -> Back + Send + 's,
    ) where
        'a: 's,
    {
        let (Cut::At(at), Source::File(bytes)) = (&self.cut, &self.source) else {
            return;
        };
        let rest = Positional {
            file: bytes.file,
            pos: *at,
            end: None,
            quoted: false,
            stop: Some(Arc::clone(&self.stop)),
        };
        let (tx, back) = mpsc::sync_channel(1);
        let spawned = std::thread::Builder::new()
            .name("csv-rest".into())
            .spawn_scoped(scope, move || {
                // Nobody waits for rows whose reader read on alone.
                let _ = tx.send(read(rest));
            });
        if spawned.is_ok() {
            self.cut = Cut::Handed { back };
        }
    }

    /// The other core's rows, once this thread has stopped at the cut.
    pub(super) fn take_back(&mut self) -> Option<Back> {
        match &mut self.cut {
            Cut::Stopped(back) => back.take(),
            _ => None,
        }
    }

    /// Tells the other core, if any, that its rows will not be used (this
    /// thread met an error first): it stops at its next read.
    pub(super) fn stop_rest(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Gives up the cut: this thread reads on to the end, and the other
    /// core (if any) stops.
    fn read_on_alone(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.cut = Cut::None;
        if let Source::File(bytes) = &mut self.source {
            bytes.end = None;
        }
    }
}

impl Read for Front<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            let bytes = match (&mut self.source, &self.cut) {
                (_, Cut::Stopped(_)) => return Ok(0),
                (Source::Stream(reader), _) => return reader.read(buf),
                (Source::File(bytes), _) => bytes,
            };
            let n = bytes.read(buf)?;
            if bytes.quoted && !matches!(self.cut, Cut::None) {
                // A newline may be inside quotes: no cut is safe.
                self.read_on_alone();
            }
            if n > 0 || matches!(self.cut, Cut::None) {
                return Ok(n);
            }
            // At the cut: the other core's rows follow these, unless it
            // met a quote (or nobody took the rest).
            if let Cut::Handed { back } = &self.cut
                && let Ok(back) = back.recv()
                && !back.quoted
            {
                self.cut = Cut::Stopped(Some(back));
                #[cfg(test)]
                CUTS_TAKEN.with(|taken| taken.set(taken.get() + 1));
                return Ok(0);
            }
            self.read_on_alone();
        }
    }
}

#[cfg(test)]
mod tests {
    use std::io::Write;
    use std::path::Path;

    use proptest::prelude::*;

    use super::super::{ColumnSpec, Covariates, RowsRead, parse_dataset, parse_dataset_sized};
    use super::*;

    /// What one reader makes of `text`, and what two make of it cut at
    /// every byte, as `Debug` (a dataset, or an error's message).
    fn one_and_every_cut(text: &str) -> (String, Vec<(u64, String)>) {
        let path = Path::new("rec.csv");
        let show = |read: Result<_, CsvError>| match read {
            Ok(data) => format!("{data:?}"),
            Err(e) => e.to_string(),
        };
        let one = show(parse_dataset(text.as_bytes(), path, &ColumnSpec::default()));
        let mut file = tempfile::tempfile().unwrap();
        file.write_all(text.as_bytes()).unwrap();
        let size = text.len() as u64;
        let every = (0..size)
            .map(|from| {
                let front = Front::file(&file, cut_after(&file, from));
                let mut rows = 0;
                let mut watch = |shown: RowsRead<'_>| rows = shown.x.len();
                let read = parse_dataset_sized(
                    front,
                    path,
                    &ColumnSpec::default(),
                    &Covariates::All,
                    size,
                    &mut watch,
                );
                let shown_all = read.as_ref().map_or(true, |d| d.x.len() == rows);
                (
                    from,
                    format!(
                        "{}{}",
                        show(read),
                        if shown_all {
                            ""
                        } else {
                            " (rows not all shown)"
                        }
                    ),
                )
            })
            .collect();
        (one, every)
    }

    fn same_at_every_cut(text: &str) {
        let (one, every) = one_and_every_cut(text);
        for (from, two) in every {
            assert_eq!(two, one, "cut from byte {from} of {text:?}");
        }
    }

    #[test]
    fn rows_read_in_two_halves_are_the_rows_one_reader_reads() {
        let text = "t,x,y,temp,label\n0,1.5,-2,20,a\n1,2.5,-3,21,b\n2,3.5,-4,22,c\n3,4.5,-5,23,d\n";
        let before = CUTS_TAKEN.with(std::cell::Cell::get);
        same_at_every_cut(text);
        // The other core read the rest at every cut from the first row on
        // (from bytes 17 to 72: 56 cuts, the last at the end of the file);
        // a cut after the header alone leaves the file to one reader.
        let taken = CUTS_TAKEN.with(std::cell::Cell::get) - before;
        assert_eq!(taken, 56, "cuts taken in {} bytes", text.len());
        // CRLF, comments, blank lines, no newline at the end.
        same_at_every_cut("t,x,y\r\n0,1,2\r\n# a note\r\n\r\n1,2,3\r\n\n2, 3 ,4\r\n3,4,5");
    }

    #[test]
    fn an_error_in_the_second_half_names_the_line_one_reader_names() {
        let rows: String = (0..12).map(|i| format!("{i},{i}.5,-{i}\n")).collect();
        for bad in ["7,x,8\n", "7,1\n", "7,1,2,3\n", "7,1e999,2\n"] {
            let text = format!("t,x,y\n# first\n{rows}{bad}\n{rows}");
            let (one, _) = one_and_every_cut(&text);
            assert!(one.starts_with("rec.csv:15: "), "{one}");
            same_at_every_cut(&text);
        }
        // The same in CRLF, after a blank line: the line it is on.
        let crlf = rows.replace('\n', "\r\n");
        for bad in ["7,x,8\r\n", "7,1\r\n"] {
            let text = format!("t,x,y\r\n# first\r\n\r\n{crlf}{bad}\r\n{crlf}");
            let (one, _) = one_and_every_cut(&text);
            assert!(one.starts_with("rec.csv:16: "), "{one}");
            same_at_every_cut(&text);
        }
        // Both halves wrong: the first one's error, whatever the cut.
        same_at_every_cut(&format!("t,x,y\n0,a,1\n{rows}1,2\n"));
    }

    #[test]
    fn a_quote_anywhere_leaves_the_file_to_one_reader() {
        // A newline inside quotes is no end of a record, wherever the cut.
        same_at_every_cut("t,x,y,note\n0,1,2,\"a\nb\"\n1,2,3,c\n2,3,4,\"d\n\ne\"\n3,4,5,f\n");
        same_at_every_cut("t,x,y\n0,1,2\n1,\"2\n\",3\n2,3,4\n");
        // A byte-order mark after a newline stays in its field.
        same_at_every_cut("t,x,y\n0,1,2\n\u{feff}1,2,3\n2,3,4\n");
    }

    #[test]
    fn a_byte_order_mark_just_past_the_window_still_forbids_the_cut() {
        let mut file = tempfile::tempfile().unwrap();
        let mut bytes = vec![b'1'; MAX_LINE_BYTES - 1];
        bytes.push(b'\n');
        bytes.extend_from_slice(BOM);
        bytes.extend_from_slice(b"1,2,3\n");
        file.write_all(&bytes).unwrap();
        assert_eq!(cut_after(&file, 0), None);
        // Without the mark, the cut is just after that newline.
        file.set_len(MAX_LINE_BYTES as u64).unwrap();
        file.write_all_at(b"1,2,3\n", MAX_LINE_BYTES as u64)
            .unwrap();
        assert_eq!(cut_after(&file, 0), Some(MAX_LINE_BYTES as u64));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn any_recording_reads_the_same_on_two_cores(
            rows in prop::collection::vec((-1e3f64..1e3, 0u8..13), 1..12),
        ) {
            let mut text = String::from("t,x,y\n");
            for (i, (v, kind)) in rows.iter().enumerate() {
                let line = match kind {
                    0 => format!("{i},{v},{v}\r\n"),
                    1 => "# note\n".to_string(),
                    2 => "\n".to_string(),
                    3 => format!("{i},{v}\n"),
                    4 => format!("{i},\"{v}\",1\n"),
                    5 => format!("{i},?,1\n"),
                    // A lone CR: the crate reads from here.
                    6 => format!("{i},{v},1\r{i},{v},2\n"),
                    _ => format!("{i},{v},{}\n", -v),
                };
                text.push_str(&line);
            }
            let (one, every) = one_and_every_cut(&text);
            for (from, two) in every {
                prop_assert_eq!(&two, &one, "cut from byte {} of {:?}", from, text);
            }
        }
    }
}
