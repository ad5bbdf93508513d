"""GPS L1 C/A spreading codes (IS-GPS-200, Sec. 3.3.2.3 and Table 3-Ia).

Each code is the modulo-2 sum of two 10-stage maximal-length sequences clocked at 1.023 MHz:
G1 with feedback 1 + x³ + x¹⁰ and G2 with 1 + x² + x³ + x⁶ + x⁸ + x⁹ + x¹⁰, both starting all ones;
the PRN selects two G2 stages whose modulo-2 sum is the delayed G2 output.  1023 chips per 1 ms.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from cdgps_cli.core.errors import CdgpsError

#: chips per code period and chipping rate, Hz
CODE_LENGTH = 1023
CHIP_RATE_HZ = 1.023e6

#: G2 output taps (stage numbers, 1-based) per PRN 1–32, IS-GPS-200 Table 3-Ia
G2_TAPS = {
    1: (2, 6), 2: (3, 7), 3: (4, 8), 4: (5, 9), 5: (1, 9), 6: (2, 10), 7: (1, 8), 8: (2, 9),
    9: (3, 10), 10: (2, 3), 11: (3, 4), 12: (5, 6), 13: (6, 7), 14: (7, 8), 15: (8, 9), 16: (9, 10),
    17: (1, 4), 18: (2, 5), 19: (3, 6), 20: (4, 7), 21: (5, 8), 22: (6, 9), 23: (1, 3), 24: (4, 6),
    25: (5, 7), 26: (6, 8), 27: (7, 9), 28: (8, 10), 29: (1, 6), 30: (2, 7), 31: (3, 8), 32: (4, 9),
}


def _register(feedback_stages: tuple, output_stages: tuple | None) -> np.ndarray:
    """1023 output bits of a 10-stage shift register starting all ones (stage 10 out, unless taps)."""
    reg = [1] * 10
    out = np.empty(CODE_LENGTH, dtype=np.int8)
    for i in range(CODE_LENGTH):
        if output_stages is None:
            out[i] = reg[9]
        else:
            out[i] = reg[output_stages[0] - 1] ^ reg[output_stages[1] - 1]
        fb = 0
        for s in feedback_stages:
            fb ^= reg[s - 1]
        reg = [fb] + reg[:9]
    return out


@lru_cache(maxsize=None)
def _ca_bits(prn: int) -> bytes:
    g1 = _register((3, 10), None)
    g2 = _register((2, 3, 6, 8, 9, 10), G2_TAPS[prn])
    return (g1 ^ g2).astype(np.int8).tobytes()


def ca_code(prn: int) -> np.ndarray:
    """The C/A code of ``prn`` (1–32) as ±1 chips (bit 0 → +1, bit 1 → −1), shape (1023,), int8."""
    if not isinstance(prn, (int, np.integer)) or int(prn) not in G2_TAPS:
        raise CdgpsError(f"prn: expected a GPS PRN 1-32, got {prn!r}")
    bits = np.frombuffer(_ca_bits(int(prn)), dtype=np.int8)
    return (1 - 2 * bits).astype(np.int8)


def first_chips_octal(prn: int, chips: int = 10) -> str:
    """The first ``chips`` chips as an octal number, the form of IS-GPS-200 Table 3-Ia (bit 1 = chip −1)."""
    bits = (1 - ca_code(prn)[:chips]) // 2
    return format(int("".join(map(str, bits)), 2), "o")


def sampled_code(prn: int, fs_hz: float, n: int, code_phase_chips: float = 0.0,
                 code_rate_hz: float = CHIP_RATE_HZ) -> np.ndarray:
    """n samples of the ±1 code at rate fs, starting at ``code_phase_chips`` (float64)."""
    idx = np.floor(code_phase_chips + np.arange(n) * (code_rate_hz / fs_hz)).astype(np.int64) % CODE_LENGTH
    return ca_code(prn)[idx].astype(np.float64)
