//! What packets, a takeoff and a new autopilot do to what lluavd knows.

use ::mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, EXTENDED_SYS_STATE_DATA, HEARTBEAT_DATA, HOME_POSITION_DATA, MavAutopilot, MavLandedState,
    MavModeFlag, MavState, MavType, MavVtolState,
};
use lluav_core::{Pose, SessionId};

use super::*;
use crate::mavlink::authority::Asked;
use crate::mavlink::mission::{Mission, OnAutopilot, Waypoint};
use crate::vehicle::Ned;

fn addr(port: u16) -> Option<SocketAddr> {
    Some(SocketAddr::from(([127, 0, 0, 1], port)))
}

fn header(system: u32) -> MavHeader {
    MavHeader {
        system_id: system,
        component_id: 1,
        sequence: 0,
    }
}

fn heartbeat(armed: bool) -> MavMessage {
    let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
    if armed {
        base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode,
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

fn landed(state: MavLandedState) -> MavMessage {
    MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
        vtol_state: MavVtolState::MAV_VTOL_STATE_MC,
        landed_state: state,
    })
}

fn home(latitude: i32) -> MavMessage {
    MavMessage::HOME_POSITION(HOME_POSITION_DATA {
        latitude,
        ..HOME_POSITION_DATA::DEFAULT
    })
}

fn attitude(time_boot_ms: u32) -> MavMessage {
    MavMessage::ATTITUDE(ATTITUDE_DATA {
        time_boot_ms,
        ..ATTITUDE_DATA::DEFAULT
    })
}

const POSE: Pose = Pose {
    x: 1.0,
    y: 2.0,
    z: -3.0,
    yaw: 0.0,
};

/// Following system 1 at port 1, armed and in the air, a setpoint
/// streamed, mission 7 on the autopilot.
fn flying() -> Known {
    let mut k = Known::new(Wanted::System(1));
    assert_eq!(
        k.receive(addr(1), &header(1), &heartbeat(true), 0),
        Receipt::LinkUp
    );
    k.receive(
        addr(1),
        &header(1),
        &landed(MavLandedState::MAV_LANDED_STATE_IN_AIR),
        0,
    );
    k.receive(addr(1), &header(1), &home(473_977_420), 0);
    k.receive(addr(1), &header(1), &attitude(60_000), 0);
    k.stream(POSE, SessionId(1));
    let mission = Mission {
        ext_id: 7,
        waypoints: vec![Waypoint {
            id: 1,
            ned: Ned::new(1.0, 0.0, -3.0),
            yaw: None,
        }],
    };
    k.missions_mut().uploaded(mission, 0);
    k
}

#[test]
fn a_foreign_packet_changes_nothing_whatever_it_claims() {
    let mut k = flying();
    for (from, system) in [(addr(2), 1), (addr(1), 2), (None, 1)] {
        assert_eq!(
            k.receive(from, &header(system), &heartbeat(false), 10),
            Receipt::Dropped
        );
        assert_eq!(k.receive(from, &header(system), &home(1), 10), Receipt::Dropped);
        assert_eq!(
            k.receive(from, &header(system), &attitude(1), 10),
            Receipt::Dropped
        );
    }
    assert!(k.tel().armed());
    assert_eq!(k.tel().home_global().map(|h| h.e7().0), Some(473_977_420));
    assert_eq!((k.peer(), k.setpoint()), (addr(1), Some(POSE)));
    assert!(k.missions().on_autopilot().is_some());
    assert_eq!(k.take_foreign(), 9);
    assert_eq!(k.tel().total_messages(), 4);
}

#[test]
fn the_same_autopilot_back_after_a_loss_is_the_same_vehicle() {
    let mut k = flying();
    assert!(!k.link_up(5000));
    assert_eq!(
        k.receive(addr(1), &header(1), &heartbeat(true), 5000),
        Receipt::LinkUp
    );
    k.receive(addr(1), &header(1), &attitude(65_000), 5000);
    assert_eq!(k.setpoint(), Some(POSE));
    assert!(k.missions().on_autopilot().is_some());
    assert_eq!(k.tel().home_global().map(|h| h.e7().0), Some(473_977_420));
}

