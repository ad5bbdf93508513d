"""Checks every command gets for free (issue 12): option values are what they claim to be, and no
output path is one of the command's inputs, empty, or another of its outputs.

:class:`GuardedCommand` is the Click command class of the ``cdgps`` group: it turns every float
option into :data:`FINITE_FLOAT` (NaN and ±inf refused, naming the option) and, before the command
body runs, calls :func:`cdgps_cli.io.atomic.refuse_input_overwrite` with the command's output
parameters and every input it names — path arguments and options, ``NAME=FILE`` options, and the
files listed in a GNSS run config / baseline job given as an input.  Library functions validate
their own arguments too (:func:`cdgps_cli.core.checks.require_finite`).
"""

from __future__ import annotations

import math

import click

from cdgps_cli.core.errors import CdgpsError

#: parameter names (the Python names, not the spellings) of every command's outputs
OUTPUT_PARAMS = ("output", "out_dir", "out_csv", "figure_png")


class FiniteFloat(click.ParamType):
    """A float option that must be finite: ``nan``, ``inf``, ``1e999`` are refused."""

    name = "float"

    def convert(self, value, param, ctx):
        x = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(x):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return x


FINITE_FLOAT = FiniteFloat()


def _spelling(param: click.Parameter) -> str:
    if not isinstance(param, click.Option):
        return param.name.upper()
    return next((o for o in param.opts if o.startswith("--")), param.opts[0])


def _is_named_files(param: click.Parameter) -> bool:
    meta = (getattr(param, "metavar", None) or "")
    return meta.endswith("=FILE") or meta.endswith("=PATH")


def _listed_files(name: str, path: str) -> list[tuple[str, str]]:
    """Input files a GNSS run config or baseline job lists (none if it is neither or does not load)."""
    out = []
    try:
        if name == "job":
            from cdgps_cli.pipeline.baseline_job import load_baseline_job

            job = load_baseline_job(path)
            out += [(f"{path} rinex {k}", str(v)) for k, v in job["rinex"].items()]
            out += [(f"{path} nav", str(v)) for v in job["nav"]]
        elif name == "config":
            from pathlib import Path

            from cdgps_cli.config.structure import config_kind, load_gnss_config

            if config_kind(Path(path).read_text(errors="replace")) == "gnss":
                cfg = load_gnss_config(path)
                out += [(f"{path} antenna {a.name}", str(f)) for a in cfg.antennas for v in (a.rinex, a.ubx) if v
                        for f in (v if isinstance(v, (list, tuple)) else (v,))]
                out += [(f"{path} nav", str(v)) for v in cfg.nav]
    except (CdgpsError, OSError, ValueError, KeyError, TypeError):
        pass
    return out


def command_paths(command: click.Command, params: dict) -> tuple[list, list]:
    """(outputs, inputs) of one parsed command: lists of (option spelling, path, is_directory)."""
    outputs, inputs = [], []
    for p in command.params:
        value = params.get(p.name)
        if value in (None, (), []):
            continue
        values = value if isinstance(value, (tuple, list)) else (value,)
        if p.name in OUTPUT_PARAMS:
            is_dir = isinstance(p.type, click.Path) and not p.type.file_okay
            outputs += [(_spelling(p), str(v), is_dir) for v in values]
        elif isinstance(p.type, click.Path):
            for v in values:
                inputs.append((_spelling(p), str(v), False))
                inputs += [(f"{_spelling(p)} ({what})", f, False) for what, f in _listed_files(p.name, str(v))]
        elif _is_named_files(p):
            inputs += [(_spelling(p), str(v).partition("=")[2].strip(), False) for v in values if "=" in str(v)]
    return outputs, _with_pattern_matches(inputs)


def _with_pattern_matches(inputs: list) -> list:
    """``inputs`` and, for each given as a quoted glob pattern (a receiver's consecutive files), every file it matches:
    an output that is one of them is refused as a named input is."""
    import glob  # noqa: PLC0415   (io.log_sequence's is_pattern would load pandas into every command)
    from pathlib import Path  # noqa: PLC0415

    out = list(inputs)
    for spelling, path, _ in inputs:
        if glob.has_magic(path) and not Path(path).is_file():        # as io.log_sequence.expand_paths decides
            out += [(spelling, m, False) for m in sorted(glob.glob(path))]
    return out


class GuardedCommand(click.Command):
    """A cdgps command: finite floats, and outputs that are never one of its inputs."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for p in self.params:
            if p.type is click.FLOAT:
                p.type = FINITE_FLOAT

    def invoke(self, ctx):
        from cdgps_cli.io.atomic import refuse_input_overwrite, refuse_output_collisions

        from cdgps_cli.config.limits import check_option

        for p in self.params:
            check_option(p.name, _spelling(p), ctx.params.get(p.name))   # plausible ranges (limits.py)
        outputs, inputs = command_paths(self, ctx.params)
        refuse_output_collisions(outputs)
        refuse_input_overwrite(outputs, inputs)
        return super().invoke(ctx)
