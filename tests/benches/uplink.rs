//! The uplink measured, in one run on one Mosquitto:
//!
//! ```text
//! cargo bench -p lluav-tests --features broker --bench uplink -- [--round-trips N] [--vehicles V] [--fan-outs F]
//! ```
//!
//! 1. Round trips, closed loop, one request at a time: `state` through
//!    lluavd's uplink (a request envelope on `lluav/V/req/C`, QoS 1, the
//!    answer on `lluav/V/res/C`, QoS 1), the same `state` over WebSocket to
//!    the same lluavd, and a bare MQTT echo: a plain rumqttc client (this
//!    binary re-executed with `--mqtt-echo`, a process of its own like
//!    lluavd) answering every message on its request topic at once, on its
//!    response topic, with a payload as long as lluavd's answer. Two rounds
//!    that alternate the order; p50/p99 in µs and the uplink's ratio to the
//!    echo.
//! 2. A fleet: V lluavd (release) on the broker, each publishing its state
//!    at 1 Hz. The broker's CPU over 10 s of that; then F fan-outs of one
//!    `state` to every vehicle from one operator (the time from the first
//!    request out to the last answer in); each lluavd's VmRSS, against one
//!    lluavd without an uplink.
//!
//! Defaults: 2000 round trips per path and round (200 more to warm up),
//! 100 vehicles, 50 fan-outs. The summary is Markdown for BENCHMARKS.md.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use hdrhistogram::Histogram;
use lluav_tests::broker::{Mosquitto, Mqtt};
use lluav_tests::{Lluavd, Options};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio_tungstenite::tungstenite::Message;

const WARM_UP: usize = 200;

struct Args {
    round_trips: usize,
    vehicles: usize,
    fan_outs: usize,
}

fn args() -> Args {
    let mut a = Args {
        round_trips: 2000,
        vehicles: 100,
        fan_outs: 50,
    };
    let argv: Vec<String> = std::env::args().collect();
    for pair in argv.windows(2) {
        let n = pair[1].parse().ok();
        match (pair[0].as_str(), n) {
            ("--round-trips", Some(n)) => a.round_trips = n,
            ("--vehicles", Some(n)) => a.vehicles = n,
            ("--fan-outs", Some(n)) => a.fan_outs = n,
            _ => {}
        }
    }
    a
}

fn histogram() -> Histogram<u64> {
    // Bounds and precision are constants that hdrhistogram accepts.
    Histogram::new_with_bounds(1, 60_000_000_000, 3).expect("valid histogram bounds")
}

fn record(h: &mut Histogram<u64>, since: Instant) {
    h.saturating_record(u64::try_from(since.elapsed().as_nanos()).unwrap_or(u64::MAX));
}

fn us(h: &Histogram<u64>, q: f64) -> f64 {
    h.value_at_quantile(q) as f64 / 1000.0
}

/// The bare echo, as a process of its own: every message on `echo/req/+`
/// answered on `echo/res/<same>` with `size` bytes, at once.
fn serve_echo(port: u16, size: usize) {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async move {
        let mut options = MqttOptions::new("bench-echo", "127.0.0.1", port);
        options.set_max_packet_size(1 << 20, 1 << 20);
        let (client, mut events) = AsyncClient::new(options, 1024);
        let answer = vec![b'x'; size];
        let mut network = rumqttc::NetworkOptions::new();
        network.set_tcp_nodelay(true);
        events.set_network_options(network);
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    client
                        .try_subscribe("echo/req/+", QoS::AtLeastOnce)
                        .expect("subscribe queued");
                }
                Ok(Event::Incoming(Packet::SubAck(_))) => println!("ready"),
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let topic = p.topic.replacen("/req/", "/res/", 1);
                    let _ = client.try_publish(topic, QoS::AtLeastOnce, false, answer.clone());
                }
                Ok(_) => {}
                Err(e) => panic!("echo: {e}"),
            }
        }
    });
}

/// One requester over MQTT: publish, wait for the next message.
struct Requester {
    mqtt: Mqtt,
    topic: String,
}

impl Requester {
    async fn new(broker: &Mosquitto, id: &str, requests: String, answers: &str) -> Requester {
        let mut mqtt = Mqtt::connect(broker, id).await;
        mqtt.subscribe(answers).await;
        Requester {
            mqtt,
            topic: requests,
        }
    }