#[test]
fn another_autopilot_is_a_new_vehicle_and_nothing_of_the_old_one_holds() {
    for (from, system) in [(addr(2), 1), (addr(1), 2)] {
        let mut k = Known::new(Wanted::Any);
        k.receive(addr(1), &header(1), &heartbeat(true), 0);
        k.stream(POSE, SessionId(1));
        k.took_off(0);
        assert_eq!(
            k.receive(from, &header(system), &heartbeat(false), 3001),
            Receipt::LinkUp
        );
        assert_eq!((k.setpoint(), k.peer()), (None, from));
        assert_eq!((k.fsm(3001), k.tel().home_global()), ("disarmed", None));
    }
}

#[test]
fn a_rebooted_autopilot_behind_the_same_address_is_a_new_vehicle() {
    let mut k = flying();
    assert_eq!(k.receive(addr(1), &header(1), &attitude(500), 100), Receipt::Kept);
    assert_eq!(k.setpoint(), None);
    assert_eq!(k.missions().on_autopilot(), None::<&OnAutopilot>);
    assert_eq!(k.tel().home_global(), None);
    assert!(k.link_up(100), "still the followed autopilot");
}

#[test]
fn after_takeoff_answered_the_vehicle_counts_as_flying_until_the_telemetry_takes_over() {
    let mut k = Known::new(Wanted::System(1));
    k.receive(addr(1), &header(1), &heartbeat(true), 0);
    k.receive(
        addr(1),
        &header(1),
        &landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND),
        0,
    );
    assert_eq!((k.fsm(0), k.airborne(0)), ("armed", false));
    k.took_off(1000);
    assert_eq!((k.fsm(1000), k.airborne(1000)), ("takeoff", true));
    // A ground report that was on its way changes nothing.
    k.receive(
        addr(1),
        &header(1),
        &landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND),
        1100,
    );
    assert_eq!(k.fsm(1100), "takeoff");
    k.receive(
        addr(1),
        &header(1),
        &landed(MavLandedState::MAV_LANDED_STATE_IN_AIR),
        2000,
    );
    assert_eq!(k.fsm(2000), "hover");
    k.receive(
        addr(1),
        &header(1),
        &landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND),
        9000,
    );
    assert_eq!(
        (k.fsm(9000), k.airborne(9000)),
        ("armed", false),
        "telemetry rules again"
    );
}

#[test]
fn a_takeoff_the_telemetry_never_shows_stops_counting_and_a_disarm_ends_it() {
    let mut k = Known::new(Wanted::System(1));
    k.receive(addr(1), &header(1), &heartbeat(true), 0);
    k.took_off(0);
    assert!(k.airborne(TAKEOFF_GRACE_MS - 1));
    assert!(!k.airborne(TAKEOFF_GRACE_MS));
    k.took_off(0);
    k.stream(POSE, SessionId(3));
    k.disarmed();
    assert_eq!((k.airborne(1), k.setpoint()), (false, None));
}

#[test]
fn a_disarmed_heartbeat_after_takeoff_answered_ends_the_takeoff() {
    let mut k = Known::new(Wanted::System(1));
    k.receive(addr(1), &header(1), &heartbeat(true), 0);
    k.took_off(1000);
    // Another message saying nothing of the arming changes nothing.
    k.receive(addr(1), &header(1), &attitude(1_500), 1500);
    assert_eq!((k.fsm(1500), k.airborne(1500)), ("takeoff", true));
    k.receive(addr(1), &header(1), &heartbeat(false), 2000);
    assert_eq!((k.fsm(2000), k.airborne(2000)), ("disarmed", false));
    // Armed again without a takeoff: still on the ground.
    k.receive(addr(1), &header(1), &heartbeat(true), 2500);
    assert_eq!((k.fsm(2500), k.airborne(2500)), ("armed", false));
}

#[test]
fn a_disarmed_heartbeat_from_another_system_does_not_end_the_takeoff() {
    let mut k = Known::new(Wanted::System(1));
    k.receive(addr(1), &header(1), &heartbeat(true), 0);
    k.took_off(1000);
    for (from, system) in [(addr(2), 1), (addr(1), 2)] {
        assert_eq!(
            k.receive(from, &header(system), &heartbeat(false), 1500),
            Receipt::Dropped
        );
    }
    assert_eq!((k.fsm(1500), k.airborne(1500)), ("takeoff", true));
}

#[test]
fn a_landing_answered_ends_the_takeoff_and_the_telemetry_tells() {
    let mut k = Known::new(Wanted::System(1));
    k.receive(addr(1), &header(1), &heartbeat(true), 0);
    k.took_off(1000);
    k.landing();
    assert_eq!((k.fsm(1100), k.airborne(1100)), ("armed", false));
    // Once the climb showed, landing leaves the telemetry to say so.
    k.took_off(2000);
    k.receive(
        addr(1),
        &header(1),
        &landed(MavLandedState::MAV_LANDED_STATE_IN_AIR),
        2500,
    );
    k.landing();
    assert_eq!((k.fsm(2600), k.airborne(2600)), ("hover", true));
}

