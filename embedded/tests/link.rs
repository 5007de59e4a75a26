//! The adapter served on one embassy-net stack, driven over an in-memory
//! Ethernet link by a WebSocket client on a second stack.

mod support;

use embassy_futures::select::{Either, select};
use embassy_net::tcp::ConnectError;
use embassy_time::Timer;
use lluav_embedded::Config;
use serde_json::json;
use support::{
    Client, KEY, PASSWORD, SESSIONS, join_all, op, protocol_server, upgrade_request, with_server,
    with_service, with_world,
};

#[test]
fn login_gates_every_command_then_serves_it() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        let r = c.call("state").await;
        assert_eq!(
            (r["ret"].as_i64(), r["cmd"].as_i64(), r["msg"].as_str()),
            (Some(-1), Some(2), Some("Login first!"))
        );
        let r = c.call(&format!("login {PASSWORD}")).await;
        assert_eq!(
            (r["ret"].as_i64(), r["logged_in"].as_bool()),
            (Some(0), Some(true))
        );
        let r = c.call("state").await;
        assert_eq!(
            r["state"],
            json!({"armed": false, "fsm": "disarmed", "lock_mode": false})
        );
        assert_eq!(c.close(1000).await, 1000);
    });
}

#[test]
fn armed_vehicle_refuses_reboot_but_lands() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.call(&format!("login {PASSWORD}")).await;
        assert_eq!(c.call("takeoff").await["ret"], 0);
        let r = c.call("reboot_system").await;
        assert_eq!(
            (r["ret"].as_i64(), r["msg"].as_str()),
            (Some(-1), Some("Not allow when vehicle is ARMED!"))
        );
        assert_eq!(c.call("land").await["ret"], 0);
        assert_eq!(c.call("state").await["state"]["armed"], false);
    });
}

/// `takeoff` in the test vehicle waits for its autopilot (it answers
/// pending for about 100 ms): its answer comes once the backend finishes,
/// and another session is served meanwhile.
#[test]
fn a_pending_command_is_answered_when_the_backend_finishes_and_others_go_on() {
    with_world(protocol_server(), Config::new(), |[a, b, _, _]| async move {
        let mut pilot = Client::connect(a).await;
        let mut watcher = Client::connect(b).await;
        for c in [&mut pilot, &mut watcher] {
            assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
        }
        pilot.send("takeoff").await;
        let first = select(pilot.recv(), watcher.call("state")).await;
        let Either::Second(state) = first else {
            panic!("the pending takeoff was answered before another session's state");
        };
        assert_eq!(state["state"]["armed"], false);
        let r = pilot.recv().await.text();
        assert_eq!(
            (r["ret"].as_i64(), r["armed"].as_bool()),
            (Some(0), Some(true)),
            "{r}"
        );
        assert_eq!(watcher.call("state").await["state"]["armed"], true);
        // The pilot's session goes on after its pending command.
        assert_eq!(pilot.call("land").await["ret"], 0);
    });
}

#[test]
fn admin_lock_is_admin_only_and_vehicle_wide() {
    with_server(|stack| async move {
        let mut user = Client::connect(stack).await;
        let mut admin = Client::connect(stack).await;
        user.call(&format!("login {PASSWORD}")).await;
        assert_eq!(user.call("admin_lock").await["msg"], "Admin only!");
        assert_eq!(admin.call("login 1025").await["admin"], true);
        assert_eq!(admin.call("admin_lock").await["lock_mode"], true);
        let r = user.call("set_param speed:1").await;
        assert_eq!(r["msg"], "CMD not permitted to run in LOCK mode!");
        assert_eq!(user.call("state").await["state"]["lock_mode"], true);
    });
}

#[test]
fn unknown_and_malformed_commands_get_error_responses() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.call(&format!("login {PASSWORD}")).await;
        let r = c.call("fly_to_the_moon").await;
        assert_eq!((r["ret"].as_i64(), r["cmd"].as_i64()), (Some(-2), Some(0)));
        assert_eq!(r["msg"], "Unsupported command: fly_to_the_moon");
        let r = c.call("set_sp_ned 1:2:NaN:0").await;
        assert_eq!(r["msg"], "Invalid arguments, usage: set_sp_ned x:y:z:yaw");
        assert_eq!(c.call("ledpwm 700").await["pwm"], 700);
        assert_eq!(c.call("   ").await["msg"], "Empty command");
    });
}

