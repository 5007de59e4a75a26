//! Attack and transport-security scenarios, each against fresh real lluavd
//! processes in one run:
//!
//! - `--attacks`: an operator's experience under attack. For no attack, a
//!   slowloris swarm (400 half-open upgrades from 50 addresses, reopened
//!   when dropped), a swarm of 320 sessions from 40 addresses that never
//!   log in (pinging, reconnecting when closed), and a flood from one
//!   address (64 clients that know the password and hold every session
//!   they get, plus 64 half-open upgrades): the time an operator from
//!   127.0.0.1 takes to connect, log in and get `land` answered (20
//!   times), and the latency of `state` on its logged-in session (2000
//!   closed-loop requests). The attackers run on their own runtime thread.
//! - `--tls`: msg/s and latency of `state` at 100 closed-loop connections,
//!   over `wss://` and over `ws://` against two daemons, rounds
//!   alternating which goes first.
//! - `--guesses`: password guesses one address can make in `--seconds`
//!   (default 10) with 50 connections that reconnect whenever closed:
//!   how many were checked (`Wrong password!`) and how many refused
//!   unchecked (`Too many wrong passwords`). `--baseline-lluavd PATH` runs
//!   the same against another build first (e.g. one from before the
//!   throttle).

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use lluav_core::CommandId;
use lluav_tests::tcp_from;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::runtime::Runtime;

use super::{Arc, Duration, Histogram, Instant, Lluavd, Message, Options, SinkExt, StreamExt, WAIT, timeout};
use super::{Args, BenchError, FRAME, PASSWORD, Stats, Target, Ws, connect, histogram, load, round_trip};

/// Which scenarios to run.
#[derive(Debug, Default)]
pub struct Scenarios {
    /// `--attacks`.
    pub attacks: bool,
    /// `--tls`.
    pub tls: bool,
    /// `--guesses`.
    pub guesses: bool,
    /// `--seconds` for `--guesses` (0: 10).
    pub seconds: usize,
    /// `--baseline-lluavd`.
    pub baseline: Option<PathBuf>,
}

impl Scenarios {
    /// Whether any scenario was asked for.
    pub fn any(&self) -> bool {
        self.attacks || self.tls || self.guesses
    }
}

/// Runs the scenarios `args` asks for.
pub fn run(args: &Args) -> Result<(), BenchError> {
    super::raise_open_file_limit(1200)?;
    let runtime = super::client_runtime(args.client_threads)?;
    println!("lluavd:  {}", lluav_tests::lluavd_bin().display());
    println!(
        "machine: {} CPUs, load average {}",
        std::thread::available_parallelism().map_or(0, usize::from),
        super::load_average()
    );
    if args.scenarios.tls {
        tls_cost(args, &runtime)?;
    }
    if args.scenarios.attacks {
        under_attack(&runtime)?;
    }
    if args.scenarios.guesses {
        guessing(&args.scenarios, &runtime)?;
    }
    println!("load average after: {}", super::load_average());
    Ok(())
}

fn temp_dir() -> Result<tempfile::TempDir, BenchError> {
    tempfile::tempdir().map_err(|e| BenchError::Process(format!("temp dir: {e}")))
}

