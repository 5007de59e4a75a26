// What the answers say about the vehicle, read defensively.
//
// Every field name of an answer the page reads is in FIELDS below, and
// nowhere else: backends (the simulator, the MAVLink bridge) may add,
// drop or reshape fields, and a field that is missing or of another type
// reads as null rather than breaking the page. Coordinates are NED metres
// (x north, y east, z down), angles radians.

/** Where each fact lives; a list gives alternatives, first found wins. */
export const FIELDS = {
  state: ['state'],
  fsm: ['fsm', 'mode'],
  armed: ['armed'],
  lockMode: ['lock_mode'],
  airborne: ['airborne'],
  battery: ['battery'],
  batteryPercent: ['remaining', 'percent', 'percentage'],
  batteryVoltage: ['voltage', 'voltage_v'],
  position: ['position'],
  velocity: ['velocity'],
  yaw: ['yaw', 'heading'],
  altitude: ['altitude'],
  setpoint: ['setpoint'],
  home: ['home'],
  link: ['link'],
  linkAgeMs: ['heartbeat_age_ms', 'link_age_ms'],
  waypointsLeft: ['waypoints_left'],
  task: ['taskname'],
  north: ['x', 'n', 'north'],
  east: ['y', 'e', 'east'],
  down: ['z', 'd', 'down'],
  missionId: ['ext_id'],
  waypoints: ['waypoints'],
  waypointId: ['id', 'wp_id'],
  loggedIn: ['logged_in'],
  admin: ['admin'],
  commands: ['commands'],
};

function pick(object, names) {
  if (object === null || typeof object !== 'object') return undefined;
  for (const name of names) {
    if (Object.hasOwn(object, name)) return object[name];
  }
  return undefined;
}

function number(value) {
  return typeof value === 'number' && Number.isFinite(value) ? value : null;
}

function bool(value) {
  return typeof value === 'boolean' ? value : null;
}

function text(value) {
  return typeof value === 'string' && value !== '' ? value : null;
}

/** `{n, e, d}` from `{x, y, z}` (or n/e/d, or a 3-array); null if unusable. */
export function ned(value) {
  if (Array.isArray(value)) {
    const [n, e, d] = value.map(number);
    return n === null || e === null ? null : { n, e, d };
  }
  const n = number(pick(value, FIELDS.north));
  const e = number(pick(value, FIELDS.east));
  if (n === null || e === null) return null;
  return { n, e, d: number(pick(value, FIELDS.down)) };
}

function battery(value) {
  if (typeof value === 'number') return { percent: number(value), voltage: null };
  const percent = number(pick(value, FIELDS.batteryPercent));
  const voltage = number(pick(value, FIELDS.batteryVoltage));
  return percent === null && voltage === null ? null : { percent, voltage };
}

/** The vehicle as a `state` answer describes it; every field may be null. */
export function readState(answer) {
  const s = pick(answer, FIELDS.state) ?? {};
  const setpointRaw = pick(s, FIELDS.setpoint);
  const setpoint = ned(setpointRaw);
  if (setpoint) setpoint.yaw = number(pick(setpointRaw, FIELDS.yaw));
  const link = pick(s, FIELDS.link);
  return {
    fsm: text(pick(s, FIELDS.fsm)),
    armed: bool(pick(s, FIELDS.armed)),
    lockMode: bool(pick(s, FIELDS.lockMode)),
    airborne: bool(pick(s, FIELDS.airborne)),
    battery: battery(pick(s, FIELDS.battery)),
    position: ned(pick(s, FIELDS.position)),
    velocity: ned(pick(s, FIELDS.velocity)),
    yaw: number(pick(s, FIELDS.yaw)),
    altitude: number(pick(s, FIELDS.altitude)),
    setpoint,
    home: ned(pick(s, FIELDS.home)),
    link: typeof link === 'boolean' ? (link ? 'up' : 'lost') : text(link),
    linkAgeMs: number(pick(s, FIELDS.linkAgeMs)),
    waypointsLeft: number(pick(s, FIELDS.waypointsLeft)),
    task: text(pick(s, FIELDS.task)),
  };
}

/** The current mission from an `mw_list` answer: `{id, waypoints: [{id, n, e, d}]}`. */
export function readMission(answer) {
  const list = pick(answer, FIELDS.waypoints);
  const waypoints = [];
  if (Array.isArray(list)) {
    list.forEach((raw, index) => {
      const p = ned(raw);
      if (p) waypoints.push({ ...p, id: number(pick(raw, FIELDS.waypointId)) ?? index + 1 });
    });
  }
  return { id: number(pick(answer, FIELDS.missionId)), waypoints };
}

/** `{loggedIn, admin}` from a `login` answer. */
export function readLogin(answer) {
  return {
    loggedIn: bool(pick(answer, FIELDS.loggedIn)) ?? false,
    admin: bool(pick(answer, FIELDS.admin)) ?? false,
  };
}

/** Every command name from a `help` answer. */
export function readCommands(answer) {
  const list = pick(answer, FIELDS.commands);
  return Array.isArray(list) ? list.filter((c) => typeof c === 'string') : [];
}

/** The altitude (metres up) of a NED point, or null. */
export function altitudeOf(point) {
  return point && point.d !== null ? -point.d : null;
}

/**
 * A number as the protocol's decimal grammar accepts it: at most `digits`
 * decimals, no exponent, no "-0".
 */
export function decimal(value, digits = 2) {
  const rounded = Number(value.toFixed(digits));
  return Object.is(rounded, -0) ? '0' : String(rounded);
}

/**
 * The `set_sp_ned` line that sends the vehicle to north/east at the
 * altitude it is holding: the active setpoint's when flying (the height it
 * is going to), else its position's; the heading is kept.
 */
export function setpointLine(state, north, east) {
  const flying = state.airborne && state.setpoint && state.setpoint.d !== null;
  const holding = flying ? state.setpoint : state.position;
  const down = holding?.d ?? 0;
  const yaw = state.yaw ?? state.setpoint?.yaw ?? 0;
  return `set_sp_ned ${decimal(north)}:${decimal(east)}:${decimal(down)}:${decimal(yaw, 3)}`;
}
