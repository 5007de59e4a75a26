//! Plain HTTP on lluavd's port: the browser console for `GET`/`HEAD`, 404
//! and 405 for the rest, nothing at all with `--no-console`, and never the
//! protocol: a request that is not a WebSocket upgrade cannot run a command.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};

use lluav_tests::{Conn, Lluavd, Options, WAIT};

/// One HTTP answer, read until the server closes.
struct Answer {
    status: u16,
    head: String,
    body: Vec<u8>,
}

impl Answer {
    /// The value of header `name` (case-insensitive).
    fn header(&self, name: &str) -> Option<&str> {
        self.head.lines().skip(1).find_map(|line| {
            let (n, v) = line.split_once(':')?;
            n.trim().eq_ignore_ascii_case(name).then(|| v.trim())
        })
    }

    fn body_text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

/// Sends `request` as is and reads the whole answer; the server must close.
fn exchange(addr: SocketAddr, request: &[u8]) -> Answer {
    let mut stream = TcpStream::connect(addr).expect("connects");
    stream.set_read_timeout(Some(WAIT)).expect("timeout set");
    stream.write_all(request).expect("request written");
    let mut bytes = Vec::new();
    stream
        .read_to_end(&mut bytes)
        .expect("the server answers and closes (Connection: close)");
    let split = bytes
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| panic!("no end of head in {:?}", String::from_utf8_lossy(&bytes)));
    let head = String::from_utf8(bytes[..split].to_vec()).expect("the head is text");
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no status in {head:?}"));
    Answer {
        status,
        head,
        body: bytes[split + 4..].to_vec(),
    }
}

fn get(addr: SocketAddr, method: &str, target: &str) -> Answer {
    exchange(
        addr,
        format!("{method} {target} HTTP/1.1\r\nHost: {addr}\r\nUser-Agent: lluav-tests\r\n\r\n").as_bytes(),
    )
}

fn daemon(args: &[&str]) -> (tempfile::TempDir, Lluavd) {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        args: args.iter().map(|a| (*a).to_owned()).collect(),
        ..Options::default()
    };
    let d = Lluavd::start(dir.path(), &options);
    (dir, d)
}

#[test]
fn get_root_serves_the_console_page() {
    let (_dir, d) = daemon(&[]);
    let a = get(d.addr, "GET", "/");
    assert_eq!(a.status, 200, "{}", a.head);
    assert_eq!(a.header("Content-Type"), Some("text/html; charset=utf-8"));
    assert_eq!(a.header("X-Content-Type-Options"), Some("nosniff"));
    assert_eq!(a.header("Connection"), Some("close"));
    let policy = a
        .header("Content-Security-Policy")
        .expect("a Content-Security-Policy");
    assert!(
        policy.contains("default-src 'none'") && policy.contains("connect-src 'self'"),
        "{policy}"
    );
    assert!(a.header("Cache-Control").is_some());
    assert_eq!(
        a.header("Content-Length"),
        Some(a.body.len().to_string().as_str())
    );
    assert!(a.body_text().contains("<title>lluav console</title>"));
}

#[test]
fn the_page_and_its_modules_and_styles_are_served_with_their_types() {
    let (_dir, d) = daemon(&[]);
    let page = get(d.addr, "GET", "/index.html").body_text();
    for (path, ty) in [
        ("/main.js", "text/javascript; charset=utf-8"),
        ("/console.css", "text/css; charset=utf-8"),
        ("/favicon.svg", "image/svg+xml"),
    ] {
        assert!(page.contains(&path[1..]), "the page links {path}");
        let a = get(d.addr, "GET", path);
        assert_eq!((a.status, a.header("Content-Type")), (200, Some(ty)), "{path}");
    }
}

#[test]
fn head_answers_the_headers_without_a_body() {
    let (_dir, d) = daemon(&[]);
    let full = get(d.addr, "GET", "/main.js");
    let head = get(d.addr, "HEAD", "/main.js");
    assert_eq!(head.status, 200);
    assert!(head.body.is_empty(), "HEAD has no body");
    assert_eq!(
        head.header("Content-Length"),
        Some(full.body.len().to_string().as_str())
    );
}

