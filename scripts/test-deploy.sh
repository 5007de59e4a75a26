#!/usr/bin/env bash
# The deploy suite: lluavd's Debian packages and its systemd unit.
#   - builds both packages (scripts/package.sh: amd64 and arm64, each
#     binary built once) and checks their control fields, files,
#     conffiles, maintainer scripts and binaries (architecture, stripped,
#     no debug info, no glibc symbol newer than the Depends floor);
#   - the unit from the package: systemd-analyze verify, and
#     systemd-analyze security --offline=yes under an exposure threshold;
#   - install, edit the config, upgrade, remove, purge with dpkg, in a
#     private mount namespace whose /etc, /usr, /var are overlays thrown
#     away after (this machine is left as it was);
#   - the packaged binaries (lluavd and the lluav client) against every
#     integration test in tests/tests: amd64 natively, arm64 under
#     qemu-aarch64-static (correctness only: timings under qemu-user are
#     the emulator's);
#   - the figures for BENCHMARKS.md "Packages" (sizes, exec to READY=1,
#     idle RSS, exposure).
# `--built`: the packages are built already (scripts/test.sh builds them
# in the background while other suites run).
# Needs root (apt, dpkg, mount). Installs qemu-user-static,
# libc6-arm64-cross, systemd (for systemd-analyze), binutils and adduser
# when missing.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
trap steps_done EXIT
target_dir=$(realpath -m -- "${CARGO_TARGET_DIR:-target}")
work=$target_dir/deploy/check
GLIBC=2.31
EXPOSURE_THRESHOLD=20 # systemd's scale: 20 is an exposure of 2.0
passed=0
failed=0
check() { # check DESCRIPTION COMMAND...
    if "${@:2}"; then
        passed=$((passed + 1))
    else
        failed=$((failed + 1))
        echo "FAILED: $1" >&2
    fi
}
has_line() { grep -qxF -- "$2" "$1"; }
has_text() { grep -qF -- "$2" "$1"; }

