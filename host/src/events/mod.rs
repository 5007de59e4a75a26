//! What happened to the vehicle, told as it happens (DESIGN.md, "Events"):
//! the FSM, arming, mission progress, failsafes, who flies, the battery,
//! the autopilot link, the uplink and the log's warnings.
//!
//! The parts that notice a change emit an [`Event`] (the vehicle while it
//! runs a command or advances, the daemon for control, the uplink for its
//! connection, the log for warnings); the [`Bus`] numbers it (`seq`, from 1
//! per boot, and the `boot` id) and hands it to every subscriber: the
//! `/events` WebSocket endpoint, the uplink's `events` topic, and the parts
//! of lluavd that act on changes instead of polling (the uplink's state on
//! change). Each subscriber has a bounded queue; a slow one misses the
//! oldest events and gets a `gap` saying how many — the vehicle never
//! waits for a subscriber.

pub mod json;
pub mod outbox;

use std::sync::{Arc, Mutex, PoisonError};

use tokio::sync::broadcast;

pub use json::{gap, render};
pub use outbox::{Hold, Outbox};

/// Events a subscriber's queue holds before the oldest are dropped.
pub const QUEUE: usize = 256;

/// The battery's band, whose change is told as a `battery` event
/// (DESIGN.md, "Events": when it crosses `low_battery`, each 10 % below
/// it, and 0): 0 at or above `low`, one more for each 10 % below it,
/// `i32::MAX` when empty. Both backends tell the battery by it.
pub fn battery_band(percent: f64, low: f64) -> i32 {
    if percent <= 0.0 {
        i32::MAX
    } else if percent >= low {
        0
    } else {
        1 + ((low - percent) / 10.0).floor() as i32
    }
}

/// A mission's progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MissionStatus {
    /// The run started.
    Started,
    /// A waypoint was reached.
    Reached {
        /// The waypoint's id.
        wp: u32,
        /// Its 1-based position in the run.
        index: u32,
        /// How many waypoints the run has.
        count: u32,
    },
    /// Every waypoint was reached.
    Completed,
    /// It ended before its last waypoint.
    Aborted,
}

/// Something that happened, with its own fields.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// The FSM changed state (names as `state.fsm` gives them).
    Fsm {
        /// The state it left.
        from: &'static str,
        /// The state it entered.
        to: &'static str,
    },
    /// The motors were armed or disarmed.
    Armed {
        /// Armed now.
        armed: bool,
    },
    /// A mission run's progress.
    Mission {
        /// The mission's external id.
        ext_id: u32,
        /// What happened.
        status: MissionStatus,
    },
    /// A failsafe started, was overridden or ended.
    Failsafe {
        /// Its reason as `state.failsafe` names it; `None` when it ended.
        reason: Option<String>,
        /// What the vehicle does: `rtl`, `land`, `hold` or `none`.
        action: &'static str,
        /// Whether the session in control overrode it.
        overridden: bool,
    },
    /// Control passed, was released or lapsed.
    Control {
        /// Who flies now; `None` when control is free.
        by: Option<String>,
        /// Who flew before; `None` when control was free.
        from: Option<String>,
    },
    /// The battery crossed a level worth telling: `low_battery`, each 10 %
    /// below it, and 0.
    Battery {
        /// Percent, one decimal.
        percent: f64,
    },
    /// The link to the autopilot came up or was lost (MAVLink).
    Link {
        /// Up now.
        up: bool,
    },
    /// The uplink's broker connection came up or went down.
    Uplink {
        /// Up now.
        up: bool,
    },
    /// A warning or error the log (`showmsg`) shows.
    Log {
        /// `warning` or `error`.
        level: &'static str,
        /// The line.
        msg: String,
    },
}

impl Event {
    /// The event's name on the wire.
    pub fn name(&self) -> &'static str {
        match self {
            Event::Fsm { .. } => "fsm",
            Event::Armed { .. } => "armed",
            Event::Mission { .. } => "mission",
            Event::Failsafe { .. } => "failsafe",
            Event::Control { .. } => "control",
            Event::Battery { .. } => "battery",
            Event::Link { .. } => "link",
            Event::Uplink { .. } => "uplink",
            Event::Log { .. } => "log",
        }
    }
}

/// An event as the bus numbered it.
#[derive(Clone, Debug, PartialEq)]
pub struct Numbered {
    /// Counts from 1 in this boot.
    pub seq: u64,
    /// When it was published, ms since the Unix epoch.
    pub ts: i64,
    /// What happened.
    pub event: Event,
    /// The JSON object subscribers get (rendered once for all of them).
    pub json: Arc<str>,
}

/// Numbers events and hands them to every subscriber.
#[derive(Clone, Debug)]
pub struct Bus {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    boot: String,
    /// The last `seq` given, under the lock that also orders sends, so
    /// that subscribers see `seq` in order.
    last: Mutex<u64>,
    tx: broadcast::Sender<Arc<Numbered>>,
}

