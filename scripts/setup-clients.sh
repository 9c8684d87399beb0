#!/usr/bin/env bash
# Installs what the client tests need, idempotently: Debian's curl, jq and python3-requests for
# the batch examples of docs/api.md (tests/service/readme_clients.rs), and the client generators
# (tests/service/generated_clients.rs). Safe to run on every test run.
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

# The client generators of tests/service/generated_clients.rs (docs/api.md, "Generated clients"), at
# pinned versions: openapi-python-client in its own virtual environment, openapi-typescript,
# openapi-fetch and TypeScript from tests/clients/package-lock.json.
venv=${COVEC_CLIENTS_VENV:-$HOME/.cache/covec/clients-venv}
if [[ ! -x $venv/bin/openapi-python-client ]] \
    || [[ $("$venv/bin/openapi-python-client" --version) != *" 0.29.1" ]]; then
    echo "setup-clients: installing openapi-python-client into $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q openapi-python-client==0.29.1
fi
clients=$(dirname "$0")/../tests/clients
if [[ ! -d $clients/node_modules/openapi-fetch ]]; then
    echo "setup-clients: installing tests/clients' npm packages" >&2
    npm ci --prefix "$clients" --no-audit --no-fund >/dev/null
fi
