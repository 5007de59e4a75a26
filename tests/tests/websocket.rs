//! lluavd's WebSocket behaviour (DESIGN.md, "WebSocket behaviour") and its
//! limits, over real sockets; the behaviour over both `ws://` and `wss://`.

use futures_util::future::join_all;
use lluav_tests::{Conn, Lluavd, Options, Received, Scheme, WAIT, upgrade_request};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::coding::Data;

const PASSWORD: &str = "s3cret";

fn daemon_over(scheme: Scheme, options: Options) -> (tempfile::TempDir, Lluavd) {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        tls: scheme == Scheme::Wss,
        ..options
    };
    let daemon = Lluavd::start(dir.path(), &options);
    (dir, daemon)
}

async fn daemon_with(scheme: Scheme, args: &[&str]) -> (tempfile::TempDir, Lluavd) {
    daemon_over(scheme, Options::password(PASSWORD).with_args(args))
}

lluav_tests::over_ws_and_wss!(
    binary_message_closes_with_1003,
    invalid_utf8_closes_with_1007,
    message_over_the_limit_closes_with_1009,
    fragmented_message_over_the_limit_closes_with_1009,
    ping_gets_pong_with_the_same_payload,
    fragmented_text_is_reassembled_into_one_request,
    five_wrong_passwords_are_answered_then_closed_with_1008,
    client_close_is_answered_with_a_close,
    pipelined_requests_are_answered_in_order,
    a_hundred_and_fifty_concurrent_sessions_are_served,
    a_stalled_client_does_not_delay_the_others,
    idle_connections_are_closed,
);

async fn binary_message_closes_with_1003(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    c.send_raw(Message::binary(b"state".to_vec())).await;
    assert_eq!(c.close_code().await, Some(1003));
}

async fn invalid_utf8_closes_with_1007(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    c.send_text_frame(b"state \xff\xfe", Data::Text, true).await;
    assert_eq!(c.close_code().await, Some(1007));
}

async fn message_over_the_limit_closes_with_1009(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let big = format!("plan {}", "x".repeat(64 * 1024));
    c.send(&big).await;
    assert_eq!(c.close_code().await, Some(1009));
}

async fn fragmented_message_over_the_limit_closes_with_1009(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &["--max-message", "1000"]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let chunk = [b'x'; 600];
    c.send_text_frame(b"plan ", Data::Text, false).await;
    c.send_text_frame(&chunk, Data::Continue, false).await;
    c.send_text_frame(&chunk, Data::Continue, true).await;
    assert_eq!(c.close_code().await, Some(1009));
}

