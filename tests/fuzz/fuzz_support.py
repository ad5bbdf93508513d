"""Shared pieces of the fuzz suite (issue 12 item 10): settings, mutations, the property (the base
files are the ``base`` fixture of this folder's conftest.py).  A module of its own name, not
``conftest``: another folder's conftest.py would shadow it when both are collected.

Every test here states one property over generated inputs: a reader or a command given any input
returns a valid result or raises the project's own :class:`~cdgps_cli.core.errors.CdgpsError` whose
message names the file (and the line, key or option where it can), never another exception; the
input files are byte-identical afterwards (sha256); and nothing is left at an output path after an
error.  Runs are bounded and deterministic (``derandomize=True``, no example database): the
example count is :data:`MAX_EXAMPLES` unless ``CDGPS_FUZZ_EXAMPLES`` says otherwise, for a longer
local run.  The long campaign is ``benchmarks/fault_campaign.py``.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from click.testing import CliRunner
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError

REPO_ROOT = Path(__file__).resolve().parents[2]
DATA = REPO_ROOT / "tests" / "data"
SHARED = REPO_ROOT.parent / "shared" / "data"
DOF2 = REPO_ROOT / "configs" / "teague-1995-2dof.toml"
TESTBED = REPO_ROOT / "configs" / "testbed-1998-lumped.toml"

#: examples per property in `make test` (a few seconds per file on a loaded 2-core machine)
MAX_EXAMPLES = int(os.environ.get("CDGPS_FUZZ_EXAMPLES", "0")) or None


def fuzz_settings(examples: int):
    """Bounded, deterministic hypothesis settings: ``examples`` unless CDGPS_FUZZ_EXAMPLES is set."""
    return settings(max_examples=MAX_EXAMPLES or examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cli(*args):
    """The CLI in-process (quiet); exceptions other than SystemExit are kept on the result."""
    return CliRunner().invoke(main, ["-q", *map(str, args)], catch_exceptions=True)


@contextmanager
def scratch():
    """A fresh temporary folder per example (pytest's tmp_path is one per test, not per example)."""
    with tempfile.TemporaryDirectory(prefix="cdgps-fuzz-") as d:
        yield Path(d)


def check_reader(call, path: Path, *names: str):
    """Run ``call()``: a result, or a CdgpsError naming ``path`` (and one of ``names`` if given).
    Any other exception propagates (hypothesis reports it with the input).  The input file is
    byte-identical afterwards.  Returns the result, or None after a clean error."""
    before = sha256(path)
    try:
        result = call()
    except CdgpsError as exc:
        msg = str(exc)
        assert str(path) in msg or path.name in msg, f"message does not name the file: {msg!r}"
        if names:
            assert any(n in msg for n in names), f"message names none of {names}: {msg!r}"
        result = None
    assert sha256(path) == before, f"{path} was modified"
    return result


def check_command(r, inputs, outputs, *names: str) -> bool:
    """A CliRunner result: exit 0, or exit 2 (no traceback) whose message names one of ``names``
    and leaves nothing at any of ``outputs`` nor hidden temporaries beside them.  ``inputs``:
    {path: sha256 before}, all unchanged.  True if the command succeeded."""
    for p, h in inputs.items():
        assert sha256(p) == h, f"input {p} was modified"
    exc = r.exception
    if exc is not None and not isinstance(exc, SystemExit):
        raise AssertionError(f"traceback ({type(exc).__name__}: {exc}); output: {r.output[-500:]}") from exc
    assert "Traceback" not in r.output, r.output
    if r.exit_code == 0:
        return True
    assert r.exit_code == 2, f"exit {r.exit_code}: {r.output[-500:]}"
    if names:
        assert any(n in r.output for n in names), f"message names none of {names}: {r.output[-500:]!r}"
    for o in outputs:
        o = Path(o)
        assert not o.exists(), f"{o} left after an error: {r.output[-300:]}"
        if o.parent.exists():
            left = [q.name for q in o.parent.iterdir() if q.name.startswith(".") and o.name in q.name]
            assert not left, f"hidden temporaries left beside {o}: {left}"
    return False


# ---- mutations of a file's bytes -----------------------------------------------------------------


@st.composite
def byte_mutation(draw, data: bytes, region: tuple[int, int] | None = None):
    """(description, mutated bytes): a flipped byte, a truncation, an inserted or deleted run, a
    duplicated run, within ``region`` (start, end offsets) if given."""
    lo, hi = region or (0, len(data))
    hi = max(hi, lo + 1)
    kind = draw(st.sampled_from(["flip", "flip", "truncate", "insert", "delete", "duplicate"]))
    i = draw(st.integers(lo, min(hi, len(data)) - 1))
    if kind == "flip":
        x = draw(st.integers(1, 255))
        b = bytearray(data)
        b[i] ^= x
        return f"flip@{i}^{x:#04x}", bytes(b)
    if kind == "truncate":
        return f"truncate@{i}", data[:i]
    n = draw(st.integers(1, 64))
    if kind == "insert":
        ins = draw(st.binary(min_size=1, max_size=n))
        return f"insert@{i}:{ins!r}", data[:i] + ins + data[i:]
    if kind == "delete":
        return f"delete@{i}+{n}", data[:i] + data[i + n:]
    return f"duplicate@{i}+{n}", data[:i + n] + data[i:]


#: numeric-looking text: what a corrupted or hand-edited number field may hold
NUMBER_TEXT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-2**80, 2**80).map(str),
    st.sampled_from(["inf", "-inf", "nan", "NaN", "1e999", "-1e999", "1e308", "-1e308", "1e-308", "1e12", "-1e9",
                     "0", "-0", "-1", "0x10", "1_000", " 1 ", "1e", "", "true", "∞", "١"]),
)
#: any short text, including separators, quotes and non-ASCII
ANY_TEXT = st.text(max_size=12)
