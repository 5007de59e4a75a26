"""A small autopilot made with pymavlink that misbehaves on purpose:
delayed, refused or missing COMMAND_ACKs, lost mission items, a link that
dies in the middle of a mission upload, a failsafe or a pilot taking it
over. Its heartbeat says PX4 by default, or ArduPilot, so both flavours'
paths are exercised."""

import os
import threading
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

HOME = (47.397742, 8.545594, 488.0)


def px4_mode(main, sub=0):
    """PX4's custom_mode: the main mode in bits 16..24, the sub mode in 24..32."""
    return (main << 16) | (sub << 24)


# The modes the tests switch to, as each autopilot numbers them.
PX4 = {"MANUAL": px4_mode(1), "POSCTL": px4_mode(3), "OFFBOARD": px4_mode(6),
       "AUTO.TAKEOFF": px4_mode(4, 2), "AUTO.LOITER": px4_mode(4, 3), "AUTO.MISSION": px4_mode(4, 4),
       "AUTO.RTL": px4_mode(4, 5), "AUTO.LAND": px4_mode(4, 6)}
COPTER = {"STABILIZE": 0, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9}
# The modes a flying autopilot enters when it accepts these commands
# (`mode_on`): PX4's takeoff mode (its hold follows when the climb ends),
# landing, return and mission modes; ArduPilot stays in GUIDED to take off.
FLIGHT_MODES = {
    mav.MAV_AUTOPILOT_PX4: {mav.MAV_CMD_NAV_TAKEOFF: PX4["AUTO.TAKEOFF"], mav.MAV_CMD_NAV_LAND: PX4["AUTO.LAND"],
                            mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: PX4["AUTO.RTL"],
                            mav.MAV_CMD_MISSION_START: PX4["AUTO.MISSION"]},
    mav.MAV_AUTOPILOT_ARDUPILOTMEGA: {mav.MAV_CMD_NAV_LAND: COPTER["LAND"],
                                      mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: COPTER["RTL"],
                                      mav.MAV_CMD_MISSION_START: COPTER["AUTO"]},
}


