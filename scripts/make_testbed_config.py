#!/usr/bin/env python3
"""Write configs/testbed-1998.toml: the 1998 Stanford testbed (Teague, How & Parkinson 1998), and
configs/testbed-1998-lumped.toml, the previous lumped model kept for the bundled data and tests.

The paper's mode shapes came from NASTRAN and are not published.  This script builds a mass and
stiffness model of the testbed from the layout the paper describes (Sec. III.A), fits its unknown
parameters by least squares so that the generalized eigenproblem K φ = ω² M φ gives Table 1's
frequencies with the shapes the paper names, and writes those shapes with Table 1's frequencies and
time constants, as the paper did with its analytic model.  Derivation, assumptions and the table of
paper vs model per mode: docs/testbed-model.md.

Model (body frame B: x along the structure, y horizontal, z up; q1..q9 = [y, twist φ about x,
yaw θ about z] of sections C1, C2, C3 at x = -4, 0, +4 m)
---------------------------------------------------------------------------------------------
* M = diag(m, I_xx, I_zz) per section; m = 60 kg (180 kg / 3), identical sections, so one I_xx and
  one I_zz = I_xx + I_yy (perpendicular-axis theorem for a section lying in the horizontal plane).
* Two aluminium tubes (½ in. = 12.7 mm OD, wall t, E = 70 GPa, G = 26 GPa, 3.7 m) clamped to the
  cube faces 0.15 m from the section centres: an Euler-Bernoulli element in the horizontal plane
  (y, θ) through rigid offsets, and torsion GJ/L between the twists.
* Threads (12 m) hang each section from a top beam that turns freely on a thrust bearing: pendulum
  stiffness m g/L on y relative to the top beam, whose angle is eliminated (static condensation: it
  is massless and frictionless), and gravity stiffness m g h on the twist, h the height of the
  attachment above the centre of mass (per section: the paper balances each section by adjusting it).
  The rigid rotation of the whole assembly about the vertical is then the null vector of K: the
  rigid-body coordinate q10; the 8 elastic modes are M-orthogonal to it (mean-axis frame B).
* Fitted (least squares on log frequency, all 8 elastic modes, equal weights): t, I_xx, I_yy ≥ 0,
  h (C1, C3) and h (C2).  The fitted values are written below as FITTED (4 significant digits);
  ``--fit`` runs the fit again and prints it with the residuals.

Run ``python scripts/make_testbed_config.py`` to regenerate both files; ``--check`` exits 1 when
a file differs from what the script renders (tests use it).
"""

from __future__ import annotations

import math
import re
import sys
from dataclasses import astuple, dataclass
from pathlib import Path

import numpy as np
import scipy.linalg

G0 = 9.80665
X_SECTIONS = np.array([-4.0, 0.0, 4.0])
MASS_KG = 60.0                  # per section: 180 kg / 3
I_XX = 6.0                      # the lumped model's section inertias and tube wall (testbed-1998-lumped.toml)
I_ZZ = 6.0
ARM_M = 1.0                     # antennas and jets at the arm tips, 1 m from the section centre (assumed)
BEAM_L = 3.7                    # tube length (Sec. III.A)
BEAM_OFFSET = 0.15              # tube clamped at the cube face: (4 m spacing - 3.7 m tube) / 2
E_AL, G_AL = 70e9, 26e9         # aluminium, Pa
OD, WALL = 0.0127, 0.001        # ½ in. tube; WALL: the lumped model's wall
THREAD_L = 12.0                 # suspension threads (Sec. III.A)
THREAD_H = 0.0015               # the lumped model's thread height above the centre of mass

# Table 1 of the paper: (name, frequency_hz, time_constant_s)
TABLE1 = {
    "pendulum": (0.059, 20.0), "swing": (0.160, 130.0), "bending-1": (0.132, 200.0),
    "twist-1": (0.085, 45.0), "twist-2": (0.138, 35.0), "bending-2": (0.135, 140.0),
    "bending-3": (0.23, 50.0), "bending-4": (0.28, 25.0), "rigid-body": (0.0, 140.0),
}
ORDER = ["pendulum", "swing", "bending-1", "twist-1", "twist-2", "bending-2", "bending-3",
         "bending-4", "rigid-body"]


