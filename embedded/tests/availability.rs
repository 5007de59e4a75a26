//! The admission rules over the in-memory link: hostile clients on other
//! addresses hold every slot they can, and the operator still connects,
//! logs in and lands (within the test's generous timeout: speed claims
//! belong to benchmarks). The limits are checked at their boundaries.

mod support;

use embassy_futures::select::{Either, select};
use embassy_net::Stack;
use embassy_time::{Duration, Instant, Timer};
use lluav_embedded::Config;
use support::{Client, KEY, PASSWORD, join_all, op, protocol_server, upgrade_request, with_world};

/// The first line and a header of an upgrade: a slowloris never sends more.
const HALF_REQUEST: &[u8] = b"GET / HTTP/1.1\r\nHost: 10.53.0.1:53001\r\n";

fn full_request() -> String {
    upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n"))
}

/// Keeps `n` half-open upgrades open from `stack`, reopening each as soon
/// as the board drops it. Never ends.
async fn slowloris(stack: Stack<'static>, n: usize) {
    join_all((0..n).map(|_| async move {
        loop {
            match Client::try_tcp_with(stack, 512).await {
                Ok(mut c) => {
                    if c.try_raw(HALF_REQUEST).await {
                        c.wait_until_dropped().await;
                    }
                }
                Err(_) => Timer::after_millis(5).await,
            }
        }
    }))
    .await;
}

/// Keeps `n` WebSocket sessions open from `stack` that never log in but
/// ping every 100 ms, reopening each as soon as the board drops it. Never
/// ends.
async fn idlers(stack: Stack<'static>, n: usize) {
    join_all((0..n).map(|_| async move {
        loop {
            let Ok(mut c) = Client::try_tcp_with(stack, 1024).await else {
                Timer::after_millis(5).await;
                continue;
            };
            if c.try_request(&full_request()).await.is_some() {
                while c.try_raw(&support::masked(true, op::PING, b"still here")).await {
                    if let Either::First(()) = select(c.wait_until_dropped(), Timer::after_millis(100)).await
                    {
                        break;
                    }
                }
            }
        }
    }))
    .await;
}

/// Opens connections from `stack` as fast as it can, each sending a whole
/// upgrade request and then holding on. Never ends.
async fn flood(stack: Stack<'static>) {
    join_all((0..6).map(|_| async move {
        loop {
            match Client::try_tcp_with(stack, 1024).await {
                Ok(mut c) => {
                    let _ = c.try_request(&full_request()).await;
                    c.wait_until_dropped().await;
                }
                Err(_) => Timer::after_millis(1).await,
            }
        }
    }))
    .await;
}

/// The operator: connects (retrying a refused or reset connection, as any
/// client would), logs in, lands; then, still under attack, is served again.
async fn operator(stack: Stack<'static>) {
    let mut c = Client::connect_retrying(stack).await;
    assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
    assert_eq!(c.call("land").await["ret"], 0);
    Timer::after_millis(500).await;
    assert_eq!(
        c.call("state").await["ret"],
        0,
        "a logged-in session is never evicted"
    );
}

/// How long an attack runs before the operator comes: long enough for the
/// swarm to hold every slot it can and to have evicted its own connections
/// (older than `Config::reclaim_after`) many times over.
const HEAD_START: Duration = Duration::from_millis(1500);

/// Runs `attack` until the operator, who comes once the attack is under
/// way, is done.
async fn under<A: Future<Output = ()>>(attack: A, stack: Stack<'static>) {
    let late_operator = async {
        Timer::after(HEAD_START).await;
        operator(stack).await;
    };
    match select(attack, late_operator).await {
        Either::First(()) => unreachable!("the attack never ends"),
        Either::Second(()) => {}
    }
}

#[test]
fn slowloris_swarm_of_half_open_upgrades_does_not_lock_out_the_operator() {
    with_world(protocol_server(), Config::new(), |[me, a, b, c]| async move {
        let swarm = join_all([slowloris(a, 2), slowloris(b, 2), slowloris(c, 2)]);
        under(swarm, me).await;
    });
}

#[test]
fn swarm_of_sessions_that_never_log_in_does_not_lock_out_the_operator() {
    with_world(protocol_server(), Config::new(), |[me, a, b, c]| async move {
        let swarm = join_all([idlers(a, 2), idlers(b, 2), idlers(c, 2)]);
        under(swarm, me).await;
    });
}

