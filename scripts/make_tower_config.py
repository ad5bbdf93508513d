#!/usr/bin/env python3
"""Write configs/tower-120m-fe.toml: a 120 m tower described the way a structural engineer would,
by finite-element mode shapes at the antenna points on ``modal`` coordinates.

FE model (Euler-Bernoulli beam, linear, small displacements)
------------------------------------------------------------
* A steel tube cantilever clamped at the foundation, 120 m high, 12 elements of 10 m, two
  bending planes (x-z and y-z) with different stiffness (platforms and cable trays stiffen the
  y direction), so the frequencies are distinct and the shapes unique.  Per node: lateral
  displacement u and slope θ; consistent element mass matrices; a 20 t equipment platform as a
  lumped mass at the top.
* Each plane's generalized eigenproblem K φ = ω² M φ gives its two lowest bending modes; the
  shapes are normalized to 1 m displacement at the top (so a modal coordinate is "m at the top
  in that mode") and the FE frequencies are used as they are.
* Mode shapes at the antenna points (``displacement_m``), at the gyro mounts (``rotation_rad``:
  θy = du_x/dz for bending in x, θx = −du_y/dz for bending in y) and at named points.
* Damping as a structural engineer gives it: ``damping_ratio`` ζ per mode (steel, 1–1.5 %).
* Wind forcing: a lateral load per unit height with a power-law profile (∝ (z/120)^0.3) and
  spatial coherence exp(−|z₁ − z₂| / 60 m) along the height, independent in x and y; projected
  on the modes (modal acceleration = φᵀ f / φᵀ M φ) it gives the full covariance W of the modal
  accelerations (correlated within each direction).  Its scale gives a top RMS of a few cm.

Numbers are written machine-independently (the helpers of make_testbed_config.py: round-off
below 1e-9 of the largest entry → 0, six significant digits, never "-0"); ``--check`` compares
the file to a fresh rendering within a relative tolerance and prints the first difference.

Run ``python scripts/make_tower_config.py`` to regenerate; tests check the file matches.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.linalg

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_testbed_config import check_or_write, fmt_number  # noqa: E402

HEIGHT_M = 120.0
N_ELEMENTS = 12
E_STEEL = 210e9
DIAMETER_M = 5.0
WALL_M = 0.025
EXTRA_MASS_KG_M = 2000.0        # ladders, cables, platforms (non-structural), per metre
TOP_MASS_KG = 20000.0
STIFFNESS_RATIO_Y = 1.15        # EI_y / EI_x
DAMPING = {"bend-x-1": 0.010, "bend-y-1": 0.010, "bend-x-2": 0.015, "bend-y-2": 0.015}
LOAD_EXPONENT = 0.3
COHERENCE_LENGTH_M = 60.0
TOP_MODAL_ACCEL_SIGMA = 0.04    # scale: σ of the first mode's modal acceleration noise, m/s² (per sample)
SAMPLE_PERIOD_S = 0.1

# antennas (name, height of their FE node, horizontal offset from the tower axis in m)
ANTENNAS = [("a60", 60.0, (1.0, 0.0)), ("a90", 90.0, (0.0, 1.0)), ("a120", 120.0, (-1.0, 0.0))]
MASTER = ("base", 0.0, (3.0, 0.0))            # on the foundation: does not move
GYROS = [("g120x", 120.0, "x"), ("g120y", 120.0, "y"), ("g60y", 60.0, "y")]
POINTS = [("z30", 30.0), ("z100", 100.0), ("top", 120.0)]
# pseudolites around the tower (lab frame, m): ground masts and neighbouring roofs
PSEUDOLITES = [(180.0, 20.0, 12.0), (-60.0, 170.0, 30.0), (-150.0, -90.0, 8.0), (40.0, -190.0, 25.0),
               (120.0, 130.0, 45.0), (-170.0, 60.0, 20.0)]
SHAPE_ZERO_REL = 1e-9


def beam_matrices(EI: float, m_per_m: float):
    """Global K, M over the free nodes' [u, θ] (clamped base removed) and node heights."""
    n = N_ELEMENTS
    L = HEIGHT_M / n
    k = EI / L**3 * np.array([[12, 6 * L, -12, 6 * L], [6 * L, 4 * L**2, -6 * L, 2 * L**2],
                              [-12, -6 * L, 12, -6 * L], [6 * L, 2 * L**2, -6 * L, 4 * L**2]])
    m = m_per_m * L / 420 * np.array([[156, 22 * L, 54, -13 * L], [22 * L, 4 * L**2, 13 * L, -3 * L**2],
                                      [54, 13 * L, 156, -22 * L], [-13 * L, -3 * L**2, -22 * L, 4 * L**2]])
    ndof = 2 * (n + 1)
    K = np.zeros((ndof, ndof))
    M = np.zeros((ndof, ndof))
    for e in range(n):
        idx = slice(2 * e, 2 * e + 4)
        K[idx, idx] += k
        M[idx, idx] += m
    M[2 * n, 2 * n] += TOP_MASS_KG
    return K[2:, 2:], M[2:, 2:], np.linspace(0.0, HEIGHT_M, n + 1)


