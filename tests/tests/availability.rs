//! Hostile clients cannot lock the operator out: while a swarm
//! of half-open upgrades, a swarm of sessions that never log in, or a
//! flood from one address is running, a legitimate client connects, logs
//! in and sends `land`, and is served every time. Plus the limits'
//! boundaries, the login deadline and the rate-limited log.
//!
//! Attackers use other loopback addresses (127.0.1.x and up) than the
//! operator (127.0.0.1), as hosts on a network would. The bound on the
//! operator's wait is generous because the test machines are shared and
//! noisy; the one-second promise is measured by the load bench
//! (`cargo bench -p lluav-tests --bench load -- --attacks`).

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use lluav_core::CommandId;
use lluav_tests::{Conn, Lluavd, Options, Received, WAIT, http_status, tcp_from, upgrade_request};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinSet;
use tokio_tungstenite::tungstenite::Message;

const PASSWORD: &str = "s3cret";

/// The operator's bound for connect + login + `land`, in these tests:
/// well inside the attackers' deadlines ([`attacked`]), so an operator
/// served only because an attacker's handshake or login deadline freed
/// room fails, and generous for a loaded machine.
const SERVED_WITHIN: Duration = Duration::from_secs(15);

/// A daemon under attack: its handshake and login deadlines (5 s and 10 s
/// by default) moved beyond [`SERVED_WITHIN`], so only the eviction rules
/// can make room for the operator in time.
fn attacked() -> Options {
    Options::password(PASSWORD).with_args(&["--handshake-timeout", "30", "--login-timeout", "30"])
}

/// How many times the operator comes back during one attack.
const ROUNDS: usize = 5;

fn attacker(n: usize) -> IpAddr {
    // 127.0.1.0 onwards: never the operator's 127.0.0.1.
    let n = u16::try_from(n).unwrap_or(u16::MAX);
    let [hi, lo] = n.to_be_bytes();
    IpAddr::V4(Ipv4Addr::new(127, 1 + hi, lo, 1))
}

fn daemon(options: &Options) -> (tempfile::TempDir, Lluavd) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), options);
    (dir, daemon)
}

/// The operator: connect, log in, `land`; returns how long that took.
async fn operator_lands(url: &str) -> Duration {
    let start = Instant::now();
    let mut c = Conn::login(url, PASSWORD).await;
    let r = c.request("land").await;
    assert_eq!(r["cmd"], u8::from(CommandId::Land), "{r}");
    assert_ne!(r["msg"], "Login first!", "{r}");
    let took = start.elapsed();
    c.close().await;
    took
}

