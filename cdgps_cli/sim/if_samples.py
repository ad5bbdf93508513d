"""Simulated GPS L1 C/A front-end samples for antennas on a moving structure (issue 16 item 4).

Signal of transmitter j at antenna a, complex baseband, at receiver time t (s):

    s_aj(t) = A_j · d_j(χ_aj) · c_j(χ_aj) · exp(j2π φ_aj(t))
    χ_aj(t) = χ0_j + f_chip (1 + δf_j / f_L1) (t − τ_aj(t))            emitted chip count
    φ_aj(t) = φ0_j + δf_j t − (f_L1 + δf_j) τ_aj(t)                     carrier phase, cycles
    τ_aj(t) = (ρ_aj(t) + ℓ_a) / c + δt(t)                               delay, s

with ρ the line-of-sight range |p_j − p_a(t)| (near field, a pseudolite at p_j) or −s_jᵀ p_a(t) (far
field, a source in unit direction s_j), ℓ_a the antenna's line bias (its cable), δt the receiver
clock's time error — one oscillator shared by every antenna of the structure, so that it cancels in
the single difference antenna − master —, δf_j the transmitter's frequency offset (its clock, or a
satellite's motion), d_j the 50 bit/s navigation data (one bit per 20 code periods; the same bits
reach every antenna), c_j the ±1 C/A code and A_j the amplitude giving C/N0_j against the thermal
noise.  The sum over transmitters (times e^{j2π f_IF t} at an IF), plus complex white noise of unit
variance per component, is quantized and written as int8 I, Q pairs: the ``int8-iq`` format that
``cdgps track`` reads (``iq_sign`` ``minus`` writes Q = −Im, read back as I − jQ).

τ and φ are computed on a grid of knots every :data:`KNOT_S` (1 ms) and linearly interpolated
between them: a range with acceleration a is then off by at most a·(1 ms)²/8 (1.2e-7 m at 1 m/s²),
and the oscillator's phase noise above 500 Hz is left out.  Everything per sample is vectorized over
blocks of :attr:`IfOptions.block_s`.  Same inputs and seed → byte-identical files.

The spreading codes are an argument (``codes``: PRN → 1023 chips ±1): this module sits below the
tracking package in the layer order and does not import it; :mod:`cdgps_cli.pipeline.if_chain`
passes :func:`cdgps_cli.tracking.ca_code.ca_code`.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from cdgps_cli.io.atomic import output_set, write_atomic
from cdgps_cli.io.sim_truth import read_truth_folder, truth_coordinates
from cdgps_cli.config.structure import StructureConfig
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.model.kinematics import antenna_positions

C_M_S = 299792458.0
L1_HZ = 1575.42e6
CHIP_RATE_HZ = 1.023e6
CODE_LENGTH = 1023
#: chips per navigation bit: 20 code periods (50 bit/s)
CHIPS_PER_BIT = 20 * CODE_LENGTH
#: spacing of the knots on which delays and phases are computed, s
KNOT_S = 1e-3
#: quantizer step per bit count, in units of the noise σ per component: Max's (1960) optimum
#: uniform steps for 4, 8, 16 and 32 levels (1 bit: any step, the sign); from 6 bits a full scale of ±4σ
QUANTIZER_STEP = {1: 1.0, 2: 0.9957, 3: 0.5860, 4: 0.3352, 5: 0.1881, 6: 8 / 64, 7: 8 / 128, 8: 8 / 256}
#: sample rates accepted (acquisition needs at least 2.1 samples per chip), Hz
FS_RANGE_HZ = (2.1e6, 1e8)
#: C/N0 accepted, dB-Hz
CN0_RANGE_DBHZ = (10.0, 80.0)
#: largest total size of the sample files one call may write, bytes
MAX_FILE_BYTES = 16 * 2**30
MANIFEST = "if.json"
MANIFEST_FORMAT = "cdgps-if-samples/1"


@dataclass(frozen=True)
class Transmitter:
    """One GPS L1 C/A transmitter (a pseudolite or a satellite)."""

    name: str
    prn: int
    position_m: tuple                   # near field: position (m); far field: unit direction to the source
    far_field: bool = False
    cn0_dbhz: float = 45.0
    frequency_offset_hz: float = 0.0    # carrier frequency offset δf_j (its clock; a satellite's motion), Hz
    code_offset_chips: float = CHIPS_PER_BIT   # χ0_j: chip count at emission time 0 (≥ one bit: counts stay positive)
    carrier_phase_cycles: float = 0.0   # φ0_j


@dataclass(frozen=True)
class Oscillator:
    """Receiver oscillator: fractional-frequency PSD S_y(f) = h0 + h_minus1/f + h_minus2/f² (one-sided;
    h0 in s, h_minus1 dimensionless, h_minus2 in 1/s) and a constant fractional frequency offset."""

    h0: float = 0.0
    h_minus1: float = 0.0
    h_minus2: float = 0.0
    frequency_offset: float = 0.0

    def check(self) -> None:
        for k, v in asdict(self).items():
            if not (isinstance(v, (int, float)) and math.isfinite(v)) or (k != "frequency_offset" and v < 0):
                raise CdgpsError(f"oscillator {k}: expected a finite{' non-negative' if k != 'frequency_offset' else ''} "
                                 f"number, got {v!r}")
        if abs(self.frequency_offset) > 1e-4:
            raise CdgpsError(f"oscillator frequency_offset {self.frequency_offset!r}: expected at most 1e-4 (100 ppm)")


@dataclass(frozen=True)
class IfOptions:
    """Front end: sample rate and IF (Hz), quantizer bits (1–8), I/Q sign convention, seed, block length (s)."""

    fs_hz: float = 4e6
    if_hz: float = 0.0
    bits: int = 8
    iq_sign: str = "minus"
    seed: int = 0
    block_s: float = 0.05

    def check(self) -> None:
        lo, hi = FS_RANGE_HZ
        if not (isinstance(self.fs_hz, (int, float)) and lo <= self.fs_hz <= hi):
            raise CdgpsError(f"fs_hz {self.fs_hz!r}: expected a sample rate between {lo:g} and {hi:g} Hz")
        if not (isinstance(self.if_hz, (int, float)) and abs(self.if_hz) < self.fs_hz / 2 - CHIP_RATE_HZ):
            raise CdgpsError(f"if_hz {self.if_hz!r}: expected |IF| + 1.023 MHz below half the sample rate")
        if self.bits not in QUANTIZER_STEP or isinstance(self.bits, bool):
            raise CdgpsError(f"bits {self.bits!r}: expected an integer from 1 to 8")
        if self.iq_sign not in ("minus", "plus"):
            raise CdgpsError(f"iq_sign {self.iq_sign!r}: expected 'minus' or 'plus'")
        if abs(self.fs_hz * KNOT_S - round(self.fs_hz * KNOT_S)) > 1e-6:
            raise CdgpsError(f"fs_hz {self.fs_hz!r}: expected a whole number of samples per millisecond")
        if not (isinstance(self.block_s, (int, float)) and 1e-3 <= self.block_s <= 1.0):
            raise CdgpsError(f"block_s {self.block_s!r}: expected 0.001 to 1 s")


# ---------------------------------------------------------------------------------------------
# oscillator


def clock_error_s(osc: Oscillator, n: int, step_s: float, rng: np.random.Generator) -> np.ndarray:
    """Receiver clock time error δt (s) at t_k = k·step_s, k = 0 … n−1, with δt(0) = 0.

    The fractional frequency y is a sum of independent power-law noises sampled at ``step_s``
    (Kasdin & Walter 1992): white FM, variance h0/(2 step); flicker FM, white noise of variance
    π·h_minus1 through the filter (1 − z⁻¹)^(−1/2) (impulse response g_k = g_{k−1}(k − ½)/k);
    random-walk FM, increments of variance 2π²·h_minus2·step.  δt = frequency_offset·t + Σ y·step.
    Allan variances: h0/(2τ), 2 ln 2·h_minus1 and (2π²/3)·h_minus2·τ (tested).
    """
    osc.check()
    y = np.zeros(n)
    if osc.h0 > 0:
        y += rng.standard_normal(n) * math.sqrt(osc.h0 / (2 * step_s))
    if osc.h_minus1 > 0:
        from scipy.signal import fftconvolve

        g = np.cumprod(np.r_[1.0, (np.arange(1, n) - 0.5) / np.arange(1, n)])
        y += fftconvolve(rng.standard_normal(n) * math.sqrt(math.pi * osc.h_minus1), g)[:n]
    if osc.h_minus2 > 0:
        y += np.cumsum(rng.standard_normal(n) * math.sqrt(2 * math.pi**2 * osc.h_minus2 * step_s))
    x = np.r_[0.0, np.cumsum(y[:-1]) * step_s]
    return x + osc.frequency_offset * step_s * np.arange(n)


# ---------------------------------------------------------------------------------------------
# knots: delays, phases and chip counts on the 1 ms grid


def line_of_sight_range_m(tx: Transmitter, positions_m: np.ndarray) -> np.ndarray:
    """Range (m) from antenna positions (..., 3) to ``tx``: |p_j − p| near field, −s_jᵀ p far field."""
    p = np.asarray(tx.position_m, dtype=float)
    if tx.far_field:
        return -positions_m @ p
    return np.linalg.norm(p - positions_m, axis=-1)


def knot_phases(tx: Transmitter, delay_s: np.ndarray, knot_s: float = KNOT_S) -> tuple[np.ndarray, np.ndarray]:
    """(carrier phase φ in cycles, emitted chip count χ) at the knots t_k = k·knot_s of the delays τ_k (s)."""
    t = np.arange(delay_s.size) * knot_s
    phase = tx.carrier_phase_cycles + tx.frequency_offset_hz * t - (L1_HZ + tx.frequency_offset_hz) * delay_s
    chips = tx.code_offset_chips + CHIP_RATE_HZ * (1 + tx.frequency_offset_hz / L1_HZ) * (t - delay_s)
    return phase, chips


def navigation_bits(seed: int, index: int, count: int) -> np.ndarray:
    """``count`` ±1 navigation bits of transmitter ``index`` (int8; the same at every antenna)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2, int(index)]))
    return (1 - 2 * rng.integers(0, 2, count)).astype(np.int8)