    async fn run(&mut self, n: usize, h: &mut Histogram<u64>) -> usize {
        let mut size = 0;
        for i in 0..n + WARM_UP {
            let envelope = format!(r#"{{"id":"{i}","frame":"state"}}"#);
            let sent = Instant::now();
            self.mqtt
                .publish(&self.topic, envelope, QoS::AtLeastOnce, false)
                .await;
            size = self.mqtt.next().await.payload.len();
            if i >= WARM_UP {
                record(h, sent);
            }
        }
        size
    }
}

async fn websocket(url: &str, n: usize, h: &mut Histogram<u64>) {
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.expect("WebSocket");
    for i in 0..n + WARM_UP {
        let sent = Instant::now();
        ws.send(Message::text("state")).await.expect("sent");
        loop {
            if let Some(Ok(Message::Text(_))) = ws.next().await {
                break;
            }
        }
        if i >= WARM_UP {
            record(h, sent);
        }
    }
    let _ = ws.close(None).await;
}

fn spawn_echo(port: u16, size: usize) -> Child {
    let mut child = Command::new(std::env::current_exe().expect("this binary"))
        .args(["--mqtt-echo", &port.to_string(), &size.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .expect("echo starts");
    let mut line = String::new();
    let mut out = std::io::BufReader::new(child.stdout.take().expect("stdout"));
    std::io::BufRead::read_line(&mut out, &mut line).expect("echo ready");
    assert_eq!(line.trim(), "ready");
    child
}

async fn round_trips(a: &Args) {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options::default().with_args(&["--allow-no-password"]);
    let daemon = lluav_tests::broker::vehicle(dir.path(), &broker, "bench", options).await;
    let mut uplink = Requester::new(
        &broker,
        "rt-up",
        "lluav/bench/req/rt-up".into(),
        "lluav/bench/res/rt-up",
    )
    .await;
    let mut h_up = histogram();
    let size = uplink.run(10, &mut histogram()).await;
    let mut echo_process = spawn_echo(broker.port, size);
    let mut echo = Requester::new(&broker, "rt-echo", "echo/req/rt-echo".into(), "echo/res/rt-echo").await;
    let (mut h_ws, mut h_echo) = (histogram(), histogram());
    for round in 0..2 {
        if round % 2 == 0 {
            echo.run(a.round_trips, &mut h_echo).await;
            uplink.run(a.round_trips, &mut h_up).await;
            websocket(&daemon.url, a.round_trips, &mut h_ws).await;
        } else {
            websocket(&daemon.url, a.round_trips, &mut h_ws).await;
            uplink.run(a.round_trips, &mut h_up).await;
            echo.run(a.round_trips, &mut h_echo).await;
        }
    }
    let _ = echo_process.kill();
    let _ = echo_process.wait();
    println!(
        "\n`state` round trips, closed loop, {} per path and round, 2 rounds ({size}-byte answers):\n",
        a.round_trips
    );
    println!("| path | p50 µs | p99 µs | p50 / echo | p99 / echo |");
    println!("|---|---:|---:|---:|---:|");
    for (name, h) in [
        ("bare MQTT echo", &h_echo),
        ("lluavd uplink", &h_up),
        ("lluavd WebSocket", &h_ws),
    ] {
        println!(
            "| {name} | {:.0} | {:.0} | {:.2}x | {:.2}x |",
            us(h, 0.5),
            us(h, 0.99),
            us(h, 0.5) / us(&h_echo, 0.5),
            us(h, 0.99) / us(&h_echo, 0.99)
        );
    }
    let _ = daemon.terminate();
}

/// (utime + stime) in seconds of process `pid`.
fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after_name = stat.rsplit_once(')').map(|(_, rest)| rest).unwrap_or_default();
    let ticks: u64 = after_name
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|f| f.parse::<u64>().ok())
        .sum();
    // SAFETY: sysconf only reads a configuration value.
    let per_s = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    ticks as f64 / if per_s > 0 { per_s as f64 } else { 100.0 }
}

fn rss_kib(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().strip_suffix("kB"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0.0)
}

async fn fleet(a: &Args) {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let mut watch = Mqtt::connect(&broker, "fleet-watch").await;
    watch.subscribe("lluav/+/status").await;
    let ids: Vec<String> = (0..a.vehicles).map(|i| format!("f{i:03}")).collect();
    let mut vehicles = Vec::new();
    for id in &ids {
        let options = Options::default().with_args(&[
            "--uplink",
            &broker.url,
            "--vehicle-id",
            id,
            "--uplink-state-hz",
            "1",
            "--allow-no-password",
        ]);
        vehicles.push(Lluavd::start(&dir.path().join(id), &options));
    }
    let mut online = std::collections::HashSet::new();
    while online.len() < a.vehicles {
        let (topic, v) = watch.json().await;
        if v["online"] == true {
            online.insert(topic);
        }
    }
    let plain = Lluavd::start(&dir.path().join("plain"), &Options::default());
    tokio::time::sleep(Duration::from_secs(2)).await;
    let pid = broker.pid().expect("broker runs");
    let (cpu0, at0) = (cpu_s(pid), Instant::now());
    let fleet_cpu0: f64 = vehicles.iter().map(|v| cpu_s(v.pid())).sum();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let idle_window = at0.elapsed().as_secs_f64();
    let broker_idle = (cpu_s(pid) - cpu0) / idle_window;
    let fleet_idle = (vehicles.iter().map(|v| cpu_s(v.pid())).sum::<f64>() - fleet_cpu0) / idle_window;

    let mut op = Mqtt::connect(&broker, "fleet-op").await;
    op.subscribe("lluav/+/res/fleet-op").await;
    let mut h = histogram();
    let (cpu1, at1) = (cpu_s(pid), Instant::now());
    for round in 0..a.fan_outs {
        let sent = Instant::now();
        for id in &ids {
            let envelope = format!(r#"{{"id":"{round}","frame":"state"}}"#);
            op.publish(
                &format!("lluav/{id}/req/fleet-op"),
                envelope,
                QoS::AtLeastOnce,
                false,
            )
            .await;
        }
        let mut answered = 0;
        while answered < a.vehicles {
            let p = op.next().await;
            if p.payload.starts_with(format!(r#"{{"id":"{round}""#).as_bytes()) {
                answered += 1;
            }
        }
        record(&mut h, sent);
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let broker_fan = (cpu_s(pid) - cpu1) / at1.elapsed().as_secs_f64();
    let rss: Vec<f64> = vehicles.iter().map(|v| rss_kib(v.pid())).collect();
    let mean = rss.iter().sum::<f64>() / rss.len() as f64;
    let max = rss.iter().copied().fold(0.0, f64::max);
    println!(
        "\n{} lluavd vehicles on one Mosquitto, state at 1 Hz; {} fan-outs of `state` to all of them:\n",
        a.vehicles, a.fan_outs
    );
    println!("| measure | value |");
    println!("|---|---:|");
    println!(
        "| fan-out, first request to last answer: p50 / p99 / max ms | {:.1} / {:.1} / {:.1} |",
        us(&h, 0.5) / 1000.0,
        us(&h, 0.99) / 1000.0,
        h.max() as f64 / 1e6
    );
    println!(
        "| broker CPU, state only / during the fan-outs | {:.1} % / {:.1} % of a core |",
        100.0 * broker_idle,
        100.0 * broker_fan
    );
    println!(
        "| all vehicles' CPU, state only | {:.1} % of a core ({:.2} % each) |",
        100.0 * fleet_idle,
        100.0 * fleet_idle / a.vehicles as f64
    );
    println!(
        "| lluavd VmRSS per vehicle: mean / max | {:.0} / {:.0} KiB |",
        mean, max
    );
    println!(
        "| lluavd VmRSS without an uplink | {:.0} KiB |",
        rss_kib(plain.pid())
    );
    let _ = plain.terminate();
    for v in vehicles {
        let _ = v.terminate();
    }
}

fn main() {
    let argv: Vec<String> = std::env::args().collect();
    if let Some(at) = argv.iter().position(|a| a == "--mqtt-echo") {
        let port = argv
            .get(at + 1)
            .and_then(|p| p.parse().ok())
            .expect("--mqtt-echo PORT SIZE");
        let size = argv
            .get(at + 2)
            .and_then(|p| p.parse().ok())
            .expect("--mqtt-echo PORT SIZE");
        return serve_echo(port, size);
    }
    let a = args();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        round_trips(&a).await;
        fleet(&a).await;
    });
}
