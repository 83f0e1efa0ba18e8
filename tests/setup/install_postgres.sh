#!/usr/bin/env bash
# Make sure a PostgreSQL server (Debian's package) is installed for the store tests.
# The tests start their own throw-away cluster in a temp dir (tests/support/pg_server.py); this
# script only installs the binaries when initdb/pg_ctl cannot be found.
# EVCBENCH_SKIP_POSTGRES=1 skips it (the PostgreSQL tests are then skipped, on purpose).
set -euo pipefail

if [ "${EVCBENCH_SKIP_POSTGRES:-0}" = "1" ]; then
    echo "install_postgres: EVCBENCH_SKIP_POSTGRES=1, not installing PostgreSQL"
    exit 0
fi

have_server() {
    if command -v initdb >/dev/null 2>&1 && command -v pg_ctl >/dev/null 2>&1; then
        return 0
    fi
    compgen -G "/usr/lib/postgresql/*/bin/pg_ctl" >/dev/null
}

if have_server; then
    exit 0
fi

echo "install_postgres: installing Debian's postgresql package"
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO="sudo"
    else
        echo "install_postgres: not root and no sudo; install the 'postgresql' package by hand" >&2
        exit 1
    fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends postgresql
have_server || { echo "install_postgres: postgresql installed but initdb/pg_ctl not found" >&2; exit 1; }
