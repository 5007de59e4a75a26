//! Events measured (DESIGN.md, "Events"; issue 27, "Measure"), in one run:
//!
//! ```text
//! cargo bench -p lluav-tests --features broker --bench events -- [--events N] [--ws-subs W] [--mqtt-subs M] [--idle-s S] [--idle-vehicles I] [--vehicles V] [--fan-outs F]
//! ```
//!
//! 1. Latency: one lluavd (with a password) and its uplink on a Mosquitto,
//!    one subscriber on `/events`, one on `lluav/V/events`. Two sessions
//!    take control from each other, one `control_take` at a time, N times
//!    (100 more to warm up): each take changes who flies and so makes one
//!    `control` event. Per event: the command's own round trip (sent →
//!    answer in: the baseline of the same run), sent → the event in on
//!    each path, and the event's `ts` (lluavd's Unix clock in ms, stamped
//!    when the change is made; the bench reads the same clock) → the event
//!    in. `ts` is truncated to the ms, so that measure reads up to 1 ms
//!    high.
//! 2. Subscribers during a mission: one lluavd flies the same 8-waypoint
//!    mission (the simulator, 2 m/s) twice: with one subscriber on
//!    `/events` (the bench's own watch), then with W on `/events` and M on
//!    `lluav/V/events`. lluavd's CPU (utime + stime) from `mw_exec` to the
//!    mission's `completed`; every subscriber's latency (`ts` → in) for
//!    every event of the mission, and whether each got them all.
//! 3. Idle: I lluavds with the simulator and the uplink at its default
//!    1 Hz, disarmed, online, and I without an uplink: their CPU over S s,
//!    from utime + stime (10 ms ticks) and from the threads' schedstat
//!    (ns; a thread that ended in the window is not counted there).
//! 4. A fleet: V lluavds with `--uplink-state-hz 1` on one Mosquitto; F
//!    fan-outs of `state` to all of them from one operator, 1 s apart,
//!    each timed from the first request out to the last answer in.
//!
//! Defaults: N 1000, W 100, M 100, S 60, I 5, V 1000, F 10. The summary is
//! Markdown for BENCHMARKS.md.

#[path = "common/fleet.rs"]
mod fleet;
#[path = "common/measure.rs"]
mod measure;

use std::time::{Duration, Instant};

use fleet::{Fleet, fan_out, operator, print_fan_outs};
use hdrhistogram::Histogram;
use lluav_tests::broker::{Mosquitto, Mqtt};
use lluav_tests::{Conn, Lluavd, Options, Received, WAIT};
use measure::{cpu_s, flag, histogram, record, us};
use serde_json::Value;
use tokio::sync::mpsc;

const WARM_UP: usize = 100;
const PASSWORD: &str = "bench-pw";

struct Args {
    events: usize,
    ws_subs: usize,
    mqtt_subs: usize,
    idle_s: u64,
    idle_vehicles: usize,
    vehicles: usize,
    fan_outs: usize,
}

fn args() -> Args {
    Args {
        events: flag("--events", 1000),
        ws_subs: flag("--ws-subs", 100),
        mqtt_subs: flag("--mqtt-subs", 100),
        idle_s: flag("--idle-s", 60) as u64,
        idle_vehicles: flag("--idle-vehicles", 5),
        vehicles: flag("--vehicles", 1000),
        fan_outs: flag("--fan-outs", 10),
    }
}

fn load_average() -> String {
    let text = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    text.split_whitespace().take(3).collect::<Vec<_>>().join(" ")
}

/// Microseconds since 1970: the clock lluavd stamps `ts` with, finer.
fn unix_us() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_micros()).unwrap_or(i64::MAX))
}

/// One event as a subscriber got it.
#[derive(Debug)]
struct Arrival {
    /// Which subscriber.
    sub: usize,
    seq: u64,
    event: String,
    /// lluavd's stamp, Unix ms.
    ts: i64,
    /// When it came in.
    at: Instant,
    /// The same, Unix µs.
    wall_us: i64,
    /// The object.
    json: Value,
}

