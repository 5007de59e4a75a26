//! The autopilot's side of lluavd's MAVLink link, played by the input:
//! raw datagrams (garbage included) and well-formed messages from a few
//! addresses and systems, against what lluavd knows of the autopilot
//! (`Known`), the mission upload state machine, and the command and
//! mission protocols over a scripted link. Checked: nothing panics; what
//! lluavd knows stays bounded; a packet that is not the followed
//! autopilot's changes nothing (no failsafe starts or ends for it); no
//! packet starts or moves a setpoint stream; after the autopilot's
//! heartbeat says disarmed, only the telemetry says whether the vehicle
//! flies, and no failsafe holds; the protocols send only
//! what the command a client asked for sends (never a cancel, a clear or
//! another command).
//!
//! Input, byte by byte: the first byte sets signing (bit 0) and `any`
//! (bit 1); then operations, each a byte `op % 8` followed by its own
//! bytes (see [`run`]). Missing bytes read as zeros, so every input is a
//! valid script.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use lluav_core::{Failsafe, Pose, SessionId};
use lluav_host::mavlink::MavError;
use lluav_host::mavlink::fuzzing::{
    Asked, Effect, Heard, Incoming, Known, Next, Port, Receipt, SigningKey, Target, Timing, Upload, Wanted,
    command, parse_datagram, upload_mission,
};
use mavlink::dialects::ardupilotmega::{
    MISSION_ITEM_INT_DATA, MavCmd, MavFrame, MavMessage, MavMissionResult, MavModeFlag,
};
use mavlink::{MavHeader, MavlinkVersion, Message as _};
use tokio::sync::broadcast;

/// Most entries what lluavd knows may hold: every message kind of the
/// dialect counted, two boot times, no mission (none is submitted here).
const FOOTPRINT_BOUND: usize = 400;
/// The ids the state machines read, so the input hits them often.
const INTERESTING: [u32; 19] = [
    0, 1, 2, 22, 30, 32, 33, 40, 42, 44, 46, 47, 51, 77, 147, 148, 242, 245, 253,
];
const AUTOPILOT: Target = Target {
    system: 1,
    component: 1,
};

/// The input, read from the front; missing bytes are zeros.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn more(&self) -> bool {
        !self.0.is_empty()
    }

    fn byte(&mut self) -> u8 {
        let (first, rest) = self.0.split_first().map_or((0, &[][..]), |(b, r)| (*b, r));
        self.0 = rest;
        first
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.byte(), self.byte()])
    }

    fn take(&mut self, n: usize) -> &[u8] {
        let n = n.min(self.0.len());
        let (taken, rest) = self.0.split_at(n);
        self.0 = rest;
        taken
    }

    /// Where a packet comes from: one of three addresses, or no address.
    fn source(&mut self) -> Option<SocketAddr> {
        match self.byte() % 4 {
            3 => None,
            n => Some(SocketAddr::from(([127, 0, 0, 1], 14_550 + u16::from(n)))),
        }
    }

    fn header(&mut self) -> MavHeader {
        let system = match self.byte() % 4 {
            0 | 1 => 1,
            2 => 2,
            _ => u32::from(self.byte()),
        };
        let component = if self.byte().is_multiple_of(4) {
            self.byte()
        } else {
            1
        };
        MavHeader {
            system_id: system,
            component_id: component,
            sequence: self.byte(),
        }
    }

    /// A well-formed message: mostly one the state machines read, with a
    /// payload from the input.
    fn message(&mut self) -> Option<MavMessage> {
        let pick = self.byte();
        let id = match INTERESTING.get(usize::from(pick % 32)) {
            Some(id) => *id,
            None => u32::from(self.u16()),
        };
        let len = usize::from(self.byte());
        let payload = self.take(len).to_vec();
        MavMessage::parse(MavlinkVersion::V2, id, &payload).ok()
    }

    fn pose(&mut self) -> Pose {
        let mut f = || f32::from(self.byte()) - 128.0;
        Pose {
            x: f(),
            y: f(),
            z: f(),
            yaw: 0.0,
        }
    }
}

/// What a dropped packet must leave as it was.
#[derive(Debug, PartialEq)]
struct Seen {
    peer: Option<SocketAddr>,
    target: Option<Target>,
    setpoint: Option<Pose>,
    messages: u64,
    armed: bool,
    failsafe: Option<Failsafe>,
}

fn seen(k: &Known) -> Seen {
    Seen {
        peer: k.peer(),
        target: k.target(),
        setpoint: k.setpoint(),
        messages: k.tel().total_messages(),
        armed: k.tel().armed(),
        failsafe: k.failsafe(),
    }
}

