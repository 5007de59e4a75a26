//! The MAVLink microservices lluavd speaks as a client of the autopilot:
//! the command protocol (`COMMAND_LONG` / `COMMAND_ACK`, retries with the
//! confirmation field), the mission upload protocol and the parameter
//! protocol. Each is an async function over a [`Port`], so the retry and
//! timeout logic is tested against a fake link (see the tests below) and
//! runs against the real one unchanged.

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use ::mavlink::MavHeader;
use ::mavlink::dialects::ardupilotmega::{
    COMMAND_LONG_DATA, MISSION_ACK_DATA, MISSION_COUNT_DATA, MISSION_ITEM_INT_DATA, MavCmd, MavMessage,
    MavMissionResult, MavParamError, MavParamType, MavResult, PARAM_REQUEST_LIST_DATA,
    PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, PARAM_VALUE_DATA,
};
use tokio::sync::broadcast::{self, error::RecvError};
use tokio::time::Instant;

use super::error::MavError;

/// A message the link received.
#[derive(Clone, Debug)]
pub struct Incoming {
    /// Who sent it.
    pub header: MavHeader,
    /// The message.
    pub msg: MavMessage,
}

/// The autopilot's address on the link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Target {
    /// Its system id.
    pub system: u8,
    /// Its component id.
    pub component: u8,
}

impl Target {
    /// Whether `header` is this autopilot's.
    fn sent(self, header: &MavHeader) -> bool {
        header.system_id == u32::from(self.system) && header.component_id == self.component
    }
}

/// What the protocols need of a link: sending, a feed of everything
/// received, and the autopilot's address.
pub trait Port: Send + Sync + 'static {
    /// Sends one message to the autopilot.
    fn send(&self, msg: MavMessage) -> impl Future<Output = Result<(), MavError>> + Send;
    /// Every message received from now on.
    fn subscribe(&self) -> broadcast::Receiver<Arc<Incoming>>;
    /// The autopilot's address, once a heartbeat named it.
    fn target(&self) -> Result<Target, MavError>;
}

/// Timeouts and retries of the protocols.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Timing {
    /// How long to wait for a `COMMAND_ACK` before sending again.
    pub ack: Duration,
    /// How many times a command is sent (confirmation 0, 1, ...).
    pub attempts: u32,
    /// How long a command the autopilot says is in progress may take.
    pub in_progress: Duration,
    /// How long to wait for the next mission request (or the final ack).
    pub mission_item: Duration,
    /// How many times a mission message is sent before giving up.
    pub mission_attempts: u32,
    /// How long to wait for a `PARAM_VALUE`.
    pub param: Duration,
    /// How many times a parameter request is sent.
    pub param_attempts: u32,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            ack: Duration::from_millis(1500),
            attempts: 3,
            in_progress: Duration::from_secs(30),
            mission_item: Duration::from_millis(1500),
            mission_attempts: 5,
            param: Duration::from_millis(1500),
            param_attempts: 3,
        }
    }
}

/// The `MAV_CMD_*` name of `cmd`.
pub fn cmd_name(cmd: MavCmd) -> String {
    format!("{cmd:?}")
}

/// Waits until `deadline` for a message from `target` that `pick` maps to
/// `Some`; `None` on timeout.
async fn next<T>(
    rx: &mut broadcast::Receiver<Arc<Incoming>>,
    target: Target,
    deadline: Instant,
    mut pick: impl FnMut(&MavMessage) -> Option<T>,
) -> Result<Option<T>, MavError> {
    loop {
        match tokio::time::timeout_at(deadline, rx.recv()).await {
            Err(_) => return Ok(None),
            // Fell behind a burst of telemetry: what was missed is either
            // repeated by the autopilot or covered by our own retries.
            Ok(Err(RecvError::Lagged(_))) => {}
            Ok(Err(RecvError::Closed)) => return Err(MavError::LinkLost("the link task stopped".into())),
            Ok(Ok(m)) if target.sent(&m.header) => {
                if let Some(t) = pick(&m.msg) {
                    return Ok(Some(t));
                }
            }
            Ok(Ok(_)) => {}
        }
    }
}

