#!/bin/sh
# The README's `python3 scripts/test.py` for those who type this (scripts/test.py says how).
exec python3 "$(dirname "$0")/test.py" "$@"
