#!/usr/bin/env bash
# Installs what the browser test needs, idempotently: Debian's Chromium (/usr/bin/chromium) and the
# pinned playwright-core under tests/browser/node_modules. Safe to run on every test run.
set -euo pipefail
cd "$(dirname "$0")/.."

if [[ ! -x /usr/bin/chromium ]]; then
    echo "setup-browser: installing Debian chromium" >&2
    sudo_cmd=()
    if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi

if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    echo "setup-browser: node and npm are needed (Debian packages nodejs and npm)" >&2
    exit 1
fi

cd tests/browser
# playwright-core ships no browser; its postinstall downloads nothing.
if [[ ! -f node_modules/playwright-core/package.json ]] \
    || [[ package-lock.json -nt node_modules/.package-lock.json ]]; then
    echo "setup-browser: npm ci in tests/browser" >&2
    npm ci --no-audit --no-fund --silent
fi
