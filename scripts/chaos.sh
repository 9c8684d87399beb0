#!/usr/bin/env bash
# The chaos harness of the shared backend (benches/chaos/, docs/operations.md): PostgreSQL and
# moto's S3 server, two API replicas and three workers, each in a network namespace the harness
# makes, steady mixed traffic with faults on a schedule (partitions, an object-store outage,
# SIGSTOP, kill -9, PostgreSQL restarts, a full disk), then the checker. Its last line says
# `violations: N`; the exit status is non-zero when N > 0.
#
#   scripts/chaos.sh [--minutes N] [--out DIR] [other options of benches/chaos/chaos.py]
#
# scripts/test.sh runs it for 3 minutes; the hour-long soak is `scripts/chaos.sh --minutes 60`.
# Needs root (namespaces, nftables, a tmpfs mount); installs iproute2 and nftables (Debian),
# PostgreSQL and moto when missing, and builds covec (dev profile).
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v ip >/dev/null || ! command -v nft >/dev/null; then
    echo "chaos: installing iproute2 and nftables (apt)" >&2
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq iproute2 nftables >/dev/null
fi
scripts/setup-postgres.sh
scripts/setup-s3.sh
python3 -c 'import boto3' 2>/dev/null || python3 -m pip install --quiet boto3

cargo build --quiet --bin covec
covec="${CARGO_TARGET_DIR:-$PWD/target}/debug/covec"
# A private copy: a target directory shared with other checkouts may be rebuilt meanwhile.
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cp "$covec" "$work/covec"

out=tests/artifacts/chaos/$(date -u +%Y%m%dT%H%M%S)
args=("$@")
for arg in "$@"; do [[ $arg == --out ]] && out=""; done
if [[ -n $out ]]; then
    mkdir -p "$out"
    args+=(--out "$out")
fi
python3 benches/chaos/chaos.py --covec "$work/covec" "${args[@]}"
