#!/usr/bin/env bash
# Set up everything the tests need from the project's own files, then run the suite.
# Usage: ./scripts/test.sh [pytest arguments]
#   Without arguments it also builds the wheel and smoke-tests it in a fresh virtualenv
#   (scripts/wheel_smoke.py); with arguments (a subset of the tests) it runs just pytest.
#   It never asks for a password: the MQTT tests need mosquitto and the dashboard's browser
#   tests chromium and chromium-driver, from the distribution; when one is missing a line
#   names the command that installs it and those tests are skipped (.ci/run installs them and
#   sets TMCL_SIM_REQUIRE_ALL=1, under which a missing one fails the run instead).
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh

missing() {  # missing WHAT PACKAGE...: one line, the command that installs them
    echo "test.sh: $1 tests skipped: $2 missing; install with: sudo apt-get install ${*:3}" >&2
}
if ! command -v mosquitto >/dev/null 2>&1 && [ ! -x /usr/sbin/mosquitto ]; then
    missing MQTT mosquitto mosquitto
fi
if ! { [ -x /usr/bin/chromium ] || command -v chromium >/dev/null 2>&1; } ||
    ! { [ -x /usr/bin/chromedriver ] || command -v chromedriver >/dev/null 2>&1; }; then
    missing "dashboard browser" "chromium or chromedriver" chromium chromium-driver
fi

ensure_venv test.sh test
.venv/bin/ruff check .
.venv/bin/mypy tmcl_spec interpreter axes tmcl_server
if [ "$#" -eq 0 ]; then
    .venv/bin/python scripts/wheel_smoke.py
fi
exec .venv/bin/python -m pytest -n 2 "$@"
