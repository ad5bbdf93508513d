"""Rewrite the golden numbers in tests/golden/data/<chain>.json from a fresh run of the chains.

Run this ONLY when a change of arithmetic is intended (a new model, a fixed bug that moves the
numbers, a changed default), never to make a failing golden test pass after a refactor that was
meant to keep the arithmetic.  Say so in the commit that carries the new JSON: which quantities
moved, by how much, and why (``git diff tests/golden/data`` shows them).

Usage::

    .venv/bin/python tests/golden/regenerate.py              # all chains
    .venv/bin/python tests/golden/regenerate.py demo gnss    # some of them

Each chain runs in a temporary directory; the stored file holds numbers with their units and
tolerances (tests/golden/golden_chains.py), never digests or floating-point text to be compared
byte for byte, so it holds on any machine.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from golden_chains import CHAINS, GEONET_OBS, GOLDEN_DIR, golden_path  # noqa: E402


def main(argv: list[str]) -> int:
    chains = argv or list(CHAINS)
    unknown = [c for c in chains if c not in CHAINS]
    if unknown:
        print(f"unknown chain(s) {unknown}; known: {sorted(CHAINS)}", file=sys.stderr)
        return 2
    if "gnss" in chains and not GEONET_OBS.exists():
        print(f"the gnss chain needs the shared GEONET data: {GEONET_OBS} not found", file=sys.stderr)
        return 2
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    for chain in chains:
        with tempfile.TemporaryDirectory(prefix=f"golden-{chain}-") as tmp:
            numbers = CHAINS[chain](Path(tmp))
        golden_path(chain).write_text(numbers.to_json(chain))
        print(f"{golden_path(chain)}: {len(numbers.items)} quantities")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
