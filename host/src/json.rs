//! JSON as lluav reads it (uplink envelopes, mission waypoints): a member
//! named twice in any object is refused (DESIGN.md, "Request grammar").
//! RFC 8259 leaves duplicates to the reader, and "the last one wins" let
//! `"frame":"ver", "frame":"login 1025"` run the second frame behind a
//! first one that a reviewer (or a filter) saw; in a waypoint it would fly
//! a `z` other than the one a reviewer read.
//!
//! [`read`] builds the value in one pass and reports the first duplicate
//! it met, so that a caller can still answer with what it could read (the
//! request's id). [`members`] reads one object's members as raw text, for
//! a caller that reads each value on its own (a number too large for an
//! `f64` is then refused at its member, not as "not JSON").

use std::collections::BTreeMap;
use std::fmt;
use std::marker::PhantomData;

use serde::de::{self, DeserializeSeed, MapAccess, SeqAccess, Visitor};
use serde_json::value::RawValue;
use serde_json::{Map, Number, Value};

/// The longest member name a [`Duplicate`] repeats, in characters.
const NAME_SHOWN: usize = 64;

/// A member named twice.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Duplicate {
    /// The member's name (cut to 64 characters).
    pub name: String,
    /// Whether it is a member of the outermost object.
    pub top: bool,
}

impl fmt::Display for Duplicate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // A JSON string: quotes and control characters escaped.
        let name = serde_json::to_string(&self.name).unwrap_or_default();
        write!(f, "duplicate member {name}")
    }
}

/// `bytes` as JSON, and the first member named twice (the value then
/// holds the member's first occurrence); `Err` when it is not JSON.
pub fn read(bytes: &[u8]) -> Result<(Value, Option<Duplicate>), serde_json::Error> {
    let mut duplicate = None;
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let value = Build {
        duplicate: &mut duplicate,
        depth: 0,
    }
    .deserialize(&mut de)?;
    de.end()?;
    Ok((value, duplicate))
}

/// `bytes` as JSON with every member named once; `None` otherwise.
pub fn unique(bytes: &[u8]) -> Option<Value> {
    match read(bytes) {
        Ok((value, None)) => Some(value),
        _ => None,
    }
}

/// Why [`members`] read no members.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum NotMembers {
    /// The text is not one JSON object.
    NotAnObject,
    /// The object names a member twice.
    Duplicate(Duplicate),
}

impl fmt::Display for NotMembers {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NotMembers::NotAnObject => f.write_str("not an object"),
            NotMembers::Duplicate(d) => d.fmt(f),
        }
    }
}

/// The members of the JSON object `text` by name, each value as its raw
/// text, every name once.
pub fn members(text: &str) -> Result<BTreeMap<String, &RawValue>, NotMembers> {
    let mut duplicate = None;
    let mut de = serde_json::Deserializer::from_str(text);
    let read = Names {
        duplicate: &mut duplicate,
        raw: PhantomData,
    }
    .deserialize(&mut de)
    .and_then(|members| de.end().map(|()| members));
    match (read, duplicate) {
        (_, Some(d)) => Err(NotMembers::Duplicate(d)),
        (Ok(members), None) => Ok(members),
        (Err(_), None) => Err(NotMembers::NotAnObject),
    }
}

/// Reads an object's members as raw text and stops at the first name
/// given twice.
struct Names<'d, 'a> {
    duplicate: &'d mut Option<Duplicate>,
    raw: PhantomData<&'a RawValue>,
}

impl<'de: 'a, 'a> DeserializeSeed<'de> for Names<'_, 'a> {
    type Value = BTreeMap<String, &'a RawValue>;

    fn deserialize<D: de::Deserializer<'de>>(self, deserializer: D) -> Result<Self::Value, D::Error> {
        deserializer.deserialize_map(self)
    }
}

impl<'de: 'a, 'a> Visitor<'de> for Names<'_, 'a> {
    type Value = BTreeMap<String, &'a RawValue>;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a JSON object")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Self::Value, A::Error> {
        let mut members = BTreeMap::new();
        while let Some(name) = map.next_key::<String>()? {
            let value: &'a RawValue = map.next_value()?;
            if members.contains_key(&name) {
                *self.duplicate = Some(Duplicate {
                    name: name.chars().take(NAME_SHOWN).collect(),
                    top: true,
                });
                return Err(de::Error::custom("duplicate member"));
            }
            members.insert(name, value);
        }
        Ok(members)
    }
}

/// Builds a [`Value`] and notes the first duplicate member.
struct Build<'a> {
    duplicate: &'a mut Option<Duplicate>,
    depth: u32,
}

impl Build<'_> {
    fn inner(&mut self) -> Build<'_> {
        Build {
            duplicate: self.duplicate,
            depth: self.depth + 1,
        }
    }
}

