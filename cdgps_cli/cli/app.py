"""The `cdgps` click group and what every command shares: the command and group classes (guarded
options, errors as ``cdgps: error: …`` with exit 2, SIGTERM, broken pipes), the one voice for
messages (:func:`_say`, :func:`_warn`, :func:`_emit_json`), the output option and small parsers.
The commands themselves live in the ``*_commands`` modules beside this one, by family."""

from __future__ import annotations

import atexit
import gc
import json
import sys
from pathlib import Path

import click

from cdgps_cli import __version__
from cdgps_cli.core import progress
from cdgps_cli.io.atomic import INTERRUPTED_EXIT, TERMINATED_EXIT, Terminated, sigterm_raises
from cdgps_cli.core.errors import AmbiguityError, CdgpsError
from cdgps_cli.cli.guard import GuardedCommand


def _no_collection_at_exit() -> None:
    """At interpreter exit, move every object to the collector's permanent generation (``gc.freeze``):
    the final collections then do not walk them all (the process frees its memory anyway).

    With numpy, scipy and pandas loaded the exit of ``cdgps estimate`` took 0.1–0.3 s of cyclic
    collection, ≈ 0.04 s without (docs/benchmarks/io.md).  Nothing cdgps writes depends on it: outputs
    are closed (and renamed into place) before the command returns, and Python flushes stdout/stderr
    and runs ``weakref.finalize``/``atexit`` callbacks whether or not objects are frozen.
    """
    gc.freeze()


atexit.register(_no_collection_at_exit)

_GC_THRESHOLDS = (100_000, 50, 100)
"""Cyclic-collector thresholds while a command runs (Python's default: 700, 10, 10).  The imports of
numpy/scipy/pandas and the per-epoch Python objects of the filter and the writers make hundreds of
thousands of objects that are not garbage; with the default first threshold the collector walks them
again and again (``cdgps estimate`` on 1 h of 10 Hz: about 0.15 s of 1.9 s, in 4 interleaved runs at
load 1).  Reference counting still frees everything at once; only cycles wait a little longer."""


def _quiet_after_command(ctx, param, value):
    """``-q`` given after a subcommand: the same as ``cdgps -q``."""
    if value:
        ctx.ensure_object(dict)["quiet"] = True
        progress.configure(enabled=False)


_QUIET_HELP = "No progress or human summaries on stderr (also accepted before the command)."


