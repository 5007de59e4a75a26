// The event log's reading (lines, gaps, restarts) and its stream, without a
// browser: node --test. The flight's events are lluavd's own, captured from
// a real run by tests/console/test_answers.py into answers/sim-events.json.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';

/** A WebSocket the test plays the server of. */
class FakeSocket extends EventTarget {
  static CONNECTING = 0;
  static OPEN = 1;
  static CLOSED = 3;
  static all = [];
  constructor(url) {
    super();
    this.url = url;
    this.readyState = 0;
    this.sent = [];
    this.closedWith = null;
    FakeSocket.all.push(this);
  }
  send(text) { this.sent.push(text); }
  close(code = 1000, reason = '') {
    this.closedWith = code;
    this.serverClose(code, reason);
  }
  serverOpen() { this.readyState = 1; this.dispatchEvent(new Event('open')); }
  serverSend(value) {
    const e = new Event('message');
    e.data = typeof value === 'string' ? value : JSON.stringify(value);
    this.dispatchEvent(e);
  }
  serverClose(code, reason = '') {
    if (this.readyState === 3) return;
    this.readyState = 3;
    const e = new Event('close'); e.code = code; e.reason = reason;
    this.dispatchEvent(e);
  }
  static get last() { return FakeSocket.all.at(-1); }
}
globalThis.WebSocket = FakeSocket;

const { describe, eventsUrl, EventStream, Feed, EVENT_LOG_MAX, RETRY_MS } = await import('../../../host/console/events.js');

const FLIGHT = JSON.parse(readFileSync(new URL('../answers/sim-events.json', import.meta.url), 'utf8'));

const ev = (seq, event, fields = {}, boot = 'b1') => ({ event, seq, boot, ts: 1_700_000_000_000 + seq, ...fields });

test('the events URL sits beside the command socket', () => {
  assert.equal(eventsUrl('ws://127.0.0.1:53001/'), 'ws://127.0.0.1:53001/events');
  assert.equal(eventsUrl('wss://vehicle:8443'), 'wss://vehicle:8443/events');
  assert.equal(eventsUrl('wss://proxy/drone-1/?x=1'), 'wss://proxy/drone-1/events');
});

test('every event lluavd sent in a real flight reads as words, not as raw fields', () => {
  const names = new Set(FLIGHT.map((e) => e.event));
  for (const name of ['control', 'fsm', 'armed', 'mission', 'battery', 'failsafe']) {
    assert.ok(names.has(name), `the captured flight has a ${name} event`);
  }
  for (const e of FLIGHT) {
    const { text, tone } = describe(e);
    // A `log` event is lluavd's own log line, fields and all (`battery=…`):
    // shown as written. Every other event is put in words.
    const raw = e.event !== 'log' && text.includes('=');
    assert.ok(text && !raw, `${JSON.stringify(e)} reads as ${text}`);
    assert.ok(['good', 'warn', 'danger', 'neutral'].includes(tone));
  }
  // The captured flight is one run counted from 1: no marker in between.
  const feed = new Feed();
  const lines = FLIGHT.flatMap((e) => feed.accept(e));
  assert.deepEqual(lines.filter((l) => l.kind === 'marker'), []);
  const reached = lines.filter((l) => l.name === 'mission' && l.text.startsWith('reached'));
  assert.deepEqual(reached.map((l) => l.text.split(' (')[0]),
    ['reached waypoint 1 of 3', 'reached waypoint 2 of 3', 'reached waypoint 3 of 3']);
  assert.deepEqual(lines.filter((l) => l.name === 'failsafe').map((l) => [l.text, l.tone]), [
    ['battery_low: returning home', 'danger'],
    ['battery_low overridden by the pilot', 'warn'],
    ['failsafe ended', 'good'],
  ]);
});

