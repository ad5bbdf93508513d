"""Multi-GNSS, multi-frequency double differences on a rover-position state (the engine's DD model).

For one epoch and one signal group g (a constellation and a frequency slot, e.g. ``E:E5a``) with
satellites s = 1…m common to base and rover and reference r (highest elevation at the base), the
rows are

    ∇Δ(λφ)_s = ∇Δρ_s(x) + λ_s N_s − λ_r N_r − ∇Δ(μ I)_s + ∇Δ(m Z)_s + ε,   ∇ΔP_s = ∇Δρ_s(x) + ∇Δ(μ I)_s + ∇Δ(m Z)_s + e

with x the rover ECEF offset from its linearization origin (m), N the single-difference
ambiguities of the group (cycles), I optional single-difference slant ionosphere at L1 (m,
μ = (f_L1/f)²) and Z optional zenith wet delays of the two receivers (m; each SD's term m_r Z_r − m_b Z_b, m the
Niell wet mapping factor at each receiver's elevation of the satellite).  λ and μ are per satellite: equal within a CDMA group (so the ambiguity term is
λ_g (N_s − N_r)), different for GLONASS (FDMA, f = f₀ + k Δf), whose DD ambiguity λ_s N_s − λ_r N_r
is not an integer times one wavelength — those groups are kept float.  Receiver clocks cancel in the DD; inter-system and inter-frequency biases
cancel because every group has its own reference satellite (no inter-system DD is formed).  The
noise is D Σ Dᵀ per group, Σ the SD variances (a² + b²/sin²el, doubled for the two receivers).
:func:`epoch_rows` gives (z − h(x), H, L) for a linearization point, :func:`dd_range` the model.

The modal path (:mod:`cdgps_cli.pipeline.gnss_modal`) takes the same groups over a whole run:
:func:`signal_sd_table` gives one group's single differences of a base and a rover (epochs, satellites,
lock segments, the SD phase residual at the nominal positions); its DDs, each group against its own
reference satellite with D Σ Dᵀ, are formed by :class:`cdgps_cli.measurement.model.SatelliteDDModal`
with the group as one slot (satellites named ``G05:L2``, so that only rows of one signal correlate
through the common master).

The rtk path (:mod:`cdgps_cli.estimation.rtk_multi`) pairs the run's base and rover rows once
(:func:`paired_sd_rows`, on the epochs of :func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`),
cuts each epoch into its signal groups (:func:`epoch_groups`) and hands them to the engine's
measurement model :class:`DDGroupModel`, whose :class:`GroupRows` keep the single differences and
weight them as their double differences (the information of :func:`epoch_rows`' Cholesky-whitened
DD rows, without forming D or factoring D Σ Dᵀ).  The static engine's model, :class:`RunDDModel`, is
DDGroupModel over fixed ambiguity columns with the rows laid out block of epochs by block (the same numbers).
"""

from __future__ import annotations

import numpy as np

from types import SimpleNamespace

import pandas as pd

from cdgps_cli.core.gps_time import nominal_interval_s
from cdgps_cli.core.signals import signal
from cdgps_cli.measurement.differencing import ambiguity_segments, dd_covariance, dd_operator, epoch_pointers, sd_variance
from cdgps_cli.measurement.base_interpolation import base_rows, interpolate_base
from cdgps_cli.measurement.epoch_pairing import age_variance_m2, carry_base_slips, channel_index
from cdgps_cli.measurement.noise import correlated_variance_factor
from cdgps_cli.model.gps.orbits import azimuth_elevation

__all__ = ["dd_range", "epoch_rows", "signal_sd_table", "group_key", "DDGroupModel", "GroupRows", "RunDDModel",
           "whitening_matrix", "paired_sd_rows", "epoch_groups", "backward_slips", "channel_index"]


def group_key(sat: str, signal_name: str) -> str:
    """Name of a satellite within a signal group: ``G05:L2`` (satellite, frequency slot)."""
    return f"{sat}:{signal_name.split(':', 1)[1]}"


def _on_grid(df: pd.DataFrame, step_s: float, tol_s: float) -> pd.DataFrame:
    """Rows whose time tag is within ``tol_s`` of a grid time k·step, with ``key`` = k."""
    t = df["time_gps_s"].to_numpy()
    key = np.rint(t / step_s).astype(np.int64)
    ok = np.abs(t - key * step_s) <= tol_s
    return df[ok].assign(key=key[ok])


