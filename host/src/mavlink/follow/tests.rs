//! The following rules, packet by packet.

use ::mavlink::dialects::ardupilotmega::{ATTITUDE_DATA, MavModeFlag, MavState, SYSTEM_TIME_DATA};

use super::*;

fn addr(port: u16) -> Option<SocketAddr> {
    Some(SocketAddr::from(([127, 0, 0, 1], port)))
}

fn header(system: u32, component: u8) -> MavHeader {
    MavHeader {
        system_id: system,
        component_id: component,
        sequence: 0,
    }
}

fn heartbeat(autopilot: MavAutopilot, mavtype: MavType) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype,
        autopilot,
        base_mode: MavModeFlag::empty(),
        system_status: MavState::MAV_STATE_ACTIVE,
        mavlink_version: 3,
    })
}

fn px4() -> MavMessage {
    heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, MavType::MAV_TYPE_QUADROTOR)
}

fn attitude(time_boot_ms: u32) -> MavMessage {
    MavMessage::ATTITUDE(ATTITUDE_DATA {
        time_boot_ms,
        ..ATTITUDE_DATA::DEFAULT
    })
}

fn system_time(time_boot_ms: u32) -> MavMessage {
    MavMessage::SYSTEM_TIME(SYSTEM_TIME_DATA {
        time_unix_usec: 0,
        time_boot_ms,
    })
}

const NEW: Admit = Admit::Acquired { new_vehicle: true };
const SAME: Admit = Admit::Acquired { new_vehicle: false };

#[test]
fn only_the_wanted_systems_autopilot_heartbeat_is_followed() {
    let mut f = Follow::new(Wanted::System(1));
    let gcs = heartbeat(MavAutopilot::MAV_AUTOPILOT_INVALID, MavType::MAV_TYPE_GCS);
    let invalid = heartbeat(MavAutopilot::MAV_AUTOPILOT_INVALID, MavType::MAV_TYPE_QUADROTOR);
    let gimbal = heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, MavType::MAV_TYPE_GIMBAL);
    assert_eq!(f.admit(addr(1), &header(1, 1), &gcs, 0), Admit::Foreign);
    assert_eq!(f.admit(addr(1), &header(1, 1), &invalid, 0), Admit::Foreign);
    assert_eq!(f.admit(addr(1), &header(1, 1), &gimbal, 0), Admit::Foreign);
    assert_eq!(
        f.admit(addr(1), &header(2, 1), &px4(), 0),
        Admit::Foreign,
        "another system"
    );
    assert_eq!(
        f.admit(addr(1), &header(1, 100), &px4(), 0),
        Admit::Foreign,
        "another component"
    );
    assert_eq!(f.target(), None);
    assert_eq!(f.admit(addr(1), &header(1, 1), &px4(), 0), NEW);
    assert_eq!(
        (f.target(), f.peer()),
        (
            Some(Target {
                system: 1,
                component: 1
            }),
            addr(1)
        )
    );
}

#[test]
fn with_any_the_first_autopilot_heartbeat_is_followed() {
    let mut f = Follow::new(Wanted::Any);
    assert_eq!(f.admit(addr(1), &header(7, 1), &px4(), 0), NEW);
    assert_eq!(f.admit(addr(2), &header(2, 1), &px4(), 10), Admit::Foreign);
    assert_eq!(f.target().map(|t| t.system), Some(7));
}

#[test]
fn packets_from_another_address_or_system_never_count_nor_move_the_peer() {
    let mut f = Follow::new(Wanted::System(1));
    f.admit(addr(1), &header(1, 1), &px4(), 0);
    for (from, h) in [
        (addr(2), header(1, 1)),
        (addr(1), header(2, 1)),
        (addr(1), header(1, 2)),
        (None, header(1, 1)),
    ] {
        assert_eq!(f.admit(from, &h, &px4(), 100), Admit::Foreign, "{from:?} {h:?}");
        assert_eq!(f.admit(from, &h, &attitude(5), 100), Admit::Foreign);
    }
    assert_eq!(f.peer(), addr(1));
    assert_eq!(f.admit(addr(1), &header(1, 1), &attitude(5), 100), Admit::Accept);
}