# ---------------------------------------------------------------- the fitted model (issue 31)
AL_DENSITY = 2700.0


@dataclass(frozen=True)
class TestbedParameters:
    """The unknowns of the testbed model (SI units)."""

    wall_m: float                  # tube wall thickness
    ixx_kg_m2: float               # section inertia about the structure axis x (twist)
    iyy_kg_m2: float               # I_zz - I_xx >= 0 (the section's inertia about y)
    thread_height_end_m: float     # thread attachment above the centre of mass, C1 and C3
    thread_height_centre_m: float  # the same, C2
    pendulum_length_m: float       # effective suspension length: lateral stiffness m g / L_p per section

    @property
    def izz_kg_m2(self) -> float:
        return self.ixx_kg_m2 + self.iyy_kg_m2


#: the least-squares solution of :func:`fit_parameters`, rounded to 4 significant digits
FITTED = TestbedParameters(wall_m=8.994e-4, ixx_kg_m2=41.17, iyy_kg_m2=0.0,
                           thread_height_end_m=6.740e-3, thread_height_centre_m=1.592e-2,
                           pendulum_length_m=9.506)
#: the fit before the suspension length was a parameter (threads of the paper's 12 m; swing -10.1 %,
#: bending-1 -6.6 %, RMS log residual 0.051); docs/testbed-model.md compares the two
FITTED_12M = TestbedParameters(wall_m=7.967e-4, ixx_kg_m2=36.11, iyy_kg_m2=0.0,
                               thread_height_end_m=5.800e-3, thread_height_centre_m=1.389e-2,
                               pendulum_length_m=THREAD_L)
FIT_START = TestbedParameters(1.0e-3, 40.0, 3.0, 8.0e-3, 2.0e-2, 11.0)
#: bounds: a "thin-walled" ½ in. tube (0.4-1.27 mm), all of a 60 kg section's mass within the 1 m arms
#: (I_xx <= m·1 m²), I_yy >= 0, the thread within 5 cm of the centre of mass, a suspension no longer
#: than the 12 m threads (a thread attached above the centre of mass only lengthens the pendulum)
FIT_LOWER = TestbedParameters(4.0e-4, 1.0, 0.0, 0.0, 0.0, 5.0)
FIT_UPPER = TestbedParameters(1.27e-3, 60.0, 30.0, 0.05, 0.05, THREAD_L)
FIT_SCALE = TestbedParameters(1.0e-3, 10.0, 3.0, 0.01, 0.01, 1.0)


def tube_stiffness(wall_m: float) -> tuple[float, float]:
    """Bending EI (N·m²) and torsion GJ (N·m²) of the ½ in. aluminium tube with wall ``wall_m``."""
    i_area = np.pi / 64 * (OD**4 - (OD - 2 * wall_m) ** 4)
    return E_AL * i_area, G_AL * 2 * i_area


def tube_sag_m(wall_m: float) -> float:
    """Mid-span sag of the clamped tube under its own weight, w L⁴ / (384 EI), m."""
    area = np.pi / 4 * (OD**2 - (OD - 2 * wall_m) ** 2)
    return AL_DENSITY * area * G0 * BEAM_L**4 / (384 * tube_stiffness(wall_m)[0])


def beam_element(ei: float, length: float) -> np.ndarray:
    """Euler-Bernoulli stiffness (4, 4) on [v1, θ1, v2, θ2]."""
    L = length
    return ei / L**3 * np.array([[12, 6 * L, -12, 6 * L], [6 * L, 4 * L * L, -6 * L, 2 * L * L],
                                 [-12, -6 * L, 12, -6 * L], [6 * L, 2 * L * L, -6 * L, 4 * L * L]])