fn arrival(sub: usize, payload: &[u8]) -> Option<Arrival> {
    let (at, wall_us) = (Instant::now(), unix_us());
    let e: Value = serde_json::from_slice(payload).ok()?;
    Some(Arrival {
        sub,
        seq: e["seq"].as_u64()?,
        event: e["event"].as_str()?.to_owned(),
        ts: e["ts"].as_i64()?,
        at,
        wall_us,
        json: e,
    })
}

/// A subscriber on `/events`, logged in, its arrivals sent to `tx` until
/// the connection ends.
async fn ws_subscriber(
    daemon: &Lluavd,
    sub: usize,
    tx: mpsc::UnboundedSender<Arrival>,
) -> tokio::task::JoinHandle<()> {
    let mut conn = Conn::connect(&format!("{}/events", daemon.url)).await;
    let r = conn.request(&format!("login {PASSWORD}")).await;
    assert_eq!(r["ret"], 0, "login on /events: {r}");
    tokio::spawn(async move {
        while let Received::Text(t) = conn.recv().await {
            if let Some(a) = arrival(sub, t.as_bytes()) {
                let _ = tx.send(a);
            }
        }
    })
}

/// A subscriber on `lluav/<vehicle>/events`, its arrivals sent to `tx`.
async fn mqtt_subscriber(
    broker: &Mosquitto,
    vehicle: &str,
    sub: usize,
    tx: mpsc::UnboundedSender<Arrival>,
) -> tokio::task::JoinHandle<()> {
    let mut mqtt = Mqtt::connect(broker, &format!("events-sub-{sub}")).await;
    mqtt.subscribe(&format!("lluav/{vehicle}/events")).await;
    tokio::spawn(async move {
        while let Some(p) = mqtt.next_within(Duration::from_secs(3600)).await {
            if let Some(a) = arrival(sub, &p.payload) {
                let _ = tx.send(a);
            }
        }
    })
}

/// The next arrival of event `name`, skipping others (the battery's).
async fn next_named(rx: &mut mpsc::UnboundedReceiver<Arrival>, name: &str) -> Arrival {
    loop {
        let a = tokio::time::timeout(WAIT, rx.recv())
            .await
            .expect("an event in time")
            .expect("the subscriber runs");
        if a.event == name {
            return a;
        }
    }
}

/// µs from lluavd's `ts` to the arrival.
fn from_ts(a: &Arrival) -> u64 {
    u64::try_from(a.wall_us - a.ts * 1000).unwrap_or(0)
}

fn ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

fn ms(h: &Histogram<u64>, q: f64, unit_ns: bool) -> f64 {
    if unit_ns {
        us(h, q) / 1000.0
    } else {
        h.value_at_quantile(q) as f64 / 1000.0
    }
}

/// A lluavd with a password and its uplink, online on `broker` as `id`.
async fn vehicle(broker: &Mosquitto, dir: &std::path::Path, id: &str, sessions: usize) -> Lluavd {
    let options = Options::password(PASSWORD).per_ip(sessions);
    lluav_tests::broker::vehicle(dir, broker, id, options).await
}

