//! The protocols against a fake autopilot whose answers a test scripts;
//! tokio's clock is paused, so timeouts pass instantly and exactly.

use std::sync::Mutex;

use ::mavlink::dialects::ardupilotmega::{
    COMMAND_ACK_DATA, MISSION_REQUEST_INT_DATA, MavFrame, PARAM_ERROR_DATA,
};

use super::*;
use crate::vehicle::Refusal;

const AUTOPILOT: Target = Target {
    system: 1,
    component: 1,
};

type Script = Box<dyn FnMut(&MavMessage, usize) -> Vec<MavMessage> + Send>;

/// A link to a scripted autopilot: each sent message is recorded and the
/// script's answers (given the message and how many were sent before it)
/// arrive from the autopilot's address.
struct Fake {
    sent: Mutex<Vec<MavMessage>>,
    feed: broadcast::Sender<Arc<Incoming>>,
    script: Mutex<Script>,
}

impl Fake {
    fn new(script: impl FnMut(&MavMessage, usize) -> Vec<MavMessage> + Send + 'static) -> Arc<Fake> {
        Arc::new(Fake {
            sent: Mutex::new(Vec::new()),
            feed: broadcast::channel(64).0,
            script: Mutex::new(Box::new(script)),
        })
    }

    fn autopilot_says(&self, msg: MavMessage) {
        let header = MavHeader {
            system_id: AUTOPILOT.system.into(),
            component_id: AUTOPILOT.component,
            sequence: 0,
        };
        let _ = self.feed.send(Arc::new(Incoming { header, msg }));
    }

    fn sent(&self) -> Vec<MavMessage> {
        self.sent.lock().unwrap().clone()
    }
}

