//! The command protocol: one JSON object a line from a subscriber, split
//! off its byte stream ([`LineSplitter`]), parsed ([`parse_request`]), and
//! answered with an `{"class":"ERROR",...}` line ([`error_line`]) when it is
//! not a command the daemon takes.

use std::fmt;
use std::sync::Arc;

use serde_json::Value;

/// Longest command line accepted, without its newline. Commands are short;
/// the limit keeps a client from growing the daemon's memory.
pub const MAX_COMMAND_LEN: usize = 4096;

/// What every refused command line is told is allowed.
const ALLOWED: &str = r#"allowed: {"command":"recalibrate"} and {"command":"rollback"}, each with an optional "sensor":"<name>" (and "token":"<token>" where one is configured), and {"command":"status"}, one JSON object a line"#;

/// A command a subscriber sent.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientCommand {
    /// Start a new calibration of one sensor, or of all when `None`.
    Recalibrate { sensor: Option<String> },
    /// Return to the calibration before the current one, of one sensor or
    /// of all when `None`; the same rights as `Recalibrate`.
    Rollback { sensor: Option<String> },
    /// Send a STATUS line back to the asking subscriber.
    Status,
}

/// What is wrong with a command line; the message is sent back to the
/// client, so it says what is allowed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    #[error("command line longer than {limit} bytes; discarded up to the next newline; {allowed}", allowed = ALLOWED)]
    TooLong { limit: usize },
    #[error("command line is not UTF-8 text; {allowed}", allowed = ALLOWED)]
    NotUtf8,
    #[error("command line is not JSON ({0}); {allowed}", allowed = ALLOWED)]
    NotJson(String),
    #[error("command is a JSON {0}, not an object; {allowed}", allowed = ALLOWED)]
    NotObject(&'static str),
    #[error("command object has no \"command\" field; {allowed}", allowed = ALLOWED)]
    MissingCommand,
    #[error("\"command\" must be a string; {allowed}", allowed = ALLOWED)]
    CommandNotString,
    #[error("unknown command {0:?}; {allowed}", allowed = ALLOWED)]
    UnknownCommand(String),
    #[error("unknown field {field:?} in a {command:?} command; {allowed}", allowed = ALLOWED)]
    UnknownField { command: String, field: String },
    #[error("\"sensor\" must be a non-empty string naming a configured sensor; {allowed}", allowed = ALLOWED)]
    BadSensor,
    #[error("\"token\" must be a string; {allowed}", allowed = ALLOWED)]
    BadToken,
    /// Not allowed from this subscriber; the message says what to configure.
    #[error("{0}")]
    Refused(String),
    #[error("key {0:?} is given twice in the command object; give each key once; {allowed}", allowed = ALLOWED)]
    DuplicateKey(String),
}

/// A parsed command line: the command and the token it carried, if any.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    pub command: ClientCommand,
    pub token: Option<String>,
}