def rigid_rotation() -> np.ndarray:
    """The rigid rotation of the assembly about the vertical in q1..q9 (1 rad), shape (9,)."""
    r = np.zeros(9)
    r[0::3] = X_SECTIONS
    r[2::3] = 1.0
    return r


def testbed_matrices(p: TestbedParameters) -> tuple[np.ndarray, np.ndarray]:
    """M and K (9, 9) over q1..q9; K has the rigid rotation as its null vector."""
    M = np.diag(np.tile([MASS_KG, p.ixx_kg_m2, p.izz_kg_m2], 3))
    ei, gj = tube_stiffness(p.wall_m)
    K = np.zeros((9, 9))
    for k in range(2):
        a, b = 3 * k, 3 * (k + 1)
        T = np.zeros((4, 9))                  # beam-end [v1, θ1, v2, θ2] from the section DOFs
        T[0, a], T[0, a + 2] = 1.0, BEAM_OFFSET
        T[1, a + 2] = 1.0
        T[2, b], T[2, b + 2] = 1.0, -BEAM_OFFSET
        T[3, b + 2] = 1.0
        K += T.T @ beam_element(ei, BEAM_L) @ T
        d = np.zeros(9)
        d[a + 1], d[b + 1] = -1.0, 1.0
        K += gj / BEAM_L * np.outer(d, d)
    heights = (p.thread_height_end_m, p.thread_height_centre_m, p.thread_height_end_m)
    Kt = np.zeros((10, 10))                   # threads on [q1..q9, β]: β the top beam's angle
    for k in range(3):
        K[3 * k + 1, 3 * k + 1] += MASS_KG * G0 * heights[k]
        a = np.zeros(10)
        a[3 * k], a[9] = 1.0, -X_SECTIONS[k]
        Kt += MASS_KG * G0 / p.pendulum_length_m * np.outer(a, a)
    K += Kt[:9, :9] - np.outer(Kt[:9, 9], Kt[9, :9]) / Kt[9, 9]   # the free top beam condensed out
    return M, 0.5 * (K + K.T)


def _mac(M, v, u) -> float:
    """Mass-weighted modal assurance criterion of two shapes (1: the same shape)."""
    return float((v @ M @ u) ** 2 / ((v @ M @ v) * (u @ M @ u)))


def ideal_shapes() -> dict:
    """The shapes the paper's mode names describe, in q1..q9 (unnormalized)."""
    def e(**kw):
        v = np.zeros(9)
        for k, x in kw.items():
            v[int(k[1:]) - 1] = x
        return v
    return {"pendulum": e(q2=1, q5=1, q8=1),        # all sections rock together about x
            "twist-1": e(q2=-1, q8=1),               # ends twist against each other
            "twist-2": e(q2=1, q5=-2, q8=1),         # centre against the ends
            "swing": e(q1=1, q4=1, q7=1)}            # the whole structure swings sideways


def name_modes(M, w2, V) -> dict:
    """Table 1's name -> column of V: the three modes with the most twist energy are the pendulum
    and twist modes (each the best MAC with its ideal shape), the remaining lateral mode closest to
    a common translation is the swing mode, the other four the bending modes by frequency."""
    elastic = [int(i) for i in np.argsort(w2)[1:]]
    twist_energy = {i: sum(V[3 * k + 1, i] ** 2 * M[3 * k + 1, 3 * k + 1] for k in range(3)) for i in elastic}
    twist = sorted(elastic, key=twist_energy.get)[-3:]
    lateral = [i for i in elastic if i not in twist]
    ideal = ideal_shapes()
    out = {}
    for n in ("pendulum", "twist-1", "twist-2"):
        out[n] = max(twist, key=lambda i: _mac(M, V[:, i], ideal[n]))
        twist.remove(out[n])
    out["swing"] = max(lateral, key=lambda i: _mac(M, V[:, i], ideal["swing"]))
    lateral.remove(out["swing"])
    for j, i in enumerate(sorted(lateral, key=lambda i: w2[i])):
        out[f"bending-{j + 1}"] = i
    return out


