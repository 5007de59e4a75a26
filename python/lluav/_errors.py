"""The exceptions of the SDK. Every one of them is an ``lluav.Error``."""

from __future__ import annotations

import builtins
from typing import Any

from . import _core


class Error(Exception):
    """Base class of every error the SDK raises."""


class InvalidArguments(Error, ValueError):
    """Arguments that do not fit a command's grammar, caught before sending.

    Raised by the client methods and :func:`lluav.parse`. ``name`` is the
    command, ``usage`` its usage line (``set_sp_ned x:y:z:yaw``) and
    ``reason`` what is wrong.
    """

    def __init__(self, name: str, usage: str, reason: str) -> None:
        super().__init__(name, usage, reason)
        self.name = name
        self.usage = usage
        self.reason = reason

    def __str__(self) -> str:
        return f"{self.name}: {self.reason}; usage: {self.usage}"


class UnknownCommand(Error, ValueError):
    """A frame given to :func:`lluav.parse` that names no command (or is empty)."""


class CommandError(Error):
    """The server answered with ``ret`` other than 0.

    ``ret`` is the code (-1: not now or not allowed, -2: invalid request,
    -3: a system call failed, -100: a fault in the server), ``cmd`` the
    command id the server answered for (0 for an unknown name), ``msg`` the
    server's message and ``response`` the whole response.
    """

    def __init__(self, response: dict[str, Any]) -> None:
        super().__init__(response)
        self.response = response
        self.ret: int = response.get("ret", 0)
        self.cmd: int = response.get("cmd", 0)
        self.msg: str = str(response.get("msg", ""))

    def __str__(self) -> str:
        table = _core.TABLE
        known = isinstance(self.cmd, int) and 0 < self.cmd <= len(table)
        name = table[self.cmd - 1].name if known else f"command {self.cmd}"
        return f"{name} failed with ret {self.ret}: {self.msg}"


class ConnectionError(Error, builtins.ConnectionError):  # noqa: A001 (lluav.ConnectionError on purpose)
    """The connection could not be opened, was lost, timed out, or the
    server sent something that is not a response to the request."""
