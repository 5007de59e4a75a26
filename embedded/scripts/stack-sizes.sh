#!/usr/bin/env bash
# Per-function stack frames of the release firmware, from nightly's
# `-Z emit-stack-sizes` read back with llvm-readobj --stack-sizes.
# Prints the largest frames and those on the frame-handling path.
# Fails when any frame exceeds LIMIT bytes: a large static built by value
# in a task (e.g. a PacketQueue, seen at 19 KB) would show up here.
# Usage: stack-sizes.sh [N]  (N largest frames, default 25; LIMIT env, default 8192)
set -euo pipefail
cd "$(dirname "$0")/../boards/nucleo-h743zi"
top=${1:-25}
limit=${LIMIT:-8192}
rustup +nightly target add thumbv7em-none-eabihf >/dev/null
rustup +nightly component add llvm-tools >/dev/null
readobj=$(rustc +nightly --print sysroot)/lib/rustlib/x86_64-unknown-linux-gnu/bin/llvm-readobj
# RUSTFLAGS replaces the config's rustflags, so they are repeated here.
RUSTFLAGS="-C link-arg=-Tlink.x -C link-arg=-Tdefmt.x -C link-arg=-T$PWD/stack-sizes.x -Z emit-stack-sizes" \
  cargo +nightly build --release --target-dir target/stack-sizes
elf=target/stack-sizes/thumbv7em-none-eabihf/release/lluav-firmware
table=$("$readobj" --stack-sizes --demangle "$elf" | awk '
  /Functions:/ { sub(/.*Functions: \[/, ""); sub(/\]$/, ""); name = $0 }
  /Size:/ { printf "%8d  %s\n", $2, name }' | sort -rn)
echo "largest stack frames (bytes, function):"
# awk, not head: head exiting early would SIGPIPE the writer under pipefail.
awk -v n="$top" 'NR <= n' <<<"$table"
echo
echo "frame-handling path (lluav_core, lluav_embedded, embedded_websocket):"
awk '/lluav_core|lluav_embedded|embedded_websocket|server_task/ && ++k <= 40' <<<"$table"

largest=$(awk 'NR == 1 { sub(/^ +/, ""); print }' <<<"$table")
if (( ${largest%% *} > limit )); then
  echo "stack frame over ${limit} bytes: ${largest}" >&2
  exit 1
fi
