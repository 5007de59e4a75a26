//! Error types, return codes and the exact message strings of DESIGN.md.
//!
//! Errors stay typed until the response is written; the strings a client
//! sees live here and nowhere else.

use core::fmt;

use crate::table::CommandId;

/// The `ret` field of a response.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(i16)]
pub enum Ret {
    /// Success.
    Ok = 0,
    /// General failure; `msg` says why.
    Failed = -1,
    /// Invalid arguments or unsupported command.
    InvalidArgs = -2,
    /// An external system call failed.
    SystemCall = -3,
    /// An unhandled fault while processing the command.
    Unhandled = -100,
}

impl Ret {
    /// The number on the wire.
    pub fn code(self) -> i16 {
        self as i16
    }
}

/// Why a command's arguments were refused. Every variant is answered with
/// ret -2: the message is `Invalid arguments: <reason>` for a variant with
/// a [`ArgError::reason`], else `Invalid arguments, usage: <usage>`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ArgError {
    /// A required argument is missing.
    Missing,
    /// Arguments were given to a command that takes none, or too many.
    Unexpected,
    /// The fields are not in the command's shape (separators, counts).
    Malformed,
    /// A field that should be a number is not a decimal number (`nan`
    /// and `inf` are not).
    NotANumber,
    /// A hand-built number is NaN or infinite.
    NotFinite,
    /// A value is outside its range (a number too large for its type
    /// included); the reason names the range.
    OutOfRange(Bound),
    /// A setpoint at or below the ground (`z >= 0`, NED from home).
    AtOrBelowGround,
    /// A flag is not exactly `0` or `1`.
    NotAFlag,
    /// A name or path could escape its directory or holds forbidden bytes.
    UnsafePath,
    /// A text field holds control or format characters (Unicode Cc, Cf)
    /// or ends with a space.
    BadText,
    /// A list holds more items than its fixed capacity.
    TooMany,
    /// A JSON payload is not well-formed (or nests too deeply).
    BadJson,
    /// A new password breaks the password rules.
    BadPassword,
    /// A new password is one of the special login values (admin, logout).
    SpecialPassword,
    /// [`crate::Command::new`] got arguments of another command's grammar.
    WrongGrammar,
}

impl ArgError {
    /// What a client must be told instead of the usage line, if anything:
    /// every range refusal names the range (DESIGN.md, "Request grammar").
    pub fn reason(self) -> Option<&'static str> {
        let at = match self {
            ArgError::AtOrBelowGround => 0,
            ArgError::SpecialPassword => 1,
            ArgError::OutOfRange(bound) => 2 + bound as usize,
            _ => return None,
        };
        messages::REASONS.get(at).copied()
    }
}

/// The range a value left: each names itself in the refusal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Bound {
    /// An angle, -90..90 degrees.
    Angle,
    /// A number that may not be negative.
    NonNegative,
    /// A PWM value, 0..65535.
    Pwm,
    /// An id or count: an unsigned 32-bit integer.
    Integer,
    /// A number a 32-bit float can hold.
    Float,
    /// Free text (a plan): at most [`crate::parse::MAX_TEXT_LEN`] bytes.
    Text,
    /// A task name: at most [`crate::parse::MAX_TASK_NAME_LEN`] bytes.
    TaskName,
}

impl Bound {
    /// The refusal's reason, naming the range.
    pub fn reason(self) -> &'static str {
        ArgError::OutOfRange(self).reason().unwrap_or("")
    }
}

/// Why a frame could not be turned into a [`crate::Command`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseError<'a> {
    /// The frame is empty or blank.
    Empty,
    /// The name is not in the command table; the name is borrowed verbatim.
    Unknown(&'a str),
    /// The command is known but its arguments are not valid.
    InvalidArgs(CommandId, ArgError),
}

impl ParseError<'_> {
    /// The `cmd` id to answer with: 0 unless the command is known.
    pub fn command(&self) -> Option<CommandId> {
        match self {
            ParseError::InvalidArgs(id, _) => Some(*id),
            ParseError::Empty | ParseError::Unknown(_) => None,
        }
    }
}

/// A gate that refused to run a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// A password is set and the session has not logged in.
    LoginFirst,
    /// The command is admin-only.
    AdminOnly,
    /// `runOnArm=false` and the vehicle is armed.
    Armed,
    /// `runInLock=false`, lock mode is on and the session is not admin.
    Locked,
}

