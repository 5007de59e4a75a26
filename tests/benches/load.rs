//! Load generator: the real lluavd against a plain tokio-tungstenite echo
//! server, side by side in one run.
//!
//! ```text
//! cargo bench -p lluav-tests --bench load -- [--connections 1,10,100,1000]
//!     [--messages M | --total N] [--rounds R] [--idle N] [--client-threads T]
//!     [--echo-default-buffers] [--lluavd-echo] [--baseline-lluavd PATH]
//! ```
//!
//! For each connection count C, C WebSocket connections each send M
//! commands closed-loop (the next one only after the previous reply), to
//! the echo server and to lluavd in turn; every round trip's latency goes into
//! an HDR histogram. Both servers get the same frame text (`state`, which
//! lluavd answers after a login with the vehicle's full state) and run the
//! same way: as a separate process on tokio's default multi-thread runtime
//! (lluavd is the release binary started through the test harness on port
//! 0; the echo server is this very binary re-executed with `--serve-echo`),
//! while the client runs on one thread here (`--client-threads`). So the
//! client and the server under test share the machine's cores in the same
//! way for both, and the echo server is the transport's ceiling: what
//! tokio-tungstenite over loopback does with no protocol behind it.
//!
//! Before the load, each server is started fresh and N idle connections
//! are opened (logged in, for lluavd); the growth of the server's VmRSS
//! divided by N is the memory per idle connection.
//!
//! Defaults: 100 000 commands per server, connection count and round
//! (`--total`; M = total / C, at least 20); two rounds that alternate which
//! server goes first, histograms merged over the rounds; 500 idle
//! connections. The echo server and the client are tuned like lluavd's own
//! framing: its message limit, reads of at most a page, replies gathered up
//! to 64 KiB (`--echo-default-buffers`: tungstenite's defaults for the
//! echo server). `--lluavd-echo` adds `lluavd --echo`, lluavd's own
//! connection code with its echo handler, which splits lluavd's cost into
//! transport and protocol. `--baseline-lluavd PATH` loads another lluavd
//! build too (and its `--echo`, with `--lluavd-echo`) in the same rounds,
//! and the summary compares this build with it.
//!
//! The summary at the end is a Markdown table for BENCHMARKS.md.

use std::fmt;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt, stream};
use hdrhistogram::Histogram;
use lluav_host::client::{ConnectOptions, Transport};
use lluav_tests::{Lluavd, Options, WAIT};

#[path = "load/attacks.rs"]
mod attacks;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Barrier;
use tokio::time::timeout;
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;

const PASSWORD: &str = "bench";

/// The command every connection sends: a full trip through the core's
/// gates and the simulator, with a reply of a few hundred bytes.
const FRAME: &str = "state";

/// Connections opened at once while setting up a load, so the servers'
/// accept backlogs never overflow.
const CONNECT_CONCURRENCY: usize = 64;

/// Highest latency the histograms hold (ns); a round trip is bounded by
/// [`WAIT`] anyway.
const MAX_LATENCY_NS: u64 = 120_000_000_000;

type Ws = WebSocketStream<Transport>;

/// Why a run failed.
#[derive(Debug)]
enum BenchError {
    /// The command line was wrong.
    Usage(String),
    /// A connection or its WebSocket handshake failed.
    Connect(String),
    /// A wait took longer than [`WAIT`].
    Timeout(&'static str),
    /// The server closed a connection or the socket failed.
    Lost(String),
    /// The server answered something other than the expected reply.
    WrongReply(String),
    /// A process could not be started or read.
    Process(String),
}

impl fmt::Display for BenchError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BenchError::Usage(m) => write!(f, "usage: {m}"),
            BenchError::Connect(m) => write!(f, "cannot connect: {m}"),
            BenchError::Timeout(what) => write!(f, "no {what} within {WAIT:?}"),
            BenchError::Lost(m) => write!(f, "connection lost: {m}"),
            BenchError::WrongReply(m) => write!(f, "unexpected reply: {m}"),
            BenchError::Process(m) => write!(f, "process: {m}"),
        }
    }
}

struct Args {
    connections: Vec<usize>,
    /// Commands per connection; `None`: `total / C`.
    messages: Option<usize>,
    total: usize,
    rounds: usize,
    idle: usize,
    client_threads: usize,
    serve_echo: bool,
    /// The echo server keeps tungstenite's default buffers instead of
    /// lluavd's.
    echo_default_buffers: bool,
    /// Also load `lluavd --echo`: lluavd's connection code with its echo
    /// handler, to split lluavd's cost into transport and protocol.
    lluavd_echo: bool,
    /// The scenarios of `load/attacks.rs` instead of the echo comparison.
    scenarios: attacks::Scenarios,
}

