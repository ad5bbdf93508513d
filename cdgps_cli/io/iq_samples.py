"""Raw GNSS front-end sample files (IF or baseband), read into complex or real arrays.

Formats by name: ``int8-iq`` / ``int16-iq`` — interleaved signed I, Q components, one complex sample
per pair; ``int8-real`` / ``int16-real`` — one real sample per value.  For complex files the sign of
the imaginary part is a convention of the front end: ``--iq-sign minus`` reads I − jQ (Pocket SDR and
other front ends whose quadrature channel is inverted), ``plus`` reads I + jQ.  A wrong sign mirrors
the spectrum: Dopplers change sign.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cdgps_cli.core.errors import CdgpsError

FORMATS = {"int8-iq": (np.int8, True), "int16-iq": ("<i2", True), "int8-real": (np.int8, False),
           "int16-real": ("<i2", False)}
IQ_SIGNS = ("minus", "plus")


def read_samples(path: str | Path, fmt: str, iq_sign: str = "minus", max_samples: int | None = None) -> np.ndarray:
    """Samples of a raw file: complex128 for IQ formats, float64 for real ones.

    Raises
    ------
    CdgpsError
        Unknown format or sign, missing or empty file, a size that is not a whole number of samples.
    """
    if fmt not in FORMATS:
        raise CdgpsError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    if iq_sign not in IQ_SIGNS:
        raise CdgpsError(f"--iq-sign {iq_sign!r}: expected one of {', '.join(IQ_SIGNS)}")
    dtype, iq = FORMATS[fmt]
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror}") from None
    item = np.dtype(dtype).itemsize * (2 if iq else 1)
    if size == 0 or size % item:
        raise CdgpsError(f"{p}: {size} bytes is not a whole number of {fmt} samples ({item} bytes each)"
                         + ("; the file is empty" if size == 0 else "; truncated or another format?"))
    count = size // item if max_samples is None else min(size // item, int(max_samples))
    raw = np.fromfile(p, dtype=dtype, count=count * (2 if iq else 1)).astype(np.float64)
    if not iq:
        return raw
    return raw[0::2] + (-1j if iq_sign == "minus" else 1j) * raw[1::2]
