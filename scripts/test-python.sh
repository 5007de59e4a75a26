#!/usr/bin/env bash
# The Python SDK's test run (a CI step of its own):
#  0. lints: rustfmt and clippy for the PyO3 crate (outside the workspace,
#     so the workspace's own checks do not cover it), ruff for the Python;
#  1. builds the wheel with maturin (from PyPI) and installs it into a fresh
#     virtual environment with the test dependencies (the `test` extra);
#  2. runs python/tests against the real lluavd (and Mosquitto for the
#     fleet's tests, installed when missing by scripts/mosquitto.sh);
#  3. checks the README's promise, `pip install ./python`, in another fresh
#     environment that holds the oldest websockets and paho-mqtt the
#     package allows (the newest a CPython 3.9 user gets), and runs the
#     suite there too.
#
#   bash scripts/test-python.sh                      # builds lluavd with cargo
#   LLUAVD=target/debug/lluavd bash scripts/test-python.sh
#   PYTHON=/usr/bin/python3.12 bash scripts/test-python.sh
#
# Idempotent: everything it makes is under target/python/ (pip's cache too);
# the test environments are made anew on every run. Every package pip
# installs, pip's build of ./python included, has its exact version in
# python/tests/constraints.txt; the websockets and paho-mqtt versions are
# named below.
set -euo pipefail
# shellcheck source=scripts/lib.sh
. "$(dirname "$0")/lib.sh"
work=$root/target/python
python=${PYTHON:-python3}
export PIP_CACHE_DIR=$work/pip-cache PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_INPUT=1 PYTHONDONTWRITEBYTECODE=1
# An environment variable, not -c, so that pip's isolated build
# environment for `pip install ./python` obeys it too.
export PIP_CONSTRAINT=$root/python/tests/constraints.txt
newest_websockets=17.4 oldest_websockets=15.0.1
newest_paho=2.2.0 oldest_paho=2.1.0
mkdir -p "$work"

fresh_venv() {
    rm -rf "$1"
    "$python" -m venv "$1"
}

echo "== tools: maturin, ruff"
if ! "$work/tools/bin/python" -c "" 2>/dev/null; then
    fresh_venv "$work/tools"
fi
"$work/tools/bin/pip" install -q maturin ruff

echo "== lints"
(cd python && cargo fmt --check && cargo clippy --all-targets -- -D warnings)
"$work/tools/bin/ruff" check python
"$work/tools/bin/ruff" format --check python

echo "== lluavd"
find_lluavd

# One target directory for both builds of the extension (the wheel and
# pip's build of ./python below): same profile, same features, so pip's
# build finds it done instead of compiling it all again.
export CARGO_TARGET_DIR=$work/cargo

echo "== wheel"
rm -rf "$work/wheels"
"$work/tools/bin/maturin" build --release -m python/Cargo.toml -i "$work/tools/bin/python" --out "$work/wheels"
wheel=$(ls "$work"/wheels/lluav-*.whl)

echo "== mosquitto"
bash scripts/mosquitto.sh

run_suite() {
    # From a directory without a `lluav` folder, so that the installed
    # package is the one under test, not python/lluav.
    (cd "$work" && "$1/bin/python" -m pytest -p no:cacheprovider "$root/python/tests")
}

echo "== tests: the wheel ($(basename "$wheel")) in a fresh environment"
fresh_venv "$work/test-venv"
"$work/test-venv/bin/pip" install -q "${wheel}[test]" "websockets==$newest_websockets" "paho-mqtt==$newest_paho"
run_suite "$work/test-venv"

echo "== tests: pip install ./python, oldest websockets and paho-mqtt"
fresh_venv "$work/pip-venv"
"$work/pip-venv/bin/pip" install -q "websockets==$oldest_websockets" "paho-mqtt==$oldest_paho"
"$work/pip-venv/bin/pip" install -q "./python[test]"
"$work/pip-venv/bin/python" -c "import websockets; assert websockets.__version__ == '$oldest_websockets', websockets.__version__"
"$work/pip-venv/bin/python" -c "from importlib.metadata import version; assert version('paho-mqtt') == '$oldest_paho'"
run_suite "$work/pip-venv"
