"""Events: what happened to a vehicle, pushed as it happens (DESIGN.md,
"Events"), on a WebSocket of their own (``/events`` beside the command
socket) or through the broker (``lluav/V/events``)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import queue
import ssl as _ssl
from types import TracebackType
from typing import Any, Optional, Union
from urllib.parse import urlsplit, urlunsplit

from websockets.asyncio.client import ClientConnection
from websockets.asyncio.client import connect as connect_async
from websockets.exceptions import ConnectionClosed, ConnectionClosedOK, WebSocketException
from websockets.sync.client import connect
from websockets.sync.connection import Connection

from . import _core, _methods
from ._errors import ConnectionError
from ._response import check

Message = Union[str, bytes]


def events_url(url: str) -> str:
    """The ``/events`` URL of the server at ``url``: the same scheme, host
    and port, ``/events`` after its path (``ws://h:53001`` gives
    ``ws://h:53001/events``, ``wss://proxy/drone-1/`` gives
    ``wss://proxy/drone-1/events``)."""
    parts = urlsplit(url)
    return urlunsplit((parts.scheme, parts.netloc, parts.path.rstrip("/") + "/events", "", ""))


def _login_frame(password: str) -> str:
    return _core.encode(_methods.LOGIN, (password,), None)


def _event(message: Message) -> dict[str, Any]:
    if isinstance(message, bytes):
        raise ConnectionError(f"the server sent a binary message ({len(message)} bytes), not an event")
    try:
        value = json.loads(message)
    except ValueError as e:
        raise ConnectionError(f"the server sent something that is not an event ({e}): {message[:200]!r}") from e
    if not isinstance(value, dict):
        raise ConnectionError(f"the server sent something that is not an event: {message[:200]!r}")
    return value


class Events:
    """The events of one server, as dicts (``{"event": "fsm", "seq": 3,
    "boot": "...", "ts": ms, "from": "takeoff", "to": "hover"}``; a
    subscriber that fell behind gets ``{"event": "gap", "missed": N, "ts":
    ms}``), from :meth:`lluav.Client.events`.

    Subscribed once this is made (logged in first when the client has a
    password): every event after that comes. Iterate to get them; the
    iteration ends after :meth:`close`, and raises ConnectionError when the
    connection ends or fails, TimeoutError when ``timeout`` seconds pass
    without an event.
    """

    def __init__(
        self,
        url: str,
        password: str | None,
        ssl: _ssl.SSLContext | None,
        open_timeout: float,
        timeout: float | None,
    ) -> None:
        self.url = events_url(url)
        self.timeout = timeout
        self._closed = False
        self._stack = contextlib.ExitStack()
        try:
            self._ws: Connection = self._stack.enter_context(
                connect(self.url, ssl=ssl, open_timeout=open_timeout, close_timeout=open_timeout, compression=None)
            )
        except (OSError, TimeoutError, WebSocketException) as e:
            raise ConnectionError(f"cannot connect to {self.url}: {e}") from e
        if password is not None:
            try:
                self._ws.send(_login_frame(password))
                check(self._ws.recv(timeout=open_timeout), _methods.LOGIN)
            except (ConnectionClosed, OSError, TimeoutError, WebSocketException) as e:
                self.close()
                raise ConnectionError(f"the login on {self.url} failed: {e}") from e
            except BaseException:
                self.close()
                raise

    def __iter__(self) -> Events:
        return self

    def __next__(self) -> dict[str, Any]:
        if self._closed:
            raise StopIteration
        try:
            return _event(self._ws.recv(timeout=self.timeout))
        except TimeoutError:
            raise TimeoutError(f"no event within {self.timeout} s") from None
        except ConnectionClosed as e:
            if self._closed:
                raise StopIteration from None
            self.close()
            raise ConnectionError(f"the events stream {self.url} ended: {e}") from e
        except (OSError, WebSocketException) as e:
            if self._closed:
                raise StopIteration from None
            self.close()
            raise ConnectionError(f"the events stream {self.url} failed: {e}") from e

    def close(self) -> None:
        """Closes the stream (the WebSocket closing handshake). Idempotent."""
        if not self._closed:
            self._closed = True
            with contextlib.suppress(OSError, WebSocketException):
                self._stack.close()

    def __enter__(self) -> Events:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<lluav.Events {self.url} {'closed' if self._closed else 'open'}>"


class AsyncEvents:
    """:class:`Events` on asyncio, from :meth:`lluav.AsyncClient.events`:
    ``async with client.events() as events:`` subscribes (so does ``await
    events.connect()``, or the first ``async for``), then ``async for event
    in events``."""

    def __init__(
        self,
        url: str,
        password: str | None,
        ssl: _ssl.SSLContext | None,
        open_timeout: float,
        timeout: float | None,
    ) -> None:
        self.url = events_url(url)
        self.timeout = timeout
        self._password = password
        self._ssl = ssl
        self._open_timeout = open_timeout
        self._ws: ClientConnection | None = None
        self._closed = False

    async def connect(self) -> AsyncEvents:
        """Subscribes (logged in first with a password). Idempotent."""
        if self._ws is not None or self._closed:
            return self
        try:
            ws = await connect_async(
                self.url,
                ssl=self._ssl,
                open_timeout=self._open_timeout,
                close_timeout=self._open_timeout,
                compression=None,
            )
        except (OSError, TimeoutError, asyncio.TimeoutError, WebSocketException) as e:
            raise ConnectionError(f"cannot connect to {self.url}: {e}") from e
        self._ws = ws
        if self._password is not None:
            try:
                await ws.send(_login_frame(self._password))
                check(await asyncio.wait_for(ws.recv(), self._open_timeout), _methods.LOGIN)
            except (ConnectionClosed, OSError, TimeoutError, asyncio.TimeoutError, WebSocketException) as e:
                await self.close()
                raise ConnectionError(f"the login on {self.url} failed: {e}") from e
            except BaseException:
                await self.close()
                raise
        return self

    def __aiter__(self) -> AsyncEvents:
        return self

    async def __anext__(self) -> dict[str, Any]:
        if self._ws is None:
            await self.connect()
        ws = self._ws
        if self._closed or ws is None:
            raise StopAsyncIteration
        try:
            message = await asyncio.wait_for(ws.recv(), self.timeout)
        except (TimeoutError, asyncio.TimeoutError):
            raise TimeoutError(f"no event within {self.timeout} s") from None
        except ConnectionClosedOK as e:
            if self._closed:
                raise StopAsyncIteration from None
            await self.close()
            raise ConnectionError(f"the events stream {self.url} ended: {e}") from e
        except (ConnectionClosed, OSError, WebSocketException) as e:
            if self._closed:
                raise StopAsyncIteration from None
            await self.close()
            raise ConnectionError(f"the events stream {self.url} failed: {e}") from e
        return _event(message)

    async def close(self) -> None:
        """Closes the stream (the WebSocket closing handshake). Idempotent."""
        self._closed = True
        ws, self._ws = self._ws, None
        if ws is not None:
            with contextlib.suppress(OSError, WebSocketException):
                await ws.close()

    async def __aenter__(self) -> AsyncEvents:
        return await self.connect()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open" if self._ws is not None else "not connected"
        return f"<lluav.AsyncEvents {self.url} {state}>"


# What a fleet's events sink is handed: (vehicle, event), or None once the
# fleet is closed.
FleetEvent = Optional[tuple[str, dict[str, Any]]]


class FleetEvents:
    """The events of every vehicle, or of one, through a broker
    (``lluav/+/events``, the vehicle picked out here), from
    :meth:`lluav.Fleet.events`: dicts as :class:`Events` gives them, with
    ``"vehicle"`` added (the vehicle's id).

    Subscribed once this is made (the broker granted it). The broker
    connection comes back by itself when lost; what was published while it
    was down does not come (``seq`` shows the hole). The iteration ends
    after :meth:`close` or the fleet's close, and raises TimeoutError when
    ``timeout`` seconds pass without an event.
    """

    def __init__(self, link: Any, vehicle: str | None, timeout: float | None) -> None:
        self.vehicle = vehicle
        self.timeout = timeout
        self._queue: queue.SimpleQueue[FleetEvent] = queue.SimpleQueue()
        self._link = link
        self._closed = False
        self._sink = link.follow_events(vehicle, self._queue.put)

    def __iter__(self) -> FleetEvents:
        return self

    def __next__(self) -> dict[str, Any]:
        if self._closed:
            raise StopIteration
        try:
            item = self._queue.get(timeout=self.timeout)
        except queue.Empty:
            raise TimeoutError(f"no event within {self.timeout} s") from None
        if item is None:
            self._closed = True
            raise StopIteration
        vehicle, event = item
        return {**event, "vehicle": vehicle}

    def close(self) -> None:
        """Stops following (the iteration ends). Idempotent."""
        if not self._closed:
            self._closed = True
            self._link.unfollow_events(self._sink)

    def __enter__(self) -> FleetEvents:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class AsyncFleetEvents:
    """:class:`FleetEvents` on asyncio, from :meth:`lluav.AsyncFleet.events`:
    ``async for event in await fleet.events()``."""

    def __init__(self, link: Any, vehicle: str | None, timeout: float | None) -> None:
        self.vehicle = vehicle
        self.timeout = timeout
        loop = asyncio.get_running_loop()
        self._queue: asyncio.Queue[FleetEvent] = asyncio.Queue()
        self._link = link
        self._closed = False

        def put(item: FleetEvent) -> None:
            with contextlib.suppress(RuntimeError):  # the loop is closed
                loop.call_soon_threadsafe(self._queue.put_nowait, item)

        self._put = put
        self._sink: Any = None

    async def _subscribe(self) -> AsyncFleetEvents:
        loop = asyncio.get_running_loop()
        self._sink = await loop.run_in_executor(None, self._link.follow_events, self.vehicle, self._put)
        return self

    def __aiter__(self) -> AsyncFleetEvents:
        return self

    async def __anext__(self) -> dict[str, Any]:
        if self._closed:
            raise StopAsyncIteration
        try:
            item = await asyncio.wait_for(self._queue.get(), self.timeout)
        except (TimeoutError, asyncio.TimeoutError):
            raise TimeoutError(f"no event within {self.timeout} s") from None
        if item is None:
            self._closed = True
            raise StopAsyncIteration
        vehicle, event = item
        return {**event, "vehicle": vehicle}

    async def close(self) -> None:
        """Stops following (the iteration ends). Idempotent."""
        if not self._closed:
            self._closed = True
            if self._sink is not None:
                self._link.unfollow_events(self._sink)

    async def __aenter__(self) -> AsyncFleetEvents:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()
