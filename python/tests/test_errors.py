"""Errors: gates and unknown commands (CommandError), login, invalid
arguments caught before sending, and connection faults."""

from __future__ import annotations

import asyncio
import json
import socket
import time

import pytest
from fakeserver import FakeServer, ok_reply, serving
from values import INVALID, call_args

import lluav


def test_login_is_required_when_the_daemon_has_a_password(lluavd):
    daemon = lluavd(password="s3cret")
    with lluav.Client(daemon.url) as c:
        with pytest.raises(lluav.CommandError) as caught:
            c.state()
        assert (caught.value.ret, caught.value.cmd, caught.value.msg) == (-1, 2, "Login first!")
        assert c.login("s3cret")["logged_in"] is True
        assert c.state()["state"]["armed"] is False
    with lluav.Client(daemon.url, password="s3cret") as c:
        assert c.state()["ret"] == 0


def test_a_wrong_password_fails_the_connect_and_closes_the_client(lluavd):
    daemon = lluavd(password="s3cret")
    with pytest.raises(lluav.CommandError) as caught:
        lluav.Client(daemon.url, password="wrong")
    assert (caught.value.ret, caught.value.msg) == (-1, "Wrong password!")
    assert str(caught.value) == "login failed with ret -1: Wrong password!"

    async def connect() -> lluav.AsyncClient:
        c = lluav.AsyncClient(daemon.url, password="wrong")
        with pytest.raises(lluav.CommandError, match="Wrong password!"):
            await c.connect()
        return c

    assert asyncio.run(connect()).closed


def test_gates_refuse_with_command_errors(lluavd):
    daemon = lluavd(password="s3cret", sim_speed=20)
    with lluav.Client(daemon.url, password="s3cret") as user, lluav.Client(daemon.url, password="1025") as admin:
        with pytest.raises(lluav.CommandError) as caught:
            user.admin_lock()
        assert (caught.value.ret, caught.value.cmd, caught.value.msg) == (-1, 98, "Admin only!")

        admin.admin_lock()
        with pytest.raises(lluav.CommandError) as caught:
            user.set_param("takeoff_alt", 3.0)
        assert (caught.value.ret, caught.value.cmd, caught.value.msg) == (
            -1,
            63,
            "CMD not permitted to run in LOCK mode!",
        )
        assert admin.set_param("takeoff_alt", 3.0)["ret"] == 0
        admin.admin_unlock()

        user.takeoff()
        with pytest.raises(lluav.CommandError) as caught:
            user.reboot_node()
        assert (caught.value.ret, caught.value.cmd, caught.value.msg) == (-1, 69, "Not allow when vehicle is ARMED!")
        user.land()


def test_unknown_commands_and_bad_frames_sent_with_call_are_command_errors(lluavd):
    daemon = lluavd()
    with lluav.Client(daemon.url) as c:
        with pytest.raises(lluav.CommandError) as caught:
            c.call("nosuch 1 2")
        assert (caught.value.ret, caught.value.cmd, caught.value.msg) == (-2, 0, "Unsupported command: nosuch")
        with pytest.raises(lluav.CommandError) as caught:
            c.call("set_sp_ned 1:2")
        assert (caught.value.ret, caught.value.cmd) == (-2, 23)
        assert caught.value.msg == "Invalid arguments, usage: set_sp_ned x:y:z:yaw"
        with pytest.raises(lluav.CommandError, match="Empty command"):
            c.call("")
        assert c.call("set_taskname a b")["taskname"] == "a b"
        with pytest.raises(TypeError):
            c.call(b"state")  # type: ignore[arg-type]


def test_invalid_arguments_of_every_grammar_are_refused_before_anything_is_sent():
    with serving() as server:
        with lluav.Client(server.url) as c:
            for spec in lluav.COMMANDS:
                for entry in INVALID[spec.grammar]:
                    args, kwargs = call_args(entry)
                    with pytest.raises(lluav.InvalidArguments) as caught:
                        getattr(c, spec.name)(*args, **kwargs)
                    assert caught.value.usage == spec.usage
            assert server.frames == []
            assert c.state()["cmd"] == 2
            assert server.frames == ["state"]


def test_invalid_arguments_leave_a_live_connection_usable(lluavd):
    daemon = lluavd()

    async def run() -> None:
        async with lluav.AsyncClient(daemon.url) as c:
            with pytest.raises(lluav.InvalidArguments, match="usage: set_sp_ned x:y:z:yaw"):
                await c.set_sp_ned(1.0, 2.0, float("nan"), 0.0)
            assert (await c.show_sp())["cmd"] == 15

    asyncio.run(run())
    with lluav.Client(daemon.url) as c:
        with pytest.raises(lluav.InvalidArguments):
            c.mw_exec(1001, [])
        assert c.state()["cmd"] == 2


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_server_is_a_connection_error():
    url = f"ws://127.0.0.1:{free_port()}"
    with pytest.raises(lluav.ConnectionError, match="cannot connect"):
        lluav.Client(url, timeout=2)
    with pytest.raises(lluav.ConnectionError, match="cannot connect"):
        asyncio.run(lluav.AsyncClient(url, timeout=2).connect())
    assert issubclass(lluav.ConnectionError, ConnectionError) and issubclass(lluav.ConnectionError, lluav.Error)


