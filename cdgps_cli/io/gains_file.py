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
from cdgps_cli.io.file_checks import refuse_deep_json
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


def gain_sha256(K) -> str:
    """Hex sha256 of the gain matrix as float64 bytes (C order): which design a closed-loop run used.

    ``cdgps simulate --controller`` writes it into truth.json (``controller.gains_k_sha256``) and
    ``cdgps report control`` refuses a GAINS.json whose K is another (issue 32)."""
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(np.asarray(K, dtype="<f8")).tobytes()).hexdigest()


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
        text = Path(path).read_text(encoding="utf-8")
        refuse_deep_json(text, path, "a GAINS.json written by 'cdgps control design'")
        doc = json.loads(text)
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
    _check_period_and_poles(doc, path)
    if config_path is not None and doc["config"].get("sha256") != file_sha256(config_path):
        raise CdgpsError(f"{path}: designed for config {doc['config'].get('path')} (sha256 "
                         f"{str(doc['config'].get('sha256'))[:12]}…), not {config_path}; design the gain "
                         f"for this config with `cdgps control design`")
    return doc


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _check_period_and_poles(doc: dict, path) -> None:
    """``sample_period_s`` a positive number; ``poles`` the tables ``control design`` writes (issue 32:
    ``"poles": null`` ended in a TypeError inside ``report control``)."""
    dt = doc.get("sample_period_s")
    if not (_is_number(dt) and dt > 0):
        raise CdgpsError(f"{path}: key 'sample_period_s': expected a positive number of seconds, got {dt!r}")
    poles = doc.get("poles")
    if not isinstance(poles, dict):
        raise CdgpsError(f"{path}: key 'poles': expected the pole tables written by `cdgps control design`, got {poles!r}")
    for loop in ("open_loop", "closed_loop"):
        rows = poles.get(loop)
        if not isinstance(rows, list) or not all(isinstance(r, dict) and _is_number(r.get("z_re"))
                                                 and _is_number(r.get("z_im")) for r in rows):
            raise CdgpsError(f"{path}: key 'poles.{loop}': expected a list of poles with numeric z_re and z_im")
    for loop in ("open_loop", "closed_loop"):
        settle = (poles.get("settling_time_s") or {}).get(loop) if isinstance(poles.get("settling_time_s"), dict) else None
        if not isinstance(settle, dict) or not all(v is None or (_is_number(v) and v >= 0) for v in settle.values()):
            raise CdgpsError(f"{path}: key 'poles.settling_time_s.{loop}': expected a table of mode -> seconds (or null)")
