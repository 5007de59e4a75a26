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
# lluavd is built once (debug, the binary `cargo test` already built) and
# handed to every suite. Extra suites can be skipped by naming the ones to
# run: `bash scripts/test.sh rust python` (default: all six).
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
trap steps_done EXIT
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

for suite in "${suites[@]}"; do
    case $suite in
        rust)
            step "tests: the Rust workspace (cargo test --workspace)"
            cargo test --workspace
            ;;
        python)
            step "tests: the Python SDK (scripts/test-python.sh)"
            find_lluavd
            bash scripts/test-python.sh
            ;;
        console)
            step "tests: the browser console in headless Chromium (scripts/test-console.sh)"
            find_lluavd
            bash scripts/test-console.sh
            ;;
        mavlink)
            step "tests: the MAVLink backend against MAVSDK and pymavlink (scripts/test-mavlink.sh)"
            find_lluavd
            bash scripts/test-mavlink.sh
            ;;
        uplink)
            step "tests: the MQTT uplink and lluav --broker against Mosquitto (scripts/test-uplink.sh)"
            find_lluavd
            bash scripts/test-uplink.sh
            ;;
        deploy)
            step "tests: the Debian packages and the systemd unit (scripts/test-deploy.sh; its own === steps)"
            bash scripts/test-deploy.sh
            ;;
    esac
done
