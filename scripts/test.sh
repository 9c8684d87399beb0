#!/usr/bin/env bash
# The test command: installs what the tests need on a fresh machine, then runs every test.
set -euo pipefail
cd "$(dirname "$0")/.."

# A fresh machine has cargo but maybe not nextest.
if ! cargo nextest --version >/dev/null 2>&1; then
    echo "test.sh: installing cargo-nextest" >&2
    cargo install cargo-nextest --locked
fi

# The library's shape (README, "Code map"): layered imports, and a build without the command
# line's and the service's dependencies.
python3 scripts/check-modules.py
cargo check --quiet --lib --no-default-features
# The Dockerfile and deploy/ files, which nothing here builds or applies: linted and validated.
scripts/check-deploy.sh
# Formatting and lints, where the toolchain has rustfmt and clippy (rustup's default profile does).
if cargo fmt --version >/dev/null 2>&1; then
    cargo fmt --check
else
    echo "test.sh: no rustfmt in this toolchain, formatting not checked" >&2
fi
if cargo clippy --version >/dev/null 2>&1; then
    cargo clippy --quiet --all-targets -- -D warnings
else
    echo "test.sh: no clippy in this toolchain, lints skipped" >&2
fi

scripts/setup-renderers.sh
scripts/setup-clients.sh
scripts/setup-s3.sh
scripts/setup-postgres.sh
cargo nextest run --no-fail-fast --cargo-profile test "$@"

# The service tests again on the shared backend (README, "Scaling out"): every test data directory
# gets its own throwaway PostgreSQL (tests/service_support). Left out, what only the embedded
# backend promises: SQLite rows quarantined, files of any age swept at start (the shared backend
# waits 10 minutes: another replica may be admitting them). COVEC_SKIP_PG_PASS=1 skips it.
if [[ -z "${COVEC_SKIP_PG_PASS:-}" ]]; then
    COVEC_TEST_BACKEND=postgres cargo nextest run --no-fail-fast --cargo-profile test -E \
        'binary(/^(service_(api|jobs|edits|faults|fair|hardening|records|s3|webhooks)|readme_clients)$/)
         and not test(/^(a_corrupt_job_record|orphaned_job_directories|deleted_jobs_stay_deleted|deletes_on_a_full|results_live_in_the_bucket)/)'
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

# The web page end to end (issue 7), the same test in headless Debian Chromium and Firefox ESR
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