def model_modes(M, K) -> dict:
    """Table 1's name -> (model frequency, Hz; mass-normalized shape (9,)) for the 8 elastic modes."""
    w2, V = scipy.linalg.eigh(K, M)
    names = name_modes(M, w2, V)
    return {n: (float(np.sqrt(max(w2[i], 0.0)) / 2 / np.pi), clean_shape(V[:, i])) for n, i in names.items()}


def frequency_residuals(p: TestbedParameters) -> np.ndarray:
    """ln(model / Table 1) per elastic mode in ORDER, shape (8,)."""
    modes = model_modes(*testbed_matrices(p))
    return np.array([np.log(modes[n][0] / TABLE1[n][0]) for n in ORDER[:-1]])


def fit_parameters(pendulum_length_m: float | None = None) -> tuple[TestbedParameters, np.ndarray]:
    """Least-squares parameters (from FIT_START within the bounds) and their residuals; with
    ``pendulum_length_m`` the suspension length is held at that value (e.g. the paper's 12 m)."""
    from scipy.optimize import least_squares  # noqa: PLC0415

    vec = lambda p: np.array(astuple(p), dtype=float)  # noqa: E731
    free = slice(None) if pendulum_length_m is None else slice(0, -1)
    tail = () if pendulum_length_m is None else (pendulum_length_m,)
    r = least_squares(lambda x: frequency_residuals(TestbedParameters(*x, *tail)), vec(FIT_START)[free],
                      bounds=(vec(FIT_LOWER)[free], vec(FIT_UPPER)[free]), x_scale=vec(FIT_SCALE)[free],
                      xtol=1e-12, ftol=1e-12)
    return TestbedParameters(*map(float, r.x), *tail), r.fun


def swing_bound_hz(thread_m: float, attach_above_cm_m: float = 0.0) -> float:
    """Upper bound of the swing mode (a common sideways translation on the threads), Hz.

    A section hung by one thread of length ``thread_m`` attached ``attach_above_cm_m`` above its
    centre of mass is a compound pendulum whose lower frequency is at most that of a point mass on
    thread + offset, sqrt(g / (L + h)) / 2π; the tubes carry no load in a common translation.  So the
    paper's 12 m threads cannot give more than 0.1439 Hz, whatever the sections' mass distribution.
    """
    return float(np.sqrt(G0 / (thread_m + attach_above_cm_m)) / 2 / np.pi)


# ---------------------------------------------------------------- the previous lumped model
def lumped_model():
    """Mass and stiffness matrices (9×9) over q1..q9 = [y, twist, yaw] per section."""
    M = np.diag(np.tile([MASS_KG, I_XX, I_ZZ], 3))
    K = np.zeros((9, 9))
    Iarea = np.pi / 64 * (OD**4 - (OD - 2 * WALL) ** 4)
    EI, GJ = E_AL * Iarea, G_AL * 2 * Iarea
    L = BEAM_L
    kb = EI / L**3 * np.array([[12, 6 * L, -12, 6 * L], [6 * L, 4 * L * L, -6 * L, 2 * L * L],
                               [-12, -6 * L, 12, -6 * L], [6 * L, 2 * L * L, -6 * L, 4 * L * L]])
    for k in range(2):
        a, b = 3 * k, 3 * (k + 1)
        T = np.zeros((4, 9))          # beam end DOFs [v1, φ1, v2, φ2] from section DOFs
        T[0, a], T[0, a + 2] = 1.0, BEAM_OFFSET
        T[1, a + 2] = 1.0
        T[2, b], T[2, b + 2] = 1.0, -BEAM_OFFSET
        T[3, b + 2] = 1.0
        K += T.T @ kb @ T
        kt = GJ / L
        K[a + 1, a + 1] += kt
        K[b + 1, b + 1] += kt
        K[a + 1, b + 1] -= kt
        K[b + 1, a + 1] -= kt
    for k in range(3):
        K[3 * k, 3 * k] += MASS_KG * G0 / THREAD_L
        K[3 * k + 1, 3 * k + 1] += MASS_KG * G0 * THREAD_H
    return M, K


