//! The upgrade request both adapters judge with: its HTTP/1.1 form, the
//! WebSocket headers, each refusal's status, and the Origin/Host policy
//! given the address a connection arrived on.

use std::net::IpAddr;

use lluav_core::websocket::handshake::{Malformed, Rejection, Request, Upgrade, head_end, judge, parse};
use lluav_core::websocket::policy::{Forbidden, Policy, valid_host_name, valid_origin};

const KEY: &str = "dGhlIHNhbXBsZSBub25jZQ==";

const GOOD: &str = "GET /chat HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: keep-alive, Upgrade\r\n\
Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n";

/// `GOOD` with extra header lines (each without its CRLF).
fn with(extra: &str) -> String {
    GOOD.replace("\r\n\r\n", &format!("\r\n{extra}\r\n\r\n"))
}

fn parsed(head: &str) -> Result<Request<'_>, Rejection> {
    parse(head.as_bytes())
}

fn status(head: &str) -> u16 {
    match parsed(head) {
        Ok(Request::Upgrade(_)) => 101,
        Ok(Request::Plain { .. }) => 200,
        Err(why) => why.status().0,
    }
}

const LOOPBACK: IpAddr = IpAddr::V4(std::net::Ipv4Addr::LOCALHOST);
const LAN: IpAddr = IpAddr::V4(std::net::Ipv4Addr::new(192, 168, 1, 5));