test('each event name says what happened in words', () => {
  const cases = [
    [{ event: 'fsm', from: 'hover', to: 'mission' }, 'hover → mission', 'neutral'],
    [{ event: 'armed', armed: true }, 'motors armed', 'warn'],
    [{ event: 'armed', armed: false }, 'motors disarmed', 'neutral'],
    [{ event: 'mission', ext_id: 7, status: 'started' }, 'mission 7 started', 'neutral'],
    [{ event: 'mission', ext_id: 7, status: 'reached', wp: 12, index: 2, count: 3 }, 'reached waypoint 2 of 3 (id 12, mission 7)', 'good'],
    [{ event: 'mission', ext_id: 7, status: 'completed' }, 'mission 7 completed', 'good'],
    [{ event: 'mission', ext_id: 7, status: 'aborted' }, 'mission 7 aborted', 'warn'],
    [{ event: 'failsafe', reason: 'battery_low', action: 'rtl', overridden: false }, 'battery_low: returning home', 'danger'],
    [{ event: 'failsafe', reason: 'autopilot: LAND', action: 'land', overridden: false }, 'autopilot: LAND: landing', 'danger'],
    [{ event: 'failsafe', reason: 'battery_low', action: 'rtl', overridden: true }, 'battery_low overridden by the pilot', 'warn'],
    [{ event: 'failsafe', reason: null, action: 'none', overridden: false }, 'failsafe ended', 'good'],
    [{ event: 'control', by: 'mqtt alice', from: null }, 'taken by mqtt alice', 'neutral'],
    [{ event: 'control', by: 'mqtt bob', from: 'mqtt alice' }, 'taken by mqtt bob from mqtt alice', 'warn'],
    [{ event: 'control', by: null, from: 'mqtt alice' }, 'free (mqtt alice no longer in control)', 'neutral'],
    [{ event: 'battery', percent: 19.9 }, 'battery at 19.9 %', 'warn'],
    [{ event: 'battery', percent: 0 }, 'battery at 0 %', 'danger'],
    [{ event: 'link', state: 'lost' }, 'autopilot link lost', 'danger'],
    [{ event: 'link', state: 'up' }, 'autopilot link up', 'good'],
    [{ event: 'uplink', state: 'down' }, 'uplink (broker) down', 'warn'],
    [{ event: 'log', level: 'error', msg: 'autopilot: EKF failure' }, 'error: autopilot: EKF failure', 'danger'],
    [{ event: 'log', level: 'warning', msg: 'battery low' }, 'warning: battery low', 'warn'],
    [{ event: 'gap', missed: 12 }, '12 events dropped: this console fell behind', 'warn'],
    [{ event: 'gap', missed: 1 }, '1 event dropped: this console fell behind', 'warn'],
  ];
  for (const [e, text, tone] of cases) {
    assert.deepEqual(describe({ seq: 1, boot: 'b', ts: 0, ...e }), { text, tone }, JSON.stringify(e));
  }
});

test('a control label that is this console says so', () => {
  const isYou = (label) => (label === 'ws 127.0.0.1:5000 #3' ? true : label === 'mqtt alice' ? false : null);
  assert.equal(describe({ event: 'control', by: 'ws 127.0.0.1:5000 #3', from: 'mqtt alice' }, isYou).text,
    'taken by this console (ws 127.0.0.1:5000 #3) from mqtt alice');
});

test('an event this page does not know yet shows its fields', () => {
  assert.deepEqual(describe(ev(4, 'geofence', { zone: 'north', inside: false })),
    { text: 'zone="north" inside=false', tone: 'neutral' });
});

test('a skip in seq is marked before the event that shows it', () => {
  const feed = new Feed();
  feed.accept(ev(1, 'armed', { armed: true }));
  feed.accept(ev(2, 'fsm', { from: 'disarmed', to: 'takeoff' }));
  const lines = feed.accept(ev(6, 'fsm', { from: 'takeoff', to: 'hover' }));
  assert.deepEqual(lines.map((l) => [l.kind, l.name, l.text]), [
    ['marker', 'skip', '3 events missed (seq 2 → 6)'],
    ['event', 'fsm', 'takeoff → hover'],
  ]);
  assert.equal(lines[0].tone, 'warn');
  assert.deepEqual(feed.accept(ev(7, 'armed', { armed: false })).map((l) => l.kind), ['event']);
});