impl Port for Arc<Fake> {
    async fn send(&self, msg: MavMessage) -> Result<(), MavError> {
        let n = {
            let mut sent = self.sent.lock().unwrap();
            sent.push(msg.clone());
            sent.len() - 1
        };
        let answers = (self.script.lock().unwrap())(&msg, n);
        for a in answers {
            self.autopilot_says(a);
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

fn ack(command: MavCmd, result: MavResult) -> MavMessage {
    MavMessage::COMMAND_ACK(COMMAND_ACK_DATA { command, result })
}

fn confirmations(sent: &[MavMessage]) -> Vec<u8> {
    sent.iter()
        .filter_map(|m| match m {
            MavMessage::COMMAND_LONG(c) => Some(c.confirmation),
            _ => None,
        })
        .collect()
}

const ARM: MavCmd = MavCmd::MAV_CMD_COMPONENT_ARM_DISARM;

#[tokio::test(start_paused = true)]
async fn an_acknowledged_command_is_sent_once_to_the_autopilot() {
    let port = Fake::new(|_, _| vec![ack(ARM, MavResult::MAV_RESULT_ACCEPTED)]);
    command(
        &port,
        &Timing::default(),
        ARM,
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        None,
    )
    .await
    .unwrap();
    let sent = port.sent();
    assert_eq!(confirmations(&sent), [0]);
    let MavMessage::COMMAND_LONG(c) = &sent[0] else {
        panic!("{sent:?}")
    };
    assert_eq!((c.target_system, c.target_component, c.param1), (1, 1, 1.0));
}

#[tokio::test(start_paused = true)]
async fn an_unanswered_command_is_resent_with_the_confirmation_counting_up() {
    let port = Fake::new(|_, n| {
        if n == 2 {
            vec![ack(ARM, MavResult::MAV_RESULT_ACCEPTED)]
        } else {
            vec![]
        }
    });
    let started = Instant::now();
    command(&port, &Timing::default(), ARM, [0.0; 7], None)
        .await
        .unwrap();
    assert_eq!(confirmations(&port.sent()), [0, 1, 2]);
    assert_eq!(started.elapsed(), Timing::default().ack * 2);
}

#[tokio::test(start_paused = true)]
async fn a_silent_autopilot_is_no_answer_after_every_attempt() {
    let port = Fake::new(|_, _| vec![]);
    let err = command(&port, &Timing::default(), ARM, [0.0; 7], None)
        .await
        .unwrap_err();
    assert_eq!(
        err,
        MavError::NoAnswer("no COMMAND_ACK for MAV_CMD_COMPONENT_ARM_DISARM after 3 attempts".into())
    );
    assert_eq!(err.ret().code(), -3);
    assert_eq!(confirmations(&port.sent()), [0, 1, 2]);
}

#[tokio::test(start_paused = true)]
async fn a_refusal_names_the_mav_result_and_is_not_retried() {
    let port = Fake::new(|_, _| vec![ack(ARM, MavResult::MAV_RESULT_TEMPORARILY_REJECTED)]);
    let err = command(&port, &Timing::default(), ARM, [0.0; 7], None)
        .await
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "MAV_CMD_COMPONENT_ARM_DISARM refused by the autopilot: MAV_RESULT_TEMPORARILY_REJECTED"
    );
    assert_eq!(err.ret().code(), -1);
    assert_eq!(port.sent().len(), 1);
}

#[tokio::test(start_paused = true)]
async fn acks_for_other_commands_or_from_other_systems_are_not_taken() {
    let port = Fake::new(|_, _| vec![ack(MavCmd::MAV_CMD_NAV_LAND, MavResult::MAV_RESULT_ACCEPTED)]);
    let stranger = port.feed.clone();
    let p = Arc::clone(&port);
    let task = tokio::spawn(async move { command(&p, &Timing::default(), ARM, [0.0; 7], None).await });
    tokio::time::sleep(Duration::from_millis(100)).await;
    let header = MavHeader {
        system_id: 2,
        component_id: 1,
        sequence: 0,
    };
    let msg = ack(ARM, MavResult::MAV_RESULT_ACCEPTED);
    let _ = stranger.send(Arc::new(Incoming { header, msg }));
    assert!(matches!(task.await.unwrap(), Err(MavError::NoAnswer(_))));
}

#[tokio::test(start_paused = true)]
async fn in_progress_stops_the_resending_and_waits_for_the_final_answer() {
    let port = Fake::new(|_, _| vec![ack(ARM, MavResult::MAV_RESULT_IN_PROGRESS)]);
    let p = Arc::clone(&port);
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_secs(10)).await;
        p.autopilot_says(ack(ARM, MavResult::MAV_RESULT_ACCEPTED));
    });
    command(&port, &Timing::default(), ARM, [0.0; 7], None)
        .await
        .unwrap();
    assert_eq!(confirmations(&port.sent()), [0]);
}

fn waypoints(n: u16) -> Vec<MISSION_ITEM_INT_DATA> {
    (0..n)
        .map(|i| {
            mission_item(
                MavCmd::MAV_CMD_NAV_WAYPOINT,
                MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                [0.0; 4],
                (i32::from(i), 0, 5.0),
            )
        })
        .collect()
}

fn request(seq: u16) -> MavMessage {
    MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
        seq,
        target_system: 255,
        target_component: 0,
    })
}

fn mission_ack(result: MavMissionResult) -> MavMessage {
    MavMessage::MISSION_ACK(MISSION_ACK_DATA {
        target_system: 255,
        target_component: 0,
        mavtype: result,
    })
}

/// An autopilot that requests every item in turn and accepts at the end;
/// `drop` names a sent-message index it ignores (a lost message).
fn obedient(count: u16, drop: Option<usize>) -> impl FnMut(&MavMessage, usize) -> Vec<MavMessage> + Send {
    move |m, n| {
        if Some(n) == drop {
            return vec![];
        }
        match m {
            MavMessage::MISSION_COUNT(_) => vec![request(0)],
            MavMessage::MISSION_ITEM_INT(i) if i.seq + 1 < count => vec![request(i.seq + 1)],
            MavMessage::MISSION_ITEM_INT(_) => vec![mission_ack(MavMissionResult::MAV_MISSION_ACCEPTED)],
            _ => vec![],
        }
    }
}

