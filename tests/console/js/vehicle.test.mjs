// The page's reading of answers, without a browser: node --test.
import { test } from 'node:test';
import assert from 'node:assert/strict';

import {
  decimal, readCommands, readLogin, readMission, readState, setpointLine,
} from '../../../host/console/vehicle.js';

const SIM_STATE = {
  ret: 0, cmd: 2, ts: 1,
  state: {
    armed: true, fsm: 'hover', lock_mode: false, airborne: true,
    position: { x: 1.5, y: -2, z: -3 }, velocity: { x: 0, y: 0.5, z: -0.1 },
    yaw: 1.57, altitude: 3, battery: 87.5,
    setpoint: { x: 2, y: -2, z: -3, yaw: 1.57 }, home: { x: 0, y: 0, z: 0 },
    waypoints_left: 2, taskname: null,
  },
};

test('the simulator state reads field by field', () => {
  const s = readState(SIM_STATE);
  assert.equal(s.fsm, 'hover');
  assert.equal(s.armed, true);
  assert.equal(s.lockMode, false);
  assert.deepEqual(s.position, { n: 1.5, e: -2, d: -3 });
  assert.deepEqual(s.setpoint, { n: 2, e: -2, d: -3, yaw: 1.57 });
  assert.deepEqual(s.battery, { percent: 87.5, voltage: null });
  assert.equal(s.link, null, 'the simulator has no autopilot link');
  assert.equal(s.waypointsLeft, 2);
  assert.equal(s.task, null);
});

test('missing or mistyped fields read as null instead of breaking', () => {
  const s = readState({ ret: 0, state: { fsm: 7, armed: 'yes', position: { x: 'a', y: 1 }, battery: null } });
  assert.equal(s.fsm, null);
  assert.equal(s.armed, null);
  assert.equal(s.position, null);
  assert.equal(s.battery, null);
  assert.equal(s.setpoint, null);
  assert.deepEqual(readState({ ret: 0 }).position, null);
  assert.deepEqual(readState(null).fsm, null);
});

test('a MAVLink-style state with a link, a battery object and arrays reads too', () => {
  const s = readState({
    state: {
      fsm: 'mission', link: 'lost', heartbeat_age_ms: 2500,
      battery: { voltage: 15.2, remaining: 41 }, position: [1, 2, -5], velocity: { n: 1, e: 0, d: 0 },
    },
  });
  assert.equal(s.link, 'lost');
  assert.equal(s.linkAgeMs, 2500);
  assert.deepEqual(s.battery, { percent: 41, voltage: 15.2 });
  assert.deepEqual(s.position, { n: 1, e: 2, d: -5 });
  assert.deepEqual(s.velocity, { n: 1, e: 0, d: 0 });
  assert.equal(readState({ state: { link: true } }).link, 'up');
});

test('mission waypoints keep their ids, or get their place in the list', () => {
  const m = readMission({ ext_id: 1001, waypoints: [{ id: 7, x: 1, y: 2, z: -3 }, { x: 4, y: 5, z: -6 }, { x: 'bad' }] });
  assert.equal(m.id, 1001);
  assert.deepEqual(m.waypoints, [{ n: 1, e: 2, d: -3, id: 7 }, { n: 4, e: 5, d: -6, id: 2 }]);
  assert.deepEqual(readMission({ ext_id: null, waypoints: [] }), { id: null, waypoints: [] });
});

test('login and help answers', () => {
  assert.deepEqual(readLogin({ ret: 0, logged_in: true, admin: false }), { loggedIn: true, admin: false });
  assert.deepEqual(readLogin({ ret: -1 }), { loggedIn: false, admin: false });
  assert.deepEqual(readCommands({ commands: ['login', 'state', 3] }), ['login', 'state']);
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
  const flying = readState(SIM_STATE);
  assert.equal(setpointLine(flying, 4.444, -1), 'set_sp_ned 4.44:-1:-3:1.57');
  const climbing = readState({ state: { ...SIM_STATE.state, position: { x: 0, y: 0, z: -1.2 } } });
  assert.equal(setpointLine(climbing, 1, 1), 'set_sp_ned 1:1:-3:1.57', 'the target height, not the current one');
  const ground = readState({ state: { airborne: false, position: { x: 0, y: 0, z: 0 }, yaw: 0 } });
  assert.equal(setpointLine(ground, 1, 2), 'set_sp_ned 1:2:0:0');
  assert.equal(setpointLine(readState({}), 1, 2), 'set_sp_ned 1:2:0:0', 'nothing known: ground level, north');
});
