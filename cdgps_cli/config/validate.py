"""The config validator: the field declarations of :mod:`cdgps_cli.config.schema` applied to a
parsed TOML document (issue 32 item 6: validation declared once).

A table's declaration (:class:`~cdgps_cli.config.schema.Field` per key) gives each key's kind —
a name, free text, a number with its sign, a flag, one of some words, a vector or matrix with
its size, a reference to another table's names, a table of per-coordinate vectors — whether it is
required, and its default.  :func:`check_table` judges one table by it and returns the values
(defaults for keys not given); every problem is collected as ``key.path: what was expected, got
what`` so that a config's problems are all listed at once.  Checks that relate several keys
(exactly one master, one of two keys, matrices that must be a covariance …) are short named
functions in :mod:`cdgps_cli.config.structure`.
"""

from __future__ import annotations

import math

import numpy as np

#: a value that failed its check (the caller's fallback is used instead)
INVALID = object()

AXES = ("x", "y", "z")


def full_key(key: str, name) -> str:
    """``key.name`` (``name`` alone at the top level)."""
    return f"{key}.{name}" if key else str(name)


class Problems:
    """The problems found in one document, in the order found (``key: message`` each)."""

    def __init__(self, path: str):
        self.path = path
        self.problems: list[str] = []

    def add(self, key: str, msg: str) -> None:
        self.problems.append(f"{key}: {msg}")

    def __len__(self) -> int:
        return len(self.problems)

    def keys(self, table, key: str, required: set, optional: set) -> bool:
        """Unknown and missing keys of ``table``; False (and a problem) if it is not a table."""
        if not isinstance(table, dict):
            self.add(key, "expected a table")
            return False
        for k in sorted(set(table) - required - optional):
            self.add(full_key(key, k), f"unknown key (allowed: {', '.join(sorted(required | optional))})")
        for k in sorted(required - set(table)):
            self.add(full_key(key, k), "missing required key")
        return True

    # the value checks below add a problem and return INVALID, or return the checked value

    def number(self, full: str, v, sign: str = ""):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            self.add(full, f"expected a finite number, got {v!r}")
            return INVALID
        if sign == "positive" and v <= 0:
            self.add(full, f"expected a positive number, got {v!r}")
            return INVALID
        if sign == "nonneg" and v < 0:
            self.add(full, f"expected a non-negative number, got {v!r}")
            return INVALID
        return float(v)

    def name(self, full: str, v):
        if not isinstance(v, str) or not v:
            self.add(full, f"expected a non-empty string, got {v!r}")
            return INVALID
        bad = next((c for c in v if not c.isprintable()), None)
        if bad is not None:        # a NUL or newline in a name breaks every file that carries it (issue 32)
            self.add(full, f"expected printable characters, got {v!r} (contains U+{ord(bad):04X})")
            return INVALID
        return v

    def vector(self, full: str, v, size: int | None, unit: bool = False, sign: str = ""):
        ok = isinstance(v, list) and all(
            isinstance(e, (int, float)) and not isinstance(e, bool) and np.isfinite(e) for e in v)
        if not ok or (size is not None and len(v) != size):
            want = f"{size} finite numbers" if size is not None else "a list of finite numbers"
            got = f"{len(v)} values" if isinstance(v, list) else repr(v)
            self.add(full, f"expected {want}, got {got}")
            return INVALID
        arr = np.asarray(v, dtype=float)
        if unit:
            n = np.linalg.norm(arr)
            if n == 0:
                self.add(full, "expected a non-zero direction vector")
                return INVALID
            arr = arr / n
        if sign == "nonneg" and np.any(arr < 0):
            self.add(full, "expected non-negative values")
            return arr                    # (as before: the values are kept, the problem listed)
        return arr

    def matrix(self, full: str, v, size: int):
        ok = (isinstance(v, list) and len(v) == size and all(
            isinstance(r, list) and len(r) == size and all(
                isinstance(e, (int, float)) and not isinstance(e, bool) and np.isfinite(e) for e in r) for r in v))
        if not ok:
            got = f"{len(v)} rows" if isinstance(v, list) else repr(v)
            self.add(full, f"expected a {size}×{size} matrix (a list of {size} rows of {size} finite numbers), got {got}")
            return INVALID
        return np.array(v, dtype=float)