#[test]
fn the_link_is_up_for_three_seconds_after_each_heartbeat() {
    let mut f = Follow::new(Wanted::System(1));
    assert!(!f.link_up(0));
    f.admit(addr(1), &header(1, 1), &px4(), 1000);
    assert_eq!(f.admit(addr(1), &header(1, 1), &px4(), 2000), Admit::Accept);
    assert!(f.link_up(5000) && !f.link_up(5001));
    assert_eq!(f.heartbeat_age_ms(5001), Some(3001));
    // Foreign heartbeats keep nothing alive.
    f.admit(addr(2), &header(1, 1), &px4(), 4000);
    assert!(!f.link_up(5001));
}

#[test]
fn after_a_loss_the_same_autopilot_is_the_same_vehicle() {
    let mut f = Follow::new(Wanted::System(1));
    f.admit(addr(1), &header(1, 1), &px4(), 0);
    f.admit(addr(1), &header(1, 1), &attitude(10_000), 100);
    assert_eq!(f.admit(addr(1), &header(1, 1), &px4(), 9000), SAME);
    assert_eq!(
        f.admit(addr(1), &header(1, 1), &attitude(19_000), 9100),
        Admit::Accept
    );
}

#[test]
fn after_a_loss_another_system_or_address_is_a_new_vehicle() {
    let mut f = Follow::new(Wanted::Any);
    f.admit(addr(1), &header(1, 1), &px4(), 0);
    assert_eq!(
        f.admit(addr(2), &header(1, 1), &px4(), 1000),
        Admit::Foreign,
        "the link is up"
    );
    assert_eq!(f.admit(addr(2), &header(1, 1), &px4(), 3001), NEW);
    assert_eq!(f.peer(), addr(2));
    assert_eq!(f.admit(addr(2), &header(3, 1), &px4(), 6002), NEW);
    assert_eq!(f.target().map(|t| t.system), Some(3));
}

#[test]
fn a_boot_time_that_goes_back_is_a_reboot_but_reordering_is_not() {
    let mut f = Follow::new(Wanted::System(1));
    f.admit(addr(1), &header(1, 1), &px4(), 0);
    let h = header(1, 1);
    assert_eq!(f.admit(addr(1), &h, &system_time(60_000), 0), Admit::Accept);
    assert_eq!(f.admit(addr(1), &h, &attitude(60_100), 0), Admit::Accept);
    // A packet a radio delayed behind newer ones.
    assert_eq!(f.admit(addr(1), &h, &attitude(59_900), 0), Admit::Accept);
    assert_eq!(f.admit(addr(1), &h, &attitude(60_200), 0), Admit::Accept);
    assert_eq!(f.admit(addr(1), &h, &attitude(900), 0), Admit::Rebooted);
    // Its other boot-time messages do not report the same reboot again.
    assert_eq!(f.admit(addr(1), &h, &system_time(950), 0), Admit::Accept);
    assert_eq!(f.admit(addr(1), &h, &attitude(1000), 0), Admit::Accept);
}

#[test]
fn an_autopilot_that_sends_no_boot_time_never_looks_rebooted() {
    let mut f = Follow::new(Wanted::System(1));
    f.admit(None, &header(1, 1), &px4(), 0);
    for _ in 0..3 {
        assert_eq!(f.admit(None, &header(1, 1), &attitude(0), 0), Admit::Accept);
    }
}

#[test]
fn system_ids_parse_as_the_command_line_takes_them() {
    assert_eq!("1".parse(), Ok(Wanted::System(1)));
    assert_eq!("255".parse(), Ok(Wanted::System(255)));
    assert_eq!("any".parse(), Ok(Wanted::Any));
    for bad in ["0", "256", "", "ANY", "-1"] {
        assert!(bad.parse::<Wanted>().is_err(), "{bad}");
    }
    assert_eq!(Wanted::default(), Wanted::System(1));
}
