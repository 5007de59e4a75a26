//! DESIGN.md's mission JSON, `{"waypoints":[{"x":..,"y":..,"z":..,"yaw":..}, ...]}`
//! (NED metres, yaw optional), as every vehicle reads it: the simulator
//! flies it, the MAVLink vehicle turns it into mission items.

use std::collections::BTreeMap;

use lluav_core::{Fields, Ret};
use serde_json::Value;
use serde_json::value::RawValue;

use super::envelope::Envelope;
use super::{Ned, Refusal};
use crate::json::{self, NotMembers};

/// Most waypoints one mission may hold: `mw_list` of that many, every
/// number at its longest, is under 55 KB, so it fits lluavd's 64 KiB
/// response buffer.
pub(crate) const MAX_WAYPOINTS: usize = 400;

/// How a waypoint run goes, as `dump_missionresult` and `state.mission`
/// name it on every vehicle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunStatus {
    /// Still flying.
    Running,
    /// Every waypoint reached.
    Completed,
    /// The vehicle stopped flying it before its last waypoint (another
    /// command took it over: setpoint, land, RTL, disarm, another run; or,
    /// over MAVLink, the autopilot left it).
    Interrupted,
    /// Ended by `abort_report` (the simulator's).
    Aborted,
}

impl RunStatus {
    /// Its name in answers.
    pub fn name(self) -> &'static str {
        match self {
            RunStatus::Running => "running",
            RunStatus::Completed => "completed",
            RunStatus::Interrupted => "interrupted",
            RunStatus::Aborted => "aborted",
        }
    }
}

/// A mission the vehicle cannot use: answered -2 (DESIGN.md, "Errors": a
/// mission it cannot fly is a wrong request).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("Invalid arguments: {0}")]
pub struct BadMission(pub String);

impl Refusal for BadMission {
    fn ret(&self) -> Ret {
        Ret::InvalidArgs
    }
}

/// A mission waypoint, NED metres and radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Waypoint {
    /// Its id: given, or its 1-based position in the list.
    id: u32,
    /// North.
    x: f64,
    /// East.
    y: f64,
    /// Down (negative is up).
    z: f64,
    /// Heading on arrival, if any.
    pub(crate) yaw: Option<f64>,
}

impl Waypoint {
    /// The position.
    pub(crate) fn ned(&self) -> Ned {
        Ned::new(self.x, self.y, self.z)
    }

    /// The id.
    pub(crate) fn wp_id(&self) -> u32 {
        self.id
    }

    /// Writes `id`, `x`, `y`, `z` and `yaw` as given.
    pub(crate) fn write(&self, out: &mut Fields<'_>) {
        out.u64("id", self.id.into())
            .f64("x", self.x)
            .f64("y", self.y)
            .f64("z", self.z);
        match self.yaw {
            Some(yaw) => out.f64("yaw", yaw),
            None => out.null("yaw"),
        };
    }
}

