#!/usr/bin/env bash
# Installs what the browser test needs, idempotently: Debian's Chromium (/usr/bin/chromium) and
# Firefox ESR (/usr/bin/firefox-esr), and the pinned puppeteer-core under tests/browser/node_modules.
# Safe to run on every test run.
set -euo pipefail
cd "$(dirname "$0")/.."

missing=()
[[ -x /usr/bin/chromium ]] || missing+=(chromium)
[[ -x /usr/bin/firefox-esr ]] || missing+=(firefox-esr)
if [[ ${#missing[@]} -gt 0 ]]; then
    echo "setup-browser: installing Debian ${missing[*]}" >&2
    sudo_cmd=()
    if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    echo "setup-browser: node and npm are needed (Debian packages nodejs and npm)" >&2
    exit 1
fi

cd tests/browser
# puppeteer-core ships no browser and downloads none.
if [[ ! -f node_modules/puppeteer-core/package.json ]] \
    || [[ package-lock.json -nt node_modules/.package-lock.json ]]; then
    echo "setup-browser: npm ci in tests/browser" >&2
    npm ci --no-audit --no-fund --silent
fi
