"""Which side gives up a 50-item mission upload over a lossy link: lluavd
or the MAVSDK autopilot (its MissionRawServer), for BENCHMARKS.md
("MAVLink over a lossy link").

    python tests/mavlink/upload_probe.py --lluavd target/debug/lluavd
        [--loss 0.25] [--seed 7] [--uploads 6]

One lluavd, one autopilot behind the seeded lossy relay (relay.py), the
same loss both ways; the uploads one after the other. Prints one JSON
line per upload: lluavd's answer and its time, the items the autopilot
holds, and the transfers the autopilot itself failed (MAVSDK's result
numbers: "5" is TIMEOUT). After a failed transfer or answer, the
autopilot's last MISSION_REQUEST_INTs as it sent them (before the relay's
loss): time, seq, whether the relay delivered it. Then lluavd's log lines
about stalls and restarts.
"""

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from conftest import Daemon, free_udp_port, wait_for  # noqa: E402
from mavsdk_autopilot import MavsdkAutopilot  # noqa: E402
from radio import waypoints  # noqa: E402
from relay import LossyRelay  # noqa: E402


def record_requests(relay):
    """The autopilot's MISSION_REQUEST_INTs as it sends them, with their fate."""
    requests = []
    fate = relay.up.fate

    def logged(now, msgs):
        delays = fate(now, msgs)
        requests.extend((round(now, 2), m.seq, bool(delays)) for m in msgs
                        if m.get_type() == "MISSION_REQUEST_INT")
        return delays

    relay.up.fate = logged
    return requests


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--lluavd", default=str(HERE.parent.parent / "target" / "debug" / "lluavd"))
    p.add_argument("--loss", type=float, default=0.25)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--uploads", type=int, default=6)
    args = p.parse_args()
    os.environ["LLUAVD"] = args.lluavd
    radio = dict(loss=args.loss, latency=0.02, jitter=0.02)
    port = free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        daemon = Daemon(pathlib.Path(tmp), port)
        relay = LossyRelay(port, args.seed, radio, radio)
        requests = record_requests(relay)
        ap = MavsdkAutopilot(relay.port)
        try:
            client = daemon.client(keepalive=False)
            wait_for("link up", lambda: (s := client.state())["link"] == "up" and s["home_global"], 30)
            for i in range(args.uploads):
                failed, mark, start = len(ap.failed_uploads), len(requests), time.monotonic()
                r = client.cmd(f"mission {i + 1}:{waypoints(50, radius=3)}", timeout=90)
                gave_up = [str(x) for x in ap.failed_uploads[failed:]]
                print(json.dumps({"upload": i + 1, "ret": r["ret"], "msg": r.get("msg"),
                                  "s": round(time.monotonic() - start, 1), "held": len(ap.holding),
                                  "autopilot_failed": gave_up}), flush=True)
                if gave_up or r["ret"] != 0:
                    print("  requests (t, seq, delivered):", requests[mark:][-12:], flush=True)
        finally:
            ap.close()
            relay.close()
            daemon.stop()
        for line in (pathlib.Path(tmp) / "lluavd.log").read_text().splitlines():
            if "stalled" in line or "starting" in line:
                print("  lluavd:", line[-160:])


if __name__ == "__main__":
    main()