async fn latency(a: &Args, broker: &Mosquitto) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(broker, dir.path(), "lat", 16).await;
    let (ws_tx, mut ws_rx) = mpsc::unbounded_channel();
    let (mq_tx, mut mq_rx) = mpsc::unbounded_channel();
    let ws_task = ws_subscriber(&daemon, 0, ws_tx).await;
    let mq_task = mqtt_subscriber(broker, "lat", 0, mq_tx).await;
    let mut pilots = [
        Conn::login(&daemon.url, PASSWORD).await,
        Conn::login(&daemon.url, PASSWORD).await,
    ];
    assert_eq!(pilots[0].request("control_take").await["ret"], 0);
    next_named(&mut ws_rx, "control").await;
    next_named(&mut mq_rx, "control").await;
    let (mut rtt, mut ws_sent, mut mq_sent, mut ws_ts, mut mq_ts) =
        (histogram(), histogram(), histogram(), histogram(), histogram());
    for i in 0..a.events + WARM_UP {
        let pilot = &mut pilots[(i + 1) % 2];
        let sent = Instant::now();
        let r = pilot.request("control_take").await;
        if i >= WARM_UP {
            record(&mut rtt, sent);
        }
        assert_eq!(r["ret"], 0, "control_take: {r}");
        let (w, m) = (
            next_named(&mut ws_rx, "control").await,
            next_named(&mut mq_rx, "control").await,
        );
        assert_eq!(w.seq, m.seq, "the same event on both paths");
        if i >= WARM_UP {
            ws_sent.saturating_record(ns(w.at - sent));
            mq_sent.saturating_record(ns(m.at - sent));
            ws_ts.saturating_record(from_ts(&w));
            mq_ts.saturating_record(from_ts(&m));
        }
    }
    println!(
        "\nLatency of a `control` event, {} events one at a time (one subscriber per path; load average {}):\n",
        a.events,
        load_average()
    );
    println!("| measure | p50 ms | p99 ms | max ms | p99 / command's p99 |");
    println!("|---|---:|---:|---:|---:|");
    let rows = [
        ("`control_take` sent → its answer in (baseline)", &rtt, true),
        ("sent → event in, WebSocket `/events`", &ws_sent, true),
        ("sent → event in, broker `lluav/V/events`", &mq_sent, true),
        ("`ts` → event in, WebSocket `/events`", &ws_ts, false),
        ("`ts` → event in, broker `lluav/V/events`", &mq_ts, false),
    ];
    for (name, h, unit_ns) in rows {
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} | {:.1}x |",
            ms(h, 0.5, unit_ns),
            ms(h, 0.99, unit_ns),
            ms(h, 1.0, unit_ns),
            ms(h, 0.99, unit_ns) / ms(&rtt, 0.99, true)
        );
    }
    ws_task.abort();
    mq_task.abort();
    let _ = daemon.terminate();
}

const MISSION: &str = r#"mission 9:{"waypoints":[{"id":1,"x":4,"y":0,"z":-3},{"id":2,"x":4,"y":4,"z":-3},{"id":3,"x":0,"y":4,"z":-3},{"id":4,"x":0,"y":0,"z":-3},{"id":5,"x":4,"y":0,"z":-3},{"id":6,"x":4,"y":4,"z":-3},{"id":7,"x":0,"y":4,"z":-3},{"id":8,"x":0,"y":0,"z":-3}]}"#;

/// What one flight of the mission cost and told.
struct Flight {
    cpu_s: f64,
    seconds: f64,
    /// The mission's first and last seq.
    seqs: (u64, u64),
}

/// The next arrival of event `name` whose `key` is `value`.
async fn next_where(
    rx: &mut mpsc::UnboundedReceiver<Arrival>,
    name: &str,
    key: &str,
    value: Value,
) -> Arrival {
    loop {
        let a = next_named(rx, name).await;
        if a.json[key] == value {
            return a;
        }
    }
}

/// Flies the mission once: takeoff, the mission, landing, each step
/// awaited on `watch` (subscriber 0's arrivals).
async fn fly(daemon: &Lluavd, pilot: &mut Conn, watch: &mut mpsc::UnboundedReceiver<Arrival>) -> Flight {
    assert_eq!(pilot.request("takeoff").await["ret"], 0);
    next_where(watch, "fsm", "to", "hover".into()).await;
    assert_eq!(pilot.request(MISSION).await["ret"], 0);
    let (cpu0, t0) = (cpu_s(daemon.pid()), Instant::now());
    assert_eq!(pilot.request("mw_exec 9:1,2,3,4,5,6,7,8").await["ret"], 0);
    let started = next_where(watch, "mission", "status", "started".into()).await;
    let completed = next_where(watch, "mission", "status", "completed".into()).await;
    let flight = Flight {
        cpu_s: cpu_s(daemon.pid()) - cpu0,
        seconds: t0.elapsed().as_secs_f64(),
        seqs: (started.seq, completed.seq),
    };
    assert_eq!(pilot.request("land").await["ret"], 0);
    next_where(watch, "armed", "armed", false.into()).await;
    flight
}

