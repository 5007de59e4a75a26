//! What every adapter does alike, at the MCU's limits (a 4 KiB message):
//! the login, admin and lock gates, one answer per request and in order,
//! the lockout of an address that guessed, the WebSocket rules and the
//! upgrade's Origin and Host policy, and a soak of 10,000 requests.
//!
//! In the workspace's tests they run against lluavd (`--max-message 4096`);
//! with `LLUAV_TEST_BOARD` set, against the firmware on the emulated
//! Cortex-M7 board (the MCU adapter, embassy-net and our LAN9118 driver;
//! see `lluav_tests::target` and `embedded/scripts/board-tests.sh`). Each
//! test starts its own server. Rules about the client's address beyond the
//! lockout stay with the TAP tests of `lluav-embedded`: QEMU's user
//! networking makes every client of the board 10.0.2.2. Answers that depend
//! on the backend (the simulator flies, the board's backend answers that it
//! cannot) are checked for what both share: the command's id, the gates'
//! messages.

use std::time::Instant;

use lluav_core::{CommandId, TABLE};
use lluav_tests::target::{MCU_FRAME_LIMIT, Target};
use lluav_tests::{Conn, Received, WAIT, http_status, sample_args, upgrade_request};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::coding::Data;

const LOCKED: &str = "CMD not permitted to run in LOCK mode!";

fn msg(r: &Value) -> &str {
    r["msg"].as_str().unwrap_or("")
}

#[tokio::test]
async fn the_login_gate_comes_first_and_the_admin_and_lock_gates_hold_across_sessions() {
    let t = Target::start();
    let mut user = Conn::connect(&t.url).await;
    let r = user.request("state").await;
    assert_eq!(
        (r["ret"].as_i64(), r["cmd"].as_i64(), msg(&r)),
        (Some(-1), Some(2), "Login first!")
    );
    let r = user.request("no_such_command").await;
    assert_eq!((r["cmd"].as_i64(), msg(&r)), (Some(0), "Login first!"));
    let r = user.request("login wrong").await;
    assert_eq!((r["ret"].as_i64(), msg(&r)), (Some(-1), "Wrong password!"));
    let r = user.request(&format!("login {}", t.password)).await;
    assert_eq!(
        (r["ret"].as_i64(), &r["logged_in"], &r["admin"]),
        (Some(0), &Value::Bool(true), &Value::Bool(false))
    );
    let r = user.request("admin_lock").await;
    assert_eq!((r["ret"].as_i64(), msg(&r)), (Some(-1), "Admin only!"));

    let mut admin = Conn::login(&t.url, "1025").await;
    let r = admin.request("admin_lock").await;
    assert_eq!(
        (r["ret"].as_i64(), &r["lock_mode"]),
        (Some(0), &Value::Bool(true))
    );
    // Lock mode is vehicle-wide: the user's session sees it.
    let r = user.request("set_param takeoff_alt:3").await;
    assert_eq!((r["ret"].as_i64(), msg(&r)), (Some(-1), LOCKED));
    let r = user.request("state").await;
    assert_eq!(r["state"]["lock_mode"], true, "{r}");
    let r = admin.request("set_param takeoff_alt:3").await;
    assert_ne!(msg(&r), LOCKED, "admins skip the lock gate: {r}");

    let r = admin.request("admin_unlock").await;
    assert_eq!(
        (r["ret"].as_i64(), &r["lock_mode"]),
        (Some(0), &Value::Bool(false))
    );
    let r = user.request("set_param takeoff_alt:4").await;
    assert_ne!(msg(&r), LOCKED, "{r}");
    let r = user.request("login 0315").await;
    assert_eq!(
        (r["ret"].as_i64(), &r["logged_in"]),
        (Some(0), &Value::Bool(false))
    );
    let r = user.request("state").await;
    assert_eq!(msg(&r), "Login first!");
    user.close().await;
    admin.close().await;
}

