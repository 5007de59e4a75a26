#!/usr/bin/env bash
# The browser console's tests: the page's modules under Node's test runner
# (tests/console/js), then headless Debian Chromium, driven by Selenium from
# Python, against a real lluavd (tests/console/).
#
# Self-installing and idempotent: installs Debian's chromium and
# chromium-driver (and python3-venv, nodejs, openssl) when missing, and the pinned Python
# packages into a venv under target/; reruns install nothing. Nothing is
# downloaded while the tests run.
#
#   bash scripts/test-console.sh               # builds lluavd with cargo
#   LLUAVD=target/release/lluavd bash scripts/test-console.sh
#   bash scripts/test-console.sh -k plot       # extra arguments go to pytest
#
# Screenshots land in target/console-screenshots/.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"

missing=()
[ -x /usr/bin/chromium ] || missing+=(chromium)
[ -x /usr/bin/chromedriver ] || missing+=(chromium-driver)
python3 -c 'import venv, ensurepip' 2>/dev/null || missing+=(python3-venv)
command -v node >/dev/null || missing+=(nodejs)
command -v openssl >/dev/null || missing+=(openssl)
if [ ${#missing[@]} -gt 0 ]; then
    echo "test-console: installing ${missing[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq "${missing[@]}" >/dev/null
fi

venv=$root/target/console-venv
requirements=$root/tests/console/requirements.txt
if ! cmp -s "$requirements" "$venv/installed-requirements.txt" ||
    ! "$venv/bin/python" -c 'import selenium, pytest' 2>/dev/null; then
    echo "test-console: setting up $venv" >&2
    rm -rf "$venv"
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$requirements"
    cp "$requirements" "$venv/installed-requirements.txt"
fi

find_lluavd
node --test "$root"/tests/console/js/*.test.mjs

cd "$root/tests/console"
export PYTHONDONTWRITEBYTECODE=1
exec "$venv/bin/python" -m pytest "$@"
