#!/usr/bin/env bash
# `make demo`: the whole chain on bundled and freshly simulated data; prints where the outputs are.
# Usage: scripts/demo.sh path/to/cdgps OUTDIR
set -euo pipefail
CDGPS=${1:-cdgps}
OUT=${2:-build/demo}
cd "$(dirname "$0")/.."
rm -rf "$OUT"
mkdir -p "$OUT"
echo "== cdgps demo: outputs in $OUT/"

echo "-- 1. static sensor test on the bundled testbed run (data/testbed-static: motion, then rest at -1.4 deg, 2 mm noise, 180 s)"
"$CDGPS" ingest data/testbed-static/receiver.csv.xz data/testbed-static/gyro.csv.xz \
    --config configs/testbed-1998.toml -o "$OUT/static/run.mcap"
"$CDGPS" info "$OUT/static/run.mcap"
"$CDGPS" init "$OUT/static/run.mcap" -o "$OUT/static/init.json"
# the structure was brought to rest at 80 s: static mode from there (--rest 80:), smoothed
"$CDGPS" estimate "$OUT/static/run.mcap" --init "$OUT/static/init.json" --rest 80: --smooth -o "$OUT/static/states.mcap"
"$CDGPS" evaluate --truth data/testbed-static --estimate "$OUT/static/states.mcap"
"$CDGPS" report static "$OUT/static/states.mcap" --gyro "$OUT/static/run.mcap" --angle "q6+q10" \
    --survey-deg -1.4 -o "$OUT/static/report"

echo "-- 2. dynamic sensor test: simulate 20 minutes of free vibration of the testbed, then the whole chain"
# noise and disturbance as the filter assumes (2 cm, full process noise), so NEES/NIS are meaningful
"$CDGPS" -q simulate configs/testbed-1998.toml --duration 1200 --seed 7 --scenario free --noise-m 0.02 \
    --disturbance-scale 1 -o "$OUT/free/sim"
"$CDGPS" ingest "$OUT/free/sim/receiver.csv" "$OUT/free/sim/gyro.csv" --config configs/testbed-1998.toml \
    -o "$OUT/free/run.mcap"
"$CDGPS" init "$OUT/free/run.mcap" -o "$OUT/free/init.json"
"$CDGPS" estimate "$OUT/free/run.mcap" --init "$OUT/free/init.json" --smooth -o "$OUT/free/states.mcap"
"$CDGPS" evaluate --truth "$OUT/free/sim" --estimate "$OUT/free/states.mcap"
"$CDGPS" export "$OUT/free/states.mcap" -o "$OUT/free/states.csv"
"$CDGPS" report spectrum "$OUT/free/states.mcap" --gyro "$OUT/free/run.mcap" -o "$OUT/free/report"

echo "-- 3. the 1995 two-degree-of-freedom model: batch initialization on 20 epochs (2.4 s), biases as states"
"$CDGPS" ingest data/teague-1995/receiver.csv.xz --config configs/teague-1995-2dof.toml -o "$OUT/dof2/run.mcap"
"$CDGPS" init "$OUT/dof2/run.mcap" --start 0 --duration 2.4 --no-process-noise -o "$OUT/dof2/init.json"
"$CDGPS" estimate "$OUT/dof2/run.mcap" --init "$OUT/dof2/init.json" --biases states -o "$OUT/dof2/states.mcap"
"$CDGPS" evaluate --truth data/teague-1995 --estimate "$OUT/dof2/states.mcap"

echo
echo "== done. Open in a browser:"
echo "   $OUT/static/report/report.html   (static sensor test, like Fig. 7 of the 1998 paper)"
echo "   $OUT/free/report/report.html     (spectra vs gyros and identified modes, like Fig. 8)"
echo "   MCAP files (open in Foxglove): $OUT/*/run.mcap, $OUT/*/states.mcap"
