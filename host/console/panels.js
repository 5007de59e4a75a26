// The panels around the plot: connection header, vehicle state, login,
// confirmation dialog, command line and the log. They only show things and
// report what the person does; main.js decides what to send.

import { describe } from './events.js';
import { commandName, retWords } from './protocol.js';
import { altitudeOf } from './vehicle.js';

/** The element with this id (the page has every one these panels use). */
export function byId(id) {
  const node = document.getElementById(id);
  if (!node) throw new Error(`the page has no #${id}`);
  return node;
}

/** Good, warning, danger or neutral, as CSS colours it (`data-tone`). */
function tone(node, value) {
  node.dataset.tone = value;
}

function fixed(value, digits = 1) {
  if (value === null || value === undefined) return '—';
  const text = value.toFixed(digits);
  // -0.004 shows as 0.00, not -0.00.
  return Number(text) === 0 ? text.replace('-', '') : text;
}

/** A time in ms since the epoch as the local clock shows it, `14:03:07`. */
function clock(ms) {
  return new Date(ms).toTimeString().slice(0, 8);
}

function degrees(radians) {
  return radians === null ? '—' : `${Math.round((((radians * 180) / Math.PI) % 360 + 360) % 360)}°`;
}

/** What a request line looks like in the log: passwords are not shown. */
export function shown(text) {
  const name = commandName(text);
  return name === 'login' || name === 'passwd' ? `${name} ••••` : text;
}

/** The header: connection, role and the age of the last state answer. */
export class Header {
  constructor() {
    this.conn = byId('conn');
    this.role = byId('role');
    this.age = byId('age');
    this.endpoint = byId('endpoint');
    this.logout = byId('logout');
  }

  /** `connecting`, `connected` or `disconnected`, with an optional detail. */
  connection(status, detail = '') {
    this.conn.textContent = detail ? `${status} · ${detail}` : status;
    this.conn.dataset.status = status;
    tone(this.conn, { connected: 'good', connecting: 'warn' }[status] ?? 'danger');
  }

  /** `open` (no password), `user`, `admin`, or null before anyone knows. */
  showRole(role) {
    this.role.textContent = role === null ? 'role —' : role === 'open' ? 'no password' : role;
    this.role.dataset.role = role ?? '';
    tone(this.role, role === 'admin' ? 'warn' : 'neutral');
    this.logout.hidden = role !== 'user' && role !== 'admin';
  }

  /** Age of the last state answer, and how long a state request has waited. */
  showAge(sinceAnswerMs, waitingMs) {
    if (sinceAnswerMs === null) {
      this.age.textContent = 'no state yet';
      tone(this.age, 'neutral');
      return;
    }
    const worst = Math.max(sinceAnswerMs, waitingMs ?? 0);
    this.age.textContent = `state ${(sinceAnswerMs / 1000).toFixed(1)} s ago`;
    tone(this.age, worst < 1000 ? 'good' : worst < 3000 ? 'warn' : 'danger');
  }
}

const FSM_TONES = {
  disarmed: 'neutral', armed: 'warn', takeoff: 'warn', landing: 'warn', rtl: 'warn',
  hover: 'good', mission: 'good', sleep: 'neutral',
};

/** Vehicle state as badges and numbers. */
export class StatePanel {
  constructor() {
    for (const id of ['fsm', 'armed', 'lock', 'airborne', 'link', 'battery', 'battery-bar', 'pos-n',
      'pos-e', 'alt', 'vel-n', 'vel-e', 'vel-u', 'speed', 'yaw', 'sp-n', 'sp-e', 'sp-alt', 'wp-left',
      'state-error', 'failsafe', 'failsafe-reason', 'failsafe-help', 'control', 'control-since', 'take-control',
      'release-control']) {
      this[id.replace(/-(\w)/g, (_, c) => c.toUpperCase())] = byId(id);
    }
  }

