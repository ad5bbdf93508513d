"""Raw GNSS front-end sample files (IF or baseband), read into complex or real arrays.

Formats by name: ``int8-iq`` / ``int16-iq`` — interleaved signed I, Q components, one complex sample
per pair; ``int8-real`` / ``int16-real`` — one real sample per value.  For complex files the sign of
the imaginary part is a convention of the front end: ``--iq-sign minus`` reads I − jQ (Pocket SDR and
other front ends whose quadrature channel is inverted), ``plus`` reads I + jQ.  A wrong sign mirrors
the spectrum: Dopplers change sign.

:func:`read_samples` reads the whole file (or its first samples) at once; :func:`iter_samples` reads
it block by block in its native sample type and converts one block at a time, so a reader's memory
does not grow with the file (the values are the same: the conversion is per sample and exact).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from cdgps_cli.config.options import TRACK_BLOCK_SAMPLES
from cdgps_cli.core.errors import CdgpsError

FORMATS = {"int8-iq": (np.int8, True), "int16-iq": ("<i2", True), "int8-real": (np.int8, False),
           "int16-real": ("<i2", False)}
IQ_SIGNS = ("minus", "plus")


def sample_count(path: str | Path, fmt: str, iq_sign: str = "minus") -> int:
    """Number of samples in a raw file of format ``fmt``, checked (format, sign, size).

    Raises
    ------
    CdgpsError
        Unknown format or sign, missing or empty file, a size that is not a whole number of samples.
    """
    if fmt not in FORMATS:
        raise CdgpsError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    if iq_sign not in IQ_SIGNS:
        raise CdgpsError(f"--iq-sign {iq_sign!r}: expected one of {', '.join(IQ_SIGNS)}")
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise CdgpsError(f"{p}: cannot read: {exc.strerror}") from None
    item = _bytes_per_sample(fmt)
    if size == 0 or size % item:
        raise CdgpsError(f"{p}: {size} bytes is not a whole number of {fmt} samples ({item} bytes each)"
                         + ("; the file is empty" if size == 0 else "; truncated or another format?"))
    return size // item


def _bytes_per_sample(fmt: str) -> int:
    dtype, iq = FORMATS[fmt]
    return np.dtype(dtype).itemsize * (2 if iq else 1)


def _numbers(raw: np.ndarray, iq: bool, iq_sign: str) -> np.ndarray:
    """Native values (interleaved I, Q or real) → complex128 (I ∓ jQ) or float64 samples."""
    raw = raw.astype(np.float64)
    if not iq:
        return raw
    return raw[0::2] + (-1j if iq_sign == "minus" else 1j) * raw[1::2]


def read_samples(path: str | Path, fmt: str, iq_sign: str = "minus", max_samples: int | None = None) -> np.ndarray:
    """Samples of a raw file: complex128 for IQ formats, float64 for real ones.

    Raises
    ------
    CdgpsError
        Unknown format or sign, missing or empty file, a size that is not a whole number of samples.
    """
    total = sample_count(path, fmt, iq_sign)
    dtype, iq = FORMATS[fmt]
    count = total if max_samples is None else min(total, int(max_samples))
    return _numbers(np.fromfile(Path(path), dtype=dtype, count=count * (2 if iq else 1)), iq, iq_sign)


def iter_samples(path: str | Path, fmt: str, iq_sign: str = "minus", *, block_samples: int = TRACK_BLOCK_SAMPLES,
                 max_samples: int | None = None) -> Iterator[np.ndarray]:
    """The samples of :func:`read_samples` as consecutive blocks of ``block_samples`` (the last one shorter).

    The file is read ``block_samples`` native samples at a time (e.g. 2 bytes per ``int8-iq`` sample)
    and each block converted on its own: memory is a few times ``block_samples`` × 16 bytes, whatever
    the file's length, and the concatenated blocks equal :func:`read_samples` exactly.

    Raises
    ------
    CdgpsError
        As :func:`read_samples` (checked before the first block); a ``block_samples`` below 1; a file
        that ends early (cut while it is read).
    """
    if isinstance(block_samples, bool) or not isinstance(block_samples, (int, np.integer)) or block_samples < 1:
        raise CdgpsError(f"block_samples {block_samples!r}: expected a whole number of samples ≥ 1")
    total = sample_count(path, fmt, iq_sign)
    return _blocks(Path(path), fmt, iq_sign, int(block_samples),
                   total if max_samples is None else min(total, int(max_samples)))


def _blocks(p: Path, fmt: str, iq_sign: str, block: int, count: int) -> Iterator[np.ndarray]:
    dtype, iq = FORMATS[fmt]
    per = 2 if iq else 1
    done = 0
    with open(p, "rb") as fh:
        while done < count:
            k = min(block, count - done)
            raw = np.fromfile(fh, dtype=dtype, count=k * per)
            if raw.size != k * per:
                raise CdgpsError(f"{p}: ended after {done + raw.size // per} of {count} {fmt} samples "
                                 "(was it cut while being read?)")
            yield _numbers(raw, iq, iq_sign)
            done += k
