"""Multi-GNSS, multi-frequency double differences on a rover-position state (the engine's DD model).

For one epoch and one signal group g (a constellation and a frequency slot, e.g. ``E:E5a``) with
satellites s = 1…m common to base and rover and reference r (highest elevation at the base), the
rows are

    ∇Δ(λφ)_s = ∇Δρ_s(x) + λ_s N_s − λ_r N_r − ∇Δ(μ I)_s + ε,       ∇ΔP_s = ∇Δρ_s(x) + ∇Δ(μ I)_s + e

with x the rover ECEF offset from its linearization origin (m), N the single-difference
ambiguities of the group (cycles), I optional single-difference slant ionosphere at L1 (m,
μ = (f_L1/f)²).  λ and μ are per satellite: equal within a CDMA group (so the ambiguity term is
λ_g (N_s − N_r)), different for GLONASS (FDMA, f = f₀ + k Δf), whose DD ambiguity λ_s N_s − λ_r N_r
is not an integer times one wavelength — those groups are kept float.  Receiver clocks cancel in the DD; inter-system and inter-frequency biases
cancel because every group has its own reference satellite (no inter-system DD is formed).  The
noise is D Σ Dᵀ per group, Σ the SD variances (a² + b²/sin²el, doubled for the two receivers).
:func:`epoch_rows` gives (z − h(x), H, L) for a linearization point, :func:`dd_range` the model.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.measurement.differencing import dd_covariance, dd_operator

__all__ = ["dd_range", "epoch_rows"]


def dd_range(rover_xyz_m, base_xyz_m, sat_xyz_m, ref: int, sat_base_xyz_m=None) -> np.ndarray:
    """∇Δρ (m, shape (m−1,)) of satellites ``sat_xyz_m`` (m, 3; as seen by the rover) against
    satellite ``ref``; ``sat_base_xyz_m`` the positions for the base's own transmission times
    (default: the same)."""
    sb = sat_xyz_m if sat_base_xyz_m is None else sat_base_xyz_m
    sd = np.linalg.norm(sat_xyz_m - rover_xyz_m, axis=1) - np.linalg.norm(sb - base_xyz_m, axis=1)
    return dd_operator(len(sd), ref) @ sd


def epoch_rows(x, groups, base_xyz_m, origin_xyz_m, n_state: int):
    """Residuals, Jacobian and noise factor of one epoch's DDs at state ``x``.

    Parameters
    ----------
    x : ndarray (n_state,)
        State: [rover offset (3, m), ambiguities (cycles), ionosphere (m)…].
    groups : list of dict
        One per signal group: ``sat_xyz`` (m, 3) for the rover's transmission times, ``sat_base_xyz``
        (m, 3) for the base's, ``ref`` (int), ``lam_m`` (m,) or scalar, ``mu`` (m,) or scalar,
        ``phase_sd_m`` (m,), ``code_sd_m`` (m,), ``var_phase`` / ``var_code`` (m,) m²,
        ``amb_col`` (m,) state columns of N, ``iono_col`` (m,) columns of I or −1.
    base_xyz_m, origin_xyz_m : ndarray (3,)
        Base position and the origin of the rover offset, ECEF m.
    n_state : int

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
        rs.append(D @ g["phase_sd_m"] - (geo + D @ (lam * n_amb) - D @ (mu * ion)))
        rs.append(D @ g["code_sd_m"] - (geo + D @ (mu * ion)))
        Hs += [Hg, Hc]
        Cs += [dd_covariance(g["var_phase"], ref), dd_covariance(g["var_code"], ref)]
    p = sum(c.shape[0] for c in Cs)
    C = np.zeros((p, p))
    k = 0
    for c in Cs:
        C[k:k + len(c), k:k + len(c)] = c
        k += len(c)
    return np.concatenate(rs), np.vstack(Hs), np.linalg.cholesky(C)
