#!/usr/bin/env bash
# Installs what the Python package's tests need (scripts/test-python.sh), idempotently: Debian's
# python3-venv where `python3 -m venv` lacks it, maturin 1.16.0 in a virtual environment of its
# own, and the wheels of pytest, numpy and Pillow in a folder, from which the tests' fresh
# virtual environment installs them without the network. Safe to run on every test run.
set -euo pipefail

if ! python3 -c 'import ensurepip, venv' 2>/dev/null; then
    echo "setup-python: installing Debian python3-venv" >&2
    sudo_cmd=()
    if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends python3-venv >/dev/null
fi

cache=${COVEC_PYTHON_CACHE:-$HOME/.cache/covec/python}
if [[ ! -x $cache/maturin/bin/maturin ]] || [[ $("$cache/maturin/bin/maturin" --version) != *" 1.16.0" ]]; then
    echo "setup-python: installing maturin into $cache/maturin" >&2
    python3 -m venv "$cache/maturin"
    "$cache/maturin/bin/pip" install -q maturin==1.16.0
fi
# The test environment's packages, pinned; test-python.sh installs exactly these.
requirements=(pytest==9.2.0 numpy==2.4.6 pillow==13.0.0)
if [[ ! -f $cache/wheels/done ]] || [[ $(cat "$cache/wheels/done") != "${requirements[*]}" ]]; then
    echo "setup-python: downloading ${requirements[*]} into $cache/wheels" >&2
    rm -rf "$cache/wheels"
    "$cache/maturin/bin/pip" download -q -d "$cache/wheels" "${requirements[@]}"
    echo "${requirements[*]}" >"$cache/wheels/done"
fi
