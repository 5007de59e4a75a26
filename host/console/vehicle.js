// What the answers say about the vehicle, read defensively.
//
// Every member name of an answer the page reads is in FIELDS below, and
// nowhere else. They are the names lluavd sends (tests/console/answers/
// holds each backend's answers, captured from real runs): both vehicles
// send the `state` members, except `link` and `heartbeat_age_ms` (the
// MAVLink backend only) and `waypoints_left` (the simulator only); a member
// that is missing, null or of another type reads as null rather than
// breaking the page. Coordinates are NED metres (x north, y east, z down),
// angles radians.
//
// Flight authority (DESIGN.md): `state` names the failsafe (a reason, with
// " (overridden)" once the session in control overrode it, or null) and who
// is in control (`{by, since}` or null); `control`, `control_take` and
// `control_release` answer `control` the same way, with `you` saying whether
// it is the asking session. `state` never says `you`: the page learns its
// own label from those answers.

/** The member each fact is read from. */
export const FIELDS = {
  state: 'state',
  fsm: 'fsm',
  armed: 'armed',
  lockMode: 'lock_mode',
  airborne: 'airborne',
  battery: 'battery',
  position: 'position',
  velocity: 'velocity',
  yaw: 'yaw',
  altitude: 'altitude',
  setpoint: 'setpoint',
  home: 'home',
  link: 'link',
  linkAgeMs: 'heartbeat_age_ms',
  waypointsLeft: 'waypoints_left',
  failsafe: 'failsafe',
  control: 'control',
  controlBy: 'by',
  controlSince: 'since',
  controlYou: 'you',
  north: 'x',
  east: 'y',
  down: 'z',
  missionId: 'ext_id',
  waypoints: 'waypoints',
  waypointId: 'id',
  loggedIn: 'logged_in',
  admin: 'admin',
  commands: 'commands',
};

function pick(object, name) {
  return object !== null && typeof object === 'object' && Object.hasOwn(object, name) ? object[name] : undefined;
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

/** `{n, e, d}` from `{x, y, z}`; null if any is unusable. */
export function ned(value) {
  const n = number(pick(value, FIELDS.north));
  const e = number(pick(value, FIELDS.east));
  const d = number(pick(value, FIELDS.down));
  return n === null || e === null || d === null ? null : { n, e, d };
}

/** The vehicle as a `state` answer describes it; every field may be null. */
export function readState(answer) {
  const s = pick(answer, FIELDS.state) ?? {};
  const setpointRaw = pick(s, FIELDS.setpoint);
  const setpoint = ned(setpointRaw);
  if (setpoint) setpoint.yaw = number(pick(setpointRaw, FIELDS.yaw));
  return {
    fsm: text(pick(s, FIELDS.fsm)),
    armed: bool(pick(s, FIELDS.armed)),
    lockMode: bool(pick(s, FIELDS.lockMode)),
    airborne: bool(pick(s, FIELDS.airborne)),
    battery: number(pick(s, FIELDS.battery)),
    position: ned(pick(s, FIELDS.position)),
    velocity: ned(pick(s, FIELDS.velocity)),
    yaw: number(pick(s, FIELDS.yaw)),
    altitude: number(pick(s, FIELDS.altitude)),
    setpoint,
    home: ned(pick(s, FIELDS.home)),
    link: text(pick(s, FIELDS.link)),
    linkAgeMs: number(pick(s, FIELDS.linkAgeMs)),
    waypointsLeft: number(pick(s, FIELDS.waypointsLeft)),
    failsafe: readFailsafe(pick(s, FIELDS.failsafe)),
    control: readControl(pick(s, FIELDS.control)),
  };
}

/** What the server appends to a failsafe's reason once it is overridden. */
const OVERRIDDEN = ' (overridden)';

/**
 * `{reason, overridden}` from `state`'s failsafe (`"battery_low"`,
 * `"battery_low (overridden)"`), or null when there is none.
 */
export function readFailsafe(value) {
  const said = text(value);
  if (said === null) return null;
  const overridden = said.endsWith(OVERRIDDEN) && said.length > OVERRIDDEN.length;
  return { reason: overridden ? said.slice(0, -OVERRIDDEN.length) : said, overridden };
}

/**
 * `{by, since, you}` from a `control` member, or null when control is free
 * (or the member is unusable). `you` is null where the answer does not say
 * (`state`).
 */
export function readControl(value) {
  const by = text(pick(value, FIELDS.controlBy));
  const since = number(pick(value, FIELDS.controlSince));
  if (by === null || since === null) return null;
  return { by, since, you: bool(pick(value, FIELDS.controlYou)) };
}

/** Who is in control, from a `control`, `control_take` or `control_release` answer. */
export function readControlAnswer(answer) {
  return readControl(pick(answer, FIELDS.control));
}

/** The current mission from an `mw_list` answer: `{id, waypoints: [{id, n, e, d}]}`. */
export function readMission(answer) {
  const list = pick(answer, FIELDS.waypoints);
  const waypoints = [];
  if (Array.isArray(list)) {
    for (const raw of list) {
      const p = ned(raw);
      const id = number(pick(raw, FIELDS.waypointId));
      if (p && id !== null) waypoints.push({ ...p, id });
    }
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
  return point ? -point.d : null;
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
  const flying = state.airborne && state.setpoint !== null;
  const holding = flying ? state.setpoint : state.position;
  const down = holding?.d ?? 0;
  const yaw = state.yaw ?? state.setpoint?.yaw ?? 0;
  return `set_sp_ned ${decimal(north)}:${decimal(east)}:${decimal(down)}:${decimal(yaw, 3)}`;
}
