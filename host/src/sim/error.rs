//! Why the simulated vehicle refused or failed a command, and the `ret`
//! each answer carries (DESIGN.md, "Errors"): -2 `Invalid arguments:
//! <reason>` for a value the vehicle refuses, -1 for the vehicle's state,
//! -3 for failed I/O. The text a client sees is the `Display` of these
//! variants, written whole into the response.

use lluav_core::Ret;

use crate::files;
use crate::vehicle::Refusal;
use crate::vehicle::envelope::Outside;
use crate::vehicle::mission::BadMission;

/// A command the simulated vehicle did not carry out.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The command moves a flying vehicle; this one is on the ground.
    #[error("Vehicle is not flying")]
    NotFlying,
    /// Disarmed in the air: it falls until it hits the ground, and no
    /// command can fly it meanwhile.
    #[error("Vehicle is falling: it was disarmed in the air")]
    Falling,
    /// `bms_setpower 0`: the battery powers nothing, the motors included.
    #[error("Battery power is off: bms_setpower 1 first")]
    PowerOff,
    /// The vehicle sleeps; `wakeup` first.
    #[error("Vehicle is asleep: wakeup first")]
    Asleep,
    /// Not enough battery to take off.
    #[error("Battery too low for takeoff: {0:.0}%")]
    BatteryLow(f64),
    /// A preflight check failed (preflight is enabled).
    #[error("Preflight check failed: {0}")]
    Preflight(String),
    /// `relocate_pos` without map localisation.
    #[error("Map localization is disabled: set_maplocate 1 first")]
    MapLocateOff,
    /// A plan holds the plan lock.
    #[error("Plan locked: unlock_plan first")]
    PlanLocked,
    /// LED control is disabled.
    #[error("LED control is disabled: ledenable first")]
    LedDisabled,
    /// A value the vehicle refuses: outside the fence, out of a device's
    /// range.
    #[error("Invalid arguments: {0}")]
    Refused(String),
    /// No such parameter.
    #[error("Invalid arguments: unknown parameter {0}")]
    UnknownParam(String),
    /// A parameter value of the wrong type.
    #[error("Invalid arguments: {name} expects {expected}, got '{value}'")]
    ParamType {
        /// Parameter name.
        name: String,
        /// The type it has.
        expected: &'static str,
        /// What was sent.
        value: String,
    },
    /// A parameter value outside its range.
    #[error("Invalid arguments: {name} {value} out of range {min}..{max}")]
    ParamRange {
        /// Parameter name.
        name: String,
        /// What was sent.
        value: String,
        /// Smallest allowed value.
        min: f64,
        /// Largest allowed value.
        max: f64,
    },
    /// A mission payload the simulator cannot fly.
    #[error(transparent)]
    Mission(#[from] BadMission),
    /// A mission with this external id is running: its waypoints cannot
    /// be replaced under the vehicle.
    #[error("Mission {0} is running")]
    MissionRunning(u32),
    /// An abort id at or below the highest given out: ids are never
    /// reused.
    #[error(
        "Invalid arguments: abort_id {id} is not above the last one given, {last} (abort ids are never reused)"
    )]
    AbortIdUsed {
        /// The id asked for.
        id: u32,
        /// The highest id given so far.
        last: u32,
    },
    /// The highest abort id was given out: no new one exists.
    #[error("No abort_id is left: 4294967295 was given")]
    AbortIdsSpent,
    /// No mission with this external id.
    #[error("Invalid arguments: unknown mission {0}")]
    UnknownMission(u32),
    /// Waypoint ids the mission does not have.
    #[error("Invalid arguments: mission {ext_id} has no waypoint {ids}")]
    UnknownWaypoints {
        /// The mission.
        ext_id: u32,
        /// The ids it lacks, comma-separated.
        ids: String,
    },
    /// Something the command names does not exist (yet): the reason.
    #[error("Invalid arguments: {0}")]
    NotFound(String),
    /// `siyi_downvideo` without an id while the card holds no video.
    #[error("No video on the SIYI card")]
    NoVideo,
    /// The data directory refused a path or failed.
    #[error(transparent)]
    Files(#[from] files::Error),
    /// A command the vehicle does not own reached it: a routing bug,
    /// answered as a fault.
    #[error("Unhandled exception")]
    NotOwned(&'static str),
}

impl SimError {
    /// A target outside the envelope: -2 with the reason.
    pub(crate) fn outside(why: Outside) -> SimError {
        SimError::Refused(why.to_string())
    }
    /// An I/O failure while doing `what`.
    pub(crate) fn io(what: impl Into<String>, err: std::io::Error) -> Self {
        SimError::Files(files::Error::io(what, err))
    }
}

impl Refusal for SimError {
    fn ret(&self) -> Ret {
        match self {
            SimError::Refused(_)
            | SimError::UnknownParam(_)
            | SimError::ParamType { .. }
            | SimError::ParamRange { .. }
            | SimError::UnknownMission(_)
            | SimError::UnknownWaypoints { .. }
            | SimError::AbortIdUsed { .. }
            | SimError::NotFound(_) => Ret::InvalidArgs,
            SimError::Mission(e) => e.ret(),
            SimError::Files(e) => e.ret(),
            SimError::NotOwned(_) => Ret::Unhandled,
            _ => Ret::Failed,
        }
    }
}

/// The simulator's result type.
pub type SimResult<T = ()> = Result<T, SimError>;