def signal_sd_table(base: pd.DataFrame, rover: pd.DataFrame, base_xyz_m, rover_xyz_m, *, mask_rad: float,
                    max_gap_s: float | None, troposphere: bool = True, interval_s: float | None = None,
                    sync_tol_s: float = 0.025, segment_starts=None) -> SimpleNamespace:
    """Single differences (rover − base) of one signal group over a run.

    Parameters
    ----------
    base, rover : DataFrame
        One signal's rows with the satellite geometry of each receiver
        (:func:`cdgps_cli.estimation.rtk_multi.receiver_geometry`: ``time_gps_s``, ``sat``, ``signal``,
        ``phase_cycles``, ``lli``, ``wavelength_m``, ``sx/sy/sz`` (m, ECEF at reception), ``el_rad``, ``trop_m``,
        and ``pseudorange_m`` when present).
    base_xyz_m, rover_xyz_m : array_like (3,)
        Nominal positions, ECEF m.
    mask_rad : float
        Elevation mask at both receivers, rad.
    max_gap_s : float
        A longer gap in a satellite's rows starts a new ambiguity (as an LLI slip flag does).
    interval_s : float, optional
        Epoch grid step, s (default: the base's median spacing).
    sync_tol_s : float
        Each receiver's time tags are put on the grid of GPS times k·interval when within this of
        one (others dropped); epochs pair on grid times, labelled by them.  The geometry stays at each
        receiver's own reception instant (the "geometry" epoch alignment of the GPS L1 path).
    segment_starts : iterable of (str, float), optional
        (satellite as in ``sat``, e.g. "G05"; time s) where a segment also starts, at the epoch within half a
        step of that time: a solution's segments (INIT's, cut where it found slips no receiver flagged).

    Returns
    -------
    SimpleNamespace
        ``t_label`` (n_ep,), per row (epoch then satellite order): ``epoch``, ``sat`` (index into
        ``sat_names``, :func:`group_key` names), ``rover_sat_xyz`` (N, 3), ``el_rover``, ``el_base`` (rad),
        ``slip`` (bool), ``seg`` (ambiguity segment), ``r_raw_m`` (λ·SD phase − SD of the ranges and
        troposphere at the nominal positions, m: receiver clocks, λ·(N_r − N_b) and the motion remain),
        ``r_code_m`` (the same for the SD pseudorange, m; NaN without a ``pseudorange_m`` column);
        ``ptr`` (n_ep + 1,), ``lam_m`` (the group's wavelength), ``signal``.
    """
    cols = ["time_gps_s", "sat", "phase_cycles", "lli", "wavelength_m", "sx", "sy", "sz", "el_rad", "trop_m"]
    cols += [c for c in ("pseudorange_m",) if c in base.columns and c in rover.columns]
    step = nominal_interval_s(base["time_gps_s"]) if interval_s is None else float(interval_s)
    b, r = (_on_grid(df[cols], step, sync_tol_s) for df in (base, rover))
    m = b.drop(columns="time_gps_s").merge(r.drop(columns="time_gps_s"), on=["key", "sat"], suffixes=("_b", "_r"))
    m = m[(m["el_rad_b"] >= mask_rad) & (m["el_rad_r"] >= mask_rad)].sort_values(["key", "sat"], kind="stable")
    keys, epoch = np.unique(m["key"].to_numpy(), return_inverse=True)
    t_label = keys * step
    names, sat = np.unique(m["sat"].to_numpy().astype(str), return_inverse=True)
    slip = ((m["lli_b"].to_numpy() | m["lli_r"].to_numpy()) & 1) > 0
    if segment_starts is not None:
        slip |= _rows_at_starts(segment_starts, names, sat, epoch, t_label, step)
    seg, _ = ambiguity_segments(epoch, sat, slip, epoch_time_s=t_label, max_gap_s=max_gap_s)
    xs_r, xs_b = m[["sx_r", "sy_r", "sz_r"]].to_numpy(), m[["sx_b", "sy_b", "sz_b"]].to_numpy()
    lam = m["wavelength_m_r"].to_numpy()
    trop = (m["trop_m_r"].to_numpy() - m["trop_m_b"].to_numpy()) if troposphere else 0.0
    model = np.linalg.norm(xs_r - np.asarray(rover_xyz_m, float), axis=1) - np.linalg.norm(xs_b - np.asarray(base_xyz_m, float), axis=1)
    r_raw = lam * (m["phase_cycles_r"].to_numpy() - m["phase_cycles_b"].to_numpy()) - model - trop
    r_code = (m["pseudorange_m_r"].to_numpy() - m["pseudorange_m_b"].to_numpy() - model - trop) if "pseudorange_m" in cols \
        else np.full(r_raw.size, np.nan)
    sig = str(base["signal"].iloc[0]) if len(base) else ""
    return SimpleNamespace(t_label=t_label, epoch=epoch.astype(np.int64), ptr=epoch_pointers(epoch, t_label.size),
                           sat=sat.astype(np.int64), sat_names=[group_key(n, sig) for n in names], rover_sat_xyz=xs_r,
                           el_rover=m["el_rad_r"].to_numpy(), el_base=m["el_rad_b"].to_numpy(), slip=slip,
                           seg=np.asarray(seg, dtype=np.int64), r_raw_m=r_raw, r_code_m=r_code, lam_m=float(lam[0]) if lam.size else np.nan,
                           signal=sig)


def dd_range(rover_xyz_m, base_xyz_m, sat_xyz_m, ref: int, sat_base_xyz_m=None) -> np.ndarray:
    """∇Δρ (m, shape (m−1,)) of satellites ``sat_xyz_m`` (m, 3; as seen by the rover) against
    satellite ``ref``; ``sat_base_xyz_m`` the positions for the base's own transmission times
    (default: the same)."""
    sb = sat_xyz_m if sat_base_xyz_m is None else sat_base_xyz_m
    sd = np.linalg.norm(sat_xyz_m - rover_xyz_m, axis=1) - np.linalg.norm(sb - base_xyz_m, axis=1)
    return dd_operator(len(sd), ref) @ sd


def epoch_rows(x, groups, base_xyz_m, origin_xyz_m, n_state: int, noise_chol=None):
    """Residuals, Jacobian and noise factor of one epoch's DDs at state ``x``.

    Parameters
    ----------
    x : ndarray (n_state,)
        State: [rover offset (3, m), ambiguities (cycles), ionosphere (m)…].
    groups : list of dict
        One per signal group: ``sat_xyz`` (m, 3) for the rover's transmission times, ``sat_base_xyz``
        (m, 3) for the base's, ``ref`` (int), ``lam_m`` (m,) or scalar, ``mu`` (m,) or scalar,
        ``phase_sd_m`` (m,), ``code_sd_m`` (m,), ``var_phase`` / ``var_code`` (m,) m²,
        ``amb_col`` (m,) state columns of N, ``iono_col`` (m,) columns of I or −1; optionally ``wet_col`` (2,)
        the columns of the base's and the rover's zenith wet delays (m) with ``mw_b`` / ``mw_r`` (m,) their
        wet mapping factors.
    base_xyz_m, origin_xyz_m : ndarray (3,)
        Base position and the origin of the rover offset, ECEF m.
    n_state : int
    noise_chol : ndarray (p, p), optional
        ``L`` of an earlier call on the same ``groups`` (the noise does not depend on ``x``): returned
        as is instead of being formed again (iterated updates relinearize only r and H).

    Returns
    -------
    r : ndarray (p,)   z − h(x), m
    H : ndarray (p, n_state)
    L : ndarray (p, p)   lower Cholesky factor of the block-diagonal noise covariance
    """
    rover = origin_xyz_m + x[:3]
    rs, Hs, Cs = [], [], []
    for g in groups:
        m, ref = len(g["phase_sd_m"]), g["ref"]
        D = dd_operator(m, ref)
        los = g["sat_xyz"] - rover
        e = los / np.linalg.norm(los, axis=1)[:, None]
        geo = dd_range(rover, base_xyz_m, g["sat_xyz"], ref, g.get("sat_base_xyz"))
        Hg = np.zeros((m - 1, n_state))
        Hg[:, :3] = -(D @ e)
        Hc = Hg.copy()
        amb = g["amb_col"]
        lam = np.broadcast_to(np.asarray(g["lam_m"], dtype=float), (m,))
        mu = np.broadcast_to(np.asarray(g["mu"], dtype=float), (m,))
        Hg[:, amb] += D * lam
        n_amb = x[amb]
        iono = g["iono_col"]
        ion = np.zeros(m)
        if np.all(iono >= 0):
            ion = x[iono]
            Hg[:, iono] -= D * mu
            Hc[:, iono] += D * mu
        wet = g.get("wet_col")
        if wet is not None:                     # zenith wet delays [base, rover]: SD m_r Z_r − m_b Z_b, not dispersive
            geo = geo + D @ (g["mw_r"] * x[wet[1]] - g["mw_b"] * x[wet[0]])
            for Hk in (Hg, Hc):
                Hk[:, wet[1]] += D @ g["mw_r"]
                Hk[:, wet[0]] -= D @ g["mw_b"]
        rs.append(D @ g["phase_sd_m"] - (geo + D @ (lam * n_amb) - D @ (mu * ion)))
        rs.append(D @ g["code_sd_m"] - (geo + D @ (mu * ion)))
        Hs += [Hg, Hc]
        if noise_chol is None:
            Cs += [dd_covariance(g["var_phase"], ref), dd_covariance(g["var_code"], ref)]
    if noise_chol is not None:
        return np.concatenate(rs), np.vstack(Hs), noise_chol
    p = sum(c.shape[0] for c in Cs)
    C = np.zeros((p, p))
    k = 0
    for c in Cs:
        C[k:k + len(c), k:k + len(c)] = c
        k += len(c)
    return np.concatenate(rs), np.vstack(Hs), np.linalg.cholesky(C)


