#!/usr/bin/env bash
# Regenerate the bundled sample logs in data/ with the simulator (deterministic: fixed seeds,
# xz).  Usage: scripts/make_samples.sh [path/to/cdgps]
set -euo pipefail
cd "$(dirname "$0")/.."
CDGPS=${1:-.venv/bin/cdgps}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$CDGPS" -q simulate configs/testbed-1998-lumped.toml --duration 60 --seed 11 --scenario free -o "$tmp/testbed-free"
"$CDGPS" -q simulate configs/testbed-1998-lumped.toml --duration 180 --seed 12 --scenario static --noise-m 0.002 -o "$tmp/testbed-static"
"$CDGPS" -q simulate configs/teague-1995-2dof.toml --duration 30 --seed 13 --scenario free -o "$tmp/teague-1995"
for d in testbed-free testbed-static teague-1995; do
  rm -rf "data/$d"; mkdir -p "data/$d"
  for f in "$tmp/$d"/*; do
    case "$f" in
      *.csv) xz -9e -c "$f" > "data/$d/$(basename "$f").xz" ;;
      *) cp "$f" "data/$d/" ;;
    esac
  done
done
du -sh data/*