fn item_seqs(sent: &[MavMessage]) -> Vec<u16> {
    sent.iter()
        .filter_map(|m| match m {
            MavMessage::MISSION_ITEM_INT(i) => Some(i.seq),
            _ => None,
        })
        .collect()
}

#[tokio::test(start_paused = true)]
async fn a_mission_is_uploaded_item_by_item_as_requested() {
    let port = Fake::new(obedient(3, None));
    upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap();
    let sent = port.sent();
    assert!(matches!(&sent[0], MavMessage::MISSION_COUNT(c) if c.count == 3 && c.target_system == 1));
    assert_eq!(item_seqs(&sent), [0, 1, 2]);
    let MavMessage::MISSION_ITEM_INT(second) = &sent[2] else {
        panic!()
    };
    assert_eq!(
        (second.x, second.target_system, second.target_component),
        (1, 1, 1)
    );
}

#[tokio::test(start_paused = true)]
async fn a_lost_mission_item_is_sent_again() {
    // The autopilot never sees the second item (sent message 2).
    let port = Fake::new(obedient(3, Some(2)));
    upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap();
    assert_eq!(item_seqs(&port.sent()), [0, 1, 1, 2]);
}

#[tokio::test(start_paused = true)]
async fn an_item_the_autopilot_asks_for_twice_is_sent_twice() {
    let mut asked_again = false;
    let port = Fake::new(move |m, _| match m {
        MavMessage::MISSION_COUNT(_) => vec![request(0)],
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 && !asked_again => {
            asked_again = true;
            vec![request(0)]
        }
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 => vec![request(1)],
        MavMessage::MISSION_ITEM_INT(_) => vec![mission_ack(MavMissionResult::MAV_MISSION_ACCEPTED)],
        _ => vec![],
    });
    upload_mission(&port, &Timing::default(), &waypoints(2))
        .await
        .unwrap();
    assert_eq!(item_seqs(&port.sent()), [0, 0, 1]);
}

#[tokio::test(start_paused = true)]
async fn a_link_that_dies_mid_upload_is_no_answer_and_nothing_is_cancelled() {
    let port = Fake::new(|m, _| match m {
        MavMessage::MISSION_COUNT(_) => vec![request(0)],
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 => vec![request(1)],
        _ => vec![],
    });
    let started = Instant::now();
    let err = upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap_err();
    assert_eq!(
        err,
        MavError::NoAnswer(
            "mission upload stalled after mission item 1 of 3, and after mission item 1 when started over \
             (5 attempts); the autopilot may hold part of it: upload it again"
                .into()
        )
    );
    assert_eq!(err.ret().code(), -3);
    // Started over once, each start bounded by its attempts.
    let sent = port.sent();
    assert_eq!(item_seqs(&sent), [0, 1, 1, 1, 1, 1, 0, 1, 1, 1, 1, 1]);
    assert_eq!(
        sent_kinds(&sent)
            .iter()
            .filter(|k| **k == "MISSION_COUNT")
            .count(),
        2
    );
    let timing = Timing::default();
    assert_eq!(
        started.elapsed(),
        timing.mission_item * timing.mission_attempts * 2
    );
    let refusals = sent
        .iter()
        .filter(|m| matches!(m, MavMessage::MISSION_ACK(_)))
        .count();
    assert_eq!(refusals, 0, "nothing cancelled: {sent:?}");
}

