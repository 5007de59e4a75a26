"""A scripted WebSocket server for the client's fault handling: it records
every frame it receives and answers with whatever the test says (nothing,
binary, non-JSON, a response for another command). lluavd itself never
misbehaves like this, which is why the faults need a stand-in."""

from __future__ import annotations

import contextlib
import json
import ssl
import threading
from collections.abc import Iterator
from typing import Callable, Optional, Union

from websockets.sync.server import Server, ServerConnection, serve

import lluav

Reply = Optional[Union[str, bytes]]


def ok_reply(frame: str) -> Reply:
    """What a well-behaved server with every command allowed answers."""
    return json.dumps({"ret": 0, "cmd": lluav.parse(frame).id, "ts": 0})


class FakeServer:
    """Serves on a free loopback port; `reply(frame)` gives each answer
    (None: answer nothing)."""

    def __init__(self, reply: Callable[[str], Reply] = ok_reply, tls: ssl.SSLContext | None = None) -> None:
        self.frames: list[str] = []
        self._reply = reply
        self._server: Server = serve(self._handle, "127.0.0.1", 0, ssl=tls, compression=None)
        host, port = self._server.socket.getsockname()[:2]
        self.url = f"{'wss' if tls else 'ws'}://{'localhost' if tls else host}:{port}"
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def _handle(self, ws: ServerConnection) -> None:
        for frame in ws:
            assert isinstance(frame, str)
            self.frames.append(frame)
            answer = self._reply(frame)
            if answer is not None:
                ws.send(answer)

    def close(self) -> None:
        self._server.shutdown()
        self._thread.join(timeout=10)


@contextlib.contextmanager
def serving(reply: Callable[[str], Reply] = ok_reply, tls: ssl.SSLContext | None = None) -> Iterator[FakeServer]:
    """A FakeServer for the length of a `with` block."""
    server = FakeServer(reply, tls)
    try:
        yield server
    finally:
        server.close()
