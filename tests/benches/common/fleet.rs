//! A fleet of release lluavds on one Mosquitto, and fan-outs of one
//! `state` to all of them from one operator.

use std::collections::HashSet;
use std::path::Path;
use std::time::{Duration, Instant};

use lluav_tests::broker::{Mosquitto, Mqtt, QoS, with_admin};
use lluav_tests::{Lluavd, Options};

/// Vehicles `f000`, `f001`, ... on one broker.
pub struct Fleet {
    pub ids: Vec<String>,
    pub vehicles: Vec<Lluavd>,
}

impl Fleet {
    /// Starts `n` vehicles on `broker` (data directories under `dir`, each
    /// with the tests' admin value and `args`) and returns once every one
    /// has said it is online.
    pub async fn start(broker: &Mosquitto, dir: &Path, n: usize, args: &[&str]) -> Fleet {
        let mut watch = Mqtt::connect(broker, "fleet-watch").await;
        watch.subscribe("lluav/+/status").await;
        let ids: Vec<String> = (0..n).map(|i| format!("f{i:03}")).collect();
        let mut vehicles = Vec::new();
        for id in &ids {
            let options = Options::default()
                .with_args(&["--uplink", &broker.url, "--vehicle-id", id])
                .with_args(args);
            let data = dir.join(id);
            vehicles.push(Lluavd::start(&data, &with_admin(&data, options)));
        }
        let mut online = HashSet::new();
        while online.len() < n {
            let (topic, v) = watch.json().await;
            if v["online"] == true {
                online.insert(topic);
            }
        }
        watch.close().await;
        Fleet { ids, vehicles }
    }

    /// [`Fleet::start`] with each vehicle's state at 1 Hz and no
    /// password.
    pub async fn at_1hz(broker: &Mosquitto, dir: &Path, n: usize) -> Fleet {
        Fleet::start(broker, dir, n, &["--uplink-state-hz", "1", "--allow-no-password"]).await
    }

    /// All vehicles' CPU time so far, in seconds.
    pub fn cpu_s(&self) -> f64 {
        self.vehicles.iter().map(|v| super::measure::cpu_s(v.pid())).sum()
    }

    /// Stops every vehicle.
    pub fn stop(self) {
        for v in self.vehicles {
            let _ = v.terminate();
        }
    }
}

/// The operator's client id.
const OPERATOR: &str = "fleet-op";

/// The operator that fans out: connected, subscribed to its answers.
pub async fn operator(broker: &Mosquitto) -> Mqtt {
    let mut op = Mqtt::connect(broker, OPERATOR).await;
    op.subscribe(&format!("lluav/+/res/{OPERATOR}")).await;
    op
}

/// One `state` to each of `ids` from `op` (an [`operator`]) with request
/// id `round`: the time from the first request out to the last answer in,
/// and how many vehicles had not answered within `limit`.
pub async fn fan_out(op: &mut Mqtt, ids: &[String], round: usize, limit: Duration) -> (Duration, usize) {
    let sent = Instant::now();
    let envelope = format!(r#"{{"id":"{round}","frame":"state"}}"#);
    for id in ids {
        op.publish(
            &format!("lluav/{id}/req/{OPERATOR}"),
            envelope.clone(),
            QoS::AtLeastOnce,
            false,
        )
        .await;
    }
    let mine = format!(r#"{{"id":"{round}""#);
    let mut answered = 0;
    while answered < ids.len() {
        let left = limit.saturating_sub(sent.elapsed());
        match op.next_within(left).await {
            Some(p) if p.payload.starts_with(mine.as_bytes()) => answered += 1,
            Some(_) => {}
            None => break,
        }
    }
    (sent.elapsed(), ids.len() - answered)
}

/// The head of a fleet's table and its first row, the fan-outs' times
/// (`h` in ns): p50 / p99 / max in ms.
pub fn print_fan_outs(h: &hdrhistogram::Histogram<u64>) {
    println!("| measure | value |");
    println!("|---|---:|");
    println!(
        "| fan-out, first request to last answer: p50 / p99 / max ms | {:.1} / {:.1} / {:.1} |",
        h.value_at_quantile(0.5) as f64 / 1e6,
        h.value_at_quantile(0.99) as f64 / 1e6,
        h.max() as f64 / 1e6
    );
}
