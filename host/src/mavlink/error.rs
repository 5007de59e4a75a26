//! Why the MAVLink vehicle refused or failed a command, and the `ret` each
//! answer carries (DESIGN.md, "Errors", "Backends"): -1 with the
//! autopilot's `MAV_RESULT` name when it refuses, -3 when it does not
//! answer or the link is lost, -2 for a value it cannot take or a command
//! with no MAVLink meaning. The `Display` is the whole message a client
//! sees.

use lluav_core::Ret;

use crate::vehicle::Refusal;

/// A command the MAVLink vehicle did not carry out.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum MavError {
    /// No heartbeat from the autopilot for the link timeout, or none yet.
    #[error("MAVLink link lost: {0}")]
    LinkLost(String),
    /// The autopilot answered the command with a refusal.
    #[error("{cmd} refused by the autopilot: {result}")]
    Refused {
        /// The `MAV_CMD_*` name.
        cmd: String,
        /// The `MAV_RESULT_*` name.
        result: String,
    },
    /// No `COMMAND_ACK` (or other answer) within the timeout.
    #[error("No answer from the autopilot: {0}")]
    NoAnswer(String),
    /// Sending on the link failed.
    #[error("MAVLink send failed: {0}")]
    Send(String),
    /// A command with no MAVLink counterpart.
    #[error("Invalid arguments: not supported by this vehicle")]
    Unsupported,
    /// A value the autopilot cannot take (a parameter value of the wrong
    /// type, a mission it refused as invalid).
    #[error("Invalid arguments: {0}")]
    Invalid(String),
    /// The vehicle's state does not allow the command now.
    #[error("{0}")]
    State(String),
    /// A refusal computed elsewhere (the mission parser, the companion's
    /// files) with its own `ret`.
    #[error("{1}")]
    Other(Ret, String),
}

impl MavError {
    /// The vehicle is on the ground (or disarmed) and the command moves a
    /// flying vehicle.
    pub(crate) fn not_flying() -> MavError {
        MavError::State("Vehicle is not flying".into())
    }

    /// Any other refusal, keeping its `ret` and message.
    pub(crate) fn from_refusal(r: &dyn Refusal) -> MavError {
        MavError::Other(r.ret(), r.to_string())
    }
}

impl Refusal for MavError {
    fn ret(&self) -> Ret {
        match self {
            MavError::LinkLost(_) | MavError::NoAnswer(_) | MavError::Send(_) => Ret::SystemCall,
            MavError::Refused { .. } | MavError::State(_) => Ret::Failed,
            MavError::Unsupported | MavError::Invalid(_) => Ret::InvalidArgs,
            MavError::Other(ret, _) => *ret,
        }
    }
}
