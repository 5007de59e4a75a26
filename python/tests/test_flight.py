"""Whole flights on the simulator (sped up 20 times): takeoff, setpoints,
missions (JSON and a file) flown by waypoint ids, zyhk, landing."""

from __future__ import annotations

import asyncio
import json
import math
import time
from typing import Any, Callable

import lluav

SIM_SPEED = 20
WAIT_S = 30.0


def wait_for(state: Callable[[], dict[str, Any]], done: Callable[[dict[str, Any]], bool], what: str) -> dict[str, Any]:
    deadline = time.monotonic() + WAIT_S
    while True:
        s = state()["state"]
        if done(s):
            return s
        assert time.monotonic() < deadline, f"still waiting for {what}: {s}"
        time.sleep(0.02)


def near(s: dict[str, Any], x: float, y: float, z: float, tolerance: float = 0.35) -> bool:
    p = s["position"]
    return math.dist((p["x"], p["y"], p["z"]), (x, y, z)) <= tolerance


def test_a_flight_with_setpoints_a_mission_and_a_landing(lluavd):
    daemon = lluavd(password="s3cret", sim_speed=SIM_SPEED)
    with lluav.Client(daemon.url, password="s3cret") as c:
        assert c.state()["state"]["fsm"] == "disarmed"
        c.set_param("takeoff_alt", 3.0)
        c.takeoff()
        wait_for(c.state, lambda s: s["fsm"] == "hover" and near(s, 0, 0, -3), "hover at 3 m")

        c.set_sp_ned(4.0, -2.0, -5.0, 0.5)
        s = wait_for(c.state, lambda s: near(s, 4, -2, -5), "the setpoint")
        assert s["armed"] and s["fsm"] == "hover"

        mission = {
            "waypoints": [
                {"id": 1, "x": 0, "y": 0, "z": -4},
                {"id": 2, "x": 6, "y": 0, "z": -4},
                {"id": 3, "x": 6, "y": 6, "z": -6, "yaw": 1.0},
            ]
        }
        assert c.mission(1001, mission)["waypoints"] == 3
        assert c.mw_list()["ext_id"] == 1001
        started = c.mw_exec(1001, [2, 3])
        assert (started["wp_ids"], started["fsm"]) == ([2, 3], "mission")
        wait_for(c.state, lambda s: s["fsm"] == "hover" and near(s, 6, 6, -6), "waypoint 3")

        c.land()
        s = wait_for(c.state, lambda s: s["fsm"] == "disarmed", "the landing")
        assert not s["armed"] and s["position"]["z"] >= -0.05


def test_a_mission_from_a_file_and_a_zyhk_flight_on_asyncio(lluavd):
    daemon = lluavd(sim_speed=SIM_SPEED)
    (daemon.data_dir / "missions").mkdir(exist_ok=True)
    (daemon.data_dir / "missions" / "square.json").write_text(
        json.dumps({"waypoints": [{"x": 2, "y": 0, "z": -3}, {"x": 2, "y": 2, "z": -3}]})
    )

    async def state_of(c: lluav.AsyncClient, done: Callable[[dict[str, Any]], bool], what: str) -> dict[str, Any]:
        deadline = time.monotonic() + WAIT_S
        while True:
            s = (await c.state())["state"]
            if done(s):
                return s
            assert time.monotonic() < deadline, f"still waiting for {what}: {s}"
            await asyncio.sleep(0.02)

    async def run() -> None:
        async with lluav.AsyncClient(daemon.url) as c:
            assert (await c.mission(7, "missions/square.json"))["waypoints"] == 2
            # Long enough (0.5 s of real time) to be seen at each height by
            # polling on a loaded machine.
            await c.set_param("zyhk_hover", 10.0)
            await c.takeoff()
            await state_of(c, lambda s: s["fsm"] == "hover", "hover")
            await c.mw_exec(7, [1, 2])
            await state_of(c, lambda s: s["fsm"] == "hover" and near(s, 2, 2, -3), "the last waypoint")
            await c.zyhk([1.5, 2.5], land=(1.0, 1.0, 0.0))
            await state_of(c, lambda s: near(s, 2, 2, -1.5), "the first height")
            await state_of(c, lambda s: near(s, 2, 2, -2.5), "the second height")
            s = await state_of(c, lambda s: s["fsm"] == "disarmed", "the zyhk landing")
            assert near(s, 1, 1, 0)

    asyncio.run(run())
