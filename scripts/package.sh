#!/usr/bin/env bash
# Builds lluavd's Debian packages, lluavd_VERSION_amd64.deb and
# lluavd_VERSION_arm64.deb, into target/debian/ (DESIGN.md, "Running as a
# service on the companion computer"; contents in host/Cargo.toml's
# [package.metadata.deb] and host/debian/).
#
# Both binaries are built by zig through cargo-zigbuild for
# `*-unknown-linux-gnu.2.31`: linked against glibc 2.31's symbols, so they
# run on Ubuntu 20.04 / JetPack 5 and newer whatever glibc this machine
# has (Debian's own cross gcc would tie them to bookworm's 2.36), and zig
# also compiles ring's C and assembly for arm64. The profile is `deb`:
# release without debug info, stripped.
#
# Installs what it needs, pinned and idempotently, inside the target
# directory: cargo-deb (target/deploy/bin), cargo-zigbuild and zig (a venv,
# target/deploy/venv), the rustup targets; apt's python3-venv when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
CARGO_DEB_VERSION=3.8.0
CARGO_ZIGBUILD_VERSION=0.24.1
ZIGLANG_VERSION=0.15.2
GLIBC=2.31
TARGETS=(x86_64-unknown-linux-gnu aarch64-unknown-linux-gnu)
target_dir=$(realpath -m -- "${CARGO_TARGET_DIR:-target}")
tools=$target_dir/deploy
venv=$tools/venv

if [ "$("$tools/bin/cargo-deb" --version 2>/dev/null)" != "cargo-deb $CARGO_DEB_VERSION" ]; then
    echo "installing cargo-deb $CARGO_DEB_VERSION into $tools"
    cargo install --quiet --locked --force --root "$tools" --version "$CARGO_DEB_VERSION" cargo-deb
fi
if ! { "$venv/bin/cargo-zigbuild" --version 2>/dev/null | grep -qx "cargo-zigbuild $CARGO_ZIGBUILD_VERSION" &&
    [ "$("$venv/bin/python" -m ziglang version 2>/dev/null)" = "$ZIGLANG_VERSION" ]; }; then
    echo "installing cargo-zigbuild $CARGO_ZIGBUILD_VERSION and zig $ZIGLANG_VERSION into $venv"
    python3 -c 'import ensurepip' 2>/dev/null || { apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null; }
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check \
        "cargo-zigbuild==$CARGO_ZIGBUILD_VERSION" "ziglang==$ZIGLANG_VERSION"
fi
rustup target add "${TARGETS[@]}" >/dev/null
export PATH=$venv/bin:$tools/bin:$PATH

# One cargo run for both targets: the build scripts and proc macros are
# built once for this machine and the two targets share the cores.
zig_targets=()
for t in "${TARGETS[@]}"; do zig_targets+=(--target "$t.$GLIBC"); done
cargo zigbuild --locked --profile deb -p lluav-host --bins "${zig_targets[@]}"

mkdir -p "$target_dir/debian"
# Only this build's packages: an older version's would look built.
rm -f "$target_dir"/debian/lluavd_*.deb
for t in "${TARGETS[@]}"; do
    # Stripped by the profile already; cargo-deb's strip would be this
    # machine's, which does not read arm64 binaries.
    cargo deb --no-build --no-strip -p lluav-host --profile deb --target "$t" \
        --output "$target_dir/debian/"
done
ls -l "$target_dir"/debian/*.deb
