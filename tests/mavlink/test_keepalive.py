"""A client's keepalive across a command the autopilot is slow to
acknowledge: lluavd answers pings while the command waits, so a Python
`websockets` client (whose keepalive closes with 1011 when a pong is late)
keeps its session and gets the answer. One daemon and one autopilot each."""

import json
import time

from websockets.sync.client import connect

from conftest import PASSWORD
from fault_autopilot import mav

ARM = mav.MAV_CMD_COMPONENT_ARM_DISARM
# The client's keepalive: a ping every PING s, the session given up when
# its pong has not come PING s later.
PING = 1.0
# The autopilot acknowledges the arming this late: three pings into the
# wait, well past the keepalive's timeout, and before lluavd's third and
# last send (1.5 s apart) gives up.
ACK_DELAY = 3.5


def test_keepalive_pings_are_answered_while_a_command_waits(vehicle):
    daemon, ap, _ = vehicle()
    ap.ack_delay[ARM] = ACK_DELAY
    with connect(daemon.url, open_timeout=10, close_timeout=5,
                 ping_interval=PING, ping_timeout=PING) as ws:
        ws.send(f"login {PASSWORD}")
        assert json.loads(ws.recv(timeout=10))["ret"] == 0
        start = time.monotonic()
        ws.send("takeoff")
        # A ping of our own while the command waits: its pong comes at once.
        time.sleep(PING)
        assert ws.ping(b"during the wait").wait(timeout=PING), "no pong while the command waited"
        reply = json.loads(ws.recv(timeout=30))
        waited = time.monotonic() - start
        assert reply["ret"] == 0 and reply["fsm"] == "takeoff", reply
        # The answer came after the acknowledgement, so the keepalive ran
        # several times during the wait (and would have closed the session
        # had a pong been late).
        assert waited >= ACK_DELAY, waited
        assert ap.commands(mav.MAV_CMD_NAV_TAKEOFF), "the takeoff was sent after the arming"
        # The session goes on.
        ws.send("state")
        assert json.loads(ws.recv(timeout=10))["ret"] == 0
