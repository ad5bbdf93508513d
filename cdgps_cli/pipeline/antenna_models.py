"""Receiver antenna models (ANTEX) in every GNSS command: which calibration serves each receiver, and the
observations of its antenna reference point.

A receiver measures ranges to its antenna's phase centre, which lies centimetres from the antenna reference point
(ARP) that positions, heights and RINEX headers refer to, by an offset (PCO) and an elevation-dependent variation
(PCV) that differ between antenna types and frequencies.  Between two antennas of one type they cancel on a short
baseline; between two types they do not: the rover's position is then its phase centre placed from the base's,
off by the difference of the offsets (centimetres, mostly in height).

The one correction is :func:`~cdgps_cli.io.antex.antenna_range_m` (−PCO·u + PCV at each signal's frequency, u the
unit vector to the satellite); this module applies it to each table the commands solve with:

* :func:`with_antenna_model` — a geometry table (``cdgps rtk``: satellite positions already there);
* :func:`signals_with_antenna_model`, :func:`obs_with_antenna_model` — a receiver's multi-signal table or its GPS L1
  table (``cdgps baseline``, and ``init`` / ``estimate`` on a RUN, through :func:`station_with_antenna_model` and
  :func:`receiver_with_antenna_model`), the satellites placed from the broadcast ephemerides at the time tags.

:func:`antenna_models` chooses each receiver's calibration (named by an option, or by its RINEX header's
``ANT # / TYPE``; ``none``: no model) and refuses, naming the receiver and the option, an antenna the file lacks.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import GPS_L1_WAVELENGTH_M
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.antex import antenna_key, antenna_range_m, find_antenna, header_antenna_type, read_antex
from cdgps_cli.model.gps.orbits import azimuth_elevation, ephemeris_rows, sat_position_rows
from cdgps_cli.model.gps.positioning import ephemeris_coverage

__all__ = ["antenna_models", "named_antennas_known", "mixed_antennas_note", "with_antenna_model", "signals_with_antenna_model",
           "obs_with_antenna_model", "station_with_antenna_model", "receiver_with_antenna_model"]


def antenna_models(antex, named: dict, headers: dict, paths: dict, warnings: list, option: dict,
                   antex_option: str = "--antex", models: dict | None = None) -> dict:
    """{receiver: :class:`~cdgps_cli.io.antex.AntennaModel` or None} of the ANTEX file ``antex``.

    Parameters
    ----------
    antex : str or Path or None
        The ANTEX file; None: no models (then a receiver named anything but ``none`` in ``named`` is refused, and a
        warning says when the headers name antennas of different types).
    named : dict
        {receiver: antenna type given by the user, or None (its header's ``ANT # / TYPE``); ``"none"``: no model}.
    headers, paths : dict
        {receiver: RINEX header dict}, {receiver: file name for messages}.
    warnings : list
        Gets a note for each antenna served by another radome's calibration (``NONE``), and the mixed-types note.
    option : dict
        {receiver: the option or key that names its antenna, for messages (``--rover-antenna``)}.
    antex_option : str
        The option or key that gives the ANTEX file, for messages.
    models : dict, optional
        The file's :func:`~cdgps_cli.io.antex.read_antex` when already read (None: read here).

    Raises
    ------
    CdgpsError
        An antenna named without a file; a receiver whose antenna no option or header names; an antenna the file has
        no calibration of; the file's own errors (:func:`~cdgps_cli.io.antex.read_antex`).
    """
    if antex is None:
        for who, name in named.items():
            if name is not None and str(name).strip().lower() != "none":
                raise CdgpsError(f"{option[who]} {name!r}: no {antex_option} file to take its calibration from")
        warnings += mixed_antennas_note(headers, paths, antex_option)
        return dict.fromkeys(named)
    for who, name in named.items():
        _two_words(name, option[who])
    models = read_antex(antex) if models is None else models
    out = {}
    for who in named:
        name = named[who] or header_antenna_type(headers[who]) or ""
        if name.strip().lower() == "none":
            out[who] = None
            continue
        if not name.strip():
            raise CdgpsError(f"{paths[who]} ({who}): the file names no antenna (a RINEX header's ANT # / TYPE; a u-blox "
                             f"log has none); give {_with_type(option[who])} (or none) for {antex_option} {antex}")
        model, note = find_antenna(models, name)
        if model is None:
            raise CdgpsError(f"{antex}: no calibration of {paths[who]}'s ({who}) antenna {' '.join(name.split())!r}; "
                             f"give {option[who]} with a type the file has, or none")
        if note:
            warnings.append(f"{paths[who]} ({who}): {note}")
        out[who] = model
    return out


def named_antennas_known(antex, named: dict, option: dict) -> dict:
    """The ANTEX file's models (:func:`~cdgps_cli.io.antex.read_antex`), once every antenna ``named`` {receiver: type or
    None} by an option is checked to be in it (CdgpsError as :func:`antenna_models` words it): what can be known of the
    file before the observations (and their headers) are read."""
    for who, name in named.items():
        _two_words(name, option[who])
    models = read_antex(antex)
    for who, name in named.items():
        if name is not None and name.strip().lower() != "none" and find_antenna(models, name)[0] is None:
            raise CdgpsError(f"{antex}: no calibration of {who}'s antenna {' '.join(name.split())!r}; give {option[who]} "
                             f"with a type the file has, or none")
    return models


def _with_type(option: str) -> str:
    """An option as a user types it with an antenna: ``--rover-antenna TYPE``; one that shows its form already
    (``--antenna rover=TYPE``) as it is."""
    return option if "TYPE" in option else f"{option} TYPE"


def _two_words(name, option: str) -> None:
    """CdgpsError for an antenna named by more than a type and a radome (IGS types hold no space): a third word was
    dropped unsaid, and another antenna's calibration could be taken."""
    if name is not None and len(str(name).split()) > 2:
        raise CdgpsError(f"{option} {name!r}: expected an antenna type and at most its radome (\"TRM59800.80 SCIT\"), "
                         f"got {len(str(name).split())} words")


def mixed_antennas_note(headers: dict, paths: dict, antex_option: str = "--antex") -> list:
    """A warning when the headers name antennas of different types (:func:`~cdgps_cli.io.antex.antenna_key`) and no
    ANTEX file is given: the positions are then each rover's phase centre placed from the base's, whose offsets
    differ by centimetres between types (on the real 164 km DELF → EIJS pair, 66 mm in height, and a wrong fix).
    ``headers`` and ``paths`` in receiver order, the first the base (master); ``antex_option`` names the option
    or key that would give the file."""
    names = {who: header_antenna_type(h) or "" for who, h in headers.items()}
    if not all(names.values()) or len({antenna_key(n) for n in names.values()}) < 2:
        return []
    listed = "; ".join(f"{paths[w]} ({w}): {' '.join(n.split())}" for w, n in names.items())
    return [f"the antennas differ ({listed}) and no {antex_option} file is given: their phase-centre offsets, centimetres "
            f"apart between types, are in the rover's position (its height most), and on a long baseline they can "
            f"give wrong integers"]


def _corrected(table: pd.DataFrame, d_m: np.ndarray, wavelength_m, phase: str, code: str) -> pd.DataFrame:
    """``table`` with d (m) taken out of column ``code`` and d/λ (cycles) out of column ``phase``; attrs kept."""
    out = table.assign(**{phase: table[phase].to_numpy(dtype=float) - d_m / wavelength_m,
                          code: table[code].to_numpy(dtype=float) - d_m})
    out.attrs = dict(table.attrs)
    return out


def with_antenna_model(g: pd.DataFrame, antenna, xyz) -> pd.DataFrame:
    """A receiver's geometry table (:func:`~cdgps_cli.estimation.rtk_multi.receiver_geometry`) with its antenna's
    range correction d (:func:`~cdgps_cli.io.antex.antenna_range_m`, at each satellite's azimuth and elevation from
    ``xyz``) taken out of every phase (d / λ cycles) and pseudorange (d m): the observations of the antenna reference
    point, which the positions are.  The attrs are kept."""
    az, el = azimuth_elevation(np.asarray(xyz, float), g[["sx", "sy", "sz"]].to_numpy(dtype=float))
    d = antenna_range_m(antenna, g["signal"].to_numpy(), az, el)
    return _corrected(g, d, g["wavelength_m"].to_numpy(dtype=float), "phase_cycles", "pseudorange_m")


def _range_at_tags(model, nav: pd.DataFrame, xyz, time_s, sats, signals) -> np.ndarray:
    """(N,) the correction d (m) of each row, the satellite placed from its broadcast ephemeris at the row's time
    tag (the 70 ms of travel move it by 0.001°: nothing at the scale of a calibration); 0 where no healthy
    ephemeris covers the row (the solvers drop those rows)."""
    t = np.asarray(time_s, dtype=np.float64)
    sats = np.asarray(sats, dtype=object)
    d = np.zeros(t.size)
    if not t.size:
        return d
    # each (time, satellite) once: a receiver's signals share its satellites' directions
    names, code = np.unique(sats.astype(str), return_inverse=True)
    pair, first, back = np.unique(np.column_stack([t.view(np.int64), code.astype(np.int64)]), axis=0,
                                  return_index=True, return_inverse=True)
    back = back.ravel()
    tu, su = t[first], sats[first]
    ok = ephemeris_coverage(nav, su, tu)
    if ok.any():
        xyz_sat, _ = sat_position_rows(ephemeris_rows(nav, su[ok], tu[ok]), tu[ok])
        az_u, el_u = np.zeros(tu.size), np.zeros(tu.size)
        az_u[ok], el_u[ok] = azimuth_elevation(np.asarray(xyz, float), xyz_sat)
        rows = ok[back]
        sig = np.asarray(signals, dtype=object)[rows] if np.ndim(signals) else np.full(int(rows.sum()), signals, dtype=object)
        d[rows] = antenna_range_m(model, sig, az_u[back][rows], el_u[back][rows])
    return d


def signals_with_antenna_model(sig: pd.DataFrame | None, nav: pd.DataFrame, xyz, model) -> pd.DataFrame | None:
    """A multi-signal table (``time_gps_s``, ``sat``, ``signal``, ``phase_cycles``, ``pseudorange_m``,
    ``wavelength_m``) with ``model``'s correction taken out (:func:`with_antenna_model`'s, the satellites placed at
    the time tags); None and a None model: unchanged."""
    if sig is None or model is None or not len(sig):
        return sig
    d = _range_at_tags(model, nav, xyz, sig["time_gps_s"], sig["sat"].astype(str).to_numpy(dtype=object),
                       sig["signal"].astype(str).to_numpy(dtype=object))
    return _corrected(sig, d, sig["wavelength_m"].to_numpy(dtype=float), "phase_cycles", "pseudorange_m")


def obs_with_antenna_model(obs: pd.DataFrame, nav: pd.DataFrame, xyz, model, *, phase: str = "phase_l1_cycles",
                           code: str = "pseudorange_l1_m") -> pd.DataFrame:
    """A receiver's GPS L1 table (:data:`~cdgps_cli.core.records.OBS_COLUMNS`, or the RUN's raw table with
    ``phase``/``code`` named) with ``model``'s L1 correction taken out of its GPS rows (the table's other systems'
    rows, which no GPS L1 solution uses, unchanged); a None model: unchanged."""
    if model is None or not len(obs):
        return obs
    sats = obs["sat"].astype(str).to_numpy(dtype=object)
    gps = np.char.startswith(sats.astype(str), "G")
    d = np.zeros(sats.size)
    d[gps] = _range_at_tags(model, nav, xyz, obs["time_gps_s"].to_numpy(dtype=np.float64)[gps], sats[gps], "G:L1")
    return _corrected(obs, d, GPS_L1_WAVELENGTH_M, phase, code)


def station_with_antenna_model(st, nav: pd.DataFrame, xyz, model):
    """A :class:`~cdgps_cli.estimation.baseline.Station` with ``model`` taken out of its GPS L1 table and its
    signals (None: the station itself)."""
    if model is None:
        return st
    return st._replace(obs=obs_with_antenna_model(st.obs, nav, xyz, model),
                       signals=signals_with_antenna_model(st.signals, nav, xyz, model))


def receiver_with_antenna_model(rx, nav: pd.DataFrame, xyz, model, *, raw: bool = True):
    """A RUN's :class:`~cdgps_cli.io.gnss_run.GnssReceiver` with ``model`` taken out of its signals and, with
    ``raw``, its raw (GPS L1) table (None: the receiver itself)."""
    if model is None:
        return rx
    return replace(rx, raw=obs_with_antenna_model(rx.raw, nav, xyz, model, phase="phase_cycles", code="pseudorange_m")
                   if raw else rx.raw, signals=signals_with_antenna_model(rx.signals, nav, xyz, model))