class FaultyAutopilot:
    """An autopilot on `udpout:127.0.0.1:port` (or another `transport`) whose answers a test sets:

    - `ack_delay[cmd] = s`: acknowledge `cmd` only after `s` seconds;
    - `ack_result[cmd] = r`: answer `cmd` with MAV_RESULT `r`, or never if None;
    - `drop_item_once`: mission item seqs ignored the first time they arrive;
    - `die_after_item`: after this mission item, fall silent for good;
    - `mission_result`: the MISSION_ACK result at the end of an upload;
    - `params`: name -> (raw float on the wire, MAV_PARAM_TYPE);
    - `request_out_of_range_after`: after this mission item, also ask for
      an item past the end of the mission;
    - `mode_on[cmd] = custom_mode`: the mode it enters when it accepts
      `cmd` (FLIGHT_MODES has a flying autopilot's);
    - `armed`, `custom_mode`, `system_status`, `landed_state` (None: no
      EXTENDED_SYS_STATE at all), `home` and `home_local` (HOME_POSITION's
      global and local position): what it reports, from the start when
      given to the constructor, changed at once with `switch`.
    Everything received is in `received` (monotonic time, message).

    `signing_key` (32 bytes) signs what it sends; it then still takes in
    unsigned or wrongly signed messages, and each message's `get_signed()`
    says whether its signature was good. SYSTEM_TIME carries the time
    since it started, as a flight controller's boot time.
    """

    def __init__(self, port, autopilot=mav.MAV_AUTOPILOT_PX4, transport="udpout", signing_key=None,
                 system_id=1, armed=False, custom_mode=0, landed_state=None,
                 system_status=mav.MAV_STATE_STANDBY, params=None, mode_on=None):
        self.conn = mavutil.mavlink_connection(
            f"{transport}:127.0.0.1:{port}", source_system=system_id, source_component=1,
            dialect="ardupilotmega")
        if signing_key is not None:
            self.conn.setup_signing(signing_key, sign_outgoing=True,
                                    allow_unsigned_callback=lambda _mav, _msg_id: True)
        self.booted = time.monotonic()
        self.autopilot = autopilot
        self.lock = threading.Lock()
        self.received = []
        self.ack_delay = {}
        self.ack_result = {}
        self.drop_item_once = set()
        self.die_after_item = None
        self.request_out_of_range_after = None
        self.mission_result = mav.MAV_MISSION_ACCEPTED
        self.params = dict(params or {})
        self.mode_on = dict(mode_on or {})
        self.mission = []
        self.mission_count = 0
        self.armed = armed
        self.custom_mode = custom_mode
        self.system_status = system_status
        self.landed_state = landed_state
        self.home = HOME
        self.home_local = (0.0, 0.0, 0.0)
        self.silent = threading.Event()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=f, daemon=True) for f in (self._beat, self._listen)]
        for t in self._threads:
            t.start()

    def _send(self, fn, *args, **kwargs):
        if not self.silent.is_set():
            with self.lock:
                fn(*args, **kwargs)

    def _heartbeat(self):
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        self._send(self.conn.mav.heartbeat_send, mav.MAV_TYPE_QUADROTOR, self.autopilot, base,
                   self.custom_mode, self.system_status)
        if self.landed_state is not None:
            self._send(self.conn.mav.extended_sys_state_send, mav.MAV_VTOL_STATE_MC, self.landed_state)

    def _beat(self):
        m = self.conn.mav
        while not self._stop.is_set():
            self._heartbeat()
            (lat, lon, alt), (x, y, z) = self.home, self.home_local
            self._send(m.home_position_send, int(lat * 1e7), int(lon * 1e7), int(alt * 1000), x, y, z,
                       [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)
            boot_ms = int((time.monotonic() - self.booted) * 1000)
            self._send(m.system_time_send, int(time.time() * 1e6), boot_ms)
            self._stop.wait(0.5)

    def _listen(self):
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is None or self.silent.is_set():
                continue
            with self.lock:
                self.received.append((time.monotonic(), msg))
            handler = getattr(self, "_on_" + msg.get_type(), None)
            if handler:
                handler(msg)

    def _on_COMMAND_LONG(self, msg):
        cmd = msg.command
        result = self.ack_result.get(cmd, mav.MAV_RESULT_ACCEPTED)
        if result is None:
            return
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM and result == mav.MAV_RESULT_ACCEPTED:
            self.armed = msg.param1 == 1.0
        if cmd == mav.MAV_CMD_DO_SET_MODE and result == mav.MAV_RESULT_ACCEPTED:
            if self.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
                self.custom_mode = int(msg.param2)
            else:
                self.custom_mode = px4_mode(int(msg.param2), int(msg.param3))
        if cmd in self.mode_on and result == mav.MAV_RESULT_ACCEPTED:
            self.custom_mode = self.mode_on[cmd]
        ack = (self.conn.mav.command_ack_send, cmd, result, 0, 0, msg.get_srcSystem(),
               msg.get_srcComponent())
        delay = self.ack_delay.get(cmd, 0)
        if delay:
            threading.Timer(delay, self._send, ack).start()
        else:
            self._send(*ack)

    def _on_MISSION_COUNT(self, msg):
        self.mission_count = msg.count
        self.mission = []
        self._send(self.conn.mav.mission_request_int_send, msg.get_srcSystem(),
                   msg.get_srcComponent(), 0)

    def _on_MISSION_ITEM_INT(self, msg):
        if msg.seq in self.drop_item_once:
            self.drop_item_once.discard(msg.seq)
            return
        if msg.seq == len(self.mission):
            self.mission.append(msg)
        if self.die_after_item is not None and msg.seq >= self.die_after_item:
            self.silent.set()
            return
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.request_out_of_range_after == msg.seq:
            self._send(self.conn.mav.mission_request_int_send, *src, self.mission_count + 5)
        if len(self.mission) < self.mission_count:
            self._send(self.conn.mav.mission_request_int_send, *src, len(self.mission))
        else:
            self._send(self.conn.mav.mission_ack_send, *src, self.mission_result)

    def _param_value(self, name):
        raw, ty = self.params[name]
        index = list(self.params).index(name)
        self._send(self.conn.mav.param_value_send, name.encode(), raw, ty, len(self.params), index)

    def _on_PARAM_REQUEST_READ(self, msg):
        if msg.param_id in self.params:
            self._param_value(msg.param_id)

    def _on_PARAM_SET(self, msg):
        if msg.param_id in self.params:
            self.params[msg.param_id] = (msg.param_value, msg.param_type)
            self._param_value(msg.param_id)

    def switch(self, **what):
        """Changes what it reports (`custom_mode`, `armed`, `system_status`,
        `landed_state`) and heartbeats at once, as an autopilot does on a
        mode change; returns the monotonic time it did."""
        for name, value in what.items():
            assert hasattr(self, name), name
            setattr(self, name, value)
        when = time.monotonic()
        self._heartbeat()
        return when

    def commands(self, cmd, since=0.0):
        with self.lock:
            return [m for t, m in self.received
                    if t >= since and m.get_type() == "COMMAND_LONG" and m.command == cmd]

    def messages(self, kind, since=0.0):
        with self.lock:
            return [m for t, m in self.received if t >= since and m.get_type() == kind]

    def close(self):
        self._stop.set()
        for t in self._threads:
            t.join()
        self.conn.close()
