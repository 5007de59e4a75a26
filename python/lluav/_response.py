"""Responses: one JSON object per request, checked before it is returned."""

from __future__ import annotations

import json
from typing import Any

from ._errors import CommandError, ConnectionError

_loads = json.loads


def check(message: str | bytes, cid: int) -> dict[str, Any]:
    """The response to a request for command ``cid`` (0: a name the table
    does not know), or the error it stands for.

    The server answers every request with one JSON object whose ``cmd`` is
    the request's command id (0 for an unknown name, also for errors), so a
    ``cmd`` that belongs to another command means requests and responses
    no longer pair up: that is a connection fault, not a command failure.
    """
    if not isinstance(message, str):
        raise ConnectionError("the server sent a binary message instead of a JSON response")
    try:
        response = _loads(message)
    except ValueError:
        raise ConnectionError(f"the server sent something that is not JSON: {message[:80]!r}") from None
    return check_response(response, cid, message)


def check_response(response: Any, cid: int, text: str | None = None) -> dict[str, Any]:
    """:func:`check` of a response already read from JSON (an uplink
    answer's ``response``); ``text`` is what to quote when it is not one."""
    if not isinstance(response, dict) or type(response.get("ret")) is not int:
        quoted = text if text is not None else json.dumps(response)
        raise ConnectionError(f"the server sent something that is not a protocol response: {quoted[:80]!r}")
    cmd = response.get("cmd")
    if cmd != cid and not (cmd == 0 and response["ret"] != 0):
        raise ConnectionError(
            f"the response is for command {cmd!r}, the request was for command {cid}: "
            "responses no longer pair up with requests"
        )
    if response["ret"] != 0:
        raise CommandError(response)
    return response
