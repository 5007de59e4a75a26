//! DESIGN.md's mission JSON, `{"waypoints":[{"x":..,"y":..,"z":..,"yaw":..}, ...]}`
//! (NED metres, yaw optional), as every vehicle reads it: the simulator
//! flies it, the MAVLink vehicle turns it into mission items.

use lluav_core::{Fields, Ret};
use serde::Deserialize;

use super::{Ned, Refusal};

/// Most waypoints one mission may hold.
const MAX_WAYPOINTS: usize = 1000;

/// A mission the vehicle cannot use: answered -2 (DESIGN.md, "Errors": a
/// mission it cannot fly is a wrong request).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("Invalid arguments: bad mission: {0}")]
pub struct BadMission(pub String);

impl Refusal for BadMission {
    fn ret(&self) -> Ret {
        Ret::InvalidArgs
    }
}

/// A mission waypoint, NED metres and radians.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Waypoint {
    /// Its id: given, or its 1-based position in the list.
    #[serde(default)]
    id: Option<u32>,
    /// North.
    x: f64,
    /// East.
    y: f64,
    /// Down (negative is up).
    z: f64,
    /// Heading on arrival, if any.
    #[serde(default)]
    pub(crate) yaw: Option<f64>,
}

impl Waypoint {
    /// The position.
    pub(crate) fn ned(&self) -> Ned {
        Ned::new(self.x, self.y, self.z)
    }

    /// The id (always set after [`parse`]).
    pub(crate) fn wp_id(&self) -> u32 {
        self.id.unwrap_or(0)
    }

    /// Writes `id`, `x`, `y`, `z` and `yaw` as given.
    pub(crate) fn write(&self, out: &mut Fields<'_>) {
        out.u64("id", self.wp_id().into())
            .f64("x", self.x)
            .f64("y", self.y)
            .f64("z", self.z);
        match self.yaw {
            Some(yaw) => out.f64("yaw", yaw),
            None => out.null("yaw"),
        };
    }
}

/// DESIGN.md's mission JSON, `{"waypoints":[...]}`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Waypoints {
    waypoints: Vec<Waypoint>,
}

/// Where the simulator may fly: a cylinder around home.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Fence {
    /// Home.
    pub(crate) home: Ned,
    /// Largest horizontal distance from home, m.
    pub(crate) radius: f64,
    /// Highest altitude above home, m.
    pub(crate) max_alt: f64,
}

impl Fence {
    /// No limits at all.
    pub(crate) const NONE: Fence = Fence {
        home: Ned {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        },
        radius: f64::INFINITY,
        max_alt: f64::INFINITY,
    };

    /// Why `p` is not flyable, if it is not. Coordinates are written as the
    /// `f32` a client sends.
    pub(crate) fn check(&self, p: Ned) -> Result<(), String> {
        let dist = ((p.x - self.home.x).powi(2) + (p.y - self.home.y).powi(2)).sqrt();
        if dist > self.radius {
            return Err(format!(
                "{dist:.1} m from home, beyond geofence_radius {}",
                self.radius
            ));
        }
        if p.z > 0.0 {
            let z = p.z as f32;
            return Err(format!("z = {z} is below the ground (NED: up is negative)"));
        }
        if -p.z > self.max_alt {
            let alt = -p.z as f32;
            return Err(format!("altitude {alt} m above max_alt {}", self.max_alt));
        }
        Ok(())
    }
}

/// Parses DESIGN.md's mission JSON (or a top-level array of waypoints)
/// and checks every waypoint against the fence. Waypoints without an id
/// get their 1-based position.
pub(crate) fn parse(text: &str, fence: &Fence) -> Result<Vec<Waypoint>, BadMission> {
    // serde would also read the object from an array of its fields, so
    // the first character decides which of the two shapes this is.
    let mut wps = if text.trim_start().starts_with('[') {
        serde_json::from_str::<Vec<Waypoint>>(text)
    } else {
        serde_json::from_str::<Waypoints>(text).map(|w| w.waypoints)
    }
    .map_err(|e| BadMission(e.to_string()))?;
    if wps.is_empty() {
        return Err(BadMission("no waypoints".into()));
    }
    if wps.len() > MAX_WAYPOINTS {
        return Err(BadMission(format!("more than {MAX_WAYPOINTS} waypoints")));
    }
    let mut seen = std::collections::HashSet::new();
    for (i, wp) in wps.iter_mut().enumerate() {
        let id = *wp.id.get_or_insert(u32::try_from(i + 1).unwrap_or(u32::MAX));
        if !seen.insert(id) {
            return Err(BadMission(format!("duplicate waypoint id {id}")));
        }
        if wp.yaw.is_some_and(|y| !y.is_finite()) {
            return Err(BadMission(format!("waypoint {id}: yaw is not finite")));
        }
        fence
            .check(wp.ned())
            .map_err(|why| BadMission(format!("waypoint {id}: {why}")))?;
    }
    Ok(wps)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fence() -> Fence {
        Fence {
            home: Ned::default(),
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
    fn unusable_missions_are_refused_with_a_reason() {
        let refused = |json: &str| parse(json, &fence()).unwrap_err().to_string();
        assert!(refused(r#"[{"x":1}]"#).contains("missing field `y`"));
        assert!(refused(r#"{"waypoints":[{"x":1,"y":2}]}"#).contains("missing field `z`"));
        assert!(
            refused(r#"{"waypoints":[{"x":1,"y":2,"z":-1,"speed":3}]}"#).contains("unknown field `speed`")
        );
        assert_eq!(
            refused(r#"{"waypoints":[]}"#),
            "Invalid arguments: bad mission: no waypoints"
        );
        assert_eq!(refused("[]"), "Invalid arguments: bad mission: no waypoints");
        assert_eq!(
            refused(r#"{"waypoints":[{"id":4,"x":0,"y":0,"z":-1},{"id":4,"x":0,"y":0,"z":-2}]}"#),
            "Invalid arguments: bad mission: duplicate waypoint id 4"
        );
        assert!(refused(r#"{"waypoints":[{"x":0,"y":0,"z":2}]}"#).contains("below the ground"));
        assert!(refused(r#"{"waypoints":[{"x":500,"y":0,"z":-2}]}"#).contains("geofence_radius"));
        assert!(refused(r#"{"waypoints":[{"x":0,"y":0,"z":-80}]}"#).contains("max_alt"));
    }
}