impl Args {
    fn parse() -> Result<Args, BenchError> {
        let mut args = Args {
            connections: vec![1, 10, 100, 1000],
            messages: None,
            total: 100_000,
            rounds: 2,
            idle: 500,
            client_threads: 1,
            serve_echo: false,
            echo_default_buffers: false,
            lluavd_echo: false,
            scenarios: attacks::Scenarios::default(),
        };
        let mut it = std::env::args().skip(1);
        while let Some(arg) = it.next() {
            let mut value = |name: &str| {
                it.next()
                    .ok_or_else(|| BenchError::Usage(format!("{name} needs a value")))
            };
            match arg.as_str() {
                "--connections" => {
                    args.connections = value("--connections")?
                        .split(',')
                        .map(|c| number("--connections", c))
                        .collect::<Result<_, _>>()?;
                }
                "--messages" => args.messages = Some(number("--messages", &value("--messages")?)?),
                "--total" => args.total = number("--total", &value("--total")?)?,
                "--rounds" => args.rounds = number("--rounds", &value("--rounds")?)?,
                "--idle" => args.idle = number("--idle", &value("--idle")?)?,
                "--client-threads" => {
                    args.client_threads = number("--client-threads", &value("--client-threads")?)?
                }
                "--serve-echo" => args.serve_echo = true,
                "--echo-default-buffers" => args.echo_default_buffers = true,
                "--lluavd-echo" => args.lluavd_echo = true,
                "--attacks" => args.scenarios.attacks = true,
                "--tls" => args.scenarios.tls = true,
                "--guesses" => args.scenarios.guesses = true,
                "--seconds" => args.scenarios.seconds = number("--seconds", &value("--seconds")?)?,
                "--baseline-lluavd" => args.scenarios.baseline = Some(value("--baseline-lluavd")?.into()),
                // cargo bench passes --bench to every bench binary.
                "--bench" => {}
                other => {
                    return Err(BenchError::Usage(format!(
                        "unknown argument {other}; \
                         [--connections 1,10,100,1000] [--messages M | --total N] [--rounds R] [--idle N] [--client-threads T] [--echo-default-buffers] [--lluavd-echo] [--baseline-lluavd PATH] \
                         [--attacks] [--tls] [--guesses] [--seconds S]"
                    )));
                }
            }
        }
        Ok(args)
    }

    fn messages_for(&self, connections: usize) -> usize {
        // Every connection sends enough for its own warm-up and tail.
        self.messages.unwrap_or((self.total / connections).max(20))
    }
}

fn number(name: &str, text: &str) -> Result<usize, BenchError> {
    match text.trim().parse() {
        Ok(n) if n > 0 => Ok(n),
        _ => Err(BenchError::Usage(format!(
            "{name}: `{text}` is not a positive number"
        ))),
    }
}

fn main() {
    let result = Args::parse().and_then(|args| {
        if args.serve_echo {
            serve_echo(args.echo_default_buffers)
        } else if args.scenarios.any() {
            attacks::run(&args)
        } else {
            bench(&args)
        }
    });
    if let Err(e) = result {
        eprintln!("load: {e}");
        std::process::exit(1);
    }
}

fn client_runtime(threads: usize) -> Result<tokio::runtime::Runtime, BenchError> {
    let built = if threads == 1 {
        tokio::runtime::Builder::new_current_thread().enable_all().build()
    } else {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(threads)
            .enable_all()
            .build()
    };
    built.map_err(|e| BenchError::Process(format!("client runtime: {e}")))
}

/// The server processes a load runs against.
struct Servers {
    echo: EchoServer,
    lluavd: Lluavd,
    lluavd_echo: Option<Lluavd>,
    /// `--baseline-lluavd`: that build, and its `--echo` with `--lluavd-echo`.
    baseline: Option<Lluavd>,
    baseline_echo: Option<Lluavd>,
    _dir: tempfile::TempDir,
}