def whitening_matrix(u, inv_sigma, block) -> np.ndarray:
    """B (p, p) = (I − blockdiag(u uᵀ)) Σ^{-1/2} of :class:`GroupRows`, from ``u`` (p,) (each block's
    Σ^{-1/2} 1 / ‖Σ^{-1/2} 1‖), ``inv_sigma`` (p,) = Σ^{-1/2} and ``block`` (p,) each row's block.

    Entry by entry what ``−(Uᵀ U) + I`` then ``· inv_sigma`` gives (U (blocks, p) holding each block's u in
    its row): within a block −u_i u_j (Uᵀ U sums one product and zeros), +1 on the diagonal; across blocks
    −0.0 (the negated zero sum); so every bit is that product's."""
    B = np.multiply.outer(u, u)
    B[block[:, None] != block[None, :]] = 0.0
    np.negative(B, out=B)
    B.flat[::B.shape[0] + 1] += 1.0
    B *= inv_sigma
    return B


class GroupRows:
    """One epoch's single differences of signal groups, weighted as their double differences.

    ``z_m`` (2M,) holds the groups' SD phases (M rows, group after group), then their SD ranges;
    each group's phase block and code block is one block of ``starts``.  A block's DDs ``D z`` with
    noise ``D Σ Dᵀ`` (Σ = diag(var), SD variances) carry the information of the SDs weighted by
    ``W = Σ⁻¹ − Σ⁻¹ 1 1ᵀ Σ⁻¹ / (1ᵀ Σ⁻¹ 1)`` whatever the reference (``D 1 = 0``): :meth:`whiten`
    applies ``B = (I − u uᵀ) Σ^{-1/2}``, ``u = Σ^{-1/2} 1 / ‖Σ^{-1/2} 1‖``, with ``Bᵀ B = W`` (one
    row per SD, rank m − 1 per block), so the engine's update needs no DD operator and no
    Cholesky factor of the DD noise.  ``context`` holds what :meth:`DDGroupModel.predict` needs.
    The NIS the driver computes on these rows has 2M − (number of blocks) degrees of freedom, one
    fewer per block than ``z_m.size`` (the driver's ``nis_dof``); rtk does not use it.
    """

    def __init__(self, z_m, var_m2, sizes, context):
        inv_sigma = 1.0 / np.sqrt(var_m2)
        block = np.repeat(np.arange(sizes.size), sizes)
        norm2 = np.add.reduceat(inv_sigma * inv_sigma, np.cumsum(sizes) - sizes)
        self.z_m = z_m
        self.B = whitening_matrix(inv_sigma / np.sqrt(norm2[block]), inv_sigma, block)
        self.context = context

    @classmethod
    def from_parts(cls, z_m, B, context) -> "GroupRows":
        """Rows whose whitening ``B`` (:func:`whitening_matrix`) is already formed."""
        self = cls.__new__(cls)
        self.z_m, self.B, self.context = z_m, B, context
        return self

    def whiten(self, v):
        """B v for v (2M,) or (2M, p)."""
        return self.B @ v


#: the shortest range from a receiver on the ground to a navigation satellite, m (GLONASS orbits at 19,100 km, GPS
#: at 20,200 km, Galileo 23,200 km; BeiDou MEO 21,500 km, its GEO/IGSO 35,800 km)
MIN_SATELLITE_RANGE_M = 1.9e7


