// The page's reading of answers, without a browser: node --test. The
// answers are the backends' own, captured from real lluavd runs by
// tests/console/test_answers.py, which fails when a backend's answers no
// longer have the shape kept in tests/console/answers/.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readdirSync, readFileSync } from 'node:fs';

import {
  decimal, FIELDS, readCommands, readControl, readControlAnswer, readFailsafe, readLogin, readMission, readState,
  setpointLine,
} from '../../../host/console/vehicle.js';

const DIR = new URL('../answers/', import.meta.url);
const answer = (name) => JSON.parse(readFileSync(new URL(`${name}.json`, DIR), 'utf8'));
const STATES = [
  'sim-state-ground', 'sim-state-mission', 'sim-state-failsafe', 'sim-state-overridden', 'mavlink-state',
  'mavlink-state-lost',
];

/** Every member name anywhere in an answer. */
function members(value, into = new Set()) {
  if (Array.isArray(value)) value.forEach((v) => members(v, into));
  else if (value !== null && typeof value === 'object') {
    for (const [k, v] of Object.entries(value)) {
      into.add(k);
      members(v, into);
    }
  }
  return into;
}

test('every member the page reads is one a backend sends', () => {
  const sent = new Set();
  for (const file of readdirSync(DIR)) members(answer(file.replace(/\.json$/, '')), sent);
  const unsent = Object.values(FIELDS).filter((name) => !sent.has(name));
  assert.deepEqual(unsent, [], 'FIELDS names members no captured answer has');
});

test('a fact reads as null exactly when its backend does not send it', () => {
  for (const name of STATES) {
    const sent = answer(name).state;
    for (const [fact, value] of Object.entries(readState(answer(name)))) {
      assert.equal(value === null, (sent[FIELDS[fact]] ?? null) === null, `${name}: ${fact}`);
    }
  }
});

test("the simulator's state on the ground and flying a mission", () => {
  const ground = readState(answer('sim-state-ground'));
  assert.equal(ground.fsm, 'disarmed');
  assert.equal(ground.armed, false);
  assert.equal(ground.lockMode, false);
  assert.deepEqual(ground.position, { n: 0, e: 0, d: 0 });
  assert.deepEqual(ground.setpoint, { n: 0, e: 0, d: 0, yaw: 0 });
  assert.equal(ground.battery, 100, 'a percentage');
  assert.equal(ground.link, null, 'the simulator has no autopilot link');
  assert.equal(ground.waypointsLeft, 0);
  const flying = readState(answer('sim-state-mission'));
  assert.equal(flying.fsm, 'mission');
  assert.equal(flying.airborne, true);
  assert.equal(flying.waypointsLeft, 3);
  assert.equal(flying.altitude, -flying.position.d);
});

test("the MAVLink backend's state, its link up and lost", () => {
  // The telemetry tests/console/test_answers.py's autopilot streams.
  const up = readState(answer('mavlink-state'));
  assert.equal(up.fsm, 'disarmed');
  assert.equal(up.link, 'up');
  assert.ok(up.linkAgeMs >= 0 && up.linkAgeMs < 3000, up.linkAgeMs);
  assert.deepEqual(up.position, { n: 3, e: -2, d: -10 });
  assert.deepEqual(up.velocity, { n: 0.5, e: 0.25, d: -0.1 });
  assert.equal(up.yaw, 1.25);
  assert.equal(up.altitude, 10);
  assert.equal(up.battery, 76);
  assert.deepEqual(up.home, { n: 0, e: 0, d: 0 });
  assert.equal(up.setpoint, null, 'no setpoint stream');
  assert.equal(up.waypointsLeft, null, 'the simulator only');
  assert.equal(up.failsafe, null);
  assert.equal(up.control, null, 'no one flies yet');
  const lost = readState(answer('mavlink-state-lost'));
  assert.equal(lost.link, 'lost');
  assert.ok(lost.linkAgeMs > 3000, lost.linkAgeMs);
});

