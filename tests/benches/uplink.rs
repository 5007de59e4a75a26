//! The uplink measured, in one run on one Mosquitto:
//!
//! ```text
//! cargo bench -p lluav-tests --features broker --bench uplink -- [--round-trips N] [--vehicles V] [--fan-outs F] [--clients C] [--flood MIB] [--only PART]
//! ```
//!
//! 1. Round trips, closed loop, one request at a time: `state` through
//!    lluavd's uplink (a request envelope on `lluav/V/req/C`, QoS 1, the
//!    answer on `lluav/V/res/C`, QoS 1), the same `state` over WebSocket to
//!    the same lluavd, and a bare MQTT 5 echo: a plain rumqttc `v5` client
//!    (this binary re-executed with `--mqtt-echo`, a process of its own
//!    like lluavd) answering every message on its request topic at once,
//!    on its response topic, with a payload as long as lluavd's answer. Two
//!    rounds that alternate the order; p50/p99 in µs and the uplink's ratio
//!    to the echo. Then `siyi_sync` (a command that changes the vehicle:
//!    its answer is synced to disk twice) against `ver` (a read), both
//!    through the uplink.
//! 2. The durable store on its own: N requests' two synced records
//!    (started, answered), one request at a time, in the data directory's
//!    file system, against writing the same records unsynced.
//! 3. Memory: one lluavd's VmRSS and peak (VmHWM) while C distinct client
//!    ids send it a request each through the broker, and while a stand-in
//!    broker floods it with MIB MiB of QoS 1 requests and never reads
//!    (tests/src/flooder.rs); against its VmRSS before, and against a
//!    lluavd without an uplink.
//! 4. A fleet: V lluavd (release) on the broker, each publishing its state
//!    at 1 Hz. The broker's CPU over 10 s of that; then F fan-outs of one
//!    `state` to every vehicle from one operator (the time from the first
//!    request out to the last answer in); each lluavd's VmRSS, against one
//!    lluavd without an uplink.
//!
//! Defaults: 2000 round trips per path and round (200 more to warm up),
//! 100 vehicles, 50 fan-outs, 100 000 client ids, a 256 MiB flood. The
//! summary is Markdown for BENCHMARKS.md. `--only PART` runs one part:
//! `round-trips` (1), `store` (2), `memory` (3) or `fleet` (4).

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

#[path = "common/fleet.rs"]
mod fleet;
#[path = "common/measure.rs"]
mod measure;

use fleet::{Fleet, fan_out, operator, print_fan_outs};
use futures_util::{SinkExt, StreamExt};
use hdrhistogram::Histogram;
use lluav_host::uplink::durable::{Entry, Store};
use lluav_tests::broker::{Mosquitto, Mqtt, QoS, topic, with_admin};
use lluav_tests::flooder::{Flood, Flooder};
use lluav_tests::{Lluavd, Options, WAIT};

/// (VmRSS, VmHWM) of process `pid`, in KiB.
fn memory_kib(pid: u32) -> (f64, f64) {
    let (rss, hwm) = lluav_tests::memory_kib(pid);
    (rss as f64, hwm as f64)
}
use measure::{cpu_s, flag, flag_word, histogram, record, us};
use rumqttc::v5::mqttbytes::v5::{Filter, Packet};
use rumqttc::v5::{AsyncClient, Event, MqttOptions};
use tokio_tungstenite::tungstenite::Message;

const WARM_UP: usize = 200;

struct Args {
    round_trips: usize,
    vehicles: usize,
    fan_outs: usize,
    clients: usize,
    flood_mib: u64,
    /// `--only PART`: run this part alone.
    only: Option<String>,
}

impl Args {
    fn runs(&self, part: &str) -> bool {
        self.only.as_deref().is_none_or(|only| only == part)
    }
}

fn args() -> Args {
    Args {
        round_trips: flag("--round-trips", 2000),
        vehicles: flag("--vehicles", 100),
        fan_outs: flag("--fan-outs", 50),
        clients: flag("--clients", 100_000),
        flood_mib: flag("--flood", 256) as u64,
        only: flag_word("--only"),
    }
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
        options.set_max_packet_size(Some(1 << 20));
        let mut network = rumqttc::NetworkOptions::new();
        network.set_tcp_nodelay(true);
        options.set_network_options(network);
        let (client, mut events) = AsyncClient::new(options, 1024);
        let answer = vec![b'x'; size];
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    client
                        .try_subscribe_many([Filter::new("echo/req/+", QoS::AtLeastOnce)])
                        .expect("subscribe queued");
                }
                Ok(Event::Incoming(Packet::SubAck(_))) => println!("ready"),
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let topic = topic(&p).replacen("/req/", "/res/", 1);
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
    /// Request ids are never reused: a repeated id is answered from the
    /// vehicle's memory without running.
    next_id: usize,
}

impl Requester {
    async fn new(broker: &Mosquitto, id: &str, requests: String, answers: &str) -> Requester {
        let mut mqtt = Mqtt::connect(broker, id).await;
        mqtt.subscribe(answers).await;
        Requester {
            mqtt,
            topic: requests,
            next_id: 0,
        }
    }

