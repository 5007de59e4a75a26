//! Flight authority (DESIGN.md, "Flight authority"): which session flies
//! the vehicle, and the failsafes no motion command may cancel.
//!
//! lluav serves many operators at once (WebSocket sessions on the
//! vehicle's network, client ids through a broker). Obeying whoever spoke
//! last let a streamed setpoint cancel a low-battery return and another
//! operator's landing. Three rules, here so that every adapter and
//! transport shares them:
//! - one envelope for every target: the backends' business (their limits);
//! - failsafes win: the backend says when one holds ([`Failsafe`]); while
//!   it does, motion commands are refused and only the session in control
//!   can override it (`control_take failsafe`);
//! - one session flies at a time ([`Pilot`]): the one whose motion command
//!   last answered 0, until it ends, releases, lapses after the backend's
//!   control timeout without a request, or someone takes over.

use crate::number::Digits;
use crate::response::Fields;

/// Longest [`Label`], in bytes: `mqtt ` and a 64-byte client id, or `ws `,
/// a bracketed IPv6 address with its port and ` #` and a session id.
pub const MAX_LABEL_LEN: usize = 72;

/// Who a session is, as `control` names it: `ws 192.0.2.7:51234 #12`,
/// `mqtt <client id>`. No secrets: what a peer could see anyway.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Label(heapless::String<MAX_LABEL_LEN>);

impl Label {
    /// No label yet.
    pub(crate) const EMPTY: Label = Label(heapless::String::new());

    /// The label of session `id` reached `via` a transport. Written
    /// without `core::fmt`, which a firmware would link for it.
    pub(crate) fn new(via: Via<'_>, id: SessionId) -> Label {
        let mut label = Label(heapless::String::new());
        let session = Digits::of(i64::from(id.0));
        let parts: [&str; 4] = match via {
            Via::WebSocket(addr) => ["ws ", addr, " #", session.as_str()],
            Via::Uplink(client) => ["mqtt ", client, "", ""],
            Via::Local => ["local #", session.as_str(), "", ""],
        };
        for part in parts {
            // Cut at a character boundary: a label never holds half a
            // character, and the longest valid one fits.
            let room = MAX_LABEL_LEN - label.0.len();
            let _ = label.0.push_str(crate::error::cut_at_char_boundary(part, room));
        }
        label
    }

    /// The label's text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

/// How a session reaches the vehicle, for its [`Label`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Via<'a> {
    /// A WebSocket connection from this address and port, as the adapter
    /// writes it (`192.0.2.7:51234`, `[2001:db8::1]:40000`): an adapter
    /// that only ever sees IPv4 never links IPv6's formatting.
    WebSocket(&'a str),
    /// A client id through the uplink's broker.
    Uplink(&'a str),
    /// In-process (tests, the daemon's own reports).
    Local,
}

/// What the vehicle does on its own in a failsafe.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Action {
    /// Returns home.
    Rtl,
    /// Lands where it is.
    Land,
    /// Holds where it is (a pilot on the RC, an autopilot's hold).
    Hold,
    /// Nothing lluav can name.
    None,
}

impl Action {
    /// The name events and `state` use.
    pub fn name(self) -> &'static str {
        match self {
            Action::Rtl => "rtl",
            Action::Land => "land",
            Action::Hold => "hold",
            Action::None => "none",
        }
    }
}

/// A failsafe as the backend reports it: the vehicle acts on its own for
/// safety (the simulator's low or empty battery, an autopilot's own return
/// or landing, a pilot on the RC).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Failsafe {
    /// What started it: `battery_low`, `battery_empty`, `autopilot`,
    /// `external`.
    pub source: &'static str,
    /// What it is, when the source needs saying: the autopilot's mode or
    /// status (`RTL`, `CRITICAL`); empty otherwise.
    pub detail: &'static str,
    /// What the vehicle does.
    pub action: Action,
    /// Whether the session in control overrode it (`control_take
    /// failsafe`): it no longer refuses anything, and `state` still names
    /// it.
    pub overridden: bool,
}

impl Failsafe {
    /// A failsafe from `source` (with no detail) doing `action`.
    pub const fn new(source: &'static str, action: Action) -> Failsafe {
        Failsafe {
            source,
            detail: "",
            action,
            overridden: false,
        }
    }

    /// Whether the vehicle is coming down: only `land`, `tether_land` and
    /// `disarm` may then run (an RTL would climb).
    pub fn landing(&self) -> bool {
        self.action == Action::Land
    }

