"""A seeded lossy UDP relay between lluavd (`--mavlink udpin:...`) and an
autopilot, standing in for a telemetry radio.

The autopilot sends to `relay.port` (`udpout`); the relay forwards from its
own socket to lluavd's port, so lluavd sees one address whatever autopilot
is behind the relay (an autopilot replaced behind it keeps the address, as
a rebooted flight controller behind a radio does). Each direction, `up`
(autopilot to lluavd) and `down` (lluavd to autopilot), has its own
impairments: loss, duplication, reordering, latency with jitter, blackout
windows, and `drop_if` (a predicate on the messages a datagram carries, to
lose exactly one kind). Every random decision comes from one seed: the
n-th datagram of a direction meets the same fate in every run.

The relay parses MAVLink (pymavlink) to count messages by type, and keeps
`down.log`: every message that reached the autopilot, with the time it
was delivered.
"""

import collections
import heapq
import os
import random
import select
import socket
import threading
import time

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402


def parse(data):
    """The MAVLink messages in one datagram (garbage and bad CRCs skipped;
    signatures are not checked: the relay is not a party to the key)."""
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    try:
        found = parser.parse_buffer(bytes(data)) or []
    except mav.MAVError:
        return []
    return [m for m in found if m.get_type() != "BAD_DATA"]


class Direction:
    """One direction's impairments and counters.

    `loss`, `duplicate`, `reorder`: probabilities per datagram; `latency`
    and `jitter`: seconds (uniform jitter added to the latency); a reordered
    datagram is held `reorder_delay` seconds more, so later ones overtake it.
    """

    def __init__(self, name, seed, loss=0.0, duplicate=0.0, reorder=0.0, latency=0.0, jitter=0.0,
                 reorder_delay=0.08):
        self.name = name
        self.rng = random.Random(f"{seed}:{name}")
        self.loss, self.duplicate, self.reorder = loss, duplicate, reorder
        self.latency, self.jitter, self.reorder_delay = latency, jitter, reorder_delay
        self.blackouts = []
        self.drop_if = None
        self.counts = collections.Counter()
        self.delivered = collections.Counter()
        # What was delivered, with its time: kept for `down` (what reached
        # the autopilot); for `up` only when asked (telemetry is plentiful).
        self.keep_log = name == "down"
        self.log = []

    def blacked_out(self, now):
        return any(start <= now < end for start, end in self.blackouts)

    def fate(self, now, msgs):
        """The delays (seconds from now) at which this datagram is delivered:
        none when it is lost. Always draws four numbers, so the n-th datagram's
        fate depends on the seed and n only."""
        lose, jitter, reorder, dup = (self.rng.random() for _ in range(4))
        self.counts["received"] += 1
        if self.blacked_out(now):
            self.counts["blackout"] += 1
            return []
        if self.drop_if is not None and any(self.drop_if(m) for m in msgs):
            self.counts["filtered"] += 1
            return []
        if lose < self.loss:
            self.counts["lost"] += 1
            return []
        delay = self.latency + jitter * self.jitter
        if reorder < self.reorder:
            self.counts["reordered"] += 1
            delay += self.reorder_delay
        delays = [delay]
        if dup < self.duplicate:
            self.counts["duplicated"] += 1
            delays.append(delay + 0.005)
        return delays


class LossyRelay:
    """The relay: `LossyRelay(lluavd_port, seed, up=dict(...), down=dict(...))`
    with `Direction`'s keyword arguments per direction."""

    def __init__(self, lluavd_port, seed=0, up=None, down=None):
        self.lluavd = ("127.0.0.1", lluavd_port)
        self.up = Direction("up", seed, **(up or {}))
        self.down = Direction("down", seed, **(down or {}))
        self.lock = threading.Lock()
        self.autopilot = None  # the address the autopilot last sent from
        self.ap_sock = self._socket()
        self.ll_sock = self._socket()
        self.port = self.ap_sock.getsockname()[1]
        self._queue = []
        self._n = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @staticmethod
    def _socket():
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        return s

    def blackout(self, seconds, directions=("up", "down"), start_in=0.0):
        """Nothing passes in `directions` for `seconds`, from `start_in` s on."""
        start = time.monotonic() + start_in
        with self.lock:
            for d in directions:
                getattr(self, d).blackouts.append((start, start + seconds))

    def _take(self, sock, direction, now):
        try:
            data, addr = sock.recvfrom(65535)
        except (BlockingIOError, ConnectionRefusedError):
            return False
        if direction is self.up:
            self.autopilot = addr
        msgs = parse(data)
        with self.lock:
            delays = direction.fate(now, msgs)
            for delay in delays:
                self._n += 1
                heapq.heappush(self._queue, (now + delay, self._n, direction.name, data, msgs))
        return True

    def _deliver(self, name, data, msgs, now):
        direction = getattr(self, name)
        if name == "up":
            sock, dest = self.ll_sock, self.lluavd
        else:
            sock, dest = self.ap_sock, self.autopilot
        if dest is None:
            direction.counts["no_peer"] += 1
            return
        try:
            sock.sendto(data, dest)
        except OSError:
            direction.counts["send_failed"] += 1
            return
        with self.lock:
            direction.counts["forwarded"] += 1
            for m in msgs:
                direction.delivered[m.get_type()] += 1
                if direction.keep_log:
                    direction.log.append((now, m))

    def _run(self):
        socks = {self.ap_sock: self.up, self.ll_sock: self.down}
        while not self._stop.is_set():
            now = time.monotonic()
            with self.lock:
                due = self._queue[0][0] - now if self._queue else 0.05
            ready, _, _ = select.select(list(socks), [], [], max(0.0, min(due, 0.05)))
            now = time.monotonic()
            for sock in ready:
                while self._take(sock, socks[sock], now):
                    pass
            while True:
                with self.lock:
                    if not self._queue or self._queue[0][0] > now:
                        break
                    _, _, name, data, msgs = heapq.heappop(self._queue)
                self._deliver(name, data, msgs, now)

    # --- for the tests -------------------------------------------------

    def received(self, kind=None, since=0.0):
        """Messages that reached the autopilot (of type `kind`), delivered
        at or after monotonic time `since`."""
        with self.lock:
            return [m for t, m in self.down.log
                    if t >= since and (kind is None or m.get_type() == kind)]

    def commands(self, command, since=0.0):
        return [m for m in self.received("COMMAND_LONG", since) if m.command == command]

    def counters(self):
        with self.lock:
            return {"up": dict(self.up.counts), "down": dict(self.down.counts)}

    def close(self):
        self._stop.set()
        self._thread.join()
        self.ap_sock.close()
        self.ll_sock.close()
