//! The simulated vehicle's FSM and motion, driven through lluav-core's
//! server with real frames and simulated time (no real sleeping).

mod sim_support;

use sim_support::Harness;

fn altitude(h: &mut Harness) -> f64 {
    h.state()["altitude"].as_f64().unwrap()
}

#[test]
fn takeoff_arms_at_once_and_reaches_hover_at_speed_one() {
    let mut h = Harness::new(1.0);
    let r = h.ok("takeoff");
    assert_eq!(r["fsm"], "takeoff");
    assert_eq!(h.state()["armed"], true);
    h.run_for(1.0);
    assert_eq!(h.fsm(), "takeoff");
    assert!(
        (altitude(&mut h) - 1.0).abs() < 1e-6,
        "climbs at climb_speed 1 m/s"
    );
    let t = h.run_until_fsm("hover", 5.0);
    assert!(t <= 1.1, "2 m at 1 m/s: hover after about 2 s, got 1 + {t}");
    assert!((altitude(&mut h) - 2.0).abs() < 0.05);
}

#[test]
fn speed_ten_runs_the_same_flight_ten_times_faster() {
    let mut h = Harness::new(10.0);
    h.ok("takeoff");
    h.run_for(0.1);
    assert_eq!(h.fsm(), "takeoff");
    assert!((altitude(&mut h) - 1.0).abs() < 1e-6);
    let t = h.run_until_fsm("hover", 1.0);
    assert!(t <= 0.11, "hover after 0.2 s of wall time, got 0.1 + {t}");
    h.ok("land");
    let t = h.run_until_fsm("disarmed", 1.5);
    assert!(t <= 1.5);
}

#[test]
fn land_disarms_within_fifteen_seconds_even_from_high_up() {
    for alt in ["2", "50", "120"] {
        let mut h = Harness::new(1.0);
        h.ok(&format!("set_param takeoff_alt:{alt}"));
        h.airborne();
        let r = h.ok("land");
        assert_eq!(r["fsm"], "landing");
        let mut t = 0.0;
        while h.state()["armed"] == true {
            h.run_for(0.1);
            t += 0.1;
            assert!(t <= 15.0, "still armed {t} s after land from {alt} m");
        }
        assert_eq!(h.fsm(), "disarmed");
        assert_eq!(altitude(&mut h), 0.0);
    }
}

#[test]
fn a_vehicle_disarmed_in_the_air_falls_and_state_shows_the_fall() {
    let mut h = Harness::new(1.0);
    h.ok("set_param takeoff_alt:8");
    h.ok("set_param climb_speed:5");
    h.airborne();
    // Hovering still: a vehicle disarmed while climbing rises on first.
    h.run_for(1.0);
    let r = h.ok("disarm");
    assert_eq!(
        (r["armed"].as_bool(), r["fsm"].as_str()),
        (Some(false), Some("falling"))
    );
    // Within the same millisecond it is still where it was.
    let s = h.state();
    assert_eq!(
        (s["armed"].as_bool(), s["fsm"].as_str(), s["airborne"].as_bool()),
        (Some(false), Some("falling"), Some(true))
    );
    assert!((altitude(&mut h) - 8.0).abs() < 0.1, "{s}");
    // Half a second of free fall: about 1.2 m down, at about 4.9 m/s.
    h.run_for(0.5);
    let s = h.state();
    let (alt, down) = (
        s["altitude"].as_f64().unwrap(),
        s["velocity"]["z"].as_f64().unwrap(),
    );
    assert!((6.5..7.0).contains(&alt), "{s}");
    assert!((4.5..5.5).contains(&down), "{s}");
    // Nothing flies a falling vehicle.
    for frame in ["takeoff", "land", "rtl", "set_sp_ned 0:0:-5:0", "sleep"] {
        assert_eq!(
            h.fails(frame, -1),
            "Vehicle is falling: it was disarmed in the air",
            "{frame}"
        );
    }
    // From 8 m: on the ground after about 1.28 s, at rest and disarmed.
    let t = h.run_until_fsm("disarmed", 2.0);
    assert!(0.5 + t > 1.2 && 0.5 + t < 1.4, "{t}");
    let s = h.state();
    assert_eq!((altitude(&mut h), s["velocity"]["z"].as_f64()), (0.0, Some(0.0)));
    h.ok("takeoff");
}

#[test]
fn disarm_on_the_ground_disarms_at_once() {
    let mut h = Harness::new(1.0);
    h.airborne();
    h.ok("land");
    h.run_until_fsm("armed", 20.0);
    let r = h.ok("disarm");
    assert_eq!(
        (r["armed"].as_bool(), r["fsm"].as_str()),
        (Some(false), Some("disarmed"))
    );
}