impl Servers {
    fn start(max_connections: usize, args: &Args) -> Result<Servers, BenchError> {
        let dir = tempfile::tempdir().map_err(|e| BenchError::Process(format!("temp dir: {e}")))?;
        let max = max_connections.to_string();
        let daemon = |binary: Option<&std::path::Path>, echo: bool, sub: &str| {
            let options = if echo {
                Options::default().with_args(&["--echo", "--max-connections", &max])
            } else {
                Options::password(PASSWORD).with_args(&["--max-connections", &max])
            };
            let options = Options {
                binary: binary.map(Into::into),
                ..options.per_ip(max_connections)
            };
            Lluavd::start(&dir.path().join(sub), &options)
        };
        let lluavd = daemon(None, false, "lluavd");
        let lluavd_echo = args.lluavd_echo.then(|| daemon(None, true, "echo"));
        let base = args.scenarios.baseline.as_deref();
        let baseline = base.map(|b| daemon(Some(b), false, "baseline"));
        let baseline_echo = base
            .filter(|_| args.lluavd_echo)
            .map(|b| daemon(Some(b), true, "baseline-echo"));
        let echo = EchoServer::start(args.echo_default_buffers)?;
        Ok(Servers {
            echo,
            lluavd,
            lluavd_echo,
            baseline,
            baseline_echo,
            _dir: dir,
        })
    }
}

/// One row of the summary.
struct Row {
    connections: usize,
    messages: usize,
    echo: Stats,
    lluavd: Stats,
    lluavd_echo: Option<Stats>,
    baseline: Option<Stats>,
    baseline_echo: Option<Stats>,
}

fn bench(args: &Args) -> Result<(), BenchError> {
    raise_open_file_limit(args.connections.iter().copied().max().unwrap_or(1).max(args.idle))?;
    let load_before = load_average();
    println!("lluavd:  {}", lluav_tests::lluavd_bin().display());
    println!(
        "machine: {} CPUs, load average {load_before}; client: {} thread(s); frame `{FRAME}`",
        std::thread::available_parallelism().map_or(0, usize::from),
        args.client_threads,
    );
    let runtime = client_runtime(args.client_threads)?;
    let max_connections = args.connections.iter().copied().max().unwrap_or(1).max(args.idle) + 64;

    // Memory first, on fresh processes: after a load, freed buffers would
    // absorb new connections and hide their cost.
    let memory = {
        let servers = Servers::start(max_connections, args)?;
        runtime.block_on(idle_memory(&servers, args.idle))?
    };
    println!(
        "idle connections: {}; VmRSS per connection: echo {:.1} KiB, lluavd {:.1} KiB",
        args.idle, memory.echo, memory.lluavd
    );

    let servers = Servers::start(max_connections, args)?;
    // For `perf record -p PID` or `/proc/PID/status` while the load runs.
    println!(
        "pids: lluavd {}, echo server {}",
        servers.lluavd.pid(),
        servers.echo.child.id()
    );
    let (echo_pid, lluavd_pid) = (servers.echo.child.id(), servers.lluavd.pid());
    let echo_url = servers.echo.url.clone();
    let lluavd_url = servers.lluavd.url.clone();
    let (echo_reply, lluavd_reply) = runtime.block_on(async {
        let mut echo = connect(&echo_url, Target::Echo).await?;
        let mut lluavd = connect(&lluavd_url, Target::Lluavd).await?;
        Ok::<_, BenchError>((
            round_trip(&mut echo, FRAME).await?,
            round_trip(&mut lluavd, FRAME).await?,
        ))
    })?;
    println!(
        "replies to `{FRAME}`: echo {} bytes, lluavd {} bytes: {lluavd_reply}",
        echo_reply.len(),
        lluavd_reply.len()
    );
    let mut rows = Vec::new();
    for &c in &args.connections {
        let m = args.messages_for(c);
        // Every server this run loads, with its totals over the rounds.
        let mut loads: Vec<(Target, &str, u32, Option<Stats>)> = vec![
            (Target::Echo, &echo_url, echo_pid, None),
            (Target::Lluavd, &lluavd_url, lluavd_pid, None),
        ];
        let optional = [
            (Target::LluavdEcho, &servers.lluavd_echo),
            (Target::Baseline, &servers.baseline),
            (Target::BaselineEcho, &servers.baseline_echo),
        ];
        for (target, daemon) in optional {
            if let Some(d) = daemon {
                loads.push((target, &d.url, d.pid(), None));
            }
        }
        for round in 0..args.rounds {
            // Alternate who goes first, so that a change in the machine's
            // background load does not always fall on the same server.
            let mut order: Vec<usize> = (0..loads.len()).collect();
            if round % 2 == 1 {
                order.reverse();
            }
            for i in order {
                let (target, url, pid, total) = &mut loads[i];
                let stats = runtime.block_on(load(url, *pid, *target, c, m))?;
                println!("{:<7} C={c:<5} M={m:<6} round {round}: {stats}", target.name());
                match total {
                    Some(t) => t.merge(&stats)?,
                    None => *total = Some(stats),
                }
            }
        }
        let mut take = |want: Target| loads.iter_mut().find(|l| l.0 == want).and_then(|l| l.3.take());
        if let (Some(echo), Some(lluavd)) = (take(Target::Echo), take(Target::Lluavd)) {
            rows.push(Row {
                connections: c,
                messages: m,
                echo,
                lluavd,
                lluavd_echo: take(Target::LluavdEcho),
                baseline: take(Target::Baseline),
                baseline_echo: take(Target::BaselineEcho),
            });
        }
    }
    drop(servers);
    let load_after = load_average();
    print_summary(&rows, &memory, args.idle, &load_before, &load_after);
    Ok(())
}

