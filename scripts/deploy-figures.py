"""lluavd's start-up as systemd sees it: the time from exec to READY=1 on
the notification socket (the median and the fastest of RUNS starts),
against a baseline measured in the same run, the same binary's
`lluavd --version` from exec to exit (the cost of starting the process at
all); and the resident memory of the idle daemon one second after READY=1.

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


def version_once(binary):
    start = time.perf_counter()
    subprocess.run([binary, "--version"], stdout=subprocess.DEVNULL, check=True)
    return time.perf_counter() - start


def main():
    binary = sys.argv[1]
    runs = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    times = []
    baseline = []
    rss = None
    # Interleaved, so that load from elsewhere falls on both alike.
    for i in range(runs):
        ready, measured = start_once(binary, measure_rss=(i == 0))
        times.append(ready * 1000)
        baseline.append(version_once(binary) * 1000)
        rss = measured if measured is not None else rss
    ready_ms, base_ms = statistics.median(times), statistics.median(baseline)
    print(
        f"exec to READY=1 ({runs} starts): median {ready_ms:.1f} ms, fastest {min(times):.1f} ms; "
        f"baseline exec to exit of --version: median {base_ms:.1f} ms, fastest {min(baseline):.1f} ms; "
        f"ratio of medians {ready_ms / base_ms:.1f}"
    )
    print(f"idle RSS 1 s after READY=1: {rss} KiB")


if __name__ == "__main__":
    main()
