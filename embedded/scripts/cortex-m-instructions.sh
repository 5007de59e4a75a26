#!/usr/bin/env bash
# Instructions per frame of lluav-core on the emulated Cortex-M7 (QEMU
# mps2-an500), for the frame mix of core/benches/frames/workload.rs.
#
# embedded/core-only, built with feature `qemu` (release: opt-level "s",
# fat LTO, as the firmware), runs each frame between two marker functions;
# a TCG plugin of ours (qemu-insn-between.c, built here with cc) counts the
# guest instructions executed between them. Counts are exact and
# deterministic: every translation block adds its instruction count when it
# runs, and a run with one instruction per block (-singlestep) gives the
# same figures. The markers' own cost (an empty interval) is subtracted.
# Cycles are not modelled by QEMU, so these are instructions, not time.
#
# Usage: cortex-m-instructions.sh [--host]
#   --host  also run scripts/instructions.sh (valgrind on x86-64) and print
#           the host's core instructions per frame beside the Cortex-M's.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
command -v qemu-system-arm >/dev/null || { echo "needs qemu-system-arm (apt-get install qemu-system-arm)"; exit 2; }
command -v cc >/dev/null || { echo "needs a C compiler for the QEMU plugin (apt-get install gcc)"; exit 2; }

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

cc -shared -fPIC -O2 -Wall -Wextra -Werror -fvisibility=hidden \
  -o "$work/insn-between.so" "$here/qemu-insn-between.c"

# A target dir of its own: the board build (core-size.sh) links the same
# binary name with another memory map.
cd "$root/embedded/core-only"
cargo build --release --features qemu --target-dir target/qemu
elf=target/qemu/thumbv7em-none-eabihf/release/lluav-core-only
addr() { nm "$elf" | awk -v s="$1" '$3 == s { print "0x" $1 }'; }
start=$(addr lluav_mark_start)
stop=$(addr lluav_mark_stop)
[[ -n $start && -n $stop ]] || { echo "marker symbols not found in $elf"; exit 1; }

timeout 300 qemu-system-arm -machine mps2-an500 -cpu cortex-m7 -nographic \
  -semihosting-config enable=on,target=native \
  -plugin "$work/insn-between.so,start=$start,stop=$stop" -d plugin -D "$work/insns" \
  -kernel "$elf" >"$work/guest"

host=()
if [[ ${1:-} == --host ]]; then
  mapfile -t host < <(bash "$root/scripts/instructions.sh" | awk 'NR > 1 { print $1, $2 }')
fi

# The guest prints "frame LABEL REPS" (and the reply it measured); the
# plugin prints one "insns N" per interval, in the same order.
awk -v hostlist="$(printf '%s\n' "${host[@]}")" '
  BEGIN {
    n = split(hostlist, lines, "\n")
    for (i = 1; i <= n; i++) if (split(lines[i], f, " ") == 2) hostins[f[1]] = f[2]
  }
  FNR == NR {
    if ($1 == "insns") counts[++ncounts] = $2
    next
  }
  $1 == "frame" { labels[++nlabels] = $2; reps[nlabels] = $3 }
  $1 == "reply" || $1 == "close" { replies[nlabels] = $0 }
  END {
    at = 0
    for (l = 1; l <= nlabels; l++) {
      lo = ""; hi = ""
      for (r = 1; r <= reps[l]; r++) {
        c = counts[++at]
        if (c == "") { print "missing counts for " labels[l] > "/dev/stderr"; exit 1 }
        if (lo == "" || c < lo) lo = c
        if (hi == "" || c > hi) hi = c
      }
      if (lo != hi) { print labels[l] ": runs differ (" lo ".." hi ")" > "/dev/stderr"; exit 1 }
      if (labels[l] == "empty") { empty = lo; continue }
      got[l] = lo - empty
    }
    if (at != ncounts) { print "unexpected extra counts" > "/dev/stderr"; exit 1 }
    if (length(hostins) > 0)
      printf "%-20s %18s %18s %8s\n", "frame", "cortex-m7 instr", "x86-64 instr", "m7/x86"
    else
      printf "%-20s %18s\n", "frame", "cortex-m7 instr"
    for (l = 1; l <= nlabels; l++) {
      if (labels[l] == "empty") continue
      if (labels[l] in hostins)
        printf "%-20s %18d %18d %8.2f\n", labels[l], got[l], hostins[labels[l]], got[l] / hostins[labels[l]]
      else
        printf "%-20s %18d\n", labels[l], got[l]
    }
    printf "(markers: %d instructions per interval, subtracted)\n", empty
    for (l = 1; l <= nlabels; l++)
      if (labels[l] != "empty") printf "  %s: %s\n", labels[l], substr(replies[l], 1, 110)
  }' "$work/insns" "$work/guest"
