"""Vehicles through an MQTT broker: lluavd's uplink, for vehicles behind NAT
and for fleets.

One :class:`Fleet` is one connection to the broker with one client id, so
one session on every vehicle it talks to. It follows every vehicle's
retained ``status`` and ``state``, and sends requests in envelopes with
ids of its own: an answer is matched by its id, so a late answer is never
taken for another one's.

The MQTT side is paho-mqtt's network thread; the synchronous and asyncio
classes share it.
"""

from __future__ import annotations

import asyncio
import json
import re
import secrets
import threading
import time
from itertools import count
from types import TracebackType
from typing import Any, Callable, Optional

import paho.mqtt.client as mqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from . import _core, _methods
from ._async import _make as _make_async
from ._errors import ConnectionError
from ._events import AsyncFleetEvents, FleetEvent, FleetEvents
from ._response import check_response
from ._sync import _make as _make_sync

_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")
_URL = re.compile(r"(mqtts?)://(\[[^\]]+\]|[^:/@?#\[\]\s]+)(?::(\d+))?/?")
# Retained messages come in a burst once the subscriptions are granted:
# the first listing is complete once none came for this long (or after
# LISTING_WAIT at most).
_LISTING_QUIET = 0.15
LISTING_WAIT = 1.0
"""How long the first :meth:`Fleet.vehicles` waits for retained messages at most."""
# The largest message the fleet takes: answers are at most a response
# buffer (64 KiB); the broker drops anything larger rather than send it.
_MAX_PACKET = 1 << 20

_encode = _core.encode

# What a waiting request is handed: the response, or why there is none.
Deliver = Callable[[Any, Optional[str]], None]


def _broker(url: str) -> tuple[bool, str, int]:
    """(tls, host, port) of ``mqtt://HOST[:PORT]`` or ``mqtts://HOST[:PORT]``."""
    m = _URL.fullmatch(url) if isinstance(url, str) else None
    if m is None:
        raise ValueError(f"a broker URL is mqtt://HOST[:PORT] or mqtts://HOST[:PORT], not {url!r}")
    tls = m.group(1) == "mqtts"
    port = int(m.group(3)) if m.group(3) else (8883 if tls else 1883)
    if not 0 < port < 65536:
        raise ValueError(f"port {port} out of range in {url!r}")
    return tls, m.group(2).strip("[]"), port


def _name(kind: str, value: str) -> str:
    if not isinstance(value, str) or not _NAME.fullmatch(value):
        raise ValueError(f"a {kind} is 1-64 of [A-Za-z0-9_-], not {value!r}")
    return value


def _default_client_id(username: str | None) -> str:
    """The broker user name (the account is the identity: with the
    recommended broker config the broker makes it the client id anyway),
    else ``lluav-<random>``."""
    if username is not None:
        if not isinstance(username, str) or not _NAME.fullmatch(username):
            raise ValueError(
                f"the client id defaults to the broker user name, and {username!r} is not 1-64 of "
                "[A-Za-z0-9_-]: give client_id="
            )
        return username
    return f"lluav-{secrets.token_hex(4)}"


def _unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose members are each named once (DESIGN.md,
    "Request grammar"): which of two would be the vehicle's word?"""
    obj: dict[str, Any] = {}
    for name, value in pairs:
        if name in obj:
            raise ValueError(f"duplicate member {name!r}")
        obj[name] = value
    return obj


