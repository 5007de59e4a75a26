"""The C++ MAVSDK library acting as the autopilot lluavd flies.

MAVSDK's server plugins answer the MAVLink protocols (heartbeat, commands,
mission upload, parameters, telemetry); this module adds what they lack:
a kinematic model (MAVSDK has no physics), NAV_LAND / RETURN_TO_LAUNCH /
MISSION_START (not handled by ActionServer: taken with MavlinkDirectServer,
acknowledged here) and a record of everything lluavd sent, for the tests.

Quirks worked around (measured, see shared/notes/mavsdk-test-peer.md):
set_armed_state is never called from inside the arm callback; PARAM_SET
must target component 1; HOME_POSITION.altitude is pre-scaled by 1e6.
"""

import json
import logging
import math
import threading
import time

from mavsdk import ComponentType, Configuration, LogLevel, Mavsdk, log_subscribe
from mavsdk.plugins.action_server.action_server import (
    ActionServer,
    ActionServerResult,
    AllowableFlightModes,
    FlightMode,
)
from mavsdk.plugins.mavlink_direct_server.mavlink_direct_server import (
    MavlinkDirectServer,
    MavlinkMessage,
)
from mavsdk.plugins.mission_raw_server.mission_raw_server import MissionRawServer, MissionRawServerResult
from mavsdk.plugins.param_server.param_server import ParamServer
from mavsdk.plugins.telemetry_server.telemetry_server import (
    AngularVelocityBody,
    Battery,
    EulerAngle,
    Heading,
    LandedState,
    Position,
    PositionNed,
    PositionVelocityNed,
    TelemetryServer,
    VelocityNed,
    VtolState,
)

import geo

log = logging.getLogger("mavsdk")


def _route_log(level, message, file, line):
    """MAVSDK's own log into Python's (pytest shows it for failed tests)."""
    py_level = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO,
                LogLevel.WARN: logging.WARNING}.get(level, logging.ERROR)
    log.log(py_level, "%s (%s:%s)", message, file, line)
    return True


log_subscribe(_route_log)

HOME = (47.397742, 8.545594, 488.0)
TAKEOFF_CLIMB = 1.5  # m/s
CRUISE = 3.0  # m/s
RATE_HZ = 50
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_MISSION_START = 300
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
# The model's modes as the heartbeat reports them.
HEARTBEAT_MODES = {"ready": FlightMode.READY, "takeoff": FlightMode.TAKEOFF, "hold": FlightMode.HOLD,
                   "offboard": FlightMode.OFFBOARD, "land": FlightMode.LAND, "landed": FlightMode.LAND,
                   "rtl": FlightMode.RETURN_TO_LAUNCH, "mission": FlightMode.MISSION}
FLOAT_PARAMS = {"MPC_XY_VEL_MAX": 12.0, "MIS_TAKEOFF_ALT": 2.5}
INT_PARAMS = {"SYS_AUTOSTART": 4001, "COM_RC_LOSS_T": -7}


