"""lluavd over a lossy radio link and on a shared port, for BENCHMARKS.md
("MAVLink over a lossy link").

1. Flights: the MAVSDK autopilot behind the seeded lossy relay (relay.py),
   the same loss both ways, 20-40 ms of latency. Each flight is the same
   eight steps, each tried once, in order: link up, upload a 3-waypoint
   mission, upload a 50-waypoint mission, takeoff, hover, set_sp_ned and
   reach it, mw_exec the 3 waypoints and fly them, land and be disarmed.
   For each answer, what the autopilot did is read on the autopilot's side
   (armed and climbing, the mission it holds, its mode, where it is): an
   answer that disagrees with it is counted, and so is every cleanup
   message no client asked for that reached it (disarm, MISSION_CLEAR_ALL,
   a cancelled transfer).
2. Garbage: the autopilot hovering on a clean link with a setpoint
   streamed, a hostile neighbour (hostile.py) sending random datagrams to
   lluavd's port at each rate: setpoints per second at the autopilot and
   what lluavd sent to the neighbour.

    python tests/mavlink/lossy_bench.py --lluavd target/debug/lluavd
        [--losses 0,5,15,30] [--seeds 1,2,3] [--garbage-rates 0,1,100,2000]
        [--garbage-seconds 10] [--skip-flights] [--skip-garbage]

Prints one JSON line per flight and per garbage rate, then a summary in
Markdown.
"""

import argparse
import json
import math
import os
import pathlib
import statistics
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from conftest import Daemon, free_udp_port, wait_for  # noqa: E402
from hostile import Neighbour  # noqa: E402
from mavsdk_autopilot import MavsdkAutopilot  # noqa: E402
from radio import cancelled_transfers, per_second, setpoints_since, unrequested, waypoints  # noqa: E402
from relay import LossyRelay  # noqa: E402

STEPS = ("link", "mission_3", "mission_50", "takeoff", "hover", "set_sp_ned", "mw_exec", "land")
LAST_WP = (3 * math.cos(4 * math.pi / 3), 3 * math.sin(4 * math.pi / 3))


def happens(predicate, timeout):
    """True if `predicate` holds within `timeout` seconds."""
    try:
        wait_for("", predicate, timeout=timeout)
        return True
    except AssertionError:
        return False


class Flight:
    """One flight; `steps` records each step: done, the answer, how long
    the answer took, and whether the answer agreed with the autopilot."""

    def __init__(self, client, ap):
        self.client, self.ap = client, ap
        self.steps = {}

    def answer(self, step, text, timeout=60):
        start = time.monotonic()
        try:
            r = self.client.cmd(text, timeout=timeout)
        except TimeoutError:
            r = {"ret": None}
        self.steps[step] = {"ret": r["ret"], "s": round(time.monotonic() - start, 2)}
        if r["ret"] not in (0, None):
            self.steps[step]["msg"] = r.get("msg")
        return r["ret"]

    def judge(self, step, ret, happened, done=None):
        """`happened`: did the autopilot do it; `done`: the step's own goal
        (defaults to `happened` after a 0)."""
        s = self.steps[step]
        s["happened"] = happened
        s["disagrees"] = (ret == 0) != happened
        s["done"] = ret == 0 and happened if done is None else done

    def mission(self, step, ext_id, n):
        ret = self.answer(step, f"mission {ext_id}:{waypoints(n, radius=3)}")
        held = happens(lambda: len(self.ap.holding) == n, 3)
        self.judge(step, ret, held)

    def fly(self):
        c, ap = self.client, self.ap
        up = happens(lambda: (s := c.state())["link"] == "up" and s["home_global"], 30)
        self.steps["link"] = {"done": up}
        if not up:
            return
        self.mission("mission_3", 3, 3)
        self.mission("mission_50", 50, 50)
        ret = self.answer("takeoff", "takeoff")
        climbing = happens(lambda: ap.armed and ap.position()[2] < -0.3, 8)
        self.judge("takeoff", ret, climbing)
        if not climbing:
            return
        hovering = happens(lambda: c.state()["fsm"] == "hover", 20)
        self.steps["hover"] = {"done": hovering}
        ret = self.answer("set_sp_ned", "set_sp_ned 3:2:-4:0")
        following = happens(lambda: ap.mode == "offboard", 5)
        self.judge("set_sp_ned", ret, following,
                   done=ret == 0 and happens(lambda: math.dist(ap.position(), [3, 2, -4]) < 0.3, 20))
        ret = self.answer("mw_exec", "mw_exec 3:1,2,3")
        started = happens(lambda: ap.mode in ("mission", "hold") and len(ap.holding) == 3, 5)
        self.judge("mw_exec", ret, started, done=ret == 0 and started and happens(
            lambda: ap.mode == "hold" and math.dist(ap.position()[:2], LAST_WP) < 0.3, 40))
        ret = self.answer("land", "land")
        landing = happens(lambda: ap.mode in ("land", "landed", "ready"), 5)
        self.judge("land", ret, landing, done=ret == 0 and happens(lambda: not ap.armed, 30))