/// Sends `cmd` as `COMMAND_LONG` until the autopilot acknowledges it:
/// `attempts` sends, the confirmation field counting them, each followed
/// by up to `ack` of waiting. `MAV_RESULT_IN_PROGRESS` stops the resending
/// and waits up to `in_progress` for the final answer.
pub async fn command<P: Port>(
    port: &P,
    timing: &Timing,
    cmd: MavCmd,
    params: [f32; 7],
) -> Result<(), MavError> {
    let target = port.target()?;
    let mut rx = port.subscribe();
    let [param1, param2, param3, param4, param5, param6, param7] = params;
    for confirmation in 0..timing.attempts {
        let msg = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1,
            param2,
            param3,
            param4,
            param5,
            param6,
            param7,
            command: cmd,
            target_system: target.system,
            target_component: target.component,
            confirmation: u8::try_from(confirmation).unwrap_or(u8::MAX),
        });
        port.send(msg).await?;
        let mut deadline = Instant::now() + timing.ack;
        let mut in_progress = false;
        loop {
            let result = next(&mut rx, target, deadline, |m| match m {
                MavMessage::COMMAND_ACK(a) if a.command == cmd => Some(a.result),
                _ => None,
            })
            .await?;
            match result {
                Some(MavResult::MAV_RESULT_ACCEPTED) => return Ok(()),
                Some(MavResult::MAV_RESULT_IN_PROGRESS) => {
                    in_progress = true;
                    deadline = Instant::now() + timing.in_progress;
                }
                Some(refused) => {
                    return Err(MavError::Refused {
                        cmd: cmd_name(cmd),
                        result: format!("{refused:?}"),
                    });
                }
                None if in_progress => {
                    return Err(MavError::NoAnswer(format!(
                        "{} still in progress after {} s",
                        cmd_name(cmd),
                        timing.in_progress.as_secs()
                    )));
                }
                None => break,
            }
        }
    }
    Err(MavError::NoAnswer(format!(
        "no COMMAND_ACK for {} after {} attempts",
        cmd_name(cmd),
        timing.attempts
    )))
}

/// An answer in the mission upload.
enum Upload {
    Request(u16),
    Ack(MavMissionResult),
}

// Legacy MISSION_REQUEST is deprecated, but older autopilots still send
// it; MISSION_ITEM_INT is the right answer to both.
#[allow(deprecated)]
/// Uploads `items` with the mission protocol: `MISSION_COUNT`, then the
/// item each `MISSION_REQUEST_INT` (or legacy `MISSION_REQUEST`) asks for,
/// until `MISSION_ACK`. A silent autopilot gets the last message again,
/// up to `mission_attempts` times; then the transfer is cancelled.
pub async fn upload_mission<P: Port>(
    port: &P,
    timing: &Timing,
    items: &[MISSION_ITEM_INT_DATA],
) -> Result<(), MavError> {
    let target = port.target()?;
    let count = u16::try_from(items.len()).map_err(|_| MavError::Invalid("too many mission items".into()))?;
    let mut rx = port.subscribe();
    let mut last = MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
        count,
        target_system: target.system,
        target_component: target.component,
    });
    let mut highest: Option<u16> = None;
    let mut silent = 0;
    port.send(last.clone()).await?;
    loop {
        let deadline = Instant::now() + timing.mission_item;
        let answer = next(&mut rx, target, deadline, |m| match m {
            MavMessage::MISSION_REQUEST_INT(r) => Some(Upload::Request(r.seq)),
            MavMessage::MISSION_REQUEST(r) => Some(Upload::Request(r.seq)),
            MavMessage::MISSION_ACK(a) => Some(Upload::Ack(a.mavtype)),
            _ => None,
        })
        .await?;
        match answer {
            None => {
                silent += 1;
                if silent >= timing.mission_attempts {
                    cancel_upload(port, target).await;
                    let stage = highest.map_or("MISSION_COUNT".to_owned(), |s| format!("mission item {s}"));
                    return Err(MavError::NoAnswer(format!(
                        "mission upload stalled after {stage} of {count} ({silent} attempts)"
                    )));
                }
                port.send(last.clone()).await?;
            }
            Some(Upload::Request(seq)) => {
                let Some(item) = items.get(usize::from(seq)) else {
                    cancel_upload(port, target).await;
                    return Err(MavError::NoAnswer(format!(
                        "the autopilot asked for mission item {seq} of {count}"
                    )));
                };
                silent = 0;
                highest = highest.max(Some(seq));
                last = MavMessage::MISSION_ITEM_INT(MISSION_ITEM_INT_DATA {
                    seq,
                    target_system: target.system,
                    target_component: target.component,
                    ..*item
                });
                port.send(last.clone()).await?;
            }
            Some(Upload::Ack(MavMissionResult::MAV_MISSION_ACCEPTED))
                if highest.map(|h| h + 1) == Some(count) =>
            {
                return Ok(());
            }
            Some(Upload::Ack(MavMissionResult::MAV_MISSION_ACCEPTED)) => {
                return Err(MavError::NoAnswer(format!(
                    "the autopilot accepted the mission before receiving all {count} items"
                )));
            }
            Some(Upload::Ack(refused)) => return Err(mission_refused(refused)),
        }
    }
}

