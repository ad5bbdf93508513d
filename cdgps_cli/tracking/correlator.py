"""Early, prompt and late correlations of one block of samples: the compiled kernel
(``cdgps_cli.tracking._trackcore``) when it is built, else numpy (same sums; tested against each other).

Each correlation is Σ_k x_k e^{−j2π(φ + f_D t_k)} c(θ + r t_k + δ) over the block, t_k = k/f_s, with
δ = +half (early), 0 (prompt), −half (late) chips.
"""

from __future__ import annotations

import os

import numpy as np

from cdgps_cli.tracking.ca_code import CODE_LENGTH

try:
    from cdgps_cli.tracking import _trackcore
except ImportError:                     # optional extension not built
    _trackcore = None


def kernel_available() -> bool:
    """True when the compiled correlator is importable and not disabled by CDGPS_NO_KERNEL."""
    if os.environ.get("CDGPS_NO_KERNEL", "") not in ("", "0"):      # the rule of cdgps_cli.estimation.kernel.available
        return False
    return _trackcore is not None and getattr(_trackcore, "API", None) == 2


def correlate_numpy(x, code, phase_cycles, doppler_hz, fs_hz, code_phase_chips, code_rate_hz, half_chips):
    """(E, P, L) complex correlations, numpy."""
    t = np.arange(x.size) / fs_hz
    base = x * np.exp(-2j * np.pi * (phase_cycles + doppler_hz * t))
    chips = code_phase_chips + t * code_rate_hz
    c = code.astype(np.float64)
    return tuple(base @ c[np.floor(chips + d).astype(np.int64) % CODE_LENGTH] for d in (half_chips, 0.0, -half_chips))


def correlate(x, code, phase_cycles, doppler_hz, fs_hz, code_phase_chips, code_rate_hz, half_chips):
    """(E, P, L) complex correlations of the block ``x`` (complex128) with the ±1 ``code`` (int8, 1023)."""
    if not kernel_available():
        return correlate_numpy(x, code, phase_cycles, doppler_hz, fs_hz, code_phase_chips, code_rate_hz, half_chips)
    out = np.empty(6)
    _trackcore.correlate(np.ascontiguousarray(x, dtype=np.complex128), np.ascontiguousarray(code, dtype=np.int8), out,
                         x.size, float(phase_cycles), float(doppler_hz), float(fs_hz), float(code_phase_chips),
                         float(code_rate_hz), float(half_chips))
    return complex(out[0], out[1]), complex(out[2], out[3]), complex(out[4], out[5])