/// Reads DESIGN.md's mission JSON, `{"waypoints":[...]}` or a top-level
/// array of waypoints, each an object `{"id":..,"x":..,"y":..,"z":..,"yaw":..}`
/// (`id` and `yaw` optional), and checks every waypoint against the
/// envelope. Waypoints without an id get their 1-based position. Reasons
/// name waypoints by position and members by the protocol's names, and
/// never quote the text (it may come from a file).
///
/// The text is read in two steps: its syntax as a whole, then each
/// member's value on its own, so that a number too large for its member
/// (`1e400`) is refused as out of range at its waypoint, not as "not JSON".
pub(crate) fn parse(text: &str, envelope: &Envelope) -> Result<Vec<Waypoint>, BadMission> {
    let bad = BadMission;
    let top: &RawValue = serde_json::from_str(text)
        .map_err(|e| bad(format!("not JSON (line {}, column {})", e.line(), e.column())))?;
    let list = match first_byte(top) {
        b'[' => elements(top).map_err(bad)?,
        b'{' => {
            let members = members(top).map_err(|e| bad(e.to_string()))?;
            waypoints_member(&members).map_err(bad)?
        }
        _ => {
            return Err(bad(
                r#"a mission is {"waypoints":[...]} or an array of waypoints"#.into(),
            ));
        }
    };
    if list.is_empty() {
        return Err(bad("no waypoints".into()));
    }
    if list.len() > MAX_WAYPOINTS {
        return Err(bad(format!("more than {MAX_WAYPOINTS} waypoints")));
    }
    let mut seen = std::collections::HashSet::new();
    let mut wps = Vec::with_capacity(list.len());
    for (i, item) in list.iter().enumerate() {
        let n = i + 1;
        let wp = waypoint(item, n).map_err(|why| bad(format!("waypoint {n}: {why}")))?;
        if !seen.insert(wp.id) {
            return Err(bad(format!("waypoint {n}: duplicate id {}", wp.id)));
        }
        envelope
            .check(wp.ned())
            .map_err(|why| bad(format!("waypoint {n}: {why}")))?;
        wps.push(wp);
    }
    Ok(wps)
}

/// An object's members, their values unread.
type Members<'a> = BTreeMap<String, &'a RawValue>;

/// The first byte of a value: `{`, `[`, `"`, a digit or `-`, or a letter.
fn first_byte(raw: &RawValue) -> u8 {
    raw.get().trim_start().bytes().next().unwrap_or(0)
}

/// The elements of an array whose syntax was checked already.
fn elements(raw: &RawValue) -> Result<Vec<&RawValue>, String> {
    serde_json::from_str(raw.get()).map_err(|_| "not an array".into())
}

/// The members of an object whose syntax was checked already, each named
/// once.
fn members(raw: &RawValue) -> Result<Members<'_>, NotMembers> {
    json::members(raw.get())
}