#[test]
fn the_stream_stops_when_the_last_session_that_set_it_leaves() {
    let mut k = flying();
    k.stream(POSE, SessionId(2));
    k.release(SessionId(1));
    assert_eq!(k.setpoint(), Some(POSE));
    k.release(SessionId(2));
    assert_eq!(k.setpoint(), None);
}

fn heartbeat_in(custom_mode: u32, status: MavState) -> MavMessage {
    let MavMessage::HEARTBEAT(hb) = heartbeat(true) else {
        unreachable!()
    };
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode,
        system_status: status,
        ..hb
    })
}

const PX4_RTL: u32 = (4 << 16) | (5 << 24);
const PX4_OFFBOARD: u32 = 6 << 16;

#[test]
fn a_failsafe_mode_stops_the_stream_and_refuses_steering_until_overridden() {
    let mut k = flying();
    k.ask(Asked::Setpoints, 0);
    k.receive(
        addr(1),
        &header(1),
        &heartbeat_in(PX4_OFFBOARD, MavState::MAV_STATE_ACTIVE),
        10,
    );
    assert_eq!((k.failsafe(), k.setpoint()), (None, Some(POSE)));
    assert_eq!(k.check_steering(), Ok(()));
    k.receive(
        addr(1),
        &header(1),
        &heartbeat_in(PX4_RTL, MavState::MAV_STATE_CRITICAL),
        20,
    );
    let f = k.failsafe().expect("the autopilot's return");
    assert_eq!(f.reason().to_string(), "autopilot: AUTO.RTL");
    assert_eq!(
        k.setpoint(),
        None,
        "the vehicle left the setpoint: no more streaming"
    );
    assert_eq!(
        k.check_steering().unwrap_err().to_string(),
        "Vehicle is in failsafe (autopilot: AUTO.RTL): land, rtl or control_take failsafe"
    );
    assert!(k.override_failsafe().is_some_and(|f| f.overridden));
    assert_eq!(k.check_steering(), Ok(()));
    // Disarmed: over.
    k.receive(addr(1), &header(1), &heartbeat(false), 30);
    assert_eq!(k.failsafe(), None);
}

#[test]
fn a_critical_status_keeps_the_stream_the_vehicle_still_follows() {
    let mut k = flying();
    k.ask(Asked::Setpoints, 0);
    k.receive(
        addr(1),
        &header(1),
        &heartbeat_in(PX4_OFFBOARD, MavState::MAV_STATE_CRITICAL),
        10,
    );
    assert_eq!(
        k.failsafe().map(|f| f.reason().to_string()).as_deref(),
        Some("autopilot: CRITICAL")
    );
    assert_eq!(k.setpoint(), Some(POSE));
}

#[test]
fn a_new_vehicle_is_seen_afresh_and_its_return_counts_at_first_sight() {
    let mut k = flying();
    k.receive(
        addr(1),
        &header(1),
        &heartbeat_in(PX4_RTL, MavState::MAV_STATE_ACTIVE),
        10,
    );
    assert!(k.failsafe().is_some());
    // Rebooted (its boot time went back): nothing of the old one holds,
    // what it does now is looked at afresh.
    k.receive(addr(1), &header(1), &attitude(500), 20);
    assert_eq!(k.failsafe(), None);
    k.receive(
        addr(1),
        &header(1),
        &heartbeat_in(PX4_RTL, MavState::MAV_STATE_ACTIVE),
        30,
    );
    assert_eq!(
        k.failsafe().map(|f| f.reason().to_string()).as_deref(),
        Some("autopilot: AUTO.RTL")
    );
}

#[test]
fn a_mission_runs_while_the_autopilot_flies_it() {
    let mut k = flying();
    let plan = k.missions().on_autopilot().cloned().expect("mission 7");
    k.missions_mut().start_run(plan);
    assert!(!k.mission_running(10), "not in the mission mode yet");
    k.receive(
        addr(1),
        &header(1),
        &heartbeat_in((4 << 16) | (4 << 24), MavState::MAV_STATE_ACTIVE),
        10,
    );
    assert!(k.mission_running(10));
    k.missions_mut().drop_run();
    assert!(!k.mission_running(10));
}