#[tokio::test]
async fn every_command_of_the_table_gets_exactly_one_answer_of_its_own() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, "1025").await;
    for spec in &TABLE {
        let args = sample_args(spec.grammar);
        let frame = if args.is_empty() {
            spec.name().to_owned()
        } else {
            format!("{} {args}", spec.name())
        };
        let r = c.request(&frame).await;
        assert_eq!(
            r["cmd"].as_i64(),
            Some(i64::from(u8::from(spec.id))),
            "`{frame}`: {r}"
        );
        assert!(!msg(&r).starts_with("Invalid arguments, usage"), "`{frame}`: {r}");
        assert_ne!(r["ret"], -100, "`{frame}` hit a fault: {r}");
        assert_ne!(msg(&r), "Response too large", "`{frame}`: {r}");
        if spec.id == CommandId::Help {
            let names: Vec<&str> = TABLE.iter().map(|s| s.name()).collect();
            assert_eq!(r["commands"], serde_json::json!(names), "help lists the table");
        }
        if spec.id == CommandId::State {
            for key in ["armed", "fsm", "lock_mode"] {
                assert!(!r["state"][key].is_null(), "state has `{key}`: {r}");
            }
        }
        // Keep the vehicle on the ground and awake, so that the next
        // command reaches the backend rather than a gate.
        let s = c.request("state").await;
        if s["state"]["armed"] == true {
            assert_eq!(c.request("disarm").await["ret"], 0);
        }
        if s["state"]["fsm"] == "sleep" {
            assert_eq!(c.request("wakeup").await["ret"], 0);
        }
    }
    let r = c.request("ver").await;
    assert_eq!(r["cmd"], u8::from(CommandId::Ver), "nothing more arrived: {r}");
    c.close().await;
}

/// On a board each reply after the first of a burst waits for the peer to
/// acknowledge the one before (the transmit buffer holds one 2 KiB reply),
/// which a peer delaying its ACKs makes slow (QEMU's user networking: 200
/// ms): a few rounds prove the order.
#[tokio::test]
async fn pipelined_requests_are_answered_in_order() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, &t.password).await;
    let frames = [
        "state",
        "ver",
        "param",
        "get_param takeoff_alt",
        "show_sp",
        "help",
        "nonsense",
        "machineid",
    ];
    let expected: Vec<i64> = vec![2, 5, 3, 4, 15, 97, 0, 9];
    for round in 0..5 {
        for f in frames {
            c.send(f).await;
        }
        let mut got = Vec::new();
        for _ in frames {
            got.push(c.response().await["cmd"].as_i64().unwrap_or(-1));
        }
        assert_eq!(got, expected, "round {round}");
    }
    c.close().await;
}

#[tokio::test]
async fn five_wrong_passwords_close_the_session_with_1008_and_lock_the_address_out() {
    let t = Target::start();
    let mut c = Conn::connect(&t.url).await;
    for _ in 0..5 {
        let r = c.request("login guess").await;
        assert_eq!(r["msg"], "Wrong password!", "{r}");
    }
    assert_eq!(c.close_code().await, Some(1008));
    // The address is locked out across connections: even the right
    // password is not checked.
    let mut again = Conn::connect(&t.url).await;
    let r = again.request(&format!("login {}", t.password)).await;
    assert_eq!(
        (r["ret"].as_i64(), msg(&r)),
        (Some(-1), "Too many wrong passwords, retry later"),
        "{r}"
    );
    assert!(
        r["retry_after_s"].as_u64().is_some_and(|s| s > 0),
        "says when: {r}"
    );
}

#[tokio::test]
async fn binary_message_closes_with_1003() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, &t.password).await;
    c.send_raw(Message::binary(b"state".to_vec())).await;
    assert_eq!(c.close_code().await, Some(1003));
}

#[tokio::test]
async fn invalid_utf8_closes_with_1007() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, &t.password).await;
    c.send_text_frame(b"state \xff\xfe", Data::Text, true).await;
    assert_eq!(c.close_code().await, Some(1007));
}

#[tokio::test]
async fn a_message_at_the_limit_is_answered_and_one_byte_more_closes_with_1009() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, &t.password).await;
    // Trailing spaces are not part of the command.
    let at_limit = format!("{:<width$}", "state", width = MCU_FRAME_LIMIT);
    let r = c.request(&at_limit).await;
    assert_eq!((r["ret"].as_i64(), r["cmd"].as_i64()), (Some(0), Some(2)), "{r}");
    c.send(&format!("{at_limit} ")).await;
    assert_eq!(c.close_code().await, Some(1009));
}

#[tokio::test]
async fn a_fragmented_message_over_the_limit_closes_with_1009() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, &t.password).await;
    let chunk = [b' '; 2000];
    c.send_text_frame(b"state", Data::Text, false).await;
    c.send_text_frame(&chunk, Data::Continue, false).await;
    c.send_text_frame(&chunk, Data::Continue, false).await;
    c.send_text_frame(&chunk, Data::Continue, true).await;
    assert_eq!(c.close_code().await, Some(1009));
}