def amplitude(cn0_dbhz: float, fs_hz: float) -> float:
    """Carrier amplitude for C/N0 against complex noise of unit variance per component: N0 = 2/fs."""
    return math.sqrt(10 ** (cn0_dbhz / 10) * 2.0 / fs_hz)


def quantize(x: np.ndarray, bits: int) -> np.ndarray:
    """int8 of ``x`` (noise σ = 1): up to 7 bits mid-rise on the odd levels ±1, ±3, …, ±(2^bits − 1);
    8 bits mid-tread on −127 … 127; steps :data:`QUANTIZER_STEP`."""
    step = QUANTIZER_STEP[bits]
    if bits == 8:
        return np.clip(np.rint(x / step), -127, 127).astype(np.int8)
    half = 2 ** (bits - 1)
    return (2 * np.clip(np.floor(x / step), -half, half - 1) + 1).astype(np.int8)


@dataclass
class _Channel:
    """One transmitter at one antenna, per knot: carrier phase (fractional base + increment over the
    knot, float32: at most a few cycles, sin/cos good to 1e-6 rad) and chip count (float64, full)."""

    phase_base: np.ndarray
    phase_step: np.ndarray
    chip_base: np.ndarray
    chip_step: np.ndarray
    code: np.ndarray           # (1023,) float32 chips ±1, times the amplitude
    bits: np.ndarray           # (n_bits,) float32 navigation bits ±1