class DDGroupModel:
    """The engine's measurement model of the multi-GNSS double differences (module docstring).

    ``groups_of(k)`` gives epoch k's signal groups (dicts as for :func:`epoch_rows`, their
    ``amb_col`` / ``iono_col`` set by the time :meth:`rows` runs: the driver's ``prepared`` hooks
    open the state columns).  The state is [rover offset from ``origin_xyz_m`` (3, m), SD
    ambiguities (cycles), SD slant ionosphere at L1 (m)…]; its size is read from the drive's
    context at :meth:`prepare`.  Groups with ``wet_col`` (the state columns of the base's and the rover's zenith
    wet delays, m) and rows with ``mw_b`` / ``mw_r`` (their wet mapping factors) add ``m_r Z_r − m_b Z_b`` to every
    SD, phase and code alike (the troposphere is not dispersive).  Groups that carry ``epoch_rows`` (:func:`epoch_groups`, when an
    epoch's groups are adjacent rows of the run) give their row columns as that one view instead of
    being concatenated (the same values).  ``remember_last``: :meth:`predict` gives its last result of the same
    rows again for the same state (bit for bit) instead of forming it (a caller that predicts twice at one state).
    """

    def __init__(self, groups_of, base_xyz_m, origin_xyz_m, linearization_tol_m: float | None = None,
                 remember_last: bool = False):
        self.groups_of = groups_of
        self.base_xyz = np.asarray(base_xyz_m, dtype=float)
        self.origin = np.asarray(origin_xyz_m, dtype=float)
        self.groups, self._ctx = [], None
        self.linearization_tol_m = linearization_tol_m
        self.remember_last = remember_last

    def linear_within(self, dx) -> bool:
        """Whether a Gauss–Newton step ``dx`` (state, the rover offset first) leaves every DD's linearization good
        to ``linearization_tol_m`` (None: never said): a range's second-order term is at most |δ|²/(2ρ), a DD's
        two rover ranges' at most |δ|²/ρ_min with ρ_min :data:`MIN_SATELLITE_RANGE_M` — so relinearizing at
        the new state would move it by no more than that (:func:`~cdgps_cli.estimation.kalman.iterated_update`
        then stops)."""
        if self.linearization_tol_m is None:
            return False
        d = np.asarray(dx[:3], dtype=float)
        return float(d @ d) <= self.linearization_tol_m * MIN_SATELLITE_RANGE_M

    def prepare(self, k: int, ctx) -> None:
        """Epoch k's groups (the hooks that follow open their state columns)."""
        self.groups, self._ctx = self.groups_of(k), ctx

    def rows(self, k: int):
        """:class:`GroupRows` of epoch k, or None without a group."""
        groups = self.groups
        if not groups:
            return None
        n_sats = [len(g["sats"]) for g in groups]
        sizes = np.array(n_sats)
        whole = groups[0].get("epoch_rows") if len(groups) > 1 else groups[0]

        def cat(key):
            if whole is not None and key in whole:        # the groups' rows are one view already (epoch_groups)
                return whole[key]
            return np.concatenate([g[key] for g in groups])

        M, n = sum(n_sats), len(self._ctx.x)
        amb, ion, lam, mu = cat("amb_col"), cat("iono_col"), cat("lam_m"), cat("mu")
        H = np.zeros((2 * M, n))
        r = np.arange(M)
        H[r, amb] = lam
        has_iono = bool((ion >= 0).all())
        if has_iono:
            H[r, ion] = -mu
            H[M + r, ion] = mu
        wet = groups[0].get("wet_col")
        if wet is not None:                   # zenith wet delays [base, rover]: SD = m_r·Z_r − m_b·Z_b, phase and code
            wet = (wet, cat("mw_b"), cat("mw_r"))
            H[r, wet[0][0]] = H[M + r, wet[0][0]] = -wet[1]
            H[r, wet[0][1]] = H[M + r, wet[0][1]] = wet[2]
        sx = cat("sat_xyz")
        los_b = cat("sat_base_xyz") - self.base_xyz
        ctx = {"sat_xyz": sx, "base_rng": np.sqrt(np.einsum("ij,ij->i", los_b, los_b)),
               "lam": lam, "mu": mu, "amb": amb, "ion": ion if has_iono else None, "wet": wet, "H": H, "M": M}
        return GroupRows(np.concatenate([cat("phase_sd_m"), cat("code_sd_m")]),
                         np.concatenate([cat("var_phase"), cat("var_code")]), np.concatenate([sizes, sizes]), ctx)

    def predict(self, x, rows):
        """h(x) (2M,) m and H (2M, n) of :meth:`rows`' SDs (the rows' H template, position columns set).

        With ``remember_last``, the last ``h`` of these rows is kept with the state's bytes and given again for the
        same state: the H template still holds that state's position columns (only this method writes them, its
        callers read H)."""
        c = rows.context
        if self.remember_last:
            key = x.tobytes()
            last = c.get("last_predict")
            if last is not None and last[0] == key:
                return last[1], c["H"]
            h, H = self._predict(x, c)
            c["last_predict"] = (key, h)
            return h, H
        return self._predict(x, c)

    def _predict(self, x, c):
        los = c["sat_xyz"] - (self.origin + x[:3])
        rng = np.sqrt(np.einsum("ij,ij->i", los, los))
        H, M = c["H"], c["M"]
        H[:M, :3] = H[M:, :3] = -los / rng[:, None]
        geo = rng - c["base_rng"]
        wet = c.get("wet")
        if wet is not None:
            geo = geo + (wet[2] * x[wet[0][1]] - wet[1] * x[wet[0][0]])
        iono_m = c["mu"] * x[c["ion"]] if c["ion"] is not None else 0.0
        return np.concatenate([geo + c["lam"] * x[c["amb"]] - iono_m, geo + iono_m]), H


class _RunBlock(SimpleNamespace):
    """:class:`RunDDModel`'s layout of epochs ``k0`` … ``k1 − 1`` (see there)."""


