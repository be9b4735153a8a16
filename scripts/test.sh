#!/usr/bin/env bash
# Set up everything the tests need from the project's own files, then run the suite.
# Usage: ./scripts/test.sh [pytest arguments]
set -euo pipefail
cd "$(dirname "$0")/.."

# Packages from the distribution: apt_install WHAT PACKAGE... (root or sudo; otherwise, or if
# the install fails, a note, and the tests that need them are skipped).
apt_install() {
    what=$1; shift
    sudo=""
    if [ "$(id -u)" -ne 0 ]; then
        if ! command -v sudo >/dev/null 2>&1; then
            echo "note: $* not installed and cannot be installed here; $what tests will be skipped" >&2
            return 0
        fi
        sudo=sudo
    fi
    if ! { $sudo apt-get update -qq && $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@"; }; then
        echo "note: installing $* failed; $what tests will be skipped" >&2
    fi
}

# The MQTT tests start a real broker: mosquitto.
if ! command -v mosquitto >/dev/null 2>&1 && [ ! -x /usr/sbin/mosquitto ]; then
    apt_install MQTT mosquitto
fi
# The dashboard's end-to-end tests drive a headless Chromium through its chromedriver
# (selenium, in the test extra); nothing is downloaded at run time.
if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
    apt_install "dashboard browser" chromium chromium-driver
fi

python3 -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet -e '.[test]'
.venv/bin/ruff check .
.venv/bin/mypy tmcl_spec interpreter axes tmcl_server
exec .venv/bin/python -m pytest -n 2 "$@"