def _channel(tx: Transmitter, delay_s: np.ndarray, code: np.ndarray, bits: np.ndarray, opt: IfOptions) -> _Channel:
    phase, chips = knot_phases(tx, delay_s)
    phase = phase + opt.if_hz * KNOT_S * np.arange(phase.size)          # at the IF
    if chips.min() < 0 or chips.max() >= CHIPS_PER_BIT * bits.size:
        raise CdgpsError(f"transmitter {tx.name}: code_offset_chips {tx.code_offset_chips:g}: expected 0 to "
                         f"{2 * CHIPS_PER_BIT} chips more than the largest delay ({delay_s.max():.3g} s)")
    return _Channel((phase - np.floor(phase)).astype(np.float32), np.diff(phase).astype(np.float32), chips,
                    np.diff(chips), (np.asarray(code) * amplitude(tx.cn0_dbhz, opt.fs_hz)).astype(np.float32),
                    bits.astype(np.float32))


def _block(chans: list, k0: int, k1: int, spk: int, opt: IfOptions, rng: np.random.Generator) -> np.ndarray:
    """Interleaved int8 I, Q of the samples of knots k0 … k1−1 (``spk`` samples per knot)."""
    nk = k1 - k0
    u32 = (np.arange(spk) / spk).astype(np.float32)
    z = rng.standard_normal((nk, spk, 2), dtype=np.float32)          # one stream, whatever the blocking
    re, im = z[..., 0], z[..., 1]
    two_pi = np.float32(2 * np.pi)
    # per channel, the same float32 operations as written out (each result computed once, in buffers
    # reused from channel to channel: the same values, fewer allocations)
    ang = np.empty((nk, spk), dtype=np.float32)
    tmp = np.empty((nk, spk), dtype=np.float32)
    a = np.empty((nk, spk), dtype=np.float32)
    idx = np.empty((nk, spk), dtype=np.int32)
    for ch in chans:
        np.multiply(ch.phase_step[k0:k1, None], u32, out=ang)
        np.add(ch.phase_base[k0:k1, None], ang, out=ang)
        np.multiply(two_pi, ang, out=ang)
        # chip index = whole chips at the knot + floor(fraction + increment), the latter in float32 (< 1100
        # chips: 1e-4 chip), counts relative to the first navigation bit of the block
        base = ch.chip_base[k0:k1]
        whole = np.floor(base)
        b0 = int(whole[0]) // CHIPS_PER_BIT
        b1 = int(base[-1] + ch.chip_step[k1 - 1]) // CHIPS_PER_BIT + 1
        np.multiply(ch.chip_step[k0:k1].astype(np.float32)[:, None], u32, out=tmp)
        np.add((base - whole).astype(np.float32)[:, None], tmp, out=tmp)
        idx[...] = tmp                                                  # float32 → int32 (truncation, as astype)
        idx += (whole - b0 * CHIPS_PER_BIT).astype(np.int32)[:, None]
        table = np.tile(ch.code, 20 * (b1 - b0)) * np.repeat(ch.bits[b0:b1], CHIPS_PER_BIT)
        np.take(table, idx, out=a)
        np.cos(ang, out=tmp)
        tmp *= a
        re += tmp
        np.sin(ang, out=tmp)
        tmp *= a
        im += tmp
    out = np.empty(2 * re.size, dtype=np.int8)
    out[0::2] = quantize(re.ravel(), opt.bits)
    out[1::2] = quantize((im if opt.iq_sign == "plus" else -im).ravel(), opt.bits)
    return out