class _Link:
    """The broker connection: paho's network thread, the requests waiting
    for answers, and what was heard of every vehicle."""

    def __init__(
        self,
        url: str,
        client_id: str | None,
        username: str | None,
        password: str | None,
        cafile: str | None,
        timeout: float,
    ) -> None:
        tls, host, port = _broker(url)
        if cafile is not None and not tls:
            raise ValueError(f"cafile is for mqtts:// URLs, not {url!r}")
        self.client_id = _name("client id", client_id) if client_id is not None else _default_client_id(username)
        self.url = url
        self._timeout = timeout
        self._lock = threading.Lock()
        self._waiting: dict[str, Deliver] = {}
        self._heard: dict[str, dict[str, Any]] = {}
        self._down: str | None = None
        self._granted: float | None = None
        self._last_retained: float | None = None
        self._ids = count()
        self._nonce = secrets.token_hex(4)
        self._connected = threading.Event()
        self._refused: str | None = None
        # Events followers: sink id to (vehicle or None, put); the topics
        # subscribed for them; subscriptions granted, by message id.
        self._sinks: dict[int, tuple[str | None, Callable[[FleetEvent], None]]] = {}
        self._sink_ids = count()
        self._event_topics: set[str] = set()
        self._granted_mids: set[int] = set()
        self._grant = threading.Condition(self._lock)
        client = mqtt.Client(
            mqtt.CallbackAPIVersion.VERSION2,
            client_id=self.client_id,
            protocol=mqtt.MQTTv5,
        )
        if username is not None:
            client.username_pw_set(username, password)
        if tls:
            client.tls_set(ca_certs=cafile)
        client.reconnect_delay_set(1, 30)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_subscribe = self._on_subscribe
        client.on_message = self._on_message
        self._client = client
        # Clean start and no session expiry: nothing sent while the fleet
        # was away is delivered late, and the broker keeps nothing of it.
        connect = Properties(PacketTypes.CONNECT)
        connect.MaximumPacketSize = _MAX_PACKET
        try:
            client.connect(host, port, keepalive=10, clean_start=True, properties=connect)
        except (OSError, ValueError) as e:
            raise ConnectionError(f"cannot connect to the broker {url}: {e}") from e
        client.loop_start()
        if not self._connected.wait(timeout) or self._refused is not None:
            why = self._refused or f"no answer within {timeout} s"
            self.close()
            raise ConnectionError(f"cannot connect to the broker {url}: {why}")

    # paho's thread -------------------------------------------------------

    def _on_connect(self, client: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        if reason.is_failure:
            self._refused = str(reason)
            self._connected.set()
            client.disconnect()
            return
        # Clean start: the broker kept nothing of the last connection, and
        # neither may paho. What it still holds (a request published as the
        # link went, or one whose PUBACK never came) belongs to a caller
        # already told it failed; paho would send it again right after this
        # callback, and the vehicle would run it late.
        with client._out_message_mutex:
            client._out_messages.clear()
            client._inflight_messages = 0
        with self._lock:
            self._down = None
        # Clean start: subscribe on every connection.
        topics = [f"lluav/+/res/{self.client_id}", "lluav/+/status", "lluav/+/state"]
        with self._lock:
            topics += sorted(self._event_topics)
        client.subscribe([(t, SubscribeOptions(qos=1)) for t in topics])
        self._connected.set()

    def _on_disconnect(self, _c: Any, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        self._fail_all(f"the connection to the broker was lost ({reason})")

    def _on_subscribe(self, _c: Any, _u: Any, mid: int, *_args: Any) -> None:
        with self._lock:
            self._granted = time.monotonic()
            self._granted_mids.add(mid)
            self._grant.notify_all()

    def _on_message(self, _c: Any, _u: Any, message: mqtt.MQTTMessage) -> None:
        parts = message.topic.split("/")
        if len(parts) < 3 or parts[0] != "lluav" or not _NAME.fullmatch(parts[1]):
            return
        try:
            value = json.loads(message.payload, object_pairs_hook=_unique)
        except ValueError:
            return
        vehicle, kind = parts[1], "/".join(parts[2:])
        with self._lock:
            if kind == "status" and isinstance(value, dict):
                self._heard.setdefault(vehicle, {})["online"] = value.get("online") is True
            elif kind == "state" and isinstance(value, dict):
                self._heard.setdefault(vehicle, {})["state"] = value
            elif kind == "events" and isinstance(value, dict):
                sinks = list(self._sinks.values())
                for only, put in sinks:
                    if only is None or only == vehicle:
                        put((vehicle, value))
                return
            elif kind.startswith("res/") and isinstance(value, dict):
                deliver = self._waiting.pop(str(value.get("id")), None)
                if deliver is not None:
                    deliver(value.get("response"), None)
                return
            else:
                return
            if message.retain:
                self._last_retained = time.monotonic()

    def _fail_all(self, why: str) -> None:
        with self._lock:
            self._down = why
            waiting, self._waiting = self._waiting, {}
        for deliver in waiting.values():
            deliver(None, why)

    # callers' side -------------------------------------------------------

    def send(self, vehicle: str, frame: str, deliver: Deliver) -> str:
        """Sends ``frame`` to ``vehicle``; ``deliver`` gets the answer. The
        request's id is returned, to :meth:`forget` it on a timeout."""
        rid = f"{self._nonce}-{next(self._ids)}"
        with self._lock:
            if self._down is not None:
                raise ConnectionError(self._down)
            self._waiting[rid] = deliver
        envelope = json.dumps({"id": rid, "frame": frame})
        info = self._client.publish(f"lluav/{vehicle}/req/{self.client_id}", envelope, qos=1)
        if info.rc != mqtt.MQTT_ERR_SUCCESS:
            self.forget(rid)
            raise ConnectionError(f"the request could not be sent: {mqtt.error_string(info.rc)}")
        return rid

    def forget(self, rid: str) -> None:
        with self._lock:
            self._waiting.pop(rid, None)

    def late(self, vehicle: str, timeout: float) -> str:
        """Why no answer came within ``timeout``."""
        with self._lock:
            online = self._heard.get(vehicle, {}).get("online") is True
        if online:
            return f"vehicle {vehicle} did not answer within {timeout} s"
        return f"vehicle {vehicle} is offline"

    def settled(self) -> bool:
        """Whether the retained messages have come (see LISTING_WAIT)."""
        with self._lock:
            if self._granted is None:
                return False
            since = max(self._granted, self._last_retained or 0.0)
        return time.monotonic() - since >= _LISTING_QUIET

    def vehicles(self) -> dict[str, dict[str, Any]]:
        now_ms = time.time() * 1000
        with self._lock:
            heard = {v: dict(h) for v, h in self._heard.items()}
        listing = {}
        for vehicle in sorted(heard):
            state = heard[vehicle].get("state")
            ts = state.get("ts") if isinstance(state, dict) else None
            age = max(0.0, (now_ms - ts) / 1000) if isinstance(ts, int) else None
            listing[vehicle] = {"online": heard[vehicle].get("online") is True, "state": state, "age_s": age}
        return listing

    def follow_events(self, vehicle: str | None, put: Callable[[FleetEvent], None]) -> int:
        """Subscribes to ``lluav/+/events``, waits for the grant, and hands
        every event of ``vehicle`` (of every vehicle for None) to ``put``
        from then on; returns the sink's id, for :meth:`unfollow_events`.
        One filter for every follower: two overlapping ones would bring
        each event twice (once per subscription, as MQTT 5 allows)."""
        if vehicle is not None:
            _name("vehicle id", vehicle)
        topic = "lluav/+/events"
        with self._lock:
            sink = next(self._sink_ids)
            self._sinks[sink] = (vehicle, put)
            self._event_topics.add(topic)
        rc, mid = self._client.subscribe(topic, options=SubscribeOptions(qos=1))
        if rc != mqtt.MQTT_ERR_SUCCESS:
            self.unfollow_events(sink)
            raise ConnectionError(f"cannot subscribe to {topic}: {mqtt.error_string(rc)}")
        with self._grant:
            if not self._grant.wait_for(lambda: mid in self._granted_mids, self._timeout):
                self._sinks.pop(sink, None)
                raise ConnectionError(f"the broker did not grant {topic} within {self._timeout} s")
        return sink

    def unfollow_events(self, sink: int) -> None:
        with self._lock:
            self._sinks.pop(sink, None)

    def close(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()
        self._fail_all("the fleet is closed")
        with self._lock:
            sinks, self._sinks = list(self._sinks.values()), {}
        for _, put in sinks:
            put(None)


class FleetVehicle:
    """One vehicle reached through a :class:`Fleet`: every command is a
    method, exactly as on :class:`lluav.Client` (``v.state()``,
    ``v.set_sp_ned(1.0, 2.0, -3.0, 0.5)``), with the same argument checks
    and errors; ``call`` sends any frame. A response that does not come
    within the fleet's ``timeout`` raises ConnectionError (``vehicle V is
    offline``, or did not answer); the connection stays usable."""

    def __init__(self, fleet: Fleet, vehicle: str) -> None:
        self.fleet = fleet
        self.vehicle = _name("vehicle id", vehicle)

    def _request(self, frame: str, cid: int) -> dict[str, Any]:
        link = self.fleet._live()
        done = threading.Event()
        box: list[tuple[Any, str | None]] = []

        def deliver(response: Any, why: str | None) -> None:
            box.append((response, why))
            done.set()

        rid = link.send(self.vehicle, frame, deliver)
        timeout = self.fleet.timeout
        if not done.wait(timeout):
            link.forget(rid)
            raise ConnectionError(link.late(self.vehicle, timeout))
        response, why = box[0]
        if why is not None:
            raise ConnectionError(why)
        return check_response(response, cid)

    def call(self, frame: str) -> dict[str, Any]:
        """Sends any frame (``"set_sp_ned 1:2:-3:0"``) as it is and returns
        the response; the vehicle, not the SDK, decides whether it is valid."""
        if not isinstance(frame, str):
            raise TypeError(f"a frame is a str, not {type(frame).__name__}")
        return self._request(frame, _core.command_id(frame))

    def __repr__(self) -> str:
        return f"<lluav.FleetVehicle {self.vehicle} via {self.fleet.url}>"


class Fleet:
    """Vehicles through an MQTT broker (lluavd ``--uplink``).

    Connects at once to ``url`` (``mqtt://HOST[:PORT]``, or ``mqtts://``
    checked against the system's trust store or only ``cafile``) over MQTT
    5, as ``client_id`` (1-64 of ``[A-Za-z0-9_-]``; default: ``username``
    when given, else ``lluav-<random>``), with ``username``/``password`` at
    the broker when given. ``timeout`` bounds the connection and the wait
    for each answer, in seconds.

    :meth:`vehicles` lists every vehicle heard of; :meth:`vehicle` gives
    one, with the same methods as :class:`lluav.Client`. One fleet is one
    session on each vehicle (its client id); calls from several threads are
    safe.
    """

    def __init__(
        self,
        url: str,
        client_id: str | None = None,
        username: str | None = None,
        password: str | None = None,
        cafile: str | None = None,
        timeout: float = 10.0,
    ) -> None:
        self.url = url
        self.timeout = timeout
        self._link: _Link | None = _Link(url, client_id, username, password, cafile, timeout)
        self.client_id = self._link.client_id
        self._listed = False

    def _live(self) -> _Link:
        if self._link is None:
            raise ConnectionError("the fleet is closed")
        return self._link

    def vehicles(self) -> dict[str, dict[str, Any]]:
        """Every vehicle heard of: its id to ``{"online": bool, "state": the
        latest state response or None, "age_s": seconds since that state, or
        None}``. The first call waits up to 1 s for the retained messages."""
        link = self._live()
        if not self._listed:
            self._listed = True
            deadline = time.monotonic() + LISTING_WAIT
            while not link.settled() and time.monotonic() < deadline:
                time.sleep(0.02)
        return link.vehicles()

    def vehicle(self, vehicle: str, password: str | None = None) -> FleetVehicle:
        """The vehicle called ``vehicle``; logs in first when ``password``
        is given (a refused login raises CommandError)."""
        v = FleetVehicle(self, vehicle)
        if password is not None:
            v._request(_encode(_methods.LOGIN, (password,), None), _methods.LOGIN)
        return v

    def events(self, vehicle: str | None = None, timeout: float | None = None) -> FleetEvents:
        """Follows the events of ``vehicle``, or of every vehicle (from
        ``lluav/+/events``): an iterator of dicts, each with
        ``"vehicle"`` added; subscribed (granted) when this returns.
        ``timeout``: seconds to wait for each event (TimeoutError), or None.
        See :class:`lluav.FleetEvents`."""
        return FleetEvents(self._live(), vehicle, timeout)

    def close(self) -> None:
        """Disconnects from the broker. Idempotent."""
        link, self._link = self._link, None
        if link is not None:
            link.close()

    @property
    def closed(self) -> bool:
        """Whether the fleet is closed."""
        return self._link is None

    def __enter__(self) -> Fleet:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<lluav.Fleet {self.url} as {self.client_id} {'closed' if self.closed else 'open'}>"


class AsyncFleetVehicle:
    """One vehicle reached through an :class:`AsyncFleet`: every command is
    a coroutine method, exactly as on :class:`lluav.AsyncClient`; ``call``
    sends any frame. Concurrent calls are safe: each gets its own answer."""

    def __init__(self, fleet: AsyncFleet, vehicle: str) -> None:
        self.fleet = fleet
        self.vehicle = _name("vehicle id", vehicle)

    async def _request(self, frame: str, cid: int) -> dict[str, Any]:
        link = self.fleet._live()
        loop = asyncio.get_running_loop()
        answer: asyncio.Future[tuple[Any, str | None]] = loop.create_future()

        def settle(response: Any, why: str | None) -> None:
            if not answer.done():
                answer.set_result((response, why))

        def deliver(response: Any, why: str | None) -> None:
            loop.call_soon_threadsafe(settle, response, why)

        rid = link.send(self.vehicle, frame, deliver)
        timeout = self.fleet.timeout
        try:
            response, why = await asyncio.wait_for(answer, timeout)
        except (TimeoutError, asyncio.TimeoutError):
            link.forget(rid)
            raise ConnectionError(link.late(self.vehicle, timeout)) from None
        if why is not None:
            raise ConnectionError(why)
        return check_response(response, cid)

    async def call(self, frame: str) -> dict[str, Any]:
        """Sends any frame (``"set_sp_ned 1:2:-3:0"``) as it is and returns
        the response; the vehicle, not the SDK, decides whether it is valid."""
        if not isinstance(frame, str):
            raise TypeError(f"a frame is a str, not {type(frame).__name__}")
        return await self._request(frame, _core.command_id(frame))

    def __repr__(self) -> str:
        return f"<lluav.AsyncFleetVehicle {self.vehicle} via {self.fleet.url}>"


class AsyncFleet:
    """:class:`Fleet` on asyncio: ``async with lluav.AsyncFleet(url) as f:``
    connects (so does ``await f.connect()``); ``await f.vehicles()``;
    ``v = await f.vehicle(V, password=None)`` then ``await v.state()``.
    The arguments are as for :class:`Fleet`."""

    def __init__(
        self,
        url: str,
        client_id: str | None = None,
        username: str | None = None,
        password: str | None = None,
        cafile: str | None = None,
        timeout: float = 10.0,
    ) -> None:
        _broker(url)
        self.url = url
        self.timeout = timeout
        self._args = (url, client_id, username, password, cafile, timeout)
        self._link: _Link | None = None
        self._listed = False

    def _live(self) -> _Link:
        if self._link is None:
            raise ConnectionError("not connected: use `async with` or `await fleet.connect()`")
        return self._link

    @property
    def client_id(self) -> str | None:
        """The client id, once connected."""
        return self._link.client_id if self._link is not None else None

    async def connect(self) -> AsyncFleet:
        """Connects to the broker (paho's connect blocks: it runs off the loop)."""
        if self._link is None:
            self._link = await asyncio.get_running_loop().run_in_executor(None, _Link, *self._args)
        return self

    async def vehicles(self) -> dict[str, dict[str, Any]]:
        """As :meth:`Fleet.vehicles`."""
        link = self._live()
        if not self._listed:
            self._listed = True
            deadline = time.monotonic() + LISTING_WAIT
            while not link.settled() and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
        return link.vehicles()

    async def vehicle(self, vehicle: str, password: str | None = None) -> AsyncFleetVehicle:
        """The vehicle called ``vehicle``; logs in first when ``password``
        is given (a refused login raises CommandError)."""
        v = AsyncFleetVehicle(self, vehicle)
        if password is not None:
            await v._request(_encode(_methods.LOGIN, (password,), None), _methods.LOGIN)
        return v

    async def events(self, vehicle: str | None = None, timeout: float | None = None) -> AsyncFleetEvents:
        """As :meth:`Fleet.events`, an async iterator: ``async for event in
        await fleet.events()``; subscribed (granted) when this returns."""
        return await AsyncFleetEvents(self._live(), vehicle, timeout)._subscribe()

    async def close(self) -> None:
        """Disconnects from the broker. Idempotent."""
        link, self._link = self._link, None
        if link is not None:
            await asyncio.get_running_loop().run_in_executor(None, link.close)

    @property
    def closed(self) -> bool:
        """Whether the fleet is closed or not yet connected."""
        return self._link is None

    async def __aenter__(self) -> AsyncFleet:
        return await self.connect()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    def __repr__(self) -> str:
        return f"<lluav.AsyncFleet {self.url} {'closed' if self.closed else 'open'}>"


_methods.install(FleetVehicle, _make_sync)
_methods.install(AsyncFleetVehicle, _make_async)
