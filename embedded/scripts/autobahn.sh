#!/usr/bin/env bash
# Runs the Autobahn|Testsuite (text cases) against the embedded adapter's
# echo configuration on embassy's std platform, over a TAP interface inside
# a network namespace of its own. Needs root (ip netns, /dev/net/tun).
#
# The runner only accepts loopback URLs, so the adapter's stack gets a
# 127.53.0.1 address on the TAP link: inside the namespace `lo` stays down
# (so 127.0.0.0/8 is not claimed by it) and route_localnet lets the kernel
# route 127.53.0.0/24 over tap0. Nothing leaves the namespace.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/../../scripts/lib.sh"
NS=${LLUAV_NETNS:-lluav-embedded}
OUT=${1:-target/autobahn-embedded}
ADAPTER=127.53.0.1
PEER=127.53.0.2

cleanup() {
  [[ -n ${PID:-} ]] && kill "$PID" 2>/dev/null || true
  ip netns del "$NS" 2>/dev/null || true
}
trap cleanup EXIT

tap=$(built_executable -p lluav-embedded --example tap --release)
# The runner installs itself on first use; the namespace has no route out.
runner=${AUTOBAHN_RUNNER:-../shared/tools/autobahn/run.sh}
"$runner" --install-only
ip netns del "$NS" 2>/dev/null || true
ip netns add "$NS"
ip netns exec "$NS" ip tuntap add dev tap0 mode tap
ip netns exec "$NS" sysctl -qw net.ipv4.conf.all.route_localnet=1 net.ipv4.conf.tap0.route_localnet=1
ip netns exec "$NS" ip addr add "$PEER/24" dev tap0
ip netns exec "$NS" ip link set tap0 up

mkdir -p "$(dirname "$OUT")"
ip netns exec "$NS" "$tap" --tap tap0 --address "$ADAPTER/24" --echo \
  >"$OUT.log" 2>&1 &
PID=$!
for _ in $(seq 50); do
  grep -q '^listening on ' "$OUT.log" && break
  sleep 0.2
done
grep -q '^listening on ' "$OUT.log" || { cat "$OUT.log"; exit 2; }

rm -rf "$OUT"; mkdir -p "$(dirname "$OUT")"
ip netns exec "$NS" "$runner" "ws://$ADAPTER:53001" --text-only \
  --agent lluav-embedded --outdir "$OUT"
