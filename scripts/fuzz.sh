#!/usr/bin/env bash
# Runs the cargo-fuzz targets (fuzz/fuzz_targets/) for a bounded time each; installs cargo-fuzz
# when missing. Usage: scripts/fuzz.sh [SECONDS_PER_TARGET (default 20)] [TARGET...]
# scripts/test.sh runs it with 20 s per target; README, "Fuzzing", gives the longer run.
#
# libFuzzer's instrumentation needs nightly rustc flags (-Zsanitizer, -Cpasses=sancov-module);
# on a stable toolchain RUSTC_BOOTSTRAP=1 lets stable rustc accept them. COVEC_FUZZ_SANITIZER
# picks cargo-fuzz's sanitizer: default `none` (still coverage-guided; panics, aborts, hangs and
# out-of-memory are crashes), a build CI can afford (README, "Fuzzing", has the cost);
# `address` adds AddressSanitizer for the unsafe code below covec.
# New corpus entries go to fuzz/corpus/<target>/ (not committed; fuzz/seeds/ are the seeds), a
# crash input to fuzz/artifacts/<target>/: keep it as a test in tests/cli/fuzz_regressions.rs.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=${1:-20}
shift || true
sanitizer=${COVEC_FUZZ_SANITIZER:-none}
target_dir=${COVEC_FUZZ_TARGET_DIR:-${CARGO_TARGET_DIR:-$PWD/target}/fuzz}
# The same options for the build and each run, or `cargo fuzz run` builds again. 16 codegen
# units instead of cargo-fuzz's 1: a build that uses both cores, for somewhat slower runs.
build=(-s "$sanitizer" --codegen-units 16 --target-dir "$target_dir")

if ! cargo fuzz --version >/dev/null 2>&1; then
    echo "fuzz.sh: installing cargo-fuzz" >&2
    cargo install cargo-fuzz --locked
fi
export RUSTC_BOOTSTRAP=1

targets=("$@")
if [[ ${#targets[@]} -eq 0 ]]; then
    mapfile -t targets < <(cargo fuzz list)
fi
cargo fuzz build "${build[@]}"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
for target in "${targets[@]}"; do
    mkdir -p "fuzz/corpus/$target"
    # -timeout: one input running 10 s is a hang; -rss_limit_mb: libFuzzer's default, stated.
    if ! cargo fuzz run "${build[@]}" "$target" \
        "fuzz/corpus/$target" "fuzz/seeds/$target" -- \
        -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
        >"$log" 2>&1; then
        tail -n 40 "$log" >&2
        echo "fuzz.sh: $target failed; the input is in fuzz/artifacts/$target/" >&2
        exit 1
    fi
    runs=$(grep -oE 'stat::number_of_executed_units: [0-9]+' "$log" | grep -oE '[0-9]+$')
    echo "fuzz.sh: $target: ${runs:-?} executions in ${seconds} s, no crash" >&2
done
