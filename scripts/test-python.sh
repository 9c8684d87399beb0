#!/usr/bin/env bash
# The Python package's tests (docs/python.md): builds its wheel with maturin, installs it into a
# fresh virtual environment with pytest, numpy and Pillow, and runs python/tests/ there against
# the `covec` command line built by the same checkout (the package must write the same files).
# Extra arguments go to pytest. COVEC_PYTHON_PROFILE picks the wheel's Cargo profile: default
# `dev`, the test profile's settings (whose optimised dependencies the Rust tests have built
# where their features agree), not `test` itself, which builds a test harness, not a module.
set -euo pipefail
cd "$(dirname "$0")/.."
profile=${COVEC_PYTHON_PROFILE:-dev}

# maturin in a virtual environment of its own, kept between runs (as the client generators').
tools=${COVEC_MATURIN_VENV:-$HOME/.cache/covec/maturin-venv}
if [[ ! -x $tools/bin/maturin ]] || [[ $("$tools/bin/maturin" --version) != *" 1.16.0" ]]; then
    echo "test-python: installing maturin into $tools" >&2
    python3 -m venv "$tools"
    "$tools/bin/pip" install -q maturin==1.16.0
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$tools/bin/maturin" build --quiet --manifest-path python/Cargo.toml --profile "$profile" \
    --out "$work/wheels"
wheel=$(echo "$work"/wheels/covec-*.whl)
echo "test-python: $(basename "$wheel"), $(du -k "$wheel" | cut -f1) KiB ($profile profile)" >&2

python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q pytest==9.2.0 numpy==2.4.6 pillow==13.0.0 "$wheel"

covec_bin=$(cargo build --quiet --bin covec --profile test --message-format=json \
    | python3 -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("executable") and m["target"]["name"] == "covec":
        print(m["executable"])')
# Run from the tests' folder, so that `import covec` finds the installed wheel, not python/covec.
cd python/tests
COVEC_BIN=$covec_bin "$work/venv/bin/python" -m pytest -q -p no:cacheprovider "$@"
