//! The parser's value rules applied to hand-built arguments, so that
//! [`Command::new`](crate::Command::new) accepts exactly what
//! [`parse`](crate::parse()) can produce.

use super::rules;
use crate::command::{Args, Payload};
use crate::error::ArgError;
use crate::number::Number;

impl Args<'_> {
    /// Checks every value against the rules the parser enforces, so that a
    /// hand-built command is exactly as valid as a parsed one.
    pub(crate) fn validate(&self) -> Result<(), ArgError> {
        let finite = |v: f32| rules::finite(v).map(|_| ());
        match self {
            Args::None | Args::Flag(_) | Args::OptCount(_) | Args::Pwm(_) | Args::Override(_) => Ok(()),
            Args::Amount(n) | Args::OptAmount(Some(n)) => rules::non_negative(*n).map(|_| ()),
            Args::OptAmount(None) | Args::OptName(None) => Ok(()),
            Args::Angle(v) => rules::angle(Number::from(*v)).map(|_| ()),
            Args::Name(s) | Args::OptName(Some(s)) => rules::name(s).map(|_| ()),
            Args::Path(s) => rules::path(s).map(|_| ()),
            Args::Text(s) => rules::free_text(s).map(|_| ()),
            Args::TaskName(s) => rules::task_name(s).map(|_| ()),
            Args::Secret(s) => rules::secret(s).map(|_| ()),
            Args::NewPassword(s) => rules::new_password(s).map(|_| ()),
            Args::ParamName(s) => rules::param_name(s).map(|_| ()),
            Args::SetParam { name, value } => {
                rules::param_name(name)?;
                rules::text(value).map(|_| ())
            }
            Args::Setpoint(p) => rules::setpoint(*p).map(|_| ()),
            Args::Pose(p) => [p.x, p.y, p.z, p.yaw].into_iter().try_for_each(finite),
            Args::Point(p) => [p.x, p.y, p.z].into_iter().try_for_each(finite),
            Args::Zyhk { heights, land } => {
                if heights.is_empty() {
                    return Err(ArgError::Missing);
                }
                heights.iter().copied().try_for_each(finite)?;
                land.map_or(Ok(()), |l| [l.x, l.y, l.yaw].into_iter().try_for_each(finite))
            }
            Args::Mission { payload, .. } => match payload {
                Payload::Json(s) => rules::json(s).map(|_| ()),
                Payload::Path(s) => rules::path(s).map(|_| ()),
            },
            Args::MwExec { wp_ids, .. } => {
                if wp_ids.is_empty() {
                    Err(ArgError::Missing)
                } else {
                    Ok(())
                }
            }
            Args::Ai1Mission { task_id, file } => {
                rules::task_id(task_id)?;
                rules::path(file).map(|_| ())
            }
        }
    }
}