def antenna_blocks(delay_s: np.ndarray, transmitters: list, codes: dict, n_samples: int, opt: IfOptions,
                   noise_rng: np.random.Generator):
    """Yield the interleaved int8 I, Q samples of one antenna (2 bytes per sample), block by block.

    Parameters
    ----------
    delay_s : ndarray, shape (K, J)
        τ_aj at the knots k·KNOT_S (s), covering the samples: (K − 1)·KNOT_S ≥ n_samples / fs.
    transmitters : list of Transmitter, length J
    codes : dict
        PRN → 1023 chips ±1.
    n_samples : int
    opt : IfOptions
    noise_rng : numpy Generator
        Thermal noise of this antenna.
    """
    opt.check()
    spk = int(round(opt.fs_hz * KNOT_S))
    n_knots = -(-int(n_samples) // spk)
    if delay_s.ndim != 2 or delay_s.shape[1] != len(transmitters) or delay_s.shape[0] < n_knots + 1:
        raise CdgpsError(f"delay knots: expected shape (≥ {n_knots + 1}, {len(transmitters)}), got {delay_s.shape}")
    n_bits = int(np.ceil(n_samples / opt.fs_hz / 0.02)) + 3
    chans = [_channel(tx, delay_s[:, j], codes[tx.prn], navigation_bits(opt.seed, j, n_bits), opt)
             for j, tx in enumerate(transmitters)]
    step = max(int(round(opt.block_s / KNOT_S)), 1)
    for k0 in range(0, n_knots, step):
        k1 = min(k0 + step, n_knots)
        blk = _block(chans, k0, k1, spk, opt, noise_rng)
        yield blk[: 2 * (min(k1 * spk, n_samples) - k0 * spk)]


def truth_at(tx: Transmitter, delay_s: np.ndarray, time_s: np.ndarray) -> dict:
    """The signal of ``tx`` at receiver times ``time_s`` (s from the first sample), from its knot delays:
    ``carrier_phase_cycles`` (φ, baseband, unwrapped), ``doppler_hz`` (dφ/dt), ``code_phase_chips``
    (χ mod 1023: the replica's code phase at that time), ``bit`` (index of the navigation bit)."""
    phase, chips = knot_phases(tx, delay_s)
    kf = np.asarray(time_s, dtype=float) / KNOT_S
    k = np.clip(np.floor(kf).astype(np.int64), 0, delay_s.size - 2)
    u = kf - k
    dph = np.diff(phase)
    ch = chips[k] + np.diff(chips)[k] * u
    return {"carrier_phase_cycles": phase[k] + dph[k] * u, "doppler_hz": dph[k] / KNOT_S,
            "code_phase_chips": ch % CODE_LENGTH, "bit": np.floor(ch / CHIPS_PER_BIT).astype(np.int64)}


# ---------------------------------------------------------------------------------------------
# a structure simulated by `cdgps simulate`


def read_structure_truth(sim_dir: str | Path, cfg: StructureConfig) -> tuple[np.ndarray, np.ndarray]:
    """(time_s (N,), q (N, n_q)) of a ``cdgps simulate`` folder (truth.csv, truth.json) of ``cfg``."""
    sim = read_truth_folder(sim_dir)
    if sim.info.get("config_sha256") != cfg.sha256:
        raise CdgpsError(f"{sim.json_path}: simulated with another config than {cfg.path} (config_sha256 differs)")
    truth = truth_coordinates(sim, cfg)                  # q1_rad, or a bare q1 (files before issue 32)
    t = truth["time_s"].to_numpy(dtype=float)
    q = truth[list(cfg.coord_names)].to_numpy(dtype=float)
    if t.size < 4 or not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0) and np.all(np.isfinite(q))):
        raise CdgpsError(f"{sim.csv_path}: expected at least 4 rows of finite values in increasing time_s")
    return t, q