class RunDDModel(DDGroupModel):
    """:class:`DDGroupModel` over a whole run's SD rows (:func:`paired_sd_rows`, with its ``groups`` layout)
    with fixed ambiguity columns ``cols`` (N,) and no ionosphere state: the static engine's model.

    The rows of every epoch's groups (:func:`epoch_groups`: each epoch's groups one after the other) are laid
    out for a block of ``block_epochs`` epochs at once, with whole-block numpy: their columns gathered,
    each epoch's SD phases then SD ranges side by side (``z``), their Σ^{-1/2} and whitening weights ``u``
    (:class:`GroupRows`).  An epoch's :meth:`rows` then takes views and forms only its H template, its base
    ranges and B (:func:`whitening_matrix`), every number the one DDGroupModel forms from
    ``static_engine._groups`` (the same elementwise operations on the same values, the same sums)."""

    def __init__(self, rows, cols, base_xyz_m, origin_xyz_m, *, block_epochs: int = 4096):
        super().__init__(None, base_xyz_m, origin_xyz_m)
        self.run, self.cols = rows, np.asarray(cols, dtype=np.int64)
        self.block_epochs = max(int(block_epochs), 1)
        self._lay = None

    def prepare(self, k: int, ctx) -> None:
        """Only the drive's context (the epoch's layout is made by :meth:`rows`)."""
        self._ctx = ctx

    def _block(self, k: int) -> _RunBlock:
        lay = self._lay
        if lay is None or not lay.k0 <= k < lay.k1:
            lay = self._lay = self._layout(k, min(k + self.block_epochs, self.run["ptr"].size - 1))
        return lay

    def _layout(self, k0: int, k1: int) -> _RunBlock:
        run, g = self.run, self.run["groups"]
        j0, j1 = int(g["ptr"][k0]), int(g["ptr"][k1])
        size = (g["stop"][j0:j1] - g["start"][j0:j1]).astype(np.int64)
        first = np.cumsum(size) - size                          # each group's first compacted row
        n = int(size.sum())
        idx = np.arange(n) - np.repeat(first - g["start"][j0:j1], size)      # run rows, group after group
        cptr = np.r_[first, n][g["ptr"][k0:k1 + 1] - j0]        # each epoch's compacted rows
        m_ep = np.diff(cptr)
        shift = np.repeat(cptr[:-1], m_ep)                      # phase of row i at i + cptr[e], code M_e later
        at_p, at_c = np.arange(n) + shift, np.arange(n) + shift + np.repeat(m_ep, m_ep)
        gid = np.repeat(np.arange(size.size), size)
        z, inv, u, blk = np.empty(2 * n), np.empty(2 * n), np.empty(2 * n), np.empty(2 * n, dtype=np.int64)
        for key, at, b in (("phase", at_p, 2 * gid), ("code", at_c, 2 * gid + 1)):
            z[at] = run[f"{key}_sd_m"][idx]
            inv_sigma = 1.0 / np.sqrt(run[f"var_{key}"][idx])
            norm2 = np.add.reduceat(inv_sigma * inv_sigma, first) if n else np.zeros(0)
            inv[at], u[at], blk[at] = inv_sigma, inv_sigma / np.sqrt(norm2[gid]), b
        # an epoch whose rows are adjacent in the run takes its satellite positions as views of the run's
        # (N, 3) arrays, as epoch_groups gives them, the others as np.concatenate of its groups' views (their
        # memory order, e.g. pandas' column-major, decides how einsum sums ‖los‖²): the same arrays
        run_ep = idx[np.minimum(cptr[:-1], max(n - 1, 0))] if n else np.zeros(k1 - k0, dtype=np.int64)
        step = np.r_[False, idx[1:] - idx[:-1] != 1] if n else np.zeros(0, dtype=bool)
        jumps = np.r_[0, np.cumsum(step)] if n else np.zeros(1, dtype=np.int64)
        view = (jumps[cptr[1:]] - jumps[np.minimum(cptr[:-1] + 1, n)] == 0) if n else np.zeros(k1 - k0, dtype=bool)
        return _RunBlock(k0=k0, k1=k1, cptr=cptr, z=z, inv=inv, u=u, blk=blk, amb=self.cols[idx],
                         lam=run["lam_m"][idx], mu=run["mu"][idx], run_ep=run_ep, view=view,
                         gptr=g["ptr"][k0:k1 + 1] - j0, start=g["start"][j0:j1], stop=g["stop"][j0:j1])

    def predict(self, x, rows):
        """:meth:`DDGroupModel.predict` without an ionosphere state: h = [ρ_r − ρ_b + λ N, ρ_r − ρ_b] (the
        same values: its ``− 0.0`` and ``+ 0.0`` of a zero ionosphere change no bit, ρ_r − ρ_b never being −0.0)."""
        c = rows.context
        los = c["sat_xyz"] - (self.origin + x[:3])
        rng = np.sqrt(np.einsum("ij,ij->i", los, los))
        H, M = c["H"], c["M"]
        H[:M, :3] = H[M:, :3] = -los / rng[:, None]
        h = np.empty(2 * M)
        geo = np.subtract(rng, c["base_rng"], out=h[M:])
        np.add(geo, c["lam"] * x[c["amb"]], out=h[:M])
        return h, H

    def _positions(self, lay: _RunBlock, e: int, M: int):
        """Satellite positions (rover's, base's) of the block's epoch ``e`` (M rows), as DDGroupModel.rows takes them."""
        sx, sb = self.run["sat_xyz"], self.run["sat_base_xyz"]
        if lay.view[e]:
            r0 = int(lay.run_ep[e])
            return sx[r0:r0 + M], sb[r0:r0 + M]
        spans = [(int(a), int(b)) for a, b in zip(lay.start[lay.gptr[e]:lay.gptr[e + 1]], lay.stop[lay.gptr[e]:lay.gptr[e + 1]])]
        return np.concatenate([sx[a:b] for a, b in spans]), np.concatenate([sb[a:b] for a, b in spans])

    def rows(self, k: int):
        """:class:`GroupRows` of epoch k (views of its block's layout), or None without a group; its whitening B,
        base ranges and H template are formed on first use (:class:`_RunRows`: the engine's compiled update
        reads the terms they are made of, :meth:`range_terms`)."""
        lay = self._block(k)
        a, b = int(lay.cptr[k - lay.k0]), int(lay.cptr[k - lay.k0 + 1])
        if a == b:
            return None
        M = b - a
        sx, sb = self._positions(lay, k - lay.k0, M)
        ctx = _RunContext(sat_xyz=sx, lam=lay.lam[a:b], mu=lay.mu[a:b], amb=lay.amb[a:b], ion=None, M=M,
                          _sb=sb, _base=self.base_xyz, _n=len(self._ctx.x))
        zs = slice(2 * a, 2 * b)
        return _RunRows(lay.z[zs], lay.u[zs], lay.inv[zs], lay.blk[zs], ctx)

    def range_terms(self, rows):
        """What :meth:`predict` and the rows' whitening are made of: (sat_xyz (M, 3), the base's satellite positions
        (M, 3), the base position (3,), λ (M,), ambiguity columns (M,), origin (3,), and B's u, Σ^{-1/2} and blocks
        (2M,) of :func:`whitening_matrix`); the engine's compiled update forms h, H, B and the base ranges from
        them as :meth:`rows` and :meth:`predict` do (:func:`cdgps_cli.estimation.kalman.iterated_update_covariance`)."""
        c = rows.context
        return (c["sat_xyz"], c["_sb"], c["_base"], c["lam"], c["amb"], self.origin, rows.u, rows.inv, rows.blk)


class _RunContext(dict):
    """:meth:`RunDDModel.rows`' context: ``base_rng`` (M,) (‖base's satellite − base‖) and the ``H`` template
    (2M, n) (λ at each row's ambiguity column) made on first use, as DDGroupModel.rows makes them."""

    def __missing__(self, key):
        if key == "base_rng":
            los_b = self["_sb"] - self["_base"]
            value = np.sqrt(np.einsum("ij,ij->i", los_b, los_b))
        elif key == "H":
            M = self["M"]
            value = np.zeros((2 * M, self["_n"]))
            value[np.arange(M), self["amb"]] = self["lam"]
        else:
            raise KeyError(key)
        self[key] = value
        return value


