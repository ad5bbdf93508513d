"""Receiver antenna phase-centre models from an ANTEX file (IGS ``.atx``, format 1.4).

:func:`read_antex` reads the receiver antennas of the file (type calibrations: an empty serial field; satellite and
individual calibrations are passed over): per frequency (``G01``, ``G02``, ``E05``, …) the phase-centre offset
(north, east, up, mm) and the elevation-only variations (the ``NOAZI`` row, mm, on the file's zenith grid).
:func:`antenna_range_m` gives a receiver's range correction per observation — what the antenna adds to the
geometric range of its reference point:

    d = −PCO·u + PCV(z)

with u the unit line of sight (east, north, up), z the zenith angle; as RTKLIB's ``antmodel`` (offsets and the
azimuth-free variations; the azimuth-dependent rows are read past).

References
----------
IGS, "ANTEX: The Antenna Exchange Format, Version 1.4", 2012.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cdgps_cli.core.errors import CdgpsError

__all__ = ["AntennaModel", "read_antex", "antenna_key", "find_antenna", "antenna_range_m", "ANTEX_FREQUENCIES",
           "model_to_json", "model_from_json", "header_antenna_type"]

#: the ANTEX frequency codes of a signal, first the signal's own, then those RTKLIB-like fallbacks take (a file with
#: GPS calibrations alone serves the other systems' bands nearest in frequency)
ANTEX_FREQUENCIES = {
    "G:L1": ("G01",), "G:L2": ("G02",), "G:L5": ("G05", "G02"),
    "E:E1": ("E01", "G01"), "E:E5a": ("E05", "G05", "G02"), "E:E5b": ("E07", "G02"),
    "C:B1I": ("C02", "G01"), "C:B2I": ("C07", "G02"), "C:B2a": ("C05", "G05", "G02"),
    "R:G1": ("R01", "G01"), "R:G2": ("R02", "G02"),
}


@dataclass(frozen=True)
class AntennaModel:
    """One antenna type's calibration: ``offsets_neu_mm`` {frequency: (3,) north, east, up, mm}, ``variations_mm``
    {frequency: (n,) on ``zenith_deg`` (n,)}; ``name`` as the file writes it (type and radome), ``source`` the
    file."""

    name: str
    zenith_deg: np.ndarray
    offsets_neu_mm: dict
    variations_mm: dict
    source: str = ""                   # the file it was read from

    def frequency(self, signal_name: str) -> str | None:
        """The frequency of this model that serves ``signal_name`` (:data:`ANTEX_FREQUENCIES`), or None."""
        return next((f for f in ANTEX_FREQUENCIES.get(signal_name, ()) if f in self.offsets_neu_mm), None)


def header_antenna_type(header: dict) -> str | None:
    """A RINEX header's ``ANT # / TYPE`` as an antenna name, or None for a blank or a placeholder (``Unknown``,
    convbin's empty field, Spirent's ``ant_type``, gnss-sdr's ``Antenna type``): such a receiver names no antenna."""
    typ = " ".join(str(header.get("antenna_type") or "").split())
    if not typ or typ.lower() in _PLACEHOLDER_TYPES:
        return None
    return typ if typ.split()[0].lower() not in ("unknown", "ant_type", "none") else None


#: ``ANT # / TYPE`` texts that fill the field without naming an antenna (gnss-sdr writes the field's label)
_PLACEHOLDER_TYPES = ("antenna type",)


def antenna_key(text: str) -> tuple[str, str]:
    """(type, radome) of an antenna name as RINEX (``ANT # / TYPE`` columns 21–40) and ANTEX write it — the type in
    its first 16 characters, the radome in the last four — or as a person types it (``LEIAR25.R4 LEIT``): IGS type
    names hold no space (at most 15 characters), so the first word is the type and the second the radome (none:
    ``NONE``)."""
    words = str(text).upper().split()
    return (words[0] if words else ""), (words[1] if len(words) > 1 else "NONE")