  /** Shows a state read by `readState`. */
  show(s) {
    this.fsm.textContent = s.fsm ?? 'unknown';
    tone(this.fsm, FSM_TONES[s.fsm] ?? 'neutral');
    this.#flag(this.armed, s.armed, 'armed', 'disarmed', 'warn');
    this.#flag(this.lock, s.lockMode, 'lock mode', 'unlocked', 'warn');
    this.#flag(this.airborne, s.airborne, 'airborne', 'on ground', 'good');
    this.link.hidden = s.link === null;
    if (s.link !== null) {
      const age = s.linkAgeMs === null ? '' : ` · ${(s.linkAgeMs / 1000).toFixed(1)} s`;
      this.link.textContent = `link ${s.link}${age}`;
      tone(this.link, s.link === 'up' ? 'good' : 'danger');
    }
    this.#battery(s.battery);
    this.posN.textContent = fixed(s.position?.n, 2);
    this.posE.textContent = fixed(s.position?.e, 2);
    this.alt.textContent = fixed(s.altitude ?? altitudeOf(s.position), 2);
    const v = s.velocity;
    this.velN.textContent = fixed(v?.n, 2);
    this.velE.textContent = fixed(v?.e, 2);
    this.velU.textContent = fixed(altitudeOf(v), 2);
    this.speed.textContent = v ? Math.hypot(v.n, v.e).toFixed(2) : '—';
    this.yaw.textContent = degrees(s.yaw);
    this.spN.textContent = fixed(s.setpoint?.n, 2);
    this.spE.textContent = fixed(s.setpoint?.e, 2);
    this.spAlt.textContent = fixed(altitudeOf(s.setpoint), 2);
    this.wpLeft.textContent = s.waypointsLeft === null ? '—' : String(s.waypointsLeft);
  }

  /**
   * Who flies and the failsafe: `failsafe` and `control` as vehicle.js
   * reads them, `you` whether the pilot is this console (null: not known
   * yet, or no pilot).
   */
  showAuthority({ failsafe, control, you }) {
    this.failsafe.hidden = failsafe === null;
    if (failsafe !== null) {
      const overridden = failsafe.overridden ? 'true' : 'false';
      // Rewritten only when it changes: it is an alert, read out when it does.
      if (this.failsafeReason.textContent !== failsafe.reason || this.failsafe.dataset.overridden !== overridden) {
        this.failsafeReason.textContent = failsafe.reason;
        this.failsafe.dataset.overridden = overridden;
        this.failsafeHelp.textContent = failsafe.overridden
          ? 'Overridden by the pilot: motion commands steer again. A new failsafe still wins.'
          : 'The vehicle acts on its own for safety and refuses motion commands. Land and Disarm still run; '
            + 'Take control overrides it.';
      }
      tone(this.failsafe, failsafe.overridden ? 'warn' : 'danger');
    }
    const holds = failsafe !== null && !failsafe.overridden;
    this.control.dataset.you = you === null ? '' : String(you);
    if (control === null) {
      this.control.textContent = 'free';
      this.control.title = 'No one is in control: the first motion command takes it.';
      this.controlSince.textContent = '';
      tone(this.control, 'neutral');
    } else {
      this.control.textContent = you ? 'this console' : control.by;
      this.control.title = you ? `This console (${control.by}) flies the vehicle.` : `${control.by} flies the vehicle.`;
      this.controlSince.textContent = `since ${clock(control.since)}`;
      tone(this.control, you ? 'good' : you === false ? 'warn' : 'neutral');
    }
    // Taking control is for when someone else (or no one) has it, and for
    // overriding a failsafe, which even the pilot must do.
    this.takeControl.hidden = you === true && !holds;
    this.takeControl.classList.toggle('danger', holds);
    this.takeControl.title = holds
      ? 'Override the failsafe and take control (control_take failsafe; asks first)'
      : 'Take control of the flight (control_take)';
    this.releaseControl.hidden = you !== true;
  }

  /** A `state` request that failed: shown until the next good one. */
  showError(text) {
    this.stateError.hidden = !text;
    this.stateError.textContent = text;
  }

  #flag(node, value, yes, no, onTone) {
    node.textContent = value === null ? `${yes}?` : value ? yes : no;
    tone(node, value ? onTone : 'neutral');
  }

  #battery(percent) {
    this.battery.textContent = percent === null ? '—' : `${percent.toFixed(0)} %`;
    this.batteryBar.value = percent ?? 0;
    tone(this.battery, percent === null ? 'neutral' : percent < 20 ? 'danger' : percent < 40 ? 'warn' : 'good');
  }
}

