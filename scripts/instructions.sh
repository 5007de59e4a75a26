#!/usr/bin/env bash
# Instructions per frame of lluav-core and of the std baseline, counted by
# callgrind (deterministic: the same on a loaded machine as on an idle one).
# Each figure is (instructions for N+1000 frames - for N frames) / 1000, so
# start-up and the first frame's warm-up cancel out.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)"; exit 2; }
bin=$(built_executable --release -p lluav-core --example instructions)
count() { # impl label n
    valgrind --tool=callgrind --callgrind-out-file=/dev/null "$bin" "$1" "$2" "$3" 2>&1 |
        sed -n 's/.*Collected : \([0-9]*\).*/\1/p'
}
per_frame() { echo $(( ($(count "$1" "$2" 1100) - $(count "$1" "$2" 100)) / 1000 )); }
printf '%-20s %12s %16s %8s\n' frame "core instr" "baseline instr" ratio
for label in $("$bin" --list); do
    c=$(per_frame core "$label"); b=$(per_frame baseline "$label")
    printf '%-20s %12d %16d %7.1fx\n' "$label" "$c" "$b" "$(echo "$b / $c" | bc -l)"
done
