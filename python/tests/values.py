"""Argument values per grammar, for the table-driven tests.

Keyed by the core's grammar name, so a command added to the table later is
covered automatically; a grammar added later makes the tests fail until it
has values here.
"""

from __future__ import annotations

from typing import Any

MISSION = {
    "waypoints": [{"id": 1, "x": 1.0, "y": 0.0, "z": -2.0}, {"id": 2, "x": 2.0, "y": 1.0, "z": -2.5, "yaw": 0.5}]
}

# Arguments the core accepts (positional tuples or keyword dicts), with
# every optional parameter both left out and given.
VALID: dict[str, list[Any]] = {
    "None": [()],
    "Flag": [(True,), (False,), (1,)],
    "OptCount": [(), (5,), {}],
    "Pwm": [(1500,), (0,), (65535,)],
    "Amount": [(12.5,), (0,)],
    "OptAmount": [(), (0.5,)],
    "Angle": [(-45.0,), (90,)],
    "Name": [("m1",)],
    "OptName": [(), ("restart.sh",)],
    "Path": [("maps/m1",)],
    "Text": [("survey north field",), ("p" * 4096,)],
    "TaskName": [("inspection east",), ("t" * 256,)],
    "Secret": [("1025",)],
    "NewPassword": [("n3w-Pass!",)],
    "ParamName": [("takeoff_alt",)],
    "SetParam": [("takeoff_alt", 3.5), ("rtl_land", True), ("mavlink_rate", 40), ("takeoff_alt", "2.5")],
    "Setpoint": [(1.0, 2.0, -3.0, 0.5), {"x": 0, "y": 0, "z": -2, "yaw": 0}],
    "Point": [(1.0, 2.0, -3.0)],
    "Pose": [(1.0, 2.0, -3.0, 0.5)],
    "Zyhk": [([1.5, 2.0],), ([1.5], (0.0, 0.0, 0.0)), {"heights": (2.0,), "land": [1.0, 1.0, 0.5]}],
    "Mission": [(1001, MISSION), (1002, MISSION["waypoints"]), (1003, "missions/m1.json")],
    "MwExec": [(1001, [1, 2]), (1001, (1,))],
    "Ai1Mission": [("task-1", "missions/m1.json")],
    "Override": [(), (True,), (False,), {"failsafe": True}],
}

# Arguments the SDK refuses before sending, per grammar: wrong types,
# values outside the grammar, wrong counts. Each must raise InvalidArguments.
INVALID: dict[str, list[Any]] = {
    "None": [(1,), {"x": 1}],
    "Flag": [(), (2,), ("1",), (None,), (1.0,)],
    "OptCount": [(-1,), (2**32,), (1.5,), ("3",), (True,), (1, 2)],
    "Pwm": [(), (65536,), (-1,), (1.0,), (None,)],
    "Amount": [(), (-0.5,), (float("nan"),), (float("inf"),), ("1",), (True,), (1e39,)],
    "OptAmount": [(-1.0,), (float("nan"),), ("1",)],
    "Angle": [(), (90.5,), (-91,), (float("inf"),), ("0",)],
    "Name": [
        (),
        ("",),
        ("a/b",),
        ("..",),
        (".hidden",),
        ("evil\u202egpj.exe",),
        ("x" * 129,),
        ("bad\nname",),
        (" padded",),
        (b"m1",),
        (1,),
    ],
    "OptName": [("a/b",), ("..",), ("",), (1,)],
    "Path": [(), ("",), ("/etc/passwd",), ("../up",), ("a//b",), ("a/../b",), ("x" * 1025,), (1,)],
    "Text": [(), ("",), ("trailing ",), ("line\nbreak",), ("a\u202eb",), ("p" * 4097,), (1,)],
    "TaskName": [(), ("",), ("a\u202eb",), ("zero\u200bwidth",), ("t" * 257,), (1,)],
    "Secret": [(), ("",), ("tab\t",), (1025,)],
    "NewPassword": [(), ("",), ("has space",), ("x" * 33,), ("nön-ascii",), ("1025",), ("0315",), (1,)],
    "ParamName": [(), ("",), ("bad name",), ("a:b",), ("x" * 65,), (1,)],
    "SetParam": [
        ("takeoff_alt",),
        ("bad name", 1),
        ("takeoff_alt", float("nan")),
        ("takeoff_alt", None),
        ("takeoff_alt", [1]),
        ("takeoff_alt", ""),
    ],
    "Setpoint": [
        (1.0, 2.0, 0.0, 0.0),
        (1.0, 2.0, 3.0, 0.0),
        (1.0, 2.0, 3.0),
        (1.0, 2.0, 3.0, float("nan")),
        (1.0, 2.0, 3.0, "4"),
        (1, 2, 3, 4, 5),
        {"x": 1, "y": 2, "z": 3, "w": 4},
        (1.0, 2.0, 3.0, None),
    ],
    "Point": [(1.0, 2.0), (1.0, 2.0, float("inf")), (1.0, "2", 3.0)],
    "Pose": [(1.0, 2.0, 3.0), (1.0, 2.0, 3.0, float("-inf"))],
    "Zyhk": [
        (),
        ([],),
        ([1.0] * 33,),
        ([float("nan")],),
        ("1.5",),
        (1.5,),
        ([1.0], (0.0, 0.0)),
        ([1.0], (0.0, 0.0, float("nan"))),
        ([1.0], "0,0,0"),
    ],
    "Mission": [
        (1001,),
        (-1, MISSION),
        (2**32, MISSION),
        (1001, {"x": float("nan")}),
        (1001, {"x": object()}),
        (1001, '{"waypoints":[]}'),
        (1001, "/abs/path.json"),
        (1001, "../up.json"),
        (1001, 5),
        (1001, None),
    ],
    "MwExec": [
        (1001,),
        (1001, []),
        (1001, [1] * 65),
        (1001, [-1]),
        (1001, [1.5]),
        (1001, "1,2"),
        (-1, [1]),
        (1001, None),
    ],
    "Ai1Mission": [
        ("task-1",),
        ("bad task", "m.json"),
        ("task:1", "m.json"),
        ("task-1", "/abs.json"),
        ("task-1", "../up.json"),
        ("", "m.json"),
    ],
    "Override": [(2,), ("failsafe",), (1.0,), (True, True)],
}


def call_args(args: Any) -> tuple[tuple[Any, ...], dict[str, Any]]:
    """(positional, keyword) arguments from a table entry."""
    return ((), dict(args)) if isinstance(args, dict) else (tuple(args), {})
