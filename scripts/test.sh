#!/usr/bin/env bash
# The whole test suite, as the README's "Set up and run" gives it and as CI
# runs it: the Rust workspace (unit, property and integration tests over
# real sockets), then the suites that need more than cargo, each installing
# what it needs under target/ (idempotently):
#   - the Python SDK (maturin wheel, pytest against the real lluavd);
#   - the browser console (Node's test runner, headless Chromium + Selenium);
#   - the MAVLink backend against real third-party peers (MAVSDK, pymavlink).
# lluavd is built once (debug, the binary `cargo test` already built) and
# handed to every suite. Extra suites can be skipped by naming the ones to
# run: `bash scripts/test.sh rust python` (default: all four).
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
step() { printf '\n=== %s\n' "$*"; }
suites=("$@")
[ ${#suites[@]} -gt 0 ] || suites=(rust python console mavlink)
for suite in "${suites[@]}"; do
    case $suite in
        rust | python | console | mavlink) ;;
        *)
            echo "unknown suite '$suite': rust, python, console or mavlink" >&2
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
    esac
done
