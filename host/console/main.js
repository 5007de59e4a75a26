// The console: connects, logs in, polls, follows the events, and turns what
// the person does into requests. What is shown lives in panels.js and
// plot.js; how requests travel lives in protocol.js; what answers mean lives
// in vehicle.js; what events mean, and their stream, in events.js.

import { EVENT_LOG_MAX, EventStream, eventsUrl, Feed } from './events.js';
import { Client, commandName, defaultUrl } from './protocol.js';
import { Plot } from './plot.js';
import { byId, CommandLine, Confirm, EventLog, Header, Log, Login, StatePanel } from './panels.js';
import {
  altitudeOf, readCommands, readControlAnswer, readLogin, readMission, readState, setpointLine,
} from './vehicle.js';

/** `state` every 200 ms: the server never pushes. */
const STATE_EVERY_MS = 200;
/** `mw_list` every 2 s. */
const MISSION_EVERY_MS = 2000;
/** Waits before reconnecting, growing with each failure. */
const RECONNECT_MS = [500, 1000, 2000, 4000];
/** Commands after which the mission is read again at once. */
const MISSION_COMMANDS = new Set(['mission', 'mw_exec', 'ai1_mission', 'test_listwp', 'plan', 'unlock_plan']);
/** Commands whose answer says who is in control, `you` included. */
const CONTROL_COMMANDS = new Set(['control', 'control_take', 'control_release']);

