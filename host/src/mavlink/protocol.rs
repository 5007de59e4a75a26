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
    COMMAND_LONG_DATA, MISSION_ACK_DATA, MISSION_COUNT_DATA, MISSION_ITEM_INT_DATA,
    MISSION_REQUEST_LIST_DATA, MavCmd, MavMessage, MavMissionResult, MavParamError, MavParamType, MavResult,
    PARAM_REQUEST_LIST_DATA, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA, PARAM_VALUE_DATA,
};
use tokio::sync::broadcast::{self, error::RecvError};
use tokio::time::Instant;

use super::effect::Effect;
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
    pub(super) fn sent(self, header: &MavHeader) -> bool {
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
    /// How many times an upload that stalled mid-transfer starts over
    /// with `MISSION_COUNT`: an autopilot gives up its side of a transfer
    /// after its own few re-requests (MAVSDK after 5 × 0.5 s) and then
    /// answers nothing but a new one.
    pub mission_restarts: u32,
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
            mission_restarts: 1,
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
/// and waits up to `in_progress` for the final answer. When no answer
/// comes, the acknowledgement may have been lost on the way back: the
/// command happened if the autopilot's telemetry showed its `effect`
/// meanwhile, and is no answer (-3) if it did not or nothing says.
pub async fn command<P: Port>(
    port: &P,
    timing: &Timing,
    cmd: MavCmd,
    params: [f32; 7],
    effect: Option<Effect>,
) -> Result<(), MavError> {
    let target = port.target()?;
    let mut rx = port.subscribe();
    // Whether the telemetry showed the effect while waiting.
    let mut seen = false;
    let unanswered = match acknowledge(port, timing, (cmd, params), target, &mut rx, |m| {
        seen |= effect.is_some_and(|e| e.seen(m));
    })
    .await?
    {
        Some(unanswered) => unanswered,
        None => return Ok(()),
    };
    if seen {
        tracing::info!(cmd = %cmd_name(cmd), "no COMMAND_ACK, but the telemetry shows it happened");
        return Ok(());
    }
    Err(unanswered)
}

/// The command protocol proper: `Ok(None)` when accepted, `Ok(Some(e))`
/// when no answer came (`e` says how), `Err` for a refusal or a link
/// failure; `watch` sees every other message of the autopilot meanwhile.
async fn acknowledge<P: Port>(
    port: &P,
    timing: &Timing,
    (cmd, params): (MavCmd, [f32; 7]),
    target: Target,
    rx: &mut broadcast::Receiver<Arc<Incoming>>,
    mut watch: impl FnMut(&MavMessage),
) -> Result<Option<MavError>, MavError> {
    let [param1, param2, param3, param4, param5, param6, param7] = params;
    for confirmation in 0..timing.attempts {
        port.send(MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
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
        }))
        .await?;
        let mut deadline = Instant::now() + timing.ack;
        let mut in_progress = false;
        loop {
            let result = next(rx, target, deadline, |m| match m {
                MavMessage::COMMAND_ACK(a) if a.command == cmd => Some(a.result),
                other => {
                    watch(other);
                    None
                }
            })
            .await?;
            match result {
                Some(MavResult::MAV_RESULT_ACCEPTED) => return Ok(None),
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
                    let secs = timing.in_progress.as_secs();
                    let why = format!("{} still in progress after {secs} s", cmd_name(cmd));
                    return Ok(Some(MavError::NoAnswer(why)));
                }
                None => break,
            }
        }
    }
    Ok(Some(MavError::NoAnswer(format!(
        "no COMMAND_ACK for {} after {} attempts",
        cmd_name(cmd),
        timing.attempts
    ))))
}

// Legacy MISSION_REQUEST is deprecated, but older autopilots still send
// it; MISSION_ITEM_INT is the right answer to both.
#[allow(deprecated)]
/// Uploads `items` with the mission protocol: `MISSION_COUNT`, then the
/// item each `MISSION_REQUEST_INT` (or legacy `MISSION_REQUEST`) asks for,
/// until `MISSION_ACK` (see [`Upload`]). When the final acknowledgement
/// is lost, the mission count is read back: the autopilot holds the
/// mission if it holds that many items. A transfer that stalls after the
/// autopilot asked for an item, or whose read-back finds another count,
/// starts over with `MISSION_COUNT` up to `mission_restarts` times.
/// Nothing is ever cancelled: the autopilot may hold the mission. Each
/// start, and each read-back, waits at most
/// `mission_attempts × mission_item` for an answer.
pub async fn upload_mission<P: Port>(
    port: &P,
    timing: &Timing,
    items: &[MISSION_ITEM_INT_DATA],
) -> Result<(), MavError> {
    let target = port.target()?;
    let mut upload = Upload::new(target, items, timing.mission_attempts)?.restarting(timing.mission_restarts);
    let mut rx = port.subscribe();
    port.send(upload.first()).await?;
    loop {
        let deadline = Instant::now() + timing.mission_item;
        let heard = next(&mut rx, target, deadline, |m| match m {
            MavMessage::MISSION_REQUEST_INT(r) => Some(Heard::Request(r.seq)),
            MavMessage::MISSION_REQUEST(r) => Some(Heard::Request(r.seq)),
            MavMessage::MISSION_ACK(a) => Some(Heard::Ack(a.mavtype)),
            _ => None,
        })
        .await?;
        match upload.step(heard) {
            Next::Send => port.send(upload.last()).await?,
            Next::Wait => {}
            Next::Done => return Ok(()),
            Next::ReadBack => match upload.read_back(read_back(port, timing).await?) {
                Next::Send => port.send(upload.last()).await?,
                Next::Fail(e) => return Err(e),
                _ => return Ok(()),
            },
            Next::Fail(e) => return Err(e),
        }
    }
}

