# shellcheck shell=bash
# What the scripts share; sourced (`. "$(dirname "$0")/lib.sh"`), not run.
# Sourcing it makes a relative $LLUAVD absolute (relative to the directory
# the script was started from) and moves to the repository's root, which
# it names $root.

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ -n "${LLUAVD:-}" ]; then
    LLUAVD=$(realpath -m -- "$LLUAVD")
    export LLUAVD
fi
cd "$root" || exit

# Builds with `cargo build ARGS` and prints the path of the one executable
# it built, as cargo reports it: wherever CARGO_TARGET_DIR (relative or
# absolute) or cargo's configuration puts it.
built_executable() {
    local json exe
    json=$(cargo build -q --message-format=json-render-diagnostics "$@")
    exe=$(sed -n 's/^{"reason":"compiler-artifact".*"executable":"\([^"]*\)".*/\1/p' <<<"$json")
    if [ -z "$exe" ] || [ "$(wc -l <<<"$exe")" -ne 1 ]; then
        echo "cargo build $* built no single executable: '$exe'" >&2
        return 1
    fi
    echo "$exe"
}

# Exports LLUAVD, the daemon the suites test: the one $LLUAVD names, or a
# debug build made now. A script that calls its sibling scripts calls this
# first, so lluavd is built once.
find_lluavd() {
    if [ -z "${LLUAVD:-}" ]; then
        LLUAVD=$(built_executable -p lluav-host --bin lluavd)
    fi
    if [ ! -x "$LLUAVD" ]; then
        echo "LLUAVD=$LLUAVD is not an executable" >&2
        return 1
    fi
    export LLUAVD
}

# Starts a named step: prints how long the previous one took, then the new
# one's name. `steps_done` (run it on exit) closes the last step and prints
# the total, so a slow suite shows in the log of every run.
step() {
    step_end
    step_name=$*
    step_started=$SECONDS
    printf '\n=== %s\n' "$step_name"
}
step_end() {
    if [ -n "${step_name:-}" ]; then
        printf '=== %s: %d s\n' "$step_name" $((SECONDS - step_started))
        step_name=
    fi
}
steps_done() {
    local rc=$?
    step_end
    printf '=== %s: %d s in all (exit %d)\n' "$(basename "$0")" "$SECONDS" "$rc"
}