fn policy<'a>(local: IpAddr, origins: &'a [&'a str], hosts: &'a [&'a str]) -> Policy<'a> {
    Policy {
        local,
        tls: false,
        allowed_origins: origins,
        allowed_hosts: hosts,
    }
}

fn open(local: IpAddr) -> Policy<'static> {
    policy(local, &[], &[])
}

#[test]
fn the_rfc_example_is_an_upgrade_with_its_key_host_and_origin() {
    assert_eq!(
        parsed(GOOD),
        Ok(Request::Upgrade(Upgrade {
            target: "/chat",
            key: b"dGhlIHNhbXBsZSBub25jZQ==",
            host: "x",
            origin: None,
        }))
    );
    let origin = with("Origin: http://x");
    assert!(matches!(parsed(&origin), Ok(Request::Upgrade(u)) if u.origin == Some("http://x")));
}

#[test]
fn a_request_that_is_not_an_upgrade_is_plain_http() {
    let head = "GET /index.html?x HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
    assert_eq!(
        parsed(head),
        Ok(Request::Plain {
            method: "GET",
            target: "/index.html?x"
        })
    );
    // Upgrade without Connection (or to another protocol) is no WebSocket.
    assert_eq!(
        status(&GOOD.replace("Connection: keep-alive, Upgrade\r\n", "")),
        200
    );
    assert_eq!(status(&GOOD.replace("Upgrade: websocket", "Upgrade: h2c")), 200);
    let post = "POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\n";
    assert!(matches!(parsed(post), Ok(Request::Plain { method: "POST", .. })));
}

#[test]
fn each_broken_upgrade_has_its_status() {
    let cases = [
        (GOOD.replace("GET", "POST"), 405),
        (GOOD.replace("Version: 13", "Version: 8"), 426),
        (GOOD.replace("Sec-WebSocket-Version: 13\r\n", ""), 426),
        (GOOD.replace(KEY, "short=="), 400),
        (
            GOOD.replace("Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n", ""),
            400,
        ),
        (with("Content-Length: 5"), 400),
        (with("Transfer-Encoding: chunked"), 400),
        (GOOD.replace("Host: x\r\n", ""), 400),
        (GOOD.replace("Host: x", "Host: "), 400),
        (GOOD.replace("HTTP/1.1", "HTTP/1.0"), 400),
    ];
    for (head, code) in cases {
        assert_eq!(status(&head), code, "{head}");
    }
    assert_eq!(status(&with("Content-Length: 0")), 101);
}

#[test]
fn keys_must_be_a_base64_sixteen_byte_nonce() {
    for bad in [
        "dGhlIHNhbXBsZSBub25jZQ==AAAA", // longer
        "dGhlIHNhbXBsZSBub25jZR==",     // stray bits in the last character
        "dGhlIHNhbXBsZSBub25jZQ=!",     // not padding
        "dGhlIHNhbXBsZSBub25jZ!==",     // not base64
    ] {
        let head = GOOD.replace(KEY, bad);
        assert_eq!(parsed(&head), Err(Rejection::Malformed(Malformed::Key)), "{bad}");
    }
}

#[test]
fn headers_that_may_appear_once_are_refused_twice() {
    for extra in [
        "Host: y",
        "Origin: http://a\r\nOrigin: http://b",
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
        "Sec-WebSocket-Version: 13",
    ] {
        assert_eq!(
            parsed(&with(extra)),
            Err(Rejection::Malformed(Malformed::Repeated)),
            "{extra}"
        );
    }
    // Token lists may repeat.
    assert_eq!(status(&with("Connection: Upgrade\r\nUpgrade: websocket")), 101);
}

#[test]
fn heads_that_are_not_well_formed_http_are_refused_with_400() {
    let cases = [
        (
            GOOD.replace("Upgrade: websocket\r\n", "Upgrade: websocket\n"),
            Malformed::Bytes,
        ),
        (GOOD.replace("Host: x", "Host: x\ry"), Malformed::Bytes),
        (with("X-Nul: a\0b"), Malformed::Bytes),
        (GOOD.replace("GET /chat", "GET  /chat"), Malformed::RequestLine),
        (GOOD.replace("GET /chat", "GET"), Malformed::RequestLine),
        (GOOD.replace("GET /chat", "G\tT /chat"), Malformed::RequestLine),
        (with("X-Name : value"), Malformed::HeaderLine),
        (with(" folded"), Malformed::HeaderLine),
        (with(": value"), Malformed::HeaderLine),
        (with("no colon"), Malformed::HeaderLine),
    ];
    for (head, why) in cases {
        assert_eq!(parsed(&head), Err(Rejection::Malformed(why)), "{head:?}");
    }
    // Latin-1 bytes are not UTF-8.
    let mut latin1 = with("X-Name: caf").into_bytes();
    let at = latin1.len() - 4;
    latin1.insert(at, 0xe9);
    assert_eq!(parse(&latin1), Err(Rejection::Malformed(Malformed::Bytes)));
    // UTF-8 in a value nobody reads is fine.
    assert_eq!(status(&with("User-Agent: caf\u{e9}")), 101);
    // Only a whole head is parsed.
    assert_eq!(
        parse(b"GET / HTTP/1.1\r\n"),
        Err(Rejection::Malformed(Malformed::Bytes))
    );
}

#[test]
fn subprotocols_of_any_length_are_ignored() {
    let offered = with("Sec-WebSocket-Protocol: chat, a-protocol-name-well-over-24-bytes");
    assert_eq!(status(&offered), 101);
}

#[test]
fn the_end_of_the_head_is_its_blank_line() {
    assert_eq!(head_end(b"GET / HTTP/1.1\r\n\r\nrest"), Some(18));
    assert_eq!(head_end(b"GET / HTTP/1.1\r\n"), None);
}

#[test]
fn judging_applies_the_policy_to_upgrades_only() {
    let p = open(LOOPBACK);
    let evil = with("Origin: https://evil.example").replace("Host: x", "Host: 127.0.0.1:53001");
    assert_eq!(
        judge(evil.as_bytes(), &p),
        Err(Rejection::Forbidden(Forbidden::Origin))
    );
    assert_eq!(
        Rejection::Forbidden(Forbidden::Origin).status(),
        (403, "Forbidden")
    );
    assert_eq!(
        judge(GOOD.as_bytes(), &p),
        Err(Rejection::Forbidden(Forbidden::Host))
    );
    let plain = "GET / HTTP/1.1\r\nHost: evil.example\r\n\r\n";
    assert!(matches!(judge(plain.as_bytes(), &p), Ok(Request::Plain { .. })));
}

#[test]
fn no_origin_is_a_non_browser_client_and_accepted() {
    assert_eq!(open(LOOPBACK).check("127.0.0.1:53001", None), Ok(()));
}

#[test]
fn a_page_served_by_the_vehicle_itself_is_accepted() {
    let p = open(LAN);
    assert_eq!(
        p.check("192.168.1.5:53001", Some("http://192.168.1.5:53001")),
        Ok(())
    );
    assert_eq!(
        open(LOOPBACK).check("LOCALHOST:8080", Some("http://localhost:8080")),
        Ok(())
    );
    let v6 = open("::1".parse().expect("ip"));
    assert_eq!(v6.check("[::1]:1", Some("http://[::1]:1")), Ok(()));
    // Default ports on both sides: 80 for ws, 443 for wss.
    assert_eq!(p.check("192.168.1.5", Some("http://192.168.1.5")), Ok(()));
    assert_eq!(p.check("192.168.1.5:80", Some("HTTP://192.168.1.5")), Ok(()));
    assert_eq!(
        p.check("192.168.1.5", Some("https://192.168.1.5")),
        Err(Forbidden::Origin)
    );
    let tls = Policy { tls: true, ..p };
    assert_eq!(tls.check("192.168.1.5", Some("https://192.168.1.5")), Ok(()));
}

#[test]
fn a_foreign_origin_is_refused_unless_allowed() {
    let host = "127.0.0.1:53001";
    let evil = Some("https://evil.example");
    assert_eq!(open(LOOPBACK).check(host, evil), Err(Forbidden::Origin));
    assert_eq!(
        policy(LOOPBACK, &["https://evil.example/"], &[]).check(host, evil),
        Ok(())
    );
    assert_eq!(
        policy(LOOPBACK, &["https://evil.example:443"], &[]).check(host, evil),
        Ok(())
    );
    assert_eq!(
        policy(LOOPBACK, &["http://evil.example"], &[]).check(host, evil),
        Err(Forbidden::Origin)
    );
    assert_eq!(policy(LOOPBACK, &["*"], &[]).check(host, evil), Ok(()));
    assert_eq!(policy(LOOPBACK, &["*"], &[]).check(host, Some("null")), Ok(()));
    assert_eq!(open(LOOPBACK).check(host, Some("null")), Err(Forbidden::Origin));
    // Same host, another port: another origin.
    assert_eq!(
        open(LOOPBACK).check(host, Some("http://127.0.0.1:8000")),
        Err(Forbidden::Origin)
    );
    let named = policy(LAN, &["http://gcs.local:8080"], &[]);
    assert_eq!(named.check("192.168.1.5", Some("http://GCS.local:8080")), Ok(()));
    assert_eq!(
        named.check("192.168.1.5", Some("http://gcs.local:8081")),
        Err(Forbidden::Origin)
    );
}

#[test]
fn a_rebound_host_name_is_refused_even_with_a_matching_origin() {
    let p = open(LOOPBACK);
    let origin = Some("http://evil.example:53001");
    assert_eq!(p.check("evil.example:53001", origin), Err(Forbidden::Host));
    assert_eq!(p.check("evil.example:53001", None), Err(Forbidden::Host));
    // The allowed origins never excuse a foreign Host.
    let any = policy(LOOPBACK, &["*"], &[]);
    assert_eq!(any.check("evil.example", origin), Err(Forbidden::Host));
    let allowed = policy(LAN, &[], &["Drone.local"]);
    assert_eq!(
        allowed.check("drone.local:53001", Some("http://drone.local:53001")),
        Ok(())
    );
    assert_eq!(allowed.check("other.local:53001", None), Err(Forbidden::Host));
}

#[test]
fn host_must_name_the_local_address_with_any_numeric_port() {
    let p = open(LAN);
    assert_eq!(p.check("192.168.1.5", None), Ok(()));
    assert_eq!(p.check("192.168.1.5:53001", None), Ok(()));
    assert_eq!(p.check("192.168.1.5:1", None), Ok(()));
    for foreign in [
        "192.168.1.6:53001",
        "localhost:53001",
        "127.0.0.1:53001",
        "192.168.1.5:x",
        "192.168.1.5:99999",
        "192.168.1.5:",
        "192.168.01.5",
        "192.168.1.5.1",
        "",
        ":80",
        "a b",
    ] {
        assert_eq!(p.check(foreign, None), Err(Forbidden::Host), "{foreign:?}");
    }
    // An IPv4-mapped literal names the IPv4 address, in the hex form
    // browsers write (a dotted-quad tail is not read).
    assert_eq!(open(LAN).check("[::ffff:c0a8:105]:53001", None), Ok(()));
    assert_eq!(
        open(LAN).check("[::ffff:192.168.1.5]", None),
        Err(Forbidden::Host)
    );
    let v6 = open("fd00::5".parse().expect("ip"));
    assert_eq!(v6.check("[FD00:0::5]:53001", None), Ok(()));
    assert_eq!(v6.check("[fd00::6]:53001", None), Err(Forbidden::Host));
    assert_eq!(v6.check("[fd00::5]x", None), Err(Forbidden::Host));
}

#[test]
fn loopback_names_pass_only_when_the_connection_is_on_loopback() {
    let p = open(LOOPBACK);
    for host in [
        "localhost",
        "LOCALHOST:53001",
        "127.0.0.1",
        "127.53.0.1:53001",
        "[::1]:53001",
    ] {
        assert_eq!(p.check(host, None), Ok(()), "{host}");
    }
    assert_eq!(p.check("evil.example", None), Err(Forbidden::Host));
    assert_eq!(open(LAN).check("[::1]:53001", None), Err(Forbidden::Host));
}

#[test]
fn unusable_allow_list_entries_are_recognised() {
    assert!(valid_origin("*"));
    assert!(valid_origin("https://gcs.example:8443/"));
    assert!(!valid_origin("evil.example"));
    assert!(!valid_origin("ftp://x"));
    assert!(!valid_origin("http://x/path"));
    assert!(!valid_origin("http://user@x"));
    assert!(valid_host_name("drone.local"));
    assert!(!valid_host_name("drone.local:80"));
    assert!(!valid_host_name(""));
}
