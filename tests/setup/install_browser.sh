#!/usr/bin/env bash
# Browser tests (tests/test_web_*.py) drive Debian's chromium headless through Playwright.
# Installs chromium with apt if it is missing (Playwright's own browser download is not used).
# EVCBENCH_SKIP_BROWSER=1 skips this; the browser tests then skip themselves.
set -euo pipefail
if [ "${EVCBENCH_SKIP_BROWSER:-0}" = "1" ]; then
    echo "install_browser: skipped (EVCBENCH_SKIP_BROWSER=1)"; exit 0
fi
if [ -x /usr/bin/chromium ]; then
    exit 0
fi
SUDO=""
if [ "$(id -u)" != "0" ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "install_browser: chromium is missing and we are not root; the browser tests will skip" >&2; exit 0
    fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq chromium >/dev/null
/usr/bin/chromium --version 2>/dev/null || true