class Console {
  constructor() {
    this.header = new Header();
    this.panel = new StatePanel();
    this.log = new Log();
    this.login = new Login();
    this.confirm = new Confirm();
    this.commandLine = new CommandLine();
    this.plot = new Plot(byId('plot'));
    this.client = null;
    this.url = defaultUrl(window.location);
    /** The password that worked, kept in memory only, to log in again after a reconnect. */
    this.password = null;
    /** True until the first answer of a connection says whether it must log in: no polls till then. */
    this.mustLogin = true;
    this.state = null;
    this.stateAt = null;
    this.stateSentAt = null;
    this.missionBusy = false;
    this.missionSupported = true;
    this.lastPollError = '';
    this.failures = 0;
    /** Who is in control (`{by, since}`), as the latest answer that says so had it. */
    this.control = null;
    /**
     * Whether a label is this connection's session, as `control` answered
     * it. `state` names the pilot but never says whether it is us, and a
     * label belongs to one session for good (ids are never reused within a
     * run), so one question per new label is enough.
     */
    this.verdicts = new Map();
    /** The label a `control` request is out for, so that polls do not ask twice. */
    this.askingAbout = null;
    /**
     * The event log, on a second socket (`/events`) opened once the command
     * socket is logged in, with the password that worked there. A control
     * label reads as "this console" when `control` said it is ours.
     */
    this.eventLog = new EventLog(new Feed(EVENT_LOG_MAX, (label) => this.verdicts.get(label) ?? null));
    this.events = new EventStream(eventsUrl(this.url));
    this.header.endpoint.textContent = this.url;
    this.header.showRole(null);
    this.#wire();
    setInterval(() => this.#pollState(), STATE_EVERY_MS);
    setInterval(() => this.#pollMission(), MISSION_EVERY_MS);
    setInterval(() => this.#showAge(), 100);
    this.#connect();
  }

  #wire() {
    this.events.addEventListener('status', (ev) => this.eventLog.connection(ev.detail.status, ev.detail.detail));
    this.events.addEventListener('event', (ev) => this.#event(ev.detail));
    this.login.addEventListener('login', (ev) => this.#logIn(ev.detail));
    this.commandLine.addEventListener('send', (ev) => this.run(ev.detail));
    this.plot.addEventListener('pick', (ev) => this.#flyTo(ev.detail));
    byId('takeoff').addEventListener('click', () => this.#takeoff());
    byId('land').addEventListener('click', () => this.run('land'));
    byId('rtl').addEventListener('click', () => this.run('rtl'));
    byId('disarm').addEventListener('click', () => this.#disarm());
    byId('take-control').addEventListener('click', () => this.#takeControl());
    byId('release-control').addEventListener('click', () => this.run('control_release'));
    byId('fit').addEventListener('click', () => this.plot.fit());
    byId('zoom-in').addEventListener('click', () => this.plot.zoom(1.25));
    byId('zoom-out').addEventListener('click', () => this.plot.zoom(0.8));
    byId('clear-track').addEventListener('click', () => this.plot.clearTrack());
    this.header.logout.addEventListener('click', () => {
      this.password = null;
      this.events.stop();
      this.client?.close();
    });
  }

  async #connect() {
    const client = new Client(this.url);
    this.client = client;
    this.mustLogin = true;
    // A new connection is a new session with a label of its own.
    this.verdicts.clear();
    this.askingAbout = null;
    this.header.connection('connecting');
    client.addEventListener('close', (ev) => this.#closed(client, ev.detail));
    client.addEventListener('stray', (ev) => this.log.note(`answer without a request: ${ev.detail}`, 'danger'));
    try {
      await client.connect();
    } catch {
      return; // #closed schedules the next try.
    }
    this.failures = 0;
    this.header.connection('connected');
    this.log.note(`connected to ${this.url}`, 'good');
    await this.#start();
  }

  #closed(client, { code, reason }) {
    if (client !== this.client) return;
    const wait = RECONNECT_MS[Math.min(this.failures, RECONNECT_MS.length - 1)];
    this.failures += 1;
    this.header.connection('disconnected', `retry in ${(wait / 1000).toFixed(1)} s`);
    this.header.showRole(null);
    this.log.note(`disconnected (${code}: ${reason})`, 'danger');
    this.stateSentAt = null;
    setTimeout(() => this.#connect(), wait);
  }

  /** A new connection: find out whether it must log in, then start reading. */
  async #start() {
    let first;
    try {
      first = await this.client.request('state');
    } catch {
      return;
    }
    if (!first.needsLogin) {
      this.mustLogin = false;
      this.header.showRole('open');
      this.#applyState(first);
      // No password: the events socket is admitted at once, and any message would close it.
      await this.#afterLogin(null);
    } else if (this.password !== null) {
      await this.#logIn(this.password);
    } else {
      this.#needLogin('');
    }
  }

  #needLogin(message) {
    this.mustLogin = true;
    // Logged out (or never in): the events are for whoever logs in next.
    this.events.stop();
    this.header.showRole(null);
    this.login.show(message);
  }

  async #logIn(password) {
    let ex;
    try {
      ex = await this.client.request(`login ${password}`);
    } catch (e) {
      this.login.show(`No answer: ${e.message}`);
      return;
    }
    this.log.exchange(ex);
    await this.#loginAnswered(ex, password);
  }

  /**
   * What a `login` answer means, from the form or the command line: the
   * role shown, the password kept to log in again after a reconnect, and
   * whether to ask for one. A refused attempt leaves a logged-in session
   * as it was (the server does too).
   */
  async #loginAnswered(ex, password) {
    if (!ex.ok) {
      if (this.mustLogin) {
        this.password = null;
        this.#needLogin(ex.msg || 'Login refused');
      }
      return;
    }
    const who = readLogin(ex.answer);
    if (!who.loggedIn) {
      this.password = null;
      this.#needLogin('That value logs out. Enter the vehicle’s password.');
      return;
    }
    this.password = password;
    this.header.showRole(who.admin ? 'admin' : 'user');
    if (this.mustLogin) {
      this.mustLogin = false;
      this.login.hide();
      await this.#afterLogin(password);
    }
  }

  /**
   * Follows the events, logging in with `password` (null: the vehicle has
   * none); the stream reopens itself, so a new command connection with the
   * same password leaves it as it is. Then reads what only changes now
   * and then: the command names, the mission.
   */
  async #afterLogin(password) {
    this.events.start(password);
    try {
      const help = await this.client.request('help');
      if (help.ok) this.commandLine.setCommands(readCommands(help.answer));
    } catch {
      // The connection went; the next one asks again.
    }
    this.missionSupported = true;
    this.#pollMission();
  }

  /**
   * An event from the stream: into the log; a pilot's label this page has
   * no verdict on is asked about once (`control`), so that the log can say
   * "this console" for its own.
   */
  #event(e) {
    this.eventLog.add(this.eventLog.feed.accept(e));
    const by = e?.event === 'control' && typeof e.by === 'string' ? e.by : null;
    if (by !== null && !this.verdicts.has(by) && this.askingAbout !== by) this.#askControl(by);
  }

  #pollState() {
    if (!this.client?.isOpen || this.mustLogin || this.stateSentAt !== null) return;
    this.stateSentAt = performance.now();
    this.client.request('state')
      .then((ex) => this.#applyState(ex))
      .catch(() => {})
      .finally(() => { this.stateSentAt = null; });
  }

  #applyState(ex) {
    if (ex.needsLogin) {
      if (!this.login.shown) this.#needLogin('The session was logged out.');
      return;
    }
    if (!ex.ok) {
      const text = `state: ${ex.ret} ${ex.msg}`;
      this.panel.showError(text);
      if (text !== this.lastPollError) this.log.exchange(ex);
      this.lastPollError = text;
      return;
    }
    this.lastPollError = '';
    this.panel.showError('');
    const s = readState(ex.answer);
    this.state = s;
    this.stateAt = performance.now();
    this.panel.show(s);
    this.plot.setHome(s.home);
    this.plot.setSetpoint(s.setpoint);
    this.plot.setVehicle(s.position, s.yaw);
    byId('takeoff').disabled = s.airborne === true;
    this.#controlSaid(s.control);
  }

  /**
   * Takes who is in control from an answer that says so. Answers arrive in
   * the order the server wrote them, so the latest one is the truth. When
   * it names a pilot without saying whether that is this console (`state`
   * never does), `control` is asked once for that label.
   */
  #controlSaid(control) {
    this.control = control;
    if (control !== null && control.you !== null && this.verdicts.get(control.by) !== control.you) {
      this.verdicts.set(control.by, control.you);
      this.eventLog.refreshControl();
    }
    if (control !== null && !this.verdicts.has(control.by) && this.askingAbout !== control.by) {
      this.#askControl(control.by);
    }
    this.#showAuthority();
  }

