#!/usr/bin/env bash
# Cargo runner: runs a defmt-test ELF under qemu-system-arm (mps2-an500,
# Cortex-M7) with semihosting, decodes its defmt output, and ends with a
# plain "N passed, N failed" line. The exit status is QEMU's: the test
# binary exits through semihosting, with a failure status on a failed test,
# a panic or a HardFault.
set -uo pipefail
elf=$1
log=$(mktemp)
trap 'rm -f "$log"' EXIT
timeout "${QEMU_TIMEOUT:-300}" qemu-system-arm -machine mps2-an500 -cpu cortex-m7 -nographic \
  -semihosting-config enable=on,target=native -kernel "$elf" \
  | defmt-print -e "$elf" | tee "$log"
status=${PIPESTATUS[0]}
total=$(grep -oE '\([0-9]+/[0-9]+\) running' "$log" | tail -1 | sed -E 's/\(([0-9]+)\/([0-9]+)\).*/\2/')
ran=$(grep -cE '\([0-9]+/[0-9]+\) running' "$log")
if [[ $status -eq 0 ]] && grep -q 'all tests passed!' "$log"; then
  echo "${ran} passed, 0 failed"
else
  echo "$((ran > 0 ? ran - 1 : 0)) passed, 1 failed ($(( ${total:-0} - ran )) not run; status ${status})"
  [[ $status -eq 0 ]] && status=1
fi
exit "$status"
