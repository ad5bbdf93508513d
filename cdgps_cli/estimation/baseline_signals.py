"""Multi-GNSS, multi-frequency single differences for the static baseline (``[gnss] signals``).

The anchor rows of each receiver — GPS L1, or the first signal listed when ``G:L1`` is not among
them (:func:`cdgps_cli.core.signals.anchor_signal`: a Galileo-only run is anchored on E1) — fix its
epochs on the grid of GPS times and its clock (:func:`cdgps_cli.estimation.baseline._receiver_rows`); every row of the receiver's signal table
(:func:`~cdgps_cli.io.rinex_signals.read_rinex_signals`) recorded at one of those epochs is then
placed in it, at the true reception instant tag − clock.  Rover and master rows of one epoch,
satellite and signal form a single difference (SD)::

    λ_g·SD_φ = SD(ρ − c·dt_sat + T) + c·Δdt_rx + b_g + λ_g·a_seg + ε
    SD_P     = SD(ρ − c·dt_sat + T) + c·Δdt_rx + b'_g + e

with λ_g the signal's wavelength, b_g the receivers' inter-system / inter-frequency bias
difference of group g (a constant per epoch and group, removed with the clock by the DDs of the
group) and one ambiguity per satellite-signal lock segment.  A group is one constellation and one
frequency slot (``G:L1``, ``E:E5a`` …); its rows are named ``G05:L1`` (:func:`group_key`), so every
segment, reference and residual carries its signal.  Rows are sorted by epoch, group, satellite,
and an (epoch, group) block with a single row forms no DD and is dropped.  No ionosphere term:
the DD ionosphere is neglected (short baselines; the same default as ``cdgps rtk`` below its
10 km threshold; the caller refuses longer baselines).  GLONASS (FDMA) rows carry their
satellite's own wavelength (frequency number from the RINEX header, the navigation records or the
UBX freqId); the solver keeps their segments float (λ_g·a_seg then differs per satellite, so the DD
of two segments is a float bias in metres, not an integer of one wavelength).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.signals import SIGNALS
from cdgps_cli.measurement.dd_signals import group_key
from cdgps_cli.measurement.differencing import epoch_pointers
from cdgps_cli.measurement.epoch_pairing import nearest_tags, rows_for_pairs
from cdgps_cli.model.gps.epoch_align import carry_slips
from cdgps_cli.model.gps.positioning import ephemeris_coverage, reception_geometry

__all__ = ["signal_sd_fields"]

_TAG_MATCH_S = 1e-6


def _rows_at_epochs(sig: pd.DataFrame, tag: np.ndarray, clk: np.ndarray, what: str) -> pd.DataFrame:
    """The signal rows recorded at the receiver's differenced epochs, with ``ep`` and ``t_true``.

    ``tag`` (n_ep,) is the receiver's time tag of each common epoch (GPS s; NaN: none); a signal row belongs
    to the epoch whose tag equals its own (within 1 µs), whichever systems have an ephemeris there (an epoch
    whose GPS satellites have none yet is kept for the others: a real F9P pair lost its first 40 epochs so).
    Slip flags of rows that are not used move to the next used row of that satellite and signal."""
    te = np.flatnonzero(np.isfinite(tag))
    tags = pd.DataFrame({"time_gps_s": tag[te], "ep": te})
    tt = np.unique(tag[te])
    t = sig["time_gps_s"].to_numpy(dtype=np.float64)
    if tt.size == 0:
        raise CdgpsError(f"{what}: no epoch with observations of the anchor signal (GPS L1, or the first of [gnss] "
                         f"signals without G:L1) in common with the other receiver")
    i, at = nearest_tags(tt, t, _TAG_MATCH_S)
    ok = at & np.isfinite(sig["phase_cycles"].to_numpy(dtype=np.float64))
    key = (sig["sat"].astype(str) + ":" + sig["signal"].astype(str)).to_numpy()
    lli = carry_slips(t, key, sig["lli"].to_numpy(dtype=np.int64), ok)
    # a base epoch serving several rover epochs gives its rows to each, its slip flags to the first
    rows = np.flatnonzero(ok)
    take, pair, first = rows_for_pairs(i[rows], np.searchsorted(tt, tags["time_gps_s"].to_numpy()))
    out = sig.iloc[rows[take]].copy()
    out["lli"] = np.where(first, lli[rows[take]], lli[rows[take]] & ~1)
    out["ep"] = te[pair]
    out["t_true"] = out["time_gps_s"].to_numpy() - clk[out["ep"].to_numpy()]
    return out


def _geometry(j: pd.DataFrame, nav, t_label, xyz, suffix: str, troposphere: bool) -> dict:
    return reception_geometry(nav, j["sat"].to_numpy(), t_label[j["ep"].to_numpy()], j["t_true" + suffix].to_numpy(),
                              xyz, troposphere=troposphere)


def _covered(j: pd.DataFrame, nav, t_label, warnings: list) -> pd.DataFrame:
    cov = ephemeris_coverage(nav, j["sat"].to_numpy(), t_label[j["ep"].to_numpy()])
    dropped = j.loc[~cov, "sat"].value_counts()
    if len(dropped):
        warnings.append(f"signals: {int(dropped.sum())} single differences of {', '.join(sorted(dropped.index))} have no "
                        f"healthy broadcast ephemeris covering them and are not used")
    if not cov.any():
        raise CdgpsError("signals: no single difference is covered by the navigation data (satellites without a healthy "
                         f"ephemeris: {' '.join(sorted(dropped.index))})")
    return j[cov]


def _group_info(order: list, grp: np.ndarray, sats: np.ndarray, lam: np.ndarray) -> dict:
    """Per signal: its SD rows, satellites and wavelength (m)."""
    out = {}
    for k, g in enumerate(order):
        m = grp == k
        out[g] = {"sd_rows": int(m.sum()), "satellites": int(np.unique(sats[m]).size),
                  "wavelength_m": float(lam[m][0]) if m.any() else None}
        if g.startswith("R:"):               # FDMA: a wavelength per satellite
            u, i = np.unique(sats[m], return_index=True)
            out[g].update(wavelength_m=None, wavelength_m_by_satellite={str(a): float(b) for a, b in zip(u, lam[m][i])})
    return out


def signal_sd_fields(master_sig: pd.DataFrame, rover_sig: pd.DataFrame, tag_m: np.ndarray, tag_r: np.ndarray,
                     clk_m: np.ndarray, clk_r: np.ndarray, t_label: np.ndarray, nav: pd.DataFrame, xm, xr,
                     *, mask_rad: float, troposphere: bool, names: tuple, warnings: list) -> dict:
    """The signal groups' SD rows as the fields of the baseline solver's data table.

    Parameters
    ----------
    master_sig, rover_sig : DataFrame
        The receivers' signal tables (``time_gps_s``, ``sat``, ``signal``, ``phase_cycles``,
        ``pseudorange_m``, ``lli``, ``wavelength_m``).
    tag_m, tag_r : ndarray (n_ep,)
        Their time tags of the common epochs, GPS s (NaN: the receiver has no epoch there).
    clk_m, clk_r : ndarray (n_ep,)
        Receiver clocks per common epoch, s.
    t_label : ndarray (n_ep,)
        Common epoch times, GPS s.
    nav : DataFrame
        Broadcast ephemerides of every system of the signals.
    xm, xr : array_like (3,)
        Master position and rover a priori position, ECEF m.
    mask_rad : float
        Elevation mask at both receivers, rad.
    troposphere : bool
        Apply the a priori hydrostatic troposphere.
    names : tuple of str
        (master name, rover name) for messages.
    warnings : list
        Warnings are appended.

    Returns
    -------
    dict
        ``ptr``, ``epoch``, ``sat``, ``sat_names`` (``G05:L1`` …), ``y_phase_m``, ``y_code_m``,
        ``base_model_m``, ``rover_sat_xyz``, ``rover_clk_trop_m``, ``el_rover``, ``el_base``,
        ``az_rover``, ``slip``, ``half``, ``slip_rover``, ``slip_base`` (per row), ``group`` (per row),
        ``group_names``, ``lam_m`` (per row, m), and ``info`` (rows, satellites per signal).
    """
    b = _rows_at_epochs(master_sig, tag_m, clk_m, names[0])
    r = _rows_at_epochs(rover_sig, tag_r, clk_r, names[1])
    cols = ["ep", "sat", "signal", "phase_cycles", "pseudorange_m", "lli", "wavelength_m", "t_true"]
    j = pd.merge(r[cols], b[cols], on=["ep", "sat", "signal"], suffixes=("_r", "_b"), how="inner")
    if len(j) == 0:
        raise CdgpsError(f"signals: {names[0]} and {names[1]} share no satellite-signal observation in a common epoch")
    j = _covered(j, nav, t_label, warnings)
    gb = _geometry(j, nav, t_label, xm, "_b", troposphere)
    gr = _geometry(j, nav, t_label, xr, "_r", troposphere)
    present = set(j["signal"].unique())          # once (the comprehension re-built the set per entry of SIGNALS)
    order = [s for s in SIGNALS if s in present]
    grp = pd.Categorical(j["signal"], categories=order).codes.astype(np.int64)
    keep = (gb["el_rad"] >= mask_rad) & (gr["el_rad"] >= mask_rad)
    ep = j["ep"].to_numpy()
    block = ep * len(order) + grp
    cnt = np.bincount(block[keep], minlength=int(block.max()) + 1)
    keep &= cnt[block] >= 2                       # a block with one row forms no DD
    if not keep.any():
        raise CdgpsError(f"signals: no double differences above the {np.degrees(mask_rad):g}° mask")
    keys = np.array([group_key(s, g) for s, g in zip(j["sat"].to_numpy(), j["signal"].to_numpy())], dtype=object)
    sel = np.flatnonzero(keep)
    sel = sel[np.lexsort((keys[sel].astype(str), grp[sel], ep[sel]))]
    sat_names = sorted(set(keys[sel].tolist()))
    sat_idx = {s: i for i, s in enumerate(sat_names)}
    lli_r, lli_b = j["lli_r"].to_numpy()[sel], j["lli_b"].to_numpy()[sel]
    lam = j["wavelength_m_r"].to_numpy(dtype=np.float64)[sel]
    ph = j["phase_cycles_r"].to_numpy()[sel] - j["phase_cycles_b"].to_numpy()[sel]
    c = SPEED_OF_LIGHT_M_S
    info = {"signals": _group_info(order, grp[sel], j["sat"].to_numpy()[sel], lam), "n_epochs_used": int(np.unique(ep[sel]).size)}
    return {
        "ptr": epoch_pointers(ep[sel], t_label.size), "epoch": ep[sel], "sat_names": sat_names,
        "sat": np.array([sat_idx[s] for s in keys[sel]], dtype=np.int64),
        "y_phase_m": lam * ph,
        "y_code_m": j["pseudorange_m_r"].to_numpy()[sel] - j["pseudorange_m_b"].to_numpy()[sel],
        "base_model_m": (gb["range_m"] - c * gb["sat_clock_s"] + gb["trop_m"])[sel],
        "rover_sat_xyz": gr["sat_xyz_m"][sel], "rover_clk_trop_m": (-c * gr["sat_clock_s"] + gr["trop_m"])[sel],
        "el_rover": gr["el_rad"][sel], "el_base": gb["el_rad"][sel], "az_rover": gr["az_rad"][sel],
        "slip": ((lli_r & 1) | (lli_b & 1)).astype(bool), "half": ((lli_r & 2) | (lli_b & 2)).astype(bool),
        "slip_rover": (lli_r & 1).astype(bool), "slip_base": (lli_b & 1).astype(bool),
        "group": grp[sel], "group_names": tuple(order), "lam_m": lam, "info": info,
    }