def structure_transmitters(cfg: StructureConfig, cn0_dbhz: float = 45.0, cn0_overrides: dict | None = None,
                           prns: dict | None = None, seed: int = 0, max_offset_hz: float = 3000.0) -> list[Transmitter]:
    """The config's transmitters as :class:`Transmitter` s: PRN 1, 2, … in config order unless ``prns``
    (name → PRN) says otherwise; C/N0 ``cn0_dbhz`` (dB-Hz) unless ``cn0_overrides`` (name → dB-Hz)
    says otherwise; frequency offsets uniform in ±``max_offset_hz`` (their clocks), code offsets
    and initial carrier phases uniform, all drawn from ``seed``."""
    names = list(cfg.transmitter_names)
    prns = dict(prns or {})
    cn0 = {n: cn0_dbhz for n in names} | dict(cn0_overrides or {})
    for what, given in (("PRN", prns), ("C/N0", cn0_overrides or {})):
        unknown = sorted(set(given) - set(names))
        if unknown:
            raise CdgpsError(f"{what} given for unknown transmitter(s) {', '.join(unknown)} (known: {', '.join(names)})")
    out, rng = [], np.random.default_rng(np.random.SeedSequence([int(seed), 1]))
    for i, name in enumerate(names):
        prn = prns.get(name, i + 1)
        c = cn0.get(name, 45.0)
        if isinstance(prn, bool) or not isinstance(prn, (int, np.integer)) or not 1 <= prn <= 32:
            raise CdgpsError(f"transmitter {name}: PRN {prn!r}: expected 1 to 32")
        if not (isinstance(c, (int, float)) and CN0_RANGE_DBHZ[0] <= c <= CN0_RANGE_DBHZ[1]):
            raise CdgpsError(f"transmitter {name}: C/N0 {c!r}: expected {CN0_RANGE_DBHZ[0]:g} to {CN0_RANGE_DBHZ[1]:g} dB-Hz")
        f, code, ph = rng.uniform(-max_offset_hz, max_offset_hz), rng.uniform(0, CODE_LENGTH), rng.uniform()
        out.append(Transmitter(name, int(prn), tuple(float(v) for v in cfg.transmitter_position_m[i]),
                               bool(cfg.transmitter_far_field), float(c), float(f), float(CHIPS_PER_BIT + 20 * code), float(ph)))
    dup = sorted({t.prn for t in out if sum(u.prn == t.prn for u in out) > 1})
    if dup:
        raise CdgpsError(f"PRN {', '.join(map(str, dup))} given to more than one transmitter")
    return out