fn tls_cost(args: &Args, runtime: &Runtime) -> Result<(), BenchError> {
    let c = 100;
    let m = args.messages_for(c);
    let dir = temp_dir()?;
    let options = Options::password(PASSWORD).per_ip(c + 64);
    let ws = Lluavd::start(&dir.path().join("ws"), &options);
    let wss = Lluavd::start(&dir.path().join("wss"), &Options { tls: true, ..options });
    let (mut plain, mut tls) = (None::<Stats>, None::<Stats>);
    for round in 0..args.rounds {
        let mut order = [(&ws, &mut plain), (&wss, &mut tls)];
        if round % 2 == 1 {
            order.reverse();
        }
        for (daemon, total) in order {
            let stats = runtime.block_on(load(&daemon.url, daemon.pid(), Target::Lluavd, c, m))?;
            println!("{:<26} C={c} M={m} round {round}: {stats}", daemon.url);
            match total {
                Some(t) => t.merge(&stats)?,
                None => *total = Some(stats),
            }
        }
    }
    let (Some(plain), Some(tls)) = (plain, tls) else {
        return Ok(());
    };
    println!();
    println!("| `state`, C = {c}, M = {m} | msg/s | p50 / p99 / p99.9 µs | server CPU µs/msg (kernel) |");
    println!("|---|---:|---:|---:|");
    for (name, s) in [("ws://", &plain), ("wss://", &tls)] {
        println!(
            "| {name} | {:.0} | {:.0} / {:.0} / {:.0} | {:.1} ({:.1}) |",
            s.msgs_per_s(),
            s.micros(0.5),
            s.micros(0.99),
            s.micros(0.999),
            s.server_cpu_us_per_msg(),
            s.server_sys_us_per_msg()
        );
    }
    println!(
        "wss/ws: throughput {:.0} %, p99 {:.2}x",
        100.0 * tls.msgs_per_s() / plain.msgs_per_s(),
        tls.micros(0.99) / plain.micros(0.99)
    );
    println!();
    Ok(())
}

/// The attacks of `--attacks`.
#[derive(Clone, Copy, Debug)]
enum Attack {
    None,
    Slowloris,
    NeverLogIn,
    Flood,
}

impl Attack {
    fn name(self) -> &'static str {
        match self {
            Attack::None => "no attack",
            Attack::Slowloris => "slowloris: 400 half-open upgrades, 50 addresses",
            Attack::NeverLogIn => "320 sessions never logging in, 40 addresses",
            Attack::Flood => "flood from one address (64 logged-in clients + 64 half-open)",
        }
    }
}

/// An attacker address: 127.1.0.1 onwards, never the operator's 127.0.0.1.
fn attacker(n: usize) -> IpAddr {
    let [hi, lo] = u16::try_from(n).unwrap_or(u16::MAX).to_be_bytes();
    IpAddr::V4(Ipv4Addr::new(127, 1 + hi, lo, 1))
}

/// What the operator saw during one attack.
struct Operator {
    /// Connect, log in, `land` answered: each time.
    lands: Vec<Duration>,
    /// `state` round trips on a logged-in session.
    state: Histogram<u64>,
}

