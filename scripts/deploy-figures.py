"""lluavd's start-up as systemd sees it: the time from exec to READY=1 on
the notification socket (the median and the fastest of RUNS starts), and
the resident memory of the idle daemon one second after READY=1.

Usage: python3 scripts/deploy-figures.py LLUAVD [RUNS]
Run it on the architecture the binary is for: under qemu-user the time
would be the emulator's.
"""

import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time


def start_once(binary, measure_rss):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "notify")
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(path)
        sock.settimeout(60)
        env = dict(os.environ, NOTIFY_SOCKET=path)
        env.pop("WATCHDOG_USEC", None)
        start = time.perf_counter()
        proc = subprocess.Popen(
            [binary, "--bind", "127.0.0.1:0", "--data-dir", os.path.join(tmp, "data")],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            while b"READY=1" not in sock.recv(4096).split(b"\n"):
                pass
            ready = time.perf_counter() - start
            rss = None
            if measure_rss:
                time.sleep(1)
                with open(f"/proc/{proc.pid}/status") as status:
                    for line in status:
                        if line.startswith("VmRSS:"):
                            rss = int(line.split()[1])
            return ready, rss
        finally:
            proc.terminate()
            proc.wait(timeout=60)
            sock.close()


def main():
    binary = sys.argv[1]
    runs = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    times = []
    rss = None
    for i in range(runs):
        ready, measured = start_once(binary, measure_rss=(i == 0))
        times.append(ready * 1000)
        rss = measured if measured is not None else rss
    print(
        f"exec to READY=1 ({runs} starts): median {statistics.median(times):.1f} ms, "
        f"fastest {min(times):.1f} ms"
    )
    print(f"idle RSS 1 s after READY=1: {rss} KiB")


if __name__ == "__main__":
    main()
