#!/usr/bin/env bash
# `make demo`: run every stage that exists on the bundled data and say where the outputs are.
# Usage: scripts/demo.sh path/to/cdgps OUTDIR
set -euo pipefail
CDGPS=${1:-cdgps}
OUT=${2:-build/demo}
cd "$(dirname "$0")/.."
mkdir -p "$OUT"
echo "== cdgps demo: outputs in $OUT/"

echo "-- 1. simulate a fresh 1998-testbed free-vibration run (60 s, seed 1)"
"$CDGPS" simulate configs/testbed-1998.toml --duration 60 --seed 1 --scenario free --out "$OUT/sim-free"

echo "-- 2. ingest the bundled testbed runs (data/) into self-contained RUN.mcap files"
"$CDGPS" ingest data/testbed-free/receiver.csv.gz data/testbed-free/gyro.csv.gz \
    --config configs/testbed-1998.toml -o "$OUT/testbed-free.mcap"
"$CDGPS" ingest data/testbed-static/receiver.csv.gz data/testbed-static/gyro.csv.gz \
    --config configs/testbed-1998.toml -o "$OUT/testbed-static.mcap"
"$CDGPS" ingest data/teague-1995/receiver.csv.gz --config configs/teague-1995-2dof.toml -o "$OUT/teague-1995.mcap"
"$CDGPS" info "$OUT/testbed-static.mcap"

echo "-- 3. bias initialization (batch dynamic least squares + LAMBDA integer fixing)"
"$CDGPS" init "$OUT/testbed-free.mcap" -o "$OUT/testbed-free.init.json"
"$CDGPS" init "$OUT/testbed-static.mcap" -o "$OUT/testbed-static.init.json"
"$CDGPS" init "$OUT/teague-1995.mcap" --start 0 --duration 2.4 --no-process-noise -o "$OUT/teague-1995.init.json"

echo
echo "== done. Outputs:"
ls -1 "$OUT" | sed "s|^|   $OUT/|"
echo "   (open the .mcap files in Foxglove; INIT.json files hold biases, integers and the filter's initial state)"