class Context:
    """What later tables refer to: the names (and coordinate kinds) of the tables checked so far,
    and the sizes of vectors and matrices (``coordinates``: n_q; ``process_noise``: its W's size)."""

    def __init__(self):
        self.names: dict[str, list] = {}
        self.coord_kinds: list[str] = []
        self.sizes: dict[str, int] = {}
        self.master: str | None = None

    def index(self, target: str) -> dict:
        return {n: i for i, n in enumerate(self.names.get(target, []))}


def _ref_expected(target: str, ctx: Context) -> str:
    names = ctx.names.get(target, [])
    if target == "coordinates":
        return f"expected the name of a coordinate ({', '.join(names)})"
    if target == "sections":
        return f"expected the name of a section ({', '.join(names) or 'none defined'})"
    if target == "rover_antennas":
        return f"expected a rover antenna ({', '.join(n for n in names if n != ctx.master)})"
    return f"expected a {target[:-1]} ({', '.join(names)})"


def check_ref(p: Problems, full: str, v, field, ctx: Context):
    """Index of the referenced name in its table (``field.ref``), or INVALID; a coordinate of
    another kind than ``field.ref_kind`` is a problem too (its index is still returned)."""
    if field.ref == "rover_antennas":
        ok = isinstance(v, str) and v in ctx.names.get("rover_antennas", []) and v != ctx.master
    else:
        ok = isinstance(v, str) and v in ctx.index(field.ref)
    if not ok:
        p.add(full, f"{_ref_expected(field.ref, ctx)}, got {v!r}")
        return INVALID
    j = ctx.index(field.ref)[v]
    if field.ref_kind and ctx.coord_kinds[j] != field.ref_kind:
        p.add(full, f"coordinate {v!r} is a {ctx.coord_kinds[j]}, expected a {field.ref_kind}")
    return j


def _per_coordinate(p: Problems, full: str, v, field, ctx: Context):
    """A ``{coordinate = [x, y, z]}`` table → (3, n_q) array (zeros where not given)."""
    out = np.zeros((3, ctx.sizes["coordinates"]))
    if not isinstance(v, dict):
        p.add(full, f"expected a table {field.what}")
        return out
    coords = ctx.index("coordinates")
    for ref, vec in v.items():
        j = coords.get(ref) if isinstance(ref, str) else None
        if j is None:
            p.add(f"{full}.{ref}", f"{_ref_expected('coordinates', ctx)}, got {ref!r}")
        vec = p.vector(f"{full}.{ref}", vec, 3)
        if j is not None and vec is not INVALID:
            out[:, j] = vec
    return out


def _axis(p: Problems, full: str, v):
    """x, y, z (a unit vector of the frame) or a 3-vector (normalised)."""
    if isinstance(v, str) and v in AXES:
        return np.eye(3)[AXES.index(v)]
    if isinstance(v, list):
        return p.vector(full, v, 3, unit=True)
    p.add(full, f"expected x, y, z or a 3-vector, got {v!r}")
    return INVALID


def _names(p: Problems, full: str, v, field, ctx: Context):
    """A list of names of ``field.ref`` (e.g. thrusters)."""
    known = ctx.names.get(field.ref, [])
    if not isinstance(v, list) or not all(isinstance(e, str) and e in known for e in v):
        bad = [e for e in v if not (isinstance(e, str) and e in known)] if isinstance(v, list) else v
        p.add(full, f"unknown {field.ref[:-1]} name(s) {bad!r}: expected a list of {field.ref[:-1]} names "
                    f"({', '.join(known) or 'none defined'})")
        return INVALID
    return v


def within(schema: dict, x: float) -> bool:
    """Whether ``x`` is inside the JSON Schema bounds of ``schema``."""
    return (x >= schema.get("minimum", -math.inf) and x > schema.get("exclusiveMinimum", -math.inf)
            and x <= schema.get("maximum", math.inf) and x < schema.get("exclusiveMaximum", math.inf))