/// Capacity of a backend's failure message, in bytes.
pub const FAILURE_MSG_CAPACITY: usize = 96;

/// A command the backend could not carry out.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Failure {
    ret: Ret,
    msg: heapless::String<FAILURE_MSG_CAPACITY>,
    /// The message is in the response buffer ([`crate::Fields::fail`]).
    written: bool,
    /// Seconds until a refused login may be tried again (0: not one).
    retry_after_s: u32,
}

impl Failure {
    /// A failure with `ret` and a message; a message longer than
    /// [`FAILURE_MSG_CAPACITY`] is cut at a character boundary.
    pub fn new(ret: Ret, msg: &str) -> Self {
        let mut f = Failure {
            ret,
            msg: heapless::String::new(),
            written: false,
            retry_after_s: 0,
        };
        push_truncated(&mut f.msg, msg);
        f
    }

    /// A failure whose message is formatted, cut like [`Failure::new`].
    pub fn fmt(ret: Ret, args: fmt::Arguments<'_>) -> Self {
        let mut w = Truncating(heapless::String::new());
        // Truncating never reports an error.
        let _ = fmt::write(&mut w, args);
        Failure {
            ret,
            msg: w.0,
            written: false,
            retry_after_s: 0,
        }
    }

    /// ret -2 as a parse error of `id` with `e` answers: `Invalid
    /// arguments: <reason>`, or `Invalid arguments, usage: ...` for an
    /// error without one. Written without `core::fmt`, which an MCU would
    /// otherwise link for this one message.
    pub(crate) fn invalid(id: CommandId, e: ArgError) -> Self {
        let [prefix, text] = ParseError::InvalidArgs(id, e).parts();
        let mut f = Failure::new(Ret::InvalidArgs, prefix);
        push_truncated(&mut f.msg, text);
        f
    }

    /// A failure whose message [`crate::Fields::fail`] wrote into the
    /// response buffer.
    pub(crate) fn written(ret: Ret) -> Self {
        Failure {
            ret,
            msg: heapless::String::new(),
            written: true,
            retry_after_s: 0,
        }
    }

    /// A login the throttle refused, and when to try again (at least 1 s:
    /// 0 would mean it is not one).
    pub(crate) fn throttled(retry_after_s: u32) -> Self {
        Failure {
            retry_after_s,
            ..Failure::failed(messages::THROTTLED)
        }
    }

    /// Seconds until a refused login may be tried again, if it is one.
    pub(crate) fn retry_after_s(&self) -> Option<u32> {
        (self.retry_after_s > 0).then_some(self.retry_after_s)
    }

    /// Whether the message is in the response buffer rather than here.
    pub(crate) fn is_written(&self) -> bool {
        self.written
    }

    /// ret -1: the command failed; `msg` says why.
    pub fn failed(msg: &str) -> Self {
        Failure::new(Ret::Failed, msg)
    }

    /// ret -2: this backend does not support the command or value.
    pub fn unsupported(msg: &str) -> Self {
        Failure::new(Ret::InvalidArgs, msg)
    }

    /// ret -3: a system call or I/O failed; `msg` says which.
    pub fn system(msg: &str) -> Self {
        Failure::new(Ret::SystemCall, msg)
    }

    /// ret -100: the backend hit a fault (the host catches panics as this).
    pub fn unhandled() -> Self {
        Failure::new(Ret::Unhandled, messages::UNHANDLED)
    }

    /// The return code.
    pub fn ret(&self) -> Ret {
        self.ret
    }

    /// The message (empty when [`crate::Fields::fail`] wrote it into the
    /// response buffer instead).
    pub fn msg(&self) -> &str {
        &self.msg
    }
}

fn push_truncated<const N: usize>(s: &mut heapless::String<N>, text: &str) {
    let room = N - s.len();
    // Cannot fail: the cut fits the room.
    let _ = s.push_str(cut_at_char_boundary(text, room));
}

struct Truncating<const N: usize>(heapless::String<N>);

impl<const N: usize> fmt::Write for Truncating<N> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        push_truncated(&mut self.0, s);
        Ok(())
    }
}

