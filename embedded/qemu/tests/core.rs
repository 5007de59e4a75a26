//! lluav-core on the target ISA (Cortex-M7 under QEMU): parsing, gates,
//! responses and the close policy through the core's public API, the
//! WebSocket rules the MCU adapter takes from the core (32-bit code paths:
//! unmasking byte by byte), and the stack high-water mark of the
//! frame-handling path.
#![no_std]
#![no_main]

use lluav_qemu_tests as _;

use core::fmt::Write;

use lluav_core::{Auth, Message, Outcome, Server, Session};
use lluav_qemu_tests::Vehicle;

const TS: i64 = 1_714_233_600_000;
type TestServer = Server<Vehicle, fn() -> i64>;

fn server() -> TestServer {
    Server::new(
        Vehicle::new(),
        (|| TS) as fn() -> i64,
        Auth::new(Some("secret")).unwrap(),
    )
}

fn reply<'o>(s: &mut TestServer, session: &mut Session, frame: &str, out: &'o mut [u8]) -> &'o str {
    match s.handle(session, Message::Text(frame.as_bytes()), out) {
        Outcome::Reply(r) => r,
        other => defmt::panic!("{}: expected a reply, got {}", frame, defmt::Debug2Format(&other)),
    }
}

fn logged_in(s: &mut TestServer) -> Session {
    let mut session = Session::new();
    let mut out = [0u8; 256];
    reply(s, &mut session, "login secret", &mut out);
    session
}

/// A fixed-capacity `fmt::Write` target.
struct Text<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> Text<N> {
    fn new() -> Self {
        Text { buf: [0; N], len: 0 }
    }
    fn as_str(&self) -> &str {
        core::str::from_utf8(&self.buf[..self.len]).unwrap()
    }
}

impl<const N: usize> Write for Text<N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let end = self.len + s.len();
        self.buf
            .get_mut(self.len..end)
            .ok_or(core::fmt::Error)?
            .copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

#[defmt_test::tests]
mod tests {
    use core::fmt::Write;

    use defmt::assert_eq;
    use lluav_core::{
        Args, CloseCode, CommandId, Message, Outcome, ParseError, Payload, Session, TABLE, parse,
    };
    use lluav_qemu_tests::stack;

    use super::{Text, logged_in, reply, server};

    #[test]
    fn setpoint_parses_into_a_typed_pose() {
        let cmd = parse("set_sp_ned 1.0:2.0:-3.0:0.5").unwrap();
        assert!(cmd.id() == CommandId::SetSpNed);
        match cmd.args() {
            Args::Setpoint(p) => assert!(p.x == 1.0 && p.y == 2.0 && p.z == -3.0 && p.yaw == 0.5),
            _ => defmt::panic!("not a setpoint"),
        }
    }

    #[test]
    fn nan_setpoint_is_refused() {
        assert!(matches!(
            parse("set_sp_ned 1:2:NaN:0"),
            Err(ParseError::InvalidArgs(CommandId::SetSpNed, _))
        ));
        assert!(matches!(
            parse("set_sp_ned 1:2:inf:0"),
            Err(ParseError::InvalidArgs(..))
        ));
    }

