"""One GPS L1 C/A tracking channel: FLL pull-in, Costas PLL, carrier-aided DLL, C/N0 and lock.

Per update (one 1 ms block of samples, not aligned to the code epoch):

* wipe off the carrier NCO, correlate with early, prompt and late code replicas (±``spacing_chips``/2);
* carrier: FLL discriminator atan(cross/dot)/(2πT) (insensitive to data bits) during pull-in, then the
  Costas discriminator atan(Q_P/I_P) (rad) through the PLL loop filter; the NCO phase is the carrier
  phase measurement (cycles; Costas leaves a half-cycle ambiguity resolved by the data);
* code: normalized early-minus-late envelope (|E| − |L|)/(|E| + |L|) (chips, times (2 − d)/2 for
  spacing d) through a first-order DLL, aided by the carrier: code rate = f_chip (1 + f_D / f_L1), i.e.
  1/1540 of the carrier Doppler;
* C/N0 by the moments method (M2M4) over 20 ms of prompt correlations; phase-lock indicator
  cos 2φ = (ΣI² − ΣQ²)/(ΣI² + ΣQ²) over the same 20 ms (lock above 0.8).

An optional external Doppler aid (Hz per update) is added to the carrier NCO before the PLL's own
correction (Alban et al. 2003, Fig. 2): the PLL then tracks only the aiding error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, CODE_LENGTH, ca_code
from cdgps_cli.tracking.correlator import correlate
from cdgps_cli.tracking.loops import LoopFilter

#: L1 carrier frequency and its ratio to the chip rate
L1_HZ = 1575.42e6
CARRIER_PER_CHIP = L1_HZ / CHIP_RATE_HZ            # 1540
#: phase-lock indicator threshold (cos 2φ)
PHASE_LOCK_THRESHOLD = 0.8
#: updates per C/N0 and lock-indicator window (20 ms: one navigation bit)
WINDOW = 20


@dataclass(frozen=True)
class TrackOptions:
    """Loop settings: bandwidths (Hz), pull-in length (s), correlator spacing (chips), PLL order."""

    pll_bn_hz: float = 15.0
    fll_bn_hz: float = 10.0
    dll_bn_hz: float = 1.0
    pull_in_s: float = 0.1
    spacing_chips: float = 0.5
    pll_order: int = 2
    #: a PLL narrower than ``wide_pll_hz`` first runs at that bandwidth for this long after the FLL,
    #: then narrows (the integrator — the frequency — carries over): a narrow loop's pull-in range is
    #: smaller than the FLL's residual frequency error
    wide_pll_s: float = 0.1
    wide_pll_hz: float = 15.0


def _m2m4_cn0(i: np.ndarray, q: np.ndarray, T: float) -> float:
    """C/N0 (dB-Hz) from prompt correlations by the second and fourth moments."""
    p = i * i + q * q
    m2, m4 = p.mean(), (p * p).mean()
    pd = math.sqrt(max(2 * m2 * m2 - m4, 0.0))
    pn = m2 - pd
    if pd <= 0 or pn <= 0:
        return float("nan")
    return 10 * math.log10(pd / pn / T)


def track(samples: np.ndarray, fs_hz: float, prn: int, doppler_hz: float, code_phase_chips: float,
          opt: TrackOptions | None = None, aid_doppler_hz=None) -> dict:
    """Track one satellite through ``samples`` starting from an acquisition.

    Parameters
    ----------
    samples : ndarray, complex, shape (N,)
        Complex baseband samples.
    fs_hz : float
    prn : int
    doppler_hz, code_phase_chips : float
        Initial carrier Doppler (Hz) and code phase at the first sample (chips).
    opt : TrackOptions, optional
    aid_doppler_hz : ndarray, shape (n_updates,), optional
        External Doppler estimate per 1 ms update (Hz), fed forward to the carrier NCO.

    Returns
    -------
    dict of arrays, one entry per 1 ms update: ``time_s`` (block start), ``doppler_hz``,
    ``carrier_phase_cycles`` (NCO phase at the block start), ``code_phase_chips`` (at the block start),
    ``i_prompt``, ``q_prompt``, ``cn0_dbhz`` and ``phase_lock`` (per 20 ms window, repeated), ``pll``
    (True once the PLL runs).
    """
    opt = TrackOptions() if opt is None else opt
    n = int(round(fs_hz * 1e-3))
    T = n / fs_hz
    m = samples.size // n
    code = ca_code(prn)
    staged = opt.pll_bn_hz < opt.wide_pll_hz
    pll = LoopFilter(opt.wide_pll_hz if staged else opt.pll_bn_hz, T, order=opt.pll_order)
    narrow_at = int(round((opt.pull_in_s + opt.wide_pll_s) / T)) if staged else 0
    fll = LoopFilter(opt.fll_bn_hz, T, order=1)
    dll = LoopFilter(opt.dll_bn_hz, T, order=1)
    out = {k: np.zeros(m) for k in ("time_s", "doppler_hz", "carrier_phase_cycles", "code_phase_chips",
                                    "i_prompt", "q_prompt", "cn0_dbhz", "phase_lock")}
    out["pll"] = np.zeros(m, dtype=bool)
    f_carr, phase_cyc, code_phase = float(doppler_hz), 0.0, float(code_phase_chips)
    f_base = f_carr                                   # frequency the PLL corrects around
    prev = None
    half = opt.spacing_chips / 2.0
    pull_in = int(round(opt.pull_in_s / T))
    for k in range(m):
        x = samples[k * n:(k + 1) * n]
        aid = 0.0 if aid_doppler_hz is None else float(aid_doppler_hz[k])
        f_now = f_carr + aid
        code_rate = CHIP_RATE_HZ * (1.0 + f_now / L1_HZ)
        e, p, late = correlate(x, code, phase_cyc, f_now, fs_hz, code_phase, code_rate, half)
        out["time_s"][k], out["doppler_hz"][k] = k * T, f_now
        out["carrier_phase_cycles"][k], out["code_phase_chips"][k] = phase_cyc, code_phase % CODE_LENGTH
        out["i_prompt"][k], out["q_prompt"][k] = p.real, p.imag
        phase_cyc += f_now * T
        code_phase += code_rate * T
        # carrier loop
        if k < pull_in:
            if prev is not None:
                cross = prev.real * p.imag - prev.imag * p.real
                dot = prev.real * p.real + prev.imag * p.imag
                f_carr += fll.update(math.atan(cross / dot) / (2 * math.pi * T) if dot != 0 else 0.0) * T
            f_base = f_carr
        else:
            out["pll"][k] = True
            if staged and k == narrow_at:
                pll.bn_hz = opt.pll_bn_hz
            err = math.atan(p.imag / p.real) if p.real != 0 else 0.0
            f_carr = f_base + pll.update(err) / (2 * math.pi)
        prev = p
        # code loop (chips): positive when the replica is early... E > L means the replica lags
        ea, la = abs(e), abs(late)
        if ea + la > 0:
            code_phase += dll.update((ea - la) / (ea + la) * (2.0 - opt.spacing_chips) / 2.0) * T
    _windows(out, T)
    return out


def _windows(out: dict, T: float) -> None:
    """C/N0 and phase-lock indicator per 20 ms window, written to every update of the window."""
    i, q = out["i_prompt"], out["q_prompt"]
    for s in range(0, len(i), WINDOW):
        sl = slice(s, min(s + WINDOW, len(i)))
        ii, qq = i[sl], q[sl]
        out["cn0_dbhz"][sl] = _m2m4_cn0(ii, qq, T) if ii.size >= 4 else np.nan
        den = np.sum(ii * ii + qq * qq)
        out["phase_lock"][sl] = np.sum(ii * ii - qq * qq) / den if den > 0 else np.nan
