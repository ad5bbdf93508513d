#!/usr/bin/env python3
"""Write docs/schema/structure-config.schema.json and gnss-config.schema.json from the one declaration of
the configs' keys (cdgps_cli/config/schema.py) and bounds (cdgps_cli/config/limits.py).

    python scripts/make_config_schema.py            # write it
    python scripts/make_config_schema.py --check    # exit 1 if the committed file differs
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.schema import gnss_json_schema, structure_json_schema  # noqa: E402
from cdgps_cli.config.structure import _SIM_DEFAULTS  # noqa: E402

OUT = ROOT / "docs" / "schema" / "structure-config.schema.json"
GNSS_OUT = ROOT / "docs" / "schema" / "gnss-config.schema.json"


def schema_text() -> str:
    return json.dumps(structure_json_schema(_SIM_DEFAULTS), indent=2, ensure_ascii=False) + "\n"


def gnss_schema_text() -> str:
    return json.dumps(gnss_json_schema(), indent=2, ensure_ascii=False) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="compare instead of writing")
    a = ap.parse_args()
    ok = True
    for out, text in ((OUT, schema_text()), (GNSS_OUT, gnss_schema_text())):
        if a.check:
            same = out.exists() and out.read_text() == text
            print(f"{out}: {'up to date' if same else 'differs from the code: run scripts/make_config_schema.py'}")
            ok &= same
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
        print(f"wrote {out}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
