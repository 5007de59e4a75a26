#!/usr/bin/env bash
# The whole test suite, as the README's "Set up and run" gives it and as CI
# runs it: the Rust workspace (unit, property and integration tests over
# real sockets), then the suites that need more than cargo, each installing
# what it needs under target/ (idempotently):
#   - the Python SDK (maturin wheel, pytest against the real lluavd);
#   - the browser console (Node's test runner, headless Chromium + Selenium);
#   - the MAVLink backend against real third-party peers (MAVSDK, pymavlink);
#   - the MQTT uplink against a real broker (Mosquitto);
#   - deploy: the Debian packages (amd64, arm64) and the systemd unit, the
#     packaged binaries against the integration tests (arm64 under qemu).
# Extra suites can be skipped by naming the ones to run: `bash
# scripts/test.sh rust python` (default: all six).
#
# Each binary is built once. lluavd's debug build (the one `cargo test`
# builds anyway) serves the Python, console, MAVLink and uplink suites.
# With the deploy suite, the packages are built in the background while
# those suites run (they mostly wait on real time: flights, brokers,
# browsers), and the integration tests in tests/ run once, against the
# packaged lluavd and lluav (amd64 natively, arm64 under qemu), instead of
# against the debug build as well.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
suites=("$@")
[ ${#suites[@]} -gt 0 ] || suites=(rust python console mavlink uplink deploy)
for suite in "${suites[@]}"; do
    case $suite in
        rust | python | console | mavlink | uplink | deploy) ;;
        *)
            echo "unknown suite '$suite': rust, python, console, mavlink, uplink or deploy" >&2
            exit 2
            ;;
    esac
done
selected() { [[ " ${suites[*]} " == *" $1 "* ]]; }

package_pid=
package_log=$(realpath -m -- "${CARGO_TARGET_DIR:-target}")/debian/package.log
# On exit, stop a package build still running (a suite failed) and print
# the last step's time and the total.
trap 'steps_done; [ -z "$package_pid" ] || kill "$package_pid" 2>/dev/null || true' EXIT

# Starts building the Debian packages in the background, once lluavd's
# debug build exists (the two builds would otherwise share the cores for
# longer than either takes alone).
start_packages() {
    if selected deploy && [ -z "$package_pid" ]; then
        mkdir -p "$(dirname "$package_log")"
        printf '\n=== deploy: building the Debian packages in the background (log: %s)\n' "$package_log"
        bash scripts/package.sh >"$package_log" 2>&1 &
        package_pid=$!
        package_started=$SECONDS
    fi
}

for suite in "${suites[@]}"; do
    case $suite in
        rust)
            if selected deploy; then
                step "tests: the Rust workspace (cargo test --workspace; tests/ against the packaged lluavd, in the deploy suite)"
                cargo test --workspace --no-run
                cargo test --workspace --exclude lluav-tests
                cargo test -p lluav-tests --lib
            else
                step "tests: the Rust workspace (cargo test --workspace)"
                cargo test --workspace
            fi
            start_packages
            ;;
        python)
            step "tests: the Python SDK (scripts/test-python.sh)"
            find_lluavd
            start_packages
            bash scripts/test-python.sh
            ;;
        console)
            step "tests: the browser console in headless Chromium (scripts/test-console.sh)"
            find_lluavd
            start_packages
            bash scripts/test-console.sh
            ;;
        mavlink)
            step "tests: the MAVLink backend against MAVSDK and pymavlink (scripts/test-mavlink.sh)"
            find_lluavd
            start_packages
            bash scripts/test-mavlink.sh
            ;;
        uplink)
            step "tests: the MQTT uplink and lluav --broker against Mosquitto (scripts/test-uplink.sh)"
            find_lluavd
            start_packages
            bash scripts/test-uplink.sh
            ;;
        deploy)
            start_packages
            step "deploy: the Debian packages built in the background (scripts/package.sh)"
            if ! wait "$package_pid"; then
                package_pid=
                cat "$package_log"
                echo "building the packages failed" >&2
                exit 1
            fi
            package_pid=
            tail -n 3 "$package_log"
            echo "(built in $((SECONDS - package_started)) s, alongside the suites before)"
            step "tests: the Debian packages and the systemd unit (scripts/test-deploy.sh --built; its own === steps)"
            bash scripts/test-deploy.sh --built
            ;;
    esac
done