#[test]
fn binary_message_closes_with_1003() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.frame(true, op::BINARY, b"\x01\x02").await;
        assert_eq!(c.recv().await.close_code(), 1003);
    });
}

#[test]
fn invalid_utf8_closes_with_1007() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.frame(true, op::TEXT, b"state \xff\xfe").await;
        assert_eq!(c.recv().await.close_code(), 1007);
    });
}

#[test]
fn message_over_the_frame_limit_closes_with_1009() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.send(&"x".repeat(support::FRAME + 1)).await;
        assert_eq!(c.recv().await.close_code(), 1009);
    });
}

#[test]
fn fragments_adding_up_past_the_limit_close_with_1009() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.frame(false, op::TEXT, "y".repeat(support::FRAME - 10).as_bytes())
            .await;
        c.frame(true, op::CONTINUATION, &[b'y'; 11]).await;
        assert_eq!(c.recv().await.close_code(), 1009);
    });
}

#[test]
fn fifth_wrong_password_is_answered_then_closed_with_1008() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        for _ in 0..4 {
            assert_eq!(c.call("login nope").await["msg"], "Wrong password!");
        }
        assert_eq!(c.call("login nope").await["msg"], "Wrong password!");
        assert_eq!(c.recv().await.close_code(), 1008);
    });
}

#[test]
fn ping_is_answered_with_pong_carrying_its_payload() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.frame(true, op::PING, b"are you there").await;
        let pong = c.recv().await;
        assert_eq!(
            (pong.opcode, pong.payload.as_slice()),
            (op::PONG, &b"are you there"[..])
        );
    });
}

#[test]
fn fragmented_text_is_reassembled_around_a_ping() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.frame(false, op::TEXT, b"log").await;
        c.frame(true, op::PING, b"p").await;
        c.frame(false, op::CONTINUATION, b"in ").await;
        c.frame(true, op::CONTINUATION, PASSWORD.as_bytes()).await;
        assert_eq!(c.recv().await.opcode, op::PONG);
        assert_eq!(c.recv().await.text()["logged_in"], true);
    });
}

#[test]
fn continuation_without_a_message_fails_with_1002() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.frame(true, op::CONTINUATION, b"state").await;
        assert_eq!(c.recv().await.close_code(), 1002);
    });
}

#[test]
fn unmasked_frame_fails_with_1002() {
    with_server(|stack| async move {
        let mut c = Client::connect(stack).await;
        c.raw(b"\x81\x05state").await;
        assert_eq!(c.recv().await.close_code(), 1002);
    });
}

/// RFC 6455, section 5.2: "the minimal number of bytes MUST be used to
/// encode the length". A 3-byte frame sent with a 16-bit length, and a
/// 200-byte one with a 64-bit length, fail with 1002; the board serves on.
#[test]
fn lengths_not_in_their_minimal_form_fail_with_1002() {
    with_server(|stack| async move {
        let mask = [1, 2, 3, 4];
        let short = [&[0x81, 0x80 | 126, 0, 3][..], &mask, b"abc"].concat();
        let medium = [
            &[0x81, 0x80 | 127, 0, 0, 0, 0, 0, 0, 0, 200][..],
            &mask,
            &[b'a'; 200],
        ]
        .concat();
        for frame in [short, medium] {
            let mut c = Client::connect(stack).await;
            c.raw(&frame).await;
            assert_eq!(c.recv().await.close_code(), 1002);
            assert!(c.closed().await);
        }
        let mut c = Client::connect(stack).await;
        assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
    });
}

#[test]
fn close_with_invalid_code_is_answered_with_1002() {
    with_server(|stack| async move {
        let c = Client::connect(stack).await;
        assert_eq!(c.close(1005).await, 1002);
    });
}

