// The event log's reading and its stream (DESIGN.md, "Events").
//
// lluavd pushes what happens (the FSM, arming, mission progress, failsafes,
// who flies, the battery, the links, the log's warnings) on a WebSocket of
// its own, `/events` beside the command socket. Each event is one JSON
// object, `{"event": name, "seq": N, "boot": id, "ts": ms, ...}`; `seq`
// counts from 1 per run of the daemon (`boot`), so a missed event or a
// restart shows. A subscriber that fell behind gets `{"event": "gap",
// "missed": N, "ts": ms}` instead of what it missed.
//
// Nothing here touches the page: `describe` and `Feed` turn events into
// the lines the log shows, `EventStream` keeps the socket open; panels.js
// draws the lines. Node's test runner exercises all of it
// (tests/console/js/events.test.mjs).

/** Lines the event log keeps: the page must not grow for as long as it is open. */
export const EVENT_LOG_MAX = 200;

/** Waits before reopening a lost stream, growing with each failure in a row. */
export const RETRY_MS = [500, 1000, 2000, 4000, 8000];

/**
 * The `/events` URL beside the command socket at `url`: same scheme, host
 * and port, `/events` after its path, no query (as the Python client's
 * `events_url`: `ws://h:53001/` gives `ws://h:53001/events`).
 */
export function eventsUrl(url) {
  const u = new URL(url);
  u.pathname = `${u.pathname.replace(/\/+$/, '')}/events`;
  u.search = '';
  u.hash = '';
  return u.href;
}

/** What a failsafe's `action` does, in words. */
const ACTION_WORDS = {
  rtl: 'returning home',
  land: 'landing',
  hold: 'holding position',
  none: 'no action',
};

function str(value) {
  return typeof value === 'string' ? value : null;
}

function num(value) {
  return typeof value === 'number' && Number.isFinite(value) ? value : null;
}

/** A control label, with "this console" when `isYou` knows it is. */
function who(label, isYou) {
  return isYou(label) === true ? `this console (${label})` : label;
}

/** A mission's name in a line: `mission 1001`. */
function missionName(e) {
  const id = num(e.ext_id);
  return id === null ? 'mission' : `mission ${id}`;
}

/** The fields of an event this page does not know, as `k=v` pairs. */
function fieldsOf(e) {
  return Object.entries(e)
    .filter(([k]) => !['event', 'seq', 'boot', 'ts'].includes(k))
    .map(([k, v]) => `${k}=${JSON.stringify(v)}`)
    .join(' ');
}

/**
 * One event in words: `{text, tone}` (tone as CSS colours it: good, warn,
 * danger or neutral). `isYou(label)` says whether a control label is this
 * console's own session (true, false, or null when not known); names this
 * page does not know yet are shown with their fields rather than dropped.
 */
export function describe(e, isYou = () => null) {
  switch (e.event) {
    case 'fsm':
      return { text: `${str(e.from) ?? '?'} → ${str(e.to) ?? '?'}`, tone: 'neutral' };
    case 'armed':
      return e.armed === true
        ? { text: 'motors armed', tone: 'warn' }
        : { text: 'motors disarmed', tone: 'neutral' };
    case 'mission':
      return mission(e);
    case 'failsafe': {
      const reason = str(e.reason);
      if (reason === null) return { text: 'failsafe ended', tone: 'good' };
      if (e.overridden === true) return { text: `${reason} overridden by the pilot`, tone: 'warn' };
      const action = ACTION_WORDS[e.action] ?? str(e.action) ?? 'no action';
      return { text: `${reason}: ${action}`, tone: 'danger' };
    }
    case 'control': {
      const by = str(e.by);
      const from = str(e.from);
      if (by !== null && from !== null) return { text: `taken by ${who(by, isYou)} from ${who(from, isYou)}`, tone: 'warn' };
      if (by !== null) return { text: `taken by ${who(by, isYou)}`, tone: 'neutral' };
      // `by` is null both when the pilot released control and when it lapsed.
      if (from !== null) return { text: `free (${who(from, isYou)} no longer in control)`, tone: 'neutral' };
      return { text: 'free', tone: 'neutral' };
    }
    case 'battery': {
      const percent = num(e.percent);
      if (percent === null) return { text: 'battery level unknown', tone: 'warn' };
      return { text: `battery at ${percent} %`, tone: percent <= 0 ? 'danger' : 'warn' };
    }
    case 'link':
      return e.state === 'up'
        ? { text: 'autopilot link up', tone: 'good' }
        : { text: `autopilot link ${str(e.state) ?? 'unknown'}`, tone: 'danger' };
    case 'uplink':
      return e.state === 'up'
        ? { text: 'uplink (broker) up', tone: 'good' }
        : { text: `uplink (broker) ${str(e.state) ?? 'unknown'}`, tone: 'warn' };
    case 'log': {
      const level = str(e.level) ?? 'log';
      return { text: `${level}: ${str(e.msg) ?? ''}`, tone: level === 'error' ? 'danger' : 'warn' };
    }
    case 'gap':
      return { text: missed(num(e.missed), 'dropped: this console fell behind'), tone: 'warn' };
    default:
      return { text: fieldsOf(e), tone: 'neutral' };
  }
}