/// One packet into what lluavd knows, with the invariants checked.
fn receive(k: &mut Known, from: Option<SocketAddr>, header: &MavHeader, msg: &MavMessage, now: i64) {
    let before = seen(k);
    let receipt = k.receive(from, header, msg, now);
    let after = seen(k);
    match receipt {
        Receipt::Dropped => assert_eq!(before, after, "a dropped packet changed what lluavd knows"),
        Receipt::Kept => assert_eq!(before.peer, after.peer, "a packet moved where lluavd sends"),
        Receipt::LinkUp => assert_eq!(after.peer, from),
    }
    assert!(
        after.setpoint.is_none() || after.setpoint == before.setpoint,
        "a packet started or moved the setpoint stream"
    );
    // The autopilot's heartbeat saying disarmed: lluavd's word that a
    // takeoff is under way no longer counts, the telemetry does.
    if receipt != Receipt::Dropped && matches!(msg, MavMessage::HEARTBEAT(_)) && !k.tel().armed() {
        assert_eq!(
            k.airborne(now),
            k.tel().airborne(),
            "a takeoff still counted after a disarmed heartbeat"
        );
        assert_eq!(k.failsafe(), None, "a failsafe outlived a disarmed heartbeat");
    }
    assert!(k.footprint() <= FOOTPRINT_BOUND, "{} entries", k.footprint());
}

/// Plays `data` (see the module doc).
pub fn run(data: &[u8]) {
    let mut input = Input(data);
    let flags = input.byte();
    let key = SigningKey::from_hex(&"2a".repeat(32)).expect("a valid key");
    let (autopilot_signer, lluavd_checker) = (key.data(), key.data());
    let signed = flags & 1 == 1;
    let wanted = if flags & 2 == 2 {
        Wanted::Any
    } else {
        Wanted::System(1)
    };
    let mut k = Known::new(wanted);
    let mut now = 1_000_i64;
    while input.more() {
        match input.byte() % 8 {
            // A datagram of raw bytes: garbage, or frames.
            0 => {
                let from = input.source();
                let len = usize::from(input.u16() % 600);
                let bytes = input.take(len).to_vec();
                let checker = signed.then_some(&*lluavd_checker);
                for (header, msg) in parse_datagram(&bytes, checker) {
                    receive(&mut k, from, &header, &msg, now);
                }
            }
            // A well-formed message, through the framing (and signing).
            1 => {
                let (from, header) = (input.source(), input.header());
                let Some(msg) = input.message() else { continue };
                let sign = input.byte() % 4 != 0;
                let mut frame = Vec::new();
                let signer = sign.then_some(&*autopilot_signer);
                if mavlink::write_v2_msg_signed(&mut frame, header, &msg, signer).is_err() {
                    continue;
                }
                let checker = signed.then_some(&*lluavd_checker);
                for (header, msg) in parse_datagram(&frame, checker) {
                    receive(&mut k, from, &header, &msg, now);
                }
            }
            2 => now += i64::from(input.u16()) * 10,
            3 => k.stream(input.pose(), SessionId(u32::from(input.byte() % 4))),
            4 => k.release(SessionId(u32::from(input.byte() % 4))),
            5 => match input.byte() % 10 {
                0 => k.took_off(now),
                1 => k.disarmed(),
                2 => k.landing(),
                3 => k.ask(Asked::Takeoff, now),
                4 => k.ask(Asked::Setpoints, now),
                5 => k.ask(Asked::Mission, now),
                6 => k.ask(Asked::Land, now),
                7 => k.ask(Asked::Return, now),
                8 => k.unask(Asked::Land),
                _ => {
                    k.override_failsafe();
                }
            },
            6 => upload_steps(&mut input),
            _ => protocols(&mut input),
        }
        let _ = (k.fsm(now), k.airborne(now), k.link_up(now));
    }
}

fn items(n: u16) -> Vec<MISSION_ITEM_INT_DATA> {
    (0..n)
        .map(|i| MISSION_ITEM_INT_DATA {
            seq: i,
            frame: MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
            command: MavCmd::MAV_CMD_NAV_WAYPOINT,
            ..MISSION_ITEM_INT_DATA::DEFAULT
        })
        .collect()
}

fn mission_result(b: u8) -> MavMissionResult {
    match MavMessage::parse(MavlinkVersion::V2, 47, &[1, 1, b % 16]) {
        Ok(MavMessage::MISSION_ACK(a)) => a.mavtype,
        _ => MavMissionResult::MAV_MISSION_ACCEPTED,
    }
}

/// The upload state machine, heard answers from the input.
fn upload_steps(input: &mut Input<'_>) {
    let n = 1 + u16::from(input.byte() % 8);
    let items = items(n);
    let Ok(upload) = Upload::new(AUTOPILOT, &items, 1 + u32::from(input.byte() % 5)) else {
        return;
    };
    let mut upload = upload.restarting(u32::from(input.byte() % 3));
    check_upload_message(&upload.first(), n);
    for _ in 0..64 {
        let heard = match input.byte() % 4 {
            0 => None,
            1 => Some(Heard::Request(input.u16())),
            2 => Some(Heard::Ack(mission_result(input.byte()))),
            _ => Some(Heard::Request(u16::from(input.byte()) % (n + 2))),
        };
        match upload.step(heard) {
            Next::Send => check_upload_message(&upload.last(), n),
            Next::Wait => {}
            // The count read back, or none: the upload may start over.
            Next::ReadBack => {
                let held = input
                    .byte()
                    .is_multiple_of(2)
                    .then(|| u16::from(input.byte()) % (n + 2));
                match upload.read_back(held) {
                    Next::Send => check_upload_message(&upload.last(), n),
                    _ => return,
                }
            }
            Next::Done | Next::Fail(_) => return,
        }
    }
}

