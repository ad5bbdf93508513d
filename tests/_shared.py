"""Helpers shared by test files (imported as ``_shared``; pytest puts tests/ on sys.path: the root
conftest.py lives there)."""

from __future__ import annotations

import contextlib
import os

import click

from pathlib import Path

from cdgps_cli.estimation import kernel as _ekf_kernel

#: the repository root (tests/ is one level below it)
REPO_ROOT = Path(__file__).resolve().parent.parent
#: True when the compiled EKF kernel of this build is importable and of the API this code expects
COMPILED = _ekf_kernel._ekfcore is not None and getattr(_ekf_kernel._ekfcore, "API", None) == _ekf_kernel.API


def cli_commands(group: click.Group, prefix=()):
    """Every leaf command of a Click group, as (path tuple, command), sorted by name."""
    for name, cmd in sorted(group.commands.items()):
        if isinstance(cmd, click.Group):
            yield from cli_commands(cmd, prefix + (name,))
        else:
            yield prefix + (name,), cmd


@contextlib.contextmanager
def kernel(enabled: bool):
    """Force the compiled (enabled) or the numpy filter path, restoring the caller's environment."""
    old = os.environ.get("CDGPS_NO_KERNEL")
    if enabled:
        os.environ.pop("CDGPS_NO_KERNEL", None)
    else:
        os.environ["CDGPS_NO_KERNEL"] = "1"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("CDGPS_NO_KERNEL", None)
        else:
            os.environ["CDGPS_NO_KERNEL"] = old


def can_fork() -> bool:
    """Whether core.beside forks here when asked to (``CDGPS_SERIAL=0``): ``os.fork`` and two usable CPUs —
    :func:`cdgps_cli.core.beside.forking_allowed` without the suite's default ``CDGPS_SERIAL=1`` (conftest.py)."""
    from cdgps_cli.core import beside  # noqa: PLC0415

    old = os.environ.pop("CDGPS_SERIAL", None)
    try:
        return beside.forking_allowed()
    finally:
        if old is not None:
            os.environ["CDGPS_SERIAL"] = old


def run_cli(*args):
    """``cdgps ARGS…`` in-process (Click's runner); the result (``exit_code``, ``output``)."""
    from click.testing import CliRunner  # noqa: PLC0415

    from cdgps_cli.cli.commands import main  # noqa: PLC0415

    return CliRunner().invoke(main, [str(a) for a in args])


def run_commands(*commands) -> None:
    """Run each ``cdgps`` command (a tuple of arguments) quietly; assert that every one succeeds."""
    for args in commands:
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