/// The exact messages of DESIGN.md's error table.
pub mod messages {
    /// Unknown name; the (cut, escaped) name follows.
    pub const UNSUPPORTED_PREFIX: &str = "Unsupported command: ";
    /// Empty or blank frame.
    pub const EMPTY: &str = "Empty command";
    /// Bad or missing arguments; the usage line follows.
    pub const INVALID_ARGS_PREFIX: &str = "Invalid arguments, usage: ";
    /// A value refused for a reason; the reason follows.
    pub const INVALID_REASON_PREFIX: &str = "Invalid arguments: ";
    /// A setpoint at or below the ground.
    pub const GROUND: &str =
        "setpoint at or below the ground (z >= 0; up is negative z): use land to descend";
    /// The reasons [`super::ArgError::reason`] gives, in its order: a
    /// setpoint at or below the ground, a special login value as a new
    /// password, then one per [`super::Bound`], in its order. One table,
    /// so that a firmware links one lookup for all of them.
    pub const REASONS: [&str; 9] = [
        GROUND,
        "the admin and logout values cannot be passwords",
        "angle out of range -90..90",
        "number below 0",
        "PWM value out of range 0..65535",
        "integer out of range 0..4294967295",
        "number beyond a 32-bit float (3.4028235e38)",
        "text longer than 4096 bytes",
        "task name longer than 256 bytes",
    ];
    /// Not logged in.
    pub const LOGIN_FIRST: &str = "Login first!";
    /// Wrong password.
    pub const WRONG_PASSWORD: &str = "Wrong password!";
    /// The client's address is locked out after too many wrong passwords.
    pub const THROTTLED: &str = "Too many wrong passwords, retry later";
    /// Armed gate.
    pub const ARMED: &str = "Not allow when vehicle is ARMED!";
    /// Lock gate.
    pub const LOCKED: &str = "CMD not permitted to run in LOCK mode!";
    /// Admin-only command, session not admin.
    pub const ADMIN_ONLY: &str = "Admin only!";
    /// The response did not fit the buffer.
    pub const TOO_LARGE: &str = "Response too large";
    /// A fault while processing.
    pub const UNHANDLED: &str = "Unhandled exception";
    /// A failsafe refusal starts so; the failsafe's reason follows.
    pub const FAILSAFE_OPEN: &str = "Vehicle is in failsafe (";
    /// ... and ends so for a command that would steer.
    pub const FAILSAFE_MOTION: &str = "): land, rtl or control_take failsafe";
    /// ... and so for a return while the failsafe lands the vehicle.
    pub const FAILSAFE_LANDING: &str = "): land, tether_land, disarm or control_take failsafe";
    /// ... and so for a plain `control_take` during a failsafe.
    pub const FAILSAFE_TAKE: &str = "): control_take failsafe overrides it";
    /// Another session is in control; its label follows.
    pub const FLOWN_BY: &str = "Vehicle is flown by ";
    /// ... then since when (ms since the Unix epoch) ...
    pub const FLOWN_SINCE: &str = " since ";
    /// ... then what to do.
    pub const FLOWN_TAKE: &str = ": control_take to take over";
    /// `control_release` from a session that does not hold control.
    pub const NOT_IN_CONTROL: &str = "This session is not in control";
    /// How many bytes of an unknown name are echoed back.
    pub const UNKNOWN_NAME_ECHO: usize = 32;
}

impl Refusal {
    /// The message a client sees.
    pub fn message(self) -> &'static str {
        match self {
            Refusal::LoginFirst => messages::LOGIN_FIRST,
            Refusal::AdminOnly => messages::ADMIN_ONLY,
            Refusal::Armed => messages::ARMED,
            Refusal::Locked => messages::LOCKED,
        }
    }
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.message())
    }
}

impl<'a> ParseError<'a> {
    /// The message a client sees, in two parts (no copy of the name).
    pub(crate) fn parts(&self) -> [&'a str; 2] {
        match *self {
            ParseError::Empty => [messages::EMPTY, ""],
            ParseError::Unknown(name) => [
                messages::UNSUPPORTED_PREFIX,
                cut_at_char_boundary(name, messages::UNKNOWN_NAME_ECHO),
            ],
            ParseError::InvalidArgs(id, e) => match e.reason() {
                Some(reason) => [messages::INVALID_REASON_PREFIX, reason],
                None => [messages::INVALID_ARGS_PREFIX, id.spec().usage],
            },
        }
    }
}

impl fmt::Display for ParseError<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [a, b] = self.parts();
        f.write_str(a)?;
        f.write_str(b)
    }
}

/// The longest prefix of `s` that is at most `max` bytes and ends on a
/// character boundary.
pub(crate) fn cut_at_char_boundary(s: &str, max: usize) -> &str {
    let mut end = max.min(s.len());
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    s.get(..end).unwrap_or("")
}
