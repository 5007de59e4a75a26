#!/usr/bin/env bash
# The firmware on QEMU's mps2-an500 (Cortex-M7, LAN9118), reachable from
# this machine through a forwarded port: builds embedded/boards/mps2-an500
# (release, LLUAV_PASSWORD or `qemu-secret`), starts
#
#   qemu-system-arm -M mps2-an500 -nic user,model=lan9118,restrict=on,hostfwd=tcp:127.0.0.1:PORT-:53001
#
# (user networking: no root, no route out), prints `listening on
# ws://127.0.0.1:PORT` once a WebSocket upgrade gets its 101 through the
# forward, and stays in the foreground. SIGTERM or SIGINT stops QEMU, after
# reading through QEMU's monitor how deep the painted stack ever went. If
# the firmware ends QEMU itself (a HardFault or a panic exits through
# semihosting with a failure status), so does this script, with QEMU's
# status.
#
# Usage: qemu-board.sh [--port P] [--echo] [--elf ELF] [--log FILE] [--plugin SPEC --plugin-log FILE]
#   --port P    the host port (default 53001; 0: a free one)
#   --echo      the echo build (feature `echo`), for the Autobahn|Testsuite
#   --elf ELF   boot ELF instead of building (cargo run passes it)
#   --log FILE  the board's log (defmt, decoded) goes to FILE, not stderr
#   --plugin SPEC, --plugin-log FILE
#               a TCG plugin for QEMU (-plugin SPEC) and where its output
#               goes (board-instructions.sh counts instructions with one)
# On stderr, besides the board's log: `board: ...` lines with the image's
# flash and static RAM, the time from starting QEMU to the first answer,
# and at the end the stack's high-water mark.
# Installs qemu-system-arm (apt-get), flip-link and defmt-print (cargo
# install) when they are missing.
set -euo pipefail

port=53001 echo=0 elf= log= plugin=()
while (($#)); do
  case $1 in
    --plugin) plugin+=(-plugin "${2:?--plugin needs a value}" -d plugin); shift ;;
    --plugin-log) plugin+=(-D "$(realpath -m -- "${2:?--plugin-log needs a value}")"); shift ;;
    --port) port=${2:?--port needs a value}; shift ;;
    --echo) echo=1 ;;
    --elf) elf=$(realpath -- "${2:?--elf needs a value}"); shift ;;
    --log) log=$(realpath -m -- "${2:?--log needs a value}"); shift ;;
    -h | --help) sed -n '2,/^set -euo/{/^set -euo/d; s/^# \{0,1\}//; p}' "$0"; exit 0 ;;
    *) echo "qemu-board.sh: unexpected argument $1" >&2; exit 2 ;;
  esac
  shift
done
# After the arguments: their paths are relative to where we were started.
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/../../scripts/lib.sh"

say() { printf 'board: %s\n' "$*" >&2; }

if ! command -v qemu-system-arm >/dev/null; then
  say "installing qemu-system-arm"
  apt-get update -qq && apt-get install -y -qq qemu-system-arm >/dev/null
fi
command -v flip-link >/dev/null || cargo install -q flip-link --version 0.1.12 --locked
command -v defmt-print >/dev/null || cargo install -q defmt-print --version 1.2.0 --locked

board=embedded/boards/mps2-an500
if [[ -z $elf ]]; then
  rustup target add thumbv7em-none-eabihf >/dev/null 2>&1 || true
  build=(--release)
  # The same target dir: switching between the two rebuilds only the
  # board's crate and the adapter's (the echo's feature reaches no further).
  ((echo)) && build+=(--features echo)
  elf=$(cd "$board" && LLUAV_PASSWORD=${LLUAV_PASSWORD:-qemu-secret} built_executable "${build[@]}")
fi
size -A "$elf" | awk '
  { s[$1] = $2 }
  END {
    printf "board: flash %d bytes, static RAM %d bytes (.data %d, .bss %d, .uninit %d)\n",
      s[".vector_table"] + s[".text"] + s[".rodata"] + s[".data"],
      s[".data"] + s[".bss"] + s[".uninit"], s[".data"], s[".bss"], s[".uninit"]
  }' >&2
# The stack: from the start of RAM (flip-link puts it below the statics)
# up to the initial stack pointer, painted by the firmware at boot.
stack_bottom=0x20000000
stack_top=0x$(nm "$elf" | awk '$3 == "_stack_start" { print $1 }')

if [[ $port == 0 ]]; then
  port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
fi

