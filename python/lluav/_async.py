"""The asyncio client."""

from __future__ import annotations

import asyncio
from collections import deque
from types import TracebackType
from typing import Any, Callable, Coroutine, Optional, Union

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, WebSocketException
from websockets.protocol import State

from . import _core, _methods, _tls
from ._errors import ConnectionError
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
        self.message: Optional[Message] = None
        # What the request's caller awaits while another one reads: woken
        # when the response is in, or when it is its turn to read.
        self.waiter: Optional[asyncio.Future[None]] = None


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
    # FIFO (the server answers in order). There is no reader task: the
    # caller that finds nobody reading reads responses off the connection,
    # hands each to its request, and stops at its own; it then wakes the
    # oldest waiting caller to read on. A lone call (the common case)
    # therefore sends and receives by itself, with no task switch.

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
        self._ws: ClientConnection | None = None
        self._closed_why = "not connected: use `async with` or `await client.connect()`"
        self._pending: deque[_Request] = deque()
        self._reading = False
        # Held from queuing a request until its frame is written, so that
        # the queue's order is the order on the wire. Made in connect():
        # before 3.10 a lock binds to the loop it is made on.
        self._send_lock: asyncio.Lock | None = None
        self._watchdog: asyncio.TimerHandle | None = None
        self._closing: set[asyncio.Task[None]] = set()

    async def connect(self) -> AsyncClient:
        """Opens the connection and logs in when a password was given."""
        if self._ws is not None:
            return self
        try:
            ws = await connect(
                self.url, ssl=self._ssl, open_timeout=self.timeout, close_timeout=self.timeout, compression=None
            )
        except (OSError, asyncio.TimeoutError, WebSocketException) as e:
            raise ConnectionError(f"cannot connect to {self.url}: {e}") from e
        self._ws = ws
        self._send_lock = asyncio.Lock()
        if self._password is not None:
            try:
                await self._request(_encode(_methods.LOGIN, (self._password,), None), _methods.LOGIN)
            except BaseException:
                await self.close()
                raise
        return self

    async def _request(self, frame: str, cid: int) -> dict[str, Any]:
        ws, lock = self._ws, self._send_lock
        if ws is None or lock is None:
            raise ConnectionError(self._closed_why)
        loop = asyncio.get_running_loop()
        request = _Request(loop.time() + self.timeout)
        async with lock:
            if self._ws is not ws:
                raise ConnectionError(self._closed_why)
            self._pending.append(request)
            try:
                await ws.send(frame)
            except (ConnectionClosed, OSError, WebSocketException) as e:
                self._drop(ws, f"the connection was closed: {e}")
                raise ConnectionError(self._closed_why) from e
        if self._watchdog is None:
            self._watchdog = loop.call_at(request.deadline, self._watch, ws)
        message = await self._response(ws, request, loop)
        try:
            return check(message, cid)
        except ConnectionError as e:
            # The server does not speak the protocol (or answered another
            # request): no later response could be trusted either.
            self._drop(ws, str(e))
            raise

    async def _response(self, ws: ClientConnection, request: _Request, loop: asyncio.AbstractEventLoop) -> Message:
        """Waits for the response to ``request``, reading when nobody else is."""
        while request.message is None:
            if self._reading:
                request.waiter = loop.create_future()
                await request.waiter
                continue
            self._reading = True
            try:
                while request.message is None:
                    message = await ws.recv()
                    if not self._pending:
                        self._drop(ws, "the server sent a message no request was waiting for")
                        raise ConnectionError(self._closed_why)
                    answered = self._pending.popleft()
                    answered.message = message
                    if answered.waiter is not None and not answered.waiter.done():
                        answered.waiter.set_result(None)
            except ConnectionClosed as e:
                self._drop(ws, f"the connection was closed: {e}")
                raise ConnectionError(self._closed_why) from e
            finally:
                self._reading = False
                self._pass_reading_on()
        return request.message

    def _pass_reading_on(self) -> None:
        """Wakes the oldest caller still waiting, to read on. Callers that
        were cancelled leave their requests queued (their responses are
        still to come), so they are skipped."""
        for request in self._pending:
            waiter = request.waiter
            if waiter is not None and not waiter.done():
                waiter.set_result(None)
                return

    def _watch(self, ws: ClientConnection) -> None:
        """The one timer: only the oldest request can be late."""
        self._watchdog = None
        if self._ws is not ws or not self._pending:
            return
        oldest = self._pending[0].deadline
        loop = asyncio.get_running_loop()
        if oldest <= loop.time():
            self._drop(ws, f"no response within {self.timeout} s; the connection was closed", abort=True)
        else:
            self._watchdog = loop.call_at(oldest, self._watch, ws)

    def _drop(self, ws: ClientConnection, why: str, abort: bool = False) -> None:
        """Forgets the connection (unless close() already did, whose reason
        then stands), closes it and fails every waiting request. ``abort``
        closes without the closing handshake, for a peer that no longer
        answers."""
        if self._ws is ws:
            self._ws = None
            self._closed_why = why
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        pending, self._pending = self._pending, deque()
        for request in pending:
            if request.waiter is not None and not request.waiter.done():
                request.waiter.set_exception(ConnectionError(self._closed_why))
        if abort:
            ws.transport.abort()
        elif ws.state is not State.CLOSED:
            task = asyncio.get_running_loop().create_task(ws.close())
            self._closing.add(task)
            task.add_done_callback(self._closing.discard)

    async def call(self, frame: str) -> dict[str, Any]:
        """Sends any frame (``"set_sp_ned 1:2:-3:0"``) as it is and returns
        the response; the server, not the SDK, decides whether it is valid."""
        if not isinstance(frame, str):
            raise TypeError(f"a frame is a str, not {type(frame).__name__}")
        return await self._request(frame, _core.command_id(frame))

    async def close(self) -> None:
        """Closes the connection (the WebSocket closing handshake); requests
        still in flight fail with ConnectionError. Idempotent."""
        ws = self._ws
        if ws is not None:
            self._closed_why = "the client is closed"
            self._drop(ws, self._closed_why)
        if self._closing:
            await asyncio.gather(*self._closing, return_exceptions=True)

    @property
    def closed(self) -> bool:
        """Whether the connection is closed, lost, or not yet open."""
        return self._ws is None

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
