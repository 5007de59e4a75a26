//! `state` throughput of a running lluavd: C WebSocket connections, logged
//! in, each sending `state` closed-loop (the next one only after the
//! reply) for S seconds. Prints requests per second and latency
//! percentiles as one line of JSON. Used by `tests/mavlink/bench.py` to
//! compare the MAVLink backend (an autopilot streaming telemetry) with the
//! simulator in the same run.
//!
//! ```text
//! cargo bench -p lluav-host --bench state_load -- --url ws://127.0.0.1:PORT
//!     [--connections 100] [--seconds 10] [--password PASS]
//! ```

use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::connect_async;
use tokio_tungstenite::tungstenite::Message;

struct Args {
    url: String,
    connections: usize,
    seconds: u64,
    password: Option<String>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        url: String::new(),
        connections: 100,
        seconds: 10,
        password: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--url" => args.url = value()?,
            "--connections" => {
                args.connections = value()?.parse().map_err(|e| format!("--connections: {e}"))?
            }
            "--seconds" => args.seconds = value()?.parse().map_err(|e| format!("--seconds: {e}"))?,
            "--password" => args.password = Some(value()?),
            "--bench" => {}
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if args.url.is_empty() {
        return Err("--url is required".into());
    }
    Ok(args)
}

/// One connection's closed loop until `until`; its latencies in µs.
async fn run_connection(url: String, password: Option<String>, until: Instant) -> Result<Vec<u32>, String> {
    let (mut ws, _) = connect_async(url.as_str()).await.map_err(|e| e.to_string())?;
    if let Some(p) = password {
        ws.send(Message::text(format!("login {p}")))
            .await
            .map_err(|e| e.to_string())?;
        ws.next()
            .await
            .ok_or("closed at login")?
            .map_err(|e| e.to_string())?;
    }
    let mut latencies = Vec::new();
    while Instant::now() < until {
        let start = Instant::now();
        ws.send(Message::text("state")).await.map_err(|e| e.to_string())?;
        let reply = ws.next().await.ok_or("closed")?.map_err(|e| e.to_string())?;
        if !reply.to_text().is_ok_and(|t| t.starts_with(r#"{"ret":0,"#)) {
            return Err(format!("unexpected reply: {reply}"));
        }
        latencies.push(u32::try_from(start.elapsed().as_micros()).unwrap_or(u32::MAX));
    }
    let _ = ws.close(None).await;
    Ok(latencies)
}

fn main() -> std::process::ExitCode {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("state_load: {e}");
            return std::process::ExitCode::from(2);
        }
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a tokio runtime");
    let result = runtime.block_on(async {
        let until = Instant::now() + Duration::from_secs(args.seconds);
        let started = Instant::now();
        let tasks: Vec<_> = (0..args.connections)
            .map(|_| tokio::spawn(run_connection(args.url.clone(), args.password.clone(), until)))
            .collect();
        let mut all = Vec::new();
        for t in tasks {
            all.extend(t.await.map_err(|e| e.to_string())??);
        }
        Ok::<_, String>((all, started.elapsed()))
    });
    let (mut latencies, elapsed) = match result {
        Ok(r) => r,
        Err(e) => {
            eprintln!("state_load: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    latencies.sort_unstable();
    let pct = |p: f64| {
        latencies
            .get(((latencies.len() as f64 - 1.0) * p) as usize)
            .copied()
            .unwrap_or(0)
    };
    println!(
        r#"{{"connections":{},"requests":{},"seconds":{:.2},"per_second":{:.0},"p50_us":{},"p99_us":{},"max_us":{}}}"#,
        args.connections,
        latencies.len(),
        elapsed.as_secs_f64(),
        latencies.len() as f64 / elapsed.as_secs_f64(),
        pct(0.5),
        pct(0.99),
        latencies.last().copied().unwrap_or(0)
    );
    std::process::ExitCode::SUCCESS
}
