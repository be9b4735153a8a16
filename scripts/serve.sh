#!/usr/bin/env bash
# Set up the simulator from the project's own files and start it.
# Usage: ./scripts/serve.sh [tmcl-server arguments]   (default: TCP 127.0.0.1:2323 + /tmp/ttyTMCL0)
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv .venv
# the "examples" extra: pytrinamic, for scripts/example_pytrinamic.py and the README's snippets;
# the "fast" extra: uvloop, which the server uses when it is installed
.venv/bin/python -m pip install --quiet -e '.[examples,fast]'
if [ "$#" -eq 0 ]; then set -- --pty /tmp/ttyTMCL0; fi
exec .venv/bin/tmcl-server "$@"