/// The one-minute load averages from `/proc/loadavg`.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

/// 1000 client sockets here and as many in each server need more than the
/// usual soft limit of 1024 descriptors; the servers inherit it.
fn raise_open_file_limit(connections: usize) -> Result<(), BenchError> {
    let needed = u64::try_from(connections)
        .unwrap_or(u64::MAX)
        .saturating_mul(2)
        .saturating_add(256);
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes into the struct we pass and nothing else.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } != 0 {
        return Err(BenchError::Process(format!(
            "getrlimit: {}",
            std::io::Error::last_os_error()
        )));
    }
    if limit.rlim_cur >= needed {
        return Ok(());
    }
    if limit.rlim_max < needed {
        return Err(BenchError::Process(format!(
            "{connections} connections need {needed} open files, the hard limit is {}",
            limit.rlim_max
        )));
    }
    limit.rlim_cur = needed;
    // SAFETY: setrlimit only reads the struct we pass.
    if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &limit) } != 0 {
        return Err(BenchError::Process(format!(
            "setrlimit: {}",
            std::io::Error::last_os_error()
        )));
    }
    Ok(())
}

/// Which server a connection talks to, and so what its replies must be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Target {
    Echo,
    Lluavd,
    LluavdEcho,
    /// `--baseline-lluavd`.
    Baseline,
    /// `--baseline-lluavd` with `--echo`.
    BaselineEcho,
}

impl Target {
    fn name(self) -> &'static str {
        match self {
            Target::Echo => "echo",
            Target::Lluavd => "lluavd",
            Target::LluavdEcho => "lluavd --echo",
            Target::Baseline => "baseline",
            Target::BaselineEcho => "baseline --echo",
        }
    }

    /// A reply counts only if it is the right one: the frame itself from the
    /// echo server, a successful response (ret 0; the core always writes
    /// `ret` first) from lluavd.
    fn check(self, reply: &str) -> Result<(), BenchError> {
        let ok = match self {
            Target::Echo | Target::LluavdEcho | Target::BaselineEcho => reply == FRAME,
            Target::Lluavd | Target::Baseline => reply.starts_with("{\"ret\":0,"),
        };
        if ok {
            Ok(())
        } else {
            Err(BenchError::WrongReply(format!("{self:?}: {reply}")))
        }
    }
}

async fn connect(url: &str, target: Target) -> Result<Ws, BenchError> {
    // Nagle off (the client sets it), as lluavd and the echo server have
    // it: small request and reply frames must not wait for delayed ACKs.
    // `wss://` is lluavd with a certificate from the test CA.
    let options = if url.starts_with("wss://") {
        lluav_tests::test_ca().options()
    } else {
        ConnectOptions::default()
    };
    let mut ws = timeout(
        WAIT,
        lluav_host::client::open_with_config(url, &options, Some(transport_config())),
    )
    .await
    .map_err(|_| BenchError::Timeout("WebSocket handshake"))?
    .map_err(|e| BenchError::Connect(format!("{url}: {e}")))?;
    match target {
        Target::Lluavd | Target::Baseline => {
            let reply = round_trip(&mut ws, &format!("login {PASSWORD}")).await?;
            target.check(&reply)?;
        }
        // The echo server's connection does its first read and write, as a
        // login does for lluavd's.
        Target::Echo | Target::LluavdEcho | Target::BaselineEcho => {
            let reply = round_trip(&mut ws, FRAME).await?;
            target.check(&reply)?;
        }
    }
    Ok(ws)
}