class _Command(GuardedCommand):
    """A subcommand that also accepts ``-q/--quiet`` after its name (``cdgps info X -q``); finite
    floats and outputs that are never an input (:class:`cdgps_cli.cli.guard.GuardedCommand`)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.params.append(click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, is_eager=True,
                                        callback=_quiet_after_command, help=_QUIET_HELP))


class _Group(click.Group):
    command_class = _Command
    group_class = type                     # subgroups (``report``) are _Group too

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if not any(p.name == "quiet" for p in self.params):
            self.params.append(click.Option(["-q", "--quiet"], is_flag=True, expose_value=False, is_eager=True,
                                            callback=_quiet_after_command, help=_QUIET_HELP))

    def main(self, *args, **kwargs):
        """Run the command with the cyclic collector's first threshold at :data:`_GC_THRESHOLDS`
        (restored afterwards, for callers in the same process)."""
        before = gc.get_threshold()
        gc.set_threshold(*_GC_THRESHOLDS)
        try:
            return super().main(*args, **kwargs)
        finally:
            gc.set_threshold(*before)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except CdgpsError as exc:
            _fail(ctx, str(exc))
        except BrokenPipeError:                 # stdout read by `| head` that has exited
            _quiet_broken_pipe(ctx)
        except Terminated:                      # SIGTERM: temporaries already removed on the way up
            progress.close_all()
            click.echo("cdgps: terminated (SIGTERM); no partial output left", err=True)
            ctx.exit(TERMINATED_EXIT)
        except KeyboardInterrupt:               # Ctrl-C: as SIGTERM (click's own "Aborted!" and exit 1 said less)
            progress.close_all()
            click.echo("cdgps: interrupted (Ctrl-C); no partial output left", err=True)
            ctx.exit(INTERRUPTED_EXIT)
        except AmbiguityError as exc:           # last line of defence: LAMBDA refused what a solver gave it
            _fail(ctx, f"integer ambiguity resolution could not run: {exc} (the float solution's covariance; "
                       f"please report it with the command and its input files)")
        except MemoryError:                     # last line of defence (inputs are bounded first)
            _fail(ctx, "out of memory: the inputs or options ask for more memory than this machine has "
                       "(a shorter --duration or a smaller input)")
        except OSError as exc:                  # last line of defence: a full device while writing
            from cdgps_cli.io.atomic import is_no_room, output_error

            if not is_no_room(exc):
                raise
            _fail(ctx, str(output_error(exc.filename or "an output", exc)))


def _fail(ctx, message: str) -> None:
    """Print a user error (no traceback) and exit with status 2."""
    progress.close_all()
    click.echo(f"cdgps: error: {message}", err=True)
    ctx.exit(2)


#: exit status after stdout was closed by its reader: 128 + SIGPIPE, as a shell reports a program
#: killed by SIGPIPE (``cdgps info X --json | head -1``); nothing is printed
BROKEN_PIPE_EXIT = 141


def _quiet_broken_pipe(ctx) -> None:
    """Exit quietly when the reader of stdout has gone; stdout points to /dev/null afterwards so the
    interpreter's final flush does not complain either."""
    import os

    progress.close_all()
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):              # no real stdout (library use, test runner)
        pass
    ctx.exit(BROKEN_PIPE_EXIT)


def _echo(text: str) -> None:
    """Print command output on stdout; a full device there is a user error naming stdout."""
    try:
        click.echo(text)
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise CdgpsError(f"standard output: cannot write: {exc.strerror or exc} (is it redirected to a full "
                         f"device?)") from None


def _warn(msg: str) -> None:
    """One voice for warnings (issue 32): ``cdgps: warning: …`` on stderr, also with --quiet (a warning
    is about the data or the result, not progress)."""
    progress.write(f"cdgps: warning: {msg}")


def _say(ctx, msg: str) -> None:
    if not ctx.obj.get("quiet"):
        progress.write(msg)


def _output_option(dest: str, help: str, *, directory: bool = False, old: tuple = ()):
    """The one spelling of every output, ``-o/--output``; ``old`` spellings (``--out``, ``--csv``)
    are still accepted for older scripts and named in the help text, not listed as options."""
    return click.option("-o", "--output", *old, dest, cls=_AliasedOption, aliases=old, required=True,
                        type=click.Path(file_okay=False) if directory else click.Path(dir_okay=False),
                        help=help.rstrip(".") + (f" (older spelling {', '.join(old)} still accepted)." if old else "."))


class _AliasedOption(click.Option):
    """An option whose older spellings parse but do not show in the usage line and help."""

    def __init__(self, *args, aliases=(), **kwargs):
        super().__init__(*args, **kwargs)
        self.aliases = tuple(aliases)

    def get_help_record(self, ctx):
        shown, self.opts = self.opts, [o for o in self.opts if o not in self.aliases]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = shown


def _named_by_flags(build, flags: dict):
    """``build()``, with the library's field names in its CdgpsError replaced by the command-line
    flags the user gave (``mask_deg must be in [0, 90)`` → ``--mask-deg must be in [0, 90)``)."""
    import re

    try:
        return build()
    except CdgpsError as exc:
        msg = str(exc)
        for field, flag in flags.items():
            msg = re.sub(rf"(?<![\w-]){re.escape(field)}(?!\w)", flag, msg)
        raise CdgpsError(msg) from None


