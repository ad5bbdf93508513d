"""One pass over a STATES.mcap for the run report: envelopes per plot bin and whole-record sums.

Reads :class:`cdgps_cli.report.run_data.StatesBlocks` a block of epochs at a time and keeps, per
figure bin (:class:`cdgps_cli.report.envelope.EnvelopeBins`), the extremes of each coordinate and
section angle and of its ±1σ band, of NIS/dof and its χ² bounds, of NEES (with truth), the residual
RMS per channel, and the further arrays (satellites, PDOP of GNSS solutions); and over the whole
record the sums the summary table needs.  Memory: one block and the bins.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cdgps_cli.analysis.spectra import column_sums
from cdgps_cli.config.options import STATES_CHUNK_EPOCHS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.sim_truth import check_truth_config, read_truth_folder, truth_coordinates
from cdgps_cli.estimation.chi2 import chi2_quantile
from cdgps_cli.report.envelope import DEFAULT_BINS, EnvelopeBins

#: two-sided probability of the χ² intervals drawn and counted (95 %)
CHI2_LOWER, CHI2_UPPER = 0.025, 0.975
#: the residual map has this many times fewer time bins than a line plot (each cell an RMS over
#: enough epochs to be read as one; a cell per pixel column would be noise)
RESIDUAL_BIN_FACTOR = 5


@dataclass
class Sums:
    """Whole-record sums of some series: count, sum, sum of squares (finite values only)."""

    n: np.ndarray
    s: np.ndarray
    ss: np.ndarray

    @classmethod
    def zeros(cls, m: int) -> "Sums":
        return cls(np.zeros(m, dtype=np.int64), np.zeros(m), np.zeros(m))

    def add(self, x: np.ndarray) -> None:
        """Add the rows of x (k, m) in order (:func:`column_sums`: any chunking, the same bits)."""
        x = np.asarray(x, dtype=float).reshape(-1, len(self.n))  # (0, m) too: a chunk with no value
        ok = np.isfinite(x)
        v = np.where(ok, x, 0.0)
        self.n += ok.sum(axis=0)
        self.s = column_sums(v, self.s)
        self.ss = column_sums(v * v, self.ss)

    def mean(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.n > 0, self.s / np.maximum(self.n, 1), np.nan)

    def rms(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.n > 0, np.sqrt(self.ss / np.maximum(self.n, 1)), np.nan)

    def std(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            m = self.mean()
            return np.sqrt(np.maximum(self.ss / np.maximum(self.n, 1) - m * m, 0.0))


@dataclass
class Scan:
    """What :func:`scan_states` gathered (see the module docstring)."""

    n_epochs: int
    start_s: float = np.nan
    end_s: float = np.nan
    period_s: float = np.nan
    q: EnvelopeBins | None = None
    q_sums: Sums | None = None
    sigma_sums: Sums | None = None
    angles: EnvelopeBins | None = None
    angle_names: list = field(default_factory=list)
    angle_expr: list = field(default_factory=list)
    angle_sums: Sums | None = None
    angle_sigma_sums: Sums | None = None
    nis: EnvelopeBins | None = None
    nis_bounds: EnvelopeBins | None = None
    nis_stats: dict = field(default_factory=dict)
    nees: EnvelopeBins | None = None
    nees_stats: dict = field(default_factory=dict)
    error_sums: Sums | None = None
    resid: EnvelopeBins | None = None
    resid_sums: Sums | None = None
    extra: dict = field(default_factory=dict)


def read_truth(truth_dir: str | Path, states) -> dict:
    """The simulator's truth (``truth.csv`` with a column per coordinate, ``truth.json``) of
    ``states``' config: ``{"us": (M,) int64 µs, "q": (M, n_q)}``; CdgpsError naming the file on a
    missing column or another config (:mod:`cdgps_cli.io.sim_truth`)."""
    truth = read_truth_folder(truth_dir, "--truth")
    check_truth_config(truth, states.config_sha256, states.config_name, states.path)
    table = truth_coordinates(truth, states.coordinate_model(), list(states.coord_names))  # q1_m, or bare q1
    return {"us": np.rint(table["time_s"].to_numpy(dtype=float) * 1e6).astype(np.int64),
            "q": table[list(states.coord_names)].to_numpy(dtype=float), "dir": str(truth.folder)}


def _angle_rows(cfg) -> tuple[list, list, np.ndarray]:
    if cfg is None:
        return [], [], np.zeros((0, 0))
    from cdgps_cli.model.kinematics import section_angles  # noqa: PLC0415

    angles = section_angles(cfg)
    return [a[0] for a in angles], [a[1] for a in angles], np.array([a[2] for a in angles]).reshape(len(angles), -1)


def scan_states(states, truth: dict | None = None, n_bins: int = DEFAULT_BINS,
                chunk_epochs: int = STATES_CHUNK_EPOCHS) -> Scan:
    """One pass over ``states`` (a :class:`~cdgps_cli.report.run_data.StatesBlocks`), a block of
    ``chunk_epochs`` epochs at a time; ``truth`` from :func:`read_truth` adds NEES and errors."""
    N = states.n_epochs
    nq = len(states.coord_names)
    sc = Scan(N)
    sc.q, sc.q_sums, sc.sigma_sums = EnvelopeBins(N, nq, n_bins), Sums.zeros(nq), Sums.zeros(nq)
    names, exprs, A = _angle_rows(states.cfg)
    sc.angle_names, sc.angle_expr = names, exprs
    if names:
        AU = A @ np.asarray(states.output_map, dtype=float)
        sc.angles, sc.angle_sums, sc.angle_sigma_sums = EnvelopeBins(N, len(names), n_bins), \
            Sums.zeros(len(names)), Sums.zeros(len(names))
    sc.nis, sc.nis_bounds = EnvelopeBins(N, 1, n_bins), EnvelopeBins(N, 2, n_bins)
    nis = {"epochs": 0, "inside": 0, "sums": Sums.zeros(3)}          # NIS, dof, NIS/dof
    nc = len(states.channels)
    if nc:
        sc.resid, sc.resid_sums = EnvelopeBins(N, nc, max(n_bins // RESIDUAL_BIN_FACTOR, 1)), Sums.zeros(nc)
    if truth is not None:
        pinv = np.linalg.pinv(np.asarray(states.output_map, dtype=float))
        sc.nees, sc.error_sums = EnvelopeBins(N, 1, n_bins), Sums.zeros(nq)
        nees = {"epochs": 0, "inside": 0, "sums": Sums.zeros(1), "dof": states.n_pos}
        order = np.argsort(truth["us"], kind="stable")
        t_us = truth["us"][order]
    first_t = prev_t = None
    dts = []
    for b in states.blocks(chunk_epochs):
        a, t, q, sq = b["start"], b["time_s"], b["q"], b["sigma_q"]
        if first_t is None:
            first_t = float(t[0])
        dts.append(np.diff(t if prev_t is None else np.concatenate([[prev_t], t])))
        prev_t = float(t[-1])
        lo = None if sq is None else q - sq
        hi = None if sq is None else q + sq
        sc.q.add(a, t, q, lo, hi)
        sc.q_sums.add(q)
        if sq is not None:
            sc.sigma_sums.add(sq)
        if names:
            deg = np.degrees(q @ A.T)
            sc.angle_sums.add(deg)
            sd = None
            if b["P_xi"] is not None:
                var = np.einsum("ai,nij,aj->na", AU, b["P_xi"], AU)
                sd = np.degrees(np.sqrt(np.maximum(var, 0.0)))
                sc.angle_sigma_sums.add(sd)
            sc.angles.add(a, t, deg, None if sd is None else deg - sd, None if sd is None else deg + sd)
        _nis_block(sc, nis, a, t, b["nis"], b["nis_dof"])
        if nc and b["residual_m"] is not None:
            r_mm = 1e3 * b["residual_m"]
            sc.resid.add(a, t, r_mm * r_mm)          # per-bin mean square, mm²
            sc.resid_sums.add(r_mm)
        for name, v in b["extra"].items():
            v = np.asarray(v, dtype=float).reshape(len(t), -1)
            env = sc.extra.setdefault(name, EnvelopeBins(N, v.shape[1], n_bins))
            env.add(a, t, v)
        if truth is not None:
            _nees_block(sc, nees, a, t, q, b["xi"], b["P_xi"], t_us, truth["q"][order], pinv)
    sc.start_s, sc.end_s = first_t, prev_t
    d = np.concatenate(dts) if dts else np.zeros(0)
    sc.period_s = float(np.median(d)) if d.size else float("nan")
    sc.nis_stats = _nis_summary(nis)
    if truth is not None:
        if nees["epochs"] == 0:
            raise CdgpsError(f"--truth {truth['dir']}: no epoch in common with {states.path}")
        sc.nees_stats = _nees_summary(nees)
    return sc


def _nis_block(sc: Scan, acc: dict, a: int, t, nis, dof) -> None:
    if nis is None or dof is None:
        return
    nis = np.asarray(nis, dtype=float)
    ok = np.isfinite(nis) & (dof > 0)
    r = np.where(ok, nis / np.where(ok, dof, 1.0), np.nan)
    lo = np.where(ok, chi2_quantile(CHI2_LOWER, np.where(ok, dof, 1.0)) / np.where(ok, dof, 1.0), np.nan)
    hi = np.where(ok, chi2_quantile(CHI2_UPPER, np.where(ok, dof, 1.0)) / np.where(ok, dof, 1.0), np.nan)
    sc.nis.add(a, t, r[:, None])
    sc.nis_bounds.add(a, t, np.column_stack([lo, hi]))
    acc["epochs"] += int(ok.sum())
    acc["inside"] += int(np.sum(ok & (r >= lo) & (r <= hi)))
    acc["sums"].add(np.column_stack([nis[ok], dof[ok], r[ok]]))


def _nis_summary(acc: dict) -> dict:
    n = acc["epochs"]
    if n == 0:
        return {"epochs": 0}
    sum_nis, dof, sum_ratio = acc["sums"].s.tolist()
    return {"epochs": n, "mean_per_dof": sum_ratio / n, "pooled_per_dof": sum_nis / dof,
            "fraction_in_interval95": acc["inside"] / n,
            "pooled_interval95_if_independent": [float(chi2_quantile(CHI2_LOWER, dof) / dof),
                                                 float(chi2_quantile(CHI2_UPPER, dof) / dof)]}


def _nees_block(sc: Scan, acc: dict, a: int, t, q, xi, P_xi, t_us, q_truth, pinv) -> None:
    us = np.rint(np.asarray(t) * 1e6).astype(np.int64)
    k = np.searchsorted(t_us, us).clip(0, max(len(t_us) - 1, 0))
    hit = (t_us[k] == us) if len(t_us) else np.zeros(len(us), bool)
    qt = np.where(hit[:, None], q_truth[k], np.nan)
    sc.error_sums.add(q - qt)
    nees = np.full(len(us), np.nan)
    if P_xi is not None and hit.any():
        d = xi[hit] - qt[hit] @ pinv.T
        nees[hit] = np.einsum("ni,ni->n", d, np.linalg.solve(P_xi[hit], d[..., None])[..., 0])
    sc.nees.add(a, t, nees[:, None])
    ok = np.isfinite(nees)
    m = acc["dof"]
    lo, hi = chi2_quantile(CHI2_LOWER, m), chi2_quantile(CHI2_UPPER, m)
    acc["epochs"] += int(ok.sum())
    acc["inside"] += int(np.sum((nees[ok] >= lo) & (nees[ok] <= hi)))
    acc["sums"].add(nees[ok][:, None])


def _nees_summary(acc: dict) -> dict:
    m, n = acc["dof"], acc["epochs"]
    return {"epochs": n, "dof": m, "mean": float(acc["sums"].s[0]) / n if n else None,
            "interval95_single": [float(chi2_quantile(CHI2_LOWER, m)), float(chi2_quantile(CHI2_UPPER, m))],
            "fraction_in_interval95": acc["inside"] / n if n else None}


def scan_series(states, n_bins: int = DEFAULT_BINS, chunk_epochs: int = STATES_CHUNK_EPOCHS) -> Scan:
    """The coordinates (with ±σ) and further arrays of a series without diagnostics (e.g. a GNSS
    run's single-epoch solutions ``/cdgps/kinematic``), one block at a time."""
    N, nq = states.n_epochs, len(states.coord_names)
    sc = Scan(N)
    sc.q, sc.q_sums, sc.sigma_sums = EnvelopeBins(N, nq, n_bins), Sums.zeros(nq), Sums.zeros(nq)
    for b in states.blocks(chunk_epochs):
        a, t, q, sq = b["start"], b["time_s"], b["q"], b["sigma_q"]
        sc.q.add(a, t, q, None if sq is None else q - sq, None if sq is None else q + sq)
        sc.q_sums.add(q)
        if sq is not None:
            sc.sigma_sums.add(sq)
        for name, v in b["extra"].items():
            v = np.asarray(v, dtype=float).reshape(len(t), -1)
            sc.extra.setdefault(name, EnvelopeBins(N, v.shape[1], n_bins)).add(a, t, v)
        sc.start_s = float(t[0]) if a == 0 else sc.start_s
        sc.end_s = float(t[-1])
    return sc
