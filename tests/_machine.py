"""This machine's fingerprint for golden records whose floating-point digests are exact only on the
machine that recorded them (the project's rule: never compare digests made on another machine)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np


def machine() -> str:
    """CPU model, architecture and numpy version, as stored in a golden record's ``_machine``."""
    model = ""
    try:
        model = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                      if ln.startswith("model name")), "")
    except OSError:
        pass
    return f"{platform.machine()}|{model or platform.processor()}|numpy {np.__version__}"


def exact_here(recorded_machine: str | None) -> bool:
    """Compare digests exactly: ``GOLDEN_EXACT=1`` forces, ``GOLDEN_EXACT=0`` relaxes, otherwise only on
    the machine that made the record."""
    env = os.environ.get("GOLDEN_EXACT")
    if env is not None:
        return env not in ("0", "")
    return recorded_machine == machine()