/** The login form, shown over the page while the session must log in. */
export class Login extends EventTarget {
  constructor() {
    super();
    this.root = byId('login');
    this.form = byId('login-form');
    this.input = byId('password');
    this.error = byId('login-error');
    this.main = byId('main');
    this.form.addEventListener('submit', (ev) => {
      ev.preventDefault();
      const password = this.input.value;
      if (password === '') return;
      this.dispatchEvent(new CustomEvent('login', { detail: password }));
    });
  }

  /** Whether it is showing. */
  get shown() {
    return !this.root.hidden;
  }

  /** Shows the form, with `message` as the reason (or none). */
  show(message = '') {
    this.error.textContent = message;
    this.root.hidden = false;
    this.main.inert = true;
    this.input.select();
    this.input.focus();
  }

  /** Hides the form and forgets what was typed. */
  hide() {
    this.root.hidden = true;
    this.main.inert = false;
    this.input.value = '';
    this.error.textContent = '';
  }
}

/** A modal yes/no question (a `<dialog>`: Esc and Cancel say no). */
export class Confirm {
  constructor() {
    this.dialog = byId('confirm');
    this.title = byId('confirm-title');
    this.text = byId('confirm-text');
    this.command = byId('confirm-command');
    this.ok = byId('confirm-ok');
    byId('confirm-cancel').addEventListener('click', () => this.dialog.close('cancel'));
    this.ok.addEventListener('click', () => this.dialog.close('ok'));
  }

  /** Asks; resolves true only when the person presses the OK button. */
  ask({ title, text, command, ok, danger = false }) {
    if (this.dialog.open) this.dialog.close('cancel');
    this.title.textContent = title;
    this.text.textContent = text;
    this.command.textContent = command;
    this.ok.textContent = ok;
    this.ok.classList.toggle('danger', danger);
    this.dialog.returnValue = '';
    return new Promise((resolve) => {
      this.dialog.addEventListener('close', () => resolve(this.dialog.returnValue === 'ok'), { once: true });
      this.dialog.showModal();
      (danger ? byId('confirm-cancel') : this.ok).focus();
    });
  }
}

/** History kept across visits; lines with passwords are never stored. */
const HISTORY_KEY = 'lluav.console.history';
const HISTORY_MAX = 200;

/**
 * The command line: Tab completes command names (from `help`), Up/Down walk
 * the history, Enter sends (`send` event, `detail: line`).
 */
export class CommandLine extends EventTarget {
  constructor() {
    super();
    this.form = byId('command-form');
    this.input = byId('command');
    this.hint = byId('command-hint');
    this.commands = [];
    this.history = this.#loadHistory();
    this.cursor = this.history.length;
    this.form.addEventListener('submit', (ev) => {
      ev.preventDefault();
      const line = this.input.value.trim();
      if (line === '') return;
      this.#remember(line);
      this.input.value = '';
      this.#showHint();
      this.dispatchEvent(new CustomEvent('send', { detail: line }));
    });
    this.input.addEventListener('keydown', (ev) => this.#key(ev));
    this.input.addEventListener('input', () => this.#showHint());
  }

  /** The names completion offers. */
  setCommands(names) {
    this.commands = [...names].sort();
    this.#showHint();
  }

  /** Names that complete the word being typed (none once a space is typed). */
  candidates() {
    const text = this.input.value;
    if (text === '' || /\s/.test(text)) return [];
    return this.commands.filter((c) => c.startsWith(text));
  }

  #key(ev) {
    if (ev.key === 'Tab' && !ev.shiftKey) {
      const found = this.candidates();
      // Tab leaves the field as usual unless there is something to complete.
      if (found.length === 0 || (found.length === 1 && found[0] === this.input.value)) return;
      ev.preventDefault();
      this.input.value = found.length === 1 ? `${found[0]} ` : commonPrefix(found);
      this.#showHint();
    } else if (ev.key === 'ArrowUp' || ev.key === 'ArrowDown') {
      ev.preventDefault();
      const step = ev.key === 'ArrowUp' ? -1 : 1;
      this.cursor = Math.min(this.history.length, Math.max(0, this.cursor + step));
      this.input.value = this.history[this.cursor] ?? '';
      this.#showHint();
    } else if (ev.key === 'Escape') {
      this.input.value = '';
      this.#showHint();
    }
  }

  #showHint() {
    const found = this.candidates();
    if (found.length === 0 || (found.length === 1 && found[0] === this.input.value)) {
      this.hint.textContent = this.commands.length
        ? 'Tab completes · ↑↓ history · help lists every command'
        : '';
      return;
    }
    const more = found.length > 12 ? ` … ${found.length - 12} more` : '';
    this.hint.textContent = found.slice(0, 12).join('  ') + more;
  }