def plane_modes(EI: float, m_per_m: float, count: int = 2):
    """Lowest ``count`` modes of one bending plane: frequencies (Hz), shapes over all nodes
    (u, θ per node incl. the clamped base), normalized to u = 1 at the top, and M."""
    K, M, z = beam_matrices(EI, m_per_m)
    w2, V = scipy.linalg.eigh(K, M, subset_by_index=[0, count - 1])
    full = np.zeros((2 * len(z), count))
    full[2:] = V
    full /= full[-2]                         # u at the top = 1 (fixes the sign too)
    full[np.abs(full) < SHAPE_ZERO_REL * np.abs(full).max()] = 0.0
    return np.sqrt(w2) / (2 * np.pi), full, M, z


def tower_model():
    """Modes (name, f_hz, u(z) (nodes,), θ(z) (nodes,), direction), node heights, W."""
    I_x = np.pi * DIAMETER_M**3 * WALL_M / 8
    m_per_m = 7850.0 * np.pi * DIAMETER_M * WALL_M + EXTRA_MASS_KG_M
    modes = []
    loads = []
    for d, ratio in (("x", 1.0), ("y", STIFFNESS_RATIO_Y)):
        f, S, M, z = plane_modes(E_STEEL * I_x * ratio, m_per_m)
        # wind load: nodal forces of a distributed load with profile and coherence (lumped at nodes)
        L = HEIGHT_M / N_ELEMENTS
        prof = (z / HEIGHT_M) ** LOAD_EXPONENT * L
        prof[-1] *= 0.5
        C = np.exp(-np.abs(z[:, None] - z[None, :]) / COHERENCE_LENGTH_M) * np.outer(prof, prof)
        Phi_u = S[0::2]                                     # (nodes, count)
        modal_mass = np.einsum("ik,ij,jk->k", S[2:], M, S[2:])
        A = Phi_u.T / modal_mass[:, None]                   # modal accel per nodal force
        loads.append(A @ C @ A.T)
        for i in range(S.shape[1]):
            modes.append((f"bend-{d}-{i + 1}", float(f[i]), S[0::2, i], S[1::2, i], d))
    order = sorted(range(len(modes)), key=lambda i: modes[i][1])
    modes = [modes[i] for i in order]
    W = scipy.linalg.block_diag(*loads)[np.ix_(order, order)]
    W *= TOP_MODAL_ACCEL_SIGMA**2 / W[0, 0]
    W = 0.5 * (W + W.T)
    return modes, z, W


def node(z, height):
    i = int(np.flatnonzero(np.isclose(z, height))[0])
    return i


def point_displacement(mode, z, height, offset):
    """[dx, dy, dz] of a point at ``offset`` (horizontal, from the axis) per unit of the mode."""
    _, _, u, th, d = mode
    i = node(z, height)
    rx, ry = offset
    if d == "x":                      # u_x, rotation about y: θy = du_x/dz; θ × r = (0, 0, −θy·rx)
        return [u[i], 0.0, -th[i] * rx]
    return [0.0, u[i], -th[i] * ry]  # u_y, rotation about x: θx = −du_y/dz; θ × r = (0, 0, θx·ry)


def mount_rotation(mode, z, height):
    """[rx, ry, rz] rotation (rad) of the tower cross-section at ``height`` per unit of the mode."""
    _, _, _, th, d = mode
    i = node(z, height)
    return [0.0, th[i], 0.0] if d == "x" else [-th[i], 0.0, 0.0]


def fmt(v):
    return "[" + ", ".join(fmt_number(x) for x in v) + "]"


def per_mode_table(modes, vectors):
    return "{ " + ", ".join(f'{m[0].replace("bend-", "q")} = {fmt(v)}' for m, v in zip(modes, vectors)) + " }"


