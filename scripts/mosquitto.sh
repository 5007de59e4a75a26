#!/usr/bin/env bash
# Makes sure Debian's Mosquitto (the broker the uplink's tests start, each
# on a free loopback port with a config file of its own) is installed;
# installs it with apt-get when it is missing (idempotent; needs root).
# Never starts, stops or configures the system's own service.
set -euo pipefail
if [ -x /usr/sbin/mosquitto ] || command -v mosquitto >/dev/null; then
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "Mosquitto is missing: install it (apt-get install mosquitto) or run this as root" >&2
    exit 2
fi
apt-get update -qq
# Whatever the package does with its own service, the tests never use it
# (they listen on free ports of their own).
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends mosquitto >/dev/null