/// An autopilot like MAVSDK's: it gives up its side of a transfer when an
/// item does not come, and then answers only a new `MISSION_COUNT`; the
/// first transfer never sees item `lost`.
fn gives_up_once(count: u16, lost: u16) -> impl FnMut(&MavMessage, usize) -> Vec<MavMessage> + Send {
    let mut starts = 0;
    move |m, _| match m {
        MavMessage::MISSION_COUNT(_) => {
            starts += 1;
            vec![request(0)]
        }
        MavMessage::MISSION_ITEM_INT(i) if starts == 1 && i.seq >= lost => vec![],
        MavMessage::MISSION_ITEM_INT(i) if i.seq + 1 < count => vec![request(i.seq + 1)],
        MavMessage::MISSION_ITEM_INT(_) => vec![mission_ack(MavMissionResult::MAV_MISSION_ACCEPTED)],
        _ => vec![],
    }
}

#[tokio::test(start_paused = true)]
async fn an_upload_the_autopilot_gave_up_starts_over_with_mission_count() {
    let port = Fake::new(gives_up_once(4, 2));
    upload_mission(&port, &Timing::default(), &waypoints(4))
        .await
        .unwrap();
    let sent = port.sent();
    assert_eq!(item_seqs(&sent), [0, 1, 2, 2, 2, 2, 2, 0, 1, 2, 3]);
    let kinds = sent_kinds(&sent);
    assert_eq!(kinds.iter().filter(|k| **k == "MISSION_COUNT").count(), 2);
    assert_eq!(kinds[8], "MISSION_COUNT", "{kinds:?}");
    assert!(
        matches!(&sent[8], MavMessage::MISSION_COUNT(c) if c.count == 4 && c.target_system == 1),
        "{sent:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn without_restarts_a_stalled_upload_is_no_answer_at_once() {
    let port = Fake::new(gives_up_once(4, 2));
    let timing = Timing {
        mission_restarts: 0,
        ..Timing::default()
    };
    let err = upload_mission(&port, &timing, &waypoints(4)).await.unwrap_err();
    assert_eq!(err.ret().code(), -3);
    assert_eq!(
        err.to_string(),
        "No answer from the autopilot: mission upload stalled after mission item 2 of 4 (5 attempts); \
         the autopilot may hold part of it: upload it again"
    );
    assert_eq!(item_seqs(&port.sent()), [0, 1, 2, 2, 2, 2, 2]);
}

#[tokio::test(start_paused = true)]
async fn an_autopilot_silent_after_starting_over_is_no_answer_naming_both_stalls() {
    let mut counts = 0;
    let port = Fake::new(move |m, _| match m {
        MavMessage::MISSION_COUNT(_) if counts == 0 => {
            counts += 1;
            vec![request(0)]
        }
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 => vec![request(1)],
        _ => vec![],
    });
    let err = upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "No answer from the autopilot: mission upload stalled after mission item 1 of 3, and after \
         MISSION_COUNT when started over (5 attempts); the autopilot may hold part of it: upload it again"
    );
}

#[tokio::test(start_paused = true)]
async fn an_autopilot_that_never_asks_is_not_sent_the_count_again_and_again() {
    let port = Fake::new(|_, _| vec![]);
    let started = Instant::now();
    let err = upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap_err();
    assert_eq!(
        err,
        MavError::NoAnswer("mission upload stalled after MISSION_COUNT of 3 (5 attempts)".into())
    );
    assert_eq!(sent_kinds(&port.sent()), ["MISSION_COUNT"; 5]);
    let timing = Timing::default();
    assert_eq!(started.elapsed(), timing.mission_item * timing.mission_attempts);
}

#[test]
fn a_restart_forgets_the_items_asked_for() {
    let items = waypoints(3);
    let mut upload = Upload::new(AUTOPILOT, &items, 2).unwrap().restarting(1);
    assert_eq!(upload.step(Some(Heard::Request(0))), Next::Send);
    assert_eq!(upload.step(Some(Heard::Request(1))), Next::Send);
    assert_eq!(upload.step(None), Next::Send);
    assert!(matches!(upload.last(), MavMessage::MISSION_ITEM_INT(i) if i.seq == 1));
    assert_eq!(upload.step(None), Next::Send);
    assert!(matches!(upload.last(), MavMessage::MISSION_COUNT(c) if c.count == 3));
    // An acceptance before the new transfer's items is not believed.
    assert!(matches!(
        upload.step(Some(Heard::Ack(MavMissionResult::MAV_MISSION_ACCEPTED))),
        Next::Fail(_)
    ));
}