def _floats(line: str, path, lineno: int, what: str, n: int | None = None) -> list:
    try:
        vals = [float(v) for v in line.split()]
    except ValueError:
        raise CdgpsError(f"{path}: line {lineno}: {what}: expected numbers, got {line.strip()!r}") from None
    if n is not None and len(vals) < n:
        raise CdgpsError(f"{path}: line {lineno}: {what}: expected {n} numbers, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise CdgpsError(f"{path}: line {lineno}: {what}: expected finite numbers, got {line.strip()!r}")
    return vals


class _Entry:
    """The antenna being read: its name, zenith grid and per-frequency calibration."""

    def __init__(self, name: str, receiver: bool):
        self.name, self.receiver = name, receiver
        self.zen = None
        self.freq = None
        self.off, self.var = {}, {}

    def model(self, path, lineno: int) -> AntennaModel:
        if self.zen is None:
            raise CdgpsError(f"{path}: line {lineno}: antenna {self.name.strip()!r} has no ZEN1 / ZEN2 / DZEN")
        grid = np.arange(self.zen[0], self.zen[1] + 0.5 * self.zen[2], self.zen[2])
        for f, v in self.var.items():
            if v.size != grid.size:
                raise CdgpsError(f"{path}: antenna {self.name.strip()!r} {f}: its NOAZI row has {v.size} values, "
                                 f"its zenith grid {self.zen[0]:g}–{self.zen[1]:g}° by {self.zen[2]:g}° has {grid.size}")
        missing = sorted(set(self.off) - set(self.var))
        if missing:
            raise CdgpsError(f"{path}: antenna {self.name.strip()!r}: no NOAZI row for {', '.join(missing)}")
        return AntennaModel(self.name, grid, dict(self.off), dict(self.var), str(path))


def read_antex(path: str | Path) -> dict:
    """The receiver antenna models of an ANTEX file, keyed by :func:`antenna_key`.

    Parameters
    ----------
    path : str or Path
        ANTEX 1.3/1.4 file.

    Returns
    -------
    dict
        {(type, radome): :class:`AntennaModel`}: type calibrations only (an empty serial field); the first of a
        type written twice.

    Raises
    ------
    CdgpsError
        An unreadable file, no ``ANTEX VERSION / SYST`` header, a malformed or non-finite line (its number named),
        an antenna without its zenith grid or its variations, a file that ends inside its header or an antenna
        (truncated), a file with no receiver antenna.
    """
    p = Path(path)
    try:
        lines = p.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror or exc}") from None
    if not lines or "ANTEX VERSION / SYST" not in lines[0][60:]:
        raise CdgpsError(f"{p}: not an ANTEX file (its first line is not 'ANTEX VERSION / SYST')")
    out, cur, started = {}, None, 0
    for i, line in enumerate(lines, start=1):
        label = line[60:].strip()
        if label == "START OF ANTENNA":
            cur, started = _Entry("", False), i
        elif cur is None:
            continue
        elif label == "TYPE / SERIAL NO":
            cur.name, cur.receiver = line[:20], not line[20:40].strip()
        elif label == "ZEN1 / ZEN2 / DZEN":
            z = _floats(line[:60], p, i, label, 3)
            if not (z[2] > 0 and z[1] >= z[0]):
                raise CdgpsError(f"{p}: line {i}: {label}: expected ZEN1 <= ZEN2 and DZEN > 0, got {z[:3]}")
            cur.zen = z[:3]
        elif label == "START OF FREQUENCY":
            cur.freq = line[3:6].strip()
        elif label == "END OF FREQUENCY":
            cur.freq = None
        elif label == "NORTH / EAST / UP" and cur.freq:
            cur.off[cur.freq] = np.array(_floats(line[:60], p, i, label, 3)[:3])
        elif line[3:8] == "NOAZI" and cur.freq:
            cur.var[cur.freq] = np.array(_floats(line[8:], p, i, "NOAZI"))
        elif label == "END OF ANTENNA":
            if cur.receiver:
                out.setdefault(antenna_key(cur.name), cur.model(p, i))
            cur = None
    if not any(ln[60:].strip() == "END OF HEADER" for ln in lines):
        raise CdgpsError(f"{p}: no END OF HEADER: the file ends inside its header (truncated?)")
    if not out and cur is None:
        raise CdgpsError(f"{p}: holds no receiver antenna type calibration (an ANTEX file of satellites, or cut short)")
    if cur is not None:
        raise CdgpsError(f"{p}: line {started}: antenna {' '.join(cur.name.split()) or '?'} has no END OF ANTENNA: the "
                         f"file ends inside it (truncated?)")
    return out


