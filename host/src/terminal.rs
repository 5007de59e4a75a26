//! Text from the network on a terminal (DESIGN.md, "Uplink"): control
//! characters (Unicode Cc: C0, DEL, C1) and invisible format characters
//! (Cf, e.g. U+202E) are written as JSON escapes (`\u001b`), so that a
//! vehicle's state, a response or an event can neither drive the terminal
//! (clear the screen, set the window title, move the cursor over earlier
//! rows) nor reorder what follows it.
//!
//! The escapes are JSON's: [`escape`] of a JSON text is the same JSON
//! value, and a line of plain text shows the character's code point.

use std::borrow::Cow;
use std::fmt::Write as _;
use std::time::{Duration, UNIX_EPOCH};

use serde_json::{Map, Value};

/// The Unicode format characters (general category Cf, Unicode 16), as
/// `(first, last)`: the same set core refuses in names and stored text.
const FORMAT: [(u32, u32); 21] = [
    (0xAD, 0xAD),
    (0x600, 0x605),
    (0x61C, 0x61C),
    (0x6DD, 0x6DD),
    (0x70F, 0x70F),
    (0x890, 0x891),
    (0x8E2, 0x8E2),
    (0x180E, 0x180E),
    (0x200B, 0x200F),
    (0x202A, 0x202E),
    (0x2060, 0x2064),
    (0x2066, 0x206F),
    (0xFEFF, 0xFEFF),
    (0xFFF9, 0xFFFB),
    (0x110BD, 0x110BD),
    (0x110CD, 0x110CD),
    (0x13430, 0x1343F),
    (0x1BCA0, 0x1BCA3),
    (0x1D173, 0x1D17A),
    (0xE0001, 0xE0001),
    (0xE0020, 0xE007F),
];

/// Whether `c` must not reach a terminal as it is.
pub fn unsafe_char(c: char) -> bool {
    let n = u32::from(c);
    c.is_control() || FORMAT.iter().any(|&(first, last)| (first..=last).contains(&n))
}