test('the first event seen is no skip: the console subscribed in the middle of a run', () => {
  const feed = new Feed();
  assert.deepEqual(feed.accept(ev(40, 'battery', { percent: 20 })).map((l) => l.kind), ['event']);
});

test('a gap is marked once, and the seq skip it announced is not marked again', () => {
  const feed = new Feed();
  feed.accept(ev(10, 'armed', { armed: true }));
  const gap = feed.accept({ event: 'gap', missed: 5, ts: 1 });
  assert.deepEqual(gap.map((l) => [l.kind, l.name, l.text, l.seq]),
    [['marker', 'gap', '5 events dropped: this console fell behind', null]]);
  assert.deepEqual(feed.accept(ev(16, 'fsm', { from: 'a', to: 'b' })).map((l) => l.kind), ['event']);
  // A gap that says less than the skip: the rest is marked as a skip.
  feed.accept({ event: 'gap', missed: 1, ts: 2 });
  assert.deepEqual(feed.accept(ev(20, 'fsm', { from: 'b', to: 'c' })).map((l) => [l.name, l.text]),
    [['skip', '2 events missed (seq 16 → 20)'], ['fsm', 'b → c']]);
});

test('a new boot is marked as a restart, not as a skip', () => {
  const feed = new Feed();
  feed.accept(ev(30, 'armed', { armed: true }));
  const lines = feed.accept(ev(1, 'fsm', { from: 'disarmed', to: 'takeoff' }, 'b2'));
  assert.deepEqual(lines.map((l) => [l.kind, l.name]), [['marker', 'restart'], ['event', 'fsm']]);
  assert.match(lines[0].text, /restarted/);
  assert.doesNotMatch(lines[0].text, /not seen/);
  // Joining the new run late says how much of it was not seen.
  const later = feed.accept(ev(4, 'armed', { armed: false }, 'b3'));
  assert.equal(later[0].name, 'restart');
  assert.match(later[0].text, /3 events of the new run before this one not seen/);
  // Then seq counts on in the new run.
  assert.deepEqual(feed.accept(ev(5, 'armed', { armed: true }, 'b3')).map((l) => l.kind), ['event']);
});

test('the log keeps the last lines only', () => {
  assert.equal(EVENT_LOG_MAX, 200);
  const feed = new Feed(5);
  for (let seq = 1; seq <= 12; seq += 1) feed.accept(ev(seq, 'battery', { percent: 100 - seq }));
  assert.deepEqual(feed.lines.map((l) => l.seq), [8, 9, 10, 11, 12]);
  feed.clear();
  assert.deepEqual(feed.lines, []);
  // Clearing the lines does not forget where the stream was.
  assert.equal(feed.accept(ev(14, 'battery', { percent: 80 }))[0].name, 'skip');
});

test('something that is not an event object is marked, not shown as one', () => {
  const feed = new Feed();
  for (const bad of [null, 'text', { seq: 1 }]) {
    assert.deepEqual(feed.accept(bad).map((l) => [l.kind, l.name]), [['marker', 'unreadable']]);
  }
});

/** Timers the test runs by hand: `due()` fires the pending one and says after how long. */
function manualTimers() {
  const pending = [];
  return {
    pending,
    set: (f, ms) => { pending.push({ f, ms }); return pending.length; },
    clear: () => { pending.length = 0; },
    due() {
      const t = pending.shift();
      t.f();
      return t.ms;
    },
  };
}

