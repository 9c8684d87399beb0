#!/usr/bin/env bash
# The test command: installs what the tests need on a fresh machine, then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo nextest run --no-fail-fast --cargo-profile test "$@"
