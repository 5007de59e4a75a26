#!/usr/bin/env bash
# Builds the NUCLEO-H743ZI firmware (release: opt-level "s", fat LTO) and
# prints its flash and static RAM use from the ELF's section sizes.
#   flash      = .vector_table + .text + .rodata + .data (its load image)
#   static RAM = .data + .bss + .uninit (the stack takes what is left)
# Fails when the firmware is over its budgets: 96 KiB of flash, 48 KiB of
# static RAM (four sessions).
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/../../scripts/lib.sh"
cd embedded/boards/nucleo-h743zi
elf=$(built_executable --release)
size -A "$elf" | awk -v flash_budget=$((96 * 1024)) -v ram_budget=$((48 * 1024)) '
  { s[$1] = $2 }
  END {
    flash = s[".vector_table"] + s[".text"] + s[".rodata"] + s[".data"]
    ram = s[".data"] + s[".bss"] + s[".uninit"]
    printf "firmware flash: %d bytes (%.1f KiB)  [.vector_table %d, .text %d, .rodata %d, .data %d]\n", flash, flash / 1024, s[".vector_table"], s[".text"], s[".rodata"], s[".data"]
    printf "firmware static RAM: %d bytes (%.1f KiB)  [.data %d, .bss %d, .uninit %d]\n", ram, ram / 1024, s[".data"], s[".bss"], s[".uninit"]
    if (flash > flash_budget) { printf "over budget: flash %d > %d bytes\n", flash, flash_budget; exit 1 }
    if (ram > ram_budget) { printf "over budget: static RAM %d > %d bytes\n", ram, ram_budget; exit 1 }
  }'