/// What the autopilot said during an upload.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Heard {
    /// It asks for this item.
    Request(u16),
    /// It ends the transfer so.
    Ack(MavMissionResult),
}

/// What the uploader does next.
#[derive(Clone, Debug, PartialEq)]
pub enum Next {
    /// Send [`Upload::last`].
    Send,
    /// Keep waiting.
    Wait,
    /// The autopilot accepted the mission.
    Done,
    /// The final acknowledgement is lost: read the mission count back.
    ReadBack,
    /// The upload failed.
    Fail(MavError),
}

/// The mission upload, message by message (sans-IO): which item to send
/// for each request, when to send the last message again, and what a
/// silence or an acknowledgement means at each point.
#[derive(Clone, Debug)]
pub struct Upload<'a> {
    target: Target,
    items: &'a [MISSION_ITEM_INT_DATA],
    count: u16,
    attempts: u32,
    /// What was sent last, sent again when the autopilot is silent.
    last: MavMessage,
    /// The highest item asked for.
    highest: Option<u16>,
    silent: u32,
    /// How many times a stalled transfer starts over.
    restarts: u32,
    /// How many times it started over.
    restarted: u32,
    /// The item the first transfer stalled after, once started over.
    first_stall: Option<u16>,
    /// The final item was sent again after a silence: the autopilot may
    /// have finished already, so an error acknowledgement may only say
    /// that no transfer is in progress.
    final_again: bool,
}

impl<'a> Upload<'a> {
    /// An upload of `items` to `target`, each message sent up to
    /// `attempts` times.
    pub fn new(target: Target, items: &'a [MISSION_ITEM_INT_DATA], attempts: u32) -> Result<Self, MavError> {
        let count =
            u16::try_from(items.len()).map_err(|_| MavError::Invalid("too many mission items".into()))?;
        Ok(Upload {
            target,
            items,
            count,
            attempts,
            last: count_message(target, count),
            highest: None,
            silent: 0,
            restarts: 0,
            restarted: 0,
            first_stall: None,
            final_again: false,
        })
    }

    /// The same upload, started over with `MISSION_COUNT` up to `restarts`
    /// times when it stalls after the autopilot asked for an item, or when
    /// the read-back after a lost final acknowledgement finds the
    /// autopilot holding another count.
    #[must_use]
    pub fn restarting(self, restarts: u32) -> Self {
        Upload { restarts, ..self }
    }

    fn count_message(&self) -> MavMessage {
        count_message(self.target, self.count)
    }

    /// The first message: `MISSION_COUNT`.
    pub fn first(&self) -> MavMessage {
        self.last.clone()
    }

    /// The message to send now.
    pub fn last(&self) -> MavMessage {
        self.last.clone()
    }

    fn all_sent(&self) -> bool {
        self.highest.map(|h| h.saturating_add(1)) == Some(self.count)
    }

    /// What to do after hearing `heard`, or a silence (`None`).
    pub fn step(&mut self, heard: Option<Heard>) -> Next {
        match heard {
            None => self.silence(),
            Some(Heard::Request(seq)) => {
                let Some(item) = self.items.get(usize::from(seq)) else {
                    tracing::debug!(seq, count = self.count, "mission request past the end ignored");
                    return Next::Wait;
                };
                self.silent = 0;
                self.final_again = false;
                self.highest = self.highest.max(Some(seq));
                self.last = MavMessage::MISSION_ITEM_INT(MISSION_ITEM_INT_DATA {
                    seq,
                    target_system: self.target.system,
                    target_component: self.target.component,
                    ..*item
                });
                Next::Send
            }
            Some(Heard::Ack(MavMissionResult::MAV_MISSION_ACCEPTED))
                if self.all_sent() || self.count == 0 =>
            {
                Next::Done
            }
            Some(Heard::Ack(MavMissionResult::MAV_MISSION_ACCEPTED)) => {
                Next::Fail(MavError::NoAnswer(format!(
                    "the autopilot accepted the mission before receiving all {} items",
                    self.count
                )))
            }
            Some(Heard::Ack(_)) if self.final_again => Next::ReadBack,
            Some(Heard::Ack(refused)) => Next::Fail(mission_refused(refused)),
        }
    }