/// Ends an upload the autopilot still waits on, best effort.
async fn cancel_upload<P: Port>(port: &P, target: Target) {
    let cancel = MavMessage::MISSION_ACK(MISSION_ACK_DATA {
        target_system: target.system,
        target_component: target.component,
        mavtype: MavMissionResult::MAV_MISSION_OPERATION_CANCELLED,
    });
    if let Err(e) = port.send(cancel).await {
        tracing::debug!(error = %e, "could not cancel the mission upload");
    }
}

/// A `MISSION_ACK` refusal: the mission itself (-2) or the vehicle's state
/// (-1).
fn mission_refused(result: MavMissionResult) -> MavError {
    use MavMissionResult as R;
    let why = format!("the autopilot refused the mission: {result:?}");
    match result {
        R::MAV_MISSION_DENIED | R::MAV_MISSION_ERROR | R::MAV_MISSION_OPERATION_CANCELLED => {
            MavError::State(why)
        }
        _ => MavError::Invalid(why),
    }
}

/// Whether a `PARAM_VALUE` or `PARAM_ERROR` names `name`.
fn names(id: &::mavlink::types::CharArray<16>, name: &str) -> bool {
    id.to_str().is_ok_and(|s| s == name)
}

/// An answer about a parameter.
enum ParamAnswer {
    Value(PARAM_VALUE_DATA),
    Error(MavParamError),
}

/// Sends `request` until a `PARAM_VALUE` (or `PARAM_ERROR`) for `name`
/// arrives.
async fn param_exchange<P: Port>(
    port: &P,
    timing: &Timing,
    name: &str,
    request: MavMessage,
) -> Result<PARAM_VALUE_DATA, MavError> {
    let target = port.target()?;
    let mut rx = port.subscribe();
    for _ in 0..timing.param_attempts {
        port.send(request.clone()).await?;
        let answer = next(&mut rx, target, Instant::now() + timing.param, |m| match m {
            MavMessage::PARAM_VALUE(v) if names(&v.param_id, name) => Some(ParamAnswer::Value(v.clone())),
            MavMessage::PARAM_ERROR(e) if names(&e.param_id, name) => Some(ParamAnswer::Error(e.error)),
            _ => None,
        })
        .await?;
        match answer {
            Some(ParamAnswer::Value(v)) => return Ok(v),
            Some(ParamAnswer::Error(MavParamError::MAV_PARAM_ERROR_DOES_NOT_EXIST)) => {
                return Err(MavError::Invalid(format!("unknown parameter {name}")));
            }
            Some(ParamAnswer::Error(e)) => {
                return Err(MavError::State(format!("parameter {name}: {e:?}")));
            }
            None => {}
        }
    }
    Err(MavError::NoAnswer(format!(
        "no PARAM_VALUE for {name} after {} requests (is the name right?)",
        timing.param_attempts
    )))
}