async fn operator(url: &str) -> Result<Operator, BenchError> {
    let mut lands = Vec::new();
    let land_cmd = format!("\"cmd\":{},", u8::from(CommandId::Land));
    for _ in 0..20 {
        let start = Instant::now();
        let mut ws = connect(url, Target::Lluavd).await?;
        let reply = round_trip(&mut ws, "land").await?;
        if !reply.contains(&land_cmd) || reply.contains("Login first") {
            return Err(BenchError::WrongReply(reply));
        }
        lands.push(start.elapsed());
        let _ = ws.close(None).await;
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let mut ws = connect(url, Target::Lluavd).await?;
    let mut state = histogram();
    for _ in 0..2000 {
        let sent = Instant::now();
        let reply = round_trip(&mut ws, FRAME).await?;
        Target::Lluavd.check(&reply)?;
        state.saturating_record(u64::try_from(sent.elapsed().as_nanos()).unwrap_or(u64::MAX));
    }
    Ok(Operator { lands, state })
}

/// Keeps a half-open upgrade from `source` open, reopening it whenever the
/// server drops it.
async fn half_open(source: IpAddr, addr: SocketAddr, stop: Arc<AtomicBool>, opened: Arc<AtomicUsize>) {
    while !stop.load(Ordering::Relaxed) {
        let Ok(mut tcp) = tcp_from(source, addr).await else {
            tokio::time::sleep(Duration::from_millis(10)).await;
            continue;
        };
        opened.fetch_add(1, Ordering::Relaxed);
        if tcp.write_all(b"GET / HTTP/1.1\r\n").await.is_ok() {
            let mut byte = [0u8; 1];
            let _ = timeout(WAIT, tcp.read(&mut byte)).await;
        }
    }
}

/// A WebSocket session from `source` over plain TCP.
async fn session_from(source: IpAddr, addr: SocketAddr) -> Option<Ws> {
    let tcp = tcp_from(source, addr).await.ok()?;
    let transport = lluav_host::client::Transport::Plain(tcp);
    let (ws, _) = tokio_tungstenite::client_async(format!("ws://{addr}"), transport)
        .await
        .ok()?;
    Some(ws)
}

/// A session that never logs in: pings every half second, reconnects
/// whenever it is closed.
async fn never_log_in(source: IpAddr, addr: SocketAddr, stop: Arc<AtomicBool>, opened: Arc<AtomicUsize>) {
    while !stop.load(Ordering::Relaxed) {
        let Some(mut ws) = session_from(source, addr).await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        opened.fetch_add(1, Ordering::Relaxed);
        while !stop.load(Ordering::Relaxed) {
            if ws.send(Message::Ping(b"alive".to_vec().into())).await.is_err() {
                break;
            }
            match timeout(WAIT, ws.next()).await {
                Ok(Some(Ok(Message::Pong(_)))) => tokio::time::sleep(Duration::from_millis(500)).await,
                _ => break,
            }
        }
    }
}

/// A client that knows the password and holds every session it gets.
async fn hoarder(source: IpAddr, addr: SocketAddr, stop: Arc<AtomicBool>, opened: Arc<AtomicUsize>) {
    let mut held = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        match session_from(source, addr).await {
            Some(mut ws) => {
                if round_trip(&mut ws, &format!("login {PASSWORD}")).await.is_ok() {
                    opened.fetch_add(1, Ordering::Relaxed);
                    held.push(ws);
                }
            }
            None => tokio::time::sleep(Duration::from_millis(5)).await,
        }
    }
}

/// Starts `attack` on `attackers`; returns the count of connections the
/// attack opened so far.
fn start(attack: Attack, addr: SocketAddr, attackers: &Runtime, stop: &Arc<AtomicBool>) -> Arc<AtomicUsize> {
    let opened = Arc::new(AtomicUsize::new(0));
    let spawn = |f: std::pin::Pin<Box<dyn std::future::Future<Output = ()> + Send>>| {
        attackers.spawn(f);
    };
    let (s, o) = (stop, &opened);
    match attack {
        Attack::None => {}
        Attack::Slowloris => {
            for i in 0..400 {
                spawn(Box::pin(half_open(
                    attacker(i / 8),
                    addr,
                    Arc::clone(s),
                    Arc::clone(o),
                )));
            }
        }
        Attack::NeverLogIn => {
            for i in 0..320 {
                spawn(Box::pin(never_log_in(
                    attacker(i / 8),
                    addr,
                    Arc::clone(s),
                    Arc::clone(o),
                )));
            }
        }
        Attack::Flood => {
            for _ in 0..64 {
                spawn(Box::pin(hoarder(attacker(0), addr, Arc::clone(s), Arc::clone(o))));
                spawn(Box::pin(half_open(
                    attacker(0),
                    addr,
                    Arc::clone(s),
                    Arc::clone(o),
                )));
            }
        }
    }
    opened
}