#[tokio::test]
async fn fragmented_text_is_reassembled_into_one_request_around_a_ping() {
    let t = Target::start();
    let mut c = Conn::login(&t.url, &t.password).await;
    c.send_text_frame(b"set_sp", Data::Text, false).await;
    c.send_raw(Message::Ping(b"mid".to_vec().into())).await;
    c.send_text_frame(b"_ned 1.0:2.0", Data::Continue, false).await;
    c.send_text_frame(b":-3.0:0.5", Data::Continue, true).await;
    assert_eq!(c.recv().await, Received::Pong(b"mid".to_vec()));
    let r = c.response().await;
    assert_eq!(r["cmd"].as_i64(), Some(23), "{r}");
    assert!(!msg(&r).starts_with("Invalid arguments, usage"), "{r}");
}

#[tokio::test]
async fn ping_gets_pong_with_the_same_payload_before_login() {
    let t = Target::start();
    let mut c = Conn::connect(&t.url).await;
    let payload = vec![b'p'; 125];
    c.send_raw(Message::Ping(payload.clone().into())).await;
    assert_eq!(c.recv().await, Received::Pong(payload));
    let r = c.request(&format!("login {}", t.password)).await;
    assert_eq!(r["ret"], 0, "{r}");
}

#[tokio::test]
async fn client_close_is_answered_with_a_close() {
    let t = Target::start();
    let mut c = Conn::connect(&t.url).await;
    c.send_raw(Message::Close(None)).await;
    assert!(
        matches!(c.recv().await, Received::Close(_)),
        "the server completes the handshake"
    );
}

#[tokio::test]
async fn a_stalled_client_does_not_delay_another_session() {
    let t = Target::start();
    let mut stalled = Conn::login(&t.url, &t.password).await;
    // Half a message that never completes.
    stalled.send_text_frame(b"sta", Data::Text, false).await;
    let mut other = Conn::login(&t.url, &t.password).await;
    for _ in 0..50 {
        let r = other.request("state").await;
        assert_eq!(r["ret"], 0, "{r}");
    }
}

/// RFC 6455, 5.2: lengths in their minimal form. A 3-byte frame with a
/// 16-bit length and a 200-byte one with a 64-bit length close with 1002
/// (no WebSocket library sends them: hand-made frames after a hand-made
/// upgrade).
#[tokio::test]
async fn lengths_not_in_their_minimal_form_close_with_1002() {
    let t = Target::start();
    let mask = [1, 2, 3, 4];
    let short = [&[0x81, 0x80 | 126, 0, 3][..], &mask, b"abc"].concat();
    let medium = [
        &[0x81, 0x80 | 127, 0, 0, 0, 0, 0, 0, 0, 200][..],
        &mask,
        &[b'a'; 200],
    ]
    .concat();
    for frame in [short, medium] {
        let mut tcp = TcpStream::connect(t.addr).await.expect("TCP connect");
        tcp.write_all(upgrade_request(t.addr, "").as_bytes())
            .await
            .expect("upgrade written");
        let mut got = Vec::new();
        let mut buf = [0u8; 1024];
        let read = async {
            // The 101's head, then the close frame: 2 bytes and the code.
            loop {
                let head = got.windows(4).position(|w| w == b"\r\n\r\n").map(|i| i + 4);
                match head {
                    Some(end) if got.len() >= end + 4 => return end,
                    Some(end) if got.len() == end => tcp.write_all(&frame).await.expect("frame written"),
                    _ => {}
                }
                match tcp.read(&mut buf).await {
                    Ok(0) | Err(_) => panic!("closed early: {:?}", String::from_utf8_lossy(&got)),
                    Ok(n) => got.extend_from_slice(&buf[..n]),
                }
            }
        };
        let end = tokio::time::timeout(WAIT, read).await.expect("answers in time");
        assert!(
            got.starts_with(b"HTTP/1.1 101 "),
            "{:?}",
            String::from_utf8_lossy(&got)
        );
        assert_eq!(
            got[end..end + 4],
            [0x88, 2, 0x03, 0xea],
            "a close frame with 1002"
        );
    }
}