def find_antenna(models: dict, name: str) -> tuple[AntennaModel | None, str | None]:
    """The model of antenna ``name`` (RINEX's type and radome) and a note when it is not the exact one: its type
    with radome ``NONE`` when the file has not that radome (as RTKLIB falls back to the bare type); (None, None)
    when the file has neither."""
    typ, radome = antenna_key(name)
    got = models.get((typ, radome))
    if got is not None:
        return got, None
    got = models.get((typ, "NONE"))
    if got is not None:
        return got, f"antenna {typ} {radome}: the file has no calibration with radome {radome}; {typ} NONE is used"
    return None, None


def antenna_range_m(model: AntennaModel, signals, az_rad, el_rad) -> np.ndarray:
    """Range correction of each observation (m): −PCO·u + PCV(90° − el) at the frequency serving its signal.

    Parameters
    ----------
    model : AntennaModel
    signals : array_like of str (n,)
        Signal names (``G:L1`` …) of the observations.
    az_rad, el_rad : array_like (n,)
        Azimuth and elevation of each satellite at the antenna, rad.

    Returns
    -------
    ndarray (n,)
        m; CdgpsError naming a signal the model cannot serve.
    """
    sig = np.asarray(signals, dtype=object)
    az, el = np.asarray(az_rad, float), np.asarray(el_rad, float)
    u = np.column_stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])
    out = np.zeros(sig.size)
    zen = 90.0 - np.degrees(el)
    for name in np.unique(sig):
        f = model.frequency(str(name))
        if f is None:
            raise CdgpsError(f"{model.source or 'the ANTEX file'}: antenna {' '.join(model.name.split())} has no "
                             f"calibration for {name} (it has {', '.join(sorted(model.offsets_neu_mm))})")
        k = sig == name
        n_, e_, up = model.offsets_neu_mm[f]
        pco = np.array([e_, n_, up]) * 1e-3
        pcv = np.interp(zen[k], model.zenith_deg, model.variations_mm[f]) * 1e-3
        out[k] = -(u[k] @ pco) + pcv
    return out


def model_to_json(model: AntennaModel) -> dict:
    """``model`` as JSON values (a RUN keeps the calibrations it was ingested with: :func:`model_from_json`); its
    source file by name only (no machine's path: the same inputs give the same RUN from any directory)."""
    return {"name": model.name, "source": Path(str(model.source)).name, "zenith_deg": [float(z) for z in model.zenith_deg],
            "offsets_neu_mm": {f: [float(x) for x in v] for f, v in model.offsets_neu_mm.items()},
            "variations_mm": {f: [float(x) for x in v] for f, v in model.variations_mm.items()}}


def model_from_json(d, where: str) -> AntennaModel:
    """The :class:`AntennaModel` of :func:`model_to_json`'s dict; CdgpsError naming ``where`` when it is not one (a
    key missing, a number not finite, a grid and variations of different sizes)."""
    try:
        zen = np.asarray(d["zenith_deg"], dtype=float)
        off = {str(f): np.asarray(v, dtype=float) for f, v in d["offsets_neu_mm"].items()}
        var = {str(f): np.asarray(v, dtype=float) for f, v in d["variations_mm"].items()}
        name, source = str(d["name"]), str(d.get("source", ""))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CdgpsError(f"{where}: not an antenna calibration ({type(exc).__name__}: {exc})") from None
    bad = [f for f in off if off[f].shape != (3,) or f not in var or var[f].shape != zen.shape]
    if bad or zen.ndim != 1 or zen.size < 2 or not all(np.isfinite(a).all() for a in (zen, *off.values(), *var.values())):
        raise CdgpsError(f"{where}: not an antenna calibration (frequencies {', '.join(bad) or 'all'}: expected a "
                         f"finite north/east/up offset and one variation per zenith angle)")
    return AntennaModel(name, zen, off, var, source)