function mission(e) {
  const name = missionName(e);
  switch (e.status) {
    case 'started':
      return { text: `${name} started`, tone: 'neutral' };
    case 'reached': {
      const [index, count, wp] = [num(e.index), num(e.count), num(e.wp)];
      const which = index !== null && count !== null ? `${index} of ${count}` : '?';
      const id = wp === null ? '' : ` (id ${wp}, ${name})`;
      return { text: `reached waypoint ${which}${id}`, tone: 'good' };
    }
    case 'completed':
      return { text: `${name} completed`, tone: 'good' };
    case 'aborted':
      return { text: `${name} aborted`, tone: 'warn' };
    default:
      return { text: `${name} ${str(e.status) ?? '?'}`, tone: 'neutral' };
  }
}

/** `N events <what>`, with the right plural; unknown counts say "some". */
function missed(n, what) {
  if (n === null) return `some events ${what}`;
  return `${n} event${n === 1 ? '' : 's'} ${what}`;
}

/**
 * The log's lines from the events as they arrive: one line per event, and
 * a marker line before it when events were missed (a `gap`, or `seq`
 * skipping, as it does across a reconnect) or the daemon restarted (a new
 * `boot`: `seq` starts again). Lines: `{kind: 'event' | 'marker', name,
 * text, tone, ts, seq, event}` (`event`: the object, to describe it again
 * once `isYou` knows more); markers have `name` `gap`, `skip` or `restart`
 * (or `unreadable` for a message that is not an event object).
 *
 * It keeps the last `max` lines, oldest first, in `lines`.
 */
export class Feed {
  constructor(max = EVENT_LOG_MAX, isYou = () => null) {
    this.max = max;
    this.isYou = isYou;
    /** The lines kept, oldest first. */
    this.lines = [];
    /** The last event's run and number (null before the first). */
    this.boot = null;
    this.seq = null;
    /** Events a `gap` said were dropped and the next `seq` will skip. */
    this.announced = 0;
  }

  /** Takes one event object; returns the lines it adds, in order. */
  accept(e) {
    if (e === null || typeof e !== 'object' || typeof e.event !== 'string') {
      return this.#add([this.#marker('unreadable', 'a message that is not an event', 'warn', null, null)]);
    }
    const ts = num(e.ts);
    if (e.event === 'gap') {
      // Said once, here; the skip in `seq` that follows is this gap.
      this.announced += num(e.missed) ?? 0;
      const { text, tone } = describe(e, this.isYou);
      return this.#add([this.#marker('gap', text, tone, ts, null)]);
    }
    const out = [];
    const seq = num(e.seq);
    const boot = str(e.boot);
    if (boot !== null && this.boot !== null && boot !== this.boot) {
      const before = seq !== null && seq > 1 ? `; ${missed(seq - 1, 'of the new run before this one not seen')}` : '';
      out.push(this.#marker('restart', `lluavd restarted (a new run: seq starts again)${before}`, 'warn', ts, seq));
    } else if (seq !== null && this.seq !== null && boot === this.boot) {
      const skipped = seq - this.seq - 1 - this.announced;
      if (skipped > 0) {
        out.push(this.#marker('skip', `${missed(skipped, 'missed')} (seq ${this.seq} → ${seq})`, 'warn', ts, seq));
      }
    }
    if (seq !== null) {
      this.seq = seq;
      this.boot = boot;
      this.announced = 0;
    }
    const { text, tone } = describe(e, this.isYou);
    out.push({ kind: 'event', name: e.event, text, tone, ts, seq, event: e });
    return this.#add(out);
  }

  /** Forgets the lines (the person cleared the log); what was seen still counts. */
  clear() {
    this.lines = [];
  }

  #marker(name, text, tone, ts, seq) {
    return { kind: 'marker', name, text, tone, ts, seq, event: null };
  }

  #add(out) {
    this.lines.push(...out);
    if (this.lines.length > this.max) this.lines.splice(0, this.lines.length - this.max);
    return out;
  }
}