  #remember(line) {
    const name = commandName(line);
    this.cursor = this.history.length;
    if (name === 'login' || name === 'passwd') return;
    if (this.history.at(-1) !== line) this.history.push(line);
    if (this.history.length > HISTORY_MAX) this.history.splice(0, this.history.length - HISTORY_MAX);
    this.cursor = this.history.length;
    try {
      localStorage.setItem(HISTORY_KEY, JSON.stringify(this.history));
    } catch {
      // Storage may be off (private windows); history then lasts the visit.
    }
  }

  #loadHistory() {
    try {
      const list = JSON.parse(localStorage.getItem(HISTORY_KEY) ?? '[]');
      return Array.isArray(list) ? list.filter((l) => typeof l === 'string').slice(-HISTORY_MAX) : [];
    } catch {
      return [];
    }
  }
}

function commonPrefix(words) {
  let prefix = words[0];
  for (const w of words) {
    while (!w.startsWith(prefix)) prefix = prefix.slice(0, -1);
  }
  return prefix;
}

const LOG_MAX = 300;
/** Answers longer than this are folded under their first part. */
const FOLD_AT = 160;

/** The log of requests and answers, newest first. */
export class Log {
  constructor() {
    this.list = byId('log');
    this.last = byId('last-result');
    byId('log-clear').addEventListener('click', () => this.list.replaceChildren());
  }

  /** Logs an exchange and shows it as the last result. */
  exchange(ex) {
    const tone = ex.ok ? 'good' : ex.ret === -2 ? 'warn' : 'danger';
    const item = this.#entry(shown(ex.request), tone, `${ex.ret} ${retWords(ex.ret)}`, ex.ms);
    item.dataset.ret = String(ex.ret);
    if (ex.msg) {
      const msg = document.createElement('div');
      msg.className = 'msg';
      msg.textContent = ex.msg;
      item.append(msg);
    }
    item.append(json(ex.answer));
    this.#showLast(ex.ok ? `${shown(ex.request)}: ok` : `${shown(ex.request)}: ${retWords(ex.ret)} (${ex.ret})${ex.msg ? ` — ${ex.msg}` : ''}`, tone, ex.ret);
  }

  /** Logs a request that got no answer (connection lost, bad JSON). */
  failure(request, error) {
    const item = this.#entry(shown(request), 'danger', 'no answer', null);
    const msg = document.createElement('div');
    msg.className = 'msg';
    msg.textContent = error.message;
    item.append(msg);
    this.#showLast(`${shown(request)}: no answer — ${error.message}`, 'danger', null);
  }

  /** Logs a note of the page's own (connection changes). */
  note(text, noteTone = 'neutral') {
    const item = document.createElement('li');
    item.className = 'entry note';
    item.dataset.tone = noteTone;
    item.append(stamp(), document.createTextNode(` ${text}`));
    this.#insert(item);
  }

  #entry(request, entryTone, status, ms) {
    const item = document.createElement('li');
    item.className = 'entry';
    item.dataset.tone = entryTone;
    const head = document.createElement('div');
    head.className = 'head';
    const req = document.createElement('code');
    req.className = 'request';
    req.textContent = request;
    const ret = document.createElement('span');
    ret.className = 'ret';
    ret.textContent = status;
    head.append(stamp(), req, ret);
    if (ms !== null) {
      const took = document.createElement('span');
      took.className = 'ms';
      took.textContent = `${ms.toFixed(0)} ms`;
      head.append(took);
    }
    item.append(head);
    this.#insert(item);
    return item;
  }

  #insert(item) {
    this.list.prepend(item);
    while (this.list.children.length > LOG_MAX) this.list.lastElementChild.remove();
  }

  #showLast(text, lastTone, ret) {
    this.last.textContent = text;
    this.last.dataset.tone = lastTone;
    this.last.dataset.ret = ret === null ? '' : String(ret);
  }
}

