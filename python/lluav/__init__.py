"""lluav: the Python SDK of the LLUAV WebSocket command protocol for drones.

The command table, argument validation and encoding are lluav-core's own
(the Rust core the servers are built on), reached through PyO3, so this
package cannot disagree with a server about a command.

>>> import lluav
>>> with lluav.Client("ws://127.0.0.1:53001", password="s3cret") as c:  # doctest: +SKIP
...     c.takeoff()
...     c.set_sp_ned(5.0, 0.0, -3.0, 0.0)
...     c.land()

- :class:`Client` (synchronous) and :class:`AsyncClient` (asyncio): one
  method per command, named and typed after the table, plus ``call(frame)``.
- :class:`Fleet` and :class:`AsyncFleet`: vehicles through an MQTT broker
  (lluavd's uplink); ``fleet.vehicle(V)`` has the same methods.
- Events (what happened, pushed as it happens): ``client.events()``,
  ``fleet.events(vehicle=None)`` iterate over them as dicts
  (:class:`Events`, :class:`AsyncEvents`, :class:`FleetEvents`,
  :class:`AsyncFleetEvents`).
- :func:`parse`: a frame read exactly as the server reads it; :func:`encode`:
  the frame a method would send.
- :data:`COMMANDS`: the command table, in id order.
- Errors: :class:`Error` and its subclasses :class:`InvalidArguments`,
  :class:`UnknownCommand`, :class:`CommandError`, :class:`ConnectionError`.
"""

from __future__ import annotations

from typing import Any

from ._async import AsyncClient
from ._core import TABLE, Command, Param, Spec
from ._core import encode as _encode
from ._core import parse as _parse
from ._errors import CommandError, ConnectionError, Error, InvalidArguments, UnknownCommand
from ._events import AsyncEvents, AsyncFleetEvents, Events, FleetEvents
from ._fleet import AsyncFleet, AsyncFleetVehicle, Fleet, FleetVehicle
from ._sync import DEFAULT_URL, Client

COMMANDS: tuple[Spec, ...] = TABLE
"""Every command of the protocol, in id order (``COMMANDS[id - 1]``)."""

_IDS = {spec.name: spec.id for spec in TABLE}


def encode(command: str, /, *args: Any, **kwargs: Any) -> str:
    """The frame a client method sends for these arguments, validated the
    same way (``encode("set_sp_ned", 1.0, 2.0, -3.0, 0.5)`` is
    ``"set_sp_ned 1.0:2.0:-3.0:0.5"``), for logging or another transport.

    Raises InvalidArguments like the method, UnknownCommand for a name that
    is not in the table.
    """
    cid = _IDS.get(command)
    if cid is None:
        raise UnknownCommand(f"Unsupported command: {command}")
    return _encode(cid, args, kwargs)


def parse(frame: str) -> Command:
    """Reads a frame exactly as the server will: the command's ``name``,
    ``id`` and ``args`` (a dict keyed like the client method's parameters)
    and the canonical ``frame``.

    Raises InvalidArguments (with the usage line) for a known command with
    bad arguments, UnknownCommand for an empty frame or an unknown name.
    """
    return _parse(frame)


__all__ = [
    "COMMANDS",
    "DEFAULT_URL",
    "AsyncClient",
    "AsyncEvents",
    "AsyncFleet",
    "AsyncFleetEvents",
    "AsyncFleetVehicle",
    "Client",
    "Command",
    "CommandError",
    "ConnectionError",
    "Error",
    "Events",
    "Fleet",
    "FleetEvents",
    "FleetVehicle",
    "InvalidArguments",
    "Param",
    "Spec",
    "UnknownCommand",
    "encode",
    "parse",
]
