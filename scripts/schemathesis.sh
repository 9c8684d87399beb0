#!/usr/bin/env bash
# Property-based tests of the running service against api/openapi.yaml (docs/design.md,
# "Tests"): schemathesis 4.x with every check and every phase (examples, coverage, fuzzing,
# stateful), against fresh `covec serve`s on free loopback ports with default limits, one open
# and one with an API key.
# The document's examples create a real job (a 16×16 PNG) and an edit of it, and its links carry
# their ids to every other operation. Installs schemathesis from PyPI into a virtual environment
# under ~/.cache on first use.
#
#   scripts/schemathesis.sh [PATH/TO/covec] [extra schemathesis options…]
#
# Without a binary it builds one (the dev profile, as the tests use). Exits non-zero when schemathesis finds a failure.
set -euo pipefail
cd "$(dirname "$0")/.."

venv="${XDG_CACHE_HOME:-$HOME/.cache}/covec-schemathesis"
if [[ ! -x "$venv/bin/schemathesis" ]]; then
    echo "schemathesis.sh: installing schemathesis (PyPI) into $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet schemathesis==4.32.5
fi

if [[ $# -gt 0 && -x "$1" ]]; then
    covec=$1
    shift
else
    cargo build --quiet --bin covec
    covec="${CARGO_TARGET_DIR:-target}/debug/covec"
fi

work=$(mktemp -d)
servers=()
trap 'kill "${servers[@]}" 2>/dev/null; wait 2>/dev/null; rm -rf "$work"' EXIT

# Runs schemathesis against a fresh server started with `serve_args`; the rest of the arguments
# go to schemathesis. Room for every job the run creates; one worker keeps the machine usable.
run_against() {
    local name=$1 serve_args=$2
    shift 2
    "$covec" serve --addr 127.0.0.1:0 --data-dir "$work/$name" --workers 1 --max-queued 100000 \
        $serve_args >"$work/$name.stdout" 2>"$work/$name.log" &
    servers+=($!)
    for _ in $(seq 100); do
        grep -q "listening on" "$work/$name.stdout" 2>/dev/null && break
        sleep 0.1
    done
    local base
    base=$(sed -n 's/^covec serve: listening on //p' "$work/$name.stdout")
    [[ -n "$base" ]] || { echo "schemathesis.sh: the server did not start:" >&2; cat "$work/$name.log" >&2; exit 1; }
    echo "schemathesis.sh: $name server" >&2
    # Fixed seed and bounded examples: the same run each time, about a minute.
    "$venv/bin/schemathesis" --config-file scripts/schemathesis.toml run api/openapi.yaml --url "$base" \
        --checks all --phases examples,coverage,fuzzing,stateful --max-examples 25 --seed 20 \
        --request-timeout 60 "$@"
}

# Without keys, and with a key (every request authorised; `X-Client-Key` is checked either way).
run_against open "" "$@"
run_against keyed "--api-keys schemathesis-key" -H "Authorization: Bearer schemathesis-key" "$@"
