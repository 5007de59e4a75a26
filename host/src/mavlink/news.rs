//! What the MAVLink vehicle tells as events (DESIGN.md, "Events"), from
//! what the autopilot says: its link, the FSM as `state.fsm` derives it,
//! arming, failsafes, the battery crossing its levels and its
//! `STATUSTEXT`s of severity WARNING or graver. Mission progress comes
//! from [`super::mission`] and is told here in its place.
//!
//! Sans-IO: [`News::notice`] compares what the vehicle looks like now
//! ([`Seen`]) with what was told last and queues one event per change;
//! the link's tasks call it after every packet and when time alone
//! changes something (the link lost), the daemon drains the queue.

use std::collections::VecDeque;

use ::mavlink::dialects::ardupilotmega::{MavSeverity, STATUSTEXT_DATA};
use lluav_core::Failsafe;

use crate::events::{Event, battery_band};

/// The battery level the first battery event is told at: the simulator's
/// `low_battery` default. (The autopilot's own low-battery level is not
/// read: PX4 and ArduPilot name and scale it differently, and a charge
/// told at 20 % is what operators of both backends see alike.)
pub const LOW_BATTERY: f64 = 20.0;
/// How far above a level the battery must climb again before the climb
/// is told: an autopilot's charge estimate rests on the voltage, which
/// sags under load and recovers when it eases (a climb, then a hover),
/// and a level crossed back and forth would be told every time.
const BATTERY_HYSTERESIS: f64 = 2.0;
/// Events queued before the oldest are dropped: only when nobody drains
/// them (a vehicle opened without a daemon); the daemon drains at once.
const MAX_QUEUED: usize = 1024;
/// What the vehicle looks like now, as far as events go.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seen {
    /// Whether the autopilot's heartbeat came within the link timeout.
    pub link_up: bool,
    /// `state.fsm`.
    pub fsm: &'static str,
    /// The heartbeat's armed flag.
    pub armed: bool,
    /// The failsafe, as `state.failsafe` shows it.
    pub failsafe: Option<Failsafe>,
    /// The battery's charge, percent, if the autopilot reports one.
    pub battery: Option<f64>,
}

/// The events told since the daemon last took them, and what was told
/// last.
#[derive(Debug)]
pub struct News {
    queue: VecDeque<Event>,
    link_up: bool,
    fsm: &'static str,
    armed: bool,
    failsafe: Option<Failsafe>,
    /// The battery's band as last told: 0 at or above the low level, one
    /// more for each 10 % below it, `i32::MAX` empty.
    band: i32,
    /// Queued events dropped because nobody drained them.
    dropped: u64,
}

impl Default for News {
    fn default() -> Self {
        News {
            queue: VecDeque::new(),
            link_up: false,
            // What `state.fsm` says of an autopilot not heard yet.
            fsm: "disarmed",
            armed: false,
            failsafe: None,
            band: 0,
            dropped: 0,
        }
    }
}

impl News {
    /// Queues `event`.
    pub fn tell(&mut self, event: Event) {
        if self.queue.len() == MAX_QUEUED {
            self.queue.pop_front();
            self.dropped += 1;
            if self.dropped.is_power_of_two() {
                tracing::warn!(
                    dropped = self.dropped,
                    "MAVLink events dropped: nobody takes them"
                );
            }
        }
        self.queue.push_back(event);
    }

    /// Hands every queued event to `out`, oldest first.
    pub fn drain(&mut self, out: &mut Vec<Event>) {
        out.extend(self.queue.drain(..));
    }

    /// Tells what changed since the last look: the link coming up first
    /// (whatever follows comes from it), then the mission's progress
    /// (`mission`), a failsafe starting or overridden (the cause before
    /// the mode change it brings), the FSM, arming, a failsafe ending
    /// (disarmed), the link lost and the battery: the simulator's order
    /// where it has one.
    pub fn notice(&mut self, seen: &Seen, mission: impl IntoIterator<Item = Event>) {
        if seen.link_up && !self.link_up {
            self.link_up = true;
            self.tell(Event::Link { up: true });
        }
        for event in mission {
            self.tell(event);
        }
        let failsafe = (seen.failsafe != self.failsafe).then_some(seen.failsafe);
        if let Some(Some(f)) = failsafe {
            self.failsafe = Some(f);
            self.tell(Event::Failsafe {
                reason: Some(f.reason().to_string()),
                action: f.action.name(),
                overridden: f.overridden,
            });
        }
        if seen.fsm != self.fsm {
            let from = std::mem::replace(&mut self.fsm, seen.fsm);
            self.tell(Event::Fsm { from, to: seen.fsm });
        }
        if seen.armed != self.armed {
            self.armed = seen.armed;
            self.tell(Event::Armed { armed: seen.armed });
        }
        if let Some(None) = failsafe {
            self.failsafe = None;
            self.tell(Event::Failsafe {
                reason: None,
                action: "none",
                overridden: false,
            });
        }
        if !seen.link_up && self.link_up {
            self.link_up = false;
            self.tell(Event::Link { up: false });
        }
        if let Some(percent) = seen.battery {
            let band = next_band(self.band, percent, LOW_BATTERY);
            if band != self.band {
                self.band = band;
                self.tell(Event::Battery { percent });
            }
        }
    }
}

