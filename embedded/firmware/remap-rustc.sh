#!/bin/sh
# cargo runs rustc through this script (build.rustc-wrapper in
# .cargo/config.toml) so that the firmware names source files relative to
# their crate, the toolchain's library or this repository, never by the
# build machine's absolute paths: panic locations keep their file names in
# flash, and the long registry paths cost about 2 KB of it.
set -eu
rustc=$1
shift
commit=$("$rustc" -vV | sed -n 's/^commit-hash: //p')
root=$(cd "$(dirname "$0")/../.." && pwd)
set -- --remap-path-prefix="/rustc/$commit/=" --remap-path-prefix="$root/=" "$@"
for index in "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/; do
  [ -d "$index" ] && set -- --remap-path-prefix="$index=" "$@"
done
exec "$rustc" "$@"