/// The `waypoints` array of a mission object, its only member.
fn waypoints_member<'a>(members: &Members<'a>) -> Result<Vec<&'a RawValue>, String> {
    if members.keys().any(|k| k != "waypoints") {
        return Err(r#"unexpected member (a mission object has only "waypoints")"#.into());
    }
    match members.get("waypoints") {
        Some(list) if first_byte(list) == b'[' => elements(list),
        Some(_) => Err(r#""waypoints" is not an array"#.into()),
        None => Err(r#"missing "waypoints""#.into()),
    }
}

/// A member's value read on its own: JSON's `null` is `None`; a number
/// too large for a 64-bit float is out of range.
fn number(members: &Members<'_>, key: &str) -> Result<Option<f64>, String> {
    let Some(raw) = members.get(key) else {
        return Ok(None);
    };
    match serde_json::from_str::<Value>(raw.get()) {
        Ok(Value::Null) => Ok(None),
        Ok(v) => v
            .as_f64()
            .map(Some)
            .ok_or_else(|| format!(r#""{key}" is not a number"#)),
        // The syntax was checked: what fails now is a number beyond f64.
        Err(_) if matches!(first_byte(raw), b'-' | b'0'..=b'9') => Err(format!(
            r#""{key}" out of range (a 64-bit float: -1.7976931348623157e308..1.7976931348623157e308)"#
        )),
        Err(_) => Err(format!(r#""{key}" is not a number"#)),
    }
}

/// The waypoint at 1-based position `n`: an object, never an array read
/// positionally.
fn waypoint(item: &RawValue, n: usize) -> Result<Waypoint, String> {
    const MEMBERS: [&str; 5] = ["id", "x", "y", "z", "yaw"];
    let not_an_object = || r#"not an object {"x":..,"y":..,"z":..}"#.to_owned();
    if first_byte(item) != b'{' {
        return Err(not_an_object());
    }
    let members = members(item).map_err(|e| match e {
        NotMembers::NotAnObject => not_an_object(),
        duplicate => duplicate.to_string(),
    })?;
    if members.keys().any(|k| !MEMBERS.contains(&k.as_str())) {
        return Err(r#"unexpected member (a waypoint has "id", "x", "y", "z", "yaw")"#.into());
    }
    let required = |key: &str| match members.get(key) {
        Some(_) => number(&members, key)?.ok_or_else(|| format!(r#""{key}" is not a number"#)),
        None => Err(format!(r#"missing "{key}""#)),
    };
    let id = match members.get("id") {
        None => u32::try_from(n).unwrap_or(u32::MAX),
        Some(raw) => match serde_json::from_str::<Value>(raw.get()) {
            Ok(Value::Null) => u32::try_from(n).unwrap_or(u32::MAX),
            v => v
                .ok()
                .and_then(|v| v.as_u64())
                .and_then(|id| u32::try_from(id).ok())
                .ok_or(r#""id" is not an integer 0..4294967295"#)?,
        },
    };
    let yaw = number(&members, "yaw")?;
    Ok(Waypoint {
        id,
        x: required("x")?,
        y: required("y")?,
        z: required("z")?,
        yaw,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fence() -> Envelope {
        Envelope {
            home: Ned::default(),
            min_alt: 0.5,
            radius: 100.0,
            max_alt: 50.0,
        }
    }

    #[test]
    fn a_top_level_array_of_waypoints_is_a_mission_too() {
        let wps = parse(
            r#"[{"x":1,"y":2,"z":-3},{"id":7,"x":4,"y":5,"z":-6,"yaw":1}]"#,
            &fence(),
        )
        .unwrap();
        assert_eq!((wps[0].wp_id(), wps[1].wp_id(), wps[1].yaw), (1, 7, Some(1.0)));
    }

    #[test]
    fn design_mission_json_is_accepted_with_default_ids() {
        let wps = parse(
            r#"{"waypoints":[{"x":1,"y":2,"z":-3,"yaw":0.5},{"x":4,"y":5,"z":-6}]}"#,
            &fence(),
        )
        .unwrap();
        assert_eq!(wps.len(), 2);
        assert_eq!((wps[0].wp_id(), wps[1].wp_id()), (1, 2));
        assert_eq!(wps[0].yaw, Some(0.5));
        assert_eq!(wps[1].yaw, None);
    }

    #[test]
    fn unusable_missions_are_refused_with_a_reason_in_the_protocols_words() {
        let refused = |json: &str| {
            parse(json, &fence())
                .unwrap_err()
                .to_string()
                .strip_prefix("Invalid arguments: ")
                .expect("-2")
                .to_owned()
        };
        for (json, why) in [
            (r#"[{"x":1}]"#, r#"waypoint 1: missing "y""#),
            (
                r#"{"waypoints":[{"x":1,"y":2,"z":-1},{"x":1,"y":2}]}"#,
                r#"waypoint 2: missing "z""#,
            ),
            (
                r#"[[2,0,-3,0]]"#,
                r#"waypoint 1: not an object {"x":..,"y":..,"z":..}"#,
            ),
            (
                r#"{"waypoints":[[2,0,-3,0]]}"#,
                r#"waypoint 1: not an object {"x":..,"y":..,"z":..}"#,
            ),
            (
                r#"{"waypoints":[{"x":1,"y":2,"z":-1,"speed":3}]}"#,
                r#"waypoint 1: unexpected member (a waypoint has "id", "x", "y", "z", "yaw")"#,
            ),
            (
                r#"[{"x":"1","y":2,"z":-1}]"#,
                r#"waypoint 1: "x" is not a number"#,
            ),
            (
                r#"[{"id":-1,"x":1,"y":2,"z":-1}]"#,
                r#"waypoint 1: "id" is not an integer 0..4294967295"#,
            ),
            (
                r#"[{"x":1,"y":2,"z":-1,"yaw":true}]"#,
                r#"waypoint 1: "yaw" is not a number"#,
            ),
            (
                r#"{"wp":[]}"#,
                r#"unexpected member (a mission object has only "waypoints")"#,
            ),
            (r#"{"waypoints":{}}"#, r#""waypoints" is not an array"#),
            ("{}", r#"missing "waypoints""#),
            (
                "7",
                r#"a mission is {"waypoints":[...]} or an array of waypoints"#,
            ),
            (r#"{"waypoints":[]}"#, "no waypoints"),
            (
                r#"{"waypoints":[{"x":1,"y":2,"z":-3}],"waypoints":[]}"#,
                r#"duplicate member "waypoints""#,
            ),
            (
                r#"[{"x":1,"y":2,"z":-3},{"x":1,"y":2,"z":-3,"z":0}]"#,
                r#"waypoint 2: duplicate member "z""#,
            ),
            (
                r#"[{"x":1,"y":2,"z":-3,"x":1e400}]"#,
                r#"waypoint 1: duplicate member "x""#,
            ),
            ("[]", "no waypoints"),
            (r#"{"takeoff_alt": 2.5"#, "not JSON (line 1, column 19)"),
            (
                r#"[{"x":1e400,"y":0,"z":-2}]"#,
                r#"waypoint 1: "x" out of range (a 64-bit float: -1.7976931348623157e308..1.7976931348623157e308)"#,
            ),
            (
                r#"{"waypoints":[{"x":0,"y":0,"z":-1},{"x":0,"y":-2e999,"z":-2}]}"#,
                r#"waypoint 2: "y" out of range (a 64-bit float: -1.7976931348623157e308..1.7976931348623157e308)"#,
            ),
            (
                r#"[{"x":0,"y":0,"z":-1,"yaw":1e309}]"#,
                r#"waypoint 1: "yaw" out of range (a 64-bit float: -1.7976931348623157e308..1.7976931348623157e308)"#,
            ),
            (
                r#"[{"id":1e400,"x":0,"y":0,"z":-1}]"#,
                r#"waypoint 1: "id" is not an integer 0..4294967295"#,
            ),
            (
                r#"[{"x":null,"y":0,"z":-1}]"#,
                r#"waypoint 1: "x" is not a number"#,
            ),
            (r#"[{"x":1,"y":0,"z":-1}] x"#, "not JSON (line 1, column 24)"),
            (
                r#"[{"id":4,"x":0,"y":0,"z":-1},{"id":4,"x":0,"y":0,"z":-2}]"#,
                "waypoint 2: duplicate id 4",
            ),
            (
                r#"[{"x":0,"y":0,"z":2}]"#,
                "waypoint 1: altitude -2 m below min_alt 0.5 m",
            ),
            (
                r#"[{"x":0,"y":0,"z":0}]"#,
                "waypoint 1: altitude 0 m below min_alt 0.5 m",
            ),
            (
                r#"[{"x":0,"y":0,"z":-0.0}]"#,
                "waypoint 1: altitude 0 m below min_alt 0.5 m",
            ),
            (
                r#"[{"x":0,"y":0,"z":-1e-50}]"#,
                "waypoint 1: altitude 0 m below min_alt 0.5 m",
            ),
            (
                r#"[{"x":1e300,"y":0,"z":-2}]"#,
                "waypoint 1: distance from home 1e300 m beyond geofence_radius 100 m",
            ),
            (
                r#"[{"x":0,"y":0,"z":-80}]"#,
                "waypoint 1: altitude 80 m above max_alt 50 m",
            ),
            (
                r#"[{"x":0,"y":0,"z":-1e30}]"#,
                "waypoint 1: altitude 1e30 m above max_alt 50 m",
            ),
        ] {
            assert_eq!(refused(json), why, "{json}");
        }
        let too_many = format!(
            "[{}]",
            vec![r#"{"x":0,"y":0,"z":-1}"#; MAX_WAYPOINTS + 1].join(",")
        );
        assert_eq!(refused(&too_many), "more than 400 waypoints");
    }
}
