#!/usr/bin/env bash
# The test command: installs what the tests need on a fresh machine, then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."

# A fresh machine has cargo but maybe not nextest.
if ! cargo nextest --version >/dev/null 2>&1; then
    echo "test.sh: installing cargo-nextest" >&2
    cargo install cargo-nextest --locked
fi

scripts/setup-build.sh

# The code's shape (docs/design.md, "Code map"): layered imports, a build without the command
# line's and the service's dependencies, and the command line without the service's (README,
# "Install").
python3 scripts/check-modules.py
python3 scripts/check-modules.py --self-test
# The vendored rayon-core (vendor/README.md) is the copy built: a [patch] that stops applying
# after a `cargo update` is otherwise only a warning.
python3 scripts/check-patches.py
cargo check --quiet --lib --no-default-features
cargo check --quiet --bin covec --no-default-features --features cli
# The Dockerfile and deploy/ files, which nothing here builds or applies: linted and validated.
scripts/check-deploy.sh
# Formatting and lints, where the toolchain has rustfmt and clippy (rustup's default profile does).
if cargo fmt --version >/dev/null 2>&1; then
    cargo fmt --check
else
    echo "test.sh: no rustfmt in this toolchain, formatting not checked" >&2
fi
if cargo clippy --version >/dev/null 2>&1; then
    cargo clippy --quiet --workspace --all-targets -- -D warnings
else
    echo "test.sh: no clippy in this toolchain, lints skipped" >&2
fi

scripts/setup-renderers.sh
scripts/setup-clients.sh
scripts/setup-s3.sh
scripts/setup-postgres.sh
cargo nextest run --no-fail-fast --cargo-profile test "$@"

# The Python package (docs/python.md): its wheel built with maturin, installed into a fresh
# virtual environment, its pytest suite run there against the command line (3-5 minutes after
# the builds above, most of it pyo3's). COVEC_SKIP_PYTHON=1 skips it.
if [[ -z "${COVEC_SKIP_PYTHON:-}" ]]; then
    scripts/setup-python.sh
    scripts/test-python.sh
fi

# The service tests again on the shared backend (README, "Scaling out"): every test data directory
# gets its own throwaway PostgreSQL and its own bucket on one moto S3 server started here
# (tests/service/service_support), so every service test runs on the shared backend too (the two
# disk-fault tests with their files on the local disk). COVEC_SKIP_PG_PASS=1 skips it.
if [[ -z "${COVEC_SKIP_PG_PASS:-}" ]]; then
    s3_port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    moto_server -H 127.0.0.1 -p "$s3_port" >/dev/null 2>&1 &
    moto_pid=$!
    trap 'kill "$moto_pid" 2>/dev/null || true' EXIT
    for _ in $(seq 300); do
        curl -sf -o /dev/null "http://127.0.0.1:$s3_port/" && break
        sleep 0.1
    done
    COVEC_TEST_BACKEND=postgres COVEC_TEST_S3_ENDPOINT="http://127.0.0.1:$s3_port" \
        cargo nextest run --no-fail-fast --cargo-profile test -E \
        'binary(service) & test(/^(api|jobs|edits|downloads|faults|fair|hardening|records|s3|webhooks|readme_clients|generated_clients)::/)'
    kill "$moto_pid" 2>/dev/null || true
    wait "$moto_pid" 2>/dev/null || true
    trap - EXIT
fi

# The service tests on the memory backend (`serve --in-memory`): the third implementation of the
# backend seam (docs/design.md), held to the same tests; a test whose jobs must outlive a
# restart, or whose records it reads, keeps the embedded backend (DataDir::persistent in
# tests/service/service_support). COVEC_SKIP_MEMORY_PASS=1 skips it.
if [[ -z "${COVEC_SKIP_MEMORY_PASS:-}" ]]; then
    COVEC_TEST_BACKEND=memory cargo nextest run --no-fail-fast --cargo-profile test -E \
        'binary(service) & test(/^(api|jobs|edits|downloads|fair|hardening|records|webhooks|readme_clients|generated_clients)::/)'
fi

# The running service against api/openapi.yaml with schemathesis: every check, every phase
# (README, "The HTTP service"; about 30 s). COVEC_SKIP_SCHEMATHESIS=1 skips it.
if [[ -z "${COVEC_SKIP_SCHEMATHESIS:-}" ]]; then
    scripts/schemathesis.sh
fi

# Every fuzz target for a short, bounded time (README, "Fuzzing"). COVEC_SKIP_FUZZ=1 skips it.
if [[ -z "${COVEC_SKIP_FUZZ:-}" ]]; then
    scripts/fuzz.sh 20
fi

# The container image built from the Dockerfile and started: one node, then the scaled set-up's
# API and worker (scripts/container-test.sh; docs/operations.md, "Container image").
# COVEC_SKIP_CONTAINER=1 skips it, and says so.
if [[ -z "${COVEC_SKIP_CONTAINER:-}" ]]; then
    scripts/container-test.sh
else
    echo "test.sh: COVEC_SKIP_CONTAINER=1: the container image was neither built nor started" >&2
fi

# The chaos harness of the shared backend (benches/chaos/, docs/operations.md): two API
# replicas and three workers in network namespaces on PostgreSQL and moto, 3 minutes of mixed
# traffic with every fault kind once (partitions, the object store down, SIGSTOP, kill -9,
# PostgreSQL restarted, its disk full), then the checker; fails on any violation (about 4 min).
# COVEC_SKIP_CHAOS=1 skips it.
if [[ -z "${COVEC_SKIP_CHAOS:-}" ]]; then
    scripts/chaos.sh --minutes 3
fi

# The web page end to end, the same test in headless Debian Chromium and Firefox ESR
# (tests/browser/driver.mjs), each against a real `covec serve` on a free loopback port with a
# fresh data directory. Screenshots go to tests/artifacts/browser/BROWSER/. COVEC_SKIP_BROWSER=1
# skips it.
if [[ -z "${COVEC_SKIP_BROWSER:-}" ]]; then
    scripts/setup-browser.sh
    covec_bin=$(cargo build --bin covec --message-format=json-render-diagnostics \
        | node -e 'let s = ""; process.stdin.on("data", (d) => (s += d)).on("end", () => {
              for (const line of s.split("\n")) {
                  try { const m = JSON.parse(line); if (m.executable && m.target?.name === "covec") console.log(m.executable); } catch {}
              }
          })')
    # A private copy: a target directory shared with other checkouts may be rebuilt meanwhile.
    browser_tmp=$(mktemp -d)
    trap 'rm -rf "$browser_tmp"' EXIT
    cp "$covec_bin" "$browser_tmp/covec"
    # Both browsers run even if the first fails.
    browser_failed=0
    for browser in chromium firefox; do
        node tests/browser/page.test.mjs --covec "$browser_tmp/covec" --browser "$browser" || browser_failed=1
    done
    exit "$browser_failed"
fi
