//! The frame mix both implementations are measured on. Plain std, no
//! lluav-core: `embedded/core-only/build.rs` includes this file to build
//! the same frames for the Cortex-M counts.

/// The benchmark's mission frame: `mission 1001:` and about 1 KiB of JSON.
pub fn mission_1k() -> String {
    let mut wps = Vec::new();
    let mut i = 0;
    loop {
        let wp = format!(r#"{{"x":{}.5,"y":-{}.25,"z":-10,"yaw":0.{}}}"#, i, i * 2, i % 10);
        let len: usize = wps.iter().map(|w: &String| w.len() + 1).sum::<usize>() + wp.len();
        if len > 1000 {
            break;
        }
        wps.push(wp);
        i += 1;
    }
    format!(r#"mission 1001:{{"waypoints":[{}]}}"#, wps.join(","))
}

/// (label, frame, vehicle armed)
pub fn mix() -> Vec<(&'static str, String, bool)> {
    vec![
        ("state", "state".into(), false),
        ("set_sp_ned", "set_sp_ned 1.0:2.0:-3.0:0.5".into(), false),
        (
            "mw_exec_10_ids",
            "mw_exec 1001:1,2,3,4,5,6,7,8,9,10".into(),
            false,
        ),
        ("mission_1KiB_json", mission_1k(), false),
        ("unknown_command", "fly_to_the_moon 1 2 3".into(), false),
        ("gate_refusal_armed", "reboot_system".into(), true),
    ]
}
