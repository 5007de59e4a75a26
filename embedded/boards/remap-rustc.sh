#!/bin/sh
# Every board's cargo runs rustc through this script (build.rustc-wrapper in
# its .cargo/config.toml) so that the firmware names source files relative to
# their crate, the toolchain's library or this repository, never by the
# build machine's absolute paths: panic locations keep their file names in
# flash, and the long registry paths cost about 2 KB of it.
# Arguments: the compiler (rustc, or clippy-driver and then rustc), then
# its own arguments; the remappings are appended.
set -eu
rustc=rustc
for arg in "$@"; do
  case $arg in
    */rustc | rustc) rustc=$arg; break ;;
  esac
done
commit=$("$rustc" -vV | sed -n 's/^commit-hash: //p')
root=$(cd "$(dirname "$0")/../.." && pwd)
set -- "$@" --remap-path-prefix="/rustc/$commit/=" --remap-path-prefix="$root/="
for index in "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/; do
  [ -d "$index" ] && set -- "$@" --remap-path-prefix="$index="
done
exec "$@"