def elastic_modes():
    """The previous lumped model's named modes (configs/testbed-1998-lumped.toml, rendered unchanged)."""
    M, K = lumped_model()
    r = np.zeros(9)                       # rigid rotation of the assembly about the vertical
    r[0::3] = X_SECTIONS
    r[2::3] = 1.0
    Mr = M @ r
    # orthonormal basis of {v : rᵀ M v = 0}
    basis = scipy.linalg.null_space(Mr[None, :])
    w2, V = scipy.linalg.eigh(basis.T @ K @ basis, basis.T @ M @ basis)
    modes = basis @ V                     # mass-normalized: Vᵀ (BᵀMB) V = I
    out = []
    for i in range(modes.shape[1]):
        v = clean_shape(modes[:, i])
        twist_energy = sum(v[3 * k + 1] ** 2 * I_XX for k in range(3))
        out.append((np.sqrt(max(w2[i], 0)) / 2 / np.pi, v, twist_energy > 0.5))
    twist = [m for m in out if m[2]]
    lateral = [m for m in out if not m[2]]
    assert len(twist) == 3 and len(lateral) == 5, (len(twist), len(lateral))
    names = {}
    names["pendulum"] = twist[0]
    names["twist-1"] = twist[1]
    names["twist-2"] = twist[2]
    # the swing mode: lateral mode with the largest common translation
    swing = max(lateral, key=lambda m: abs(m[1][0::3].sum()))
    names["swing"] = swing
    bends = [m for m in lateral if m is not swing]
    for i, m in enumerate(bends):
        names[f"bending-{i + 1}"] = m
    return names, M


# Mode shapes are written machine-independently: eigenvector entries below SHAPE_ZERO_REL of the
# largest one are LAPACK round-off (their value and sign depend on the BLAS kernel) and become 0,
# and the sign is fixed on the *last* component within SHAPE_TIE_REL of the largest magnitude, so
# that two entries of equal size and opposite sign cannot flip the shape from one machine to another.
SHAPE_ZERO_REL = 1e-9
SHAPE_TIE_REL = 1e-6
SIGNIFICANT_DIGITS = 6
# --check compares numbers to this relative tolerance (the file keeps 6 significant digits)
CHECK_REL_TOL = 1e-5
CHECK_ABS_TOL = 1e-12


def clean_shape(v):
    """Round-off below SHAPE_ZERO_REL·max|v| set to 0; sign fixed on the last near-largest entry."""
    v = np.asarray(v, dtype=float).copy()
    big = np.max(np.abs(v))
    v[np.abs(v) < SHAPE_ZERO_REL * big] = 0.0
    lead = np.flatnonzero(np.abs(v) >= (1.0 - SHAPE_TIE_REL) * big)[-1]
    return v * np.sign(v[lead])


def fmt_number(x):
    """A float with SIGNIFICANT_DIGITS significant digits; never '-0'."""
    return f"{float(x) + 0.0:.{SIGNIFICANT_DIGITS}g}"


def fmt(v):
    return "[" + ", ".join(fmt_number(x) for x in v) + "]"


NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def first_difference(expected: str, actual: str):
    """First line where two renderings differ beyond CHECK_REL_TOL, as (line number, expected,
    actual), or None.  Text outside numbers must match exactly."""
    exp_lines, act_lines = expected.splitlines(), actual.splitlines()
    for n, (e, a) in enumerate(zip(exp_lines, act_lines), start=1):
        if e == a:
            continue
        if NUMBER.sub("#", e) != NUMBER.sub("#", a):
            return n, e, a
        for x, y in zip(NUMBER.findall(e), NUMBER.findall(a)):
            if not math.isclose(float(x), float(y), rel_tol=CHECK_REL_TOL, abs_tol=CHECK_ABS_TOL):
                return n, e, a
    if len(exp_lines) != len(act_lines):
        n = min(len(exp_lines), len(act_lines)) + 1
        pick = lambda lines: lines[n - 1] if n <= len(lines) else "<end of file>"  # noqa: E731
        return n, pick(exp_lines), pick(act_lines)
    return None


