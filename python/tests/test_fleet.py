"""lluav.Fleet and lluav.AsyncFleet against real lluavd vehicles through a
real broker (Mosquitto), over MQTT 5: the same methods, argument checks and
errors as lluav.Client, the fleet's listing, offline vehicles, several
vehicles at once, broker credentials, mqtts://, the README's broker config
and ACL (an operator's client id is its user name), and JSON with a member
named twice."""

from __future__ import annotations

import asyncio
import inspect
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Callable

import paho.mqtt.client as mqtt
import pytest
from broker import Mosquitto, free_port
from conftest import ROOT
from test_tls import self_signed
from values import INVALID, call_args

import lluav

PASSWORD = "s3cret"


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Callable[..., Mosquitto]]:
    """Starts brokers: `broker(users=None, tls=None)`."""
    started: list[Mosquitto] = []

    def start(**kwargs) -> Mosquitto:
        b = Mosquitto(tmp_path / f"broker{len(started)}", **kwargs)
        started.append(b)
        return b

    yield start
    for b in started:
        b.stop()


# With an uplink lluavd refuses the spec's public admin value unless told
# to allow it; these vehicles never need admin.
ADMIN = "--allow-default-admin"


def vehicle(lluavd, broker: Mosquitto, vid: str, *flags: str, password: str | None = PASSWORD):
    """lluavd on `broker` as vehicle `vid`, once its status says online."""
    daemon = lluavd("--uplink", broker.url, "--vehicle-id", vid, ADMIN, *flags, password=password)
    deadline = time.monotonic() + 30
    with lluav.Fleet(broker.url, timeout=5) as f:
        while f.vehicles().get(vid, {}).get("online") is not True:
            assert time.monotonic() < deadline, daemon.stderr()
            time.sleep(0.05)
    return daemon


def test_a_fleet_vehicle_has_the_clients_methods_signatures_and_docs():
    for spec in lluav.COMMANDS:
        for fleet_cls, client_cls in [(lluav.FleetVehicle, lluav.Client), (lluav.AsyncFleetVehicle, lluav.AsyncClient)]:
            ours, theirs = getattr(fleet_cls, spec.name), getattr(client_cls, spec.name)
            assert inspect.signature(ours) == inspect.signature(theirs), spec.name
            assert ours.__doc__ == theirs.__doc__
            assert inspect.iscoroutinefunction(ours) == inspect.iscoroutinefunction(theirs)


def test_invalid_arguments_of_every_grammar_are_refused_before_sending(broker):
    b = broker()
    # Nothing listens for "nobody": anything sent would end in a timeout.
    with lluav.Fleet(b.url, timeout=0.2) as f:
        v = f.vehicle("nobody")
        for spec in lluav.COMMANDS:
            for entry in INVALID[spec.grammar]:
                args, kwargs = call_args(entry)
                with pytest.raises(lluav.InvalidArguments) as caught:
                    getattr(v, spec.name)(*args, **kwargs)
                assert caught.value.usage == spec.usage
        with pytest.raises(ValueError):
            f.vehicle("a/b")

    async def run() -> None:
        async with lluav.AsyncFleet(b.url, timeout=0.2) as f:
            v = await f.vehicle("nobody")
            with pytest.raises(lluav.InvalidArguments):
                await v.set_sp_ned(1.0, 2.0, float("nan"), 0.0)

    asyncio.run(run())


def test_answers_and_errors_are_the_clients(lluavd, broker):
    b = broker()
    daemon = vehicle(lluavd, b, "v1")
    with lluav.Fleet(b.url) as f, lluav.Client(daemon.url) as c:
        v = f.vehicle("v1")
        for call in [lambda x: x.state(), lambda x: x.call("bogus 1"), lambda x: x.login("wrong")]:
            with pytest.raises(lluav.CommandError) as over_mqtt:
                call(v)
            with pytest.raises(lluav.CommandError) as over_ws:
                call(c)
            assert (over_mqtt.value.ret, over_mqtt.value.cmd, over_mqtt.value.msg) == (
                over_ws.value.ret,
                over_ws.value.cmd,
                over_ws.value.msg,
            )
        assert v.login(PASSWORD)["logged_in"] is True
        c.login(PASSWORD)
        strip = lambda r: {k: x for k, x in r.items() if k != "ts"}  # noqa: E731
        assert strip(v.help()) == strip(c.help())
        assert strip(v.get_param("takeoff_alt")) == strip(c.get_param("takeoff_alt"))
        assert v.state()["state"]["uplink"] == "up"
        with pytest.raises(lluav.CommandError, match="Vehicle is not flying"):
            v.land()
        # Another fleet is another client id: another session.
        with lluav.Fleet(b.url) as other:
            with pytest.raises(lluav.CommandError, match="Login first!"):
                other.vehicle("v1").state()
            with pytest.raises(lluav.CommandError, match="Wrong password!"):
                other.vehicle("v1", password="wrong")
            assert other.vehicle("v1", password=PASSWORD).ver()["cmd"] == 5