#[test]
fn armed_vehicle_refuses_reboot_and_takeoff() {
    let mut h = Harness::new(1.0);
    h.airborne();
    assert_eq!(h.fails("reboot_system", -1), "Not allow when vehicle is ARMED!");
    assert_eq!(h.fails("takeoff", -1), "Not allow when vehicle is ARMED!");
}

#[test]
fn setpoints_are_tracked_at_bounded_speed_in_ned() {
    let mut h = Harness::new(1.0);
    h.airborne();
    let r = h.ok("set_sp_ned 10:0:-2:1.5");
    assert_eq!(
        (r["tracking"].as_bool(), r["fsm"].as_str()),
        (Some(true), Some("hover"))
    );
    assert_eq!(r["sp"]["x"], 10.0);
    h.run_for(1.0);
    let s = h.state();
    let x = s["position"]["x"].as_f64().unwrap();
    assert!((x - 2.0).abs() < 1e-6, "cruise_speed 2 m/s: x = {x}");
    assert!((s["velocity"]["x"].as_f64().unwrap() - 2.0).abs() < 1e-6);
    assert!(
        (s["yaw"].as_f64().unwrap() - 1.0).abs() < 1e-6,
        "yaw_rate 1 rad/s"
    );
    h.run_for(5.0);
    let s = h.state();
    assert!((s["position"]["x"].as_f64().unwrap() - 10.0).abs() < 1e-6);
    assert!((s["yaw"].as_f64().unwrap() - 1.5).abs() < 1e-6);
    assert_eq!(s["velocity"]["x"], 0.0);
}

#[test]
fn setpoints_outside_the_fence_or_underground_are_refused() {
    let mut h = Harness::new(1.0);
    h.airborne();
    // At or below the ground: refused by the core's grammar, for every
    // backend, and the vehicle keeps hovering where it was.
    let before = h.state();
    for frame in ["set_sp_ned 0:0:1:0", "set_sp_ned 3:0:0:0", "set_sp_ned 3:0:-0:0"] {
        assert_eq!(
            h.fails(frame, -2),
            "Invalid arguments: setpoint at or below the ground (z >= 0; up is negative z): use land to descend",
            "{frame}"
        );
    }
    h.run_for(2.0);
    let after = h.state();
    assert_eq!(after["fsm"], "hover");
    assert_eq!(after["position"], before["position"]);
    assert!(h.fails("set_sp_ned 900:0:-2:0", -2).contains("geofence_radius"));
    assert!(h.fails("set_sp_ned 0:0:-200:0", -2).contains("max_alt"));
    assert!(h.fails("zyhk 0.5,300", -2).contains("max_alt"));
}