def render(lumped: bool = False) -> str:
    """The config text: the fitted testbed model, or with ``lumped`` the previous lumped model
    (configs/testbed-1998-lumped.toml, byte for byte as it was generated before issue 31)."""
    if lumped:
        modes = {n: (f, v) for n, (f, v, _) in elastic_modes()[0].items()}
        izz_total = 3 * I_ZZ + MASS_KG * float(np.sum(X_SECTIONS**2))
        header = ["# Teague, How & Parkinson (1998): the 8 m, 180 kg Stanford flexible-structure testbed.",
                  "# GENERATED by scripts/make_testbed_config.py (lumped model → mode shapes, Table 1 frequencies);",
                  "# edit the script, not this file.  Format: docs/config-format.md."]
        note = "lumped-model frequency"
    else:
        M, K = testbed_matrices(FITTED)
        modes = model_modes(M, K)
        izz_total = float(rigid_rotation() @ M @ rigid_rotation())
        header = ["# Teague, How & Parkinson (1998): the 8 m, 180 kg Stanford flexible-structure testbed.",
                  "# GENERATED by scripts/make_testbed_config.py: mode shapes of the mass/stiffness model fitted to",
                  "# Table 1 (docs/testbed-model.md), frequencies and time constants of Table 1 as in the paper;",
                  "# edit the script, not this file.  Format: docs/config-format.md.",
                  f"# fitted: tube wall {FITTED.wall_m * 1e3:.3g} mm, section I_xx = I_zz = {FITTED.ixx_kg_m2:.4g} kg·m², "
                  f"I_zz - I_xx = {FITTED.iyy_kg_m2:.3g} kg·m²,",
                  f"# thread above the centre of mass {FITTED.thread_height_end_m * 1e3:.3g} mm (C1, C3), "
                  f"{FITTED.thread_height_centre_m * 1e3:.3g} mm (C2), effective suspension length "
                  f"{FITTED.pendulum_length_m:.4g} m (12 m threads in the paper)"]
        note = "model frequency"
    lines = []
    w = lines.append
    for h in header:
        w(h)
    w("")
    w("[model]")
    w('name = "testbed-1998"')
    w('description = "Three rigid sections joined by two elastic beams, hung from threads; 6 antennas + master, 6 pseudolites (near field), 24 thrusters, 6 rate gyros"')
    w("sample_period_s = 0.1            # 10 Hz, Sec. III.B")
    w("wavelength_m = 0.19029367279836487  # GPS L1")
    w("measurement_sigma_m = 0.02       # EKF/batch weighting: 2 cm (1 sigma), Sec. IV.B")
    w("line_bias_calibrated = true      # line biases below are known: bias = line bias + integer cycles")
    w("")
    w("[body]")
    w("origin_m = [0.0, 0.0, 0.0]       # lab frame: origin at the centre section, z up")
    w('rigid_rotation = "q10"           # rotation of the body frame about the vertical (large angle)')
    w("")
    desc = {"translation": "lateral translation (y) of", "twist": "twist (rotation about x) of",
            "yaw": "rotation about the vertical (z) of"}
    for k in range(3):
        for j, (kind, what) in enumerate([("translation", "translation"), ("rotation", "twist"), ("rotation", "yaw")]):
            w("[[coordinates]]")
            w(f'name = "q{3 * k + j + 1}"')
            w(f'kind = "{kind}"')
            w(f'description = "{desc[what]} section C{k + 1} relative to the body frame"')
            w("")
    w("[[coordinates]]")
    w('name = "q10"')
    w('kind = "rotation"')
    w('description = "rigid-body rotation of the body frame about the lab vertical"')
    w("")
    for k in range(3):
        w("[[sections]]")
        w(f'name = "C{k + 1}"')
        w(f"pivot_m = [{X_SECTIONS[k]:.1f}, 0.0, 0.0]")
        w(f'translation = {{ y = "q{3 * k + 1}" }}')
        w(f'rotation = {{ x = "q{3 * k + 2}", z = "q{3 * k + 3}" }}')
        w("")
    w("[[antennas]]")
    w('name = "master"')
    w('section = "C2"')
    w("position_m = [0.0, 0.0, 0.2]")
    w('receiver = "rx1+rx2"')
    w("master = true")
    w("")
    line_bias = [0.012, -0.034, 0.051, 0.007, -0.021, 0.043]
    for k in range(3):
        for side, sgn in enumerate((1, -1)):
            i = 2 * k + side
            w("[[antennas]]")
            w(f'name = "a{i + 1}"')
            w(f'section = "C{k + 1}"')
            w(f"position_m = [{X_SECTIONS[k]:.1f}, {sgn * ARM_M:.1f}, 0.05]")
            w(f'receiver = "{"rx1" if i < 3 else "rx2"}"')
            w(f"line_bias_m = {line_bias[i]}      # calibrated electrical-length difference to the master")
            w("")
    pls = [(0.5, 1.0, 13.5), (9.0, 7.0, 13.0), (-10.0, -6.0, 13.0), (18.0, -4.0, 3.0),
           (-5.0, 16.0, 5.0), (-17.0, 8.0, 1.0)]
    where = ["ceiling", "ceiling", "ceiling", "east wall", "north wall", "west wall"]
    for i, (p, wh) in enumerate(zip(pls, where)):
        w("[[transmitters]]")
        w(f'name = "PL{i + 1}"')
        w(f"position_m = {fmt(p)}   # pseudolite, {wh} of the 20 m high bay (near field, Eq. 2)")
        w("")
    for name in ORDER:
        f, tau = TABLE1[name]
        w("[[modes]]")
        w(f'name = "{name}"')
        w(f"frequency_hz = {f}")
        w(f"time_constant_s = {tau}")
        if name == "rigid-body":
            w("rigid = true")
            shape = np.zeros(10)
            shape[9] = 1.0 / np.sqrt(izz_total)
        else:
            fl, v = modes[name]
            w(f"# {note} {fl:.4f} Hz")
            shape = np.concatenate([v, [0.0]])
        w(f"shape = {fmt(shape)}")
        w("")
    w("[process_noise]")
    w('space = "modal"                  # white noise on each modal acceleration, B_w = [0; I] (ZOH)')
    w("sigma = [0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.05]   # W = diag(0.5², …, 0.05²), Sec. III.B")
    w("")
    gyros = [("g1", "C1", "x"), ("g2", "C1", "z"), ("g3", "C2", "x"), ("g4", "C2", "z"),
             ("g5", "C2", "z"), ("g6", "C3", "x")]
    for n, s, a in gyros:
        w("[[gyros]]")
        w(f'name = "{n}"')
        w(f'section = "{s}"')
        w(f'axis = "{a}"')
        w("")
    for k in range(3):
        for side, sgn in enumerate((1, -1)):
            i = 2 * k + side
            for d, vec in (("+x", "[1.0, 0.0, 0.0]"), ("-x", "[-1.0, 0.0, 0.0]"), ("+z", "[0.0, 0.0, 1.0]"), ("-z", "[0.0, 0.0, -1.0]")):
                w("[[thrusters]]")
                w(f'name = "a{i + 1}{d}"')
                w(f'section = "C{k + 1}"')
                w(f"position_m = [{X_SECTIONS[k]:.1f}, {sgn * ARM_M:.1f}, 0.0]")
                w(f"direction = {vec}")
                w("max_force_n = 1.4")
                w("")
    w("[simulation]")
    w("phase_sigma_m = 0.01             # white carrier-phase noise of the simulator")
    w("multipath_sigma_m = 0.0          # slowly varying multipath (set e.g. 0.015, Sec. I)")
    w("multipath_time_constant_s = 30.0")
    w("snr_dbhz = 45.0")
    w("initial_modal_sigma = 0.3        # free vibration: modal amplitude (sqrt(kg)·m)")
    w("initial_rigid_sigma_rad = 0.3")
    w("disturbance_scale = 0.2          # fraction of the process noise applied as true disturbance")
    w("gyro_noise_rad_s = 0.0005")
    w("gyro_bias_sigma_rad_s = 0.0005")
    w("gyro_bias_drift_rad_s_per_sqrt_s = 2.0e-5")
    w("static_rest_after_s = 60.0")
    w("static_settle_s = 20.0")
    w('static_angle_coordinate = "q10"')
    w("static_angle_deg = -1.4          # centre-section vertical angle q6 + q10 at rest (laser survey)")
    w("pulse_time_s = 5.0")
    w("pulse_duration_s = 1.0")
    w('pulse_thrusters = ["a3+z", "a4-z", "a5-z", "a6+z"]   # zero-momentum pulse of Fig. 9')
    w("pulse_force_n = 1.4")
    return "\n".join(lines) + "\n"


