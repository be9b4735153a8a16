#!/bin/sh
# Make the README's plot (docs/plot-example.png) with the tools themselves: a recording
# simulator, a program uploaded and run with `tmcl`, then `tmcl plot`.
# Usage: ./scripts/plot_example.sh [OUT.png]
#   Without OUT the picture goes to a new temporary folder (its path is printed): the tracked
#   docs/plot-example.png changes only when asked for, ./scripts/plot_example.sh docs/plot-example.png.
#   OUT is the caller's path (relative to the directory the script was started in).
set -eu
case ${1:-} in
    "") OUT=$(mktemp -d)/plot-example.png ;;
    /*) OUT=$1 ;;
    *) OUT=$(pwd)/$1 ;;
esac
cd "$(dirname "$0")/.."
BIN=${BIN:-.venv/bin}
TMP=$(mktemp -d)
trap 'kill "$SERVER" 2>/dev/null || true; rm -rf "$TMP"' EXIT

"$BIN/tmcl-server" --tcp 127.0.0.1:0 --ready-file "$TMP/ready.json" --speed 10 \
    --world docs/examples/plot-world.toml --record "$TMP/record.csv" --record-axes 0,1 \
    --record-resolution 0.005 > "$TMP/server.log" &
SERVER=$!
while [ ! -s "$TMP/ready.json" ]; do sleep 0.05; done
TCP=$("$BIN/python" -c "import json,sys; print(json.load(open(sys.argv[1]))['tcp'][0])" "$TMP/ready.json")

"$BIN/tmcl" --tcp "$TCP" program upload docs/examples/plot-demo.tmc --verify
"$BIN/tmcl" --tcp "$TCP" program run --wait
"$BIN/tmcl" --tcp "$TCP" send GAP ActualPosition 1
kill -TERM "$SERVER"; wait "$SERVER" || true
"$BIN/tmcl" plot "$TMP/record.csv" -o "$OUT" --title "docs/examples/plot-demo.tmc, recorded by tmcl-server --record"
