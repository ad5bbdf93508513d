"""Column names of coordinate tables in CSV files (issue 32 item 5: units in every exported name).

``cdgps export`` and the simulators' ``truth.csv`` carry one column per coordinate and, in the
export, its 1-σ: ``<name>_<unit>`` and ``sigma_<name>_<unit>`` (``q1_rad``, ``sigma_q1_rad``,
``a120_e_m``, ``qx-1_m``), with ``time_s`` first.  The unit is the coordinate's kind (``m`` for a
translation, ``rad`` for a rotation); a modal coordinate takes the unit its ``unit`` label starts
with (``"m at the top (x)"`` → ``m``), else ``1`` (a dimensionless modal amplitude).

Readers accept files written before the suffixes (bare ``q1``), preferring the suffixed column
when a file has both: :func:`coordinate_table`.
"""

from __future__ import annotations

#: the units a modal coordinate's label may start with (the amplitude's unit at its reference point)
_LABEL_UNITS = ("m", "rad")


def column_unit(model, name: str) -> str:
    """Unit suffix of coordinate ``name``'s columns: ``m``, ``rad`` or ``1``.

    Parameters
    ----------
    model : StructureConfig or CoordinateModel
        Anything with ``coord_unit(name)`` (``m``, ``rad``, ``1``) and ``coord_unit_label(name)``.
    name : str
    """
    unit = model.coord_unit(name)
    if unit == "1":
        first = model.coord_unit_label(name).split(" ", 1)[0]
        if first in _LABEL_UNITS:
            return first
    return unit


def coordinate_column(name: str, unit: str) -> str:
    """``<name>_<unit>``: the column of a coordinate's value."""
    return f"{name}_{unit}"


def sigma_column(name: str, unit: str) -> str:
    """``sigma_<name>_<unit>``: the column of a coordinate's 1-σ."""
    return f"sigma_{name}_{unit}"


def coordinate_columns(model, names=None) -> list[str]:
    """Value columns of ``names`` (default: every coordinate of ``model``), in order."""
    names = list(model.coord_names if names is None else names)
    return [coordinate_column(n, column_unit(model, n)) for n in names]


def find_column(columns, name: str, unit: str) -> str | None:
    """The column holding coordinate ``name``: ``<name>_<unit>``, else a bare ``<name>`` (a file
    written before issue 32), else None."""
    cols = set(columns)
    for c in (coordinate_column(name, unit), name):
        if c in cols:
            return c
    return None


def coordinate_table(df, model, names=None):
    """``(df, missing)``: ``df`` with each coordinate's values under its bare name (the suffixed
    column preferred, a bare one accepted) and the expected column names of those not found.

    Parameters
    ----------
    df : pandas.DataFrame
        A table read from ``truth.csv`` or an export.
    model : StructureConfig or CoordinateModel
    names : sequence of str, optional
        The coordinates wanted (default: all of ``model``).

    Returns
    -------
    (DataFrame, list of str)
        A frame with ``time_s`` (if present) and one column per found coordinate, named bare;
        the missing ones as ``<name>_<unit>``.
    """
    names = list(model.coord_names if names is None else names)
    found, missing = {}, []
    for n in names:
        unit = column_unit(model, n)
        c = find_column(df.columns, n, unit)
        if c is None:
            missing.append(coordinate_column(n, unit))
        else:
            found[n] = df[c]
    out = df[["time_s"]].copy() if "time_s" in df.columns else df.iloc[:, :0].copy()
    for n, col in found.items():
        out[n] = col.to_numpy()
    return out, missing


def velocity_name(name: str) -> str:
    """The velocity of a GNSS displacement coordinate ``<rover>_<e|n|u>``: ``<rover>_v<e|n|u>`` (its CSV
    column ``<rover>_ve_m_s``, as ``cdgps rtk``'s ``ve_m_s``)."""
    base, axis = name.rsplit("_", 1)
    return f"{base}_v{axis}"
