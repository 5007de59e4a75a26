#!/usr/bin/env bash
# lluavd's MAVLink backend against real third-party MAVLink peers: the C++
# MAVSDK library as the autopilot (a whole flight) and a pymavlink autopilot
# that misbehaves on purpose, through the real lluavd over WebSocket and UDP
# on loopback; a radio link (a seeded lossy relay), a hostile neighbour on
# lluavd's port, autopilots replaced mid-flight and message signing.
# Installs what it needs (a venv under target/, pinned PyPI packages)
# idempotently. LLUAVD=path uses that lluavd instead of building
# one; MAVLINK_VENV=dir puts the venv elsewhere. Extra arguments go to pytest.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
venv=${MAVLINK_VENV:-target/mavlink-venv}
requirements=tests/mavlink/requirements.txt
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv" || {
        echo "cannot create a Python venv: install python3-venv (apt-get install python3-venv)" >&2
        exit 2
    }
fi
# Reinstall only when the pinned requirements changed.
stamp="$venv/.requirements"
if ! cmp -s "$requirements" "$stamp"; then
    "$venv/bin/python" -m pip install -q --disable-pip-version-check -r "$requirements"
    cp "$requirements" "$stamp"
fi
find_lluavd
exec "$venv/bin/python" -m pytest -q -p no:cacheprovider tests/mavlink "$@"