class _RunRows(GroupRows):
    """:class:`GroupRows` whose whitening ``B`` (:func:`whitening_matrix` of ``u``, ``inv``, ``blk``) is formed on
    first use."""

    def __init__(self, z_m, u, inv, blk, context):
        self.z_m, self.u, self.inv, self.blk, self.context = z_m, u, inv, blk, context
        self._B = None

    @property
    def B(self) -> np.ndarray:
        if self._B is None:
            self._B = whitening_matrix(self.u, self.inv, self.blk)
        return self._B


# ----------------------------------------------------------------------------------------------
# the run's SD rows, paired once, and each epoch's signal groups (the rows of DDGroupModel)
# ----------------------------------------------------------------------------------------------

_LAMBDA_L1 = signal("G:L1").wavelength_m

_PAIR_COLS = ["time_gps_s", "sat", "signal", "phase_cycles", "pseudorange_m", "lli", "sx", "sy", "sz", "sat_clock_m",
              "trop_m"]


def paired_sd_rows(base, rover, pairs, opt, *, mask_rover: bool = False, base_xyz_m=None) -> dict:
    """Base and rover rows of the whole run paired on (epoch pair, satellite, signal), once, as numpy columns.

    ``pairs`` (:func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`) gives each used rover epoch
    its base epoch; a base epoch may serve several rover epochs (a base with gaps or a lower rate),
    its slip flags only the first of them.  Rows above the mask (base elevation; with ``mask_rover`` the
    rover's too, as the batch baseline solver's, so that a rising satellite's first rows agree), ordered by epoch,
    then signal name, then the base's row order; ``ptr`` (n_ep + 1,) bounds each epoch, ``code``
    (N,) the signal's index in ``names``.  Per row: ``sats``, ``lam_m``, ``mu``, ``el`` (rad),
    ``sat_xyz`` / ``sat_base_xyz`` (N, 3, m), ``phase_sd_m`` / ``code_sd_m`` (m, rover − base, each
    receiver's satellite clock and, when asked, troposphere removed), ``slip``, ``var_phase`` /
    ``var_code`` (m², the base age's share included); ``interpolated_epochs``: how many rover epochs took the
    base interpolated (in at least one signal group); with ``mask_rover`` and ``opt["rover_elevation"]`` true,
    ``el_rover`` (N,) the rover's elevation of each row too and ``el_base_wet`` (N,) the base's at the instant its
    observation stands for (rad; for the wet troposphere's mapping: :func:`_base_elevation_of_rows`).

    With ``base_xyz_m`` (the base position, ECEF m), a bridged rover epoch that has base epochs on both sides within
    the maximum age takes the base's observations interpolated to its time
    (:func:`~cdgps_cli.measurement.base_interpolation.interpolate_base`) instead of
    the nearest base epoch's alone.
    """
    tb = np.unique(base["time_gps_s"].to_numpy())
    tr = np.unique(rover["time_gps_s"].to_numpy())
    n_ep = pairs.rover_time_s.size
    pair_of_rover = np.full(tr.size, -1, dtype=np.int64)
    pair_of_rover[pairs.rover_index] = np.arange(n_ep)
    first_use = np.r_[True, pairs.base_index[1:] != pairs.base_index[:-1]] if n_ep else np.zeros(0, bool)
    b = base_rows(base, tb, np.bincount(pairs.base_index, minlength=tb.size))
    rep = np.searchsorted(tr, rover["time_gps_s"].to_numpy())
    ep_r = pair_of_rover[rep]
    # the rover's slip flags of epochs that are not used move to the channel's next used epoch
    lli_r = carry_base_slips(rep, channel_index(rover["sat"].to_numpy(), rover["signal"].to_numpy()),
                             rover["lli"].to_numpy(dtype=np.int64), (pair_of_rover >= 0).astype(np.int64))
    r = rover[_PAIR_COLS + [c for c in ("eph_row",) if c in rover.columns]].assign(_row_r=np.arange(len(rover)),
                                                                                    _ep=ep_r, lli=lli_r)
    if mask_rover:
        r = r.assign(_el_r=rover["el_rad"].to_numpy())
    r = r[ep_r >= 0]
    r = r.assign(_bep=pairs.base_index[r["_ep"].to_numpy()])
    m = b.merge(r, on=["_bep", "sat", "signal"], suffixes=("_b", "_r"))
    del r                                       # (the rover's copy, as large as the base's: not held to the end)
    above = m["el_rad"].to_numpy() >= np.radians(opt["mask_deg"])
    if "eph_row_b" in m.columns and "eph_row_r" in m.columns:
        # one single difference, one ephemeris: a bridged base epoch on the other side of a change of broadcast
        # ephemeris than its rover epoch would put the jump between the two (up to decimetres) into the row
        above &= m["eph_row_b"].to_numpy() == m["eph_row_r"].to_numpy()
    if mask_rover:
        above &= m["_el_r"].to_numpy() >= np.radians(opt["mask_deg"])
    keep_el_r = mask_rover and bool(opt.get("rover_elevation"))
    m = _kept_sorted(m, above, ["_ep", "signal", "_row_b", "_row_r"],
                     drop=tuple(c for c in _UNUSED_AFTER_SORT if not (keep_el_r and c == "_el_r")))
    m, age, n_interpolated, interpolated = _base_at_rover_times(m, b, tb, pairs, opt, base_xyz_m)
    del b                                       # (the base's copy: its rows are in ``m`` now)
    names, code = _sorted_codes(m["signal"].to_numpy())
    epoch = m["_ep"].to_numpy()
    lam = m["wavelength_m"].to_numpy(dtype=float)
    el = m["el_rad"].to_numpy(dtype=float)
    var = sd_variance(el, el, sigma_a_m=opt["sigma_a_m"], sigma_b_m=opt["sigma_b_m"], weighting=opt["weighting"])
    var_age = age_variance_m2(age, opt["sync_tol_s"], opt["age_sigma_m_per_s"])
    dtrop = m["trop_m_r"].to_numpy() - m["trop_m_b"].to_numpy() if opt["troposphere"] else 0.0
    dclk = m["sat_clock_m_r"].to_numpy() - m["sat_clock_m_b"].to_numpy()
    slip_b = ((m["lli_b"].to_numpy() & 1) > 0) & first_use[epoch]
    half = ((m["lli_r"].to_numpy() | m["lli_b"].to_numpy()) & 2) > 0
    code = code.reshape(-1)
    extra = ({"el_rover": m["_el_r"].to_numpy(dtype=float),
              "el_base_wet": _base_elevation_of_rows(m, interpolated, base_xyz_m)} if keep_el_r else {})
    return {**extra,
        "groups": _group_layout(epoch, code, el, half, n_ep),
        "ptr": np.searchsorted(epoch, np.arange(n_ep + 1)), "names": names, "code": code,
        "interpolated_epochs": n_interpolated,
        "sats": m["sat"].to_numpy(), "lam_m": lam, "el": el,
        "mu": (lam / _LAMBDA_L1) ** 2,        # (f_L1 / f)², per satellite (GLONASS FDMA)
        "sat_xyz": m[["sx_r", "sy_r", "sz_r"]].to_numpy(), "sat_base_xyz": m[["sx_b", "sy_b", "sz_b"]].to_numpy(),
        "phase_sd_m": lam * (m["phase_cycles_r"].to_numpy() - m["phase_cycles_b"].to_numpy()) + dclk - dtrop,
        "code_sd_m": m["pseudorange_m_r"].to_numpy() - m["pseudorange_m_b"].to_numpy() + dclk - dtrop,
        "slip": ((m["lli_r"].to_numpy() & 1) > 0) | slip_b,
        # LLI bit 1: half-cycle ambiguity not resolved by the receiver (u-blox before it decodes the
        # data bits): the phase may be off by λ/2; such a row has an ambiguity of its own, never fixed
        "half": half,
        "var_phase": var + var_age,
        "var_code": var * opt["code_ratio"] ** 2 * correlated_variance_factor(nominal_interval_s(pairs.rover_time_s),
                                                                             opt["code_correlation_s"])
                    * opt.get("code_variance_factor", 1.0)
                    * glonass_code_factor(m["sat"].to_numpy(), bool(opt.get("glonass_fix", False))) + var_age,
    }