/// Logs a `STATUSTEXT` at its severity: every one goes to lluavd's log
/// (what `showmsg` shows), and the log tells those of severity WARNING or
/// graver as `log` events, as it does every warning
/// ([`crate::recent_log::RecentLog::tell_warnings`]).
pub fn statustext(s: &STATUSTEXT_DATA) {
    let Some(msg) = text(s) else { return };
    match s.severity {
        MavSeverity::MAV_SEVERITY_EMERGENCY
        | MavSeverity::MAV_SEVERITY_ALERT
        | MavSeverity::MAV_SEVERITY_CRITICAL
        | MavSeverity::MAV_SEVERITY_ERROR => tracing::error!("{msg}"),
        MavSeverity::MAV_SEVERITY_WARNING => tracing::warn!("{msg}"),
        MavSeverity::MAV_SEVERITY_NOTICE | MavSeverity::MAV_SEVERITY_INFO => tracing::info!("{msg}"),
        MavSeverity::MAV_SEVERITY_DEBUG => tracing::debug!("{msg}"),
    }
}

/// A `STATUSTEXT`'s line as the log and the event show it: `autopilot: `
/// and its text (up to the first NUL, invalid UTF-8 replaced, trailing
/// white space gone), or `None` when it says nothing.
fn text(s: &STATUSTEXT_DATA) -> Option<String> {
    let bytes: &[u8] = &s.text[..];
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    let text = String::from_utf8_lossy(&bytes[..end]);
    let text = text.trim();
    (!text.is_empty()).then(|| format!("autopilot: {text}"))
}

/// The band to tell after `told` at `percent`: a fall at once, a climb
/// only once [`BATTERY_HYSTERESIS`] above the level it climbs past.
fn next_band(told: i32, percent: f64, low: f64) -> i32 {
    let now = battery_band(percent, low);
    if now >= told {
        now
    } else {
        told.min(battery_band(percent - BATTERY_HYSTERESIS, low))
    }
}

#[cfg(test)]
mod tests {
    use lluav_core::Action;

    use super::*;

    fn seen() -> Seen {
        Seen {
            link_up: true,
            fsm: "disarmed",
            armed: false,
            failsafe: None,
            battery: None,
        }
    }

    fn take(news: &mut News) -> Vec<Event> {
        let mut out = Vec::new();
        news.drain(&mut out);
        out
    }

    fn rtl() -> Failsafe {
        Failsafe {
            source: "autopilot",
            detail: "AUTO.RTL",
            action: Action::Rtl,
            overridden: false,
        }
    }

    #[test]
    fn each_change_is_told_once_in_the_simulators_order() {
        let mut news = News::default();
        news.notice(&seen(), []);
        assert_eq!(take(&mut news), [Event::Link { up: true }]);
        news.notice(&seen(), []);
        assert_eq!(take(&mut news), [], "nothing changed");
        let flying = Seen {
            fsm: "takeoff",
            armed: true,
            ..seen()
        };
        news.notice(&flying, []);
        assert_eq!(
            take(&mut news),
            [
                Event::Fsm {
                    from: "disarmed",
                    to: "takeoff"
                },
                Event::Armed { armed: true }
            ]
        );
        // A failsafe before the mode change it brings.
        let returning = Seen {
            fsm: "rtl",
            failsafe: Some(rtl()),
            ..flying
        };
        news.notice(&returning, []);
        let told = take(&mut news);
        assert_eq!(
            told[0],
            Event::Failsafe {
                reason: Some("autopilot: AUTO.RTL".into()),
                action: "rtl",
                overridden: false
            }
        );
        assert_eq!(
            told[1],
            Event::Fsm {
                from: "takeoff",
                to: "rtl"
            }
        );
        // Overridden: told again, with the flag.
        let overridden = Seen {
            failsafe: Some(Failsafe {
                overridden: true,
                ..rtl()
            }),
            ..returning
        };
        news.notice(&overridden, []);
        assert_eq!(
            take(&mut news),
            [Event::Failsafe {
                reason: Some("autopilot: AUTO.RTL".into()),
                action: "rtl",
                overridden: true
            }]
        );
        // Disarmed: the FSM, arming, then the failsafe's end.
        news.notice(&seen(), []);
        assert_eq!(
            take(&mut news),
            [
                Event::Fsm {
                    from: "rtl",
                    to: "disarmed"
                },
                Event::Armed { armed: false },
                Event::Failsafe {
                    reason: None,
                    action: "none",
                    overridden: false
                }
            ]
        );
        news.notice(
            &Seen {
                link_up: false,
                ..seen()
            },
            [],
        );
        assert_eq!(take(&mut news), [Event::Link { up: false }]);
    }