#[test]
fn a_stall_on_the_last_item_is_read_back_not_restarted() {
    let items = waypoints(2);
    let mut upload = Upload::new(AUTOPILOT, &items, 2).unwrap().restarting(1);
    assert_eq!(upload.step(Some(Heard::Request(0))), Next::Send);
    assert_eq!(upload.step(Some(Heard::Request(1))), Next::Send);
    assert_eq!(upload.step(None), Next::Send);
    assert_eq!(upload.step(None), Next::ReadBack);
}

fn count(n: u16) -> MavMessage {
    MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
        count: n,
        target_system: 255,
        target_component: 0,
    })
}

/// An autopilot that takes every item but whose final MISSION_ACK is
/// lost, answering a read-back with `holds` items.
fn final_ack_lost(items: u16, holds: u16) -> impl FnMut(&MavMessage, usize) -> Vec<MavMessage> + Send {
    move |m, _| match m {
        MavMessage::MISSION_COUNT(_) => vec![request(0)],
        MavMessage::MISSION_ITEM_INT(i) if i.seq + 1 < items => vec![request(i.seq + 1)],
        MavMessage::MISSION_REQUEST_LIST(_) => vec![count(holds)],
        _ => vec![],
    }
}

fn sent_kinds(sent: &[MavMessage]) -> Vec<&'static str> {
    use ::mavlink::Message as _;
    sent.iter().map(|m| m.message_name()).collect()
}

#[tokio::test(start_paused = true)]
async fn a_lost_final_ack_is_read_back_and_the_mission_kept() {
    let port = Fake::new(final_ack_lost(3, 3));
    upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap();
    let sent = port.sent();
    assert_eq!(item_seqs(&sent), [0, 1, 2, 2, 2, 2, 2]);
    let kinds = sent_kinds(&sent);
    assert_eq!(kinds[kinds.len() - 2..], ["MISSION_REQUEST_LIST", "MISSION_ACK"]);
    assert!(
        matches!(sent.last(), Some(MavMessage::MISSION_ACK(a)) if a.mavtype == MavMissionResult::MAV_MISSION_ACCEPTED)
    );
}

#[tokio::test(start_paused = true)]
async fn a_lost_final_ack_with_another_mission_read_back_is_no_answer() {
    let port = Fake::new(final_ack_lost(3, 0));
    let err = upload_mission(&port, &Timing::default(), &waypoints(3))
        .await
        .unwrap_err();
    assert_eq!(
        err,
        MavError::NoAnswer("no MISSION_ACK for the mission's 3 items, and the autopilot holds 0".into())
    );
    assert_eq!(err.ret().code(), -3);
    let refusals = port
        .sent()
        .iter()
        .filter(|m| matches!(m, MavMessage::MISSION_ACK(a) if a.mavtype != MavMissionResult::MAV_MISSION_ACCEPTED))
        .count();
    assert_eq!(refusals, 0, "nothing cancelled");
}