/// What an upload of `n` items may send: nothing but its count and items.
fn check_upload_message(msg: &MavMessage, n: u16) {
    match msg {
        MavMessage::MISSION_COUNT(c) => assert_eq!(c.count, n),
        MavMessage::MISSION_ITEM_INT(i) => assert!(i.seq < n, "item {} of {n}", i.seq),
        other => panic!("an upload sent {other:?}"),
    }
}

/// A link whose autopilot answers each message lluavd sends with the
/// next messages of a script.
struct Scripted {
    sent: Mutex<Vec<MavMessage>>,
    feed: broadcast::Sender<Arc<Incoming>>,
    script: Mutex<Vec<(MavHeader, MavMessage)>>,
    per_send: usize,
}

impl Port for Scripted {
    async fn send(&self, msg: MavMessage) -> Result<(), MavError> {
        self.sent.lock().expect("not poisoned").push(msg);
        let answers: Vec<_> = {
            let mut script = self.script.lock().expect("not poisoned");
            let n = self.per_send.min(script.len());
            script.drain(..n).collect()
        };
        for (header, msg) in answers {
            let _ = self.feed.send(Arc::new(Incoming { header, msg }));
        }
        Ok(())
    }

    fn subscribe(&self) -> broadcast::Receiver<Arc<Incoming>> {
        self.feed.subscribe()
    }

    fn target(&self) -> Result<Target, MavError> {
        Ok(AUTOPILOT)
    }
}

/// The command or the mission protocol against a scripted autopilot, on
/// a paused clock (timeouts pass at once).
fn protocols(input: &mut Input<'_>) {
    let mission = input.byte().is_multiple_of(2);
    let per_send = usize::from(input.byte() % 4);
    let mut script = Vec::new();
    for _ in 0..input.byte() % 16 {
        let header = match input.byte() % 4 {
            0 => input.header(),
            _ => MavHeader {
                system_id: 1,
                component_id: 1,
                sequence: 0,
            },
        };
        if let Some(msg) = input.message() {
            script.push((header, msg));
        }
    }
    let confirmable = could_confirm_arming(&script);
    let port = Scripted {
        sent: Mutex::new(Vec::new()),
        feed: broadcast::channel(64).0,
        script: Mutex::new(script),
        per_send,
    };
    let timing = Timing {
        ack: Duration::from_millis(50),
        in_progress: Duration::from_millis(500),
        mission_item: Duration::from_millis(50),
        param: Duration::from_millis(50),
        ..Timing::default()
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .start_paused(true)
        .build()
        .expect("a runtime");
    let sent = if mission {
        let n = 1 + u16::from(input.byte() % 6);
        let _ = runtime.block_on(upload_mission(&port, &timing, &items(n)));
        let sent = port.sent.into_inner().expect("not poisoned");
        check_mission_sends(&sent, n);
        sent
    } else {
        let arm = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let effect = Some(Effect::Armed(true));
        let result = runtime.block_on(command(
            &port,
            &timing,
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            arm,
            effect,
        ));
        assert!(
            result.is_err() || confirmable,
            "arming answered 0 with nothing from the autopilot saying so"
        );
        let sent = port.sent.into_inner().expect("not poisoned");
        for msg in &sent {
            match msg {
                MavMessage::COMMAND_LONG(c) => {
                    assert_eq!((c.command, c.param1), (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1.0));
                }
                other => panic!("arming sent {other:?}"),
            }
        }
        sent
    };
    assert!(sent.len() <= 64, "{} messages sent", sent.len());
}

/// What uploading `n` items may send: the count, the items, and to read
/// the count back after a lost final acknowledgement, the request and the
/// accepting acknowledgement that ends it. Never a cancel or a clear.
fn check_mission_sends(sent: &[MavMessage], n: u16) {
    for msg in sent {
        match msg {
            MavMessage::MISSION_COUNT(_) | MavMessage::MISSION_ITEM_INT(_) => check_upload_message(msg, n),
            MavMessage::MISSION_REQUEST_LIST(_) => {}
            MavMessage::MISSION_ACK(a) => assert_eq!(a.mavtype, MavMissionResult::MAV_MISSION_ACCEPTED),
            other => panic!("a mission upload sent {other:?}"),
        }
    }
}

/// Whether `script` holds what may make arming answer 0: the autopilot's
/// own acceptance, or its heartbeat armed.
fn could_confirm_arming(script: &[(MavHeader, MavMessage)]) -> bool {
    script.iter().any(|(h, m)| {
        (h.system_id, h.component_id) == (1, 1)
            && match m {
                MavMessage::COMMAND_ACK(a) => a.command == MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
                MavMessage::HEARTBEAT(hb) => hb.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
                _ => false,
            }
    })
}
