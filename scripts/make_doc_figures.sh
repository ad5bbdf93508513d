#!/usr/bin/env bash
# Regenerate docs/figures/ (the figures of docs/method.md) from a fresh demo run.
# Usage: scripts/make_doc_figures.sh [path/to/cdgps]   (default .venv/bin/cdgps; ~3 min)
set -euo pipefail
cd "$(dirname "$0")/.."
CDGPS=${1:-.venv/bin/cdgps}
PY=$(dirname "$CDGPS")/python
DEMO=build/doc-figures
bash scripts/demo.sh "$CDGPS" "$DEMO" > "$DEMO.log" 2>&1 || { cat "$DEMO.log"; exit 1; }
"$PY" scripts/make_doc_figures.py "$DEMO" docs/figures