def check_or_write(out: Path, text: str, check: bool) -> None:
    """Write ``text`` to ``out``, or with ``check`` exit 1 (first difference on stderr) when the file
    differs from it beyond CHECK_REL_TOL, exit 0 when it matches.  Shared by the config generators."""
    if not check:
        out.write_text(text)
        return
    diff = first_difference(text, out.read_text())
    if diff is not None:
        n, want, got = diff
        print(f"{out}:{n}: differs from what {Path(sys.argv[0]).name} renders\n"
              f"  rendered: {want}\n  in file:  {got}\n"
              f"(numbers are compared to a relative tolerance of {CHECK_REL_TOL:g}; "
              f"run python scripts/{Path(sys.argv[0]).name} to regenerate)", file=sys.stderr)
        sys.exit(1)
    sys.exit(0)


def report(p: TestbedParameters) -> str:
    """Per mode: Table 1, the model's frequency and the MAC with the named shape (where one is named)."""
    M, K = testbed_matrices(p)
    modes, ideal = model_modes(M, K), ideal_shapes()
    rows = [f"{n:10s} Table 1 {TABLE1[n][0]:.3f} Hz  model {modes[n][0]:.4f} Hz  "
            f"{100 * (modes[n][0] / TABLE1[n][0] - 1):+5.1f} %"
            + (f"  MAC {_mac(M, modes[n][1], ideal[n]):.4f}" if n in ideal else "") for n in ORDER[:-1]]
    ei, gj = tube_stiffness(p.wall_m)
    rows.append(f"EI {ei:.2f} N·m², GJ/L {gj / BEAM_L:.2f} N·m/rad, sag {tube_sag_m(p.wall_m) * 100:.2f} cm")
    return "\n".join(rows)


if __name__ == "__main__":
    root = Path(__file__).resolve().parent.parent / "configs"
    if "--fit" in sys.argv:
        p, res = fit_parameters(THREAD_L if "--threads-12m" in sys.argv else None)
        print(p, f"\nRMS log residual {np.sqrt(np.mean(res**2)):.4f}")
        print(report(p))
        sys.exit(0)
    if "--check" in sys.argv:
        bad = [out for out, lumped in ((root / "testbed-1998.toml", False), (root / "testbed-1998-lumped.toml", True))
               if first_difference(render(lumped), out.read_text()) is not None]
        for out in bad[1:]:
            print(f"{out}: differs from what make_testbed_config.py renders", file=sys.stderr)
        if bad:
            check_or_write(bad[0], render(bad[0].name.endswith("lumped.toml")), True)
        sys.exit(0)
    for out, lumped in ((root / "testbed-1998.toml", False), (root / "testbed-1998-lumped.toml", True)):
        check_or_write(out, render(lumped), False)
    print(report(FITTED))
