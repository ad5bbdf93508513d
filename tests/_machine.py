"""This machine's fingerprint for golden records whose floating-point digests are exact only on the
machine that recorded them (the project's rule: never compare digests made on another machine), and
the tolerance of a float recorded elsewhere.

The fingerprint names the CPU by its family, model and SIMD flags, not only by its marketing name:
two machines both called "AMD EPYC" with the same numpy (this one: Zen 1, family 23 model 1, AVX2 only; and
the one the earlier records were made on) gave other bits: records made on one did not reproduce bit for
bit on the other (2026-12-05), as their BLAS and libm kernels are chosen by the CPU.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np

#: relative tolerance (and, times the quantity's largest magnitude, absolute floor) of a float
#: recorded on another machine: round-off of 1e-16 grows through the batches and filters. Measured
#: between two AMD EPYC machines (Zen 1 against the earlier records' machine) on the same code and numpy 2.4.6: real
#: GEONET float baseline 5.6e-6 relative on its smallest component (1.9e-8 m), its ratio test
#: 3.1e-6, modal states 1.1e-7, STATES q 9.3e-6 relative on an element (1.7e-8 m absolute).
#: Still far below any intended change of arithmetic (>= 1e-4 in every golden so far).
CROSS_MACHINE_RTOL = 1e-5

#: the SIMD feature flags that choose BLAS and libm kernels
_SIMD = ("sse4_2", "avx", "avx2", "fma", "fma4", "avx512f", "avx512dq", "avx512bw", "avx512vl",
         "avx512_vnni", "avx512_bf16", "amx_tile", "asimd", "sve")


def _cpuinfo() -> dict:
    info: dict[str, str] = {}
    try:
        for ln in Path("/proc/cpuinfo").read_text().splitlines():
            key, sep, value = ln.partition(":")
            key = key.strip()
            if sep and key not in info:
                info[key] = value.strip()
            if not ln.strip() and info:
                break                                            # the first processor is enough
    except OSError:
        pass
    return info


def machine() -> str:
    """Architecture, CPU (name, family/model/stepping, SIMD flags), numpy and scipy versions, as
    stored in a golden record's ``_machine``."""
    info = _cpuinfo()
    flags = set((info.get("flags") or info.get("Features") or "").split())
    simd = ",".join(f for f in _SIMD if f in flags)
    cpu = "/".join(info.get(k, "?") for k in ("cpu family", "model", "stepping"))
    try:
        import scipy
        sp = scipy.__version__
    except ImportError:                                          # pragma: no cover - scipy is a dependency
        sp = "none"
    model = info.get("model name") or platform.processor()
    return f"{platform.machine()}|{model}|{cpu}|{simd}|numpy {np.__version__}|scipy {sp}"


def exact_here(recorded_machine: str | None) -> bool:
    """Compare digests exactly: ``GOLDEN_EXACT=1`` forces, ``GOLDEN_EXACT=0`` relaxes, otherwise only on
    the machine that made the record."""
    env = os.environ.get("GOLDEN_EXACT")
    if env is not None:
        return env not in ("0", "")
    return recorded_machine == machine()


def float_tolerance(recorded_machine: str | None, rtol: float) -> float:
    """``rtol`` on the machine that made the record, else at least :data:`CROSS_MACHINE_RTOL`."""
    return rtol if exact_here(recorded_machine) else max(rtol, CROSS_MACHINE_RTOL)


def assert_json_close(a, b, where: str, abs_tol: float = 1e-15) -> None:
    """``a`` (computed here) has ``b``'s structure, its non-floats exactly and its floats within
    :data:`CROSS_MACHINE_RTOL` (plus ``abs_tol``); ``where`` names the failing element."""
    if isinstance(b, dict):
        assert isinstance(a, dict) and a.keys() == b.keys(), where
        for k in b:
            assert_json_close(a[k], b[k], f"{where}.{k}", abs_tol)
    elif isinstance(b, list):
        assert isinstance(a, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_json_close(x, y, f"{where}[{i}]", abs_tol)
    elif isinstance(b, float):
        assert abs(a - b) <= CROSS_MACHINE_RTOL * abs(b) + abs_tol, f"{where}: {a!r} != {b!r}"
    else:
        assert a == b, where