#[test]
fn rtl_flies_home_then_lands_and_mrtl_retraces_the_mission() {
    let mut h = Harness::new(1.0);
    h.airborne();
    h.ok("set_sp_ned 20:10:-3:0");
    h.run_for(15.0);
    assert_eq!(h.ok("rtl")["fsm"], "rtl");
    h.run_for(5.0);
    assert!(altitude(&mut h) > 3.0, "climbs towards rtl_alt 10 first");
    h.run_until_fsm("disarmed", 60.0);
    // Accepted within accept_radius (0.3 m) of home, it lands on home.
    let p = h.state()["position"].clone();
    assert!(
        p["x"].as_f64().unwrap().abs() < 1e-6 && p["y"].as_f64().unwrap().abs() < 1e-6,
        "{p}"
    );

    h.airborne();
    h.ok(r#"mission 5:{"waypoints":[{"x":0,"y":8,"z":-12},{"x":8,"y":8,"z":-12}]}"#);
    h.ok("mw_exec 5:1,2");
    h.run_until_fsm("hover", 60.0);
    assert_eq!(h.ok("mrtl")["fsm"], "rtl");
    // Back through waypoint 1 (0, 8) before home.
    let mut passed_wp1 = false;
    while h.fsm() == "rtl" {
        h.run_for(0.1);
        let p = h.state()["position"].clone();
        let (x, y) = (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap());
        passed_wp1 |= x.abs() < 0.5 && (y - 8.0).abs() < 0.5;
    }
    assert!(passed_wp1, "mrtl retraces the mission");
    h.run_until_fsm("disarmed", 30.0);
}

#[test]
fn only_takeoff_leaves_the_ground_every_other_flight_command_answers_not_flying() {
    let mut h = Harness::new(10.0);
    h.ok(r#"mission 3:{"waypoints":[{"x":2,"y":0,"z":-2}]}"#);
    let moving = [
        "land",
        "tether_land",
        "rtl",
        "mrtl",
        "set_sp_ned 1:0:-2:0",
        "zyhk 1.5,3",
        "mw_exec 3:1",
    ];
    let before = h.state();
    for frame in moving {
        assert_eq!(h.fails(frame, -1), "Vehicle is not flying", "{frame}");
    }
    assert_eq!(h.state(), before, "nothing changed");
    // Landed but still armed (the second before it disarms): still not
    // flying, and takeoff is refused by the armed gate.
    h.airborne();
    h.ok("land");
    h.run_until_fsm("armed", 20.0);
    for frame in moving {
        assert_eq!(h.fails(frame, -1), "Vehicle is not flying", "{frame}");
    }
    assert_eq!(h.fails("takeoff", -1), "Not allow when vehicle is ARMED!");
    // In the air, landing twice is fine.
    h.run_until_fsm("disarmed", 2.0);
    h.airborne();
    assert_eq!(h.ok("land")["fsm"], "landing");
    assert_eq!(h.ok("tether_land")["tethered"], true);
}

#[test]
fn sleeping_vehicle_refuses_takeoff_until_woken() {
    let mut h = Harness::new(1.0);
    assert_eq!(h.ok("sleep")["fsm"], "sleep");
    assert_eq!(h.fails("takeoff", -1), "Vehicle is asleep: wakeup first");
    assert_eq!(h.ok("wakeup")["fsm"], "disarmed");
    h.ok("takeoff");
}

#[test]
fn autosleep_puts_an_idle_vehicle_to_sleep() {
    let mut h = Harness::new(10.0);
    h.ok("autosleep_enable 1");
    h.ok("set_param autosleep_after:60");
    h.run_for(5.9);
    assert_eq!(h.fsm(), "disarmed");
    h.run_for(0.2);
    assert_eq!(h.fsm(), "sleep");
}

#[test]
fn zyhk_hovers_at_each_height_then_lands() {
    let mut h = Harness::new(1.0);
    h.airborne();
    let r = h.ok("zyhk 1.5,3 4,0,0");
    assert_eq!(r["fsm"], "mission");
    assert_eq!(h.state()["armed"], true);
    let mut seen = Vec::new();
    let mut t = 0.0;
    while h.fsm() != "disarmed" {
        h.run_for(0.1);
        t += 0.1;
        let alt = (altitude(&mut h) * 10.0).round() / 10.0;
        if seen.last() != Some(&alt) {
            seen.push(alt);
        }
        assert!(t < 60.0, "zyhk did not finish");
    }
    assert!(seen.contains(&1.5) && seen.contains(&3.0), "{seen:?}");
    // Hovers 5 s at each of two heights, so it takes well over 10 s.
    assert!(t > 10.0, "{t}");
    let p = h.state()["position"].clone();
    assert!(
        (p["x"].as_f64().unwrap() - 4.0).abs() < 0.31,
        "lands at the landing point: {p}"
    );
}

#[test]
fn battery_drains_while_armed_only() {
    let mut h = Harness::new(10.0);
    h.run_for(6.0);
    assert_eq!(h.state()["battery"], 100.0);
    h.airborne();
    h.run_for(6.0);
    let b = h.state()["battery"].as_f64().unwrap();
    assert!((98.5..99.1).contains(&b), "1 %/min for a minute: {b}");
}

#[test]
fn low_battery_sends_the_vehicle_home() {
    let mut h = Harness::new(10.0);
    h.ok("set_param battery_drain:60");
    h.ok("set_param low_battery:90");
    h.airborne();
    h.ok("set_sp_ned 5:0:-2:0");
    h.run_for(1.2);
    assert_eq!(h.fsm(), "rtl");
}

#[test]
fn state_reports_armed_fsm_lock_mode_and_motion() {
    let mut h = Harness::new(1.0);
    let s = h.state();
    for key in [
        "armed",
        "fsm",
        "lock_mode",
        "position",
        "velocity",
        "yaw",
        "battery",
        "setpoint",
        "home",
    ] {
        assert!(s.get(key).is_some(), "state lacks {key}: {s}");
    }
    assert_eq!(
        (s["armed"].as_bool(), s["lock_mode"].as_bool()),
        (Some(false), Some(false))
    );
    assert_eq!(s["fsm"], "disarmed");
    h.ok("login 1025");
    h.ok("admin_lock");
    assert_eq!(h.state()["lock_mode"], true);
}