    #[test]
    fn mission_splits_at_the_first_colon_and_detects_json() {
        let cmd = parse(r#"mission 1001:{"waypoints":[{"x":1,"y":2,"z":-3}]}"#).unwrap();
        match cmd.args() {
            Args::Mission {
                ext_id: 1001,
                payload: Payload::Json(j),
            } => assert!(j.starts_with("{\"waypoints\"")),
            _ => defmt::panic!("not a JSON mission"),
        }
        assert!(matches!(
            parse("mission 7:plans/a.json").unwrap().args(),
            Args::Mission {
                ext_id: 7,
                payload: Payload::Path(_)
            }
        ));
        assert!(parse(r#"mission 7:{"unclosed":[1,2}"#).is_err());
    }

    #[test]
    fn waypoint_id_lists_parse_and_overflow_is_an_error() {
        match parse("mw_exec 1001:1,2,3,5").unwrap().args() {
            Args::MwExec { ext_id, wp_ids } => {
                assert_eq!(*ext_id, 1001);
                assert_eq!(wp_ids.as_slice(), &[1, 2, 3, 5]);
            }
            _ => defmt::panic!("not mw_exec"),
        }
        let mut many = Text::<1024>::new();
        write!(many, "mw_exec 1:0").unwrap();
        for i in 1..=lluav_core::MAX_WAYPOINT_IDS {
            write!(many, ",{}", i).unwrap();
        }
        assert!(parse(many.as_str()).is_err());
    }

    #[test]
    fn unknown_and_empty_frames_are_typed_errors() {
        assert!(matches!(
            parse("fly_to_the_moon"),
            Err(ParseError::Unknown("fly_to_the_moon"))
        ));
        assert!(matches!(parse("  \r\n"), Err(ParseError::Empty)));
    }

    #[test]
    fn every_bare_command_encodes_back_to_itself() {
        let mut n = 0;
        for spec in &TABLE {
            if let Ok(cmd) = parse(spec.name()) {
                let mut text = Text::<64>::new();
                cmd.encode(&mut text).unwrap();
                assert!(parse(text.as_str()).unwrap() == cmd, "{}", spec.name());
                n += 1;
            }
        }
        assert!(n > 40, "most commands take no arguments");
    }

    #[test]
    fn login_gates_everything_but_login() {
        let mut s = server();
        let mut session = Session::new();
        let mut out = [0u8; 256];
        assert_eq!(
            reply(&mut s, &mut session, "state", &mut out),
            r#"{"ret":-1,"cmd":2,"ts":1714233600000,"msg":"Login first!"}"#
        );
        assert_eq!(
            reply(&mut s, &mut session, "login secret", &mut out),
            r#"{"ret":0,"cmd":1,"ts":1714233600000,"logged_in":true,"admin":false}"#
        );
        assert_eq!(
            reply(&mut s, &mut session, "state", &mut out),
            r#"{"ret":0,"cmd":2,"ts":1714233600000,"state":{"armed":false,"fsm":"disarmed","lock_mode":false}}"#
        );
    }

    #[test]
    fn fifth_wrong_password_closes_with_1008() {
        let mut s = server();
        let mut session = Session::new();
        let mut out = [0u8; 256];
        for _ in 0..4 {
            assert!(reply(&mut s, &mut session, "login nope", &mut out).contains("Wrong password!"));
        }
        match s.handle(&mut session, Message::Text(b"login nope"), &mut out) {
            Outcome::ReplyThenClose(r, CloseCode::Policy) => assert!(r.contains("Wrong password!")),
            other => defmt::panic!("{}", defmt::Debug2Format(&other)),
        }
    }

    #[test]
    fn armed_vehicle_refuses_reboot_but_never_land() {
        let mut s = server();
        let mut session = logged_in(&mut s);
        let mut out = [0u8; 256];
        reply(&mut s, &mut session, "takeoff", &mut out);
        assert!(
            reply(&mut s, &mut session, "reboot_system", &mut out)
                .contains("Not allow when vehicle is ARMED!")
        );
        for safe in ["set_sp_ned 0:0:-1:0", "rtl", "mrtl", "tether_land", "land"] {
            assert!(
                reply(&mut s, &mut session, safe, &mut out).starts_with(r#"{"ret":0,"#),
                "{}",
                safe
            );
        }
    }

    #[test]
    fn lock_mode_refuses_users_not_admins() {
        let mut s = server();
        let mut user = logged_in(&mut s);
        let mut admin = Session::new();
        let mut out = [0u8; 256];
        assert!(reply(&mut s, &mut user, "admin_lock", &mut out).contains("Admin only!"));
        reply(&mut s, &mut admin, "login 1025", &mut out);
        reply(&mut s, &mut admin, "admin_lock", &mut out);
        assert!(
            reply(&mut s, &mut user, "save_param 1", &mut out)
                .contains("CMD not permitted to run in LOCK mode!")
        );
        assert!(reply(&mut s, &mut admin, "save_param 1", &mut out).starts_with(r#"{"ret":0,"#));
    }

    #[test]
    fn errors_carry_the_exact_messages() {
        let mut s = server();
        let mut session = logged_in(&mut s);
        let mut out = [0u8; 256];
        assert_eq!(
            reply(&mut s, &mut session, "set_sp_ned 1:2", &mut out),
            r#"{"ret":-2,"cmd":23,"ts":1714233600000,"msg":"Invalid arguments, usage: set_sp_ned x:y:z:yaw"}"#
        );
        assert_eq!(
            reply(&mut s, &mut session, "bad\"name", &mut out),
            r#"{"ret":-2,"cmd":0,"ts":1714233600000,"msg":"Unsupported command: bad\"name"}"#
        );
    }

    #[test]
    fn response_that_does_not_fit_is_replaced_not_truncated() {
        let mut s = server();
        let mut session = logged_in(&mut s);
        s.backend_mut().padding = 4096;
        let mut out = [0u8; 512];
        assert_eq!(
            reply(&mut s, &mut session, "sysinfo", &mut out),
            r#"{"ret":-1,"cmd":6,"ts":1714233600000,"msg":"Response too large"}"#
        );
    }

    #[test]
    fn close_policy_for_binary_invalid_utf8_and_oversized() {
        let mut s = server();
        let mut session = Session::new();
        let mut out = [0u8; 256];
        assert!(
            s.handle(&mut session, Message::Binary(b"\x00"), &mut out)
                == Outcome::Close(CloseCode::Unsupported)
        );
        assert!(
            s.handle(&mut session, Message::Text(b"state \xff"), &mut out)
                == Outcome::Close(CloseCode::InvalidPayload)
        );
        assert!(s.handle(&mut session, Message::Oversized, &mut out) == Outcome::Close(CloseCode::TooBig));
    }

    #[test]
    fn frames_unmask_in_pieces_and_lengths_must_be_minimal() {
        use lluav_core::websocket::{parse_header, unmask};
        // RFC 6455, section 5.7: "Hello", masked with 37 fa 21 3d, in
        // pieces of every size.
        let mask = [0x37, 0xfa, 0x21, 0x3d];
        for piece in 1..=5 {
            let mut wire = *b"\x7f\x9f\x4d\x51\x58";
            let mut at = 0;
            for chunk in wire.chunks_mut(piece) {
                unmask(chunk, mask, at);
                at += chunk.len();
            }
            assert_eq!(&wire, b"Hello");
        }
        let header = |b: &[u8]| parse_header(b).map(|h| h.map(|h| h.len));
        assert!(header(&[0x81, 0xfe, 0, 126, 1, 2, 3, 4]) == Ok(Some(126)));
        assert!(header(&[0x81, 0xfe, 0, 3, 1, 2, 3, 4]) == Err(CloseCode::ProtocolError));
        assert!(header(&[0x81, 0xff, 0, 0, 0, 0, 0, 0, 0xff, 0xff]) == Err(CloseCode::ProtocolError));
    }

    #[test]
    fn the_upgrade_check_and_policy_judge_a_request() {
        use lluav_core::websocket::handshake::{Rejection, Request, judge};
        use lluav_core::websocket::policy::{Forbidden, Policy};
        let policy: Policy<'_> = Policy {
            local: core::net::IpAddr::V4(core::net::Ipv4Addr::new(10, 53, 0, 1)),
            tls: false,
            allowed_origins: &[],
            allowed_hosts: &[],
        };
        macro_rules! upgrade {
            ($host:literal) => {
                concat!(
                    "GET / HTTP/1.1\r\nHost: ",
                    $host,
                    "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n",
                    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
                )
                .as_bytes()
            };
        }
        assert!(matches!(
            judge(upgrade!("10.53.0.1:53001"), &policy),
            Ok(Request::Upgrade(_))
        ));
        let rebound = judge(upgrade!("evil.example:53001"), &policy);
        assert!(rebound == Err(Rejection::Forbidden(Forbidden::Host)));
    }

    #[test]
    fn every_command_in_the_table_gets_one_response_with_its_id() {
        let mut s = server();
        let mut session = Session::new();
        let mut out = [0u8; 2048];
        reply(&mut s, &mut session, "login 1025", &mut out);
        for spec in &TABLE {
            if spec.id == CommandId::Login {
                continue;
            }
            let r = reply(&mut s, &mut session, spec.name(), &mut out);
            let mut head = Text::<48>::new();
            write!(head, ",\"cmd\":{},", u8::from(spec.id)).unwrap();
            assert!(
                r.starts_with("{\"ret\":") && r.contains(head.as_str()) && r.ends_with('}'),
                "{}",
                spec.name()
            );
        }
    }

    /// The stack the core needs to handle one frame, measured by painting:
    /// the deepest of a mix of frames that reach every part of the path.
    #[test]
    fn frame_handling_stack_high_water_mark() {
        let mut s = server();
        let mut session = Session::new();
        let mut out = [0u8; 2048];
        let mission = concat!(
            r#"mission 1001:{"waypoints":[{"x":1.5,"y":-2,"z":-3,"yaw":0.1},{"x":2,"y":2,"z":-3},"#,
            r#"{"x":3,"y":[1,[2,[3,[4,{"deep":[5,6,{"a":"\u00e9\n"}]}]]]],"z":-3}],"meta":{"k":[true,false,null]}}"#
        );
        let frames = [
            "login 1025",
            "help",
            "state",
            "set_sp_ned 1.0:2.0:-3.0:0.5",
            "zyhk 1.5,2.5,3.5 1,2,0.3",
            "mw_exec 1001:1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18,19,20",
            mission,
            "relocate_pos 1,2,3,0.5",
            "set_param speed:1.5",
            "passwd n3w-Secret",
            "fly_to_the_moon",
            "set_sp_ned 1:2:NaN:0",
            "admin_lock",
        ];
        let mut deepest = 0;
        for frame in frames {
            let sp = stack::paint();
            let _ = s.handle(&mut session, Message::Text(frame.as_bytes()), &mut out);
            let used = stack::used_since(sp);
            defmt::println!(
                "stack: {=usize} bytes for `{=str}`",
                used,
                &frame[..frame.len().min(24)]
            );
            deepest = deepest.max(used);
        }
        defmt::println!("frame-handling stack high-water mark: {=usize} bytes", deepest);
        assert!(deepest > 0 && deepest < 16 * 1024);
    }
}
