//! Round-trip latency and throughput of the real lluavd (release build)
//! over loopback: `cargo bench -p lluav-tests --bench daemon`.
//!
//! Three loads, each with `state` (a full trip through the core and the
//! simulator): one client waiting for each reply, one client keeping a
//! window of requests in flight, and many clients at once. Numbers depend
//! on the machine and what else runs on it; compare runs on one machine.

use std::time::{Duration, Instant};

use futures_util::future::join_all;
use lluav_tests::{Conn, Lluavd, Options};

const PASSWORD: &str = "bench";

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    let last = sorted.len().saturating_sub(1);
    // Rounding an index in 0..=len-1 back to usize cannot lose anything.
    let index = ((last as f64) * p).round() as usize;
    sorted.get(index).copied().unwrap_or_default()
}

fn rate(requests: usize, elapsed: Duration) -> f64 {
    requests as f64 / elapsed.as_secs_f64()
}

#[tokio::main(flavor = "multi_thread", worker_threads = 1)]
async fn main() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    println!("lluavd {}", lluav_tests::lluavd_bin().display());

    // 1. One client, one request at a time.
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    for _ in 0..1000 {
        c.request("state").await;
    }
    let n = 20_000;
    let mut samples = Vec::with_capacity(n);
    let start = Instant::now();
    for _ in 0..n {
        let t = Instant::now();
        c.request("state").await;
        samples.push(t.elapsed());
    }
    let elapsed = start.elapsed();
    samples.sort();
    println!(
        "sequential: {n} requests, {:.0} req/s, round trip p50 {:?} p99 {:?} max {:?}",
        rate(n, elapsed),
        percentile(&samples, 0.5),
        percentile(&samples, 0.99),
        percentile(&samples, 1.0),
    );

    // 2. One client, a window of 64 requests in flight.
    let (n, window) = (100_000, 64);
    let start = Instant::now();
    for _ in 0..window {
        c.send("state").await;
    }
    for sent in window..n + window {
        c.response().await;
        if sent < n {
            c.send("state").await;
        }
    }
    println!(
        "pipelined (window {window}): {n} requests, {:.0} req/s",
        rate(n, start.elapsed())
    );

    // 3. Many clients, each one request at a time.
    let (clients, each) = (100, 500);
    let mut conns = join_all((0..clients).map(|_| Conn::login(&daemon.url, PASSWORD))).await;
    let start = Instant::now();
    join_all(conns.iter_mut().map(|c| async move {
        for _ in 0..each {
            c.request("state").await;
        }
    }))
    .await;
    println!(
        "{clients} clients: {} requests, {:.0} req/s",
        clients * each,
        rate(clients * each, start.elapsed())
    );
}
