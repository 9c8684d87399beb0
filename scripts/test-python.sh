#!/usr/bin/env bash
# The Python package's tests (docs/python.md): builds its wheel with maturin, installs it into a
# fresh virtual environment with pytest, numpy and Pillow (scripts/setup-python.sh fetched them),
# and runs python/tests/ there against the `covec` command line built by the same checkout (the
# package must write the same files). Extra arguments go to pytest.
#
# The wheel is built as test.sh builds the command line: the dev profile (the test profile's
# settings, not `test` itself, which makes a test harness, not a module), on the library with
# its default features. The library code the package calls is the same with them or without
# (they add the command line and the service, which the module's linking leaves out), and so
# the wheel reuses the library the command line's build has just compiled instead of compiling
# it again (about 4 minutes of the test command's 2 cores, measured under load). The published
# wheel, without them, has the library test.sh checks alone and this module, which must not use
# what the features add: checked here by name (the words `service` and `web` appear nowhere in
# it), as checking the module once more without them took 100 s of CPU (pyo3 once more).
# COVEC_PYTHON_PROFILE picks another profile.
set -euo pipefail
cd "$(dirname "$0")/.."
if grep -nwE 'service|web' python/src/*.rs; then
    echo "test-python: the module names the service's modules, which its wheel does not have" >&2
    exit 1
fi
profile=${COVEC_PYTHON_PROFILE:-dev}
cache=${COVEC_PYTHON_CACHE:-$HOME/.cache/covec/python}

# The command line first: the library the wheel links is built by it (or, in test.sh, was).
covec_bin=$(cargo build --quiet --bin covec --profile "$profile" --message-format=json \
    | python3 -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("executable") and m["target"]["name"] == "covec":
        print(m["executable"])')

# The wheel and its virtual environment in the target directory, on the disk that holds the build,
# not in /tmp, which may be a small tmpfs.
target_dir=$(cargo metadata --quiet --format-version 1 --no-deps \
    | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
mkdir -p "$target_dir/tmp"
work=$(mktemp -d -p "$target_dir/tmp" test-python.XXXXXX)
trap 'rm -rf "$work"' EXIT
"$cache/maturin/bin/maturin" build --quiet --manifest-path python/Cargo.toml --profile "$profile" \
    --features covec/default --out "$work/wheels"
wheel=$(echo "$work"/wheels/covec-*.whl)
echo "test-python: $(basename "$wheel"), $(du -k "$wheel" | cut -f1) KiB ($profile profile)" >&2

python3 -m venv "$work/venv"
read -ra requirements <"$cache/wheels/done"
"$work/venv/bin/pip" install -q --no-cache-dir --no-index --find-links "$cache/wheels" "${requirements[@]}" "$wheel"

# Run from the tests' folder, so that `import covec` finds the installed wheel, not python/covec.
cd python/tests
COVEC_BIN=$covec_bin "$work/venv/bin/python" -m pytest -q -p no:cacheprovider "$@"
