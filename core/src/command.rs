//! The typed request: [`Command`], its [`Args`] and their value types.
//!
//! A `Command` is always valid: its arguments have the grammar of its table
//! row and every value is in range. [`crate::parse()`] produces one from a
//! frame, [`Command::new`] from typed values; [`Command::encode`] turns it
//! back into text that parses to the same command.

use heapless::Vec;

use crate::error::ArgError;
use crate::number::Number;
use crate::table::{CommandId, Grammar};

/// Most waypoint ids one `mw_exec` may carry.
pub const MAX_WAYPOINT_IDS: usize = 64;
/// Most heights one `zyhk` may carry.
pub const MAX_HEIGHTS: usize = 32;

/// A position and heading: NED metres and radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// North, metres.
    pub x: f32,
    /// East, metres.
    pub y: f32,
    /// Down, metres.
    pub z: f32,
    /// Heading, radians.
    pub yaw: f32,
}

/// A position: NED metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point {
    /// North, metres.
    pub x: f32,
    /// East, metres.
    pub y: f32,
    /// Down, metres.
    pub z: f32,
}

/// Where `zyhk` lands after its hovers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LandPoint {
    /// North, metres.
    pub x: f32,
    /// East, metres.
    pub y: f32,
    /// Heading, radians.
    pub yaw: f32,
}

/// A mission payload: JSON (it started with `{` or `[` and is well-formed)
/// or a path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Payload<'a> {
    /// A well-formed JSON object or array, verbatim.
    Json(&'a str),
    /// A relative path of safe components.
    Path(&'a str),
}

impl<'a> Payload<'a> {
    /// The payload text as it appears on the wire.
    pub fn as_str(&self) -> &'a str {
        match *self {
            Payload::Json(s) | Payload::Path(s) => s,
        }
    }
}

/// The arguments of a command. Each variant is the value of the
/// [`Grammar`] of the same name.
#[derive(Clone, Debug, PartialEq)]
pub enum Args<'a> {
    /// No arguments.
    None,
    /// `0` (false) or `1` (true).
    Flag(bool),
    /// An optional unsigned integer.
    OptCount(Option<u32>),
    /// A PWM value.
    Pwm(u16),
    /// A finite number ≥ 0, as sent (a backend checks its own range on
    /// the value as sent: [`Number::above`]).
    Amount(Number<'a>),
    /// An optional finite number ≥ 0, as sent.
    OptAmount(Option<Number<'a>>),
    /// An angle in degrees, -90..=90.
    Angle(f32),
    /// A single path component.
    Name(&'a str),
    /// An optional single path component.
    OptName(Option<&'a str>),
    /// A relative path.
    Path(&'a str),
    /// Free text.
    Text(&'a str),
    /// A task name.
    TaskName(&'a str),
    /// A login password.
    Secret(&'a str),
    /// A new login password.
    NewPassword(&'a str),
    /// A parameter name.
    ParamName(&'a str),
    /// `set_param name:value`.
    SetParam {
        /// Parameter name.
        name: &'a str,
        /// The value as text; its type is the backend's business.
        value: &'a str,
    },
    /// `set_sp_ned x:y:z:yaw`, above the ground (`z < 0`).
    Setpoint(Pose),
    /// `test_wp x:y:z`.
    Point(Point),
    /// `relocate_pos x,y,z,yaw`.
    Pose(Pose),
    /// `zyhk h1,h2,... [lx,ly,lyaw]`.
    Zyhk {
        /// Hover heights, at least one.
        heights: Vec<f32, MAX_HEIGHTS>,
        /// Optional landing point.
        land: Option<LandPoint>,
    },
    /// `mission ext_id:path_or_json`.
    Mission {
        /// External mission id.
        ext_id: u32,
        /// The mission itself.
        payload: Payload<'a>,
    },
    /// `mw_exec ext_id:id,id,...`.
    MwExec {
        /// External mission id.
        ext_id: u32,
        /// Waypoint ids, at least one.
        wp_ids: Vec<u32, MAX_WAYPOINT_IDS>,
    },
    /// `ai1_mission task_id:mission_file`.
    Ai1Mission {
        /// Task id: 1–64 of `[A-Za-z0-9_-]`.
        task_id: &'a str,
        /// Relative path of the mission file.
        file: &'a str,
    },
    /// `control_take [failsafe]`: whether the word `failsafe` was given.
    Override(bool),
}

impl Args<'_> {
    /// The grammar these arguments belong to.
    pub fn grammar(&self) -> Grammar {
        match self {
            Args::None => Grammar::None,
            Args::Flag(_) => Grammar::Flag,
            Args::OptCount(_) => Grammar::OptCount,
            Args::Pwm(_) => Grammar::Pwm,
            Args::Amount(_) => Grammar::Amount,
            Args::OptAmount(_) => Grammar::OptAmount,
            Args::Angle(_) => Grammar::Angle,
            Args::Name(_) => Grammar::Name,
            Args::OptName(_) => Grammar::OptName,
            Args::Path(_) => Grammar::Path,
            Args::Text(_) => Grammar::Text,
            Args::TaskName(_) => Grammar::TaskName,
            Args::Secret(_) => Grammar::Secret,
            Args::NewPassword(_) => Grammar::NewPassword,
            Args::ParamName(_) => Grammar::ParamName,
            Args::SetParam { .. } => Grammar::SetParam,
            Args::Setpoint(_) => Grammar::Setpoint,
            Args::Point(_) => Grammar::Point,
            Args::Pose(_) => Grammar::Pose,
            Args::Zyhk { .. } => Grammar::Zyhk,
            Args::Mission { .. } => Grammar::Mission,
            Args::MwExec { .. } => Grammar::MwExec,
            Args::Ai1Mission { .. } => Grammar::Ai1Mission,
            Args::Override(_) => Grammar::Override,
        }
    }
}

/// A valid request: a known command with arguments of its grammar.
#[derive(Clone, Debug, PartialEq)]
pub struct Command<'a> {
    id: CommandId,
    args: Args<'a>,
}

impl<'a> Command<'a> {
    /// Builds a command from typed values, checking them exactly as the
    /// parser would.
    pub fn new(id: CommandId, args: Args<'a>) -> Result<Self, ArgError> {
        if args.grammar() != id.spec().grammar {
            return Err(ArgError::WrongGrammar);
        }
        args.validate()?;
        Ok(Command { id, args })
    }

    /// A command without arguments, or `None` if `id` takes arguments.
    pub fn bare(id: CommandId) -> Option<Self> {
        Command::new(id, Args::None).ok()
    }

    /// Used by the parser, whose arguments are valid by construction.
    pub(crate) fn from_parts(id: CommandId, args: Args<'a>) -> Self {
        Command { id, args }
    }

    /// Which command this is.
    pub fn id(&self) -> CommandId {
        self.id
    }

    /// Its arguments.
    pub fn args(&self) -> &Args<'a> {
        &self.args
    }
}