async fn connect_all(url: &str, target: Target, n: usize) -> Result<Vec<Ws>, BenchError> {
    stream::iter(0..n)
        .map(|_| connect(url, target))
        .buffer_unordered(CONNECT_CONCURRENCY)
        .collect::<Vec<_>>()
        .await
        .into_iter()
        .collect()
}

async fn close_all(conns: Vec<Ws>) {
    stream::iter(conns)
        .for_each_concurrent(CONNECT_CONCURRENCY, |mut ws| async move {
            let _ = timeout(WAIT, async {
                let _ = ws.close(None).await;
                while let Some(Ok(_)) = ws.next().await {}
            })
            .await;
        })
        .await;
}

/// Sends one text frame and returns the next text reply.
async fn round_trip(ws: &mut Ws, frame: &str) -> Result<String, BenchError> {
    ws.send(Message::text(frame))
        .await
        .map_err(|e| BenchError::Lost(e.to_string()))?;
    loop {
        let next = timeout(WAIT, ws.next())
            .await
            .map_err(|_| BenchError::Timeout("reply"))?;
        match next {
            Some(Ok(Message::Text(t))) => return Ok(t.as_str().to_owned()),
            Some(Ok(Message::Ping(_) | Message::Pong(_) | Message::Frame(_))) => {}
            Some(Ok(other)) => return Err(BenchError::WrongReply(format!("{other:?}"))),
            Some(Err(e)) => return Err(BenchError::Lost(e.to_string())),
            None => return Err(BenchError::Lost("stream ended".into())),
        }
    }
}

/// Throughput and latency of one load.
/// Throughput and latency of one or more loads (rounds add up).
struct Stats {
    /// Wall time of the measured parts.
    elapsed: Duration,
    /// The server process's user + system CPU time meanwhile, in ticks.
    server_ticks: u64,
    /// The part of `server_ticks` spent in the kernel.
    server_sys_ticks: u64,
    /// This process's (the client's) CPU time meanwhile, in ticks.
    client_ticks: u64,
    histogram: Histogram<u64>,
}

impl Stats {
    fn msgs_per_s(&self) -> f64 {
        self.histogram.len() as f64 / self.elapsed.as_secs_f64()
    }

    /// What each reply costs the server, whatever else shares the machine.
    fn server_cpu_us_per_msg(&self) -> f64 {
        ticks_to_s(self.server_ticks) * 1e6 / self.histogram.len() as f64
    }

    /// The client's CPU time over wall time: near 1.0 (it has one thread by
    /// default) would mean the client, not the server, set the pace.
    /// The kernel's part of [`Stats::server_cpu_us_per_msg`].
    fn server_sys_us_per_msg(&self) -> f64 {
        ticks_to_s(self.server_sys_ticks) * 1e6 / self.histogram.len() as f64
    }

    fn client_cpu_share(&self) -> f64 {
        ticks_to_s(self.client_ticks) / self.elapsed.as_secs_f64()
    }

    fn merge(&mut self, other: &Stats) -> Result<(), BenchError> {
        self.elapsed += other.elapsed;
        self.server_ticks += other.server_ticks;
        self.server_sys_ticks += other.server_sys_ticks;
        self.client_ticks += other.client_ticks;
        self.histogram
            .add(&other.histogram)
            .map_err(|e| BenchError::Process(format!("histogram: {e:?}")))
    }

    fn micros(&self, quantile: f64) -> f64 {
        self.histogram.value_at_quantile(quantile) as f64 / 1000.0
    }
}

impl fmt::Display for Stats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{:>7.0} msg/s  p50 {:>7.1} µs  p99 {:>8.1} µs  p99.9 {:>8.1} µs  max {:>9.1} µs  \
             server CPU {:>5.1} µs/msg ({:.1} in the kernel)  client CPU {:>3.0} %  ({} samples)",
            self.msgs_per_s(),
            self.micros(0.5),
            self.micros(0.99),
            self.micros(0.999),
            self.histogram.max() as f64 / 1000.0,
            self.server_cpu_us_per_msg(),
            self.server_sys_us_per_msg(),
            100.0 * self.client_cpu_share(),
            self.histogram.len(),
        )
    }
}

fn histogram() -> Histogram<u64> {
    // Bounds and precision are constants that hdrhistogram accepts.
    Histogram::new_with_bounds(1, MAX_LATENCY_NS, 3).expect("valid histogram bounds")
}

