//! The workload both implementations are measured on: the frame mix and
//! the vehicle's answers (the baseline writes the same fields).

use lluav_core::{Args, Backend, Command, Context, Failure, Fields, Payload};

/// The same vehicle answers as the baseline's: a 12-field state, setpoint
/// echo, waypoint ids, mission waypoint count.
pub struct Vehicle {
    pub armed: bool,
}

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }
    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<(), Failure> {
        match cmd.args() {
            Args::None => {
                out.object("state", |s| {
                    s.bool("armed", self.armed)
                        .str("fsm", "hover")
                        .bool("lock_mode", ctx.lock_mode)
                        .f32("x", 1.5)
                        .f32("y", -2.25)
                        .f32("z", -10.0)
                        .f32("vx", 0.0)
                        .f32("vy", 0.1)
                        .f32("vz", 0.0)
                        .f32("yaw", 0.5)
                        .f32("battery", 87.5);
                });
            }
            Args::Setpoint(p) => {
                out.f32("x", p.x).f32("y", p.y).f32("z", p.z).f32("yaw", p.yaw);
            }
            Args::MwExec { ext_id, wp_ids } => {
                out.u64("ext_id", u64::from(*ext_id)).array("wp_ids", |a| {
                    for id in wp_ids {
                        a.u64(u64::from(*id));
                    }
                });
            }
            Args::Mission { ext_id, payload } => {
                let n = match payload {
                    Payload::Json(j) => j.matches("\"x\"").count(),
                    Payload::Path(_) => 0,
                };
                out.u64("waypoints", n as u64).u64("ext_id", u64::from(*ext_id));
            }
            _ => {}
        }
        Ok(())
    }
}

fn mission_1k() -> String {
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
