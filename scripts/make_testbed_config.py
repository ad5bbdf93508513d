#!/usr/bin/env python3
"""Write configs/testbed-1998.toml: the 1998 Stanford testbed (Teague, How & Parkinson 1998).

The paper's mode shapes came from NASTRAN and are not published; this script derives physically
plausible ones from a lumped mass/stiffness model of the testbed and then imposes Table 1's
measured frequencies and time constants, as the paper did with its analytic model.

Lumped model (body frame B: x along the structure, y horizontal, z up)
----------------------------------------------------------------------
* Three rigid sections C1, C2, C3 (60 kg each, 180 kg total) at x = -4, 0, +4 m, each with a
  lateral translation y (q1, q4, q7), a twist about x (q2, q5, q8) and a rotation about the
  vertical z (q3, q6, q9).  Section inertias I_xx = I_zz = 6 kg·m² (a 25 cm aluminium cube with two
  1 m iron arms).
* Two elastic beams (aluminium tube, 12.7 mm OD, 1 mm wall, E = 70 GPa, G = 26 GPa, 3.7 m long)
  clamped to the facing sides of adjacent sections (0.15 m from the section centres): Euler-
  Bernoulli bending stiffness in the horizontal plane (couples y and z-rotation) and torsion
  (couples the twists).
* Suspension: 12 m threads attached just above each centre of mass (1.5 mm): pendulum stiffness
  m·g/L on y, gravity stiffness m·g·h on the twist.  The threads hang from a beam on a thrust
  bearing, so a rotation of the whole assembly about the vertical is free: that motion is the
  rigid-body coordinate q10, and the elastic modes are computed on the mass-orthogonal complement of
  it (q1..q9 stay small in B).
* Generalized eigenproblem K v = ω² M v on that 8-dimensional subspace → 8 elastic modes,
  mass-normalized (Uᵀ M U = I), signs fixed so the largest component is positive.  Modes are named
  after their character (the twist subsystem gives the pendulum/roll mode and two twist modes, the
  lateral subsystem the swing mode and four bending modes) and given Table 1's frequency and time
  constant.  The rigid-body mode is q10 = ξ9 / sqrt(I_total).

Run ``python scripts/make_testbed_config.py`` to regenerate; tests check the file matches.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np
import scipy.linalg

G0 = 9.80665
X_SECTIONS = np.array([-4.0, 0.0, 4.0])
MASS_KG = 60.0
I_XX = 6.0
I_ZZ = 6.0
ARM_M = 1.0
BEAM_L = 3.7
BEAM_OFFSET = 0.15
E_AL, G_AL = 70e9, 26e9
OD, WALL = 0.0127, 0.001
THREAD_L = 12.0
THREAD_H = 0.0015

# Table 1 of the paper: (name, frequency_hz, time_constant_s)
TABLE1 = {
    "pendulum": (0.059, 20.0), "swing": (0.160, 130.0), "bending-1": (0.132, 200.0),
    "twist-1": (0.085, 45.0), "twist-2": (0.138, 35.0), "bending-2": (0.135, 140.0),
    "bending-3": (0.23, 50.0), "bending-4": (0.28, 25.0), "rigid-body": (0.0, 140.0),
}
ORDER = ["pendulum", "swing", "bending-1", "twist-1", "twist-2", "bending-2", "bending-3",
         "bending-4", "rigid-body"]


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


def render() -> str:
    names, M = elastic_modes()
    izz_total = 3 * I_ZZ + MASS_KG * float(np.sum(X_SECTIONS**2))
    lines = []
    w = lines.append
    w("# Teague, How & Parkinson (1998): the 8 m, 180 kg Stanford flexible-structure testbed.")
    w("# GENERATED by scripts/make_testbed_config.py (lumped model → mode shapes, Table 1 frequencies);")
    w("# edit the script, not this file.  Format: docs/config-format.md.")
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
            fl, v, _ = names[name]
            w(f"# lumped-model frequency {fl:.4f} Hz")
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


if __name__ == "__main__":
    out = Path(__file__).resolve().parent.parent / "configs" / "testbed-1998.toml"
    text = render()
    check_or_write(out, text, "--check" in sys.argv)
    names, _ = elastic_modes()
    for n in ORDER[:-1]:
        print(f"{n:10s} lumped {names[n][0]:.4f} Hz -> Table 1 {TABLE1[n][0]} Hz")