#[tokio::test(start_paused = true)]
async fn a_read_back_of_another_count_after_the_last_item_starts_over() {
    // The first transfer never sees its last item and gives up, keeping
    // the 7 items it held before; the second one completes.
    let mut starts = 0;
    let port = Fake::new(move |m, _| match m {
        MavMessage::MISSION_COUNT(_) => {
            starts += 1;
            vec![request(0)]
        }
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 => vec![request(1)],
        MavMessage::MISSION_ITEM_INT(_) if starts == 1 => vec![],
        MavMessage::MISSION_ITEM_INT(_) => vec![mission_ack(MavMissionResult::MAV_MISSION_ACCEPTED)],
        MavMessage::MISSION_REQUEST_LIST(_) => vec![count(7)],
        _ => vec![],
    });
    upload_mission(&port, &Timing::default(), &waypoints(2))
        .await
        .unwrap();
    let sent = port.sent();
    let kinds = sent_kinds(&sent);
    assert_eq!(
        kinds[7..],
        [
            "MISSION_REQUEST_LIST",
            "MISSION_ACK",
            "MISSION_COUNT",
            "MISSION_ITEM_INT",
            "MISSION_ITEM_INT"
        ],
        "{kinds:?}"
    );
    assert_eq!(item_seqs(&sent), [0, 1, 1, 1, 1, 1, 0, 1]);
}

#[tokio::test(start_paused = true)]
async fn an_error_ack_to_a_final_item_sent_again_is_read_back_not_believed() {
    // The autopilot finished (its ACK was lost) and answers the repeated
    // last item with "no transfer in progress".
    let mut done = false;
    let port = Fake::new(move |m, _| match m {
        MavMessage::MISSION_COUNT(_) => vec![request(0)],
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 => vec![request(1)],
        MavMessage::MISSION_ITEM_INT(_) if !done => {
            done = true;
            vec![]
        }
        MavMessage::MISSION_ITEM_INT(_) => vec![mission_ack(MavMissionResult::MAV_MISSION_INVALID_SEQUENCE)],
        MavMessage::MISSION_REQUEST_LIST(_) => vec![count(2)],
        _ => vec![],
    });
    upload_mission(&port, &Timing::default(), &waypoints(2))
        .await
        .unwrap();
}

#[tokio::test(start_paused = true)]
async fn a_request_past_the_end_is_ignored() {
    let port = Fake::new(|m, _| match m {
        MavMessage::MISSION_COUNT(_) => vec![request(0), request(9)],
        MavMessage::MISSION_ITEM_INT(i) if i.seq == 0 => vec![request(7), request(1)],
        MavMessage::MISSION_ITEM_INT(_) => vec![mission_ack(MavMissionResult::MAV_MISSION_ACCEPTED)],
        _ => vec![],
    });
    upload_mission(&port, &Timing::default(), &waypoints(2))
        .await
        .unwrap();
    assert_eq!(item_seqs(&port.sent()), [0, 1]);
}

fn heartbeat(armed: bool) -> MavMessage {
    use ::mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavModeFlag};
    let base_mode = if armed {
        MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED
    } else {
        MavModeFlag::empty()
    };
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        base_mode,
        ..HEARTBEAT_DATA::DEFAULT
    })
}

#[tokio::test(start_paused = true)]
async fn a_lost_ack_is_answered_by_the_telemetry_that_shows_the_command_happened() {
    // The ACK never comes; after the second send the heartbeats say armed.
    let port = Fake::new(|_, n| {
        if n == 1 {
            vec![heartbeat(false), heartbeat(true)]
        } else {
            vec![]
        }
    });
    let started = Instant::now();
    command(
        &port,
        &Timing::default(),
        ARM,
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        Some(Effect::Armed(true)),
    )
    .await
    .unwrap();
    // The acknowledgement is still waited for, as long as it may come.
    assert_eq!(confirmations(&port.sent()), [0, 1, 2]);
    assert_eq!(started.elapsed(), Timing::default().ack * 3);
}

#[tokio::test(start_paused = true)]
async fn a_lost_ack_counts_an_effect_that_is_over_before_the_wait_is() {
    // Armed, then disarmed again before the attempts ran out: it happened.
    let port = Fake::new(|_, n| match n {
        0 => vec![heartbeat(true)],
        1 => vec![heartbeat(false)],
        _ => vec![],
    });
    let arm = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    command(&port, &Timing::default(), ARM, arm, Some(Effect::Armed(true)))
        .await
        .unwrap();
}