#[test]
fn flood_from_one_address_does_not_lock_out_the_operator() {
    with_world(protocol_server(), Config::new(), |[me, a, _, _]| async move {
        under(flood(a), me).await;
    });
}

/// Whether the board still holds `c` open after a while.
async fn still_open(c: &mut Client) -> bool {
    matches!(
        select(c.wait_until_dropped(), Timer::after_millis(300)).await,
        Either::Second(())
    )
}

#[test]
fn handshakes_in_progress_are_limited_per_address() {
    with_world(protocol_server(), Config::new(), |[a, b, _, _]| async move {
        let mut held = Vec::new();
        for _ in 0..2 {
            let mut c = Client::tcp(a).await;
            assert!(c.try_raw(HALF_REQUEST).await);
            held.push(c);
        }
        for c in &mut held {
            assert!(still_open(c).await, "the first two handshakes are kept");
        }
        let mut third = Client::tcp(a).await;
        let _ = third.try_raw(HALF_REQUEST).await;
        assert!(
            !still_open(&mut third).await,
            "the third from the address is dropped"
        );
        let mut other = Client::tcp(b).await;
        assert!(other.try_raw(HALF_REQUEST).await);
        assert!(still_open(&mut other).await, "another address is not limited");
    });
}

#[test]
fn sessions_are_limited_per_address_with_429() {
    with_world(protocol_server(), Config::new(), |[a, b, _, _]| async move {
        let mut sessions = Vec::new();
        for _ in 0..2 {
            let mut c = Client::connect(a).await;
            assert_eq!(c.call(&format!("login {PASSWORD}")).await["ret"], 0);
            sessions.push(c);
        }
        let mut third = Client::tcp(a).await;
        let head = third.request(&full_request()).await;
        assert!(head.starts_with("HTTP/1.1 429 "), "{head}");
        assert!(third.closed().await);
        let mut other = Client::connect(b).await;
        assert_eq!(other.call(&format!("login {PASSWORD}")).await["ret"], 0);
        // Once one of its sessions ends, the address may open another.
        assert_eq!(sessions.remove(0).close(1000).await, 1000);
        let mut again = Client::tcp(a).await;
        assert!(again.request(&full_request()).await.starts_with("HTTP/1.1 101 "));
    });
}

#[test]
fn login_deadline_closes_with_1008_and_pings_do_not_extend_it() {
    let config = Config {
        login_timeout: Duration::from_millis(600),
        ..Config::new()
    };
    with_world(protocol_server(), config, |[a, b, _, _]| async move {
        let mut idle = Client::connect(a).await;
        let opened = Instant::now();
        let mut operator = Client::connect(b).await;
        assert_eq!(operator.call(&format!("login {PASSWORD}")).await["ret"], 0);
        let code = loop {
            idle.frame(true, op::PING, b"keep me").await;
            let frame = idle.recv().await;
            if frame.opcode == op::CLOSE {
                break frame.close_code();
            }
            assert_eq!(frame.opcode, op::PONG);
            Timer::after_millis(100).await;
        };
        assert_eq!(code, 1008);
        assert!(
            opened.elapsed() >= Duration::from_millis(600),
            "closed before the deadline"
        );
        assert!(idle.closed().await);
        // The session that logged in is not bound by the deadline.
        assert_eq!(operator.call("state").await["ret"], 0);
    });
}

#[test]
fn handshake_deadline_runs_from_accept_not_per_byte() {
    let config = Config {
        handshake_timeout: Duration::from_millis(500),
        ..Config::new()
    };
    with_world(protocol_server(), config, |[a, _, _, _]| async move {
        let mut c = Client::tcp(a).await;
        let accepted = Instant::now();
        let request = full_request();
        // One byte every 50 ms: the request would take seconds.
        let trickle = async {
            for byte in request.as_bytes() {
                if !c.try_raw(&[*byte]).await {
                    break;
                }
                Timer::after_millis(50).await;
            }
        };
        trickle.await;
        let elapsed = accepted.elapsed();
        assert!(
            c.try_request("").await.is_none(),
            "no 101 for a request that came too late"
        );
        assert!(
            elapsed < Duration::from_secs(5),
            "dropped long before the whole request arrived"
        );
        assert!(
            elapsed >= Duration::from_millis(500),
            "dropped before the deadline"
        );
    });
}
