//! The daemon's recent log messages, for `showmsg` and `savemsg`.
//!
//! A [`RecentLog`] is a bounded ring of formatted lines shared by clones.
//! [`RecentLog::layer`] is a tracing layer that formats every event into
//! it, so whatever the daemon logs is what `showmsg` shows. Its warnings
//! and errors are also told as `log` events (DESIGN.md, "Events") once
//! the daemon asks for them ([`RecentLog::tell_warnings`]).

use std::collections::VecDeque;
use std::fmt::{self, Write as _};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use tokio::sync::mpsc;
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::Layer;
use tracing_subscriber::layer::Context;

/// A ring buffer of the most recent log lines; clones share the buffer.
#[derive(Clone, Debug)]
pub struct RecentLog {
    inner: Arc<Mutex<Ring>>,
}

#[derive(Debug)]
struct Ring {
    lines: VecDeque<String>,
    capacity: usize,
    tap: Option<Tap>,
}

/// Warnings and errors told at once, and how many more per second: a
/// part that repeats a warning (an autopilot's pre-arm checks every 30 s,
/// a flapping link) would otherwise crowd every other event out of the
/// subscribers' queues. The log itself keeps every line.
const TELL_BURST: f64 = 20.0;
const TELL_PER_S: f64 = 2.0;
/// Warnings waiting for the daemon to publish them.
const TELL_QUEUE: usize = 64;

/// A warning or error, as a `log` event tells it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Warning {
    /// `warning` or `error`.
    pub level: &'static str,
    /// The line as `showmsg` shows it after its time, level and target:
    /// the message and its fields.
    pub msg: String,
    /// When it was logged, ms since the Unix epoch.
    pub ts: i64,
}

/// Where warnings go as events, within a budget. Sent without waiting
/// (the layer runs inside whatever logged, perhaps under a lock the
/// publisher needs): a full queue drops the warning from the events, never
/// from the log.
#[derive(Debug)]
struct Tap {
    tx: mpsc::Sender<Warning>,
    tokens: f64,
    filled: Instant,
    withheld: u64,
}

impl Tap {
    fn tell(&mut self, warning: Warning, now: Instant) {
        let since = now.saturating_duration_since(self.filled).as_secs_f64();
        self.filled = now;
        self.tokens = (self.tokens + since * TELL_PER_S).min(TELL_BURST);
        if self.tokens >= 1.0 && self.tx.try_send(warning).is_ok() {
            self.tokens -= 1.0;
        } else {
            // Counted, not logged: a warning about warnings would be one more.
            self.withheld = self.withheld.saturating_add(1);
        }
    }
}

impl RecentLog {
    /// A buffer keeping the last `capacity` lines (at least one).
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        RecentLog {
            inner: Arc::new(Mutex::new(Ring {
                lines: VecDeque::with_capacity(capacity.min(4096)),
                capacity,
                tap: None,
            })),
        }
    }

    /// Appends a line, dropping the oldest one when the buffer is full.
    pub fn push(&self, line: String) {
        self.record(line, None);
    }

    /// From now on, warnings and errors logged are also sent, within a
    /// budget (20 at once, 2 a second more), to the receiver returned: the
    /// daemon publishes them as `log` events. A second call replaces the
    /// first receiver.
    pub fn tell_warnings(&self) -> mpsc::Receiver<Warning> {
        let (tx, rx) = mpsc::channel(TELL_QUEUE);
        self.lock().tap = Some(Tap {
            tx,
            tokens: TELL_BURST,
            filled: Instant::now(),
            withheld: 0,
        });
        rx
    }

    /// Warnings and errors logged but not told as events (over the budget,
    /// or the daemon behind).
    pub fn withheld(&self) -> u64 {
        self.lock().tap.as_ref().map_or(0, |t| t.withheld)
    }

    /// Appends a line and tells `warning` if there is one to tell.
    fn record(&self, line: String, warning: Option<Warning>) {
        let mut ring = self.lock();
        if ring.lines.len() == ring.capacity {
            ring.lines.pop_front();
        }
        ring.lines.push_back(line);
        if let (Some(tap), Some(w)) = (ring.tap.as_mut(), warning) {
            tap.tell(w, Instant::now());
        }
    }

    /// The last `n` lines (fewer if fewer were logged), oldest first.
    pub fn recent(&self, n: usize) -> Vec<String> {
        let ring = self.lock();
        let skip = ring.lines.len().saturating_sub(n);
        ring.lines.iter().skip(skip).cloned().collect()
    }

    /// The last `n` lines, oldest first, and how many the buffer holds,
    /// read at one moment.
    pub fn recent_of(&self, n: usize) -> (Vec<String>, usize) {
        let ring = self.lock();
        let skip = ring.lines.len().saturating_sub(n);
        (ring.lines.iter().skip(skip).cloned().collect(), ring.lines.len())
    }

    /// How many lines the buffer holds now.
    pub fn len(&self) -> usize {
        self.lock().lines.len()
    }

    /// Whether nothing was logged yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// A tracing layer that writes every event into this buffer as
    /// `<UTC time> <LEVEL> <target>: <message> key=value ...`.
    pub fn layer<S: Subscriber>(&self) -> impl Layer<S> + use<S> {
        RecentLogLayer { log: self.clone() }
    }

    // A panic while holding the lock leaves only whole lines behind, so a
    // poisoned buffer is still consistent and worth reading.
    fn lock(&self) -> MutexGuard<'_, Ring> {
        self.inner.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