def flight(exe, loss, seed):
    radio = dict(loss=loss / 100, latency=0.02, jitter=0.02)
    port = free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["LLUAVD"] = exe
        daemon = Daemon(pathlib.Path(tmp), port)
        relay = LossyRelay(port, seed, radio, radio)
        ap = MavsdkAutopilot(relay.port)
        client = daemon.client(keepalive=False)
        f = Flight(client, ap)
        start = time.monotonic()
        try:
            f.fly()
        finally:
            took = time.monotonic() - start
            ap.close()
            extra = unrequested(relay)
            cancelled = cancelled_transfers(relay)
            counters = relay.counters()
            relay.close()
            daemon.stop()
    return {"loss": loss, "seed": seed, "steps": f.steps, "unrequested": extra, "cancelled_transfers": cancelled,
            "seconds": round(took, 1), "relay": counters}


def garbage(exe, rates, seconds):
    port = free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["LLUAVD"] = exe
        daemon = Daemon(pathlib.Path(tmp), port)
        ap = MavsdkAutopilot(port)
        client = daemon.client()
        try:
            wait_for("link up", lambda: (s := client.state())["link"] == "up" and s["home_global"], 30)
            client.ok("takeoff")
            wait_for("hover", lambda: client.state()["fsm"] == "hover", 30)
            client.ok("set_sp_ned 2:0:-3:0")
            for rate in rates:
                neighbour = Neighbour(port, seed=rate, garbage_rate=rate) if rate else None
                start = time.monotonic()
                time.sleep(seconds)
                counts = per_second(setpoints_since(ap, start), start, seconds)
                result = neighbour.stop() if neighbour else {"sent": {}, "received": {}}
                yield {"garbage_per_s": rate, "setpoints_per_s": counts,
                       "garbage_sent": result["sent"].get("garbage", 0),
                       "lluavd_sent_to_neighbour": result["received"]}
        finally:
            ap.close()
            daemon.stop()


def summary(flights, garbage_runs):
    print("\n| loss both ways | flights complete | steps done | takeoff answer (s, median) "
          "| 3-wp upload (s) | 50-wp upload (s) | answers contradicting the autopilot | unrequested |")
    print("|---|---|---|---|---|---|---|---|")
    for loss in sorted({f["loss"] for f in flights}):
        runs = [f for f in flights if f["loss"] == loss]
        done = [sum(1 for s in STEPS if f["steps"].get(s, {}).get("done")) for f in runs]

        def med(step, runs=runs):
            ts = [f["steps"][step]["s"] for f in runs
                  if step in f["steps"] and f["steps"][step].get("done")]
            return f"{statistics.median(ts):.2f}" if ts else "-"

        wrong = sum(1 for f in runs for s in f["steps"].values() if s.get("disagrees"))
        extra = sum(len(f["unrequested"]) for f in runs)
        print(f"| {loss} % | {sum(d == len(STEPS) for d in done)}/{len(runs)} "
              f"| {'+'.join(str(d) for d in done)} of {len(STEPS)} each | {med('takeoff')} "
              f"| {med('mission_3')} | {med('mission_50')} | {wrong} | {extra} |")
    if garbage_runs:
        print("\n| garbage datagrams/s | setpoints/s at the autopilot (min, mean) | lluavd sent to the neighbour |")
        print("|---|---|---|")
        for g in garbage_runs:
            c = g["setpoints_per_s"]
            print(f"| {g['garbage_per_s']} | {min(c)}, {statistics.mean(c):.1f} "
                  f"| {sum(g['lluavd_sent_to_neighbour'].values())} messages |")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--lluavd", default=str(HERE.parent.parent / "target" / "debug" / "lluavd"))
    p.add_argument("--losses", default="0,5,15,30")
    p.add_argument("--seeds", default="1,2,3")
    p.add_argument("--garbage-rates", default="0,1,100,2000")
    p.add_argument("--garbage-seconds", type=int, default=10)
    p.add_argument("--skip-flights", action="store_true")
    p.add_argument("--skip-garbage", action="store_true")
    args = p.parse_args()
    flights, garbage_runs = [], []
    if not args.skip_flights:
        for loss in (int(x) for x in args.losses.split(",")):
            for seed in (int(x) for x in args.seeds.split(",")):
                f = flight(args.lluavd, loss, seed)
                print(json.dumps(f), flush=True)
                flights.append(f)
    if not args.skip_garbage:
        rates = [int(x) for x in args.garbage_rates.split(",")]
        for g in garbage(args.lluavd, rates, args.garbage_seconds):
            print(json.dumps(g), flush=True)
            garbage_runs.append(g)
    summary(flights, garbage_runs)


if __name__ == "__main__":
    main()