/// C connections × M closed-loop commands; the first tenth of each
/// connection's commands warms up and is not measured.
async fn load(url: &str, server_pid: u32, target: Target, c: usize, m: usize) -> Result<Stats, BenchError> {
    let conns = connect_all(url, target, c).await?;
    let warm_up = (m / 10).max(1);
    // Everyone starts the measured part together, after every warm-up.
    let barrier = Arc::new(Barrier::new(c + 1));
    let mut tasks = Vec::with_capacity(c);
    for mut ws in conns {
        let barrier = Arc::clone(&barrier);
        tasks.push(tokio::spawn(async move {
            let mut h = histogram();
            let mut result = Ok(());
            for _ in 0..warm_up {
                result = round_trip(&mut ws, FRAME).await.and_then(|r| target.check(&r));
                if result.is_err() {
                    break;
                }
            }
            // Waited for even after a failure, so the others are not stuck.
            barrier.wait().await;
            if result.is_ok() {
                for _ in 0..m {
                    let sent = Instant::now();
                    result = round_trip(&mut ws, FRAME).await.and_then(|r| target.check(&r));
                    if result.is_err() {
                        break;
                    }
                    let ns = u64::try_from(sent.elapsed().as_nanos()).unwrap_or(u64::MAX);
                    h.saturating_record(ns);
                }
            }
            (result, h, ws)
        }));
    }
    barrier.wait().await;
    let start = Instant::now();
    let server_stat = format!("/proc/{server_pid}/stat");
    let (server_user_start, server_sys_start) = cpu_ticks(&server_stat)?;
    let client_cpu_start = cpu_ticks("/proc/self/stat").map(|(u, s)| u + s)?;
    let mut all = histogram();
    let mut conns = Vec::with_capacity(c);
    let mut failure = None;
    for task in tasks {
        let (result, h, ws) = task
            .await
            .map_err(|e| BenchError::Process(format!("client task: {e}")))?;
        if let Err(e) = result {
            failure.get_or_insert(e);
        }
        all.add(&h)
            .map_err(|e| BenchError::Process(format!("histogram: {e:?}")))?;
        conns.push(ws);
    }
    let elapsed = start.elapsed();
    let (server_user, server_sys) = cpu_ticks(&server_stat)?;
    let server_sys_ticks = server_sys.saturating_sub(server_sys_start);
    let server_ticks = server_user.saturating_sub(server_user_start) + server_sys_ticks;
    let client_ticks = cpu_ticks("/proc/self/stat")
        .map(|(u, s)| u + s)?
        .saturating_sub(client_cpu_start);
    close_all(conns).await;
    if let Some(e) = failure {
        return Err(e);
    }
    Ok(Stats {
        elapsed,
        server_ticks,
        server_sys_ticks,
        client_ticks,
        histogram: all,
    })
}

/// KiB of VmRSS per idle connection.
struct Memory {
    echo: f64,
    lluavd: f64,
    baseline: Option<f64>,
}

async fn idle_memory(servers: &Servers, n: usize) -> Result<Memory, BenchError> {
    async fn per_connection(pid: u32, url: &str, target: Target, n: usize) -> Result<f64, BenchError> {
        let before = vm_rss_kib(pid)?;
        let conns = connect_all(url, target, n).await?;
        // Every connection has been answered, so the server holds all of
        // its state for it.
        let after = vm_rss_kib(pid)?;
        close_all(conns).await;
        Ok((after as f64 - before as f64) / n as f64)
    }
    let baseline = match &servers.baseline {
        Some(d) => Some(per_connection(d.pid(), &d.url, Target::Baseline, n).await?),
        None => None,
    };
    Ok(Memory {
        echo: per_connection(servers.echo.child.id(), &servers.echo.url, Target::Echo, n).await?,
        lluavd: per_connection(servers.lluavd.pid(), &servers.lluavd.url, Target::Lluavd, n).await?,
        baseline,
    })
}

/// (utime, stime), in clock ticks, from a `/proc/PID/stat` file.
fn cpu_ticks(path: &str) -> Result<(u64, u64), BenchError> {
    let stat = std::fs::read_to_string(path).map_err(|e| BenchError::Process(format!("{path}: {e}")))?;
    // The command name may hold spaces; the fields after it do not. utime
    // and stime are fields 14 and 15, the 12th and 13th after the name.
    let after_name = stat.rsplit_once(')').map(|(_, rest)| rest).unwrap_or_default();
    let mut fields = after_name.split_whitespace().skip(11);
    let mut next = || fields.next().and_then(|f| f.parse::<u64>().ok());
    match (next(), next()) {
        (Some(user), Some(system)) => Ok((user, system)),
        _ => Err(BenchError::Process(format!("{path}: no utime/stime"))),
    }
}