function stamp() {
  const t = document.createElement('time');
  const now = new Date();
  t.dateTime = now.toISOString();
  t.textContent = now.toTimeString().slice(0, 8);
  return t;
}

function json(answer) {
  const compact = JSON.stringify(answer);
  const pre = document.createElement('pre');
  pre.className = 'json';
  if (compact.length <= FOLD_AT) {
    pre.textContent = compact;
    return pre;
  }
  const details = document.createElement('details');
  const summary = document.createElement('summary');
  summary.textContent = `${compact.slice(0, FOLD_AT)}…`;
  pre.textContent = JSON.stringify(answer, null, 2);
  details.append(summary, pre);
  return details;
}

/**
 * The event log: the lines of events.js's `Feed`, newest first, as many
 * as it keeps; and the stream's state in its badge.
 */
export class EventLog {
  /**
   * The line each item shows, and what is known of its control labels
   * (label → whether it is this console): kept per line, because the page
   * forgets its verdicts with each new command connection (a new session,
   * a new label), and a line once known to be about this console stays so.
   */
  #lines = new WeakMap();

  constructor(feed) {
    this.feed = feed;
    this.list = byId('events');
    this.conn = byId('events-conn');
    byId('events-clear').addEventListener('click', () => {
      this.feed.clear();
      this.list.replaceChildren();
    });
  }

  /** Shows lines the feed added, in the order they came. */
  add(lines) {
    for (const line of lines) {
      const item = document.createElement('li');
      item.className = line.kind === 'marker' ? 'event marker' : 'event';
      item.dataset.tone = line.tone;
      item.dataset.name = line.name;
      if (line.seq !== null) item.dataset.seq = String(line.seq);
      const name = document.createElement('span');
      name.className = 'name';
      name.textContent = line.kind === 'marker' ? `⚠ ${line.name}` : line.name;
      const text = document.createElement('span');
      text.className = 'text';
      text.textContent = line.text;
      item.append(eventTime(line.ts), name, text);
      this.#lines.set(item, { line, you: new Map() });
      if (line.name === 'control') this.#learn(item);
      this.list.prepend(item);
    }
    while (this.list.children.length > this.feed.max) this.list.lastElementChild.remove();
  }

  /**
   * Says the control lines again: a label seen in one may only now be
   * known as this console's own (the page learns it from `control`).
   */
  refreshControl() {
    for (const item of this.list.querySelectorAll('li[data-name="control"]')) this.#learn(item);
  }

  /** Takes what the page now knows of a control line's labels, and says the line with all it knows. */
  #learn(item) {
    const kept = this.#lines.get(item);
    if (!kept?.line.event) return;
    for (const label of [kept.line.event.by, kept.line.event.from]) {
      const verdict = typeof label === 'string' ? this.feed.isYou(label) : null;
      if (verdict !== null) kept.you.set(label, verdict);
    }
    item.querySelector('.text').textContent = describe(kept.line.event, (l) => kept.you.get(l) ?? null).text;
  }

  /** The stream's state: `connecting`, `connected`, `disconnected`, `refused` or `off`, with a detail. */
  connection(status, detail = '') {
    this.conn.textContent = detail ? `${status} · ${detail}` : status;
    this.conn.dataset.status = status;
    tone(this.conn, { connected: 'good', connecting: 'warn', off: 'neutral' }[status] ?? 'danger');
  }
}

/** When an event happened, by the vehicle's clock (its `ts`), or now when it has none. */
function eventTime(ts) {
  const t = document.createElement('time');
  const when = new Date(ts ?? Date.now());
  t.dateTime = when.toISOString();
  t.textContent = clock(when.getTime());
  return t;
}
