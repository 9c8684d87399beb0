#!/usr/bin/env bash
# Installs what the PostgreSQL-backend tests start (tests/service/pg.rs): the server binaries
# (`initdb`, `postgres`; each test runs its own throwaway cluster on a free loopback port),
# `pg_isready` and `psql`, from Debian's `postgresql` package. Safe to run on every test run.
set -euo pipefail

have_server() {
    compgen -G '/usr/lib/postgresql/*/bin/initdb' >/dev/null || command -v initdb >/dev/null
}
if ! have_server || ! command -v pg_isready >/dev/null || ! command -v psql >/dev/null; then
    echo "setup-postgres: installing postgresql (apt)" >&2
    sudo=""
    [[ $(id -u) -eq 0 ]] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq postgresql >/dev/null
fi
# As root the tests run the server as `postgres` through setpriv (PostgreSQL refuses root).
if [[ $(id -u) -eq 0 ]]; then
    id postgres >/dev/null 2>&1 || { echo "setup-postgres: no postgres user" >&2; exit 1; }
    command -v setpriv >/dev/null || { echo "setup-postgres: setpriv is missing (util-linux)" >&2; exit 1; }
fi
