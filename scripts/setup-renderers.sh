#!/usr/bin/env bash
# Installs the renderers the output tests call, idempotently: Debian's poppler-utils (pdftoppm,
# for tests/flat_output.rs's PDF test). Safe to run on every test run.
set -euo pipefail

if ! command -v pdftoppm >/dev/null; then
    echo "setup-renderers: installing Debian poppler-utils" >&2
    sudo_cmd=()
    if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends poppler-utils >/dev/null
fi
