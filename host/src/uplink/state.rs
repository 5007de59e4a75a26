//! `lluav/V/state`: the whole `state` response, retained, at the
//! configured rate and at once when `fsm`, `armed` or `link` change.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use rumqttc::v5::mqttbytes::QoS;
use serde_json::Value;
use tokio::time::{Instant, MissedTickBehavior, interval};

use super::Sessions;
use super::link::Status;
use super::serve::Shared;

/// How often the state is read to see whether it changed: a change is
/// published within this long.
pub const WATCH: Duration = Duration::from_millis(100);

/// What a change of which publishes the state at once.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Salient {
    fsm: Option<String>,
    armed: Option<bool>,
    link: Option<String>,
}

impl Salient {
    /// What matters of a `state` response; `None` if it is not a success.
    fn of(response: &str) -> Option<Salient> {
        let value: Value = serde_json::from_str(response).ok()?;
        let state = &value["state"];
        (value["ret"] == 0).then(|| Salient {
            fsm: state["fsm"].as_str().map(str::to_owned),
            armed: state["armed"].as_bool(),
            link: state["link"].as_str().map(str::to_owned),
        })
    }
}

/// Publishes the state while the uplink runs: every `1/hz` seconds (never
/// periodically when `hz` is 0), at once on a change, and at once after
/// every (re)connection.
pub async fn publish<S: Sessions>(shared: Arc<Shared<S>>, hz: f64) {
    let period = (hz > 0.0).then(|| Duration::from_secs_f64(1.0 / hz));
    let mut tick = interval(WATCH.min(period.unwrap_or(WATCH)));
    tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let mut out = vec![0u8; shared.response_capacity];
    // No client id is empty: no client shares this session's throttle key.
    let mut reporter = shared.sessions.open(None, shared.key(""));
    let mut last: Option<(Salient, Instant)> = None;
    loop {
        let now = tick.tick().await;
        if shared.stopping.load(Ordering::Relaxed) {
            return;
        }
        if shared.status.get() != Status::Up {
            last = None;
            continue;
        }
        // A refusal (a login the throttle did not check, under attack) is
        // no state: the last one stays retained.
        let Some(response) = shared.sessions.state(&mut reporter, &mut out) else {
            continue;
        };
        let Some(salient) = Salient::of(&response) else {
            continue;
        };
        // Half a watch early counts as on time: ticks jitter.
        let due = match &last {
            None => true,
            Some((seen, at)) => *seen != salient || period.is_some_and(|p| now + WATCH / 2 >= *at + p),
        };
        if due {
            let topic = shared.topics.state().to_owned();
            // Fails only once the connection's task is gone (shutdown).
            let _ = shared
                .client
                .publish(topic, QoS::AtMostOnce, true, response)
                .await;
            last = Some((salient, now));
        }
    }
}