#[test]
fn unknown_paths_answer_404() {
    let (_dir, d) = daemon(&[]);
    for target in ["/nope", "/index.htm", "/../Cargo.toml", "/main.js/x"] {
        let a = get(d.addr, "GET", target);
        assert_eq!(a.status, 404, "{target}: {}", a.head);
    }
}

#[test]
fn other_methods_answer_405_with_allow() {
    let (_dir, d) = daemon(&[]);
    for method in ["POST", "PUT", "DELETE", "OPTIONS"] {
        let a = get(d.addr, method, "/");
        assert_eq!(a.status, 405, "{method}: {}", a.head);
        assert_eq!(a.header("Allow"), Some("GET, HEAD"), "{method}");
    }
}

#[test]
fn no_console_flag_answers_404_for_the_page() {
    let (_dir, d) = daemon(&["--no-console"]);
    for path in ["/", "/index.html", "/main.js"] {
        let a = get(d.addr, "GET", path);
        assert_eq!(a.status, 404, "{path}: {}", a.head);
        assert!(
            !a.body_text().contains("<title>"),
            "{path} serves nothing of the page"
        );
    }
}

#[test]
fn config_key_console_false_turns_the_page_off() {
    let dir = tempfile::tempdir().expect("temp dir");
    let config = dir.path().join("lluavd.toml");
    std::fs::write(&config, "console = false\n").expect("config written");
    let options = Options {
        args: vec!["--config".into(), config.display().to_string()],
        ..Options::default()
    };
    let d = Lluavd::start(&dir.path().join("data"), &options);
    assert_eq!(get(d.addr, "GET", "/").status, 404);
}

#[tokio::test]
async fn websocket_upgrades_still_work_beside_the_page() {
    let (_dir, d) = daemon(&[]);
    assert_eq!(get(d.addr, "GET", "/").status, 200);
    let mut c = Conn::connect(&d.url).await;
    let r = c.request("state").await;
    assert_eq!(r["ret"], 0, "{r}");
}

#[tokio::test]
async fn plain_http_requests_never_reach_the_protocol() {
    // No password: any command that reached the protocol would run.
    let (_dir, d) = daemon(&[]);
    let host = d.addr;
    let attempts = [
        format!("GET /?takeoff HTTP/1.1\r\nHost: {host}\r\n\r\n"),
        format!("GET takeoff HTTP/1.1\r\nHost: {host}\r\n\r\n"),
        format!(
            "POST / HTTP/1.1\r\nHost: {host}\r\nContent-Type: text/plain\r\nContent-Length: 7\r\n\r\ntakeoff"
        ),
        format!(
            "POST /?passwd%20hijacked HTTP/1.1\r\nHost: {host}\r\nContent-Length: 15\r\n\r\npasswd hijacked"
        ),
        format!("PUT / HTTP/1.1\r\nHost: {host}\r\nContent-Length: 20\r\n\r\nset_param max_alt:99"),
    ];
    for (i, request) in attempts.iter().enumerate() {
        let a = exchange(d.addr, request.as_bytes());
        let body = a.body_text();
        assert!(
            !body.contains("\"ret\""),
            "{request:?} got a protocol reply: {body}"
        );
        if i == 0 {
            assert_eq!(a.status, 200, "a query is not a command: the page is served");
            assert!(body.contains("<title>lluav console</title>"));
        } else {
            assert!(a.status >= 400, "{request:?}: {}", a.head);
        }
    }
    let mut c = Conn::connect(&d.url).await;
    let state = c.request("state").await;
    // `state` without login still works: no `passwd` set a password.
    assert_eq!(state["ret"], 0, "{state}");
    assert_eq!(state["state"]["fsm"], "disarmed", "nothing took off: {state}");
    assert_eq!(state["state"]["armed"], false, "{state}");
    let param = c.request("get_param max_alt").await;
    assert_eq!(param["ret"], 0, "{param}");
    assert_ne!(param["param"]["max_alt"], 99.0, "no parameter changed: {param}");
}
