#!/usr/bin/env bash
# The main job with default settings: installs what the build needs, builds covec (release,
# with cargo's progress shown: the first build compiles about 420 crates, most of an hour on
# two cores; later ones recompile covec alone) and runs `covec serve`, the service and its web
# page on http://127.0.0.1:8080. Arguments go to `covec serve` (`scripts/serve.sh --help` lists
# them).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup-build.sh
echo "serve.sh: building covec (release); a first build takes a while, its progress below" >&2
cargo build --release --bin covec
exec cargo run --release --quiet -- serve "$@"