impl Bus {
    /// A bus for one run of the daemon, identified by `boot`.
    pub fn new(boot: String) -> Bus {
        let (tx, _) = broadcast::channel(QUEUE);
        Bus {
            inner: Arc::new(Inner {
                boot,
                last: Mutex::new(0),
                tx,
            }),
        }
    }

    /// A bus with a fresh random boot id.
    pub fn fresh() -> Bus {
        Bus::new(boot_id())
    }

    /// This run's id.
    pub fn boot(&self) -> &str {
        &self.inner.boot
    }

    /// Numbers `event`, stamped `ts`, and hands it to every subscriber
    /// (none waits: a full queue drops its oldest).
    pub fn publish(&self, event: Event, ts: i64) {
        let mut last = self.inner.last.lock().unwrap_or_else(PoisonError::into_inner);
        *last += 1;
        let seq = *last;
        let json = render(&event, seq, &self.inner.boot, ts).into();
        // No subscriber is not an error: the event is numbered all the same.
        let _ = self.inner.tx.send(Arc::new(Numbered { seq, ts, event, json }));
    }

    /// A new subscriber: it gets every event published from now on.
    pub fn subscribe(&self) -> Subscriber {
        Subscriber {
            rx: self.inner.tx.subscribe(),
        }
    }
}

/// One subscriber's view of the bus.
#[derive(Debug)]
pub struct Subscriber {
    rx: broadcast::Receiver<Arc<Numbered>>,
}

/// What a subscriber gets next.
#[derive(Clone, Debug, PartialEq)]
pub enum Next {
    /// An event.
    Event(Arc<Numbered>),
    /// It was too slow: this many events were dropped before the next.
    Gap(u64),
    /// The bus is gone (the daemon stops).
    Closed,
}

impl Subscriber {
    /// Waits for the next event, or says how many this subscriber missed.
    pub async fn next(&mut self) -> Next {
        match self.rx.recv().await {
            Ok(e) => Next::Event(e),
            Err(broadcast::error::RecvError::Lagged(n)) => Next::Gap(n),
            Err(broadcast::error::RecvError::Closed) => Next::Closed,
        }
    }

    /// The next event if one is there already, without waiting: for a
    /// subscriber that acts once on a burst of events.
    pub fn try_next(&mut self) -> Option<Next> {
        match self.rx.try_recv() {
            Ok(e) => Some(Next::Event(e)),
            Err(broadcast::error::TryRecvError::Lagged(n)) => Some(Next::Gap(n)),
            Err(broadcast::error::TryRecvError::Closed) => Some(Next::Closed),
            Err(broadcast::error::TryRecvError::Empty) => None,
        }
    }
}

/// Now, ms since the Unix epoch (0 for a clock before 1970): events and
/// gaps are stamped like responses.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// A boot id: 16 hex digits from the OS's randomness, distinct per run.
fn boot_id() -> String {
    let mut bytes = [0u8; 8];
    // getrandom never fails on Linux once the pool is initialised; the
    // time as a fallback still tells runs apart.
    if getrandom(&mut bytes).is_err() {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        bytes = (now as u64).to_be_bytes();
    }
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn getrandom(buf: &mut [u8]) -> std::io::Result<()> {
    use std::io::Read;
    std::fs::File::open("/dev/urandom")?.read_exact(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn subscribers_get_every_event_in_seq_order() {
        let bus = Bus::new("b00t".into());
        let mut a = bus.subscribe();
        let mut b = bus.subscribe();
        bus.publish(Event::Armed { armed: true }, 10);
        bus.publish(
            Event::Fsm {
                from: "armed",
                to: "takeoff",
            },
            11,
        );
        for s in [&mut a, &mut b] {
            let Next::Event(first) = s.next().await else {
                panic!()
            };
            let Next::Event(second) = s.next().await else {
                panic!()
            };
            assert_eq!((first.seq, second.seq), (1, 2));
            assert_eq!(
                &*first.json,
                r#"{"event":"armed","seq":1,"boot":"b00t","ts":10,"armed":true}"#
            );
        }
    }

    #[tokio::test]
    async fn a_slow_subscriber_gets_a_gap_and_then_the_newest_events() {
        let bus = Bus::new("b".into());
        let mut slow = bus.subscribe();
        for i in 0..(QUEUE as i64 + 10) {
            bus.publish(Event::Armed { armed: i % 2 == 0 }, i);
        }
        assert_eq!(slow.next().await, Next::Gap(10));
        let Next::Event(e) = slow.next().await else {
            panic!()
        };
        assert_eq!(e.seq, 11);
    }

    #[test]
    fn try_next_takes_what_is_there_and_never_waits() {
        let bus = Bus::new("b".into());
        let mut sub = bus.subscribe();
        assert_eq!(sub.try_next(), None);
        bus.publish(Event::Link { up: true }, 1);
        assert!(matches!(sub.try_next(), Some(Next::Event(e)) if e.seq == 1));
        assert_eq!(sub.try_next(), None);
    }

    #[test]
    fn boot_ids_differ_between_runs() {
        assert_ne!(boot_id(), boot_id());
        assert_eq!(boot_id().len(), 16);
    }
}
