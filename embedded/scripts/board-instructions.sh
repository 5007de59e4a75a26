#!/usr/bin/env bash
# Instructions per request through the whole firmware on the emulated
# Cortex-M7 (QEMU mps2-an500): the LAN9118 driver and its interrupts,
# embassy-net/smoltcp, the executor and timers, the adapter and the core.
#
# The board runs under our TCG plugin (qemu-insn-between.c, total=on),
# which counts every instruction the guest executes and prints the total
# when QEMU exits. Per frame, one run sends N requests and another 2N, each
# over one connection after the same login (the `lluav` client, one request
# at a time); the difference of the two totals over N is the cost of one
# request, everything on the board included (the request's and the ACK's
# packets in, the reply's out, the timers they set) and nothing else (boot,
# connection, login and close are the same in both runs). Each frame is
# measured twice: the figures are exact counts, but the board's timers
# follow the host's clock, so two runs may differ by a little.
#
# Usage: board-instructions.sh [N] [--core] [--profile]   (N default 500)
#   --core     also run cortex-m-instructions.sh: the core's own figures
#              for the same frames (with the benchmark's vehicle)
#   --profile  also print where a request's instructions go, by crate and
#              by function (the second pair of runs' per-block counts,
#              mapped to the functions they lie in; fat LTO inlines across
#              crates, so a function counts where it ended up)
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/../../scripts/lib.sh"
n=500 core=0 profile=
for arg in "$@"; do
  case $arg in
    --core) core=1 ;;
    --profile) profile=,profile=on ;;
    [0-9]*) n=$arg ;;
    *) echo "unknown argument $arg" >&2; exit 2 ;;
  esac
done
work=$(mktemp -d)
board_pid=
trap '[[ -n $board_pid ]] && kill -TERM "$board_pid" 2>/dev/null; rm -rf "$work"' EXIT

cc -shared -fPIC -O2 -Wall -Wextra -Werror -fvisibility=hidden \
  -o "$work/insn.so" embedded/scripts/qemu-insn-between.c
elf=$(cd embedded/boards/mps2-an500 && LLUAV_PASSWORD=qemu-secret built_executable --release)
lluav=$(built_executable -p lluav-host --bin lluav)

# total FRAME COUNT: every instruction of a board's life with COUNT
# requests of FRAME on one connection (the plugin's output stays in
# $work/plugin-COUNT).
total() {
  local frame=$1 count=$2 url
  : >"$work/plugin-$count"
  : >"$work/out"
  bash embedded/scripts/qemu-board.sh --port 0 --elf "$elf" --log "$work/log" \
    --plugin "$work/insn.so,total=on$profile" --plugin-log "$work/plugin-$count" >"$work/out" 2>"$work/err" &
  board_pid=$!
  until grep -q '^listening on ' "$work/out"; do
    kill -0 "$board_pid" 2>/dev/null || { cat "$work/err" "$work/log" >&2; exit 1; }
    sleep 0.05
  done
  url=$(sed -n 's/^listening on //p' "$work/out")
  for ((i = 0; i < count; i++)); do echo "$frame"; done >"$work/requests"
  # The client's history goes to a home of its own.
  HOME=$work "$lluav" --url "$url" --password qemu-secret <"$work/requests" >"$work/answers"
  grep -q '"ret": -1' "$work/answers" && { echo "a request was refused:" >&2; cat "$work/answers" >&2; exit 1; }
  kill -TERM "$board_pid"
  wait "$board_pid"
  board_pid=
  sed -n 's/^total //p' "$work/plugin-$count"
}

# Where one request's instructions went: the per-block counts of the
# 2N run less those of the N run, over N, by crate and by function.
where() {
  nm -n -C "$elf" >"$work/syms"
  python3 - "$work/syms" "$work/plugin-$n" "$work/plugin-$((2 * n))" "$n" <<'PY'
import bisect, collections, re, sys
syms_path, once_path, twice_path, n = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
syms = []
for line in open(syms_path):
    parts = line.split(None, 2)
    # ARM mapping symbols ($t, $d) mark code and data, not functions.
    if len(parts) == 3 and parts[1] in "tT" and not parts[2].startswith("$"):
        syms.append((int(parts[0], 16) & ~1, re.sub(r"::h[0-9a-f]{16}$", "", parts[2].strip())))
syms.sort()
starts = [a for a, _ in syms]
def per_function(path):
    counts = collections.Counter()
    for line in open(path):
        parts = line.split()
        if parts[0] == "tb":
            i = bisect.bisect_right(starts, int(parts[1], 16)) - 1
            counts[syms[i][1] if i >= 0 else "?"] += int(parts[2])
    return counts
diff = per_function(twice_path)
diff.subtract(per_function(once_path))
def crate(name):
    m = re.match(r"[<&*\s]*(?:dyn\s+)?([A-Za-z_][A-Za-z0-9_]*)::", name)
    if m:
        return m.group(1)
    if name.startswith("__aeabi") or name.startswith("__"):
        return "compiler_builtins"
    if name.startswith("OUTLINED_FUNCTION"):
        return "(outlined by LLVM, opt-level z)"
    return name
total = sum(diff.values())
by_crate = collections.Counter()
for name, count in diff.items():
    by_crate[crate(name)] += count
print("  by crate (instructions per request):")
for name, count in by_crate.most_common():
    if count >= total / 200:
        print("  %9.0f  %5.1f%%  %s" % (count / n, 100 * count / total, name))
print("  by function:")
for name, count in diff.most_common(12):
    print("  %9.0f  %5.1f%%  %s" % (count / n, 100 * count / total, name[:110]))
PY
}

printf '%-32s %14s %14s\n' "frame (whole firmware)" "instr/request" "again"
for frame in "state" "set_sp_ned 1.0:2.0:-3.0:0.5"; do
  runs=()
  for _ in 1 2; do
    once=$(total "$frame" "$n")
    twice=$(total "$frame" $((2 * n)))
    runs+=($(((twice - once) / n)))
  done
  printf '%-32s %14d %14d\n' "$frame" "${runs[0]}" "${runs[1]}"
  if [[ -n $profile ]]; then where; fi
done
echo "(N = $n requests; the board answers set_sp_ned -2, no actuator: its backend has none)"

if ((core)); then
  echo
  echo "lluav-core alone (embedded/core-only, the benchmark's vehicle):"
  bash embedded/scripts/cortex-m-instructions.sh | grep -E '^(frame|state|set_sp_ned) '
fi
