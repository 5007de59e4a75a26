#!/usr/bin/env bash
# Builds the NUCLEO-H743ZI firmware (release: opt-level "s", fat LTO) and
# prints its flash and static RAM use from the ELF's section sizes.
#   flash      = .vector_table + .text + .rodata + .data (its load image)
#   static RAM = .data + .bss + .uninit (the stack takes what is left)
set -euo pipefail
cd "$(dirname "$0")/../firmware"
cargo build --release
elf=target/thumbv7em-none-eabihf/release/lluav-firmware
size -A "$elf" | awk '
  { s[$1] = $2 }
  END {
    flash = s[".vector_table"] + s[".text"] + s[".rodata"] + s[".data"]
    ram = s[".data"] + s[".bss"] + s[".uninit"]
    printf "firmware flash: %d bytes (%.1f KiB)  [.vector_table %d, .text %d, .rodata %d, .data %d]\n", flash, flash / 1024, s[".vector_table"], s[".text"], s[".rodata"], s[".data"]
    printf "firmware static RAM: %d bytes (%.1f KiB)  [.data %d, .bss %d, .uninit %d]\n", ram, ram / 1024, s[".data"], s[".bss"], s[".uninit"]
  }'
