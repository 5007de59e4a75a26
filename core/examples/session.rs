//! Runs frames through `lluav_core::Server` with a toy vehicle and prints
//! each request and its response: the protocol without any network.
//!
//! ```text
//! cargo run -p lluav-core --example session                 # a scripted flight
//! cargo run -p lluav-core --example session -- "login 1025" "state"
//! ```

use lluav_core::{
    Args, Auth, Backend, Command, CommandId, Context, Failure, Fields, Message, Outcome, Pose, Server, Step,
};

/// A toy vehicle: arms on takeoff, disarms on land, remembers its setpoint.
#[derive(Default)]
struct Toy {
    armed: bool,
    setpoint: Option<Pose>,
}

impl Backend for Toy {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        match (cmd.id(), cmd.args()) {
            (CommandId::Takeoff, _) => self.armed = true,
            (CommandId::Land | CommandId::Disarm, _) => self.armed = false,
            (CommandId::SetSpNed, Args::Setpoint(p)) => self.setpoint = Some(*p),
            (CommandId::State, _) => {
                out.object("state", |s| {
                    s.bool("armed", self.armed)
                        .str("fsm", if self.armed { "hover" } else { "disarmed" })
                        .bool("lock_mode", ctx.lock_mode);
                    match self.setpoint {
                        Some(p) => s.array("setpoint", |a| {
                            a.f32(p.x).f32(p.y).f32(p.z).f32(p.yaw);
                        }),
                        None => s.null("setpoint"),
                    };
                });
            }
            _ => return Err(Failure::unsupported("The toy vehicle does not do that")),
        }
        Ok(Step::Done)
    }
}

fn main() {
    let script = [
        "state",
        "login secret",
        "takeoff",
        "set_sp_ned 1.0:2.0:-3.0:0.5",
        "reboot_system",
        "state",
        "set_sp_ned nan:0:0:0",
        "fly_to_the_moon",
        "land",
        "state",
    ];
    let args: Vec<String> = std::env::args().skip(1).collect();
    let frames: Vec<&str> = if args.is_empty() {
        script.to_vec()
    } else {
        args.iter().map(String::as_str).collect()
    };

    let clock = || {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
    };
    let auth = Auth::new(Some("secret")).expect("a valid password");
    let mut server = Server::new(Toy::default(), clock, auth);
    let mut session = server.open(Some(std::net::IpAddr::from(std::net::Ipv4Addr::LOCALHOST).into()));
    let mut out = [0u8; 2048];
    for frame in frames {
        println!("> {frame}");
        let outcome = server.handle(&mut session, Message::Text(frame.as_bytes()), &mut out);
        if let Outcome::Pending(ticket, _) = outcome {
            // The toy vehicle answers every command at once.
            unreachable!("the toy vehicle never waits, yet left {ticket:?} pending");
        }
        if let Some(reply) = outcome.reply() {
            println!("< {reply}");
        }
        if let Some(code) = outcome.close_code() {
            println!("< (close {})", code.code());
            break;
        }
    }
    server.close(&session);
}