def _emit_json(data: dict) -> None:
    _echo(json.dumps(data, indent=2, sort_keys=False))


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="cdgps")
@click.option("--quiet", "-q", is_flag=True, help="No progress or human summaries on stderr.")
@click.pass_context
def main(ctx, quiet):
    """cdgps: carrier-phase GPS sensing of flexible structures.

    Stages, chained through files: simulate (or your own logs) → ingest → RUN.mcap → init →
    estimate → spectra → report.  See README.md.
    """
    ctx.ensure_object(dict)
    ctx.obj["quiet"] = quiet
    progress.configure(enabled=not quiet)
    ctx.call_on_close(lambda: progress.configure(enabled=False))   # library use stays silent
    ctx.with_resource(sigterm_raises())     # SIGTERM cleans up as SIGINT does (cdgps_cli.io.atomic)


def _parse_named(items, option: str, what: str = "antenna", form: str = "ANTENNA=FILE") -> dict:
    """NAME=FILE options (--rinex/--ubx) → {name: path}; ``what`` and ``form`` word the messages."""
    out = {}
    for it in items:
        name, sep, path = it.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise CdgpsError(f"{option} expects {form} (e.g. 3040=30400920.05o), got {it!r}")
        if name.strip() in out:
            raise CdgpsError(f"{option}: {what} {name.strip()!r} given twice" + (
                f" (a config names one file or one quoted glob pattern per antenna: {option} "
                f"{name.strip()}='PATTERN' for its consecutive files; 'cdgps ingest {option}' joins repeated files "
                f"without a config)" if what == "antenna" else ""))
        out[name.strip()] = path.strip()
    return out


def _parse_antenna_types(items, name_word: str = "ANTENNA") -> dict:
    """``--antenna NAME=TYPE`` options (``baseline``'s NAME, ``ingest``'s ANTENNA) → {name: antenna type, or none};
    a later one for the same name wins."""
    out = {}
    for it in items:
        name, sep, typ = it.partition("=")
        if not sep or not name.strip() or not typ.strip():
            raise CdgpsError(f"--antenna expects {name_word}=TYPE (e.g. base=\"TRM59800.80 SCIT\", or rover=none), "
                             f"got {it!r}")
        out[name.strip()] = typ.strip()
    return out


def _parse_named_files(items, option: str, name_word: str = "ANTENNA") -> dict:
    """ANTENNA=FILE options of ``ingest`` (--rinex/--ubx; ``baseline``'s NAME=PATH, ``name_word`` NAME) →
    {antenna: [file or pattern, …]}: an antenna repeated, or a quoted glob pattern, gives its consecutive files
    (joined into one record)."""
    out: dict = {}
    file_word = "PATH" if name_word == "NAME" else "FILE"
    for it in items:
        name, sep, path = it.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise CdgpsError(f"{option} expects {name_word}={file_word} or {name_word}='PATTERN' (e.g. 3040=30400920.05o, "
                             f"rover='rover_*.obs'), got {it!r}")
        out.setdefault(name.strip(), []).append(path.strip())
    return out


def _write_json_atomic(path: str, data: dict) -> None:
    from cdgps_cli.io.atomic import write_bytes_atomic

    write_bytes_atomic(path, (json.dumps(data, indent=2) + "\n").encode())


def _write_text_atomic(path: str, text: str) -> None:
    from cdgps_cli.io.atomic import write_atomic

    write_atomic(path, lambda tmp: Path(tmp).write_text(text))


def _with(opts):
    def deco(f):
        for o in reversed(opts):
            f = o(f)
        return f
    return deco


def _report_outputs(json_help: str = "Print report.json on stdout.", dated_by: str = "the newest input's"):
    """--date, -o/--output (the report's folder) and --json of the report commands (``dated_by``: whose
    modification time dates the report by default)."""
    return _with([
        click.option("--date", "date", default=None, metavar="ISO_DATE",
                     help=f"Date printed in the report (default: $SOURCE_DATE_EPOCH, else {dated_by} "
                          "modification time)."),
        click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
                     help="Output directory."),
        click.option("--json", "as_json", is_flag=True, help=json_help),
    ])