work=$(mktemp -d)
qemu_pid= log_pid=
cleanup() {
  [[ -n $qemu_pid ]] && kill "$qemu_pid" 2>/dev/null || true
  # The last lines of the log (a HardFault's) are written before leaving.
  [[ -n $log_pid ]] && wait "$log_pid" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

# A command to QEMU's monitor (a unix socket), waiting for its prompt.
monitor() {
  python3 - "$work/monitor" "$1" <<'PY'
import socket, sys
s = socket.socket(socket.AF_UNIX)
s.connect(sys.argv[1])
s.settimeout(30)
def until_prompt():
    got = b""
    while not got.endswith(b"(qemu) "):
        chunk = s.recv(4096)
        if not chunk:
            break
        got += chunk
until_prompt()
s.sendall(sys.argv[2].encode() + b"\n")
until_prompt()
PY
}

# How deep the stack went: the lowest word that lost its paint.
stack_report() {
  local size=$((stack_top - stack_bottom))
  # QEMU may be gone already (a signal to the whole process group).
  kill -0 "$qemu_pid" 2>/dev/null || return 0
  monitor "pmemsave $stack_bottom $size \"$work/stack\"" 2>/dev/null || return 0
  python3 - "$work/stack" "$size" <<'PY' >&2
import struct, sys
data = open(sys.argv[1], "rb").read()
size = int(sys.argv[2])
words = struct.unpack("<%dI" % (len(data) // 4), data)
untouched = next((i for i, w in enumerate(words) if w != 0xCCCCCCCC), len(words))
used = size - 4 * untouched
print("board: stack high-water %d bytes of %d (painted)" % (used, size))
PY
}

stop() {
  trap - TERM INT
  stack_report || true
  # SIGTERM is QEMU's orderly shutdown (a plugin's exit callbacks run); a
  # monitor `quit` from a client that hangs up at once can go unread.
  kill -TERM "$qemu_pid" 2>/dev/null || true
  wait "$qemu_pid" 2>/dev/null || true
  qemu_pid=
  exit 0
}

# QEMU's stdout carries the firmware's defmt frames (semihosting); the
# decoded log is also kept here, to see when the firmware serves.
mkfifo "$work/defmt"
: >"$work/log"
if [[ -n $log ]]; then
  defmt-print -e "$elf" <"$work/defmt" 2>&1 | tee -a "$work/log" >>"$log" &
else
  defmt-print -e "$elf" <"$work/defmt" 2>&1 | tee -a "$work/log" >&2 &
fi
log_pid=$!
started=$(date +%s%N)
qemu-system-arm -M mps2-an500 -cpu cortex-m7 -display none -serial none \
  -monitor "unix:$work/monitor,server,nowait" \
  -semihosting-config enable=on,target=native \
  -nic "user,model=lan9118,restrict=on,hostfwd=tcp:127.0.0.1:$port-:53001" \
  ${plugin[@]+"${plugin[@]}"} -kernel "$elf" >"$work/defmt" &
qemu_pid=$!
trap stop TERM INT

# Answered once an upgrade through the forward gets its 101. The first
# try waits for the firmware to say it serves: before its controller is
# up, what the forward sends it is lost (and retried only seconds later).
serving=
answers() {
  if [[ -z $serving ]]; then
    grep -q 'serving on' "$work/log" || return 1
    serving=$(date +%s%N)
  fi
  local line=
  exec 3<>"/dev/tcp/127.0.0.1/$port" || return 1
  printf 'GET / HTTP/1.1\r\nHost: 127.0.0.1:%s\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n' \
    "$port" >&3 2>/dev/null || true
  IFS= read -r -t 0.2 line <&3 || true
  exec 3>&- 3<&-
  [[ $line == "HTTP/1.1 101 "* ]]
}
deadline=$((SECONDS + 120))
until answers 2>/dev/null; do
  if ! kill -0 "$qemu_pid" 2>/dev/null; then
    status=0
    wait "$qemu_pid" || status=$?
    qemu_pid=
    say "QEMU ended before the board answered (status $status)"
    exit $((status == 0 ? 1 : status))
  fi
  if ((SECONDS > deadline)); then
    say "no answer on port $port within 120 s"
    exit 1
  fi
  sleep 0.02
done
say "serving $(((serving - started) / 1000000)) ms after QEMU started (its log says so), first answer after $((($(date +%s%N) - started) / 1000000)) ms"
echo "listening on ws://127.0.0.1:$port"

# Until QEMU ends on its own, or whoever started the board is gone (a test
# process killed, a terminal closed): then stop it as SIGTERM would.
parent=$PPID
while kill -0 "$qemu_pid" 2>/dev/null; do
  kill -0 "$parent" 2>/dev/null || stop
  # In the background, so that a signal's trap runs at once.
  sleep 1 &
  wait $! || true
done
status=0
wait "$qemu_pid" || status=$?
qemu_pid=
say "QEMU ended (status $status)"
exit $((status == 0 ? 1 : status))