def test_the_listing_shows_online_and_offline_vehicles_with_their_state(lluavd, broker):
    b = broker()
    vehicle(lluavd, b, "up1")
    gone = vehicle(lluavd, b, "gone")
    assert gone.stop() == 0
    with lluav.Fleet(b.url) as f:
        listing = f.vehicles()
        assert listing["up1"]["online"] is True and listing["gone"]["online"] is False
        for v in ["up1", "gone"]:
            assert listing[v]["state"]["cmd"] == 2 and listing[v]["state"]["state"]["fsm"] == "disarmed"
            assert isinstance(listing[v]["age_s"], float) and listing[v]["age_s"] >= 0
    with lluav.Fleet(b.url, timeout=0.5) as f:
        started = time.monotonic()
        with pytest.raises(lluav.ConnectionError, match="vehicle gone is offline"):
            f.vehicle("gone").state()
        assert time.monotonic() - started >= 0.5
        # The connection is still good.
        assert f.vehicle("up1", password=PASSWORD).state()["ret"] == 0


def test_a_request_lost_with_the_link_is_never_sent_after_a_reconnection(lluavd, broker):
    """A request whose PUBACK never came fails for its caller, and the fleet
    does not send it again once it is back: the vehicle would run it late,
    with nobody waiting for it."""
    b = broker()
    vehicle(lluavd, b, "v1")
    with lluav.Fleet(b.url, timeout=1) as f:
        v = f.vehicle("v1", password=PASSWORD)
        # Frozen: TCP takes the request, the broker never acknowledges it.
        b.proc.send_signal(signal.SIGSTOP)
        with pytest.raises(lluav.ConnectionError, match="v1 did not answer"):
            v.siyi_sync()
        b.proc.kill()
        b.proc.wait()
        again = broker(port=b.port)
        # Subscribed before the fleet can be back (paho waits 1 s at least).
        seen: list[str] = []
        granted = threading.Event()
        spy = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="spy")
        spy.on_message = lambda _c, _u, m: seen.append(json.loads(m.payload)["frame"])
        spy.on_subscribe = lambda *_: granted.set()
        spy.connect("127.0.0.1", again.port)
        spy.subscribe("lluav/+/req/#", qos=1)
        spy.loop_start()
        try:
            assert granted.wait(5)
            deadline = time.monotonic() + 30
            while True:
                try:
                    assert v.ver()["ret"] == 0
                    break
                except lluav.ConnectionError:
                    assert time.monotonic() < deadline, "the fleet never came back"
                    time.sleep(0.1)
            time.sleep(0.2)
            assert "siyi_sync" not in seen, seen
            assert v.siyi_sync()["siyi"]["syncs"] == 1, "the lost request never ran"
        finally:
            spy.loop_stop()
            spy.disconnect()


def test_async_fleet_commands_three_vehicles_at_once(lluavd, broker):
    b = broker()
    for vid in ["a1", "a2", "a3"]:
        vehicle(lluavd, b, vid)

    async def run() -> None:
        async with lluav.AsyncFleet(b.url) as f:
            vs = await asyncio.gather(*[f.vehicle(vid, password=PASSWORD) for vid in ["a1", "a2", "a3"]])
            answers = await asyncio.gather(*[v.siyi_sync() for v in vs for _ in range(10)])
            assert [a["siyi"]["syncs"] for a in answers[:10]] == list(range(1, 11)), "in order, each once"
            assert sorted(a["siyi"]["syncs"] for a in answers) == sorted(list(range(1, 11)) * 3)
            listing = await f.vehicles()
            assert {vid for vid, v in listing.items() if v["online"]} == {"a1", "a2", "a3"}
            await vs[0].takeoff()
            with pytest.raises(lluav.CommandError, match="Not allow when vehicle is ARMED!"):
                await vs[0].reboot_node()
        with pytest.raises(lluav.ConnectionError, match="not connected"):
            await vs[0].state()

    asyncio.run(run())


def test_broker_credentials_and_unreachable_brokers(lluavd, broker):
    b = broker(users={"drone-c1": "fly-s4fe", "ops": "0ps-pw"})
    # The vehicle's id is its broker user name.
    daemon = lluavd(
        "--uplink",
        b.url,
        "--uplink-user",
        "drone-c1",
        "--uplink-password",
        "fly-s4fe",
        ADMIN,
        password=PASSWORD,
    )
    with pytest.raises(lluav.ConnectionError, match="cannot connect to the broker"):
        lluav.Fleet(b.url, username="ops", password="wrong", timeout=5)
    with pytest.raises(ValueError, match="user name"):
        lluav.Fleet(b.url, username="ops.1", password="0ps-pw")
    with lluav.Fleet(b.url, username="ops", password="0ps-pw") as f:
        assert f.client_id == "ops", "the account is the identity"
        deadline = time.monotonic() + 30
        while f.vehicles().get("drone-c1", {}).get("online") is not True:
            assert time.monotonic() < deadline, daemon.stderr()
            time.sleep(0.05)
        assert f.vehicle("drone-c1", password=PASSWORD).ver()["ret"] == 0
    # Nothing listens on a port just found free.
    with pytest.raises(lluav.ConnectionError, match="cannot connect to the broker"):
        lluav.Fleet(f"mqtt://127.0.0.1:{free_port()}", timeout=2)
    with pytest.raises(ValueError):
        lluav.Fleet("http://127.0.0.1:1883")


