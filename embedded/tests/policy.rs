//! DESIGN.md's Origin and Host rules over the in-memory link, as the
//! adapter feeds them: the address each connection arrived on and
//! `Config`'s allow-lists go to the core's policy (whose every rule is
//! tested in core/tests/handshake.rs), and a refused upgrade gets 403 and
//! no session.

mod support;

use lluav_embedded::Config;
use support::{
    Client, KEY, PASSWORD, SERVER_IP, protocol_server, upgrade_request, upgrade_request_to, with_server,
    with_world,
};

fn key() -> String {
    format!("Sec-WebSocket-Key: {KEY}\r\n")
}

/// Sends `request` on a new connection; returns the response head, and
/// checks that a refused connection is closed (no session) and that an
/// accepted one is a session (which it then closes).
async fn answer(stack: embassy_net::Stack<'static>, request: &str) -> String {
    let mut c = Client::tcp(stack).await;
    let head = c.request(request).await;
    if head.starts_with("HTTP/1.1 101 ") {
        assert_eq!(c.call("state").await["msg"], "Login first!");
        assert_eq!(c.close(1000).await, 1000);
    } else {
        assert!(c.closed().await, "a refused upgrade leaves no session: {head}");
    }
    head
}

#[test]
fn foreign_origin_gets_403_and_no_session() {
    with_server(|stack| async move {
        let request = upgrade_request(&format!("{}Origin: https://evil.example\r\n", key()));
        let head = answer(stack, &request).await;
        assert!(head.starts_with("HTTP/1.1 403 "), "{head}");
        // The board keeps serving everyone else.
        let mut c = Client::connect(stack).await;
        assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
    });
}

#[test]
fn own_origin_and_no_origin_are_served() {
    with_server(|stack| async move {
        let own = format!("{}Origin: http://{SERVER_IP}:53001\r\n", key());
        for request in [upgrade_request(&own), upgrade_request(&key())] {
            let head = answer(stack, &request).await;
            assert!(head.starts_with("HTTP/1.1 101 "), "{request}: {head}");
        }
    });
}

/// DNS rebinding: `evil.example` now resolves to the board, and the page's
/// Origin and Host agree; the Host still names no address of the board.
#[test]
fn rebinding_host_gets_403_even_with_a_matching_origin() {
    with_server(|stack| async move {
        let request = upgrade_request_to(
            "evil.example:53001",
            &format!("{}Origin: http://evil.example:53001\r\n", key()),
        );
        let head = answer(stack, &request).await;
        assert!(head.starts_with("HTTP/1.1 403 "), "{head}");
        let head = answer(stack, &upgrade_request_to("evil.example:53001", &key())).await;
        assert!(head.starts_with("HTTP/1.1 403 "), "{head}");
        // A loopback name is not this board's address either.
        let head = answer(stack, &upgrade_request_to("localhost:53001", &key())).await;
        assert!(head.starts_with("HTTP/1.1 403 "), "{head}");
    });
}

#[test]
fn allow_lists_admit_configured_origins_and_host_names() {
    let config = Config {
        allowed_origins: &["http://gcs.local:8080"],
        allowed_hosts: &["drone.local"],
        ..Config::new()
    };
    with_world(protocol_server(), config, |clients| async move {
        let stack = clients[0];
        let gcs = upgrade_request(&format!("{}Origin: http://gcs.local:8080\r\n", key()));
        assert!(answer(stack, &gcs).await.starts_with("HTTP/1.1 101 "));
        let other = upgrade_request(&format!("{}Origin: http://gcs.local:8081\r\n", key()));
        assert!(answer(stack, &other).await.starts_with("HTTP/1.1 403 "));
        let named = upgrade_request_to("drone.local:53001", &key());
        assert!(answer(stack, &named).await.starts_with("HTTP/1.1 101 "));
        let unnamed = upgrade_request_to("other.local:53001", &key());
        assert!(answer(stack, &unnamed).await.starts_with("HTTP/1.1 403 "));
    });
}
