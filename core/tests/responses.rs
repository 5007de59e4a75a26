//! Response writing: exact framing, escaping, the size limit, backend
//! failures and the WebSocket close policy.

mod common;

use common::*;
use lluav_core::{
    Auth, Backend, CloseCode, Command, Context, Failure, Fields, MIN_RESPONSE_CAPACITY, Message, Outcome,
    Ret, Server, Session, Step,
};

#[test]
fn a_success_is_one_object_with_ret_cmd_ts_first() {
    let mut s = server(None);
    let mut sess = Session::new();
    let mut out = [0u8; 512];
    let reply = s.handle(&mut sess, Message::Text(b"set_sp_ned 1.0:2.0:-3.0:0.5"), &mut out);
    assert_eq!(
        reply,
        Outcome::Reply(r#"{"ret":0,"cmd":23,"ts":1714233600000,"x":1.0,"y":2.0,"z":-3.0,"yaw":0.5}"#)
    );
}

#[test]
fn the_spec_example_error_is_reproduced_byte_for_byte() {
    let mut s = server(None);
    s.backend_mut().armed = true;
    let mut sess = Session::new();
    let mut out = [0u8; 256];
    assert_eq!(
        s.handle(&mut sess, Message::Text(b"siyi_format"), &mut out),
        Outcome::Reply(r#"{"ret":-1,"cmd":52,"ts":1714233600000,"msg":"Not allow when vehicle is ARMED!"}"#)
    );
}

/// A backend that echoes awkward strings back in keys and values.
struct Echo;

impl Backend for Echo {
    fn armed(&self) -> bool {
        false
    }
    fn execute(&mut self, cmd: &Command<'_>, _: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let lluav_core::Args::Text(t) = cmd.args() else {
            return Err(Failure::unsupported("text only"));
        };
        out.str(t, t)
            .object("nested", |o| {
                o.str("k\"ey", "v\\al")
                    .str("ctl", "\u{8}\u{c}\u{1f}\n\t\r\0")
                    .f32("nan", f32::NAN)
                    .f64("big", 1e300)
                    .f64("tiny", -2.5e-9)
                    .f64("small", 2.5e-6)
                    .f32("noise", 3.330_669e-16)
                    .f32("edge", -1e-6);
                o.array("list", |a| {
                    a.u64(u64::MAX)
                        .i64(i64::MIN)
                        .bool(true)
                        .null()
                        .str("\u{7f}\u{2028}");
                    a.object(|o| {
                        o.u64("deep", 1);
                    });
                    a.array(|_| {});
                });
            })
            .object("empty", |_| {})
            .serialize(
                "serde",
                &Sample {
                    name: "ö\"\n",
                    ok: true,
                    values: [1.5, -0.0],
                },
            );
        Ok(Step::Done)
    }
}

#[derive(serde::Serialize)]
struct Sample<'a> {
    name: &'a str,
    ok: bool,
    values: [f32; 2],
}

#[test]
fn strings_keys_and_numbers_are_escaped_into_valid_json() {
    let clock = || -5_i64;
    let mut s = Server::new(Echo, clock, Auth::new(None).unwrap());
    let mut sess = Session::new();
    let mut out = [0u8; 1024];
    let text = "plan q\"uo\\te é — 🚁 </script>";
    let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(text.as_bytes()), &mut out) else {
        panic!("expected a reply")
    };
    let v = checked_json(r);
    let t = &text["plan ".len()..];
    assert_eq!(v["ts"], -5);
    assert_eq!(v[t], t);
    assert_eq!(v["nested"]["k\"ey"], "v\\al");
    assert_eq!(v["nested"]["nan"], serde_json::Value::Null);
    assert_eq!(v["nested"]["big"], 1e300);
    // No float noise: within 1e-6 of zero is 0 (DESIGN.md).
    assert_eq!(v["nested"]["tiny"], 0.0);
    assert_eq!(v["nested"]["noise"], 0.0);
    assert_eq!(v["nested"]["edge"], 0.0);
    assert_eq!(v["nested"]["small"], 2.5e-6);
    assert_eq!(
        v["nested"]["list"],
        serde_json::json!([u64::MAX, i64::MIN, true, null, "\u{7f}\u{2028}", {"deep": 1}, []])
    );
    assert_eq!(v["empty"], serde_json::json!({}));
    assert_eq!(
        v["serde"],
        serde_json::json!({"name": "ö\"\n", "ok": true, "values": [1.5, -0.0]})
    );
    assert_eq!(v["nested"]["ctl"], "\u{8}\u{c}\u{1f}\n\t\r\0");
    assert!(r.contains(r#""ctl":"\u0008\u000c\u001f\n\t\r\u0000""#), "{r}");
}

#[test]
fn fields_that_do_not_fit_are_replaced_by_response_too_large() {
    let mut s = server(None);
    s.backend_mut().filler = 100;
    let mut sess = Session::new();
    let mut out = [0u8; 600];
    let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(b"state"), &mut out) else {
        panic!("expected a reply")
    };
    assert_eq!(
        r,
        r#"{"ret":-1,"cmd":2,"ts":1714233600000,"msg":"Response too large"}"#
    );
}