    async fn run(&mut self, n: usize, h: &mut Histogram<u64>) -> usize {
        self.run_frame("state", n, h).await
    }

    async fn run_frame(&mut self, frame: &str, n: usize, h: &mut Histogram<u64>) -> usize {
        let mut size = 0;
        for i in 0..n + WARM_UP {
            self.next_id += 1;
            let envelope = format!(r#"{{"id":"{}","frame":"{frame}"}}"#, self.next_id);
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
    // A command whose answer is kept on disk against a read, alternating.
    let (mut h_sync, mut h_ver) = (histogram(), histogram());
    for _ in 0..2 {
        uplink
            .run_frame("siyi_sync", a.round_trips / 2, &mut h_sync)
            .await;
        uplink.run_frame("ver", a.round_trips / 2, &mut h_ver).await;
    }
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
    println!(
        "\nThrough the uplink, {} per command (2 rounds): `siyi_sync` changes the vehicle (its answer is \
         synced to disk before it runs and again before it is sent); `ver` reads:\n",
        a.round_trips
    );
    println!("| command | p50 µs | p99 µs | p50 − ver's p50 |");
    println!("|---|---:|---:|---:|");
    for (name, h) in [("siyi_sync", &h_sync), ("ver", &h_ver)] {
        println!(
            "| {name} | {:.0} | {:.0} | {:.0} µs |",
            us(h, 0.5),
            us(h, 0.99),
            us(h, 0.5) - us(&h_ver, 0.5)
        );
    }
    let _ = daemon.terminate();
}

/// The durable store alone: each request's two records written and synced
/// (as lluavd does for a command that changes the vehicle), one request
/// at a time, against the same records written without a sync.
async fn store_cost(a: &Args) {
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).expect("temp dir");
    let now = lluav_host::uplink::serve::unix_ms();
    let (store, _) = Store::open(dir.path(), Duration::from_secs(600), now).expect("store");
    let answer = format!(r#"{{"id":"x","response":{{"ret":0,"cmd":51,"ts":{now},"siyi":{{"syncs":1}}}}}}"#);
    let entries = |n: usize| {
        let started = Entry::Started {
            client: "bench".into(),
            id: format!("r{n}"),
            at: now,
            cmd: 51,
        };
        let answered = Entry::Answered {
            client: "bench".into(),
            id: format!("r{n}"),
            at: now,
            answer: Some(answer.clone()),
        };
        (started, answered)
    };
    let (mut synced, mut unsynced) = (histogram(), histogram());
    for n in 0..a.round_trips + WARM_UP {
        let (started, answered) = entries(n);
        let t = Instant::now();
        store.write(started).await.expect("written");
        store.write(answered).await.expect("written");
        if n >= WARM_UP {
            record(&mut synced, t);
        }
    }
    let mut plain = std::fs::File::create(dir.path().join("unsynced")).expect("file");
    for n in 0..a.round_trips + WARM_UP {
        let (started, answered) = entries(n);
        let t = Instant::now();
        for entry in [started, answered] {
            let line = format!("{entry:?}\n");
            std::io::Write::write_all(&mut plain, line.as_bytes()).expect("written");
        }
        if n >= WARM_UP {
            record(&mut unsynced, t);
        }
    }
    println!(
        "\nThe durable store on its own ({} requests, two records each, in {}):\n",
        a.round_trips,
        env!("CARGO_TARGET_TMPDIR")
    );
    println!("| records | p50 µs per request | p99 µs per request |");
    println!("|---|---:|---:|");
    println!(
        "| written and synced (lluavd) | {:.0} | {:.0} |",
        us(&synced, 0.5),
        us(&synced, 0.99)
    );
    println!(
        "| written, not synced (baseline) | {:.1} | {:.1} |",
        us(&unsynced, 0.5),
        us(&unsynced, 0.99)
    );
}

/// One lluavd's memory while `a.clients` distinct client ids send it a
/// request each through the broker, and while a stand-in broker floods it.
async fn memory(a: &Args) {
    let dir = tempfile::tempdir().expect("temp dir");
    let plain = Lluavd::start(&dir.path().join("plain"), &Options::default());
    let broker = Mosquitto::start();
    let options = Options::default().with_args(&["--allow-no-password"]);
    let daemon = lluav_tests::broker::vehicle(&dir.path().join("ids"), &broker, "mem", options.clone()).await;
    let mut op = Mqtt::connect(&broker, "mem-op").await;
    op.subscribe("lluav/mem/res/+").await;
    let (before, _) = memory_kib(daemon.pid());
    // At most this many unanswered: the broker queues 1000 messages for a
    // client and drops the rest.
    const WINDOW: usize = 200;
    let (mut sent, mut answered) = (0, 0);
    let mut refusals: std::collections::BTreeMap<String, usize> = Default::default();
    let mut peak_rss: f64 = 0.0;
    while answered < a.clients {
        if sent < a.clients && sent - answered < WINDOW {
            let envelope = r#"{"id":"1","frame":"state"}"#;
            op.publish(
                &format!("lluav/mem/req/c{sent}"),
                envelope,
                QoS::AtLeastOnce,
                false,
            )
            .await;
            sent += 1;
            continue;
        }
        let p = op.next().await;
        let v: serde_json::Value = serde_json::from_slice(&p.payload).expect("JSON");
        if v["response"]["ret"] != 0 {
            let msg = v["response"]["msg"].as_str().unwrap_or("?").to_owned();
            *refusals.entry(msg).or_default() += 1;
        }
        answered += 1;
        if answered % 1000 == 0 {
            peak_rss = peak_rss.max(memory_kib(daemon.pid()).0);
        }
    }
    let (after, peak) = memory_kib(daemon.pid());
    let _ = daemon.terminate();

    let flooder = Flooder::start(
        "flood",
        Flood {
            bytes: a.flood_mib << 20,
            message: 4 << 10,
            clients: 16 << 10,
        },
    );
    let fdir = dir.path().join("flood");
    let options =
        with_admin(&fdir, options).with_args(&["--uplink", &flooder.url(), "--vehicle-id", "flood"]);
    let flooded = Lluavd::start(&fdir, &options);
    flooder.wait_subscribed();
    let (flood_before, _) = memory_kib(flooded.pid());
    let t = Instant::now();
    flooder.go();
    while !flooder.ended() {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let flood_s = t.elapsed().as_secs_f64();
    let (flood_after, flood_peak) = memory_kib(flooded.pid());
    let flood_sent = flooder.sent();
    let _ = flooded.terminate();
    let no_uplink = memory_kib(plain.pid()).0;
    let _ = plain.terminate();
    println!("\nlluavd's memory (KiB; a lluavd without an uplink: {no_uplink:.0} KiB VmRSS):\n");
    println!("| load | VmRSS before | VmRSS after | peak (VmHWM) | peak − before |");
    println!("|---|---:|---:|---:|---:|");
    println!(
        "| {} distinct client ids, one `state` each | {before:.0} | {after:.0} | {:.0} | {:.0} |",
        a.clients,
        peak.max(peak_rss),
        peak.max(peak_rss) - before
    );
    println!(
        "| a stand-in broker flooding {} MiB of QoS 1 requests in {flood_s:.1} s, never reading | \
         {flood_before:.0} | {flood_after:.0} | {flood_peak:.0} | {:.0} |",
        flood_sent >> 20,
        flood_peak - flood_before
    );
    println!("\nRefusals among the {} answers: {refusals:?}", a.clients);
}

fn rss_kib(pid: u32) -> f64 {
    memory_kib(pid).0
}

async fn fleet(a: &Args) {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let vehicles = Fleet::at_1hz(&broker, dir.path(), a.vehicles).await;
    let plain = Lluavd::start(&dir.path().join("plain"), &Options::default());
    tokio::time::sleep(Duration::from_secs(2)).await;
    let pid = broker.pid().expect("broker runs");
    let (cpu0, at0) = (cpu_s(pid), Instant::now());
    let fleet_cpu0 = vehicles.cpu_s();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let idle_window = at0.elapsed().as_secs_f64();
    let broker_idle = (cpu_s(pid) - cpu0) / idle_window;
    let fleet_idle = (vehicles.cpu_s() - fleet_cpu0) / idle_window;

    let mut op = operator(&broker).await;
    let mut h = histogram();
    let (cpu1, at1) = (cpu_s(pid), Instant::now());
    for round in 0..a.fan_outs {
        let (took, missing) = fan_out(&mut op, &vehicles.ids, round, WAIT).await;
        assert_eq!(missing, 0, "fan-out {round}: {missing} vehicles did not answer");
        h.saturating_record(u64::try_from(took.as_nanos()).unwrap_or(u64::MAX));
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let broker_fan = (cpu_s(pid) - cpu1) / at1.elapsed().as_secs_f64();
    let rss: Vec<f64> = vehicles.vehicles.iter().map(|v| rss_kib(v.pid())).collect();
    let mean = rss.iter().sum::<f64>() / rss.len() as f64;
    let max = rss.iter().copied().fold(0.0, f64::max);
    println!(
        "\n{} lluavd vehicles on one Mosquitto, state at 1 Hz; {} fan-outs of `state` to all of them:\n",
        a.vehicles, a.fan_outs
    );
    print_fan_outs(&h);
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
    vehicles.stop();
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
    if let Some(only) = &a.only {
        let parts = ["round-trips", "store", "memory", "fleet"];
        assert!(parts.contains(&only.as_str()), "--only takes one of {parts:?}");
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        if a.runs("round-trips") {
            round_trips(&a).await;
        }
        if a.runs("store") {
            store_cost(&a).await;
        }
        if a.runs("memory") {
            memory(&a).await;
        }
        if a.runs("fleet") && a.vehicles > 0 {
            fleet(&a).await;
        }
    });
}
