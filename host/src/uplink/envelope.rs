//! The request and response envelopes (DESIGN.md, "Uplink"):
//! `{"id":"<1-64 chars>","frame":"set_sp_ned 1:2:-3:0"}` in,
//! `{"id":"<same>","response":{...}}` out, where `response` is exactly
//! what a WebSocket session would have been answered.

use std::fmt;

use lluav_core::Ret;
use serde_json::{Map, Value};

use super::topic::MAX_NAME;
use crate::json::{self, Duplicate};

/// Longest request id, in characters.
pub const MAX_ID_CHARS: usize = MAX_NAME;

/// A request read from its envelope.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Request {
    /// The client's id for this request: 1-64 characters.
    pub id: String,
    /// The protocol frame, as a WebSocket text message would carry it.
    pub frame: String,
}

/// Why an envelope cannot be read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Unreadable {
    /// The payload is over `--max-message` bytes.
    TooLarge(usize),
    /// Not UTF-8 JSON.
    NotJson,
    /// JSON, but not an object.
    NotObject,
    /// A member named twice, in the envelope or anywhere inside it.
    Duplicate(Duplicate),
    /// `id` is missing, not a string, or not 1-64 characters.
    Id,
    /// `frame` is missing or not a string.
    Frame,
}

impl fmt::Display for Unreadable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Unreadable::TooLarge(max) => write!(f, "larger than {max} bytes"),
            Unreadable::NotJson => f.write_str("not JSON"),
            Unreadable::NotObject => f.write_str("not a JSON object"),
            Unreadable::Duplicate(d) => d.fmt(f),
            Unreadable::Id => write!(f, "\"id\" must be a string of 1-{MAX_ID_CHARS} characters"),
            Unreadable::Frame => f.write_str("\"frame\" must be a string"),
        }
    }
}

/// An envelope that cannot be read, and the request id in it if that much
/// could be read (the answer then carries it; else `"id": null`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refused {
    /// The request's id, if readable.
    pub id: Option<String>,
    /// Why.
    pub why: Unreadable,
}

/// Whether `id` can be a request id.
pub fn valid_id(id: &str) -> bool {
    !id.is_empty() && id.chars().nth(MAX_ID_CHARS).is_none()
}

/// Reads a request envelope of at most `max` bytes.
pub fn read(payload: &[u8], max: usize) -> Result<Request, Refused> {
    let (value, duplicate) = match json::read(payload) {
        Ok((value, duplicate)) => (Some(value), duplicate),
        Err(_) => (None, None),
    };
    let object = value.as_ref().and_then(Value::as_object);
    // An id named twice is no id: which one would the answer carry?
    let id_twice = duplicate.as_ref().is_some_and(|d| d.top && d.name == "id");
    let id = object.and_then(id_of).filter(|_| !id_twice);
    let refuse = |why| Refused { id: id.clone(), why };
    if payload.len() > max {
        return Err(refuse(Unreadable::TooLarge(max)));
    }
    let object = match value {
        None => return Err(refuse(Unreadable::NotJson)),
        Some(Value::Object(ref o)) => o,
        Some(_) => return Err(refuse(Unreadable::NotObject)),
    };
    if let Some(duplicate) = duplicate {
        return Err(refuse(Unreadable::Duplicate(duplicate)));
    }
    let Some(id) = id.clone() else {
        return Err(refuse(Unreadable::Id));
    };
    match object.get("frame") {
        Some(Value::String(frame)) => Ok(Request {
            id,
            frame: frame.clone(),
        }),
        _ => Err(refuse(Unreadable::Frame)),
    }
}

fn id_of(object: &Map<String, Value>) -> Option<String> {
    match object.get("id") {
        Some(Value::String(id)) if valid_id(id) => Some(id.clone()),
        _ => None,
    }
}

/// `{"id":<id>,"response":<response>}`; `response` is a JSON object
/// written by the core, copied byte for byte.
pub fn response(id: Option<&str>, response: &str) -> String {
    let id = match id {
        // Serialising a str cannot fail.
        Some(id) => serde_json::to_string(id).unwrap_or_default(),
        None => "null".to_owned(),
    };
    format!("{{\"id\":{id},\"response\":{response}}}")
}

