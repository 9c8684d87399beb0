#!/usr/bin/env bash
# The main job with default settings: installs what the build needs, builds covec (release) and
# runs `covec serve`, the service and its web page on http://127.0.0.1:8080. Arguments go to
# `covec serve` (`scripts/serve.sh --help` lists them).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup-build.sh
exec cargo run --release --quiet -- serve "$@"