/// Runs the operator [`ROUNDS`] times while the attack runs, asserting each
/// is served within [`SERVED_WITHIN`].
async fn operator_is_served_every_time(url: &str, attack: &str) {
    for round in 0..ROUNDS {
        let took = tokio::time::timeout(WAIT, operator_lands(url))
            .await
            .unwrap_or_else(|_| panic!("{attack}: round {round}: the operator was never served"));
        assert!(
            took < SERVED_WITHIN,
            "{attack}: round {round}: served after {took:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Keeps `n` connections from attacker addresses open that send the first
/// line of an upgrade and then nothing, reopening each one the server drops.
fn slowloris(
    addr: SocketAddr,
    n: usize,
    per_address: usize,
    stop: &Arc<AtomicBool>,
) -> (JoinSet<()>, Arc<AtomicUsize>) {
    let opened = Arc::new(AtomicUsize::new(0));
    let mut tasks = JoinSet::new();
    for i in 0..n {
        let (stop, opened) = (Arc::clone(stop), Arc::clone(&opened));
        tasks.spawn(async move {
            while !stop.load(Ordering::Relaxed) {
                let Ok(mut tcp) = tcp_from(attacker(i / per_address), addr).await else {
                    tokio::time::sleep(Duration::from_millis(10)).await;
                    continue;
                };
                opened.fetch_add(1, Ordering::Relaxed);
                if tcp.write_all(b"GET / HTTP/1.1\r\n").await.is_err() {
                    continue;
                }
                // Held until the server drops it (or the test ends).
                let mut byte = [0u8; 1];
                let _ = tokio::time::timeout(WAIT, tcp.read(&mut byte)).await;
            }
        });
    }
    (tasks, opened)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slowloris_swarm_of_half_open_upgrades_does_not_keep_the_operator_out() {
    let (_dir, d) = daemon(&attacked());
    let stop = Arc::new(AtomicBool::new(false));
    // 400 half-open connections from 50 addresses, reopened when dropped.
    let (mut swarm, opened) = slowloris(d.addr, 400, 8, &stop);
    let start = Instant::now();
    while opened.load(Ordering::Relaxed) < 400 && start.elapsed() < WAIT {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    operator_is_served_every_time(&d.url, "slowloris").await;
    stop.store(true, Ordering::Relaxed);
    swarm.abort_all();
    assert!(opened.load(Ordering::Relaxed) >= 400, "the swarm was running");
    assert!(d.stderr().contains("pending handshake dropped"), "{}", d.stderr());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_swarm_of_sessions_that_never_log_in_does_not_keep_the_operator_out() {
    let (_dir, d) = daemon(&attacked());
    let stop = Arc::new(AtomicBool::new(false));
    let open = Arc::new(AtomicUsize::new(0));
    let mut swarm = JoinSet::new();
    // 320 sessions from 40 addresses (8 each, the per-address share):
    // more than the 256 slots. Each pings to look alive, and comes back
    // when it is closed.
    for i in 0..320 {
        let (stop, open, addr) = (Arc::clone(&stop), Arc::clone(&open), d.addr);
        swarm.spawn(async move {
            while !stop.load(Ordering::Relaxed) {
                let Ok(mut c) = Conn::connect_from(attacker(i / 8), addr).await else {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                };
                open.fetch_add(1, Ordering::Relaxed);
                loop {
                    c.send_raw(Message::Ping(b"alive".to_vec().into())).await;
                    if !matches!(c.recv().await, Received::Pong(_)) {
                        break;
                    }
                    tokio::time::sleep(Duration::from_millis(500)).await;
                }
                open.fetch_sub(1, Ordering::Relaxed);
            }
        });
    }
    let start = Instant::now();
    while open.load(Ordering::Relaxed) < 250 && start.elapsed() < WAIT {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(open.load(Ordering::Relaxed) >= 250, "the swarm holds the slots");
    operator_is_served_every_time(&d.url, "never logging in").await;
    stop.store(true, Ordering::Relaxed);
    swarm.abort_all();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_from_one_address_does_not_keep_the_operator_out() {
    let (_dir, d) = daemon(&attacked());
    let flooder = attacker(0);
    let stop = Arc::new(AtomicBool::new(false));
    let refused = Arc::new(AtomicUsize::new(0));
    let mut flood = JoinSet::new();
    // The flooder knows the password: its sessions log in and are never
    // reclaimed, so only the per-address limit stops it.
    for _ in 0..64 {
        let (stop, refused, addr) = (Arc::clone(&stop), Arc::clone(&refused), d.addr);
        flood.spawn(async move {
            let mut held = Vec::new();
            while !stop.load(Ordering::Relaxed) {
                match Conn::connect_from(flooder, addr).await {
                    Ok(mut c) => {
                        let r = c.request(&format!("login {PASSWORD}")).await;
                        if r["ret"] == 0 {
                            held.push(c);
                        }
                    }
                    Err(e) => {
                        if e.contains("503") {
                            refused.fetch_add(1, Ordering::Relaxed);
                        }
                        tokio::time::sleep(Duration::from_millis(5)).await;
                    }
                }
            }
        });
    }
    // Half-open upgrades from the same address, too.
    let (mut half_open, _) = slowloris(d.addr, 64, 64, &stop);
    let start = Instant::now();
    while refused.load(Ordering::Relaxed) < 10 && start.elapsed() < WAIT {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(
        refused.load(Ordering::Relaxed) >= 10,
        "the flooder hits its limit"
    );
    operator_is_served_every_time(&d.url, "one-address flood").await;
    stop.store(true, Ordering::Relaxed);
    flood.abort_all();
    half_open.abort_all();
}

/// Opens a half-open upgrade from `source` and returns it.
async fn half_open(source: IpAddr, addr: SocketAddr) -> tokio::net::TcpStream {
    let mut tcp = tcp_from(source, addr).await.expect("connect");
    tcp.write_all(b"GET / HTTP/1.1\r\n").await.expect("write");
    tcp
}

/// Whether the server closed `tcp` within `limit`.
async fn dropped_within(tcp: &mut tokio::net::TcpStream, limit: Duration) -> bool {
    let mut byte = [0u8; 1];
    matches!(
        tokio::time::timeout(limit, tcp.read(&mut byte)).await,
        Ok(Ok(0) | Err(_))
    )
}

#[tokio::test]
async fn handshake_pools_drop_their_oldest_at_the_boundary_and_never_the_newcomer() {
    let options =
        Options::password(PASSWORD).with_args(&["--max-handshakes", "3", "--max-handshakes-per-ip", "2"]);
    let (_dir, d) = daemon(&options);
    let (a, b) = (attacker(0), attacker(1));
    let mut first = half_open(a, d.addr).await;
    let mut second = half_open(a, d.addr).await;
    assert!(
        !dropped_within(&mut first, Duration::from_millis(300)).await,
        "two per address fit"
    );
    let mut third = half_open(a, d.addr).await;
    assert!(
        dropped_within(&mut first, WAIT).await,
        "the address's oldest is dropped"
    );
    assert!(
        !dropped_within(&mut third, Duration::from_millis(300)).await,
        "not the newcomer"
    );
    let mut other = half_open(b, d.addr).await;
    assert!(
        !dropped_within(&mut other, Duration::from_millis(300)).await,
        "three in all fit"
    );
    let _fourth = half_open(b, d.addr).await;
    assert!(
        dropped_within(&mut second, WAIT).await,
        "the pool's oldest is dropped"
    );
    // A complete upgrade still gets through.
    let mut c = Conn::login(&d.url, PASSWORD).await;
    assert_eq!(c.request("state").await["ret"], 0);
}

#[tokio::test]
async fn an_upgrade_not_completed_within_the_handshake_timeout_is_dropped() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--handshake-timeout", "1"]));
    let start = Instant::now();
    let mut tcp = half_open(attacker(0), d.addr).await;
    // Dripping a byte every 50 ms, for ever: a deadline that each byte
    // extended would never pass. It runs from accept, so the server drops
    // the connection while the bytes still come.
    let (mut reader, mut writer) = tcp.split();
    let drip = async {
        for byte in b"Host: x\r\n".iter().cycle() {
            if writer.write_all(&[*byte]).await.is_err() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    let mut byte = [0u8; 1];
    let dropped = async { matches!(reader.read(&mut byte).await, Ok(0) | Err(_)) };
    let outcome = tokio::time::timeout(WAIT, async {
        tokio::select! {
            d = dropped => d,
            () = drip => true,
        }
    })
    .await;
    assert_eq!(outcome, Ok(true), "dropped while the bytes still came");
    assert!(
        start.elapsed() >= Duration::from_millis(900),
        "not before its deadline: {:?}",
        start.elapsed()
    );
}

#[tokio::test]
async fn one_address_gets_at_most_its_sessions_and_others_are_not_affected() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--max-sessions-per-ip", "2"]));
    let a = attacker(0);
    let mut held = Vec::new();
    for _ in 0..2 {
        let mut c = Conn::connect_from(a, d.addr).await.expect("room for two");
        assert_eq!(c.request(&format!("login {PASSWORD}")).await["ret"], 0);
        held.push(c);
    }
    let refused = Conn::connect_from(a, d.addr).await.err().unwrap_or_default();
    assert!(
        refused.contains("503"),
        "a third from the same address: {refused}"
    );
    let mut other = Conn::connect_from(attacker(1), d.addr)
        .await
        .expect("another address");
    assert_eq!(other.request(&format!("login {PASSWORD}")).await["ret"], 0);
    if let Some(c) = held.pop() {
        c.close().await;
    }
    let start = Instant::now();
    loop {
        if Conn::connect_from(a, d.addr).await.is_ok() {
            break;
        }
        assert!(start.elapsed() < WAIT, "a freed slot is reused");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test]
async fn sessions_not_logged_in_make_room_for_newcomers_oldest_first() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--max-connections", "2"]));
    let mut oldest = Conn::connect_from(attacker(0), d.addr).await.expect("room");
    let mut younger = Conn::connect_from(attacker(1), d.addr).await.expect("room");
    assert_eq!(younger.request("state").await["msg"], "Login first!");
    let mut newcomer = Conn::login(&d.url, PASSWORD).await;
    assert_eq!(
        oldest.close_code().await,
        Some(1008),
        "the oldest not logged in goes"
    );
    assert_eq!(
        younger.request("ver").await["msg"],
        "Login first!",
        "the younger stays"
    );
    assert_eq!(younger.request(&format!("login {PASSWORD}")).await["ret"], 0);
    // Both slots are now held by logged-in sessions: no one is displaced.
    let refused = Conn::try_connect(&d.url).await;
    assert!(refused.is_err(), "every slot is logged in: 503");
    assert_eq!(newcomer.request("state").await["ret"], 0);
    assert_eq!(younger.request("state").await["ret"], 0);
}

#[tokio::test]
async fn a_session_that_does_not_log_in_in_time_is_closed_and_pings_do_not_extend_it() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--login-timeout", "1"]));
    let mut lazy = Conn::connect(&d.url).await;
    let mut prompt = Conn::login(&d.url, PASSWORD).await;
    let start = Instant::now();
    let closed = loop {
        lazy.send_raw(Message::Ping(b"still here".to_vec().into())).await;
        match lazy.recv().await {
            Received::Pong(_) => tokio::time::sleep(Duration::from_millis(200)).await,
            Received::Close(code) => break code,
            other => panic!("expected a pong or a close, got {other:?}"),
        }
        assert!(start.elapsed() < WAIT, "never closed");
    };
    assert_eq!(closed, Some(1008));
    assert!(
        start.elapsed() >= Duration::from_millis(800),
        "{:?}",
        start.elapsed()
    );
    tokio::time::sleep(Duration::from_millis(1200)).await;
    assert_eq!(
        prompt.request("state").await["ret"],
        0,
        "logged-in sessions have no deadline"
    );
    // Without a password nobody needs to log in: no deadline either.
    let (_dir, open) = daemon(&Options::default().with_args(&["--login-timeout", "1"]));
    let mut c = Conn::connect(&open.url).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(c.request("state").await["ret"], 0);
}

#[tokio::test]
async fn offences_are_logged_once_per_address_per_minute() {
    let (_dir, d) = daemon(&Options::password(PASSWORD));
    let request = upgrade_request(d.addr, "Origin: https://evil.example\r\n");
    for _ in 0..30 {
        assert_eq!(http_status(d.addr, &request).await.0, 403);
    }
    // A second address is reported on its own.
    let mut tcp = tcp_from(attacker(7), d.addr).await.expect("connect");
    tcp.write_all(request.as_bytes()).await.expect("write");
    let mut answer = Vec::new();
    let _ = tokio::time::timeout(WAIT, tcp.read_to_end(&mut answer)).await;
    let start = Instant::now();
    let log = loop {
        let log = d.stderr();
        if log.contains(&attacker(7).to_string()) || start.elapsed() > WAIT {
            break log;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let lines = |ip: &str| {
        log.lines()
            .filter(|l| l.contains("Origin/Host") && l.contains(ip))
            .count()
    };
    assert_eq!(lines("127.0.0.1"), 1, "{log}");
    assert_eq!(lines(&attacker(7).to_string()), 1, "{log}");
}
