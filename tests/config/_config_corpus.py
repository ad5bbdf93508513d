"""Structure configs for the golden test of parse_config (issue 32 item 6): every shipped and test
config, and single-key mutations of them (deleted, wrong type, negative, zero, wrong length …),
with a canonical digest of what parse_config makes of each (the config's fields, or its problems)."""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

#: replacement values of a mutation (None: the key deleted)
MUTATIONS = (None, "x", "", -1.0, 0, [1.0], True, {"a": 1}, float("inf"), 1e300)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "inf" if v == math.inf else "-inf" if v == -math.inf else "nan" if v != v else repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(e) for e in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(e)}" for k, e in v.items()) + "}"
    raise TypeError(v)


def to_toml(doc: dict) -> str:
    """TOML text of a parsed config document (scalars first, then tables, then arrays of tables)."""
    out = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in doc.items()
           if not isinstance(v, dict) and not (isinstance(v, list) and v and all(isinstance(e, dict) for e in v))]
    for k, v in doc.items():
        if isinstance(v, dict):
            out.append(f"[{json.dumps(k)}]")
            out += [f"{json.dumps(kk)} = {_toml_value(vv)}" for kk, vv in v.items()]
        elif isinstance(v, list) and v and all(isinstance(e, dict) for e in v):
            for e in v:
                out.append(f"[[{json.dumps(k)}]]")
                out += [f"{json.dumps(kk)} = {_toml_value(vv)}" for kk, vv in e.items()]
    return "\n".join(out) + "\n"


def base_configs() -> dict[str, str]:
    """name → text of every structure config shipped (configs/) or written in the tests."""
    from cdgps_cli.config.structure import config_kind

    out = {p.name: p.read_text() for p in sorted((ROOT / "configs").glob("*.toml"))
           if config_kind(p.read_text()) == "structure"}
    import tests.config.test_structure as ts
    out["test_structure.FE_CONFIG"] = ts.FE_CONFIG
    return out


def _leaves(doc, prefix=(), deep=False):
    """Key paths of the first entry of every table / array of tables and of every key in them
    (``deep``: of nested tables' keys too)."""
    for k, v in doc.items():
        if deep and isinstance(v, dict):
            yield prefix + (k,)
            yield from _leaves(v, prefix + (k,), deep)
            continue
        if isinstance(v, list) and v and all(isinstance(e, dict) for e in v):
            yield prefix + (k,)
            for i in sorted({0, len(v) - 1}):
                for kk in v[i]:
                    yield prefix + (k, i, kk)
        elif isinstance(v, dict):
            yield prefix + (k,)
            for kk in v:
                yield prefix + (k, kk)
        else:
            yield prefix + (k,)


def _edit(doc: dict, path: tuple, value, delete: bool = False) -> str:
    d = json.loads(json.dumps(doc, default=float))          # a deep copy (inf survives as Infinity)
    node = d
    for step in path[:-1]:
        node = node[step]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return to_toml(d)


def mutated(text: str, deep: bool = False):
    """(label, make) of every single-key mutation of a config, plus an unknown key per table;
    ``make()`` writes the mutated config's text."""
    doc = tomllib.loads(text)
    paths = list(_leaves(doc, deep=deep))
    for path in paths:
        for m in MUTATIONS:
            yield f"{'.'.join(map(str, path))}={m!r}", (lambda path=path, m=m: _edit(doc, path, m, m is None))
    for path in dict.fromkeys(p[:-1] for p in paths):     # an unknown key in each table, once
        node = doc
        for step in path:
            node = node[step]
        if isinstance(node, dict):
            yield f"{'.'.join(map(str, path))}+no_such_key", (lambda path=path: _edit(doc, path + ("no_such_key",), 1))


#: a GNSS run config with every key of docs/gnss-pipeline.md set
GNSS_EVERY_KEY = """
[gnss]
name = "every-key"
description = "all the settings"
master = "base"
nav = ["nav/a.rnx", "nav/b.rnx"]
mask_deg = 10.0
ratio = 2.5
min_success_rate = 0.99
partial = false
fix = true
weighting = "equal"
sigma_a_m = 0.004
sigma_b_m = 0.002
code_ratio = 80.0
troposphere = false
max_gap_s = 30.0
sync_tol_s = 0.01
max_age_s = 5.0
code_correlation_s = 20.0
epoch_alignment = "doppler"
signals = ["G:L1", "E:E1"]
iono_threshold_km = 12.0

[gnss.displacement]
model = "random_walk"
sigma_m_per_sqrt_s = [0.001, 0.002, 0.003]
initial_sigma_m = 0.5
phase_noise = "auto"

[gnss.antennas.base]
rinex = "base.obs"
position_ecef_m = [-3957199.0, 3310199.0, 3737711.0]
description = "the master"

[gnss.antennas.rover]
ubx = "rover.ubx"
"""


def gnss_base_configs() -> dict[str, str]:
    """name → text of every GNSS run config shipped (configs/) and one with every key."""
    from cdgps_cli.config.structure import config_kind

    out = {p.name: p.read_text() for p in sorted((ROOT / "configs").glob("*.toml"))
           if config_kind(p.read_text()) == "gnss"}
    out["GNSS_EVERY_KEY"] = GNSS_EVERY_KEY
    return out


def _canonical(v):
    if isinstance(v, np.ndarray):
        a = np.ascontiguousarray(v)
        return ["ndarray", str(a.dtype), list(a.shape), hashlib.sha256(a.tobytes()).hexdigest()[:16],
                bool(a.flags.writeable)]
    if isinstance(v, (list, tuple)):
        return [type(v).__name__, [_canonical(e) for e in v]]
    if isinstance(v, dict):
        return ["dict", [[k, _canonical(e)] for k, e in v.items()]]
    if isinstance(v, float):
        return ["float", repr(v)]
    if hasattr(v, "__dataclass_fields__"):
        return [type(v).__name__, [[f, _canonical(getattr(v, f))] for f in v.__dataclass_fields__]]
    return [type(v).__name__, repr(v)]


def outcome(parse, text: str, path: str = "c.toml"):
    """What ``parse`` makes of a config: its fields canonically, or the sorted problems it lists."""
    from cdgps_cli.core.errors import CdgpsError

    try:
        cfg = parse(text, path)
    except CdgpsError as exc:
        msg = str(exc)
        head, _, rest = msg.partition("\n")
        lines = sorted(ln[4:] for ln in rest.splitlines()) if rest else [head.split(": ", 2)[-1]]
        return {"error": head.split(":")[0], "problems": lines}
    return {"config": _canonical(cfg)}


def digest(o) -> str:
    return hashlib.sha256(json.dumps(o, sort_keys=True).encode()).hexdigest()[:16]