async fn mission(a: &Args, broker: &Mosquitto) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(broker, dir.path(), "msn", a.ws_subs + 8).await;
    let mut pilot = Conn::login(&daemon.url, PASSWORD).await;
    let (watch_tx, mut watch) = mpsc::unbounded_channel();
    let watch_task = ws_subscriber(&daemon, 0, watch_tx).await;
    let quiet = fly(&daemon, &mut pilot, &mut watch).await;

    let (tx, mut rx) = mpsc::unbounded_channel();
    let mut tasks = Vec::new();
    for sub in 1..a.ws_subs {
        tasks.push(ws_subscriber(&daemon, sub, tx.clone()).await);
    }
    for sub in a.ws_subs..a.ws_subs + a.mqtt_subs {
        tasks.push(mqtt_subscriber(broker, "msn", sub, tx.clone()).await);
    }
    drop(tx);
    let loaded = fly(&daemon, &mut pilot, &mut watch).await;
    let (first, last) = loaded.seqs;
    let subs = a.ws_subs + a.mqtt_subs - 1;
    let mut got = vec![0u64; a.ws_subs + a.mqtt_subs];
    let (mut ws_h, mut mq_h) = (histogram(), histogram());
    let deadline = Instant::now() + WAIT;
    while got.iter().skip(1).filter(|n| **n == last - first + 1).count() < subs && Instant::now() < deadline {
        let Ok(Some(e)) = tokio::time::timeout_at(deadline.into(), rx.recv()).await else {
            break;
        };
        if (first..=last).contains(&e.seq) {
            got[e.sub] += 1;
            let h = if e.sub < a.ws_subs { &mut ws_h } else { &mut mq_h };
            h.saturating_record(from_ts(&e));
        }
    }
    let complete = got.iter().skip(1).filter(|n| **n == last - first + 1).count();
    let share = |f: &Flight| 100.0 * f.cpu_s / f.seconds;
    println!(
        "\nThe same mission flown twice by one lluavd (uplink on; load average {}): lluavd's CPU from \
         `mw_exec` to `completed`, and every subscriber's latency (`ts` → in) for the mission's {} events:\n",
        load_average(),
        last - first + 1
    );
    println!(
        "| subscribers | mission s | lluavd CPU s | % of a core | `ts` → in p50 / p99 / max ms | got every event |"
    );
    println!("|---|---:|---:|---:|---|---:|");
    println!(
        "| 1 on `/events` | {:.1} | {:.2} | {:.2} % | – | – |",
        quiet.seconds,
        quiet.cpu_s,
        share(&quiet)
    );
    println!(
        "| {} on `/events`, {} on `lluav/V/events` | {:.1} | {:.2} | {:.2} % | WebSocket {:.1} / {:.1} / {:.1}; broker {:.1} / {:.1} / {:.1} | {complete} of {subs} |",
        a.ws_subs,
        a.mqtt_subs,
        loaded.seconds,
        loaded.cpu_s,
        share(&loaded),
        ms(&ws_h, 0.5, false),
        ms(&ws_h, 0.99, false),
        ms(&ws_h, 1.0, false),
        ms(&mq_h, 0.5, false),
        ms(&mq_h, 0.99, false),
        ms(&mq_h, 1.0, false),
    );
    watch_task.abort();
    for t in tasks {
        t.abort();
    }
    let _ = daemon.terminate();
}