class MavsdkAutopilot:
    """An autopilot on `udpout://127.0.0.1:port` with a kinematic model,
    as MAVLink system `system_id`.

    Everything lluavd sent is recorded: `commands` (COMMAND_LONG fields as
    dicts, in order), `setpoints` ((monotonic time, fields) per
    SET_POSITION_TARGET_LOCAL_NED), `missions` (the uploaded item lists),
    `clears` (MISSION_CLEAR_ALLs obeyed). `holding` is the mission it holds.
    Its ATTITUDE carries the time since it started, as a flight
    controller's boot time (a new instance is a rebooted autopilot).
    """

    def __init__(self, port, system_id=1):
        self.lock = threading.Lock()
        self.commands = []
        self.setpoints = []
        self.missions = []
        self.clears = 0
        self.failed_uploads = []
        self.holding = []
        self.mode_changes = []
        self.booted = time.monotonic()
        self.armed = False
        self.mode = "ready"
        self.pos = [0.0, 0.0, 0.0]
        self.vel = [0.0, 0.0, 0.0]
        self.yaw = 0.0
        self.takeoff_alt = 2.5
        self.mission_targets = []
        self._keep = []
        self._stop = threading.Event()

        config = Configuration.create_with_component_type(ComponentType.AUTOPILOT)
        config.system_id = system_id
        self.mavsdk = Mavsdk(config)
        self.connection = self.mavsdk.add_any_connection_with_handle(f"udpout://127.0.0.1:{port}")
        sc = self.mavsdk.server_component()
        self.action = ActionServer(sc)
        self.telemetry = TelemetryServer(sc)
        self.params = ParamServer(sc)
        self.mission = MissionRawServer(sc)
        self.direct = MavlinkDirectServer(sc)
        self._setup()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _setup(self):
        self.action.set_armable(True, True)
        self.action.set_disarmable(True, True)
        self.action.set_allow_takeoff(True)
        self.action.set_allowable_flight_modes(
            AllowableFlightModes(True, True, True, True, True, True, True)
        )
        for name, value in FLOAT_PARAMS.items():
            self.params.provide_param_float(name, value)
        for name, value in INT_PARAMS.items():
            self.params.provide_param_int(name, value)
        self.action.subscribe_arm_disarm(self._on_arm)
        self.action.subscribe_takeoff(self._on_takeoff)
        self.action.subscribe_flight_mode_change(self._on_mode)
        self.mission.subscribe_incoming_mission(self._on_mission)
        self.mission.subscribe_clear_all(self._on_clear_all)
        self.direct.subscribe_message("COMMAND_LONG", self._on_command_long)
        self.direct.subscribe_message("SET_POSITION_TARGET_LOCAL_NED", self._on_setpoint)
        for cmd in (MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_MISSION_START):
            self.direct.subscribe_command(cmd, self._on_direct_command)

    # --- what lluavd sends ---------------------------------------------

    def _on_command_long(self, msg, _ud):
        with self.lock:
            self.commands.append(json.loads(msg.fields_json))

    def _on_setpoint(self, msg, _ud):
        with self.lock:
            self.setpoints.append((time.monotonic(), json.loads(msg.fields_json)))

    def _on_arm(self, result, arm_disarm, _ud):
        if result == ActionServerResult.SUCCESS:
            with self.lock:
                self.armed = bool(arm_disarm.arm)
                if not self.armed:
                    self.mode = "ready"
                    self.vel = [0.0, 0.0, 0.0]

    def _on_takeoff(self, result, _takeoff, _ud):
        if result == ActionServerResult.SUCCESS:
            with self.lock:
                taken = [c for c in self.commands if c.get("command") == 22]
                if taken and not math.isnan(taken[-1]["param7"]):
                    self.takeoff_alt = taken[-1]["param7"] - HOME[2]
                self.mode = "takeoff"

    def _on_mode(self, result, mode, _ud):
        with self.lock:
            self.mode_changes.append((result, mode))
            if result == ActionServerResult.SUCCESS and mode == FlightMode.OFFBOARD:
                self.mode = "offboard"

    def _on_mission(self, result, plan, _ud):
        if result != MissionRawServerResult.SUCCESS:
            with self.lock:
                self.failed_uploads.append(result)
            return
        with self.lock:
            self.missions.append(list(plan.mission_items))
            self.holding = self.missions[-1]

    def _on_clear_all(self, _clear_type, _ud):
        with self.lock:
            self.clears += 1
            self.holding = []

    def _on_direct_command(self, msg, _ud):
        fields = json.loads(msg.fields_json)
        cmd = fields["command"]
        result = MAV_RESULT_ACCEPTED
        with self.lock:
            if not self.armed:
                # As PX4: no landing, return or mission on the ground.
                result = MAV_RESULT_DENIED
            elif cmd == MAV_CMD_NAV_LAND and self.mode != "landed":
                self.mode = "land"
            elif cmd == MAV_CMD_NAV_RETURN_TO_LAUNCH and self.mode not in ("land", "landed"):
                self.mode = "rtl"
            elif cmd == MAV_CMD_MISSION_START and self.holding and self.mode != "mission":
                # A repeated MISSION_START (its ack lost) does not restart the mission.
                self.mission_targets = [
                    geo.ned_from(HOME, it.x * 1e-7, it.y * 1e-7, it.z) for it in self.holding
                ]
                self.mode = "mission"
        ack = {"command": cmd, "result": result, "progress": 0,
               "result_param2": 0, "target_system": msg.system_id,
               "target_component": msg.component_id}
        self.direct.send_message(MavlinkMessage(
            "COMMAND_ACK", 1, 1, msg.system_id, msg.component_id, json.dumps(ack)))

    # --- the kinematic model -------------------------------------------

    def _step(self, dt):
        """Moves the vehicle by one step of its current mode; returns the
        landed state and whether the mission item was just completed."""
        target, speed, completed = None, CRUISE, False
        if self.mode == "takeoff":
            target, speed = [self.pos[0], self.pos[1], -self.takeoff_alt], TAKEOFF_CLIMB
        elif self.mode == "offboard" and self.setpoints:
            sp = self.setpoints[-1][1]
            target = [sp["x"], sp["y"], sp["z"]]
            self.yaw = sp["yaw"]
        elif self.mode == "land":
            target, speed = [self.pos[0], self.pos[1], 0.0], TAKEOFF_CLIMB
        elif self.mode == "rtl":
            target = [0.0, 0.0, self.pos[2]] if math.hypot(*self.pos[:2]) > 0.2 else [0.0, 0.0, 0.0]
        elif self.mode == "mission" and self.mission_targets:
            target = self.mission_targets[0]
        if target is None:
            self.vel = [0.0, 0.0, 0.0]
        else:
            d = [t - p for t, p in zip(target, self.pos)]
            dist = math.sqrt(sum(x * x for x in d))
            step = min(dist, speed * dt)
            self.vel = [x / dist * speed if dist > 1e-6 else 0.0 for x in d]
            self.pos = [p + (x / dist * step if dist > 1e-6 else 0.0) for p, x in zip(self.pos, d)]
            if dist - step < 0.05:
                self.vel = [0.0, 0.0, 0.0]
                if self.mode == "takeoff":
                    self.mode = "hold"
                elif self.mode == "mission":
                    self.mission_targets.pop(0)
                    completed = True
                    if not self.mission_targets:
                        self.mode = "hold"
                elif self.mode in ("land", "rtl") and self.pos[2] > -0.05:
                    self.mode = "landed"
        on_ground = self.pos[2] > -0.1
        if not self.armed:
            landed = LandedState.ON_GROUND
        elif self.mode == "takeoff":
            landed = LandedState.TAKING_OFF
        elif self.mode == "land":
            landed = LandedState.LANDING
        else:
            landed = LandedState.ON_GROUND if on_ground else LandedState.IN_AIR
        return landed, completed

    def _publish(self, landed, tick):
        lat, lon, alt = geo.global_from(HOME, *self.pos)
        t = self.telemetry
        t.publish_position_velocity_ned(PositionVelocityNed(
            PositionNed(*self.pos), VelocityNed(*self.vel)))
        t.publish_position(Position(lat, lon, alt, -self.pos[2]), VelocityNed(*self.vel),
                           Heading(math.degrees(self.yaw) % 360))
        boot_us = int((time.monotonic() - self.booted) * 1e6)
        t.publish_attitude(EulerAngle(0.0, 0.0, math.degrees(self.yaw), boot_us),
                           AngularVelocityBody(0.0, 0.0, 0.0))
        t.publish_extended_sys_state(VtolState.MC, landed)
        if tick % RATE_HZ == 0:
            # MAVSDK packs HOME_POSITION.altitude as metres x 1e-3: pre-scale.
            t.publish_home(Position(HOME[0], HOME[1], HOME[2] * 1e6, 0.0))
            # MAVSDK scales remaining_percent by 100 into an int8: give a fraction.
            t.publish_battery(Battery(16.2, 0.87))

    def _run(self):
        tick = 0
        last = time.monotonic()
        reported = None
        while not self._stop.is_set():
            now = time.monotonic()
            with self.lock:
                landed, completed = self._step(now - last)
                disarm = self.mode == "landed" and self.armed
                mode = self.mode
            last = now
            if mode != reported:
                # The heartbeat says the mode the model flies in, as PX4's does
                # (from this thread: MAVSDK calls back on its own).
                self.action.set_flight_mode(HEARTBEAT_MODES.get(mode, FlightMode.HOLD))
                reported = mode
            if completed:
                self.mission.set_current_item_complete()
            if disarm:
                # Outside the arm callback: PX4 disarms after landing too.
                self.action.set_armed_state(False)
                with self.lock:
                    self.armed, self.mode = False, "ready"
            self._publish(landed, tick)
            tick += 1
            time.sleep(max(0.0, 1.0 / RATE_HZ - (time.monotonic() - now)))

    # --- for the tests -------------------------------------------------

    def commands_named(self, command):
        with self.lock:
            return [c for c in self.commands if c["command"] == command]

    def position(self):
        with self.lock:
            return list(self.pos)

    def param_float(self, name):
        return self.params.retrieve_param_float(name)

    def param_int(self, name):
        return self.params.retrieve_param_int(name)

    def go_silent(self):
        """Drops the link: the connection is removed, nothing more is sent."""
        self._stop.set()
        self.thread.join()
        self.mavsdk.remove_connection(self.connection)

    def close(self):
        self._stop.set()
        self.thread.join()
        self.mavsdk.destroy()