/**
 * The `/events` stream: opens it, logs in with the password the command
 * socket logged in with (none when the vehicle has none: then any message
 * would close it), and reopens it with a growing wait whenever it closes,
 * until `stop`. Events: `status` with `detail: {status, detail}`, where
 * status is `connecting`, `connected`, `disconnected` (detail: why, and
 * when it tries again), `refused` (the login was refused: no retry, since
 * each wrong password counts) or `off`; `event` with `detail:` the event
 * object.
 *
 * `timers` replaces setTimeout/clearTimeout (tests run the waits at once).
 */
export class EventStream extends EventTarget {
  #ws = null;
  #timer = null;
  #loggingIn = false;
  #failures = 0;

  constructor(url, timers = { set: (f, ms) => setTimeout(f, ms), clear: (t) => clearTimeout(t) }) {
    super();
    this.url = url;
    this.timers = timers;
    /** The password it logs in with (null: none), or undefined while stopped. */
    this.password = undefined;
    this.status = 'off';
  }

  /** Whether it is running with this password (opening, open or waiting to reopen). */
  runningWith(password) {
    return this.password === password && this.status !== 'off' && this.status !== 'refused';
  }

  /** Starts the stream, logging in with `password` (null: no login); a no-op when already running with it. */
  start(password) {
    if (this.runningWith(password)) return;
    this.stop();
    this.password = password;
    this.#failures = 0;
    this.#open();
  }

  /** Closes the stream and stops reopening it. */
  stop() {
    this.password = undefined;
    if (this.#timer !== null) this.timers.clear(this.#timer);
    this.#timer = null;
    const ws = this.#ws;
    this.#ws = null;
    ws?.close(1000, 'bye');
    this.#status('off');
  }

  #status(status, detail = '') {
    this.status = status;
    this.dispatchEvent(new CustomEvent('status', { detail: { status, detail } }));
  }

  #open() {
    this.#timer = null;
    this.#status('connecting');
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (e) {
      // A bad URL, or one the page's Content-Security-Policy forbids.
      this.#lost(null, 1006, e.message);
      return;
    }
    this.#ws = ws;
    this.#loggingIn = false;
    let ended = false;
    const end = (code, reason) => {
      if (ended) return;
      ended = true;
      this.#lost(ws, code, reason);
    };
    ws.addEventListener('open', () => {
      if (this.#ws !== ws) return;
      if (this.password === null) {
        this.#admitted();
      } else {
        this.#loggingIn = true;
        ws.send(`login ${this.password}`);
      }
    });
    ws.addEventListener('message', (ev) => this.#message(ws, ev.data));
    ws.addEventListener('close', (ev) => end(ev.code, ev.reason || `code ${ev.code}`));
    // A connection that fails before it opens may end with an error and
    // no close event (Chromium): it is closed all the same.
    ws.addEventListener('error', () => setTimeout(() => {
      if (ws.readyState === WebSocket.CLOSED) end(1006, 'no connection');
    }, 0));
  }

  #admitted() {
    this.#failures = 0;
    this.#status('connected');
  }

  #message(ws, data) {
    if (this.#ws !== ws) return;
    let value;
    try {
      value = JSON.parse(data);
    } catch {
      value = null;
    }
    if (this.#loggingIn) {
      // The first message after a login is its answer, as on the command socket.
      this.#loggingIn = false;
      if (value?.ret === 0) {
        this.#admitted();
        return;
      }
      const msg = typeof value?.msg === 'string' && value.msg ? value.msg : 'no answer to the login';
      this.#ws = null;
      this.password = undefined;
      ws.close(1000, 'bye');
      this.#status('refused', msg);
      return;
    }
    this.dispatchEvent(new CustomEvent('event', { detail: value }));
  }

  #lost(ws, code, reason) {
    if (ws !== null && this.#ws !== ws) return; // stopped, or replaced
    this.#ws = null;
    if (this.password === undefined) return;
    const wait = RETRY_MS[Math.min(this.#failures, RETRY_MS.length - 1)];
    this.#failures += 1;
    this.#status('disconnected', `${code} ${reason}; retry in ${(wait / 1000).toFixed(1)} s`);
    this.#timer = this.timers.set(() => this.#open(), wait);
  }
}