    #[test]
    fn mission_progress_comes_after_the_link_and_before_the_fsm_it_moves() {
        let mut news = News::default();
        let done = Event::Mission {
            ext_id: 3,
            status: crate::events::MissionStatus::Completed,
        };
        news.notice(
            &Seen {
                fsm: "hover",
                armed: true,
                ..seen()
            },
            [done.clone()],
        );
        let told = take(&mut news);
        assert_eq!(told[0], Event::Link { up: true });
        assert_eq!(told[1], done);
        assert!(matches!(told[2], Event::Fsm { to: "hover", .. }));
    }

    fn battery(news: &mut News, percent: f64) -> Vec<Event> {
        news.notice(
            &Seen {
                battery: Some(percent),
                ..seen()
            },
            [],
        );
        take(news)
            .into_iter()
            .filter(|e| matches!(e, Event::Battery { .. }))
            .collect()
    }

    #[test]
    fn the_battery_is_told_at_20_each_10_below_and_empty() {
        let mut news = News::default();
        let told: Vec<_> = [90.0, 21.0, 19.0, 15.0, 9.5, 3.0, 0.0]
            .into_iter()
            .flat_map(|p| battery(&mut news, p))
            .collect();
        assert_eq!(told, [19.0, 9.5, 0.0].map(|percent| Event::Battery { percent }));
    }

    #[test]
    fn a_battery_recovering_under_less_load_is_told_only_clear_of_the_level() {
        let mut news = News::default();
        assert_eq!(battery(&mut news, 19.0).len(), 1);
        // Back to 20 and 21 % in a hover: still the band below.
        assert_eq!(battery(&mut news, 20.0), []);
        assert_eq!(battery(&mut news, 21.0), []);
        assert_eq!(battery(&mut news, 19.5), []);
        // A charge well above it is told.
        assert_eq!(battery(&mut news, 60.0), [Event::Battery { percent: 60.0 }]);
        // Out of empty only with some charge.
        assert_eq!(battery(&mut news, 0.0).len(), 1);
        assert_eq!(battery(&mut news, 1.0), []);
    }

    fn statustext_data(severity: MavSeverity, text: &str) -> STATUSTEXT_DATA {
        STATUSTEXT_DATA {
            severity,
            text: text.into(),
        }
    }

    #[test]
    fn statustext_is_logged_at_its_severity_and_the_graver_told_as_log() {
        use tracing_subscriber::layer::SubscriberExt;
        let log = crate::recent_log::RecentLog::new(16);
        let mut told = log.tell_warnings();
        let subscriber = tracing_subscriber::registry().with(log.layer());
        let mut bad = statustext_data(MavSeverity::MAV_SEVERITY_ERROR, "");
        bad.text = [0xff; 50].into();
        tracing::subscriber::with_default(subscriber, || {
            statustext(&statustext_data(
                MavSeverity::MAV_SEVERITY_WARNING,
                "Low battery  ",
            ));
            statustext(&statustext_data(
                MavSeverity::MAV_SEVERITY_CRITICAL,
                "PreArm: GPS not healthy",
            ));
            statustext(&statustext_data(
                MavSeverity::MAV_SEVERITY_INFO,
                "Takeoff detected",
            ));
            statustext(&statustext_data(
                MavSeverity::MAV_SEVERITY_ERROR,
                "\0garbage after",
            ));
            statustext(&bad);
        });
        let mut warnings = Vec::new();
        while let Ok(w) = told.try_recv() {
            warnings.push((w.level, w.msg));
        }
        assert_eq!(
            warnings[..2],
            [
                ("warning", "autopilot: Low battery".to_owned()),
                ("error", "autopilot: PreArm: GPS not healthy".to_owned()),
            ]
        );
        // Invalid UTF-8 is shown replaced, not dropped; nothing is no line.
        assert!(warnings[2].1.starts_with("autopilot: \u{fffd}"), "{warnings:?}");
        assert_eq!(warnings.len(), 3);
        assert!(
            log.recent(16)
                .iter()
                .any(|l| l.ends_with("INFO lluav_host::mavlink::news: autopilot: Takeoff detected"))
        );
        assert_eq!(log.len(), 4);
    }

    #[test]
    fn events_nobody_takes_are_bounded() {
        let mut news = News::default();
        for i in 0..(MAX_QUEUED + 5) {
            news.tell(Event::Armed { armed: i % 2 == 0 });
        }
        assert_eq!(take(&mut news).len(), MAX_QUEUED);
        assert_eq!(take(&mut news), []);
    }
}