#[tokio::test]
async fn upgrades_by_loopback_names_or_from_the_servers_own_origin_are_accepted() {
    let t = Target::start();
    let (code, answer) = http_status(t.addr, &upgrade_request(t.addr, "")).await;
    assert_eq!(code, 101, "{answer}");
    let own = format!("Origin: http://{}\r\n", t.addr);
    let (code, answer) = http_status(t.addr, &upgrade_request(t.addr, &own)).await;
    assert_eq!(code, 101, "a page served by the vehicle itself: {answer}");
    let localhost = format!("localhost:{}", t.addr.port());
    let request = upgrade_request(t.addr, &format!("Origin: http://{localhost}\r\n"))
        .replace(&format!("Host: {}", t.addr), &format!("Host: {localhost}"));
    let (code, answer) = http_status(t.addr, &request).await;
    assert_eq!(code, 101, "localhost: {answer}");
}

#[tokio::test]
async fn a_foreign_origin_or_a_rebound_host_name_gets_403() {
    let t = Target::start();
    for origin in [
        "https://evil.example",
        "null",
        &format!("http://127.0.0.1:{}", t.addr.port() ^ 1),
    ] {
        let request = upgrade_request(t.addr, &format!("Origin: {origin}\r\n"));
        let (code, answer) = http_status(t.addr, &request).await;
        assert_eq!(code, 403, "Origin {origin}: {answer}");
    }
    let evil = format!("evil.example:{}", t.addr.port());
    let request = upgrade_request(t.addr, &format!("Origin: http://{evil}\r\n"))
        .replace(&format!("Host: {}", t.addr), &format!("Host: {evil}"));
    let (code, answer) = http_status(t.addr, &request).await;
    assert_eq!(code, 403, "{answer}");
}

#[tokio::test]
async fn malformed_upgrades_get_their_http_status_and_plain_http_no_answer_of_the_protocol() {
    let t = Target::start();
    let key = "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==";
    let cases = [
        (
            upgrade_request(t.addr, "").replace("Version: 13", "Version: 7"),
            426,
        ),
        (
            upgrade_request(t.addr, "").replace(key, "Sec-WebSocket-Key: abc"),
            400,
        ),
        (upgrade_request(t.addr, "").replacen("GET", "PUT", 1), 405),
        (
            upgrade_request(t.addr, &format!("X-Junk: {}\r\n", "j".repeat(9000))),
            431,
        ),
        ("GARBAGE\r\n\r\n".to_owned(), 400),
    ];
    for (request, expected) in cases {
        let (code, answer) = http_status(t.addr, &request).await;
        assert_eq!(code, expected, "{answer}");
    }
    let host = t.addr;
    for request in [
        format!("GET /state HTTP/1.1\r\nHost: {host}\r\n\r\n"),
        format!("POST / HTTP/1.1\r\nHost: {host}\r\nContent-Length: 5\r\n\r\nstate"),
    ] {
        let (code, answer) = http_status(t.addr, &request).await;
        assert!((400..500).contains(&code), "{request:?}: {answer}");
        assert!(!answer.contains("\"ret\""), "{answer}");
    }
}

/// The soak: 10,000 requests over 100 connections (a login and 99 `state`
/// and `set_sp_ned`, alternately), every one answered by a response of its
/// own. On the board, the firmware must still be running at the end (a
/// HardFault or a panic ends QEMU), and the stack's high-water mark
/// (painted at boot, read when it is stopped) is reported.
#[tokio::test]
async fn ten_thousand_requests_over_a_hundred_connections_are_all_answered() {
    let t = Target::start();
    let started = Instant::now();
    let mut answered = 0;
    for round in 0..100 {
        let mut c = Conn::login(&t.url, &t.password).await;
        answered += 1;
        for i in 0..99 {
            let (frame, cmd) = if i % 2 == 0 {
                ("state", 2)
            } else {
                ("set_sp_ned 1.0:2.0:-3.0:0.5", 23)
            };
            let r = c.request(frame).await;
            assert_eq!(r["cmd"], cmd, "connection {round}, request {i}: {r}");
            answered += 1;
        }
        c.close().await;
    }
    assert_eq!(answered, 10_000);
    let elapsed = started.elapsed();
    eprintln!(
        "soak: {answered} requests over 100 connections in {:.1} s ({:.0} µs a request)",
        elapsed.as_secs_f64(),
        elapsed.as_secs_f64() * 1e6 / f64::from(answered)
    );
    if let Some((status, log)) = t.stop() {
        for fault in ["HardFault", "panicked", "halted", "QEMU ended"] {
            assert!(!log.contains(fault), "the firmware stopped: {log}");
        }
        assert!(status.success(), "{status:?}: {log}");
        let line = log
            .lines()
            .find(|l| l.starts_with("board: stack high-water"))
            .unwrap_or_else(|| panic!("no stack report: {log}"));
        eprintln!("soak: {line}");
    }
}