/// CPU time on record for every thread of `pid` now, in ns (schedstat).
fn sched_ns(pid: u32) -> u64 {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return 0;
    };
    tasks
        .filter_map(Result::ok)
        .filter_map(|t| std::fs::read_to_string(t.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}

async fn idle(a: &Args, broker: &Mosquitto) {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut up = Vec::new();
    let mut plain = Vec::new();
    for i in 0..a.idle_vehicles {
        let options = Options::default().with_args(&["--allow-no-password"]);
        let data = dir.path().join(format!("idle{i}"));
        up.push(lluav_tests::broker::vehicle(&data, broker, &format!("idle{i}"), options).await);
        plain.push(Lluavd::start(
            &dir.path().join(format!("plain{i}")),
            &Options::default(),
        ));
    }
    let read = |ds: &[Lluavd]| -> Vec<(f64, u64)> {
        ds.iter().map(|d| (cpu_s(d.pid()), sched_ns(d.pid()))).collect()
    };
    let (up0, plain0, t0) = (read(&up), read(&plain), Instant::now());
    tokio::time::sleep(Duration::from_secs(a.idle_s)).await;
    let (up1, plain1, window) = (read(&up), read(&plain), t0.elapsed().as_secs_f64());
    println!(
        "\nIdle, disarmed lluavds over {window:.0} s, {} of each kind (load average {}); % of a core per lluavd:\n",
        a.idle_vehicles,
        load_average()
    );
    println!("| lluavd | utime + stime: mean / max | schedstat: mean / max |");
    println!("|---|---:|---:|");
    for (name, before, after) in [
        ("simulator, uplink at the default 1 Hz", &up0, &up1),
        ("simulator, no uplink", &plain0, &plain1),
    ] {
        let ticks: Vec<f64> = before
            .iter()
            .zip(after)
            .map(|(b, a)| 100.0 * (a.0 - b.0) / window)
            .collect();
        let sched: Vec<f64> = before
            .iter()
            .zip(after)
            .map(|(b, a)| 100.0 * a.1.saturating_sub(b.1) as f64 / 1e9 / window)
            .collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        println!(
            "| {name} | {:.3} % / {:.3} % | {:.4} % / {:.4} % |",
            mean(&ticks),
            max(&ticks),
            mean(&sched),
            max(&sched)
        );
    }
    for d in up.into_iter().chain(plain) {
        let _ = d.terminate();
    }
}

async fn fleet(a: &Args) {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let load_before = load_average();
    let started = Instant::now();
    let fleet = Fleet::at_1hz(&broker, dir.path(), a.vehicles).await;
    let start_s = started.elapsed().as_secs_f64();
    let (cpu0, broker0, t0) = (
        fleet.cpu_s(),
        cpu_s(broker.pid().expect("broker runs")),
        Instant::now(),
    );
    let mut op = operator(&broker).await;
    let mut h = histogram();
    let mut missing = 0;
    for round in 0..a.fan_outs {
        let (took, left) = fan_out(&mut op, &fleet.ids, round, WAIT).await;
        missing += left;
        h.saturating_record(ns(took));
        tokio::time::sleep(Duration::from_secs(1)).await;
    }
    let window = t0.elapsed().as_secs_f64();
    let fleet_cpu = (fleet.cpu_s() - cpu0) / window;
    let broker_cpu = (cpu_s(broker.pid().expect("broker runs")) - broker0) / window;
    let rss: Vec<f64> = fleet
        .vehicles
        .iter()
        .map(|v| lluav_tests::memory_kib(v.pid()).0 as f64)
        .collect();
    println!(
        "\n{} lluavd vehicles (`--uplink-state-hz 1`) on one Mosquitto; {} fan-outs of `state` to all of them, 1 s apart:\n",
        a.vehicles, a.fan_outs
    );
    print_fan_outs(&h);
    println!("| all started and online | {start_s:.1} s |");
    println!("| answers missing (of {}) | {missing} |", a.vehicles * a.fan_outs);
    println!(
        "| all vehicles' CPU during the fan-outs | {:.1} % of a core ({:.3} % each) |",
        100.0 * fleet_cpu,
        100.0 * fleet_cpu / a.vehicles as f64
    );
    println!(
        "| broker's CPU during the fan-outs | {:.1} % of a core |",
        100.0 * broker_cpu
    );
    println!(
        "| VmRSS per vehicle, mean | {:.0} KiB |",
        rss.iter().sum::<f64>() / rss.len().max(1) as f64
    );
    println!(
        "| load average before / after | {load_before} / {} |",
        load_average()
    );
    fleet.stop();
}

#[tokio::main]
async fn main() {
    let a = args();
    println!("load average at the start: {}", load_average());
    let broker = Mosquitto::start();
    if a.events > 0 {
        latency(&a, &broker).await;
    }
    if a.ws_subs > 0 {
        mission(&a, &broker).await;
    }
    if a.idle_vehicles > 0 {
        idle(&a, &broker).await;
    }
    drop(broker);
    if a.vehicles > 0 {
        fleet(&a).await;
    }
}
