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
# Usage: cortex-m-instructions.sh [--host] [--profile]
#   --host     also run scripts/instructions.sh (valgrind on x86-64) and print
#              the host's core instructions per frame beside the Cortex-M's.
#   --profile  also print, per frame, the functions the instructions ran in
#              (the plugin's per-block counts mapped to symbols; needs python3).
# LLUAV_CORE_ONLY_FEATURES adds features of embedded/core-only (ryu-small).
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
cargo build --release --features "qemu ${LLUAV_CORE_ONLY_FEATURES:-}" --target-dir target/qemu
elf=target/qemu/thumbv7em-none-eabihf/release/lluav-core-only
addr() { nm "$elf" | awk -v s="$1" '$3 == s { print "0x" $1 }'; }
host=0 profile=0
for arg in "$@"; do
  case $arg in
    --host) host=1 ;;
    --profile) profile=1 ;;
    *) echo "unknown argument $arg"; exit 2 ;;
  esac
done
plugin_args=""
[[ $profile == 1 ]] && plugin_args=",profile=on"

start=$(addr lluav_mark_start)
stop=$(addr lluav_mark_stop)
[[ -n $start && -n $stop ]] || { echo "marker symbols not found in $elf"; exit 1; }

timeout 300 qemu-system-arm -machine mps2-an500 -cpu cortex-m7 -nographic \
  -semihosting-config enable=on,target=native \
  -plugin "$work/insn-between.so,start=$start,stop=$stop$plugin_args" -d plugin -D "$work/insns" \
  -kernel "$elf" >"$work/guest"

hostlist=""
if [[ $host == 1 ]]; then
  hostlist=$(bash "$root/scripts/instructions.sh" | awk 'NR > 1 { print $1, $2 }')
fi

# The guest prints "frame LABEL REPS" (and the reply it measured); the
# plugin prints one "insns N" per interval, in the same order.
grep '^size_of' "$work/guest" || true
awk -v hostlist="$hostlist" '
  BEGIN {
    n = split(hostlist, lines, "\n")
    for (i = 1; i <= n; i++) if (split(lines[i], f, " ") == 2) hostins[f[1]] = f[2]
  }
  FNR == NR {
    if ($1 == "insns") counts[++ncounts] = $2
    # "tb" lines (--profile) are read below.
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

[[ $profile == 1 ]] || exit 0
# The first run of each frame, attributed to the function each block lies in.
nm -n -C "$elf" >"$work/syms"
python3 - "$work/syms" "$work/guest" "$work/insns" <<'PY'
import bisect, re, sys
syms_path, guest_path, insns_path = sys.argv[1:]
syms = []
for line in open(syms_path):
    parts = line.split(None, 2)
    if len(parts) == 3 and parts[1] in "tT":
        syms.append((int(parts[0], 16) & ~1, re.sub(r"::h[0-9a-f]{16}$", "", parts[2].strip())))
syms.sort()
starts = [a for a, _ in syms]
frames = [l.split()[1:3] for l in open(guest_path) if l.startswith("frame ")]
intervals, current = [], {}
for line in open(insns_path):
    parts = line.split()
    if parts[0] == "tb":
        name = syms[bisect.bisect_right(starts, int(parts[1], 16)) - 1][1]
        current[name] = current.get(name, 0) + int(parts[2])
    elif parts[0] == "insns":
        intervals.append((int(parts[1]), current))
        current = {}
at = 0
for label, reps in frames:
    total, by_function = intervals[at]
    at += int(reps)
    if label == "empty":
        continue
    print(f"\n{label}: {total} instructions (markers included), by function:")
    for name, n in sorted(by_function.items(), key=lambda kv: -kv[1])[:10]:
        print(f"{n:9d} {100 * n / total:5.1f}%  {name[:100]}")
PY