def _base_elevation_of_rows(m: pd.DataFrame, interpolated: np.ndarray, base_xyz_m) -> np.ndarray:
    """The base's elevation of each paired row at the instant its base observation stands for (rad): its base
    epoch's (``el_rad``), or for a row whose base observation was interpolated to the rover's time, the elevation at
    that time (of the rover row's satellite position, seen from the base): the wet delay the interpolated
    observation carries is the one of that instant."""
    el = m["el_rad"].to_numpy(dtype=float).copy()
    if base_xyz_m is not None and interpolated.any():
        sat = m[["sx_r", "sy_r", "sz_r"]].to_numpy(dtype=float)[interpolated]
        el[interpolated] = azimuth_elevation(np.asarray(base_xyz_m, float), sat)[1]
    return el


#: the merged rows' columns :func:`paired_sd_rows` reads no more once they are sorted (not copied with the rows kept)
_UNUSED_AFTER_SORT = ("time_gps_s_b", "time_gps_s_r", "_row_b", "_row_r", "_el_r", "eph_row_r")


def _kept_sorted(m: pd.DataFrame, keep: np.ndarray, by: list, drop=()) -> pd.DataFrame:
    """``m[keep].sort_values(by, kind="stable").drop(columns=…)`` (the same rows, order, index and dtypes) with one
    copy of the rows kept instead of two: the order is found on the ``by`` columns alone, then the rows are taken
    once, without the columns ``drop`` names (those ``m`` has).

    Parameters
    ----------
    m : DataFrame
        The table (N rows).
    keep : ndarray of bool (N,)
        The rows to keep.
    by : list of str
        The columns to sort on, first key first.
    drop : sequence of str
        Columns left out of the result.
    """
    at = np.flatnonzero(keep)
    order = m[by].take(at).reset_index(drop=True).sort_values(by, kind="stable").index.to_numpy()
    cols = [k for k, c in enumerate(m.columns) if c not in drop]
    return m.iloc[at[order], cols]


def _rows_at_starts(starts, names, sat, epoch, t_label, step: float) -> np.ndarray:
    """(N,) bool: the rows of :func:`signal_sd_table` at each (satellite name, time s) of ``starts`` (its epoch within
    half a step)."""
    starts = list(starts)
    if not starts or not t_label.size:
        return np.zeros(sat.size, dtype=bool)
    index = {str(n): k for k, n in enumerate(names)}
    k = np.array([index.get(str(name), -1) for name, _ in starts], dtype=np.int64)
    t = np.array([float(tt) for _, tt in starts])
    e = np.clip(np.searchsorted(t_label, t), 1, t_label.size - 1) if t_label.size > 1 else np.zeros(t.size, np.int64)
    if t_label.size > 1:                          # the nearer of the two neighbouring epochs
        e = np.where(np.abs(t_label[e - 1] - t) <= np.abs(t_label[e] - t), e - 1, e)
    ok = (k >= 0) & (np.abs(t_label[e] - t) <= 0.5 * step)
    n_ep = t_label.size
    return np.isin(sat.astype(np.int64) * n_ep + epoch, k[ok] * n_ep + e[ok])


def glonass_code_factor(sats, glonass_fix: bool) -> np.ndarray | float:
    """Per row, the code variance factor of a GLONASS satellite while GLONASS is float
    (:data:`~cdgps_cli.config.options.GLONASS_FLOAT_CODE_VARIANCE_FACTOR`), else 1."""
    from cdgps_cli.config.options import GLONASS_FLOAT_CODE_VARIANCE_FACTOR  # noqa: PLC0415

    if glonass_fix:
        return 1.0
    code, names = pd.factorize(np.asarray(sats, dtype=object))     # the few satellites, not every row's string
    per_name = np.array([GLONASS_FLOAT_CODE_VARIANCE_FACTOR if str(n).startswith("R") else 1.0 for n in names])
    return per_name[code] if per_name.size else np.ones(code.size)


