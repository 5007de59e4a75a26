"""Round trips per second of the SDK against a plain `websockets` loop
sending the same frame to the same lluavd, in the same run; and the cost of
the SDK's local validation per call.

    python python/bench/roundtrips.py [--lluavd target/release/lluavd] [--seconds 0.5] [--rounds 20]

Starts its own lluavd (no password, fresh data directory, port 0). Each
scenario runs `--rounds` short rounds, alternating which side goes first;
the figures are medians over the rounds: round trips per second (wall
clock, client and lluavd on the same machine), the ratio SDK/plain of each
round, and the client process's CPU time per round trip (less disturbed by
other load on the machine than the wall clock).

"plain" sends the frame and receives the reply with `websockets` alone;
"plain+json" also decodes the reply with `json.loads`, which any caller
that reads the answer has to do and which the SDK does for every call.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import timeit
from collections.abc import Awaitable
from typing import Any, Callable, NamedTuple

from websockets.asyncio.client import connect as aconnect
from websockets.sync.client import connect

import lluav

FRAME = "state"


class Run(NamedTuple):
    calls: int
    wall_s: float
    cpu_s: float

    @property
    def rate(self) -> float:
        return self.calls / self.wall_s

    @property
    def cpu_us(self) -> float:
        return self.cpu_s / self.calls * 1e6


def start_lluavd(binary: str, data_dir: str) -> tuple[subprocess.Popen[bytes], str]:
    proc = subprocess.Popen(
        [binary, "--bind", "127.0.0.1:0", "--data-dir", data_dir],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env={k: v for k, v in os.environ.items() if k != "LLUAV_PASSWORD"},
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().decode().strip()
    if not line.startswith("listening on "):
        proc.kill()
        sys.exit(f"lluavd did not start: {line!r}")
    return proc, line[len("listening on ") :]


def timed_loop(call: Callable[[], Any], seconds: float) -> Run:
    for _ in range(100):  # warm up
        call()
    n = 0
    cpu, start = time.process_time(), time.perf_counter()
    end = start + seconds
    while time.perf_counter() < end:
        call()
        n += 1
    return Run(n, time.perf_counter() - start, time.process_time() - cpu)


def sync_plain(url: str, seconds: float, decode: bool) -> Run:
    with connect(url, compression=None) as ws:

        def call() -> Any:
            ws.send(FRAME)
            reply = ws.recv()
            return json.loads(reply) if decode else reply

        return timed_loop(call, seconds)


def sync_sdk(url: str, seconds: float) -> Run:
    with lluav.Client(url) as c:
        return timed_loop(c.state, seconds)


async def many(calls: list[Callable[[], Awaitable[Any]]], seconds: float) -> Run:
    for call in calls:
        await call()
    counts = [0] * len(calls)
    cpu, start = time.process_time(), time.perf_counter()
    end = start + seconds

    async def worker(i: int) -> None:
        call = calls[i]
        while time.perf_counter() < end:
            await call()
            counts[i] += 1

    await asyncio.gather(*(worker(i) for i in range(len(calls))))
    return Run(sum(counts), time.perf_counter() - start, time.process_time() - cpu)


async def async_plain(url: str, seconds: float, n: int, decode: bool) -> Run:
    conns = [await aconnect(url, compression=None) for _ in range(n)]

    def caller(ws: Any) -> Callable[[], Awaitable[Any]]:
        async def call() -> Any:
            await ws.send(FRAME)
            reply = await ws.recv()
            return json.loads(reply) if decode else reply

        return call

    try:
        return await many([caller(ws) for ws in conns], seconds)
    finally:
        await asyncio.gather(*(ws.close() for ws in conns))


async def async_sdk(url: str, seconds: float, n: int) -> Run:
    clients = [await lluav.AsyncClient(url).connect() for _ in range(n)]
    try:
        return await many([c.state for c in clients], seconds)
    finally:
        await asyncio.gather(*(c.close() for c in clients))


def rounds(n: int, sides: dict[str, Callable[[], Run]]) -> dict[str, list[Run]]:
    """Runs every side once per round, reversing the order every round."""
    names = list(sides)
    runs: dict[str, list[Run]] = {name: [] for name in names}
    for r in range(n):
        for name in names if r % 2 == 0 else names[::-1]:
            runs[name].append(sides[name]())
    return runs


def report(title: str, runs: dict[str, list[Run]]) -> None:
    sdk = runs["SDK"]
    print(title)
    for name, side in runs.items():
        ratio = statistics.median(s.rate / p.rate for s, p in zip(sdk, side))
        print(
            f"  {name:12} {statistics.median(r.rate for r in side):9.0f} rt/s"
            f"  {statistics.median(r.cpu_us for r in side):6.1f} us client CPU/rt"
            + ("" if name == "SDK" else f"   SDK/{name} {ratio:.2f}")
        )


def ns_per_call(stmt: Callable[[], object], number: int = 100_000) -> float:
    return min(timeit.repeat(stmt, number=number, repeat=7)) / number * 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lluavd", default=os.environ.get("LLUAVD", "target/release/lluavd"))
    ap.add_argument("--seconds", type=float, default=0.5, help="length of one round of one side")
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--clients", type=int, default=100)
    args = ap.parse_args()
    s, n = args.seconds, args.clients

    print(f"lluavd {args.lluavd}; frame {FRAME!r}; {args.rounds} rounds of {s} s per side; medians")
    with tempfile.TemporaryDirectory() as data_dir:
        proc, url = start_lluavd(args.lluavd, data_dir)
        try:
            report(
                "Client.state(), one connection (sync)",
                rounds(
                    args.rounds,
                    {
                        "plain": lambda: sync_plain(url, s, False),
                        "plain+json": lambda: sync_plain(url, s, True),
                        "SDK": lambda: sync_sdk(url, s),
                    },
                ),
            )
            report(
                "AsyncClient.state(), one connection",
                rounds(
                    args.rounds,
                    {
                        "plain": lambda: asyncio.run(async_plain(url, s, 1, False)),
                        "plain+json": lambda: asyncio.run(async_plain(url, s, 1, True)),
                        "SDK": lambda: asyncio.run(async_sdk(url, s, 1)),
                    },
                ),
            )
            report(
                f"AsyncClient.state(), {n} clients at once (one connection each)",
                rounds(
                    max(args.rounds // 2, 1),
                    {
                        "plain": lambda: asyncio.run(async_plain(url, s * 2, n, False)),
                        "plain+json": lambda: asyncio.run(async_plain(url, s * 2, n, True)),
                        "SDK": lambda: asyncio.run(async_sdk(url, s * 2, n)),
                    },
                ),
            )
        finally:
            proc.terminate()
            proc.wait()

    print("local validation and encoding per call (lluav-core through PyO3), best of 7:")
    for name, stmt in [
        ('encode("state")', lambda: lluav.encode("state")),
        ('encode("set_sp_ned", 1.0, 2.0, -3.0, 0.5)', lambda: lluav.encode("set_sp_ned", 1.0, 2.0, -3.0, 0.5)),
        ('encode("mw_exec", 1001, [1, 2, 3, 5])', lambda: lluav.encode("mw_exec", 1001, [1, 2, 3, 5])),
        ('encode("mission", 1001, {3 waypoints})', lambda: lluav.encode("mission", 1001, MISSION)),
        ('parse("set_sp_ned 1:2:-3:0.5")', lambda: lluav.parse("set_sp_ned 1:2:-3:0.5")),
        ("an empty Python call (floor)", lambda: None),
    ]:
        print(f"  {name:45} {ns_per_call(stmt):7.0f} ns")


MISSION = {"waypoints": [{"x": 0, "y": 0, "z": -4}, {"x": 6, "y": 0, "z": -4}, {"x": 6, "y": 6, "z": -6, "yaw": 1.0}]}

if __name__ == "__main__":
    main()