#[test]
fn a_response_that_exactly_fits_is_kept_and_one_byte_less_is_too_large() {
    let mut s = server(None);
    let mut sess = Session::new();
    let mut big = vec![0u8; 4096];
    let Outcome::Reply(full) = s.handle(&mut sess, Message::Text(b"state"), &mut big) else {
        panic!()
    };
    let full = full.to_owned();
    // The response is assembled behind room reserved for the head, so the
    // buffer needs that slack on top of the final length.
    let mut n = full.len();
    let fits = loop {
        let mut out = vec![0u8; n];
        if let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(b"state"), &mut out)
            && r == full
        {
            break n;
        }
        n += 1;
        assert!(n < full.len() + 64, "never fitted");
    };
    let mut out = vec![0u8; fits - 1];
    let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(b"state"), &mut out) else {
        panic!()
    };
    checked_json(r);
    assert!(r.contains("Response too large"), "{r}");
}

#[test]
fn every_error_fits_the_minimum_capacity_and_a_smaller_buffer_closes_1011() {
    let mut s = server(Some("pw"));
    let mut sess = Session::new();
    let worst = "\u{1}".repeat(40);
    let mut out = vec![0u8; MIN_RESPONSE_CAPACITY];
    send(&mut s, &mut sess, "login pw");
    let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(worst.as_bytes()), &mut out) else {
        panic!("the worst unknown-name error must fit MIN_RESPONSE_CAPACITY")
    };
    assert_eq!(
        checked_json(r)["msg"],
        format!("Unsupported command: {}", "\u{1}".repeat(32))
    );
    let mut tiny = [0u8; 16];
    assert_eq!(
        s.handle(&mut sess, Message::Text(b"state"), &mut tiny),
        Outcome::Close(CloseCode::InternalError)
    );
}

#[test]
fn backend_failures_discard_partial_fields_and_carry_their_code() {
    let cases = [
        (Failure::failed("No mission loaded"), -1, "No mission loaded"),
        (Failure::unsupported("Not on this board"), -2, "Not on this board"),
        (Failure::system("statvfs failed: EIO"), -3, "statvfs failed: EIO"),
        (Failure::unhandled(), -100, "Unhandled exception"),
    ];
    for (failure, ret, msg) in cases {
        let mut s = server(None);
        s.backend_mut().fail_with = Some(failure);
        let mut sess = Session::new();
        let r = send(&mut s, &mut sess, "capture");
        assert_eq!((r.ret(), r.cmd(), r.msg()), (ret, 47, msg));
        assert!(r.json().get("partial").is_none(), "partial fields leaked: {r:?}");
    }
}

#[test]
fn failure_messages_are_cut_at_a_char_boundary() {
    let long = "é".repeat(100);
    let f = Failure::new(Ret::Failed, &long);
    assert_eq!(f.msg(), "é".repeat(48));
    let f = Failure::fmt(
        Ret::SystemCall,
        format_args!("disk {} failed: {}", "sda", "x".repeat(200)),
    );
    assert_eq!(f.msg().len(), lluav_core::error::FAILURE_MSG_CAPACITY);
    assert!(f.msg().starts_with("disk sda failed: xxx"));
}