fn ticks_to_s(ticks: u64) -> f64 {
    // SAFETY: sysconf only reads a configuration value.
    let per_s = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    ticks as f64 / if per_s > 0 { per_s as f64 } else { 100.0 }
}

fn vm_rss_kib(pid: u32) -> Result<u64, BenchError> {
    let path = format!("/proc/{pid}/status");
    let status = std::fs::read_to_string(&path).map_err(|e| BenchError::Process(format!("{path}: {e}")))?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().strip_suffix("kB"))
        .and_then(|v| v.trim().parse().ok())
        .ok_or_else(|| BenchError::Process(format!("{path}: no VmRSS line")))
}

fn print_summary(rows: &[Row], memory: &Memory, idle: usize, load_before: &str, load_after: &str) {
    println!();
    println!("load average before {load_before}, after {load_after}");
    println!();
    println!(
        "| C | M/conn | echo msg/s | echo p50 / p99 / p99.9 µs | lluavd msg/s | lluavd p50 / p99 / p99.9 µs | \
         throughput lluavd/echo | p99 lluavd/echo | server CPU µs/msg (kernel) echo / lluavd | client CPU echo / lluavd |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        println!(
            "| {} | {} | {:.0} | {:.0} / {:.0} / {:.0} | {:.0} | {:.0} / {:.0} / {:.0} | {:.0} % | {:.2}x | {:.1} ({:.1}) / {:.1} ({:.1}) | {:.0} % / {:.0} % |",
            r.connections,
            r.messages,
            r.echo.msgs_per_s(),
            r.echo.micros(0.5),
            r.echo.micros(0.99),
            r.echo.micros(0.999),
            r.lluavd.msgs_per_s(),
            r.lluavd.micros(0.5),
            r.lluavd.micros(0.99),
            r.lluavd.micros(0.999),
            100.0 * r.lluavd.msgs_per_s() / r.echo.msgs_per_s(),
            r.lluavd.micros(0.99) / r.echo.micros(0.99),
            r.echo.server_cpu_us_per_msg(),
            r.echo.server_sys_us_per_msg(),
            r.lluavd.server_cpu_us_per_msg(),
            r.lluavd.server_sys_us_per_msg(),
            100.0 * r.echo.client_cpu_share(),
            100.0 * r.lluavd.client_cpu_share(),
        );
    }
    if rows.iter().any(|r| r.lluavd_echo.is_some()) {
        println!();
        println!(
            "| C | lluavd --echo msg/s | lluavd --echo p50 / p99 / p99.9 µs | throughput against echo | p99 against echo | server CPU µs/msg (kernel) |"
        );
        println!("|---:|---:|---:|---:|---:|---:|");
        for r in rows {
            if let Some(e) = &r.lluavd_echo {
                println!(
                    "| {} | {:.0} | {:.0} / {:.0} / {:.0} | {:.0} % | {:.2}x | {:.1} ({:.1}) |",
                    r.connections,
                    e.msgs_per_s(),
                    e.micros(0.5),
                    e.micros(0.99),
                    e.micros(0.999),
                    100.0 * e.msgs_per_s() / r.echo.msgs_per_s(),
                    e.micros(0.99) / r.echo.micros(0.99),
                    e.server_cpu_us_per_msg(),
                    e.server_sys_us_per_msg(),
                );
            }
        }
    }
    print_against_baseline(rows);
    println!();
    println!(
        "VmRSS per idle connection ({idle} connections): lluavd {:.1} KiB (logged in), echo {:.1} KiB",
        memory.lluavd, memory.echo
    );
    if let Some(b) = memory.baseline {
        println!("VmRSS per idle connection, baseline lluavd: {b:.1} KiB (logged in)");
    }
}

/// This build's and the baseline's figures of one server in a row.
type Pair = fn(&Row) -> Option<(&Stats, &Stats)>;

