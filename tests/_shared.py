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


#: the real Septentrio mosaic-X5 pair of ../shared/data (GPS, GLONASS, Galileo, BeiDou; 1 s, 301 epochs from T0)
MOSAIC_DIR = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
MOSAIC_T0 = 1403252400.0                                            # 2024-06-24 08:20:00 GPST


def write_gappy_mosaic_pair(d, base_name: str = "base_gappy.obs", rover_name: str = "rover_ms.obs"):
    """The mosaic pair as low-cost receivers write it, into folder ``d``: the base's epochs thinned to a gappy grid
    (1–8 s apart, seed 7) with its clock stepped by 1 ms every 7 s around −10 ms, the rover's clock stepped every 5 s
    around −9 ms.  Returns (base path, rover path)."""
    import numpy as np  # noqa: PLC0415

    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs  # noqa: PLC0415

    base, rover = (MOSAIC_DIR / "base.obs").read_text(), (MOSAIC_DIR / "rover.obs").read_text()
    rng = np.random.default_rng(7)
    keep, t = set(), MOSAIC_T0
    while t <= MOSAIC_T0 + 300:
        keep.add(round(t))
        t += int(rng.integers(1, 9))
    (d / base_name).write_text(edit_rinex3_obs(
        base, keep=lambda t: round(t) in keep, clock_offset_s=lambda t: -0.010 + 0.001 * ((round(t) // 7) % 2)))
    (d / rover_name).write_text(edit_rinex3_obs(rover, clock_offset_s=lambda t: -0.009 + 0.001 * ((round(t) // 5) % 2)))
    return d / base_name, d / rover_name


def one_system_rinex3(text: str, system: str, header_too: bool = True) -> str:
    """A RINEX 3 observation file's text with the records (and, ``header_too``, the observation types) of
    ``system`` alone (the epoch lines' satellite counts set to what is left)."""
    lines = text.splitlines()
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER")
    head, keep = [], True
    for ln in lines[:end + 1]:
        if header_too and ln[60:].strip() == "SYS / # / OBS TYPES":
            keep = ln[0] == system if ln[0] != " " else keep        # a continuation line follows its system
            if not keep:
                continue
        head.append(ln)
    body, i = [], end + 1
    while i < len(lines):
        n = int(lines[i][32:35])
        recs = [r for r in lines[i + 1:i + 1 + n] if r[0] == system]
        body += [lines[i][:32] + f"{len(recs):3d}" + lines[i][35:], *recs]
        i += 1 + n
    return "\n".join(head + body) + "\n"
