#!/usr/bin/env bash
# Installs what the README's client examples need, idempotently (tests/readme_clients.rs runs
# them): Debian's curl, jq and python3-requests. Safe to run on every test run.
set -euo pipefail

missing=()
command -v curl >/dev/null || missing+=(curl)
command -v jq >/dev/null || missing+=(jq)
python3 -c 'import requests' 2>/dev/null || missing+=(python3-requests)
if [[ ${#missing[@]} -gt 0 ]]; then
    echo "setup-clients: installing Debian ${missing[*]}" >&2
    sudo_cmd=()
    if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
