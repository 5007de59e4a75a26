"""Events (DESIGN.md, "Events") from the Python SDK against a real lluavd
and a real broker: Client.events(), AsyncClient.events(), Fleet.events()
and AsyncFleet.events() during a takeoff and a landing flown by another
session; a wrong password refused; close() ends the iteration."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import pytest
from test_fleet import broker, vehicle  # noqa: F401 (the fixture)

import lluav

PASSWORD = "s3cret"
SIM_SPEED = 20
WAIT_S = 30.0

# A takeoff to hover, a landing: what every follower sees, in order.
FLIGHT = [
    ("control", None),
    ("fsm", ("disarmed", "takeoff")),
    ("armed", True),
    ("fsm", ("takeoff", "hover")),
    ("fsm", ("hover", "landing")),
    ("fsm", ("landing", "armed")),
    ("fsm", ("armed", "disarmed")),
    ("armed", False),
]


def gist(e: dict[str, Any]) -> tuple[str, Any]:
    if e["event"] == "fsm":
        return ("fsm", (e["from"], e["to"]))
    if e["event"] == "armed":
        return ("armed", e["armed"])
    return (e["event"], None)


def fly(url: str) -> None:
    """Takeoff, hover, landing, flown by a session of its own."""
    with lluav.Client(url, password=PASSWORD) as c:
        c.takeoff()
        wait_fsm(c, "hover")
        c.land()
        wait_fsm(c, "disarmed")


def wait_fsm(c: lluav.Client, fsm: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while c.state()["state"]["fsm"] != fsm:
        assert time.monotonic() < deadline, f"still waiting for {fsm}"
        time.sleep(0.02)


def flight_of(events: list[dict[str, Any]]) -> list[tuple[str, Any]]:
    """The flight's events, the battery and log ones left out, with `seq`
    checked to count on one by one."""
    for a, b in zip(events, events[1:]):
        assert b["seq"] == a["seq"] + 1, (a, b)
        assert a["boot"] == b["boot"]
    return [gist(e) for e in events if e["event"] not in ("battery", "log", "uplink")]


def test_client_events_iterates_over_a_flight_in_order(lluavd):
    daemon = lluavd(password=PASSWORD, sim_speed=SIM_SPEED)
    with lluav.Client(daemon.url, password=PASSWORD) as c, c.events(timeout=WAIT_S) as events:
        fly(daemon.url)
        seen: list[dict[str, Any]] = []
        for e in events:
            assert isinstance(e, dict) and isinstance(e["ts"], int)
            seen.append(e)
            if len(flight_of(seen)) == len(FLIGHT):
                break
        assert flight_of(seen) == FLIGHT
        assert seen[0]["seq"] == 1
        events.close()
        assert list(events) == []


def test_a_wrong_password_gets_no_events(lluavd):
    daemon = lluavd(password=PASSWORD)
    with lluav.Client(daemon.url) as c:
        c._password = "wrong"
        with pytest.raises(lluav.CommandError, match="Wrong password"):
            c.events()


def test_async_client_events_iterates_over_a_flight_in_order(lluavd):
    daemon = lluavd(password=PASSWORD, sim_speed=SIM_SPEED)

    async def run() -> list[dict[str, Any]]:
        async with lluav.AsyncClient(daemon.url, password=PASSWORD) as c, c.events(timeout=WAIT_S) as events:
            flight = asyncio.get_running_loop().run_in_executor(None, fly, daemon.url)
            seen: list[dict[str, Any]] = []
            async for e in events:
                seen.append(e)
                if len(flight_of(seen)) == len(FLIGHT):
                    break
            await flight
            return seen

    assert flight_of(asyncio.run(run())) == FLIGHT


def test_fleet_events_follow_every_vehicle_or_one(lluavd, broker):  # noqa: F811
    b = broker()
    v1 = vehicle(lluavd, b, "v1", "--sim-speed", str(SIM_SPEED))
    v2 = vehicle(lluavd, b, "v2", "--sim-speed", str(SIM_SPEED))
    with lluav.Fleet(b.url, timeout=10) as f:
        every = f.events(timeout=WAIT_S)
        only_v2 = f.events("v2", timeout=WAIT_S)
        fly(v1.url)
        fly(v2.url)
        seen: dict[str, list[dict[str, Any]]] = {"v1": [], "v2": []}
        while any(len(flight_of(s)) < len(FLIGHT) for s in seen.values()):
            e = next(every)
            seen[e.pop("vehicle")].append(e)
        # v1's session closed meanwhile: its control's release may follow.
        assert {v: flight_of(s)[: len(FLIGHT)] for v, s in seen.items()} == {"v1": FLIGHT, "v2": FLIGHT}
        mine: list[dict[str, Any]] = []
        while len(flight_of(mine)) < len(FLIGHT):
            e = next(only_v2)
            assert e.pop("vehicle") == "v2"
            mine.append(e)
        assert mine[: len(seen["v2"])] == seen["v2"][: len(mine)]
    # The fleet's close ends the iteration, after what had come already
    # (here the release of v2's control, as its session closed).
    assert all(e["vehicle"] in ("v1", "v2") for e in every)


def test_async_fleet_events_follow_one_vehicle(lluavd, broker):  # noqa: F811
    b = broker()
    v1 = vehicle(lluavd, b, "v1", "--sim-speed", str(SIM_SPEED))

    async def run() -> list[dict[str, Any]]:
        async with lluav.AsyncFleet(b.url, timeout=10) as f:
            events = await f.events("v1", timeout=WAIT_S)
            flight = asyncio.get_running_loop().run_in_executor(None, fly, v1.url)
            seen: list[dict[str, Any]] = []
            async for e in events:
                assert e.pop("vehicle") == "v1"
                seen.append(e)
                if len(flight_of(seen)) == len(FLIGHT):
                    break
            await flight
            await events.close()
            return seen

    assert flight_of(asyncio.run(run())) == FLIGHT
