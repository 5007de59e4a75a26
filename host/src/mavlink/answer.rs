//! The answers of the commands that wait for the autopilot: each is made
//! by the sequence that ran the command (`ops`) and writes its own
//! response fields, so no answer is ever written for the wrong command.

use ::mavlink::dialects::ardupilotmega::MavParamType;
use lluav_core::{Fields, Pose};

use super::autopilot::{self, ParamValue};
use crate::vehicle::Ned;

/// A finished command's response fields.
pub trait Answer: Send + 'static {
    /// Writes them.
    fn write(&self, out: &mut Fields<'_>);
}

/// Acknowledged by the autopilot (`land`, `rtl`, `mrtl`, the gimbal):
/// the state machine's state when it was.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Acknowledged {
    /// `fsm` then.
    pub fsm: &'static str,
}

impl Answer for Acknowledged {
    fn write(&self, out: &mut Fields<'_>) {
        out.str("fsm", self.fsm);
    }
}

/// `rtl`, `mrtl`: returning home.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Returning {
    /// `fsm` then.
    pub fsm: &'static str,
    /// Home, local NED, if the autopilot sent it.
    pub home: Option<Ned>,
    /// The altitude above home the return climbs to if lower, m, if
    /// known.
    pub return_alt: Option<f32>,
}

impl Answer for Returning {
    fn write(&self, out: &mut Fields<'_>) {
        out.str("fsm", self.fsm);
        match self.home {
            Some(h) => out.object("home", |o| h.write(o)),
            None => out.null("home"),
        };
        match self.return_alt {
            Some(alt) => out.f32("return_alt", alt),
            None => out.null("return_alt"),
        };
    }
}

/// `takeoff`: climbing towards this altitude above home.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TookOff {
    /// Metres above home.
    pub target_alt: f32,
}

impl Answer for TookOff {
    fn write(&self, out: &mut Fields<'_>) {
        out.str("fsm", "takeoff").f32("target_alt", self.target_alt);
    }
}

/// `disarm`: the motors stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Disarmed;

impl Answer for Disarmed {
    fn write(&self, out: &mut Fields<'_>) {
        out.bool("armed", false).str("fsm", "disarmed");
    }
}

/// `set_sp_ned`: the setpoint streamed (if still) and the state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Following {
    /// The setpoint streamed, if any.
    pub setpoint: Option<Pose>,
    /// `fsm`.
    pub fsm: &'static str,
}

impl Answer for Following {
    fn write(&self, out: &mut Fields<'_>) {
        write_pose(out, "sp", self.setpoint);
        out.bool("active", self.setpoint.is_some()).str("fsm", self.fsm);
    }
}

/// `mission`: on the autopilot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Uploaded {
    /// Its external id.
    pub ext_id: u32,
    /// Its waypoints.
    pub waypoints: usize,
    /// The mission items uploaded.
    pub items: usize,
}

impl Answer for Uploaded {
    fn write(&self, out: &mut Fields<'_>) {
        out.u64("ext_id", self.ext_id.into())
            .u64("waypoints", self.waypoints as u64)
            .u64("items", self.items as u64);
    }
}

/// `mw_exec`: the run started.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Started {
    /// The mission.
    pub ext_id: u32,
    /// The waypoints it flies.
    pub wp_ids: Vec<u32>,
}

impl Answer for Started {
    fn write(&self, out: &mut Fields<'_>) {
        out.u64("ext_id", self.ext_id.into()).array("wp_ids", |a| {
            for id in &self.wp_ids {
                a.u64((*id).into());
            }
        });
        out.str("fsm", "mission");
    }
}

/// `get_param`, `set_param`: one parameter.
#[derive(Clone, Debug, PartialEq)]
pub struct Param {
    /// Its name.
    pub name: String,
    /// Its value.
    pub value: ParamValue,
    /// Its type.
    pub ty: MavParamType,
    /// Its index on the autopilot.
    pub index: u16,
    /// How many parameters the autopilot has.
    pub count: u16,
}

impl Answer for Param {
    fn write(&self, out: &mut Fields<'_>) {
        out.object("param", |o| write_param(o, &self.name, self.value));
        out.object("info", |o| {
            o.str("type", autopilot::type_name(self.ty))
                .u64("index", self.index.into())
                .u64("count", self.count.into());
        });
    }
}

/// `param`: every parameter, by index.
#[derive(Clone, Debug, PartialEq)]
pub struct Params(pub Vec<(String, ParamValue)>);

impl Answer for Params {
    fn write(&self, out: &mut Fields<'_>) {
        out.object("param", |o| {
            for (name, value) in &self.0 {
                write_param(o, name, *value);
            }
        });
    }
}

/// `save_param 1` (saved), `save_param 0` and `reset_param` (not).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Saved(pub bool);

impl Answer for Saved {
    fn write(&self, out: &mut Fields<'_>) {
        out.bool("saved", self.0);
    }
}

/// `reboot_ap`: the autopilot reboots.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rebooting;

impl Answer for Rebooting {
    fn write(&self, out: &mut Fields<'_>) {
        out.object("reboot", |o| {
            o.str("target", "autopilot").bool("simulated", false);
        });
    }
}

/// `capture`: the image's sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Captured(pub u32);

impl Answer for Captured {
    fn write(&self, out: &mut Fields<'_>) {
        out.object("capture", |o| {
            o.u64("seq", self.0.into());
        });
    }
}

/// `record`: whether the camera records now.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Recording(pub bool);

impl Answer for Recording {
    fn write(&self, out: &mut Fields<'_>) {
        out.bool("recording", self.0);
    }
}

fn write_param(o: &mut Fields<'_>, name: &str, value: ParamValue) {
    match value {
        ParamValue::Int(i) => o.i64(name, i),
        ParamValue::Float(f) => o.f32(name, f),
    };
}

/// Writes `pose` under `key` as `{x,y,z,yaw}`, or null.
pub fn write_pose(out: &mut Fields<'_>, key: &str, pose: Option<Pose>) {
    match pose {
        Some(p) => out.object(key, |o| {
            o.f32("x", p.x).f32("y", p.y).f32("z", p.z).f32("yaw", p.yaw);
        }),
        None => out.null(key),
    };
}