def render() -> str:
    modes, z, W = tower_model()
    coord = {m[0]: m[0].replace("bend-", "q") for m in modes}
    lines = []
    w = lines.append
    w("# A 120 m steel tower described by finite-element mode shapes (modal coordinates, no sections).")
    w("# GENERATED by scripts/make_tower_config.py from a 12-element Euler-Bernoulli beam model;")
    w("# edit the script, not this file.  Format: docs/config-format.md.")
    w("")
    w("[model]")
    w('name = "tower-120m-fe"')
    w('description = "120 m steel tube tower (FE beam model), 4 bending modes; master on the foundation, '
      '3 antennas at 60/90/120 m, 6 pseudolites (near field), 3 rate gyros on modal coordinates"')
    w(f"sample_period_s = {SAMPLE_PERIOD_S}")
    w("wavelength_m = 0.19029367279836487  # GPS L1")
    w("measurement_sigma_m = 0.005      # prior carrier-phase noise (1 sigma) of every channel")
    w("line_bias_calibrated = true")
    w("")
    for m in modes:
        w("[[coordinates]]")
        w(f'name = "{coord[m[0]]}"')
        w('kind = "modal"')
        w(f'unit = "m at the top ({m[4]})"')
        w(f'description = "amplitude of mode {m[0]}: its displacement along {m[4]} at the top (120 m)"')
        w("")
    w("[[antennas]]")
    w(f'name = "{MASTER[0]}"')
    w(f"position_m = {fmt([MASTER[2][0], MASTER[2][1], 1.0])}   # on the foundation (clamped: no displacement)")
    w("master = true")
    w("")
    for name, h, off in ANTENNAS:
        w("[[antennas]]")
        w(f'name = "{name}"')
        w(f"position_m = {fmt([off[0], off[1], h])}")
        w(f"displacement_m = {per_mode_table(modes, [point_displacement(m, z, h, off) for m in modes])}")
        w("")
    for i, p in enumerate(PSEUDOLITES):
        w("[[transmitters]]")
        w(f'name = "PL{i + 1}"')
        az = np.degrees(np.arctan2(p[1], p[0])) % 360
        w(f"position_m = {fmt(p)}   # pseudolite, {np.hypot(p[0], p[1]):.0f} m from the tower at azimuth {az:.0f} deg")
        w("")
    for name, f, u, th, d in modes:
        w("[[modes]]")
        w(f'name = "{name}"')
        w(f"frequency_hz = {fmt_number(f)}     # FE model")
        w(f"damping_ratio = {DAMPING[name]}")
        shape = [1.0 if coord[n] == coord[name] else 0.0 for n, *_ in modes]
        w(f"shape = {fmt(shape)}")
        w("")
    w("[process_noise]")
    w('space = "modal"                  # modal accelerations, m/s² at the top per unit shape (ZOH)')
    w("# wind load with a power-law profile and coherence along the height, projected on the modes:")
    w("# correlated within each direction, independent between x and y (make_tower_config.py)")
    w("covariance = [")
    for r in W:
        w(f"    {fmt(r)},")
    w("]")
    w("")
    for name, h, axis in GYROS:
        w("[[gyros]]")
        w(f'name = "{name}"')
        w(f'axis = "{axis}"')
        w(f"rotation_rad = {per_mode_table(modes, [mount_rotation(m, z, h) for m in modes])}")
        w(f'description = "rate gyro at {h:.0f} m about {axis}"')
        w("")
    for name, h in POINTS:
        w("[[points]]")
        w(f'name = "{name}"')
        w(f"position_m = {fmt([0.0, 0.0, h])}")
        w(f"displacement_m = {per_mode_table(modes, [point_displacement(m, z, h, (0.0, 0.0)) for m in modes])}")
        w(f'description = "tower axis at {h:.0f} m"')
        w("")
    w("[simulation]")
    w("phase_sigma_m = 0.005            # white carrier-phase noise of the simulator (= the prior)")
    w("multipath_sigma_m = 0.0")
    w("multipath_time_constant_s = 30.0")
    w("snr_dbhz = 45.0")
    w("initial_modal_sigma = 0.05       # free vibration after a gust: 5 cm at the top per mode")
    w("initial_rigid_sigma_rad = 0.0")
    w("disturbance_scale = 1.0          # the wind forcing is the model's process noise")
    w("gyro_noise_rad_s = 0.0001")
    w("gyro_bias_sigma_rad_s = 0.0002")
    w("gyro_bias_drift_rad_s_per_sqrt_s = 1.0e-6")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    out = Path(__file__).resolve().parent.parent / "configs" / "tower-120m-fe.toml"
    text = render()
    check_or_write(out, text, "--check" in sys.argv)
    modes, _, W = tower_model()
    for m in modes:
        print(f"{m[0]:9s} {m[1]:.4f} Hz  zeta {DAMPING[m[0]]}")
