"""TLS for ``wss://`` URLs."""

from __future__ import annotations

import os
import selectors
import socket
import ssl
import threading
import time
from typing import Any, Callable, TypeVar

T = TypeVar("T")


def context(url: str, cafile: str | None) -> ssl.SSLContext | None:
    """The TLS context for ``url``: the system's trust store, or only
    ``cafile`` (a PEM file of CA certificates, e.g. a self-signed one)."""
    secure = url.lower().startswith("wss://")
    if cafile is None:
        ctx = ssl.create_default_context() if secure else None
    elif not secure:
        raise ValueError(f"cafile is for wss:// URLs, not {url!r}")
    else:
        ctx = ssl.create_default_context(cafile=cafile)
    if ctx is not None:
        # Only the blocking clients' sockets: asyncio's TLS goes through
        # SSLObject on one thread and needs none of this.
        ctx.sslsocket_class = OneCallAtATime
    return ctx


class OneCallAtATime(ssl.SSLSocket):
    """An SSLSocket that a reading thread and a writing thread may share.

    websockets' blocking connection reads on a thread of its own while the
    caller writes, but an OpenSSL connection is not safe to use from two
    threads at once. The damage is real: a TLS 1.3 server's session
    tickets arrive just after the handshake, and when the reader handles
    them while the upgrade request is being written, the request is lost
    and the client waits for an answer that never comes (1 to 3 % of
    connections to lluavd and to Python's own TLS server on loopback).

    So after the handshake (which runs on one thread, as usual), every
    call into OpenSSL holds one lock and never blocks: the socket
    underneath is non-blocking, and waiting for the network happens outside
    the lock, honouring the timeout the caller set."""

    def _one(self) -> threading.RLock:
        # Reentrant: SSLSocket.do_handshake calls settimeout itself.
        try:
            return self.__dict__["_lluav_one"]  # type: ignore[no-any-return]
        except KeyError:
            # setdefault is atomic: two threads arriving first share one lock.
            return self.__dict__.setdefault("_lluav_one", threading.RLock())  # type: ignore[no-any-return]

    def _shared(self) -> float | None:
        """Makes the socket non-blocking, once, keeping its timeout as the
        caller's; returns the caller's timeout."""
        if "_lluav_timeout" not in self.__dict__:
            self.__dict__["_lluav_timeout"] = super().gettimeout()
            super().settimeout(0.0)
        return self.__dict__["_lluav_timeout"]  # type: ignore[no-any-return]

    def gettimeout(self) -> float | None:
        with self._one():
            return self.__dict__.get("_lluav_timeout", super().gettimeout())

    def settimeout(self, value: float | None) -> None:
        with self._one():
            if "_lluav_timeout" in self.__dict__:
                self.__dict__["_lluav_timeout"] = value
            else:
                super().settimeout(value)

    def setblocking(self, flag: bool) -> None:
        self.settimeout(None if flag else 0.0)

    def _call(self, op: Callable[[], T], waits_for: int) -> T:
        """Runs ``op`` (non-blocking OpenSSL calls) under the lock until it
        completes, waiting for the socket between tries (``waits_for``
        when the plain socket, after a shutdown, would block)."""
        deadline = None
        while True:
            with self._one():
                timeout = self._shared()
                try:
                    return op()
                except ssl.SSLWantReadError:
                    events = selectors.EVENT_READ
                except ssl.SSLWantWriteError:
                    events = selectors.EVENT_WRITE
                except BlockingIOError:
                    events = waits_for
                if timeout == 0.0:
                    raise BlockingIOError("the socket is not ready")
                # The wait holds a descriptor of its own: a close meanwhile
                # cannot free the number for another file, and its
                # shutdown (see close) ends the wait.
                waiting_on = os.dup(self.fileno())
            if timeout is not None and deadline is None:
                deadline = time.monotonic() + timeout
            try:
                _wait(waiting_on, events, deadline)
            finally:
                os.close(waiting_on)

    def do_handshake(self, block: bool = False) -> None:
        if "_lluav_timeout" not in self.__dict__:
            super().do_handshake(block)
        else:
            shake = super().do_handshake
            self._call(shake, selectors.EVENT_READ)

    def recv(self, buflen: int = 1024, flags: int = 0) -> bytes:
        read = super().recv
        return self._call(lambda: read(buflen, flags), selectors.EVENT_READ)

    def recv_into(self, buffer: Any, nbytes: int | None = None, flags: int = 0) -> int:
        read = super().recv_into
        return self._call(lambda: read(buffer, nbytes, flags), selectors.EVENT_READ)

    def send(self, data: Any, flags: int = 0) -> int:
        write = super().send
        return self._call(lambda: write(data, flags), selectors.EVENT_WRITE)

    def shutdown(self, how: int) -> None:
        with self._one():
            super().shutdown(how)

    def unwrap(self) -> socket.socket:
        shut = super().unwrap
        return self._call(shut, selectors.EVENT_READ)

    def close(self) -> None:
        # A reader waiting for data (on its own descriptor) sees the end of
        # the stream and returns.
        with self._one():
            try:
                socket.socket.shutdown(self, socket.SHUT_RDWR)
            except OSError:
                pass
            super().close()


def _wait(fd: int, events: int, deadline: float | None) -> None:
    """Waits until ``fd`` is ready for ``events``, or raises a timeout once
    ``deadline`` (monotonic) passes."""
    with _Selector() as waiting:
        waiting.register(fd, events)
        while not waiting.select(None if deadline is None else max(0.0, deadline - time.monotonic())):
            if deadline is not None and time.monotonic() >= deadline:
                raise socket.timeout("timed out")


_Selector = getattr(selectors, "PollSelector", selectors.SelectSelector)
