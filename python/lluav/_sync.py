"""The synchronous client."""

from __future__ import annotations

import contextlib
import threading
from types import TracebackType
from typing import Any, Callable

from websockets.exceptions import ConnectionClosed, WebSocketException
from websockets.sync.client import connect
from websockets.sync.connection import Connection

from . import _core, _methods, _tls
from ._errors import ConnectionError
from ._events import Events
from ._response import check

DEFAULT_URL = "ws://127.0.0.1:53001"
"""The protocol's default address: lluavd on this machine."""

_encode = _core.encode


class Client:
    """A connection to an LLUAV server (lluavd, a board), one request at a time.

    Connects at once; logs in when ``password`` is given. ``cafile`` is a
    PEM file of CA certificates to trust for a ``wss://`` URL (e.g. the
    server's self-signed certificate). ``timeout`` bounds the opening
    handshake and the wait for each response, in seconds; a response that
    does not come in time closes the connection (it could no longer be
    told apart from the next one) and raises ConnectionError.

    Every command of the protocol is a method (``c.state()``,
    ``c.set_sp_ned(1.0, 2.0, -3.0, 0.5)``); ``call`` sends any frame.
    Calls from several threads are safe: each waits for its own response.
    """

    def __init__(
        self,
        url: str = DEFAULT_URL,
        password: str | None = None,
        cafile: str | None = None,
        timeout: float = 10.0,
    ) -> None:
        self.url = url
        self.timeout = timeout
        self._lock = threading.Lock()
        self._closed_why = "the client is closed"
        self._password = password
        self._ssl = ssl = _tls.context(url, cafile)
        # websockets' documented way in every version since 15 is the
        # context manager; the stack leaves it open until close().
        self._stack = contextlib.ExitStack()
        try:
            self._ws: Connection | None = self._stack.enter_context(
                connect(url, ssl=ssl, open_timeout=timeout, close_timeout=timeout, compression=None)
            )
        except (OSError, TimeoutError, WebSocketException) as e:
            raise ConnectionError(f"cannot connect to {url}: {e}") from e
        if password is not None:
            try:
                self._request(_encode(_methods.LOGIN, (password,), None), _methods.LOGIN)
            except BaseException:
                self.close()
                raise

    def _request(self, frame: str, cid: int) -> dict[str, Any]:
        with self._lock:
            ws = self._ws
            if ws is None:
                raise ConnectionError(self._closed_why)
            try:
                ws.send(frame)
                message = ws.recv(timeout=self.timeout)
            except TimeoutError:
                self._abandon(f"no response within {self.timeout} s; the connection was closed")
                raise ConnectionError(self._closed_why) from None
            except ConnectionClosed as e:
                self._abandon(f"the connection was closed: {e}")
                raise ConnectionError(self._closed_why) from e
            except (OSError, WebSocketException) as e:
                self._abandon(f"the connection failed: {e}")
                raise ConnectionError(self._closed_why) from e
            try:
                return check(message, cid)
            except ConnectionError as e:
                # The server does not speak the protocol (or answered another
                # request): no later response could be trusted either.
                self._abandon(str(e))
                raise

    def _abandon(self, why: str) -> None:
        if self._ws is not None:
            self._ws = None
            self._closed_why = why
            with contextlib.suppress(OSError, WebSocketException):
                self._stack.close()

    def call(self, frame: str) -> dict[str, Any]:
        """Sends any frame (``"set_sp_ned 1:2:-3:0"``) as it is and returns
        the response; the server, not the SDK, decides whether it is valid."""
        if not isinstance(frame, str):
            raise TypeError(f"a frame is a str, not {type(frame).__name__}")
        return self._request(frame, _core.command_id(frame))

    def events(self, timeout: float | None = None) -> Events:
        """Subscribes to the server's events (``/events``, on a connection
        of its own, logged in with this client's password) and returns them
        as an iterator of dicts: ``for event in c.events(): ...``.
        ``timeout``: seconds to wait for each event (TimeoutError), or None
        to wait as long as it takes. See :class:`lluav.Events`."""
        return Events(self.url, self._password, self._ssl, self.timeout, timeout)

    def close(self) -> None:
        """Closes the connection (the WebSocket closing handshake). Idempotent."""
        with self._lock:
            self._abandon("the client is closed")

    @property
    def closed(self) -> bool:
        """Whether the connection is closed or lost."""
        return self._ws is None

    def __enter__(self) -> Client:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<lluav.Client {self.url} {'closed' if self.closed else 'open'}>"


def _make(cid: int) -> Callable[..., dict[str, Any]]:
    def method(self: Client, *args: Any, **kwargs: Any) -> dict[str, Any]:
        return self._request(_encode(cid, args, kwargs), cid)

    return method


_methods.install(Client, _make)