def structure_delays_s(cfg: StructureConfig, time_s: np.ndarray, q: np.ndarray, transmitters: list,
                       knot_time_s: np.ndarray, clock_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Delays τ (K, A, J) (s) and ranges ρ + ℓ (K, A, J) (m) at the knot times (structure time, s):
    q interpolated by a cubic spline through the simulator's epochs, antenna positions p(q)."""
    from scipy.interpolate import CubicSpline

    qk = CubicSpline(time_s, q, axis=0)(knot_time_s)
    p = antenna_positions(cfg, qk)                                       # (K, A, 3)
    rng_m = np.stack([line_of_sight_range_m(tx, p) for tx in transmitters], axis=-1)
    rng_m = rng_m + np.asarray(cfg.antenna_line_bias_m)[None, :, None]
    return rng_m / C_M_S + clock_s[:, None, None], rng_m


@dataclass
class StructureIf:
    """What :func:`simulate_structure_if` needs besides the config and the simulation folder."""

    start_s: float = 0.0
    duration_s: float = 1.0
    options: IfOptions = field(default_factory=IfOptions)
    oscillator: Oscillator = field(default_factory=Oscillator)
    cn0_dbhz: float = 45.0
    cn0_overrides: dict = field(default_factory=dict)    # {transmitter: dB-Hz}
    prns: dict = field(default_factory=dict)             # {transmitter: PRN}


def _window(t: np.ndarray, spec: StructureIf, fs_hz: float) -> int:
    if not (math.isfinite(spec.start_s) and math.isfinite(spec.duration_s) and spec.duration_s > 0):
        raise CdgpsError(f"start {spec.start_s!r} s, duration {spec.duration_s!r} s: expected finite values, a positive duration")
    if spec.start_s < t[0] - 1e-9 or spec.start_s + spec.duration_s > t[-1] + 1e-9:
        raise CdgpsError(f"start {spec.start_s:g} s + duration {spec.duration_s:g} s: outside the simulation "
                         f"({t[0]:g} to {t[-1]:g} s)")
    return int(round(spec.duration_s * fs_hz))


def simulate_structure_if(cfg: StructureConfig, sim_dir: str | Path, out_dir: str | Path, codes: dict,
                          spec: StructureIf | None = None, progress=None) -> dict:
    """Write one sample file per antenna of ``cfg`` (``<antenna>.bin``, int8 I/Q) and the manifest
    ``if.json`` into ``out_dir``, from the trajectory of a ``cdgps simulate`` folder.

    All antennas share one receiver oscillator (the same clock error δt in every file); the
    transmitters are the config's (:func:`structure_transmitters`).  The files replace an earlier set
    as a whole (:func:`cdgps_cli.io.atomic.output_set`); nothing is left half-written.  The manifest
    holds the sample format, rate, IF, the transmitters, the oscillator and the truth at the
    structure's epochs inside the file: clock error, and per antenna and transmitter the range
    (ρ + ℓ, m), carrier phase (cycles), Doppler (Hz) and code phase (chips).  Returns a summary.
    """
    spec = spec or StructureIf()
    opt = spec.options
    opt.check()
    spec.oscillator.check()
    t_sim, q = read_structure_truth(sim_dir, cfg)
    n = _window(t_sim, spec, opt.fs_hz)
    n_ant = len(cfg.antenna_names)
    if 2 * n * n_ant > MAX_FILE_BYTES:
        raise CdgpsError(f"duration {spec.duration_s:g} s at {opt.fs_hz:g} Hz: {n_ant} files of {2 * n / 2**30:.3g} GiB "
                         f"exceed the {MAX_FILE_BYTES / 2**30:g} GiB limit; simulate a shorter stretch")
    txs = structure_transmitters(cfg, spec.cn0_dbhz, spec.cn0_overrides, spec.prns, opt.seed)
    missing = sorted({tx.prn for tx in txs} - set(codes))
    if missing:
        raise CdgpsError(f"no spreading code given for PRN {', '.join(map(str, missing))}")
    k = int(np.ceil(n / opt.fs_hz / KNOT_S)) + 2
    clock = clock_error_s(spec.oscillator, k, KNOT_S, np.random.default_rng(np.random.SeedSequence([int(opt.seed), 0])))
    knot_t = spec.start_s + np.arange(k) * KNOT_S
    delay, rng_m = structure_delays_s(cfg, t_sim, q, txs, np.minimum(knot_t, t_sim[-1]), clock)
    names = list(cfg.antenna_names)
    files = [f"{a}.bin" for a in names]
    ants = []
    with output_set(out_dir, replaces=(*files, MANIFEST)) as dest:
        for a, name in enumerate(names):
            if progress:
                progress(f"simulating {name}: {n / opt.fs_hz:g} s at {opt.fs_hz / 1e6:g} MHz, {len(txs)} transmitters …")
            h = hashlib.sha256()
            noise = np.random.default_rng(np.random.SeedSequence([int(opt.seed), 3, a]))
            with open(dest.path(files[a]), "wb") as fh:
                for blk in antenna_blocks(delay[:, a, :], txs, codes, n, opt, noise):
                    b = blk.tobytes()
                    h.update(b)
                    fh.write(b)
            ants.append({"name": name, "file": files[a], "sha256": h.hexdigest(),
                         "line_bias_m": float(cfg.antenna_line_bias_m[a])})
        manifest = _manifest(cfg, sim_dir, spec, txs, ants, n, delay, rng_m, clock)
        text = json.dumps(manifest, indent=1) + "\n"
        write_atomic(dest.path(MANIFEST), lambda p: p.write_text(text, encoding="utf-8"))
    return {"out_dir": str(out_dir), "files": files + [MANIFEST], "samples": n, "duration_s": n / opt.fs_hz,
            "antennas": names, "transmitters": [{"name": t.name, "prn": t.prn, "cn0_dbhz": t.cn0_dbhz,
                                                 "frequency_offset_hz": t.frequency_offset_hz} for t in txs],
            "bytes": 2 * n * n_ant}


def _manifest(cfg, sim_dir, spec: StructureIf, txs, ants, n, delay, rng_m, clock) -> dict:
    opt = spec.options
    period = cfg.sample_period_s
    first = math.ceil(spec.start_s / period - 1e-9)
    epochs = np.arange(first, math.floor((spec.start_s + n / opt.fs_hz) / period + 1e-9) + 1) * period
    rel = epochs - spec.start_s
    kk = np.rint(rel / KNOT_S).astype(np.int64)
    truth = {"time_s": [round(float(t), 9) for t in epochs], "clock_error_s": clock[kk].tolist(), "antennas": {}}
    for a, ant in enumerate(ants):
        per = {}
        for j, tx in enumerate(txs):
            tr = truth_at(tx, delay[:, a, j], rel)
            per[tx.name] = {"range_m": rng_m[kk, a, j].tolist(), "carrier_phase_cycles": tr["carrier_phase_cycles"].tolist(),
                            "doppler_hz": tr["doppler_hz"].tolist(), "code_phase_chips": tr["code_phase_chips"].tolist()}
        truth["antennas"][ant["name"]] = per
    return {"format": MANIFEST_FORMAT, "sample_format": "int8-iq", "iq_sign": opt.iq_sign, "fs_hz": opt.fs_hz,
            "if_hz": opt.if_hz, "bits": opt.bits, "samples": n, "duration_s": n / opt.fs_hz,
            "start_s": spec.start_s, "seed": opt.seed, "config": cfg.name, "config_sha256": cfg.sha256,
            "simulation": str(sim_dir), "master": cfg.antenna_names[cfg.master_index],
            "oscillator": asdict(spec.oscillator), "transmitters": [asdict(t) for t in txs],
            "antennas": ants, "truth": truth}