/// embedded-websocket 0.9.5 would panic on an over-long key or protocol
/// (24-byte heapless strings with an unwrap) if it read the request: the
/// core's upgrade check stays in front, so a bad key gets 400, an offered
/// protocol of any length is ignored (none is selected), and the board
/// keeps serving.
#[test]
fn overlong_keys_get_400_offered_protocols_are_ignored_and_the_board_keeps_serving() {
    with_server(|stack| async move {
        let long_key = format!("Sec-WebSocket-Key: {KEY}{KEY}\r\n");
        let odd_key = "Sec-WebSocket-Key: not base64 at all!!!!!!\r\n".to_string();
        for extra in [long_key, odd_key, String::new()] {
            let mut c = Client::tcp(stack).await;
            let head = c.request(&upgrade_request(&extra)).await;
            assert!(head.starts_with("HTTP/1.1 400 "), "{extra}: {head}");
            assert!(c.closed().await);
        }
        let long_protocol =
            format!("Sec-WebSocket-Key: {KEY}\r\nSec-WebSocket-Protocol: lluav-protocol-name-over-24\r\n");
        let mut c = Client::tcp(stack).await;
        let head = c.request(&upgrade_request(&long_protocol)).await;
        assert!(head.starts_with("HTTP/1.1 101 "), "{head}");
        assert!(!head.contains("Sec-WebSocket-Protocol"), "{head}");
        assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
    });
}

#[test]
fn request_head_longer_than_the_adapter_reads_gets_431() {
    with_server(|stack| async move {
        let mut c = Client::tcp(stack).await;
        let filler: String = (0..40)
            .map(|i| format!("X-Filler-{i}: {}\r\n", "f".repeat(40)))
            .collect();
        let head = c
            .request(&upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n{filler}")))
            .await;
        assert!(head.starts_with("HTTP/1.1 431 "), "{head}");
    });
}

#[test]
fn concurrent_sessions_keep_their_own_login() {
    with_world(protocol_server(), Config::new(), |clients| async move {
        // One session per address; the last one never logs in. (A session
        // that has not logged in may be evicted when a newcomer takes the
        // last free slot, so the logged-in ones come first.)
        let mut sessions = Vec::new();
        for (i, stack) in clients.into_iter().enumerate() {
            let mut c = Client::connect(stack).await;
            if i + 1 < SESSIONS {
                assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
            }
            sessions.push(c);
        }
        let calls = sessions.iter_mut().enumerate().map(|(i, c)| async move {
            for _ in 0..5 {
                let r = c.call("state").await;
                let expected = if i + 1 < SESSIONS { 0 } else { -1 };
                assert_eq!(r["ret"], expected, "session {i}: {r}");
            }
        });
        join_all(calls).await;
        for c in sessions {
            assert_eq!(c.close(1000).await, 1000);
        }
    });
}

#[test]
fn a_connection_beyond_the_slots_is_refused_until_one_frees_up() {
    with_world(protocol_server(), Config::new(), |clients| async move {
        let mut busy = Vec::new();
        for stack in clients {
            let mut c = Client::connect(stack).await;
            assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
            busy.push(c);
        }
        // Every slot holds a logged-in session: nothing listens, nothing
        // may be evicted.
        assert_eq!(
            Client::try_tcp(clients[0]).await.err(),
            Some(ConnectError::ConnectionReset)
        );
        assert_eq!(busy.remove(0).close(1000).await, 1000);
        // The freed slot listens again once its socket is torn down: poll for it.
        let mut late = None;
        for _ in 0..100 {
            if let Ok(c) = Client::try_tcp(clients[0]).await {
                late = Some(c);
                break;
            }
            Timer::after_millis(50).await;
        }
        let mut late = late.expect("the freed slot accepts again");
        let head = late
            .request(&upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n")))
            .await;
        assert!(head.starts_with("HTTP/1.1 101 "), "{head}");
        assert_eq!(late.call(&format!("login {PASSWORD}")).await["ret"], 0);
    });
}

#[test]
fn echo_service_echoes_text_on_the_same_connection_code() {
    with_service(lluav_embedded::Echo, |stack| async move {
        let mut c = Client::connect(stack).await;
        c.send("hello, \u{1F6F8}").await;
        let f = c.recv().await;
        assert_eq!(
            (f.opcode, f.payload.as_slice()),
            (op::TEXT, "hello, \u{1F6F8}".as_bytes())
        );
    });
}