test('who is in control, as another session and the pilot see it', () => {
  assert.equal(readControlAnswer(answer('sim-control-free')), null, 'free');
  const other = readControlAnswer(answer('sim-control-other'));
  assert.match(other.by, /^ws 127\.0\.0\.1:\d+ #\d+$/);
  assert.equal(other.you, false, 'asked by a session that is not the pilot');
  assert.ok(other.since > Date.UTC(2020, 0), 'ms since the epoch');
  const taken = readControlAnswer(answer('sim-control_take'));
  assert.equal(taken.you, true);
  assert.notEqual(taken.by, other.by, 'each session has a label of its own');
  assert.equal(readControlAnswer(answer('sim-control_release')), null);
  // `state` names the pilot (the session that took off) but never says `you`.
  const flying = readState(answer('sim-state-mission'));
  assert.deepEqual(flying.control, { by: other.by, since: other.since, you: null });
  assert.equal(readState(answer('sim-state-ground')).control, null);
});

test('a failsafe, and once the pilot overrode it', () => {
  assert.equal(readState(answer('sim-state-ground')).failsafe, null);
  const held = readState(answer('sim-state-failsafe'));
  assert.deepEqual(held.failsafe, { reason: 'battery_low', overridden: false });
  assert.equal(held.fsm, 'rtl', 'the vehicle returns on its own');
  const overridden = readState(answer('sim-state-overridden'));
  assert.deepEqual(overridden.failsafe, { reason: 'battery_low', overridden: true });
  const pilot = readControlAnswer(answer('sim-control_take-failsafe'));
  assert.equal(pilot.you, true);
  assert.equal(overridden.control.by, pilot.by, 'overriding took control');
});

test('failsafe and control read defensively', () => {
  assert.deepEqual(readFailsafe('autopilot: RTL'), { reason: 'autopilot: RTL', overridden: false });
  assert.deepEqual(readFailsafe('external: POSCTL (overridden)'), { reason: 'external: POSCTL', overridden: true });
  assert.deepEqual(readFailsafe(' (overridden)'), { reason: ' (overridden)', overridden: false }, 'no reason left');
  for (const value of [null, undefined, '', 7, {}]) assert.equal(readFailsafe(value), null, String(value));
  assert.equal(readControl({ by: 'mqtt alice' }), null, 'no since');
  assert.equal(readControl({ by: '', since: 1 }), null);
  assert.equal(readControl('mqtt alice'), null);
  assert.deepEqual(readControl({ by: 'mqtt alice', since: 1, you: 'yes' }), { by: 'mqtt alice', since: 1, you: null });
  assert.equal(readControlAnswer({ ret: -1, msg: 'This session is not in control' }), null);
});

test('missing or mistyped members read as null instead of breaking', () => {
  const real = answer('sim-state-ground');
  const s = readState({ ...real, state: { ...real.state, fsm: 7, armed: 'yes', position: { x: 'a', y: 1, z: 0 }, battery: null } });
  assert.equal(s.fsm, null);
  assert.equal(s.armed, null);
  assert.equal(s.position, null);
  assert.equal(s.battery, null);
  assert.deepEqual(readState({ ret: 0 }).position, null);
  assert.deepEqual(readState(null).fsm, null);
});

test('both backends list the mission the same way', () => {
  const expected = [{ n: 5, e: 0, d: -3, id: 1 }, { n: 5, e: 5, d: -3, id: 2 }, { n: 0, e: 5, d: -3, id: 3 }];
  for (const name of ['sim-mw_list', 'mavlink-mw_list']) {
    assert.deepEqual(readMission(answer(name)), { id: 1001, waypoints: expected }, name);
  }
  assert.deepEqual(readMission(answer('sim-mw_list-empty')), { id: null, waypoints: [] });
});

test('login and help answers', () => {
  assert.deepEqual(readLogin(answer('login')), { loggedIn: true, admin: false });
  assert.deepEqual(readLogin(answer('login-refused')), { loggedIn: false, admin: false });
  const commands = readCommands(answer('help'));
  assert.ok(commands.includes('login') && commands.includes('set_sp_ned'), commands);
});

test('numbers are written as the protocol grammar reads them', () => {
  assert.equal(decimal(1.005), '1');
  assert.equal(decimal(-0.001), '0');
  assert.equal(decimal(0.1 + 0.2), '0.3');
  assert.equal(decimal(1e-9), '0');
  assert.equal(decimal(-12.345, 1), '-12.3');
  assert.doesNotMatch(decimal(123456.789), /e/);
});

test('a setpoint keeps the height the vehicle is going to and its heading', () => {
  const real = answer('sim-state-mission').state;
  const at = (changes) => readState({ state: { ...real, ...changes } });
  const setpoint = { x: 2, y: -2, z: -3, yaw: 1.57 };
  const flying = at({ position: { x: 1.5, y: -2, z: -3 }, yaw: 1.57, setpoint });
  assert.equal(setpointLine(flying, 4.444, -1), 'set_sp_ned 4.44:-1:-3:1.57');
  const climbing = at({ position: { x: 0, y: 0, z: -1.2 }, yaw: 1.57, setpoint });
  assert.equal(setpointLine(climbing, 1, 1), 'set_sp_ned 1:1:-3:1.57', 'the target height, not the current one');
  const ground = readState(answer('sim-state-ground'));
  assert.equal(setpointLine(ground, 1, 2), 'set_sp_ned 1:2:0:0');
  const noStream = readState(answer('mavlink-state'));
  assert.equal(setpointLine(noStream, 1, 2), 'set_sp_ned 1:2:-10:1.25', 'no setpoint: the height it is at');
  assert.equal(setpointLine(readState({}), 1, 2), 'set_sp_ned 1:2:0:0', 'nothing known: ground level, north');
});