def test_a_server_that_never_completes_the_handshake_times_out_as_a_connection_error():
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        url = f"ws://127.0.0.1:{listener.getsockname()[1]}"
        start = time.monotonic()
        with pytest.raises(lluav.ConnectionError, match="cannot connect"):
            lluav.Client(url, timeout=0.3)
        with pytest.raises(lluav.ConnectionError, match="cannot connect"):
            asyncio.run(lluav.AsyncClient(url, timeout=0.3).connect())
        assert time.monotonic() - start < 5


def test_a_stopped_daemon_fails_calls_with_connection_errors(lluavd):
    daemon = lluavd()
    c = lluav.Client(daemon.url)
    assert c.state()["ret"] == 0
    assert daemon.stop() == 0
    with pytest.raises(lluav.ConnectionError):
        c.state()
    assert c.closed
    with pytest.raises(lluav.ConnectionError):
        c.state()


def test_a_stopped_daemon_fails_async_calls_with_connection_errors(lluavd):
    daemon = lluavd()

    async def run() -> None:
        c = await lluav.AsyncClient(daemon.url).connect()
        assert (await c.state())["ret"] == 0
        assert daemon.stop() == 0
        with pytest.raises(lluav.ConnectionError):
            await c.state()
        assert c.closed
        await c.close()

    asyncio.run(run())


def test_calls_before_connect_and_after_close_are_connection_errors(lluavd):
    daemon = lluavd()

    async def run() -> None:
        c = lluav.AsyncClient(daemon.url)
        with pytest.raises(lluav.ConnectionError, match="not connected"):
            await c.state()
        async with c:
            assert not c.closed
        with pytest.raises(lluav.ConnectionError, match="closed"):
            await c.state()

    asyncio.run(run())
    c = lluav.Client(daemon.url)
    c.close()
    c.close()
    with pytest.raises(lluav.ConnectionError, match="closed"):
        c.state()


def silent(frame: str) -> None:
    return None


def test_a_response_that_does_not_come_in_time_closes_the_connection():
    with serving(silent) as server:
        c = lluav.Client(server.url, timeout=0.3)
        start = time.monotonic()
        with pytest.raises(lluav.ConnectionError, match="no response within 0.3 s"):
            c.state()
        assert time.monotonic() - start < 5
        assert c.closed

        async def run() -> None:
            c = await lluav.AsyncClient(server.url, timeout=0.3).connect()
            calls = [asyncio.ensure_future(c.state()) for _ in range(3)]
            for call in calls:
                with pytest.raises(lluav.ConnectionError, match="no response within 0.3 s"):
                    await call
            assert c.closed
            await c.close()

        asyncio.run(run())


@pytest.mark.parametrize(
    "reply, message",
    [
        (lambda frame: b"\x00binary", "binary message"),
        (lambda frame: "not json", "not JSON"),
        (lambda frame: "[1, 2]", "not a protocol response"),
        (lambda frame: json.dumps({"ret": 0, "cmd": 3, "ts": 0}), "no longer pair up"),
    ],
    ids=["binary", "not-json", "not-an-object", "another-command"],
)
def test_a_reply_that_is_not_a_response_to_the_request_is_a_connection_error(reply, message):
    server = FakeServer(reply)
    try:
        with lluav.Client(server.url) as c:
            with pytest.raises(lluav.ConnectionError, match=message):
                c.state()
            assert c.closed

        async def run() -> None:
            async with lluav.AsyncClient(server.url) as c:
                with pytest.raises(lluav.ConnectionError, match=message):
                    await c.state()
                assert c.closed

        asyncio.run(run())
    finally:
        server.close()


def test_cafile_is_refused_for_a_plain_ws_url():
    with pytest.raises(ValueError, match="wss://"):
        lluav.Client("ws://127.0.0.1:1", cafile="ca.pem")
    with pytest.raises(ValueError, match="wss://"):
        lluav.AsyncClient("ws://127.0.0.1:1", cafile="ca.pem")


def test_closing_fails_the_calls_in_flight_and_a_dropped_client_can_connect_again():
    def garbage_for_ver(frame: str) -> str | None:
        if frame == "ping_me_never":
            return None
        return "garbage" if frame == "ver" else ok_reply(frame)

    with serving(garbage_for_ver) as server:

        async def run() -> None:
            c = await lluav.AsyncClient(server.url).connect()
            hanging = [asyncio.ensure_future(c.call("ping_me_never")) for _ in range(5)]
            await asyncio.sleep(0.05)
            await c.close()
            for call in hanging:
                with pytest.raises(lluav.ConnectionError, match="the client is closed"):
                    await call

            await c.connect()
            with pytest.raises(lluav.ConnectionError, match="not JSON"):
                await c.ver()
            assert c.closed
            await c.connect()
            assert (await c.state())["cmd"] == 2
            await c.close()

        asyncio.run(run())
