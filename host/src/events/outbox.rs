//! The order events are published in: the order they happened, and an
//! event caused by a command only once that command's answer is written
//! (DESIGN.md, "Events").
//!
//! A command's events are staged under a hold (its session) until the
//! connection has written the answer; events that follow them (a tick's,
//! another command's) wait behind them, so `seq` never runs against the
//! order things happened. Holds last microseconds: from the command's
//! answer to the write of its frame.

use std::collections::VecDeque;
use std::sync::{Mutex, PoisonError};

use super::{Bus, Event};

/// Who holds an event back: a session whose answer is not written yet.
pub type Hold = u32;

/// Events waiting for their turn on the [`Bus`].
#[derive(Debug)]
pub struct Outbox {
    bus: Bus,
    queue: Mutex<VecDeque<Entry>>,
}

#[derive(Debug)]
struct Entry {
    hold: Option<Hold>,
    event: Event,
    ts: i64,
}

impl Outbox {
    /// An outbox publishing on `bus`.
    pub fn new(bus: Bus) -> Outbox {
        Outbox {
            bus,
            queue: Mutex::new(VecDeque::new()),
        }
    }

    /// The bus events go out on.
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// Queues `events` that happened at `ts`, held by `hold` until
    /// [`Outbox::release`], or free to go (`None`); publishes whatever is
    /// free at the front.
    pub fn stage(&self, hold: Option<Hold>, events: impl IntoIterator<Item = Event>, ts: i64) {
        let mut queue = self.lock();
        queue.extend(events.into_iter().map(|event| Entry { hold, event, ts }));
        self.pump(&mut queue);
    }

    /// `hold`'s answer is written: its events may go.
    pub fn release(&self, hold: Hold) {
        let mut queue = self.lock();
        let mut any = false;
        for entry in queue.iter_mut().filter(|e| e.hold == Some(hold)) {
            entry.hold = None;
            any = true;
        }
        if any {
            self.pump(&mut queue);
        }
    }

    /// Publishes from the front until a held event.
    fn pump(&self, queue: &mut VecDeque<Entry>) {
        while queue.front().is_some_and(|e| e.hold.is_none()) {
            if let Some(e) = queue.pop_front() {
                self.bus.publish(e.event, e.ts);
            }
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<Entry>> {
        // A panic while publishing leaves the queue as it was: still usable.
        self.queue.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

#[cfg(test)]
mod tests {
    use super::super::Next;
    use super::*;

    fn seen(sub: &mut super::super::Subscriber) -> Vec<String> {
        let mut out = Vec::new();
        while let Some(next) = futures_util::FutureExt::now_or_never(sub.next()) {
            match next {
                Next::Event(e) => out.push(e.event.name().to_owned() + &e.seq.to_string()),
                other => panic!("{other:?}"),
            }
        }
        out
    }

    #[test]
    fn held_events_wait_for_their_answer_and_later_events_wait_behind_them() {
        let outbox = Outbox::new(Bus::new("b".into()));
        let mut sub = outbox.bus().subscribe();
        outbox.stage(Some(7), [Event::Armed { armed: true }], 1);
        outbox.stage(None, [Event::Battery { percent: 20.0 }], 2);
        assert_eq!(seen(&mut sub), Vec::<String>::new(), "held");
        outbox.release(8);
        assert_eq!(seen(&mut sub), Vec::<String>::new(), "another hold");
        outbox.release(7);
        assert_eq!(seen(&mut sub), ["armed1", "battery2"]);
        outbox.stage(None, [Event::Link { up: true }], 3);
        assert_eq!(seen(&mut sub), ["link3"]);
    }
}