#[tokio::test(start_paused = true)]
async fn a_lost_ack_the_telemetry_does_not_confirm_is_no_answer() {
    let port = Fake::new(|_, _| vec![heartbeat(false)]);
    let err = command(
        &port,
        &Timing::default(),
        ARM,
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        Some(Effect::Armed(true)),
    )
    .await
    .unwrap_err();
    assert_eq!(err.ret().code(), -3);
    assert_eq!(confirmations(&port.sent()), [0, 1, 2]);
}

#[tokio::test(start_paused = true)]
async fn a_mission_the_autopilot_cannot_hold_is_invalid_arguments() {
    let port = Fake::new(|_, _| vec![mission_ack(MavMissionResult::MAV_MISSION_NO_SPACE)]);
    let err = upload_mission(&port, &Timing::default(), &waypoints(2))
        .await
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "Invalid arguments: the autopilot refused the mission: MAV_MISSION_NO_SPACE"
    );
    assert_eq!(err.ret().code(), -2);
}

fn value(name: &str, v: f32) -> MavMessage {
    MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
        param_value: v,
        param_count: 1,
        param_index: 0,
        param_id: name.into(),
        param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
    })
}

#[tokio::test(start_paused = true)]
async fn a_parameter_is_read_by_name_and_other_names_are_ignored() {
    let port = Fake::new(|_, n| {
        if n == 0 {
            vec![value("OTHER", 1.0)]
        } else {
            vec![value("MPC_XY_VEL_MAX", 12.0)]
        }
    });
    let v = read_param(&port, &Timing::default(), "MPC_XY_VEL_MAX")
        .await
        .unwrap();
    assert_eq!(v.param_value, 12.0);
    assert_eq!(port.sent().len(), 2);
}

#[tokio::test(start_paused = true)]
async fn an_unknown_parameter_is_invalid_arguments_when_the_autopilot_says_so() {
    let port = Fake::new(|_, _| {
        vec![MavMessage::PARAM_ERROR(PARAM_ERROR_DATA {
            param_index: -1,
            target_system: 255,
            target_component: 0,
            param_id: "NOPE".into(),
            error: MavParamError::MAV_PARAM_ERROR_DOES_NOT_EXIST,
        })]
    });
    let err = read_param(&port, &Timing::default(), "NOPE").await.unwrap_err();
    assert_eq!(err.to_string(), "Invalid arguments: unknown parameter NOPE");
}

fn indexed(name: &str, index: u16, count: u16) -> MavMessage {
    MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
        param_value: f32::from(index),
        param_count: count,
        param_index: index,
        param_id: name.into(),
        param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
    })
}

#[tokio::test(start_paused = true)]
async fn every_parameter_is_read_and_lost_ones_are_asked_for_by_index() {
    let port = Fake::new(|m, _| match m {
        // Parameter B is lost on the way.
        MavMessage::PARAM_REQUEST_LIST(_) => vec![indexed("A", 0, 3), indexed("C", 2, 3)],
        MavMessage::PARAM_REQUEST_READ(r) if r.param_index == 1 => vec![indexed("B", 1, 3)],
        _ => vec![],
    });
    let all = read_all_params(&port, &Timing::default()).await.unwrap();
    let names: Vec<_> = all
        .iter()
        .map(|v| v.param_id.to_str().unwrap().to_owned())
        .collect();
    assert_eq!(names, ["A", "B", "C"]);
}

#[tokio::test(start_paused = true)]
async fn parameters_that_never_arrive_are_no_answer() {
    let port = Fake::new(|m, _| match m {
        MavMessage::PARAM_REQUEST_LIST(_) => vec![indexed("A", 0, 2)],
        _ => vec![],
    });
    let err = read_all_params(&port, &Timing::default()).await.unwrap_err();
    assert_eq!(err, MavError::NoAnswer("1 of 2 parameters arrived".into()));
}