def test_mqtts_with_a_ca_file(lluavd, broker, tmp_path):
    cert, key = self_signed(tmp_path)
    b = broker(tls=(cert, key))
    daemon = lluavd("--uplink", b.url, "--uplink-cafile", str(cert), "--vehicle-id", "t1", ADMIN, password=PASSWORD)
    with lluav.Fleet(b.url, cafile=str(cert)) as f:
        deadline = time.monotonic() + 30
        while f.vehicles().get("t1", {}).get("online") is not True:
            assert time.monotonic() < deadline, daemon.stderr()
            time.sleep(0.05)
        assert f.vehicle("t1", password=PASSWORD).state()["state"]["uplink"] == "up"
    with pytest.raises(lluav.ConnectionError, match="cannot connect to the broker"):
        lluav.Fleet(b.url, timeout=5)
    with pytest.raises(ValueError, match="cafile is for mqtts://"):
        lluav.Fleet("mqtt://127.0.0.1:1", cafile=str(cert))


def test_the_readme_broker_config_with_an_account_per_operator(lluavd, broker, tmp_path):
    cert, key = self_signed(tmp_path)
    users = {"alice": "a-pw", "bob": "b-pw", "drone-1": "d-pw"}
    b = broker(users=users, tls=(cert, key), recommended=True)
    daemon = lluavd(
        "--uplink",
        b.url,
        "--uplink-cafile",
        str(cert),
        "--uplink-user",
        "drone-1",
        "--uplink-password",
        "d-pw",
        ADMIN,
        password=PASSWORD,
    )
    with lluav.Fleet(b.url, username="alice", password="a-pw", cafile=str(cert)) as f:
        assert f.client_id == "alice"
        deadline = time.monotonic() + 30
        while f.vehicles().get("drone-1", {}).get("online") is not True:
            assert time.monotonic() < deadline, daemon.stderr()
            time.sleep(0.05)
        v = f.vehicle("drone-1", password=PASSWORD)
        assert v.siyi_sync()["siyi"]["syncs"] == 1

        async def bob() -> int:
            async with lluav.AsyncFleet(b.url, username="bob", password="b-pw", cafile=str(cert)) as af:
                assert af.client_id == "bob"
                bv = await af.vehicle("drone-1", password=PASSWORD)
                return (await bv.siyi_sync())["siyi"]["syncs"]

        # Another account is another session, each as itself.
        assert asyncio.run(bob()) == 2
        assert v.siyi_sync()["siyi"]["syncs"] == 3
    # An operator whose client id is not its user name is refused by the
    # ACL: nothing it sends reaches the vehicle.
    with lluav.Fleet(b.url, client_id="alice2", username="alice", password="a-pw", cafile=str(cert), timeout=1) as f:
        with pytest.raises(lluav.ConnectionError, match="did not answer"):
            f.vehicle("drone-1").siyi_sync()


def test_members_named_twice_are_not_read(lluavd, broker):
    b = broker()
    vehicle(lluavd, b, "real")
    forger = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="forger")
    forger.connect("127.0.0.1", b.port)
    forger.loop_start()
    try:
        status = '{"vehicle":"twice","online":false,"online":true}'
        forger.publish("lluav/twice/status", status, qos=1, retain=True).wait_for_publish(5)
        state = '{"ret":0,"cmd":2,"ts":1,"state":{"fsm":"disarmed","fsm":"hover"}}'
        forger.publish("lluav/twice/state", state, qos=1, retain=True).wait_for_publish(5)
    finally:
        forger.loop_stop()
        forger.disconnect()
    with lluav.Fleet(b.url) as f:
        listing = f.vehicles()
        assert listing["real"]["online"] is True
        assert "twice" not in listing, listing


def test_the_readme_fleet_script_runs(lluavd, broker):
    readme = (ROOT / "README.md").read_text()
    section = readme.split("\n## Fleets and vehicles behind NAT\n", 1)[1].split("\n## ", 1)[0]
    [script] = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    b = broker()
    vehicle(lluavd, b, "r1")
    vehicle(lluavd, b, "r2")
    env = dict(os.environ, LLUAV_BROKER=b.url, LLUAV_PASSWORD=PASSWORD)
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [
        "r1 online disarmed",
        "r2 online disarmed",
        "up",
        "-1 Vehicle is not flying",
        "simulator",
        "simulator",
    ]
