#!/usr/bin/env bash
# Set up the simulator from the project's own files and start it.
# Usage: ./scripts/serve.sh [tmcl-server arguments]
#   Default: TCP 127.0.0.1:2323 and the virtual serial port /tmp/ttyTMCL0.  Other arguments
#   are added to those; the pty is left out only when the arguments name a --pty or --serial
#   of their own.  The first start creates .venv and installs tmcl-sim with what the README's
#   examples use; later starts reuse it (scripts/venv.sh).  PYTHON=... picks the Python.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/venv.sh

# examples: pytrinamic (scripts/example_pytrinamic.py, the README's snippets); fast: uvloop;
# plot: matplotlib (tmcl plot); http: aiohttp (--http, the dashboard); tools: pytrinamic for
# tmcl --connection (real modules)
SERVE_EXTRAS="examples,fast,plot,http,tools"
ensure_venv serve.sh "$SERVE_EXTRAS"

own_port=no
for argument in "$@"; do
    case $argument in
        --pty | --pty=* | --serial | --serial=*) own_port=yes ;;
    esac
done
if [ "$own_port" = no ]; then set -- --pty /tmp/ttyTMCL0 "$@"; fi
exec .venv/bin/tmcl-server "$@"
