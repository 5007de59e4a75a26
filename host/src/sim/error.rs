//! Why the simulator refused or failed a command, and the `ret` each answer
//! carries. The text a client sees is the `Display` of these variants.

use lluav_core::{Failure, Ret};

/// A command the simulated vehicle did not carry out.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The command needs the vehicle in the air.
    #[error("Vehicle is not flying")]
    NotFlying,
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
    /// A setpoint or waypoint outside the flyable volume.
    #[error("{0}")]
    OutsideFence(String),
    /// No such parameter.
    #[error("Unknown parameter: {0}")]
    UnknownParam(String),
    /// A parameter value of the wrong type.
    #[error("{name}: expected {expected}, got '{value}'")]
    ParamType {
        /// Parameter name.
        name: String,
        /// The type it has.
        expected: &'static str,
        /// What was sent.
        value: String,
    },
    /// A parameter value outside its range.
    #[error("{name}: {value} out of range {min}..{max}")]
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
    #[error("Bad mission: {0}")]
    Mission(String),
    /// No mission with this external id.
    #[error("Unknown mission: {0}")]
    UnknownMission(u32),
    /// Waypoint ids the mission does not have.
    #[error("Unknown waypoint ids: {0}")]
    UnknownWaypoints(String),
    /// A value the simulated device does not accept.
    #[error("{0}")]
    Refused(String),
    /// A named file or directory does not exist.
    #[error("Not found: {0}")]
    NotFound(String),
    /// A client path resolves outside the data directory.
    #[error("Refused: {0} leaves the data directory")]
    Escapes(String),
    /// A command the protocol core answers itself reached the simulator.
    #[error("{0} is not handled by the simulator")]
    NotBackend(&'static str),
    /// Disk I/O failed.
    #[error("{what}: {err}")]
    Io {
        /// What was being done.
        what: String,
        /// The error.
        err: std::io::Error,
    },
}

impl SimError {
    /// An I/O failure while doing `what`.
    pub fn io(what: impl Into<String>, err: std::io::Error) -> Self {
        SimError::Io {
            what: what.into(),
            err,
        }
    }

    /// The `ret` this failure is answered with.
    pub fn ret(&self) -> Ret {
        match self {
            SimError::ParamType { .. } | SimError::NotBackend(_) => Ret::InvalidArgs,
            SimError::Io { .. } => Ret::SystemCall,
            _ => Ret::Failed,
        }
    }

    /// The protocol failure a client sees.
    pub fn to_failure(&self) -> Failure {
        Failure::fmt(self.ret(), format_args!("{self}"))
    }
}

/// The simulator's result type.
pub type SimResult<T = ()> = Result<T, SimError>;