def _base_at_rover_times(m: pd.DataFrame, b: pd.DataFrame, tb: np.ndarray, pairs, opt, base_xyz_m):
    """The paired rows ``m`` with their base observations interpolated to the rover's times when ``base_xyz_m`` is
    given (:func:`~cdgps_cli.measurement.base_interpolation.interpolate_base`), each row's age (s), the number
    of rover epochs interpolated and which rows were."""
    ep = m["_ep"].to_numpy()
    if base_xyz_m is None:
        return m, pairs.age_s[ep], 0, np.zeros(ep.size, dtype=bool)
    ph_b, rg_b, age, done = interpolate_base(m, b, tb, pairs.rover_time_s[ep], base_xyz_m=base_xyz_m,
                                             sync_tol_s=opt["sync_tol_s"], max_age_s=opt["max_age_s"],
                                             troposphere=opt["troposphere"])
    return m.assign(phase_cycles_b=ph_b, pseudorange_m_b=rg_b), age, int(np.unique(ep[done]).size), done


def _sorted_codes(values):
    """``np.unique(values.astype(str), return_inverse=True)``: the sorted distinct strings and each value's
    index among them, the strings formed for the distinct values only."""
    ids, uniq = pd.factorize(np.asarray(values).ravel())
    names, to_sorted = np.unique(np.asarray(uniq).astype(str), return_inverse=True)
    return names, to_sorted.ravel()[ids]


_ROW_KEYS = ("sats", "lam_m", "mu", "sat_xyz", "sat_base_xyz", "phase_sd_m", "code_sd_m", "slip", "half", "var_phase",
             "var_code")
#: row columns an epoch's groups take when the rows hold them: the wet troposphere's mapping factors at the base and
#: at the rover (rtk with the zenith wet delays estimated)
_WET_ROW_KEYS = ("mw_b", "mw_r")


def _row_keys(rows) -> tuple:
    """:data:`_ROW_KEYS`, and :data:`_WET_ROW_KEYS` when ``rows`` hold them."""
    return _ROW_KEYS + _WET_ROW_KEYS if _WET_ROW_KEYS[0] in rows else _ROW_KEYS


def _group_layout(epoch, code, el, half, n_ep) -> dict:
    """Every epoch's signal groups of ≥ 2 rows at once (rows ordered by epoch, then signal): ``start`` /
    ``stop`` (G,) row bounds, ``ref`` (G,) the row of the reference satellite (the highest base
    elevation ``el``, preferring rows without a ``half``-cycle flag unless the group has none; the
    first of equal ones, as ``argmax``) and ``ptr`` (n_ep + 1,) each epoch's groups."""
    n = epoch.size
    new = np.ones(n, dtype=bool)
    new[1:] = (epoch[1:] != epoch[:-1]) | (code[1:] != code[:-1])
    start = np.flatnonzero(new)
    stop = np.r_[start[1:], n].astype(np.int64)
    keep = stop - start >= 2
    start, stop = start[keep], stop[keep]
    if start.size == 0:
        return {"start": start, "stop": stop, "ref": start.copy(), "ptr": np.zeros(n_ep + 1, dtype=np.int64)}
    size = stop - start
    gid = np.repeat(np.arange(start.size), size)
    first_of = np.cumsum(size) - size                    # each group's first position in ``rows``
    rows = np.arange(size.sum()) - np.repeat(first_of, size) + np.repeat(start, size)
    all_half = np.logical_and.reduceat(half[rows], first_of)
    score = np.where(half[rows] & ~all_half[gid], -np.inf, el[rows])
    best = np.maximum.reduceat(score, first_of)
    hit = np.flatnonzero(score == best[gid])
    first = np.unique(gid[hit], return_index=True)[1]
    ref = rows[hit[first]]
    return {"start": start, "stop": stop, "ref": ref,
            "ptr": np.searchsorted(epoch[start], np.arange(n_ep + 1)).astype(np.int64)}


def epoch_groups(rows, k):
    """Signal groups (≥ 2 satellites) of epoch ``k``: views of :func:`paired_sd_rows` columns, ``ref`` the
    highest base elevation (preferring satellites without a half-cycle flag); ``rows`` (a, b) their
    row range in the run's columns and, when the epoch's groups are adjacent, ``epoch_rows`` (the
    row columns of all of them as one view, shared; :meth:`DDGroupModel.rows` uses it)."""
    lay = rows.get("groups")
    keys = _row_keys(rows)
    if lay is not None:
        names, code = rows["names"], rows["code"]
        groups = []
        j0, j1 = int(lay["ptr"][k]), int(lay["ptr"][k + 1])
        for j in range(j0, j1):
            a, b = int(lay["start"][j]), int(lay["stop"][j])
            g = {key: rows[key][a:b] for key in keys}
            g["signal"], g["ref"], g["rows"] = str(names[code[a]]), int(lay["ref"][j]) - a, (a, b)
            groups.append(g)
        if j1 - j0 > 1:
            a, b = int(lay["start"][j0]), int(lay["stop"][j1 - 1])
            if b - a == int((lay["stop"][j0:j1] - lay["start"][j0:j1]).sum()):   # adjacent groups: their rows as one view
                whole = {key: rows[key][a:b] for key in keys}
                for g in groups:
                    g["epoch_rows"] = whole
        return groups
    lo, hi = rows["ptr"][k], rows["ptr"][k + 1]
    code = rows["code"][lo:hi]
    cuts = [lo, *(lo + np.flatnonzero(code[1:] != code[:-1]) + 1), hi]
    groups = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if b - a < 2:
            continue
        g = {key: rows[key][a:b] for key in keys}
        g["signal"] = str(rows["names"][rows["code"][a]])
        el = np.where(g["half"], -np.inf, rows["el"][a:b]) if not g["half"].all() else rows["el"][a:b]
        g["ref"] = int(np.argmax(el))          # highest, preferring satellites without a half-cycle flag
        g["rows"] = (a, b)
        groups.append(g)
    return groups


def backward_slips(rows) -> np.ndarray:
    """Slip flags for a pass backward in time: a flag at a channel's row (a new ambiguity from that
    epoch on) belongs, going backward, to the channel's previous row."""
    n = rows["sats"].size
    epoch = np.repeat(np.arange(rows["ptr"].size - 1), np.diff(rows["ptr"]))
    key = channel_index(rows["sats"], rows["code"])        # the order of the strings sat + code
    order = np.lexsort((epoch, key))
    k_o, s_o = key[order], rows["slip"][order]
    nxt = np.zeros(n, dtype=bool)
    same = k_o[1:] == k_o[:-1]
    nxt[:-1] = same & s_o[1:]
    out = np.zeros(n, dtype=bool)
    out[order] = nxt
    return out