/// With `--baseline-lluavd`: this build against the baseline, server by
/// server (lluavd, and `--echo` with `--lluavd-echo`).
fn print_against_baseline(rows: &[Row]) {
    let pairs: [(&str, Pair); 2] = [
        ("lluavd", |r| r.baseline.as_ref().map(|b| (&r.lluavd, b))),
        ("lluavd --echo", |r| {
            r.lluavd_echo.as_ref().zip(r.baseline_echo.as_ref())
        }),
    ];
    for (name, pair) in pairs {
        if !rows.iter().any(|r| pair(r).is_some()) {
            continue;
        }
        println!();
        println!(
            "| C | {name} msg/s this / baseline | throughput this/baseline | server CPU µs/msg (kernel) this / baseline | CPU this/baseline | p99 µs this / baseline |"
        );
        println!("|---:|---:|---:|---:|---:|---:|");
        for r in rows {
            if let Some((this, base)) = pair(r) {
                println!(
                    "| {} | {:.0} / {:.0} | {:.1} % | {:.2} ({:.2}) / {:.2} ({:.2}) | {:.3}x | {:.0} / {:.0} |",
                    r.connections,
                    this.msgs_per_s(),
                    base.msgs_per_s(),
                    100.0 * this.msgs_per_s() / base.msgs_per_s(),
                    this.server_cpu_us_per_msg(),
                    this.server_sys_us_per_msg(),
                    base.server_cpu_us_per_msg(),
                    base.server_sys_us_per_msg(),
                    this.server_cpu_us_per_msg() / base.server_cpu_us_per_msg(),
                    this.micros(0.99),
                    base.micros(0.99),
                );
            }
        }
    }
}

/// The echo server's and the client's tungstenite settings, tuned like
/// lluavd's own framing: its message limit (`Limits::default`), replies
/// gathered up to 64 KiB before a write, and reads of at most a page
/// (`READ_CHUNK`). tungstenite zeroes its read buffer before every read,
/// so its default of 128 KiB costs microseconds per message and would make
/// the echo server a lower ceiling than it need be.
fn transport_config() -> WebSocketConfig {
    let limits = lluav_host::net::Limits::default();
    WebSocketConfig::default()
        .max_message_size(Some(limits.max_message))
        .max_frame_size(Some(limits.max_message))
        .read_buffer_size(lluav_host::net::reader::READ_CHUNK)
        .write_buffer_size(64 * 1024)
}

/// The echo server as a child process (this binary with `--serve-echo`).
struct EchoServer {
    child: Child,
    url: String,
}

impl EchoServer {
    fn start(default_buffers: bool) -> Result<EchoServer, BenchError> {
        let exe = std::env::current_exe().map_err(|e| BenchError::Process(format!("current exe: {e}")))?;
        let mut command = Command::new(exe);
        command.arg("--serve-echo");
        if default_buffers {
            command.arg("--echo-default-buffers");
        }
        let mut child = command
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| BenchError::Process(format!("echo server: {e}")))?;
        let stdout = child
            .stdout
            .take()
            .ok_or_else(|| BenchError::Process("no stdout".into()))?;
        let mut line = String::new();
        // The child prints its line at once or fails; it exits when our end
        // of its stdin closes, so a hang here would be a bug in it.
        let read = BufReader::new(stdout).read_line(&mut line);
        match line.trim().strip_prefix("listening on ") {
            Some(url) if read.is_ok() => Ok(EchoServer {
                url: url.to_owned(),
                child,
            }),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                Err(BenchError::Process(format!("echo server said {line:?}")))
            }
        }
    }
}

impl Drop for EchoServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `--serve-echo`: a plain tokio-tungstenite echo server on the runtime
/// lluavd uses (tokio's default multi-thread one), until stdin closes.
fn serve_echo(default_buffers: bool) -> Result<(), BenchError> {
    // The parent holds our stdin: when it exits, however it exits, so do we.
    std::thread::spawn(|| {
        let mut sink = Vec::new();
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut sink);
        std::process::exit(0);
    });
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| BenchError::Process(format!("echo runtime: {e}")))?;
    runtime.block_on(async {
        let listener = TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(|e| BenchError::Process(format!("echo bind: {e}")))?;
        let addr = listener
            .local_addr()
            .map_err(|e| BenchError::Process(format!("echo address: {e}")))?;
        println!("listening on ws://{addr}");
        loop {
            let Ok((stream, _)) = listener.accept().await else {
                // Typically EMFILE; the client reports the refused connection.
                continue;
            };
            let _ = stream.set_nodelay(true);
            let config = (!default_buffers).then(transport_config);
            tokio::spawn(echo_connection(stream, config));
        }
    })
}

async fn echo_connection(stream: TcpStream, config: Option<WebSocketConfig>) {
    let Ok(mut ws) = tokio_tungstenite::accept_async_with_config(stream, config).await else {
        return;
    };
    while let Some(Ok(message)) = ws.next().await {
        if message.is_text() && ws.send(message).await.is_err() {
            break;
        }
    }
}