  #askControl(label) {
    if (!this.client?.isOpen) return;
    this.askingAbout = label;
    this.client.request('control')
      .then((ex) => {
        if (ex.ok) this.#controlSaid(readControlAnswer(ex.answer));
      })
      .catch(() => {})
      .finally(() => {
        if (this.askingAbout === label) this.askingAbout = null;
      });
  }

  #showAuthority() {
    const by = this.control?.by;
    this.panel.showAuthority({
      failsafe: this.state?.failsafe ?? null,
      control: this.control,
      you: by === undefined ? null : this.verdicts.get(by) ?? null,
    });
  }

  #pollMission() {
    if (!this.client?.isOpen || this.mustLogin || this.missionBusy || !this.missionSupported) return;
    this.missionBusy = true;
    this.client.request('mw_list')
      .then((ex) => {
        if (ex.ok) {
          this.plot.setWaypoints(readMission(ex.answer).waypoints);
        } else if (ex.ret === -2) {
          // This vehicle keeps no mission list; stop asking.
          this.missionSupported = false;
          this.plot.setWaypoints([]);
        }
      })
      .catch(() => {})
      .finally(() => { this.missionBusy = false; });
  }

  #showAge() {
    const now = performance.now();
    this.header.showAge(
      this.stateAt === null ? null : now - this.stateAt,
      this.stateSentAt === null ? null : now - this.stateSentAt,
    );
  }

  /** Sends a line the person asked for, logs it and its answer. */
  async run(line) {
    if (!this.client?.isOpen) {
      this.log.failure(line, new Error('not connected'));
      return null;
    }
    let ex;
    try {
      ex = await this.client.request(line);
    } catch (e) {
      this.log.failure(line, e);
      return null;
    }
    this.log.exchange(ex);
    const name = commandName(line);
    if (name === 'login') await this.#loginAnswered(ex, line.slice(line.indexOf(' ') + 1).trim());
    if (name === 'help' && ex.ok) this.commandLine.setCommands(readCommands(ex.answer));
    if (ex.needsLogin) this.#needLogin('Log in to send commands.');
    if (MISSION_COMMANDS.has(name)) this.#pollMission();
    if (CONTROL_COMMANDS.has(name) && ex.ok) this.#controlSaid(readControlAnswer(ex.answer));
    return ex;
  }

  async #takeoff() {
    const sure = await this.confirm.ask({
      title: 'Take off?',
      text: 'The vehicle arms its motors and climbs to its takeoff altitude.',
      command: 'takeoff',
      ok: 'Take off',
      danger: true,
    });
    if (sure) await this.run('takeoff');
  }

  /**
   * `control_take`; while a failsafe holds (the vehicle acting on its own
   * for safety) only `control_take failsafe` takes control, and it
   * overrides the failsafe, so the person confirms that first. A failsafe
   * this page has not seen yet gets the plain command, which the server
   * refuses naming it: nothing is overridden without the question.
   */
  async #takeControl() {
    const failsafe = this.state?.failsafe;
    if (!failsafe || failsafe.overridden) {
      await this.run('control_take');
      return;
    }
    const sure = await this.confirm.ask({
      title: 'Override the failsafe?',
      text: `The vehicle is in failsafe (${failsafe.reason}): it acts on its own for safety and refuses motion `
        + 'commands. Overriding gives this console control and lets its commands steer again, as a pilot '
        + 'taking over with the sticks; until you send one the vehicle goes on as it is.',
      command: 'control_take failsafe',
      ok: 'Override',
      danger: true,
    });
    if (sure) await this.run('control_take failsafe');
  }

  async #disarm() {
    const flying = this.state?.airborne === true;
    const sure = await this.confirm.ask({
      title: flying ? 'Disarm in the air?' : 'Disarm?',
      text: flying
        ? 'The vehicle is flying: disarming stops the motors and it falls. Use Land or RTL to come down.'
        : 'The motors stop.',
      command: 'disarm',
      ok: 'Disarm',
      danger: true,
    });
    if (sure) await this.run('disarm');
  }

  async #flyTo({ n, e }) {
    if (this.state === null) {
      this.log.note('No vehicle state yet: cannot pick a setpoint.', 'warn');
      return;
    }
    const line = setpointLine(this.state, n, e);
    const [, , down] = line.split(' ')[1].split(':').map(Number);
    const sure = await this.confirm.ask({
      title: 'Fly here?',
      text: `North ${n.toFixed(1)} m, east ${e.toFixed(1)} m, at ${altitudeOf({ d: down }).toFixed(1)} m altitude, heading kept.`,
      command: line,
      ok: 'Fly here',
    });
    if (sure) await this.run(line);
  }
}

new Console();