/// An error response written here, not by the core (a request that never
/// reached it): `{"ret":..,"cmd":..,"ts":..,"msg":".."}`, in the core's
/// member order.
pub fn error(ret: Ret, cmd: u8, ts: i64, msg: &str) -> String {
    let ret = ret.code();
    let msg = serde_json::to_string(msg).unwrap_or_default();
    format!("{{\"ret\":{ret},\"cmd\":{cmd},\"ts\":{ts},\"msg\":{msg}}}")
}

/// The response to an envelope that cannot be read.
pub fn refused(refused: &Refused, ts: i64) -> String {
    let msg = format!("Invalid request envelope: {}", refused.why);
    response(refused.id.as_deref(), &error(Ret::InvalidArgs, 0, ts, &msg))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn why(payload: &str) -> (Option<String>, Unreadable) {
        let r = read(payload.as_bytes(), 100).expect_err("refused");
        (r.id, r.why)
    }

    #[test]
    fn a_good_envelope_is_read_whatever_else_it_holds() {
        let r = read(br#"{"id":"a1","frame":"state","extra":[1]}"#, 100).expect("read");
        assert_eq!(
            r,
            Request {
                id: "a1".into(),
                frame: "state".into()
            }
        );
        let r = read(br#"{"id":"x","frame":""}"#, 100).expect("an empty frame is a frame");
        assert_eq!(r.frame, "");
    }

    #[test]
    fn unreadable_envelopes_say_why_and_keep_the_id_when_they_can() {
        assert_eq!(why("nope"), (None, Unreadable::NotJson));
        assert_eq!(why("[1]"), (None, Unreadable::NotObject));
        assert_eq!(why(r#"{"frame":"state"}"#), (None, Unreadable::Id));
        assert_eq!(why(r#"{"id":7,"frame":"state"}"#), (None, Unreadable::Id));
        assert_eq!(why(r#"{"id":"","frame":"state"}"#), (None, Unreadable::Id));
        let long = format!(r#"{{"id":"{}","frame":"state"}}"#, "é".repeat(65));
        assert_eq!(
            read(long.as_bytes(), 1000).expect_err("long id").why,
            Unreadable::Id
        );
        let sixty_four = format!(r#"{{"id":"{}","frame":"state"}}"#, "é".repeat(64));
        assert!(read(sixty_four.as_bytes(), 1000).is_ok());
        assert_eq!(
            why(r#"{"id":"a","frame":5}"#),
            (Some("a".into()), Unreadable::Frame)
        );
        let big = format!(r#"{{"id":"b","frame":"{}"}}"#, "x".repeat(200));
        assert_eq!(why(&big), (Some("b".into()), Unreadable::TooLarge(100)));
    }

    #[test]
    fn a_member_named_twice_is_refused_and_the_id_kept_unless_it_is_the_twice_named_one() {
        let (id, refused) = why(r#"{"id":"d1","frame":"ver","frame":"login 1025"}"#);
        assert_eq!(id.as_deref(), Some("d1"));
        assert_eq!(refused.to_string(), r#"duplicate member "frame""#);
        let r = refused_answer(r#"{"id":"d1","frame":"ver","frame":"login 1025"}"#);
        assert_eq!(
            r,
            r#"{"id":"d1","response":{"ret":-2,"cmd":0,"ts":5,"msg":"Invalid request envelope: duplicate member \"frame\""}}"#
        );
        assert_eq!(why(r#"{"id":"a","id":"b","frame":"state"}"#).0, None);
        let (id, refused) = why(r#"{"id":"n","frame":"state","x":{"k":1,"k":2}}"#);
        assert_eq!(
            (id.as_deref(), refused.to_string().as_str()),
            (Some("n"), r#"duplicate member "k""#)
        );
    }

    fn refused_answer(payload: &str) -> String {
        refused(&read(payload.as_bytes(), 100).expect_err("refused"), 5)
    }

    #[test]
    fn answers_wrap_the_response_verbatim() {
        assert_eq!(
            response(Some("a\"1"), r#"{"ret":0}"#),
            r#"{"id":"a\"1","response":{"ret":0}}"#
        );
        let r = refused(
            &Refused {
                id: None,
                why: Unreadable::NotJson,
            },
            5,
        );
        assert_eq!(
            r,
            r#"{"id":null,"response":{"ret":-2,"cmd":0,"ts":5,"msg":"Invalid request envelope: not JSON"}}"#
        );
    }
}
