"""GAINS.json: an LQR design written by ``cdgps control design`` and read by the closed loop.

Format (``format = "cdgps-gains"``, ``version = 1``): the discrete ``A`` and ``B`` the gain was
designed on, the weights ``Qx`` and ``Qu``, the gain ``K`` (u = −K x, N per state unit), the
sample period, state and thruster names, ``weight_set`` (which weights: ``"paper"``, the 1998
paper's Sec. V numbers; ``"tuned"``, the experiments'; ``"custom"``), the open- and closed-loop pole tables, the Riccati
residual, the config's path and sha256, the options and the software versions.  Matrices are lists
of rows.  A reader checks the config's sha256 so a gain is never applied to another structure.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cdgps_cli.io.atomic import file_sha256, write_bytes_atomic
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.provenance import software

FORMAT = "cdgps-gains"
VERSION = 1


def gains_record(design, poles: dict, *, config_path, state_names, thruster_names, options: dict,
                 weight_set: str = "custom") -> dict:
    """The JSON-ready record of a design (see the module docstring); ``weight_set`` names the weights
    (``"paper"``, ``"tuned"`` or ``"custom"``)."""
    return {
        "format": FORMAT, "version": VERSION,
        "config": {"path": str(config_path), "sha256": file_sha256(config_path)},
        "sample_period_s": design.sample_period_s,
        "state_names": list(state_names), "thruster_names": list(thruster_names),
        "A": design.A.tolist(), "B": design.B.tolist(), "Qx": design.Qx.tolist(), "Qu": design.Qu.tolist(),
        "K": design.K.tolist(), "weight_set": weight_set,
        "riccati_residual": design.riccati_residual,
        "poles": poles,
        "options": options,
        "software": software(),
    }


def write_gains(path: str | Path, record: dict) -> None:
    """Write GAINS.json atomically (sorted keys, 2-space indent, a final newline)."""
    write_bytes_atomic(path, (json.dumps(record, indent=2, sort_keys=True, allow_nan=False) + "\n").encode())


def read_gains(path: str | Path, config_path: str | Path | None = None) -> dict:
    """Read and check a GAINS.json; with ``config_path``, refuse a gain designed for another config.

    Returns
    -------
    dict
        The record with ``A``, ``B``, ``Qx``, ``Qu`` and ``K`` as float arrays.
    """
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CdgpsError(f"{path}: not a readable GAINS.json ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise CdgpsError(f"{path}: not a GAINS.json (expected format {FORMAT!r} version {VERSION})")
    n, m = len(doc.get("state_names", [])), len(doc.get("thruster_names", []))
    for key, shape in (("A", (n, n)), ("B", (n, m)), ("Qx", (n, n)), ("Qu", (m, m)), ("K", (m, n))):
        try:
            doc[key] = np.asarray(doc[key], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise CdgpsError(f"{path}: key {key!r}: expected a numeric matrix") from None
        if doc[key].shape != shape or not np.all(np.isfinite(doc[key])):
            raise CdgpsError(f"{path}: key {key!r}: expected a finite {shape[0]}×{shape[1]} matrix, "
                             f"got shape {doc[key].shape}")
    if config_path is not None and doc["config"].get("sha256") != file_sha256(config_path):
        raise CdgpsError(f"{path}: designed for config {doc['config'].get('path')} (sha256 "
                         f"{str(doc['config'].get('sha256'))[:12]}…), not {config_path}; design the gain "
                         f"for this config with `cdgps control design`")
    return doc