/// RFC 6455, section 5.2: "the minimal number of bytes MUST be used to
/// encode the length". A 3-byte frame sent with a 16-bit length, and a
/// 200-byte one with a 64-bit length, close with 1002 (no WebSocket library
/// sends them: the frames go over a plain TCP stream after a hand-made
/// upgrade).
#[tokio::test]
async fn lengths_not_in_their_minimal_form_close_with_1002() {
    let (_dir, daemon) = daemon_with(Scheme::Ws, &[]).await;
    let mask = [1, 2, 3, 4];
    let short = [&[0x81, 0x80 | 126, 0, 3][..], &mask, b"abc"].concat();
    let medium = [
        &[0x81, 0x80 | 127, 0, 0, 0, 0, 0, 0, 0, 200][..],
        &mask,
        &[b'a'; 200],
    ]
    .concat();
    for frame in [short, medium] {
        let mut tcp = TcpStream::connect(daemon.addr).await.expect("TCP connect");
        tcp.write_all(upgrade_request(daemon.addr, "").as_bytes())
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

async fn ping_gets_pong_with_the_same_payload(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::connect(&daemon.url).await;
    c.send_raw(Message::Ping(b"are you there".to_vec().into())).await;
    assert_eq!(c.recv().await, Received::Pong(b"are you there".to_vec()));
    // The connection is still usable afterwards.
    let r = c.request(&format!("login {PASSWORD}")).await;
    assert_eq!(r["ret"], 0, "{r}");
}

async fn fragmented_text_is_reassembled_into_one_request(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    // Setpoints are for a vehicle in the air.
    let r = c.request("takeoff").await;
    assert_eq!(r["ret"], 0, "{r}");
    c.send_text_frame(b"set_sp", Data::Text, false).await;
    c.send_raw(Message::Ping(b"mid".to_vec().into())).await;
    c.send_text_frame(b"_ned 1.0:2.0", Data::Continue, false).await;
    c.send_text_frame(b":-3.0:0.5", Data::Continue, true).await;
    assert_eq!(c.recv().await, Received::Pong(b"mid".to_vec()));
    let r = c.response().await;
    assert_eq!((r["ret"].as_i64(), r["cmd"].as_i64()), (Some(0), Some(23)), "{r}");
}

async fn five_wrong_passwords_are_answered_then_closed_with_1008(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::connect(&daemon.url).await;
    for _ in 0..5 {
        let r = c.request("login guess").await;
        assert_eq!(r["msg"], "Wrong password!", "{r}");
    }
    assert_eq!(c.close_code().await, Some(1008));
}

async fn client_close_is_answered_with_a_close(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::connect(&daemon.url).await;
    c.send_raw(Message::Close(None)).await;
    assert!(
        matches!(c.recv().await, Received::Close(_)),
        "the server completes the handshake"
    );
}

async fn pipelined_requests_are_answered_in_order(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    // A mix of commands with distinct ids, all sent before reading any reply.
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
    for round in 0..25 {
        for f in frames {
            c.send(f).await;
        }
        let mut got = Vec::new();
        for _ in frames {
            got.push(c.response().await["cmd"].as_i64().unwrap_or(-1));
        }
        assert_eq!(got, expected, "round {round}");
    }
}

async fn a_hundred_and_fifty_concurrent_sessions_are_served(scheme: Scheme) {
    let (_dir, daemon) = daemon_over(scheme, Options::password(PASSWORD).per_ip(150));
    let url = daemon.url.clone();
    // All connections are open at once before any of them sends a request.
    let mut conns = join_all((0..150).map(|_| Conn::login(&url, PASSWORD))).await;
    let answers = join_all(conns.iter_mut().enumerate().map(|(i, c)| async move {
        let mut ok = 0;
        for _ in 0..5 {
            let r = c.request("state").await;
            assert_eq!(r["ret"], 0, "session {i}: {r}");
            ok += 1;
        }
        ok
    }))
    .await;
    assert_eq!(answers.iter().sum::<i32>(), 150 * 5);
    join_all(conns.into_iter().map(Conn::close)).await;
}

async fn a_stalled_client_does_not_delay_the_others(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &[]).await;
    let mut stalled = Conn::login(&daemon.url, PASSWORD).await;
    // Half a message that never completes, and many requests never read.
    stalled.send_text_frame(b"sta", Data::Text, false).await;
    let mut other = Conn::login(&daemon.url, PASSWORD).await;
    for _ in 0..50 {
        let r = other.request("state").await;
        assert_eq!(r["ret"], 0, "{r}");
    }
}

#[tokio::test]
async fn connections_over_the_limit_are_refused_with_503() {
    let (_dir, daemon) = daemon_with(Scheme::Ws, &["--max-connections", "3"]).await;
    let mut held = Vec::new();
    for _ in 0..3 {
        held.push(Conn::login(&daemon.url, PASSWORD).await);
    }
    let refused = tokio_tungstenite::connect_async(daemon.url.as_str()).await;
    match refused {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => assert_eq!(response.status(), 503),
        other => panic!("expected HTTP 503, got {:?}", other.map(|_| ())),
    }
    // A slot frees up when a connection closes.
    if let Some(c) = held.pop() {
        c.close().await;
    }
    let mut again = None;
    for _ in 0..600 {
        if let Ok((ws, _)) = tokio_tungstenite::connect_async(daemon.url.as_str()).await {
            again = Some(ws);
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert!(again.is_some(), "a freed slot is reused");
}

async fn idle_connections_are_closed(scheme: Scheme) {
    let (_dir, daemon) = daemon_with(scheme, &["--idle-timeout", "1"]).await;
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(c.close_code().await, Some(1000));
}