missing=()
command -v qemu-aarch64-static >/dev/null || missing+=(qemu-user-static)
[ -e /usr/aarch64-linux-gnu/lib/ld-linux-aarch64.so.1 ] || missing+=(libc6-arm64-cross)
command -v systemd-analyze >/dev/null || missing+=(systemd)
command -v readelf >/dev/null || missing+=(binutils)
command -v adduser >/dev/null || missing+=(adduser)
if [ ${#missing[@]} -gt 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if [ "${1:-}" = --built ]; then
    # scripts/test.sh built them alongside the other suites.
    ls "$target_dir"/debian/lluavd_*_amd64.deb "$target_dir"/debian/lluavd_*_arm64.deb >/dev/null
else
    step "deploy: build the Debian packages (scripts/package.sh)"
    rm -f "$target_dir"/debian/lluavd_*.deb
    bash scripts/package.sh
fi

# The newest glibc symbol version a binary needs.
glibc_needed() { readelf --dyn-syms -W "$1" | grep -o 'GLIBC_[0-9.]*' | sed 's/GLIBC_//' | sort -uV | tail -n 1; }
version_le() { [ "$(printf '%s\n%s\n' "$1" "$2" | sort -V | head -n 1)" = "$1" ]; }
is_machine() { readelf -h "$1" | grep -qE "^ *Machine: .*$2\$"; }
no_debug_info() { ! readelf -S -W "$1" | grep -qE ' \.(debug_|symtab)'; }

step "deploy: package contents, control fields, conffiles, maintainer scripts, binaries"
rm -rf "$work" && mkdir -p "$work"
for arch in amd64 arm64; do
    debs=("$target_dir"/debian/lluavd_*_"$arch".deb)
    deb=${debs[0]}
    root=$work/$arch
    mkdir -p "$root/fs"
    dpkg-deb -x "$deb" "$root/fs"
    dpkg-deb -e "$deb" "$root/control"
    echo "--- $deb"
    dpkg-deb -f "$deb" Package Version Architecture Depends Installed-Size
    check "$arch: Package" [ "$(dpkg-deb -f "$deb" Package)" = lluavd ]
    check "$arch: Architecture" [ "$(dpkg-deb -f "$deb" Architecture)" = "$arch" ]
    check "$arch: Depends states the glibc floor" [ "$(dpkg-deb -f "$deb" Depends)" = "adduser, libc6 (>= $GLIBC)" ]
    (cd "$root/fs" && find . -type f | sed 's|^\./|/|' | sort) >"$root/files"
    printf '%s\n' /etc/lluav/lluavd.toml /usr/lib/systemd/system/lluavd.service /usr/bin/lluav /usr/bin/lluavd \
        /usr/share/doc/lluavd/README.md /usr/share/doc/lluavd/copyright | sort >"$root/expected"
    check "$arch: the files" cmp -s "$root/files" "$root/expected"
    cmp -s "$root/files" "$root/expected" || diff "$root/expected" "$root/files" || true
    check "$arch: the conffile" cmp -s "$root/control/conffiles" <(echo /etc/lluav/lluavd.toml)
    check "$arch: the config file is host/debian/lluavd.toml" cmp -s "$root/fs/etc/lluav/lluavd.toml" host/debian/lluavd.toml
    check "$arch: the unit is host/debian/lluavd.service" cmp -s "$root/fs/usr/lib/systemd/system/lluavd.service" host/debian/lluavd.service
    check "$arch: postinst makes the system user" has_text "$root/control/postinst" "adduser --system --group --home /var/lib/lluav"
    check "$arch: postinst puts it in dialout" has_text "$root/control/postinst" "adduser --quiet lluav dialout"
    check "$arch: postinst does not enable the unit" has_text "$root/control/postinst" "deb-systemd-helper update-state lluavd.service"
    check "$arch: postinst restarts a running service after an upgrade" has_text "$root/control/postinst" "deb-systemd-invoke try-restart lluavd.service"
    check "$arch: prerm stops the service on remove" has_text "$root/control/prerm" "deb-systemd-invoke stop lluavd.service"
    check "$arch: postrm removes the data on purge only" has_text "$root/control/postrm" "rm -rf /var/lib/lluav"
    machine=$([ "$arch" = arm64 ] && echo AArch64 || echo X86-64)
    for bin in lluavd lluav; do
        b=$root/fs/usr/bin/$bin
        check "$arch: $bin is for $machine" is_machine "$b" "$machine"
        check "$arch: $bin has no debug info or symbol table" no_debug_info "$b"
        need=$(glibc_needed "$b")
        echo "$arch $bin: $(stat -c %s "$b") bytes, needs glibc $need"
        check "$arch: $bin needs glibc $need <= $GLIBC" version_le "$need" "$GLIBC"
    done
done

step "deploy: the unit (security --offline=yes --threshold=$EXPOSURE_THRESHOLD; verify runs once it is installed, below)"
unit=$work/amd64/fs/usr/lib/systemd/system/lluavd.service
systemd-analyze security --offline=yes --threshold="$EXPOSURE_THRESHOLD" "$unit" | tail -n 1
check "exposure <= 2.0" systemd-analyze security --offline=yes --threshold="$EXPOSURE_THRESHOLD" "$unit" >/dev/null
for key in Type=notify WatchdogSec=10 Restart=on-failure "ExecStart=/usr/bin/lluavd --config /etc/lluav/lluavd.toml" \
    User=lluav SupplementaryGroups=dialout StateDirectory=lluav "DeviceAllow=char-ttyAMA rw"; do
    check "the unit says $key" has_line "$unit" "$key"
done

step "deploy: install (systemd-analyze verify), edit the config, upgrade, remove, purge (dpkg, in throw-away overlays)"
amd64_debs=("$target_dir"/debian/lluavd_*_amd64.deb)
cp "${amd64_debs[0]}" "$work/first.deb"
# The upgrade: the same package one Debian revision later.
dpkg-deb -R "$work/first.deb" "$work/upgrade"
sed -i 's/^Version: .*/&+upgrade/' "$work/upgrade/DEBIAN/control"
dpkg-deb -b --root-owner-group "$work/upgrade" "$work/upgrade.deb" >/dev/null
mkdir -p "$work/overlay"
unshare --mount --propagation private bash -s "$work" >"$work/dpkg.log" 2>&1 <<'EOF' || { cat "$work/dpkg.log"; exit 1; }
set -euo pipefail
work=$1 ovl=$1/overlay
for d in etc usr var; do
    mkdir -p "$ovl/$d-up" "$ovl/$d-work"
    mount -t overlay overlay -o "lowerdir=/$d,upperdir=$ovl/$d-up,workdir=$ovl/$d-work" "/$d"
done
# The scripts would talk to a running systemd: here there is none.
mkdir -p /run/systemd && mount -t tmpfs tmpfs /run/systemd
state() { echo "$1: $2"; }
dpkg -i "$work/first.deb" </dev/null
state installed "$(id lluav)"
state verify "$(systemd-analyze verify /usr/lib/systemd/system/lluavd.service 2>&1 && echo clean)"
state etc "$(stat -c '%U:%G %a' /etc/lluav /etc/lluav/lluavd.toml | tr '\n' ' ')"
# Beyond loopback, as the file's comments say: an admin value of one's own
# (lluavd refuses the public one there).
sed -i -e 's|^#bind = .*|bind = "0.0.0.0:53001"|' \
    -e 's|^#admin_password = .*|admin_password = "4242"|' /etc/lluav/lluavd.toml
mkdir -p /var/lib/lluav && echo kept >/var/lib/lluav/params.json
dpkg -i "$work/upgrade.deb" </dev/null
state upgraded "$(dpkg-query -W -f '${Version}' lluavd)"
state edit-kept "$(grep -c -e '^bind = "0.0.0.0:53001"' -e '^admin_password = "4242"' /etc/lluav/lluavd.toml)"
state check-config "$(/usr/bin/lluavd --check-config --config /etc/lluav/lluavd.toml --password s3cretpw | grep -c '^bind = "0.0.0.0:53001"')"
dpkg -r lluavd </dev/null
state removed-binary "$([ -e /usr/bin/lluavd ] && echo present || echo gone)"
state removed-config "$([ -e /etc/lluav/lluavd.toml ] && echo present || echo gone)"
state removed-data "$(cat /var/lib/lluav/params.json 2>/dev/null || echo gone)"
dpkg -P lluavd </dev/null
state purged-config "$([ -e /etc/lluav/lluavd.toml ] && echo present || echo gone)"
state purged-data "$([ -e /var/lib/lluav ] && echo present || echo gone)"
EOF
rm -rf "$work/overlay"
grep -E '^[a-z-]+: ' "$work/dpkg.log"
check "install makes lluav, in dialout" grep -qE '^installed: uid=.*\(lluav\).*\(dialout\)' "$work/dpkg.log"
check "install: /etc/lluav root:lluav 750, the config 640" has_line "$work/dpkg.log" "etc: root:lluav 750 root:lluav 640 "
check "systemd-analyze verify of the installed unit" has_line "$work/dpkg.log" "verify: clean"
check "upgrade to the next version" has_line "$work/dpkg.log" "upgraded: $(dpkg-deb -f "$work/upgrade.deb" Version)"
check "upgrade keeps the edited config" has_line "$work/dpkg.log" "edit-kept: 2"
check "the installed lluavd checks the edited config" has_line "$work/dpkg.log" "check-config: 1"
check "remove: the binary goes" has_line "$work/dpkg.log" "removed-binary: gone"
check "remove: the config stays" has_line "$work/dpkg.log" "removed-config: present"
check "remove: the data stays" has_line "$work/dpkg.log" "removed-data: kept"
check "purge: the config goes" has_line "$work/dpkg.log" "purged-config: gone"
check "purge: the data goes" has_line "$work/dpkg.log" "purged-data: gone"

step "deploy: the packaged amd64 lluavd and lluav against every integration test (tests/tests)"
check "amd64 integration tests" env LLUAVD="$work/amd64/fs/usr/bin/lluavd" LLUAV="$work/amd64/fs/usr/bin/lluav" \
    cargo test -q -p lluav-tests --tests

step "deploy: the packaged arm64 lluavd and lluav under qemu-aarch64-static against every integration test"
for bin in lluavd lluav; do
    printf '#!/bin/sh\nexec qemu-aarch64-static -L /usr/aarch64-linux-gnu %s "$@"\n' "$work/arm64/fs/usr/bin/$bin" \
        >"$work/$bin-arm64"
    chmod +x "$work/$bin-arm64"
done
check "arm64 integration tests under qemu" env LLUAVD="$work/lluavd-arm64" LLUAV="$work/lluav-arm64" \
    cargo test -q -p lluav-tests --tests

step "deploy: figures (BENCHMARKS.md, Packages)"
for deb in "$target_dir"/debian/lluavd_*.deb; do echo "package $(basename "$deb"): $(stat -c %s "$deb") bytes"; done
for arch in amd64 arm64; do
    for bin in lluavd lluav; do echo "binary $arch $bin: $(stat -c %s "$work/$arch/fs/usr/bin/$bin") bytes"; done
done
python3 scripts/deploy-figures.py "$work/amd64/fs/usr/bin/lluavd"
echo "exposure: $(systemd-analyze security --offline=yes "$unit" | tail -n 1)"

echo
echo "deploy: $passed passed, $failed failed"
[ "$failed" -eq 0 ]
