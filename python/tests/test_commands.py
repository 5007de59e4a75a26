"""Every generated method, called against the real lluavd with valid
arguments of its grammar (tests/values.py), synchronously and on asyncio.

The server must have read every frame as the SDK meant it: the response is
for the same command, and no call is refused for its arguments' shape
(`Invalid arguments, usage: ...`). A command may still be refused for the
vehicle's state or a value the vehicle will not take (ret -1/-2 with a
reason); those refusals are counted and must stay the exception.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from values import MISSION, VALID, call_args

import lluav

USAGE_REFUSAL = "Invalid arguments, usage:"


def calls(spec: lluav.Spec) -> list[tuple[tuple[Any, ...], dict[str, Any]]]:
    """The calls of one command: each valid value of its grammar."""
    return [call_args(entry) for entry in VALID[spec.grammar]]


def prepare(data_dir: Path) -> None:
    """The files the path arguments of tests/values.py name."""
    missions = data_dir / "missions"
    missions.mkdir(exist_ok=True)
    (missions / "m1.json").write_text(json.dumps(MISSION))


class Tally:
    def __init__(self) -> None:
        self.ok: set[str] = set()
        self.refused: dict[str, str] = {}

    def answer(self, spec: lluav.Spec, entry: Any, outcome: dict[str, Any] | lluav.CommandError) -> None:
        if isinstance(outcome, lluav.CommandError):
            assert outcome.cmd == spec.id, (spec.name, entry, outcome.response)
            assert outcome.ret in (-1, -2, -3), (spec.name, entry, outcome.response)
            assert not outcome.msg.startswith(USAGE_REFUSAL), (spec.name, entry, outcome.response)
            self.refused[f"{spec.name}{entry}"] = outcome.msg
        else:
            assert (outcome["ret"], outcome["cmd"]) == (0, spec.id), (spec.name, entry, outcome)
            assert isinstance(outcome["ts"], int)
            self.ok.add(spec.name)

    def check(self) -> None:
        total = sum(len(calls(s)) for s in lluav.COMMANDS)
        # Every command was called; most calls ran. The refusals are the
        # simulator's to decide (a command that needs a flight, a value out
        # of its range), never the SDK's.
        assert len(self.refused) <= total // 5, self.refused
        print(f"{len(self.ok)} commands ran; refused by the vehicle: {self.refused}")
        assert len(self.ok) >= len(lluav.COMMANDS) * 3 // 4, sorted(set(s.name for s in lluav.COMMANDS) - self.ok)


def test_every_method_reaches_lluavd_as_the_sdk_meant_it(lluavd):
    daemon = lluavd()
    prepare(daemon.data_dir)
    tally = Tally()
    with lluav.Client(daemon.url, password="1025") as c:
        for spec in lluav.COMMANDS:
            method = getattr(c, spec.name)
            for args, kwargs in calls(spec):
                if not spec.run_on_arm:
                    c.disarm()  # the vehicle may still fly from an earlier command
                try:
                    outcome: Any = method(*args, **kwargs)
                except lluav.CommandError as e:
                    outcome = e
                tally.answer(spec, (args, kwargs), outcome)
    tally.check()


def test_every_async_method_reaches_lluavd_as_the_sdk_meant_it(lluavd):
    daemon = lluavd()
    prepare(daemon.data_dir)
    tally = Tally()

    async def run() -> None:
        async with lluav.AsyncClient(daemon.url, password="1025") as c:
            for spec in lluav.COMMANDS:
                method = getattr(c, spec.name)
                for args, kwargs in calls(spec):
                    if not spec.run_on_arm:
                        await c.disarm()  # the vehicle may still fly from an earlier command
                    try:
                        outcome: Any = await method(*args, **kwargs)
                    except lluav.CommandError as e:
                        outcome = e
                    tally.answer(spec, (args, kwargs), outcome)

    asyncio.run(run())
    tally.check()
