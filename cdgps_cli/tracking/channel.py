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

The per-update loop runs compiled (``cdgps_cli.tracking._trackcore.track``) or in Python (:func:`_run_numpy`,
the reference) on the same float64 state vector (:data:`STATE_FIELDS`), so a recording can be tracked
in pieces (:func:`run_updates`); C/N0 and lock windows are computed afterwards (:func:`outputs_dict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdgps_cli.config.options import TRACK_DEFAULTS
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.constants import GPS_L1_HZ
from cdgps_cli.tracking.ca_code import CHIP_RATE_HZ, CODE_LENGTH, ca_code
from cdgps_cli.tracking.correlator import _trackcore, correlate, kernel_available
from cdgps_cli.tracking.loops import LoopFilter

#: L1 carrier frequency (cdgps_cli.core.constants) and its ratio to the chip rate
L1_HZ = GPS_L1_HZ
CARRIER_PER_CHIP = L1_HZ / CHIP_RATE_HZ            # 1540
#: phase-lock indicator threshold (cos 2φ)
PHASE_LOCK_THRESHOLD = 0.8
#: updates per C/N0 and lock-indicator window (20 ms: one navigation bit)
WINDOW = 20


@dataclass(frozen=True)
class TrackOptions:
    """Loop settings: bandwidths (Hz), pull-in length (s), correlator spacing (chips), PLL order."""

    pll_bn_hz: float = TRACK_DEFAULTS["pll_bn_hz"]
    fll_bn_hz: float = 10.0
    dll_bn_hz: float = 1.0
    pull_in_s: float = TRACK_DEFAULTS["pull_in_s"]
    spacing_chips: float = 0.5
    pll_order: int = 2
    #: a PLL narrower than ``wide_pll_hz`` first runs at that bandwidth for this long after the FLL,
    #: then narrows (the integrator — the frequency — carries over): a narrow loop's pull-in range is
    #: smaller than the FLL's residual frequency error
    wide_pll_s: float = 0.1
    wide_pll_hz: float = 15.0

    def __post_init__(self):
        for name, (lo, hi, unit, what) in OPTION_RANGES.items():
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not (ok and (v > lo if name in OPEN_BELOW else v >= lo) and v <= hi):
                low = "(" if name in OPEN_BELOW else "["
                raise CdgpsError(f"{name} {v!r}: expected {what} in {low}{lo:g}, {hi:g}] {unit}")
        if self.pll_order not in (2, 3) or isinstance(self.pll_order, bool):
            raise CdgpsError(f"pll_order: expected 2 or 3, got {self.pll_order!r}")


#: valid ranges of :class:`TrackOptions` (low, high, unit, what): a loop bandwidth B_n must be positive
#: and small against the 1 kHz update rate (the discrete filters hold for B_n T ≪ 1); times are finite
OPTION_RANGES = {"pll_bn_hz": (0.0, 100.0, "Hz", "a PLL noise bandwidth"),
                 "fll_bn_hz": (0.0, 100.0, "Hz", "an FLL noise bandwidth"),
                 "dll_bn_hz": (0.0, 100.0, "Hz", "a DLL noise bandwidth"),
                 "wide_pll_hz": (0.0, 100.0, "Hz", "a PLL noise bandwidth"),
                 "pull_in_s": (0.0, 1e6, "s", "an FLL pull-in time"),
                 "wide_pll_s": (0.0, 1e6, "s", "a wide-PLL stage length"),
                 "spacing_chips": (0.0, 1.0, "chips", "an early-late correlator spacing")}
#: the ranges whose low end is excluded
OPEN_BELOW = ("pll_bn_hz", "fll_bn_hz", "dll_bn_hz", "wide_pll_hz", "spacing_chips")


def _m2m4_cn0(i: np.ndarray, q: np.ndarray, T: float) -> float:
    """C/N0 (dB-Hz) from prompt correlations by the second and fourth moments."""
    p = i * i + q * q
    m2, m4 = p.mean(), (p * p).mean()
    pd = math.sqrt(max(2 * m2 * m2 - m4, 0.0))
    pn = m2 - pd
    if pd <= 0 or pn <= 0:
        return float("nan")
    return 10 * math.log10(pd / pn / T)


#: per-channel loop state carried from one call of :func:`run_updates` to the next (float64 vector)
STATE_FIELDS = ("update", "f_carr_hz", "f_base_hz", "phase_cycles", "code_phase_chips", "prev_i", "prev_q",
                "pll_i1", "pll_i2", "pll_e1", "pll_y1")
#: per-update outputs (columns of :func:`run_updates`' array): block start time (s), NCO Doppler (Hz),
#: NCO carrier phase at the block start (cycles), code phase at the block start (chips, mod 1023),
#: prompt I and Q, 1 once the PLL runs, Costas discriminator atan(Q/I) (rad)
OUT_FIELDS = ("time_s", "doppler_hz", "carrier_phase_cycles", "code_phase_chips", "i_prompt", "q_prompt", "pll",
              "pll_error_rad")


def initial_state(doppler_hz: float, code_phase_chips: float) -> np.ndarray:
    """Loop state before the first update: NCO at the acquisition's Doppler (Hz) and code phase (chips)."""
    st = np.zeros(len(STATE_FIELDS))
    st[1] = st[2] = float(doppler_hz)
    st[4] = float(code_phase_chips)
    st[5] = st[6] = np.nan                                   # no previous prompt yet (the FLL waits one update)
    return st


def loop_params(opt: TrackOptions, fs_hz: float) -> np.ndarray:
    """Flat loop parameters shared by the numpy path and the kernel: samples per update, rate (Hz),
    FLL updates, update at which the PLL narrows (−1: never), first and final PLL B_n (Hz), PLL order,
    FLL and DLL B_n (Hz), correlator spacing (chips)."""
    n = int(round(fs_hz * 1e-3))
    T = n / fs_hz
    staged = opt.pll_bn_hz < opt.wide_pll_hz
    pull_in = int(round(opt.pull_in_s / T))
    narrow_at = int(round((opt.pull_in_s + opt.wide_pll_s) / T)) if staged else -1
    return np.array([n, fs_hz, pull_in, narrow_at, opt.wide_pll_hz if staged else opt.pll_bn_hz, opt.pll_bn_hz,
                     opt.pll_order, opt.fll_bn_hz, opt.dll_bn_hz, opt.spacing_chips], dtype=np.float64)


def run_updates(samples: np.ndarray, fs_hz: float, prn: int, state: np.ndarray, opt: TrackOptions | None = None,
                aid_doppler_hz=None) -> np.ndarray:
    """Run the channel over the whole 1 ms updates in ``samples``, continuing from ``state`` (updated in place).

    The compiled kernel when available (``cdgps_cli.tracking._trackcore.track``), else :func:`_run_numpy` (the
    reference; the two are tested equal).  ``samples`` start at the block of update ``state[0]``, so a long
    recording can be tracked in pieces.

    Returns
    -------
    ndarray, shape (m, len(OUT_FIELDS))
    """
    opt = TrackOptions() if opt is None else opt
    if opt.pll_order not in (2, 3):
        raise CdgpsError(f"pll_order: expected 2 or 3, got {opt.pll_order!r}")
    par = loop_params(opt, fs_hz)
    n = int(par[0])
    x = np.ascontiguousarray(samples, dtype=np.complex128)
    m = x.size // n
    aid = np.zeros(m) if aid_doppler_hz is None else np.ascontiguousarray(aid_doppler_hz, dtype=np.float64)
    if aid.shape != (m,):
        raise CdgpsError(f"aid_doppler_hz: expected one value per 1 ms update ({m}), got shape {aid.shape}")
    if not (isinstance(state, np.ndarray) and state.dtype == np.float64 and state.shape == (len(STATE_FIELDS),)):
        raise CdgpsError(f"state: expected a float64 vector of {len(STATE_FIELDS)} (initial_state), got {state!r}")
    code = ca_code(prn)
    out = np.zeros((m, len(OUT_FIELDS)))
    if kernel_available():
        _trackcore.track(x, code, state, par, aid, out, x.size, m)
    else:
        _run_numpy(x, code, state, par, aid, out)
    return out


def _run_numpy(x, code, st, par, aid, out) -> None:
    """The per-update loop in Python (reference of the kernel): correlate, carrier loop, code loop, NCOs."""
    n, fs_hz, pull_in, narrow_at = int(par[0]), par[1], int(par[2]), int(par[3])
    bn_first, bn_final, order, fll_bn, dll_bn, spacing = par[4], par[5], int(par[6]), par[7], par[8], par[9]
    T = n / fs_hz
    half = spacing / 2.0
    pll = LoopFilter(bn_first, T, order=order)
    pll._i1, pll._i2, pll._e1, pll._y1 = st[7:11]
    fll = LoopFilter(fll_bn, T, order=1)
    dll = LoopFilter(dll_bn, T, order=1)
    for j in range(out.shape[0]):
        k = int(st[0])
        f_now = st[1] + aid[j]
        code_rate = CHIP_RATE_HZ * (1.0 + f_now / L1_HZ)
        e, p, late = correlate(x[j * n:(j + 1) * n], code, st[3], f_now, fs_hz, st[4], code_rate, half)
        err = math.atan(p.imag / p.real) if p.real != 0 else 0.0
        out[j] = (k * T, f_now, st[3], st[4] % CODE_LENGTH, p.real, p.imag, k >= pull_in, err)
        st[3] += f_now * T
        st[4] += code_rate * T
        if k < pull_in:
            fll_step(st, p, fll, T)
        else:
            pll.bn_hz = bn_final if 0 <= narrow_at <= k else bn_first
            st[1] = st[2] + pll.update(err) / (2 * math.pi)
        st[5], st[6] = p.real, p.imag
        dll_step(st, e, late, dll, spacing, T)
        st[0] = k + 1
    st[7:11] = pll._i1, pll._i2, pll._e1, pll._y1


def fll_step(st: np.ndarray, p: complex, fll: LoopFilter, T: float) -> None:
    """FLL pull-in update of the state: atan(cross/dot)/(2πT) between the previous prompt and ``p``."""
    if not math.isnan(st[5]):
        cross = st[5] * p.imag - st[6] * p.real
        dot = st[5] * p.real + st[6] * p.imag
        st[1] += fll.update(math.atan(cross / dot) / (2 * math.pi * T) if dot != 0 else 0.0) * T
    st[2] = st[1]


def dll_step(st: np.ndarray, early: complex, late: complex, dll: LoopFilter, spacing: float, T: float) -> None:
    """DLL update of the code phase: normalized early-minus-late envelope through the (first-order) loop."""
    ea, la = abs(early), abs(late)
    if ea + la > 0:
        st[4] += dll.update((ea - la) / (ea + la) * (2.0 - spacing) / 2.0) * T


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
    ``i_prompt``, ``q_prompt``, ``pll_error_rad`` (Costas discriminator), ``cn0_dbhz`` and ``phase_lock``
    (per 20 ms window, repeated), ``pll`` (True once the PLL runs).
    """
    opt = TrackOptions() if opt is None else opt
    arr = run_updates(samples, fs_hz, prn, initial_state(doppler_hz, code_phase_chips), opt, aid_doppler_hz)
    return outputs_dict(arr, fs_hz)


def outputs_dict(arr: np.ndarray, fs_hz: float) -> dict:
    """The per-update array of :func:`run_updates` as named columns, plus C/N0 and lock per 20 ms window."""
    out = {k: np.ascontiguousarray(arr[:, i]) for i, k in enumerate(OUT_FIELDS)}
    out["pll"] = out["pll"] > 0.5
    out["cn0_dbhz"], out["phase_lock"] = np.zeros(arr.shape[0]), np.zeros(arr.shape[0])
    _windows(out, int(round(fs_hz * 1e-3)) / fs_hz)
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
