#!/usr/bin/env bash
# Installs the S3-compatible server the object-store tests start on loopback
# (tests/service_s3.rs): moto's `moto_server`, from PyPI. Safe to run on every test run.
set -euo pipefail

if ! command -v moto_server >/dev/null; then
    echo "setup-s3: installing moto[server] (PyPI)" >&2
    python3 -m pip install --quiet 'moto[server]'
fi
command -v curl >/dev/null || {
    echo "setup-s3: curl is missing (scripts/setup-clients.sh installs it)" >&2
    exit 1
}
