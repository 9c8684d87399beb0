#!/usr/bin/env bash
# What building covec needs besides Rust, installed idempotently: pkg-config and SQLite's
# development files (the binary links the system libsqlite3), from Debian's packages.
set -euo pipefail

sudo_cmd=()
if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
if ! pkg-config --exists sqlite3 2>/dev/null; then
    echo "setup-build: installing Debian pkg-config libsqlite3-dev" >&2
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends pkg-config libsqlite3-dev >/dev/null
fi
