#!/bin/sh
# The README's `python3 scripts/serve.py` for those who type this (scripts/serve.py says how).
exec python3 "$(dirname "$0")/serve.py" "$@"
