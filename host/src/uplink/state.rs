//! `lluav/V/state`: the whole `state` response, retained, at the
//! configured rate and at once when `fsm`, `armed` or `link` change.
//!
//! Changes are learnt from the events bus (an `fsm`, `armed`, `link` or
//! `uplink` event, or a gap), never by reading the state to compare: an
//! idle vehicle costs the configured rate and nothing else (none at
//! `--uplink-state-hz 0`). A burst of events is one read of the state,
//! published only if what matters of it changed.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use rumqttc::v5::mqttbytes::QoS;
use serde::Deserialize;
use tokio::time::{Instant, sleep};

use super::Sessions;
use super::link::Status;
use super::serve::Shared;
use crate::alarm::Alarm;
use crate::events::{Event, Next, Subscriber};

/// How long to wait before asking again when `state` was refused (a login
/// the throttle did not check, under attack).
const RETRY: Duration = Duration::from_millis(250);

/// What a change of which publishes the state at once.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
struct Salient {
    fsm: Option<String>,
    armed: Option<bool>,
    link: Option<String>,
}

impl Salient {
    /// What matters of a `state` response; `None` if it is not one.
    fn of(response: &str) -> Option<Salient> {
        // Only these fields: the rest is skipped, never built into values.
        #[derive(Deserialize)]
        struct Response {
            state: Salient,
        }
        let response: Response = serde_json::from_str(response).ok()?;
        Some(response.state)
    }
}

/// Why the state is looked at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Wake {
    /// Something that matters may have changed: published if it did.
    Change,
    /// The rate's time came: published whatever it says.
    Period,
    /// The bus is gone.
    Closed,
}

/// Whether `event` may change what [`Salient`] holds (or, `uplink` up,
/// makes a publication due: the broker has none from this connection).
fn salient(event: &Event) -> bool {
    matches!(
        event,
        Event::Fsm { .. } | Event::Armed { .. } | Event::Link { .. } | Event::Uplink { up: true }
    )
}

/// Waits for an event that may change the state, then takes the rest of
/// the burst already there; never returns without `events`.
async fn change(events: &mut Option<Subscriber>) -> Wake {
    let Some(sub) = events else {
        return std::future::pending().await;
    };
    loop {
        match sub.next().await {
            Next::Event(e) if !salient(&e.event) => continue,
            // Missed events may have been changes.
            Next::Event(_) | Next::Gap(_) => break,
            Next::Closed => return Wake::Closed,
        }
    }
    while let Some(next) = sub.try_next() {
        if next == Next::Closed {
            return Wake::Closed;
        }
    }
    Wake::Change
}

/// Publishes the state while the uplink runs: every `1/hz` seconds (never
/// periodically when `hz` is 0), at once on a change `events` tells, and at
/// once after every (re)connection.
pub async fn publish<S: Sessions>(shared: Arc<Shared<S>>, hz: f64, mut events: Option<Subscriber>) {
    let period = (hz > 0.0).then(|| Duration::from_secs_f64(1.0 / hz));
    let mut out = vec![0u8; shared.response_capacity];
    // No client id is empty: no client shares this session's throttle key.
    let mut reporter = shared.sessions.open(None, shared.key(""));
    // What the last publication said of what matters, and when it went.
    let mut seen: Option<Salient> = None;
    let mut at: Option<Instant> = None;
    let mut alarm = Alarm::new();
    loop {
        let up = shared.status.get() == Status::Up;
        if !up {
            (seen, at) = (None, None);
        }
        let due = match at {
            _ if !up => None,
            None => Some(Instant::now()),
            Some(at) => period.map(|p| at + p),
        };
        let wake = tokio::select! {
            wake = change(&mut events) => wake,
            () = alarm.until(due) => Wake::Period,
            // A (re)connection, even without events.
            () = shared.status.up(), if !up => Wake::Change,
        };
        if wake == Wake::Closed || shared.stopping.load(Ordering::Relaxed) {
            return;
        }
        if shared.status.get() != Status::Up {
            continue;
        }
        // A refusal is no state: the last one stays retained.
        let Some(response) = shared
            .sessions
            .state(&mut reporter, &mut out)
            .filter(|r| lluav_core::response::is_success(r.as_bytes()))
        else {
            sleep(RETRY).await;
            continue;
        };
        // Only a change is compared (parsed): every change of what matters
        // is an event, so a period in between publishes what was compared.
        if wake != Wake::Period || seen.is_none() {
            let salient = Salient::of(&response);
            if salient.is_some() && salient == seen {
                continue;
            }
            seen = salient;
        }
        let topic = shared.topics.state().to_owned();
        // Fails only once the connection's task is gone (shutdown).
        let _ = shared
            .client
            .publish(topic, QoS::AtMostOnce, true, response)
            .await;
        at = Some(Instant::now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::Bus;

    #[tokio::test]
    async fn a_burst_of_events_is_one_change_and_other_events_none() {
        let bus = Bus::new("b".into());
        let mut events = Some(bus.subscribe());
        bus.publish(Event::Battery { percent: 50.0 }, 1);
        bus.publish(Event::Fsm { from: "a", to: "b" }, 2);
        bus.publish(Event::Armed { armed: true }, 3);
        bus.publish(Event::Fsm { from: "b", to: "c" }, 4);
        assert_eq!(change(&mut events).await, Wake::Change);
        bus.publish(Event::Battery { percent: 40.0 }, 5);
        bus.publish(Event::Uplink { up: false }, 6);
        let waiting = futures_util::FutureExt::now_or_never(change(&mut events));
        assert_eq!(waiting, None, "neither the battery nor a down is a change");
        bus.publish(Event::Uplink { up: true }, 7);
        assert_eq!(change(&mut events).await, Wake::Change);
    }

    #[test]
    fn what_matters_of_a_state_response() {
        let s = Salient::of(
            r#"{"ret":0,"cmd":2,"state":{"fsm":"hover","pos":{"x":1.5},"armed":true,"link":"up","bat":[1,2]},"ts":9}"#,
        );
        assert_eq!(
            s,
            Some(Salient {
                fsm: Some("hover".into()),
                armed: Some(true),
                link: Some("up".into()),
            })
        );
        assert_eq!(Salient::of(r#"{"ret":-1,"cmd":2,"msg":"no"}"#), None);
        assert!(lluav_core::response::is_success(br#"{"ret":0,"cmd":2,"ts":1}"#));
        assert!(!lluav_core::response::is_success(
            br#"{"ret":-1,"cmd":2,"ts":1,"msg":"no"}"#
        ));
    }
}
