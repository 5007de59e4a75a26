//! `lluav/V/events` (DESIGN.md, "Events"): every event of the bus, the
//! same objects `/events` subscribers get (same `seq`, same `boot`), QoS 1,
//! not retained.
//!
//! The uplink is one more subscriber of the bus, with the same bounded
//! queue: when the broker takes events more slowly than they come (or the
//! link is down for long), the oldest are dropped and the next thing
//! published is a `gap` saying how many. While the link is down nothing is
//! published; what happens meanwhile waits in the queue and goes out once
//! the link is up again. The uplink cannot carry its own `uplink` `down`:
//! that `seq` is skipped.

use std::sync::Arc;

use rumqttc::v5::mqttbytes::QoS;

use super::Sessions;
use super::serve::Shared;
use crate::events::{Event, Next, Subscriber, gap, now_ms};

/// What the events topic carries of `next`: the payload, or `None` for
/// what it skips; `Err` once the bus is gone.
fn payload(next: Next) -> Result<Option<String>, ()> {
    match next {
        Next::Event(e) if e.event == (Event::Uplink { up: false }) => Ok(None),
        Next::Event(e) => Ok(Some(e.json.to_string())),
        Next::Gap(missed) => Ok(Some(gap(missed, now_ms()))),
        Next::Closed => Err(()),
    }
}

/// Publishes the events of `events` on `lluav/V/events` while the uplink
/// runs, waiting for the link while it is down.
pub async fn publish<S: Sessions>(shared: Arc<Shared<S>>, mut events: Subscriber) {
    loop {
        shared.status.up().await;
        let Ok(payload) = payload(events.next().await) else {
            return;
        };
        let Some(payload) = payload else {
            continue;
        };
        let topic = shared.topics.events().to_owned();
        // Waits while the connection's queue is full (a broker that does
        // not acknowledge): the bus's queue fills meanwhile, then a gap.
        // Fails only once the connection's task is gone (shutdown).
        let _ = shared
            .client
            .publish(topic, QoS::AtLeastOnce, false, payload)
            .await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::Bus;

    #[tokio::test]
    async fn the_uplinks_own_down_is_skipped_and_a_gap_is_told() {
        let bus = Bus::new("b".into());
        let mut sub = bus.subscribe();
        bus.publish(Event::Uplink { up: false }, 1);
        bus.publish(Event::Uplink { up: true }, 2);
        assert_eq!(payload(sub.next().await), Ok(None));
        assert_eq!(
            payload(sub.next().await),
            Ok(Some(
                r#"{"event":"uplink","seq":2,"boot":"b","ts":2,"state":"up"}"#.into()
            ))
        );
        let gap = payload(Next::Gap(3)).ok().flatten().unwrap_or_default();
        assert!(gap.starts_with(r#"{"event":"gap","missed":3,"ts":"#), "{gap}");
        assert_eq!(payload(Next::Closed), Err(()));
    }
}