    fn silence(&mut self) -> Next {
        self.silent += 1;
        if self.silent < self.attempts {
            self.final_again = self.all_sent();
            return Next::Send;
        }
        if self.all_sent() {
            return Next::ReadBack;
        }
        match self.highest {
            Some(stalled) if self.restarted < self.restarts => {
                // The autopilot may have given up its side of the transfer
                // (it asks for nothing then): a new MISSION_COUNT starts
                // it afresh, replacing what it received so far.
                tracing::info!(
                    stalled,
                    count = self.count,
                    "mission upload stalled; starting it over"
                );
                self.start_over(stalled)
            }
            // Never asked for an item (or not since starting over): a new
            // MISSION_COUNT would only be another attempt.
            highest => Next::Fail(self.stalled(highest)),
        }
    }

    /// What to do after the read-back that follows a lost final
    /// acknowledgement: the autopilot holds `held` items (`None`: nothing
    /// read back). An autopilot that gave up before the last item arrived
    /// holds another count: the upload starts over if it still may.
    pub fn read_back(&mut self, held: Option<u16>) -> Next {
        let count = self.count;
        match held {
            Some(held) if held == count => {
                tracing::info!(count, "no final MISSION_ACK, but the autopilot holds every item");
                Next::Done
            }
            Some(held) if self.restarted < self.restarts => {
                tracing::info!(
                    held,
                    count,
                    "no final MISSION_ACK and another mission read back; starting over"
                );
                self.start_over(count.saturating_sub(1))
            }
            Some(held) => Next::Fail(MavError::NoAnswer(format!(
                "no MISSION_ACK for the mission's {count} items, and the autopilot holds {held}"
            ))),
            None => Next::Fail(MavError::NoAnswer(format!(
                "no MISSION_ACK for the mission's {count} items, and no mission count read back"
            ))),
        }
    }

    /// Starts the transfer over with `MISSION_COUNT`; it had stalled after
    /// item `stalled`.
    fn start_over(&mut self, stalled: u16) -> Next {
        self.restarted += 1;
        self.first_stall = self.first_stall.or(Some(stalled));
        self.silent = 0;
        self.highest = None;
        self.final_again = false;
        self.last = self.count_message();
        Next::Send
    }

    /// The answer to an upload that stalled after the autopilot asked for
    /// `highest` (`None`: after `MISSION_COUNT`).
    fn stalled(&self, highest: Option<u16>) -> MavError {
        let (count, attempts) = (self.count, self.silent);
        let stage = |h: Option<u16>| h.map_or("MISSION_COUNT".to_owned(), |s| format!("mission item {s}"));
        let mut why = match self.first_stall {
            None => format!("mission upload stalled after {} of {count}", stage(highest)),
            Some(first) => format!(
                "mission upload stalled after mission item {first} of {count}, and after {} when started over",
                stage(highest)
            ),
        };
        why.push_str(&format!(" ({attempts} attempts)"));
        if highest.is_some() || self.first_stall.is_some() {
            // Some autopilots store items as they arrive.
            why.push_str("; the autopilot may hold part of it: upload it again");
        }
        MavError::NoAnswer(why)
    }
}

/// The `MISSION_COUNT` that starts an upload of `count` items to `target`.
fn count_message(target: Target, count: u16) -> MavMessage {
    MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
        count,
        target_system: target.system,
        target_component: target.component,
    })
}

/// After a lost final acknowledgement: how many items the autopilot
/// holds, read back with `MISSION_REQUEST_LIST` (`None`: no answer); the
/// download is then ended with `MISSION_ACK`.
async fn read_back<P: Port>(port: &P, timing: &Timing) -> Result<Option<u16>, MavError> {
    let target = port.target()?;
    let mut rx = port.subscribe();
    for _ in 0..timing.mission_attempts {
        port.send(MavMessage::MISSION_REQUEST_LIST(MISSION_REQUEST_LIST_DATA {
            target_system: target.system,
            target_component: target.component,
        }))
        .await?;
        let deadline = Instant::now() + timing.mission_item;
        let held = next(&mut rx, target, deadline, |m| match m {
            MavMessage::MISSION_COUNT(c) => Some(c.count),
            _ => None,
        })
        .await?;
        if held.is_some() {
            port.send(MavMessage::MISSION_ACK(MISSION_ACK_DATA {
                target_system: target.system,
                target_component: target.component,
                mavtype: MavMissionResult::MAV_MISSION_ACCEPTED,
            }))
            .await?;
            return Ok(held);
        }
    }
    Ok(None)
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