struct RecentLogLayer {
    log: RecentLog,
}

impl<S: Subscriber> Layer<S> for RecentLogLayer {
    fn on_event(&self, event: &Event<'_>, _ctx: Context<'_, S>) {
        let meta = event.metadata();
        let mut visitor = LineVisitor::default();
        event.record(&mut visitor);
        let mut line = String::with_capacity(64 + visitor.message.len() + visitor.fields.len());
        let now = SystemTime::now();
        write_utc(&mut line, now);
        let _ = write!(
            line,
            " {} {}: {}{}",
            meta.level(),
            meta.target(),
            visitor.message,
            visitor.fields
        );
        let level = match *meta.level() {
            Level::ERROR => Some("error"),
            Level::WARN => Some("warning"),
            _ => None,
        };
        let warning = level.map(|level| Warning {
            level,
            msg: visitor.message + &visitor.fields,
            ts: now
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX)),
        });
        self.log.record(line, warning);
    }
}

/// Collects an event's `message` and its other fields as ` key=value`.
#[derive(Default)]
struct LineVisitor {
    message: String,
    fields: String,
}

impl Visit for LineVisitor {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.message.push_str(value);
        } else {
            let _ = write!(self.fields, " {}={}", field.name(), value);
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.message, "{value:?}");
        } else {
            let _ = write!(self.fields, " {}={:?}", field.name(), value);
        }
    }
}

/// Writes `t` as `YYYY-MM-DDTHH:MM:SS.mmmZ` (also the time of `lluav
/// events` lines).
pub(crate) fn write_utc(out: &mut String, t: SystemTime) {
    let since = t.duration_since(UNIX_EPOCH).unwrap_or_default();
    let secs = since.as_secs();
    let (days, rem) = (secs / 86_400, secs % 86_400);
    let (y, m, d) = civil_from_days(days);
    let _ = write!(
        out,
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{:03}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        since.subsec_millis()
    );
}

/// The UTC date of `t` as `YYYYMMDD`, e.g. for directory names.
pub(crate) fn utc_date(t: SystemTime) -> String {
    let days = t.duration_since(UNIX_EPOCH).unwrap_or_default().as_secs() / 86_400;
    let (y, m, d) = civil_from_days(days);
    format!("{y:04}{m:02}{d:02}")
}

