#!/usr/bin/env bash
# lluavd's MQTT uplink and `lluav --broker` against a real broker: Debian's
# Mosquitto, installed when missing (scripts/mosquitto.sh), started by the
# tests themselves on free loopback ports with config files of their own.
# LLUAVD=path (and LLUAV=path) use those binaries instead of building them.
# Extra arguments go to the test binary (e.g. a test name).
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
bash scripts/mosquitto.sh
find_lluavd
exec cargo test -p lluav-tests --features broker --test uplink -- "$@"