impl<'de> DeserializeSeed<'de> for Build<'_> {
    type Value = Value;

    fn deserialize<D: de::Deserializer<'de>>(self, deserializer: D) -> Result<Value, D::Error> {
        deserializer.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Build<'_> {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }

    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_f64<E>(self, v: f64) -> Result<Value, E> {
        // JSON has no NaN or infinity: every f64 the parser gives is finite.
        Ok(Number::from_f64(v).map_or(Value::Null, Value::Number))
    }

    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_owned()))
    }

    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }

    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_seq<A: SeqAccess<'de>>(mut self, mut seq: A) -> Result<Value, A::Error> {
        let mut items = Vec::new();
        while let Some(item) = seq.next_element_seed(self.inner())? {
            items.push(item);
        }
        Ok(Value::Array(items))
    }

    fn visit_map<A: MapAccess<'de>>(mut self, mut map: A) -> Result<Value, A::Error> {
        let mut object = Map::new();
        while let Some(name) = map.next_key::<String>()? {
            let value = map.next_value_seed(self.inner())?;
            if object.contains_key(&name) {
                if self.duplicate.is_none() {
                    *self.duplicate = Some(Duplicate {
                        name: name.chars().take(NAME_SHOWN).collect(),
                        top: self.depth == 0,
                    });
                }
                continue;
            }
            object.insert(name, value);
        }
        Ok(Value::Object(object))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_read_as_serde_json_reads_them() {
        for text in [
            r#"{"a":[1,-2,3.5,"x",null,true,{"b":{}}],"c":"\u00e9\n"}"#,
            "[]",
            "1e400",
            r#""s""#,
        ] {
            let (value, duplicate) = match read(text.as_bytes()) {
                Ok(v) => v,
                Err(_) => {
                    assert!(serde_json::from_str::<Value>(text).is_err(), "{text}");
                    continue;
                }
            };
            assert_eq!(duplicate, None);
            assert_eq!(
                value,
                serde_json::from_str::<Value>(text).expect("JSON"),
                "{text}"
            );
        }
        assert!(read(b"{\"a\":1} x").is_err());
        assert!(read(b"{\"a\":").is_err());
    }

    #[test]
    fn a_member_named_twice_is_found_at_any_depth_and_the_first_one_kept() {
        let (value, duplicate) = read(br#"{"frame":"ver","frame":"login 1025"}"#).expect("JSON");
        assert_eq!(
            duplicate,
            Some(Duplicate {
                name: "frame".into(),
                top: true
            })
        );
        assert_eq!(value["frame"], "ver");
        assert_eq!(
            duplicate.map(|d| d.to_string()).as_deref(),
            Some(r#"duplicate member "frame""#)
        );
        let (_, duplicate) = read(br#"{"a":[{"x":1,"y":2,"x":3}]}"#).expect("JSON");
        assert_eq!(
            duplicate,
            Some(Duplicate {
                name: "x".into(),
                top: false
            })
        );
        // Escapes name the same member.
        let (_, duplicate) = read(br#"{"id":"1","\u0069d":"2"}"#).expect("JSON");
        assert_eq!(duplicate.map(|d| d.name).as_deref(), Some("id"));
        assert_eq!(
            unique(br#"{"a":1,"b":{"a":2}}"#).map(|v| v["b"]["a"].clone()),
            Some(2.into())
        );
        assert_eq!(unique(br#"{"a":1,"a":1}"#), None);
    }

    #[test]
    fn a_duplicate_names_itself_escaped_and_cut() {
        let long = format!(r#"{{"{n}":1,"{n}":2}}"#, n = "\\u001b".repeat(100));
        let (_, duplicate) = read(long.as_bytes()).expect("JSON");
        let shown = duplicate.expect("a duplicate").to_string();
        assert!(shown.starts_with(r#"duplicate member "\u001b"#), "{shown}");
        assert_eq!(shown.matches("\\u001b").count(), 64, "{shown}");
        assert!(!shown.contains('\u{1b}'));
    }

    #[test]
    fn members_are_one_objects_names_each_once_with_their_raw_values() {
        let m = members(r#" {"x": 1e400, "y":[1,{"a":1}], "z":null} "#).expect("members");
        let raw: Vec<(&str, &str)> = m.iter().map(|(k, v)| (k.as_str(), v.get())).collect();
        assert_eq!(raw, [("x", "1e400"), ("y", r#"[1,{"a":1}]"#), ("z", "null")]);
        for text in ["[]", "7", r#""{}""#, "{} {}", r#"{"x":1"#, ""] {
            assert_eq!(members(text).err(), Some(NotMembers::NotAnObject), "{text}");
        }
        let twice = members(r#"{"z":-3,"y":0,"z":0}"#).unwrap_err();
        assert_eq!(twice.to_string(), r#"duplicate member "z""#);
        // A value's own members are its reader's to check.
        assert!(members(r#"{"w":{"a":1,"a":2}}"#).is_ok());
    }
}