#[test]
fn websocket_close_policy_follows_design() {
    let mut s = server(None);
    let mut sess = Session::new();
    assert_eq!(
        send_bytes(&mut s, &mut sess, Message::Binary(b"state")),
        Seen::Close(1003)
    );
    assert_eq!(
        send_bytes(&mut s, &mut sess, Message::Text(b"state \xff")),
        Seen::Close(1007)
    );
    assert_eq!(
        send_bytes(&mut s, &mut sess, Message::Oversized),
        Seen::Close(1009)
    );
    assert!(s.backend().executed.is_empty());
}

#[test]
fn help_lists_every_command_of_the_table() {
    let mut s = server(None);
    let mut sess = Session::new();
    let r = send(&mut s, &mut sess, "help");
    let names: Vec<&str> = r.json()["commands"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let table: Vec<&str> = lluav_core::TABLE.iter().map(|s| s.name()).collect();
    assert_eq!(names, table);
}

#[test]
fn help_fits_the_2_kib_mcu_response_buffer() {
    let mut s = server(None);
    let mut sess = Session::new();
    let mut out = [0u8; 2048];
    let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(b"help"), &mut out) else {
        panic!()
    };
    assert_eq!(checked_json(r)["ret"], 0);
}

#[test]
fn the_minimum_capacity_is_the_documented_270_bytes() {
    assert_eq!(MIN_RESPONSE_CAPACITY, 270, "README.md states this figure");
}

#[test]
fn integers_are_written_exactly_across_the_whole_range() {
    struct Ints(Vec<u64>);
    impl Backend for Ints {
        fn armed(&self) -> bool {
            false
        }
        fn execute(&mut self, _: &Command<'_>, _: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
            out.array("u", |a| {
                for v in &self.0 {
                    a.u64(*v);
                }
            })
            .array("i", |a| {
                for v in &self.0 {
                    a.i64(*v as i64);
                }
            });
            Ok(Step::Done)
        }
    }
    let mut values = vec![
        0,
        1,
        9,
        10,
        99,
        100,
        101,
        4_294_967_295,
        4_294_967_296,
        100_000_000,
        1_714_233_600_000,
    ];
    values.extend([
        u64::MAX,
        u64::MAX - 1,
        i64::MAX as u64,
        i64::MIN as u64,
        10_000_000_000_000_000_000,
    ]);
    values.extend((0..20).map(|e| 10u64.pow(e)));
    values.extend((0..20).map(|e| 10u64.pow(e) - 1));
    values.extend((0..64).map(|b| 1u64 << b));
    for ts in [0, -1, i64::MIN, i64::MAX, 1_714_233_600_000] {
        let mut s = Server::new(Ints(values.clone()), move || ts, Auth::new(None).unwrap());
        let mut sess = Session::new();
        let mut out = vec![0u8; 8192];
        let Outcome::Reply(r) = s.handle(&mut sess, Message::Text(b"state"), &mut out) else {
            panic!()
        };
        let v = checked_json(r);
        assert_eq!(v["ts"].as_i64(), Some(ts));
        let u: Vec<u64> = serde_json::from_value(v["u"].clone()).unwrap();
        let i: Vec<i64> = serde_json::from_value(v["i"].clone()).unwrap();
        assert_eq!(u, values);
        assert_eq!(i, values.iter().map(|v| *v as i64).collect::<Vec<_>>());
    }
}

/// Writes -0 as an `f32` and an `f64`, alone and in an array.
struct NegativeZero;

impl Backend for NegativeZero {
    fn armed(&self) -> bool {
        false
    }

    fn execute(&mut self, _: &Command<'_>, _: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        out.f32("pitch", -0.0).f64("roll", -0.0).array("both", |a| {
            a.f32(-0.0).f64(-0.0).f32(-1.5);
        });
        Ok(Step::Done)
    }
}

#[test]
fn minus_zero_is_written_as_zero() {
    let mut s = Server::new(NegativeZero, || 0, Auth::new(None).unwrap());
    let mut out = [0u8; 256];
    let reply = s.handle(&mut Session::new(), Message::Text(b"lidarpose"), &mut out);
    assert_eq!(
        reply,
        Outcome::Reply(r#"{"ret":0,"cmd":11,"ts":0,"pitch":0.0,"roll":0.0,"both":[0.0,0.0,-1.5]}"#)
    );
}