function follow(password) {
  const timers = manualTimers();
  const stream = new EventStream('ws://vehicle:53001/events', timers);
  const statuses = [];
  const events = [];
  stream.addEventListener('status', (e) => statuses.push(e.detail));
  stream.addEventListener('event', (e) => events.push(e.detail));
  stream.start(password);
  return { stream, timers, statuses, events };
}

test('the stream logs in with the password first, then only listens', () => {
  const { stream, statuses, events } = follow('s3cret');
  const socket = FakeSocket.last;
  assert.equal(socket.url, 'ws://vehicle:53001/events');
  socket.serverOpen();
  assert.deepEqual(socket.sent, ['login s3cret']);
  assert.equal(stream.status, 'connecting', 'not connected until the login is answered');
  socket.serverSend({ ret: 0, cmd: 1, ts: 1, msg: 'Login successfully' });
  assert.equal(stream.status, 'connected');
  socket.serverSend(ev(1, 'armed', { armed: true }));
  assert.deepEqual(events, [ev(1, 'armed', { armed: true })], 'the login answer is no event');
  assert.deepEqual(socket.sent, ['login s3cret'], 'nothing else is ever sent');
  assert.deepEqual(statuses.map((s) => s.status), ['off', 'connecting', 'connected']);
  stream.stop();
});

test('without a password the stream sends nothing', () => {
  const { stream } = follow(null);
  const socket = FakeSocket.last;
  socket.serverOpen();
  assert.equal(stream.status, 'connected');
  assert.deepEqual(socket.sent, []);
  stream.stop();
  assert.equal(socket.closedWith, 1000);
});

test('a lost stream says so and reopens with a growing wait, reset once back', () => {
  const { stream, timers, statuses } = follow('pw');
  FakeSocket.last.serverOpen();
  FakeSocket.last.serverSend({ ret: 0 });
  const waits = [];
  for (let i = 0; i < RETRY_MS.length + 1; i += 1) {
    FakeSocket.last.serverClose(1001, 'lluavd is shutting down');
    assert.equal(stream.status, 'disconnected');
    waits.push(timers.due());
    assert.equal(stream.status, 'connecting');
  }
  assert.deepEqual(waits, [...RETRY_MS, RETRY_MS.at(-1)]);
  assert.match(statuses.find((s) => s.status === 'disconnected').detail, /^1001 lluavd is shutting down; retry in 0\.5 s$/);
  // Back and logged in: the next loss waits the shortest time again.
  FakeSocket.last.serverOpen();
  assert.deepEqual(FakeSocket.last.sent, ['login pw'], 'each new socket logs in');
  FakeSocket.last.serverSend({ ret: 0 });
  FakeSocket.last.serverClose(1006, 'no connection');
  assert.equal(timers.due(), RETRY_MS[0]);
  stream.stop();
  assert.equal(stream.status, 'off');
  assert.deepEqual(timers.pending, [], 'stopped: no retry left');
});

test('a refused login is not retried: each wrong password counts', () => {
  const { stream, timers, statuses } = follow('wrong');
  const socket = FakeSocket.last;
  socket.serverOpen();
  socket.serverSend({ ret: -1, cmd: 1, ts: 1, msg: 'Wrong password!' });
  assert.equal(stream.status, 'refused');
  assert.equal(statuses.at(-1).detail, 'Wrong password!');
  assert.equal(socket.closedWith, 1000);
  assert.deepEqual(timers.pending, []);
  // A later login with a password that works starts it again.
  stream.start('right');
  assert.equal(stream.status, 'connecting');
  stream.stop();
});

test('starting again with the same password keeps the open stream', () => {
  const { stream } = follow('pw');
  const socket = FakeSocket.last;
  socket.serverOpen();
  socket.serverSend({ ret: 0 });
  stream.start('pw');
  assert.equal(FakeSocket.last, socket, 'no second socket');
  assert.equal(socket.readyState, 1);
  stream.start('other');
  assert.notEqual(FakeSocket.last, socket, 'a new password is a new stream');
  assert.equal(socket.closedWith, 1000);
  stream.stop();
});