/// `text` with every [`unsafe_char`] written as a JSON escape (`\u001b`;
/// a surrogate pair beyond U+FFFF). Borrowed when there is none.
pub fn escape(text: &str) -> Cow<'_, str> {
    if !text.chars().any(unsafe_char) {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 16);
    for c in text.chars() {
        if unsafe_char(c) {
            let mut units = [0u16; 2];
            for unit in c.encode_utf16(&mut units) {
                // Writing into a String cannot fail.
                let _ = write!(out, "\\u{unit:04x}");
            }
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

/// [`escape`], line breaks kept: for text of several lines whose breaks
/// are its layout (pretty JSON, whose strings hold no raw line break).
pub fn escape_lines(text: &str) -> String {
    text.split('\n').map(escape).collect::<Vec<_>>().join("\n")
}

/// `value` as one line of compact JSON that is safe on a terminal: the
/// same value (escapes are only added inside strings).
pub fn json_line(value: &Value) -> String {
    escape(&value.to_string()).into_owned()
}

/// `ms` since the Unix epoch as `YYYY-MM-DDTHH:MM:SS.mmmZ` (UTC, as the
/// daemon's log writes time).
pub fn utc(ms: i64) -> String {
    let t = UNIX_EPOCH + Duration::from_millis(u64::try_from(ms).unwrap_or(0));
    let mut out = String::new();
    crate::recent_log::write_utc(&mut out, t);
    out
}

/// The members every event has, shown in the line's own columns.
const COMMON: [&str; 4] = ["event", "seq", "boot", "ts"];

/// One event (or gap, DESIGN.md "Events") as a line for a person: its
/// time, `seq` and name, then its own fields as `key=value` in the order
/// the server sent them, e.g. `2025-05-01T14:03:07.123Z #12 fsm
/// from=disarmed to=takeoff`. Events this client does not know are shown
/// the same way; the line is [`escape`]d.
pub fn event_line(event: &Map<String, Value>) -> String {
    let time = event
        .get("ts")
        .and_then(Value::as_i64)
        .map_or_else(|| "-".to_owned(), utc);
    let name = match event.get("event") {
        Some(Value::String(s)) => s.clone(),
        other => other.map_or_else(|| "?".to_owned(), Value::to_string),
    };
    let mut line = time;
    if let Some(seq) = event.get("seq") {
        let _ = write!(line, " #{seq}");
    }
    let _ = write!(line, " {name}");
    for (key, value) in event.iter().filter(|(k, _)| !COMMON.contains(&k.as_str())) {
        let _ = write!(line, " {key}={}", shown(value));
    }
    if name == "gap" {
        line.push_str(" (events dropped: this client fell behind)");
    }
    escape(&line).into_owned()
}

/// A field's value in an event line: a plain word as it is, any other
/// string quoted as JSON (so `by="ws 127.0.0.1:4242 #3"` reads as one
/// value, and a control character shows escaped inside quotes), the rest
/// as JSON.
fn shown(value: &Value) -> String {
    match value {
        Value::String(s)
            if !s.is_empty()
                && !s
                    .chars()
                    .any(|c| c.is_whitespace() || unsafe_char(c) || matches!(c, '"' | '=' | '\\')) =>
        {
            s.clone()
        }
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_and_format_characters_are_escaped_and_the_rest_kept() {
        assert!(matches!(escape("disarmed é ✓"), Cow::Borrowed(_)));
        assert_eq!(
            escape("\u{1b}[2J\u{1b}]0;pwned\u{7}"),
            "\\u001b[2J\\u001b]0;pwned\\u0007"
        );
        assert_eq!(escape("a\u{9b}b\u{7f}c"), "a\\u009bb\\u007fc");
        assert_eq!(escape("evil\u{202e}gpj.exe"), "evil\\u202egpj.exe");
        assert_eq!(escape("tag\u{e0041}"), "tag\\udb40\\udc41");
        assert_eq!(escape("line\nnext\r"), "line\\u000anext\\u000d");
        assert_eq!(
            escape_lines("{\n  \"a\": \"\u{1b}\"\n}"),
            "{\n  \"a\": \"\\u001b\"\n}"
        );
    }

    #[test]
    fn escaped_json_is_the_same_json() {
        let value = serde_json::json!({"fsm": "\u{1b}[2J\u{202e}\u{85}\u{e0020}x", "n": 1});
        let text = serde_json::to_string(&value).expect("JSON");
        let escaped = escape(&text);
        assert!(!escaped.chars().any(unsafe_char), "{escaped}");
        let back: serde_json::Value = serde_json::from_str(&escaped).expect("still JSON");
        assert_eq!(back, value);
    }

    fn object(v: serde_json::Value) -> Map<String, Value> {
        match v {
            Value::Object(m) => m,
            _ => panic!("not an object"),
        }
    }

    #[test]
    fn event_lines_show_time_seq_name_and_fields_in_order() {
        use serde_json::json;
        let e = object(
            json!({"event": "fsm", "seq": 12, "boot": "ab", "ts": 1_746_108_187_123_i64,
            "from": "disarmed", "to": "takeoff"}),
        );
        assert_eq!(
            event_line(&e),
            "2025-05-01T14:03:07.123Z #12 fsm from=disarmed to=takeoff"
        );
        let e = object(json!({"event": "control", "seq": 3, "boot": "ab", "ts": 0,
            "by": "ws 127.0.0.1:4242 #3", "from": null}));
        assert_eq!(
            event_line(&e),
            r#"1970-01-01T00:00:00.000Z #3 control by="ws 127.0.0.1:4242 #3" from=null"#
        );
        let e = object(json!({"event": "gap", "missed": 12, "ts": 0}));
        assert_eq!(
            event_line(&e),
            "1970-01-01T00:00:00.000Z gap missed=12 (events dropped: this client fell behind)"
        );
        let e =
            object(json!({"event": "log", "seq": 4, "ts": 0, "level": "warning", "msg": "\u{1b}[31mred"}));
        assert_eq!(
            event_line(&e),
            r#"1970-01-01T00:00:00.000Z #4 log level=warning msg="\u001b[31mred""#
        );
        let e = object(json!({"event": 7, "seq": 6, "ts": 0, "new": {"a": [1]}}));
        assert!(
            event_line(&e).ends_with(r#"#6 7 new={"a":[1]}"#),
            "{}",
            event_line(&e)
        );
        let v = json!({"event": "log", "msg": "\u{1b}]0;owned\u{7}\u{9b}\u{202e}", "n": 1});
        let line = json_line(&v);
        assert!(!line.chars().any(unsafe_char), "{line}");
        assert_eq!(serde_json::from_str::<Value>(&line).expect("JSON"), v);
        assert!(line.starts_with(r#"{"event":"log","msg":"#), "{line}");
    }
}