/// The proleptic Gregorian date `days` after 1970-01-01, by counting whole
/// 400-year eras (146 097 days each) and then years within the era.
fn civil_from_days(days: u64) -> (u64, u64, u64) {
    // Shift the epoch to 0000-03-01 so that leap days end each year.
    let z = days + 719_468;
    let era = z / 146_097;
    let doe = z % 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + u64::from(m <= 2);
    (y, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;
    use tracing_subscriber::layer::SubscriberExt;

    #[test]
    fn keeps_only_the_newest_lines_oldest_first() {
        let log = RecentLog::new(3);
        for i in 0..5 {
            log.push(format!("line {i}"));
        }
        assert_eq!(log.recent(10), ["line 2", "line 3", "line 4"]);
        assert_eq!(log.recent(2), ["line 3", "line 4"]);
        assert!(log.recent(0).is_empty());
    }

    #[test]
    fn clones_share_one_buffer() {
        let log = RecentLog::new(4);
        log.clone().push("from a clone".into());
        assert_eq!(log.recent(1), ["from a clone"]);
    }

    #[test]
    fn layer_records_level_target_message_and_fields() {
        let log = RecentLog::new(8);
        let subscriber = tracing_subscriber::registry().with(log.layer());
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!(target: "lluav::test", altitude = 12.5, "battery low");
        });
        let lines = log.recent(8);
        assert_eq!(lines.len(), 1);
        assert!(
            lines[0].ends_with(" WARN lluav::test: battery low altitude=12.5"),
            "{}",
            lines[0]
        );
    }

    fn told(rx: &mut mpsc::Receiver<Warning>) -> Vec<(&'static str, String)> {
        let mut out = Vec::new();
        while let Ok(w) = rx.try_recv() {
            out.push((w.level, w.msg));
        }
        out
    }

    #[test]
    fn warnings_and_errors_are_told_once_asked_for_and_the_rest_only_logged() {
        let log = RecentLog::new(16);
        let subscriber = tracing_subscriber::registry().with(log.layer());
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!("before anyone asked");
            let mut rx = log.tell_warnings();
            tracing::info!("a notice");
            tracing::warn!(altitude = 12.5, "battery low");
            tracing::error!("flush failed");
            tracing::debug!("detail");
            assert_eq!(
                told(&mut rx),
                [
                    ("warning", "battery low altitude=12.5".to_owned()),
                    ("error", "flush failed".to_owned())
                ]
            );
        });
        assert_eq!(log.len(), 5, "the log keeps every line");
    }

    #[test]
    fn a_flood_of_warnings_is_told_within_a_budget_and_nobody_reading_blocks_nothing() {
        let log = RecentLog::new(8);
        let mut rx = log.tell_warnings();
        let subscriber = tracing_subscriber::registry().with(log.layer());
        let started = Instant::now();
        tracing::subscriber::with_default(subscriber, || {
            for i in 0..1000 {
                tracing::warn!("again {i}");
            }
        });
        // The burst at once, plus what the budget refilled while the flood
        // lasted (however slow a loaded machine made it); the rest withheld.
        let refilled = (started.elapsed().as_secs_f64() * TELL_PER_S).ceil() as usize;
        let n = told(&mut rx).len();
        assert!(
            (TELL_BURST as usize..=TELL_BURST as usize + refilled).contains(&n),
            "{n} told, {refilled} refilled"
        );
        assert_eq!(log.withheld(), 1000 - n as u64);
        // Nobody reading: the layer still returns, and the log has them all.
        let _unread = log.tell_warnings();
        let subscriber = tracing_subscriber::registry().with(log.layer());
        let started = Instant::now();
        tracing::subscriber::with_default(subscriber, || {
            for i in 0..(TELL_QUEUE + 100) {
                tracing::error!("unread {i}");
            }
        });
        let refilled = (started.elapsed().as_secs_f64() * TELL_PER_S).ceil() as usize;
        let sent = TELL_QUEUE + 100 - usize::try_from(log.withheld()).unwrap_or(0);
        assert!(sent <= TELL_BURST as usize + refilled, "{sent} sent");
        assert!(log.recent(1)[0].ends_with(&format!("unread {}", TELL_QUEUE + 99)));
    }

    #[test]
    fn timestamps_are_utc_calendar_dates() {
        let mut s = String::new();
        // 2024-02-29T12:34:56.789Z: a leap day.
        write_utc(&mut s, UNIX_EPOCH + Duration::from_millis(1_709_210_096_789));
        assert_eq!(s, "2024-02-29T12:34:56.789Z");
        s.clear();
        write_utc(&mut s, UNIX_EPOCH);
        assert_eq!(s, "1970-01-01T00:00:00.000Z");
    }
}