def _paths(p: Problems, full: str, v, field) -> tuple:
    """One file path or a list of them (non-empty strings)."""
    v = [v] if isinstance(v, str) else v
    if not isinstance(v, list):
        p.add(full, f"expected a list of {field.what}, got {v!r}")
        return INVALID
    out = []
    for i, e in enumerate(v):
        if not isinstance(e, str) or not e:
            p.add(f"{full}[{i}]", f"expected a file path string, got {e!r}")
        else:
            out.append(e)
    return tuple(out)


def check_value(p: Problems, full: str, v, field, ctx: Context):
    """``v`` judged by its declaration: the checked value, or INVALID (a problem added)."""
    kind = field.kind
    if kind == "number":
        x = p.number(full, v, field.sign)
        if x is not INVALID and field.expect and not within(field.schema, x):
            p.add(full, f"expected {field.expect}, got {x!r}")     # (the value is kept, as a sign's is not)
        return x
    if kind == "name":
        return p.name(full, v)
    if kind == "text":
        if not isinstance(v, str):
            p.add(full, f"expected a string (free text in quotes), got {v!r}")
            return INVALID
        return v
    if kind == "flag":
        if not isinstance(v, bool):
            p.add(full, f"expected true or false, got {v!r}")
            return INVALID
        return v
    if kind == "enum":
        if not isinstance(v, str) or v not in field.choices:
            p.add(full, f"expected one of {sorted(field.choices)}, got {v!r}")
            return INVALID
        return v
    if kind == "vector":
        size = ctx.sizes[field.size] if isinstance(field.size, str) else field.size
        return p.vector(full, v, size, unit=field.unit, sign=field.sign)
    if kind == "matrix":
        return p.matrix(full, v, ctx.sizes[field.size])
    if kind == "ref":
        if field.allow_empty and v == "":
            return v
        j = check_ref(p, full, v, field, ctx)
        return v if (field.allow_empty and j is not INVALID) else j
    if kind == "per_coordinate":
        return _per_coordinate(p, full, v, field, ctx)
    if kind == "axis":
        return _axis(p, full, v)
    if kind == "names":
        return _names(p, full, v, field, ctx)
    if kind == "paths":
        return _paths(p, full, v, field)
    raise ValueError(f"no check for the field kind {kind!r}")


def default_of(field, index: int | None, ctx: Context):
    """A field's default (``"?{i}"`` formatted with the entry's index; a callable called with the context)."""
    d = field.default
    if callable(d):
        return d(ctx)
    if isinstance(d, str) and "{i}" in d:
        return d.format(i=index)
    return d


def check_table(p: Problems, table, key: str, fields: dict, ctx: Context, index: int | None = None) -> dict:
    """The values of one table's declared keys, judged by ``fields`` (key → Field).

    Keys judged by a cross-field check (``Field.cross``) are returned as given (``None`` when
    absent) for that check to judge; every other key gets its checked value, its default when
    absent, and its default (or ``Field.fallback``) when refused.
    """
    required = {k for k, f in fields.items() if f.required}
    if not p.keys(table, key, required, set(fields) - required):
        table = {}
    out = {}
    for name, f in fields.items():
        if f.cross:
            out[name] = table.get(name)
        elif name not in table:
            out[name] = default_of(f, index, ctx)
        else:
            v = check_value(p, full_key(key, name), table[name], f, ctx)
            out[name] = default_of(f, index, ctx) if v is INVALID else v
    return out


def array_tables(p: Problems, doc: dict, name: str, required: bool) -> list:
    """The entries of the array of tables ``[[name]]`` (empty, with a problem, if it is not one)."""
    v = doc.get(name, [])
    if not isinstance(v, list) or not all(isinstance(e, dict) for e in v):
        p.add(name, "expected an array of tables ([[%s]])" % name)
        return []
    if required and not v:
        p.add(name, f"at least one [[{name}]] entry is required")
    return v