    /// The reason as `state` and refusals name it: `battery_low`,
    /// `autopilot: RTL`.
    pub fn reason(&self) -> Reason<'_> {
        Reason(self)
    }

    /// The reason in parts, to write without `core::fmt`.
    pub fn reason_parts(&self) -> [&'static str; 3] {
        let sep = if self.detail.is_empty() { "" } else { ": " };
        [self.source, sep, self.detail]
    }

    /// Whether it still refuses motion commands.
    pub fn holds(&self) -> bool {
        !self.overridden
    }
}

/// A failsafe's reason, written as DESIGN.md names it.
#[derive(Clone, Copy, Debug)]
pub struct Reason<'a>(&'a Failsafe);

impl core::fmt::Display for Reason<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.0.source)?;
        if !self.0.detail.is_empty() {
            f.write_str(": ")?;
            f.write_str(self.0.detail)?;
        }
        Ok(())
    }
}

/// The session in control of the flight.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pilot {
    session: SessionId,
    admin: bool,
    label: Label,
    since_ms: i64,
    last_ms: i64,
}

impl Pilot {
    /// Its session.
    pub fn session(&self) -> SessionId {
        self.session
    }

    /// Who it is.
    pub fn label(&self) -> &str {
        self.label.as_str()
    }

    /// Since when it holds control, ms since the Unix epoch.
    pub fn since_ms(&self) -> i64 {
        self.since_ms
    }

    /// When its session's last request arrived, ms since the Unix epoch
    /// (control lapses `control_timeout` after it).
    pub fn last_ms(&self) -> i64 {
        self.last_ms
    }

    /// Whether its control lapsed by `now_ms`: no request for `timeout_ms`.
    fn lapsed(&self, now_ms: i64, timeout_ms: u32) -> bool {
        now_ms.saturating_sub(self.last_ms) >= i64::from(timeout_ms)
    }

    /// Whether it took control as an admin (in lock mode it then keeps it
    /// against everyone but another admin).
    pub fn admin(&self) -> bool {
        self.admin
    }

    /// Writes `{"by": label, "since": ms}`, plus `"you"` when `you` is
    /// given (the `control` command's answer).
    pub fn write(&self, o: &mut Fields<'_>, you: Option<bool>) {
        o.str("by", self.label()).i64("since", self.since_ms);
        if let Some(you) = you {
            o.bool("you", you);
        }
    }
}

/// Which session a backend is serving, unique among the open sessions of a
/// [`crate::Server`] (handed out by [`crate::Server::open`]; 0 for sessions
/// made with [`crate::Session::new`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SessionId(pub u32);

/// Who flies, vehicle-wide.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Control {
    pilot: Option<Pilot>,
}

impl Control {
    /// The session in control, if any.
    pub fn pilot(&self) -> Option<&Pilot> {
        self.pilot.as_ref()
    }

    /// Ends control held without a request for `timeout_ms` at `now_ms`;
    /// returns the pilot that lapsed.
    pub(crate) fn expire(&mut self, now_ms: i64, timeout_ms: u32) -> Option<Pilot> {
        let silent = self.pilot.as_ref().is_some_and(|p| p.lapsed(now_ms, timeout_ms));
        if silent { self.pilot.take() } else { None }
    }

    /// A request from `session` at `now_ms`: control held without a request
    /// for `timeout_ms` ends first (the lapse may be this session's own);
    /// otherwise the request keeps its session's control alive. One pass,
    /// as it runs before every request.
    #[inline]
    pub(crate) fn heard(&mut self, session: SessionId, now_ms: i64, timeout_ms: u32) {
        match &mut self.pilot {
            Some(p) if p.lapsed(now_ms, timeout_ms) => self.pilot = None,
            Some(p) if p.session == session => p.last_ms = p.last_ms.max(now_ms),
            _ => {}
        }
    }

    /// Whether `session` holds control.
    pub fn held_by(&self, session: SessionId) -> bool {
        self.pilot.as_ref().is_some_and(|p| p.session == session)
    }

    /// Gives control to session `id` (an admin or not, named `label`; no
    /// change when it holds it already); returns the pilot it replaced, if
    /// any.
    pub(crate) fn give(&mut self, id: SessionId, admin: bool, label: &Label, now_ms: i64) -> Option<Pilot> {
        if let Some(p) = self.pilot.as_mut().filter(|p| p.session == id) {
            p.last_ms = p.last_ms.max(now_ms);
            return None;
        }
        self.pilot.replace(Pilot {
            session: id,
            admin,
            label: label.clone(),
            since_ms: now_ms,
            last_ms: now_ms,
        })
    }

    /// Releases control if `session` holds it; returns whether it did.
    pub(crate) fn release(&mut self, session: SessionId) -> Option<Pilot> {
        if self.held_by(session) {
            self.pilot.take()
        } else {
            None
        }
    }
}