/// Reads one parameter by name.
pub async fn read_param<P: Port>(
    port: &P,
    timing: &Timing,
    name: &str,
) -> Result<PARAM_VALUE_DATA, MavError> {
    let target = port.target()?;
    let request = MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
        param_index: -1,
        target_system: target.system,
        target_component: target.component,
        param_id: name.into(),
    });
    param_exchange(port, timing, name, request).await
}

/// Writes one parameter (`raw` already encoded for the autopilot) and
/// returns the value the autopilot reports back.
pub async fn write_param<P: Port>(
    port: &P,
    timing: &Timing,
    name: &str,
    raw: f32,
    ty: MavParamType,
) -> Result<PARAM_VALUE_DATA, MavError> {
    let target = port.target()?;
    let request = MavMessage::PARAM_SET(PARAM_SET_DATA {
        param_value: raw,
        target_system: target.system,
        target_component: target.component,
        param_id: name.into(),
        param_type: ty,
    });
    param_exchange(port, timing, name, request).await
}

/// Reads every parameter: `PARAM_REQUEST_LIST`, then, for the indices
/// still missing once the stream pauses for `param`, `PARAM_REQUEST_READ`
/// by index, up to `param_attempts` rounds. Sorted by index.
pub async fn read_all_params<P: Port>(port: &P, timing: &Timing) -> Result<Vec<PARAM_VALUE_DATA>, MavError> {
    let target = port.target()?;
    let mut rx = port.subscribe();
    let mut got: std::collections::BTreeMap<u16, PARAM_VALUE_DATA> = std::collections::BTreeMap::new();
    let mut count: Option<u16> = None;
    port.send(MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
        target_system: target.system,
        target_component: target.component,
    }))
    .await?;
    for _ in 0..=timing.param_attempts {
        while let Some(v) = next(&mut rx, target, Instant::now() + timing.param, |m| match m {
            MavMessage::PARAM_VALUE(v) => Some(v.clone()),
            _ => None,
        })
        .await?
        {
            count = Some(v.param_count);
            got.insert(v.param_index, v);
            if count.is_some_and(|c| got.len() >= usize::from(c)) {
                return Ok(got.into_values().collect());
            }
        }
        let Some(total) = count else { break };
        for index in (0..total).filter(|i| !got.contains_key(i)) {
            port.send(MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
                param_index: i16::try_from(index).unwrap_or(i16::MAX),
                target_system: target.system,
                target_component: target.component,
                param_id: "".into(),
            }))
            .await?;
        }
    }
    Err(MavError::NoAnswer(match count {
        Some(total) => format!("{} of {total} parameters arrived", got.len()),
        None => "no PARAM_VALUE after PARAM_REQUEST_LIST".into(),
    }))
}

/// A mission item for the protocol: `seq` and the target are filled in by
/// [`upload_mission`].
pub fn mission_item(
    command: MavCmd,
    frame: ::mavlink::dialects::ardupilotmega::MavFrame,
    params: [f32; 4],
    (x, y, z): (i32, i32, f32),
) -> MISSION_ITEM_INT_DATA {
    let [param1, param2, param3, param4] = params;
    MISSION_ITEM_INT_DATA {
        param1,
        param2,
        param3,
        param4,
        x,
        y,
        z,
        seq: 0,
        command,
        target_system: 0,
        target_component: 0,
        frame,
        current: 0,
        autocontinue: 1,
    }
}

#[cfg(test)]
#[allow(deprecated)]
mod tests;
