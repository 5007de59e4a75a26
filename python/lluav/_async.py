"""The asyncio client."""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, Union

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, WebSocketException
from websockets.protocol import State

from . import _core, _methods, _tls
from ._errors import ConnectionError
from ._events import AsyncEvents
from ._response import check
from ._sync import DEFAULT_URL

_encode = _core.encode

Message = Union[str, bytes]


class _Request:
    """A request on the wire, waiting for its response."""

    __slots__ = ("deadline", "message", "waiter")

    def __init__(self, deadline: float) -> None:
        self.deadline = deadline
        # The response, once read (by whichever request was reading).
        self.message: Message | None = None
        # What the request's caller awaits while another one reads: woken
        # when the response is in, or when it is its turn to read.
        self.waiter: asyncio.Future[None] | None = None


class _Link:
    """One open connection and the requests waiting on it."""

    __slots__ = ("loop", "pending", "reading", "watchdog", "why", "ws")

    def __init__(self, ws: ClientConnection, loop: asyncio.AbstractEventLoop) -> None:
        self.ws = ws
        self.loop = loop
        # Requests on the wire, oldest first: the server answers in order.
        self.pending: deque[_Request] = deque()
        # Whether a caller is reading responses off the connection.
        self.reading = False
        # The one timer, for the oldest request's deadline.
        self.watchdog: asyncio.TimerHandle | None = None
        # Why the connection was dropped, once it is.
        self.why: str | None = None