fn under_attack(runtime: &Runtime) -> Result<(), BenchError> {
    let mut rows = Vec::new();
    for attack in [Attack::None, Attack::Slowloris, Attack::NeverLogIn, Attack::Flood] {
        let attackers = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .map_err(|e| BenchError::Process(format!("attacker runtime: {e}")))?;
        let dir = temp_dir()?;
        let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
        let stop = Arc::new(AtomicBool::new(false));
        let opened = start(attack, daemon.addr, &attackers, &stop);
        // Let the attack reach its strength before the operator comes.
        std::thread::sleep(Duration::from_secs(3));
        let before = opened.load(Ordering::Relaxed);
        let seen = runtime.block_on(operator(&daemon.url));
        stop.store(true, Ordering::Relaxed);
        attackers.shutdown_timeout(Duration::from_secs(1));
        let seen = seen?;
        println!(
            "{}: attacker connections opened {before} before the operator came",
            attack.name()
        );
        rows.push((attack, seen, opened.load(Ordering::Relaxed)));
    }
    println!();
    println!(
        "| attack | operator: connect + login + `land`, p50 / max ms (20 times) | operator's `state` p50 / p99 / max µs (2000) | attacker connections |"
    );
    println!("|---|---:|---:|---:|");
    for (attack, op, opened) in &rows {
        let mut lands = op.lands.clone();
        lands.sort();
        let ms = |d: Option<&Duration>| d.map_or(f64::NAN, |d| d.as_secs_f64() * 1e3);
        println!(
            "| {} | {:.1} / {:.1} | {:.0} / {:.0} / {:.0} | {opened} |",
            attack.name(),
            ms(lands.get(lands.len() / 2)),
            ms(lands.last()),
            op.state.value_at_quantile(0.5) as f64 / 1e3,
            op.state.value_at_quantile(0.99) as f64 / 1e3,
            op.state.max() as f64 / 1e3,
        );
    }
    println!();
    Ok(())
}

/// Password guesses from one address, 50 connections at once.
async fn guess(url: &str, seconds: u64) -> (usize, usize, Duration) {
    let checked = Arc::new(AtomicUsize::new(0));
    let refused = Arc::new(AtomicUsize::new(0));
    let start = Instant::now();
    let until = start + Duration::from_secs(seconds);
    let mut tasks = Vec::new();
    for worker in 0..50 {
        let (checked, refused, url) = (Arc::clone(&checked), Arc::clone(&refused), url.to_owned());
        tasks.push(tokio::spawn(async move {
            let mut n = 0u64;
            while Instant::now() < until {
                let Ok(mut ws) = lluav_host::client::open(&url, &Default::default()).await else {
                    continue;
                };
                while Instant::now() < until {
                    n += 1;
                    let Ok(reply) = round_trip(&mut ws, &format!("login g{worker}x{n}")).await else {
                        break;
                    };
                    if reply.contains("Wrong password!") {
                        checked.fetch_add(1, Ordering::Relaxed);
                    } else if reply.contains("Too many wrong passwords") {
                        refused.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }));
    }
    for t in tasks {
        let _ = t.await;
    }
    (
        checked.load(Ordering::Relaxed),
        refused.load(Ordering::Relaxed),
        start.elapsed(),
    )
}

fn guessing(scenarios: &Scenarios, runtime: &Runtime) -> Result<(), BenchError> {
    let seconds = if scenarios.seconds == 0 {
        10
    } else {
        scenarios.seconds as u64
    };
    let mut builds = Vec::new();
    if let Some(path) = &scenarios.baseline {
        builds.push(("baseline", path.clone()));
    }
    builds.push(("this build", lluav_tests::lluavd_bin().to_owned()));
    println!();
    println!("| lluavd | passwords checked in {seconds} s | per second | refused unchecked |");
    println!("|---|---:|---:|---:|");
    for (name, bin) in builds {
        let dir = temp_dir()?;
        let options = Options {
            binary: Some(bin.clone()),
            ..Options::password(PASSWORD)
        };
        let daemon = Lluavd::start(dir.path(), &options);
        let (checked, refused, took) = runtime.block_on(guess(&daemon.url, seconds));
        println!(
            "| {name} ({}) | {checked} | {:.1} | {refused} |",
            bin.display(),
            checked as f64 / took.as_secs_f64()
        );
    }
    println!();
    Ok(())
}
