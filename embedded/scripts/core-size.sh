#!/usr/bin/env bash
# Flash and static RAM of lluav-core alone (embedded/core-only: the core, a
# small vehicle, cortex-m-rt and panic-halt; no network, no executor, no
# logging) beside the full NUCLEO-H743ZI firmware, both release builds with
# the same profile (opt-level "s", fat LTO, thumbv7em-none-eabihf), then
# what takes the core-only image's flash, largest first.
#   flash      = .vector_table + .text + .rodata + .data
#   static RAM = .data + .bss + .uninit
# Usage: core-size.sh [TOP]   (TOP: how many symbols to list, default 20)
# LLUAV_CORE_ONLY_FEATURES adds features of embedded/core-only (ryu-small).
set -euo pipefail
top=${1:-20}
# Fails when core-only is over its flash budget, 36 KiB (32 KiB until
# flight authority, issue 29, added its gates, commands and labels: ~3 KB).
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/../../scripts/lib.sh"
core_elf=$(cd embedded/core-only && built_executable --release --features "${LLUAV_CORE_ONLY_FEATURES:-}")
fw_elf=$(cd embedded/boards/nucleo-h743zi && built_executable --release)

sections() { size -A "$1" | awk '{ print $1, $2 }'; }
{ sections "$core_elf" | sed 's/^/core /'; sections "$fw_elf" | sed 's/^/fw /'; } | awk -v budget=$((36 * 1024)) '
  { s[$1, $2] = $3 }
  function flash(w) { return s[w, ".vector_table"] + s[w, ".text"] + s[w, ".rodata"] + s[w, ".data"] }
  function ram(w) { return s[w, ".data"] + s[w, ".bss"] + s[w, ".uninit"] }
  function row(name, key) { printf "%-28s %10d %10d %10d\n", name, s["core", key], s["fw", key], s["fw", key] - s["core", key] }
  END {
    printf "%-28s %10s %10s %10s\n", "bytes", "core-only", "firmware", "difference"
    printf "%-28s %10d %10d %10d\n", "flash", flash("core"), flash("fw"), flash("fw") - flash("core")
    printf "%-28s %10d %10d %10d\n", "static RAM", ram("core"), ram("fw"), ram("fw") - ram("core")
    row("  .vector_table", ".vector_table"); row("  .text", ".text"); row("  .rodata", ".rodata")
    row("  .data", ".data"); row("  .bss", ".bss"); row("  .uninit", ".uninit")
    printf "core-only is %.0f%% of the firmware flash\n", 100 * flash("core") / flash("fw")
    if (flash("core") > budget) { printf "over budget: core-only flash %d > %d bytes\n", flash("core"), budget; exit 1 }
  }'

# Symbols in flash (text and read-only data), grouped by where they come
# from. Fat LTO inlines across crates, so a function is counted where it
# ended up: lluav_core_only::run holds the inlined Server::handle.
syms=$(nm -S -t d --size-sort -C "$core_elf" | awk '$3 ~ /^[tTrR]$/')
echo
echo "core-only flash by origin (text + rodata symbols):"
echo "$syms" | awk '
  {
    size = $2 + 0; name = $0; sub(/^[^ ]+ [^ ]+ [^ ]+ /, "", name)
    if (name ~ /dec2flt|f32 as core::str::traits::FromStr/) g = "core::num::dec2flt (f32::from_str)"
    else if (name ~ /^ryu::|ryu::/) g = "ryu (float formatting)"
    else if (name ~ /^\.Lanon/) g = "unnamed constants (strings, tables)"
    else if (name ~ /lluav_core_only::run/) g = "lluav_core::Server::handle (inlined into run)"
    else if (name ~ /^<?lluav_core/ || name ~ /lluav_core::/) g = "lluav_core"
    else if (name ~ /nom::/) g = "nom"
    else if (name ~ /^compiler_builtins|^__aeabi|^__/) g = "compiler_builtins (mem*, 64-bit division)"
    else if (name ~ /__INTERRUPTS|__RESET_VECTOR|__EXCEPTIONS/) g = "vector table"
    else if (name ~ /cortex_m/) g = "cortex-m-rt"
    else if (name ~ /core::/) g = "core (other)"
    else g = "other"
    total[g] += size; all += size
  }
  END {
    for (g in total) printf "%10d  %5.1f%%  %s\n", total[g], 100 * total[g] / all, g | "sort -rn"
    close("sort -rn")
    printf "%10d  (all sized symbols)\n", all
  }'
echo
echo "core-only: the $top largest symbols in flash:"
sort -k2,2 -rn <<<"$syms" | awk -v n="$top" 'NR > n { next }

  { size = $2 + 0; name = $0; sub(/^[^ ]+ [^ ]+ [^ ]+ /, "", name)
    sub(/::h[0-9a-f]{16}$/, "", name); printf "%10d  %s  %s\n", size, $3, substr(name, 1, 90) }'
