//! A plain HTTP/1.x client over std's TcpStream, enough for the live page's
//! API, its server-sent events and chromedriver's WebDriver API, so the
//! tests need no HTTP crate.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use serde_json::Value;

#[derive(Debug)]
pub struct Response {
    pub status: u16,
    pub headers: String,
    pub body: Vec<u8>,
}

impl Response {
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.text()))
    }

    pub fn header(&self, name: &str) -> Option<String> {
        self.headers.lines().find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.trim()
                .eq_ignore_ascii_case(name)
                .then(|| v.trim().to_owned())
        })
    }
}

/// One request to `addr` (`127.0.0.1:PORT`), the connection closed after
/// it; the whole exchange within `timeout`.
pub fn request(
    addr: &str,
    method: &str,
    path: &str,
    body: Option<&str>,
    timeout: Duration,
) -> Response {
    let mut stream = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connect {addr}: {e}"));
    stream.set_read_timeout(Some(timeout)).unwrap();
    stream.set_write_timeout(Some(timeout)).unwrap();
    let body = body.unwrap_or("");
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    // Read by Content-Length or chunks: some servers (chromedriver) keep the
    // connection open whatever the request said.
    let mut reader = BufReader::new(stream);
    let mut head = String::new();
    loop {
        let mut line = String::new();
        let n = reader
            .read_line(&mut line)
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"));
        if n == 0 || line == "\r\n" || line == "\n" {
            break;
        }
        head.push_str(&line);
    }
    let status: u16 = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("bad status line: {head:?}"));
    let response = Response {
        status,
        headers: head,
        body: Vec::new(),
    };
    let mut body = Vec::new();
    if let Some(len) = response
        .header("content-length")
        .and_then(|v| v.parse::<usize>().ok())
    {
        body.resize(len, 0);
        reader
            .read_exact(&mut body)
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"));
    } else if response
        .header("transfer-encoding")
        .is_some_and(|v| v.eq_ignore_ascii_case("chunked"))
    {
        body = read_chunks(&mut reader);
    } else {
        reader
            .read_to_end(&mut body)
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"));
    }
    Response { body, ..response }
}

fn read_chunks(reader: &mut impl BufRead) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let mut size_line = String::new();
        if reader.read_line(&mut size_line).unwrap_or(0) == 0 {
            return out;
        }
        let size = usize::from_str_radix(size_line.split(';').next().unwrap_or("").trim(), 16)
            .unwrap_or_else(|_| panic!("bad chunk size {size_line:?}"));
        if size == 0 {
            let mut trailer = String::new();
            let _ = reader.read_line(&mut trailer);
            return out;
        }
        let start = out.len();
        out.resize(start + size, 0);
        reader.read_exact(&mut out[start..]).unwrap();
        let mut crlf = [0u8; 2];
        reader.read_exact(&mut crlf).unwrap();
    }
}

/// A server-sent-events connection, asked as HTTP/1.0 so the body comes
/// unchunked and ends when the server closes it.
pub struct Events {
    reader: BufReader<TcpStream>,
    pub status: u16,
}

impl Events {
    pub fn connect(addr: &str, path: &str) -> Events {
        let mut stream = TcpStream::connect(addr).unwrap_or_else(|e| panic!("connect {addr}: {e}"));
        stream
            .set_read_timeout(Some(Duration::from_secs(20)))
            .unwrap();
        write!(
            stream,
            "GET {path} HTTP/1.0\r\nHost: {addr}\r\nAccept: text/event-stream\r\n\r\n"
        )
        .unwrap();
        let mut reader = BufReader::new(stream);
        let mut status = 0;
        let mut line = String::new();
        loop {
            line.clear();
            reader.read_line(&mut line).unwrap();
            if status == 0 {
                status = line
                    .split_whitespace()
                    .nth(1)
                    .and_then(|s| s.parse().ok())
                    .unwrap_or_else(|| panic!("bad status line {line:?}"));
            }
            if line == "\r\n" || line == "\n" || line.is_empty() {
                break;
            }
        }
        Events { reader, status }
    }

    /// The socket, to stop reading (a slow client) or set timeouts.
    pub fn socket(&self) -> &TcpStream {
        self.reader.get_ref()
    }

    /// The daemon's JSON lines of the next event (comments skipped); None
    /// when the server closed the stream.
    pub fn next_lines(&mut self) -> Option<Vec<Value>> {
        let mut lines = Vec::new();
        let mut line = String::new();
        loop {
            line.clear();
            if self.reader.read_line(&mut line).ok()? == 0 {
                return None;
            }
            let text = line.trim_end_matches(['\r', '\n']);
            if text.is_empty() {
                if lines.is_empty() {
                    continue;
                }
                return Some(lines);
            }
            if let Some(data) = text.strip_prefix("data:") {
                let data = data.strip_prefix(' ').unwrap_or(data);
                lines.push(
                    serde_json::from_str(data).unwrap_or_else(|e| panic!("not JSON ({e}): {data}")),
                );
            }
        }
    }

    /// Lines until one satisfies `want` (returned with all before it).
    pub fn until(&mut self, timeout: Duration, want: impl Fn(&Value) -> bool) -> Vec<Value> {
        let deadline = Instant::now() + timeout;
        let mut seen = Vec::new();
        while Instant::now() < deadline {
            let Some(lines) = self.next_lines() else {
                break;
            };
            for line in lines {
                let done = want(&line);
                seen.push(line);
                if done {
                    return seen;
                }
            }
        }
        panic!(
            "no wanted line within {timeout:?}; last seen: {:?}",
            seen.last()
        );
    }
}

/// The address the daemon's log says the live page listens on.
pub fn live_address(log: &str) -> String {
    let start = log
        .find("live page at http://")
        .unwrap_or_else(|| panic!("no live page address in the log:\n{log}"))
        + "live page at http://".len();
    let rest = &log[start..];
    let end = rest.find('/').unwrap_or(rest.len());
    rest[..end].to_owned()
}

/// The configuration the page's in-process tests serve: the live page on a
/// free loopback port, recalibrate allowed from it, one 2-axis compass on
/// a replayed capture.
pub fn page_config() -> fieldcal::daemon::config::Config {
    let capture = super::repo_path("tests/data/falcon_turn.fcap");
    let text = format!(
        "[outputs]\nhttp = \"127.0.0.1:0\"\nrecalibrate_from = [\"unix\", \"http\"]\n[[source]]\nname = \"imu\"\nkind = \"replay\"\nfile = \"{}\"\n\
         [[sensor]]\nname = \"compass\"\nsource = \"imu\"\nfield = \"mag\"\naxes = [\"x\", \"y\"]\n",
        capture.display()
    );
    fieldcal::daemon::config::parse(&text, &super::repo_path("tests/data/x.toml")).unwrap()
}