/// A top-level JSON value, objects kept as their entries in order, so a
/// key given twice can be told (serde_json's `Value` keeps the last).
enum TopLevel {
    Object(Vec<(String, Value)>),
    Other(&'static str),
}

impl<'de> serde::Deserialize<'de> for TopLevel {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<TopLevel, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = TopLevel;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a JSON value")
            }
            fn visit_bool<E>(self, _: bool) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("boolean"))
            }
            fn visit_i64<E>(self, _: i64) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("number"))
            }
            fn visit_u64<E>(self, _: u64) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("number"))
            }
            fn visit_f64<E>(self, _: f64) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("number"))
            }
            fn visit_str<E>(self, _: &str) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("string"))
            }
            fn visit_unit<E>(self) -> Result<TopLevel, E> {
                Ok(TopLevel::Other("null"))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<TopLevel, A::Error> {
                while seq.next_element::<serde::de::IgnoredAny>()?.is_some() {}
                Ok(TopLevel::Other("array"))
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<TopLevel, A::Error> {
                let mut entries = Vec::new();
                while let Some((k, v)) = map.next_entry::<String, Value>()? {
                    entries.push((k, v));
                }
                Ok(TopLevel::Object(entries))
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// Parses one command line (without its newline).
pub fn parse_command(line: &[u8]) -> Result<ClientCommand, CommandError> {
    parse_request(line).map(|r| r.command)
}

/// Parses one command line (without its newline), with its `"token"`.
pub fn parse_request(line: &[u8]) -> Result<Request, CommandError> {
    let text = std::str::from_utf8(line).map_err(|_| CommandError::NotUtf8)?;
    let top: TopLevel =
        serde_json::from_str(text).map_err(|e| CommandError::NotJson(e.to_string()))?;
    let entries = match top {
        TopLevel::Object(entries) => entries,
        TopLevel::Other(kind) => return Err(CommandError::NotObject(kind)),
    };
    let mut map = serde_json::Map::new();
    for (key, value) in entries {
        if map.contains_key(&key) {
            return Err(CommandError::DuplicateKey(key));
        }
        map.insert(key, value);
    }
    let token = match map.get("token") {
        None => None,
        Some(Value::String(t)) => Some(t.clone()),
        Some(_) => return Err(CommandError::BadToken),
    };
    let command = match map.get("command") {
        None => return Err(CommandError::MissingCommand),
        Some(Value::String(s)) => s.as_str(),
        Some(_) => return Err(CommandError::CommandNotString),
    };
    let fields: &[&str] = match command {
        "recalibrate" | "rollback" => &["command", "sensor", "token"],
        "status" => &["command", "token"],
        other => return Err(CommandError::UnknownCommand(other.to_owned())),
    };
    if let Some(field) = map.keys().find(|k| !fields.contains(&k.as_str())) {
        return Err(CommandError::UnknownField {
            command: command.to_owned(),
            field: field.clone(),
        });
    }
    if command == "status" {
        return Ok(Request {
            command: ClientCommand::Status,
            token,
        });
    }
    let sensor = match map.get("sensor") {
        None => None,
        Some(Value::String(s)) if !s.is_empty() => Some(s.clone()),
        Some(_) => return Err(CommandError::BadSensor),
    };
    let command = if command == "rollback" {
        ClientCommand::Rollback { sensor }
    } else {
        ClientCommand::Recalibrate { sensor }
    };
    Ok(Request { command, token })
}

/// An `{"class":"ERROR","message":...}` line, for replies.
pub fn error_line(message: &str) -> Arc<str> {
    serde_json::json!({ "class": "ERROR", "message": message })
        .to_string()
        .into()
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("line longer than {limit} bytes")]
pub(super) struct LineTooLong {
    pub(super) limit: usize,
}

/// Splits a byte stream into lines of at most `max` bytes, sans I/O. A
/// longer line is reported once, as soon as it is known to be too long, and
/// the rest of it is discarded up to the next newline.
#[derive(Debug)]
pub(super) struct LineSplitter {
    pending: Vec<u8>,
    max: usize,
    discarding: bool,
}

impl LineSplitter {
    pub(super) fn new(max: usize) -> LineSplitter {
        LineSplitter {
            pending: Vec::new(),
            max,
            discarding: false,
        }
    }

    pub(super) fn feed(&mut self, data: &[u8]) {
        self.pending.extend_from_slice(data);
    }

    /// The next complete line without its `\n` (or `\r\n`).
    pub(super) fn next_line(&mut self) -> Option<Result<Vec<u8>, LineTooLong>> {
        let too_long = LineTooLong { limit: self.max };
        loop {
            match self.pending.iter().position(|&b| b == b'\n') {
                Some(end) => {
                    let mut line: Vec<u8> = self.pending.drain(..=end).collect();
                    line.pop();
                    if std::mem::take(&mut self.discarding) {
                        // The tail of a line already reported as too long.
                        continue;
                    }
                    if line.last() == Some(&b'\r') {
                        line.pop();
                    }
                    if line.len() > self.max {
                        return Some(Err(too_long));
                    }
                    return Some(Ok(line));
                }
                None => {
                    if self.discarding {
                        self.pending.clear();
                    } else if self.pending.len() > self.max + 1 {
                        // +1: the line may still end in `\r\n`.
                        self.pending.clear();
                        self.discarding = true;
                        return Some(Err(too_long));
                    }
                    return None;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splitter_handles_chunks_crlf_and_long_lines() {
        let mut s = LineSplitter::new(8);
        let mut out = Vec::new();
        for chunk in [&b"ab"[..], b"c\r\nde", b"f\n0123456789", b"abc\nok\n"] {
            s.feed(chunk);
            while let Some(l) = s.next_line() {
                out.push(l.map(|v| String::from_utf8(v).unwrap_or_default()));
            }
        }
        assert_eq!(
            out,
            [
                Ok("abc".to_owned()),
                Ok("def".to_owned()),
                Err(LineTooLong { limit: 8 }),
                Ok("ok".to_owned()),
            ]
        );
        // A too-long line that arrives whole, newline included.
        s.feed(b"0123456789\nx\n");
        assert_eq!(s.next_line(), Some(Err(LineTooLong { limit: 8 })));
        assert_eq!(s.next_line(), Some(Ok(b"x".to_vec())));
        assert_eq!(s.next_line(), None);
    }

    #[test]
    fn commands_parse_and_errors_say_what_is_allowed() {
        assert_eq!(
            parse_command(br#"{"command":"recalibrate","sensor":"compass"}"#),
            Ok(ClientCommand::Recalibrate {
                sensor: Some("compass".into())
            })
        );
        assert_eq!(
            parse_command(br#"{"command":"recalibrate"}"#),
            Ok(ClientCommand::Recalibrate { sensor: None })
        );
        assert_eq!(
            parse_command(br#"{"command":"status"}"#),
            Ok(ClientCommand::Status)
        );
        let err = |l: &[u8]| parse_command(l).err();
        assert!(matches!(err(b"hello"), Some(CommandError::NotJson(_))));
        assert_eq!(err(b"[1]"), Some(CommandError::NotObject("array")));
        assert_eq!(err(b"{}"), Some(CommandError::MissingCommand));
        assert_eq!(
            err(br#"{"command":1}"#),
            Some(CommandError::CommandNotString)
        );
        assert_eq!(
            err(br#"{"command":"fly"}"#),
            Some(CommandError::UnknownCommand("fly".into()))
        );
        assert!(matches!(
            err(br#"{"command":"status","sensor":"x"}"#),
            Some(CommandError::UnknownField { .. })
        ));
        assert_eq!(
            err(br#"{"command":"recalibrate","sensor":""}"#),
            Some(CommandError::BadSensor)
        );
        assert_eq!(err(b"\xff"), Some(CommandError::NotUtf8));
        let message = CommandError::UnknownCommand("fly".into()).to_string();
        assert!(message.contains("\"fly\"") && message.contains("recalibrate"));
        let error: Value = serde_json::from_str(&error_line("bad \"x\"")).unwrap_or_default();
        assert_eq!(error["class"], "ERROR");
        assert_eq!(error["message"], "bad \"x\"");
    }
}