class AsyncClient:
    """A connection to an LLUAV server on asyncio.

    ``async with lluav.AsyncClient(url, password) as c:`` connects (and logs
    in when ``password`` is given); so does ``await c.connect()``. Every
    command is a coroutine method (``await c.state()``); ``call`` sends any
    frame. ``cafile`` and ``timeout`` are as for :class:`lluav.Client`: a
    response that does not come within ``timeout`` seconds closes the
    connection and raises ConnectionError.

    Concurrent calls on one client are safe: requests go out in the order
    the calls are made, the server answers in order, and each call gets its
    own response.
    """

    # How responses reach their callers: the requests on the wire form a
    # FIFO (the server answers in order). A request joins the FIFO and its
    # frame is written in one step, without yielding to the event loop in
    # between: websockets' send() writes a str message before it first
    # yields (it documents that it yields only to wait for a full write
    # buffer to drain, or between the fragments of an iterable), so the
    # FIFO's order is the order on the wire, with no lock.
    #
    # There is no reader task: the caller that finds nobody reading reads
    # responses off the connection, hands each to its request, and stops at
    # its own; it then wakes the oldest waiting caller to read on. A lone
    # call (the common case) therefore sends and receives by itself, with
    # no task switch.

    def __init__(
        self,
        url: str = DEFAULT_URL,
        password: str | None = None,
        cafile: str | None = None,
        timeout: float = 10.0,
    ) -> None:
        self.url = url
        self.timeout = timeout
        self._password = password
        self._ssl = _tls.context(url, cafile)
        self._link: _Link | None = None
        self._closed_why = "not connected: use `async with` or `await client.connect()`"
        self._closing: set[asyncio.Task[None]] = set()

    async def connect(self) -> AsyncClient:
        """Opens the connection and logs in when a password was given."""
        if self._link is not None:
            return self
        try:
            ws = await connect(
                self.url, ssl=self._ssl, open_timeout=self.timeout, close_timeout=self.timeout, compression=None
            )
        except (OSError, TimeoutError, asyncio.TimeoutError, WebSocketException) as e:
            raise ConnectionError(f"cannot connect to {self.url}: {e}") from e
        self._link = _Link(ws, asyncio.get_running_loop())
        if self._password is not None:
            try:
                await self._request(_encode(_methods.LOGIN, (self._password,), None), _methods.LOGIN)
            except BaseException:
                await self.close()
                raise
        return self

    async def _request(self, frame: str, cid: int) -> dict[str, Any]:
        link = self._link
        if link is None:
            raise ConnectionError(self._closed_why)
        request = _Request(link.loop.time() + self.timeout)
        link.pending.append(request)
        try:
            await link.ws.send(frame)
        except (ConnectionClosed, OSError, WebSocketException) as e:
            raise ConnectionError(self._drop(link, f"the connection was closed: {e}")) from e
        if link.watchdog is None:
            link.watchdog = link.loop.call_at(request.deadline, self._watch, link)
        message = await self._response(link, request)
        try:
            return check(message, cid)
        except ConnectionError as e:
            # The server does not speak the protocol (or answered another
            # request): no later response could be trusted either.
            self._drop(link, str(e))
            raise

    async def _response(self, link: _Link, request: _Request) -> Message:
        """Waits for the response to ``request``, reading when nobody else is."""
        while request.message is None:
            if link.why is not None:
                raise ConnectionError(link.why)
            if link.reading:
                request.waiter = link.loop.create_future()
                await request.waiter
                continue
            link.reading = True
            try:
                while request.message is None:
                    message = await link.ws.recv()
                    if not link.pending:
                        raise ConnectionError(self._drop(link, "the server sent a message no request was waiting for"))
                    answered = link.pending.popleft()
                    answered.message = message
                    if answered.waiter is not None and not answered.waiter.done():
                        answered.waiter.set_result(None)
            except ConnectionClosed as e:
                raise ConnectionError(self._drop(link, f"the connection was closed: {e}")) from e
            finally:
                link.reading = False
                self._pass_reading_on(link)
        return request.message

    @staticmethod
    def _pass_reading_on(link: _Link) -> None:
        """Wakes the oldest caller still waiting, to read on. Callers that
        were cancelled leave their requests queued (their responses are
        still to come), so they are skipped."""
        for request in link.pending:
            waiter = request.waiter
            if waiter is not None and not waiter.done():
                waiter.set_result(None)
                return

    def _watch(self, link: _Link) -> None:
        """The one timer: only the oldest request can be late."""
        link.watchdog = None
        if link.why is not None or not link.pending:
            return
        oldest = link.pending[0].deadline
        if oldest <= link.loop.time():
            self._drop(link, f"no response within {self.timeout} s; the connection was closed", abort=True)
        else:
            link.watchdog = link.loop.call_at(oldest, self._watch, link)

    def _drop(self, link: _Link, why: str, abort: bool = False) -> str:
        """Closes the connection and fails every request waiting on it, with
        ``why`` (unless it was dropped before: the first reason stands, and
        is returned). ``abort`` closes without the closing handshake, for a
        peer that no longer answers."""
        if link.why is not None:
            return link.why
        link.why = why
        if self._link is link:
            self._link = None
            self._closed_why = why
        if link.watchdog is not None:
            link.watchdog.cancel()
            link.watchdog = None
        pending, link.pending = link.pending, deque()
        for request in pending:
            if request.waiter is not None and not request.waiter.done():
                request.waiter.set_exception(ConnectionError(why))
        if abort:
            link.ws.transport.abort()
        elif link.ws.state is not State.CLOSED:
            task = link.loop.create_task(link.ws.close())
            self._closing.add(task)
            task.add_done_callback(self._closing.discard)
        return why

    async def call(self, frame: str) -> dict[str, Any]:
        """Sends any frame (``"set_sp_ned 1:2:-3:0"``) as it is and returns
        the response; the server, not the SDK, decides whether it is valid."""
        if not isinstance(frame, str):
            raise TypeError(f"a frame is a str, not {type(frame).__name__}")
        return await self._request(frame, _core.command_id(frame))

    def events(self, timeout: float | None = None) -> AsyncEvents:
        """The server's events (``/events``, on a connection of its own,
        logged in with this client's password) as an async iterator of
        dicts: ``async with c.events() as events: async for event in
        events: ...`` (subscribed when the ``async with`` block starts).
        ``timeout``: seconds to wait for each event (TimeoutError), or None.
        See :class:`lluav.AsyncEvents`."""
        return AsyncEvents(self.url, self._password, self._ssl, self.timeout, timeout)

    async def close(self) -> None:
        """Closes the connection (the WebSocket closing handshake); requests
        still in flight fail with ConnectionError. Idempotent."""
        link = self._link
        if link is not None:
            self._drop(link, "the client is closed")
        if self._closing:
            await asyncio.gather(*self._closing, return_exceptions=True)

    @property
    def closed(self) -> bool:
        """Whether the connection is closed, lost, or not yet open."""
        return self._link is None

    async def __aenter__(self) -> AsyncClient:
        return await self.connect()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    def __repr__(self) -> str:
        return f"<lluav.AsyncClient {self.url} {'closed' if self.closed else 'open'}>"


def _make(cid: int) -> Callable[..., Coroutine[Any, Any, dict[str, Any]]]:
    async def method(self: AsyncClient, *args: Any, **kwargs: Any) -> dict[str, Any]:
        return await self._request(_encode(cid, args, kwargs), cid)

    return method


_methods.install(AsyncClient, _make)
