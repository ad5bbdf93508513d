"""Issue 12 item 1: no command overwrites one of its inputs, however the output path is spelt.

The test walks every command of the CLI (new commands are included automatically): each one
given an output path that is one of its inputs must exit 2 naming both, and leave the input
byte-identical with nothing written.
"""

from __future__ import annotations

import os

import click
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.cli.guard import OUTPUT_PARAMS, _is_named_files

from _shared import cli_commands

NO_OUTPUT = {"info", "evaluate"}


COMMANDS = list(cli_commands(main))


def test_every_command_is_guarded_and_known():
    for path, cmd in COMMANDS:
        has_out = any(p.name in OUTPUT_PARAMS for p in cmd.params)
        assert has_out or path[-1] in NO_OUTPUT, f"{' '.join(path)}: output parameter not recognised"


def _invocation(cmd: click.Command, tmp_path, spell: str):
    """Arguments with a dummy file for every input, and the output spelt as (or around) the first input."""
    args, first, out_param = [], None, None
    for i, p in enumerate(cmd.params):
        if p.name in OUTPUT_PARAMS:
            out_param = out_param or p            # the command's first output (-o); others stay unset
            continue
        f = tmp_path / "in" / f"input{i}.dat"
        f.parent.mkdir(exist_ok=True)
        f.write_bytes(f"original {i}\n".encode())
        if isinstance(p.type, click.Path):
            value = str(f.parent if not p.type.file_okay else f)
        elif _is_named_files(p):
            value = f"A={f}"
        elif p.required and isinstance(p.type, click.Choice):
            value = str(p.type.choices[0])
        elif p.required and p.type.name in ("float", "integer", "finite float"):
            value = "1"
        elif p.required:
            value = "x"
        else:
            continue
        if isinstance(p.type, click.Path) and not p.type.file_okay:
            pass
        elif first is None:
            first = f
        args += [value] if isinstance(p, click.Argument) else [p.opts[0], value]
    assert first is not None and out_param is not None
    target = first.parent if not out_param.type.file_okay else first
    if spell == "dot":
        out = f"{target.parent}/./{target.name}"
    elif spell == "symlink":
        out = tmp_path / "link"
        out.symlink_to(target)
    elif spell == "hardlink":
        if target.is_dir():
            pytest.skip("directories have no hard links")
        out = tmp_path / "hard"
        os.link(target, out)
    else:
        out = target
    return args + [out_param.opts[0], str(out)], first


@pytest.mark.parametrize("spell", ["same", "dot", "symlink", "hardlink"])
@pytest.mark.parametrize("path,cmd", [c for c in COMMANDS if c[0][-1] not in NO_OUTPUT], ids=lambda c: " ".join(c) if isinstance(c, tuple) else "")
def test_command_refuses_to_overwrite_its_input(tmp_path, path, cmd, spell):
    args, victim = _invocation(cmd, tmp_path, spell)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    r = CliRunner().invoke(main, ["-q", *path, *args])
    assert r.exit_code == 2, (args, r.output)
    assert "would overwrite an input" in r.stderr and str(victim.name) in r.stderr
    assert victim.read_bytes().startswith(b"original")
    assert sorted(p.name for p in tmp_path.rglob("*")) == before        # nothing written


def test_gnss_config_listed_files_are_inputs_too(tmp_path):
    obs = tmp_path / "a.obs"
    obs.write_text("original\n")
    cfg = tmp_path / "run.toml"
    cfg.write_text('[gnss]\nname = "t"\nmaster = "A"\nnav = []\n[gnss.antennas.A]\nrinex = "a.obs"\n')
    r = CliRunner().invoke(main, ["-q", "ingest", "--config", str(cfg), "-o", str(obs)])
    if "would overwrite" not in r.stderr:
        pytest.skip(f"config format differs: {r.stderr[:200]}")
    assert r.exit_code == 2 and obs.read_text() == "original\n"


def test_distinct_output_is_not_refused(tmp_path):
    from cdgps_cli.io.atomic import refuse_input_overwrite

    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("x")
    refuse_input_overwrite([("-o", str(b), False), ("-o", str(tmp_path / "d"), True)], [("RUN", str(a), False)])


@pytest.mark.parametrize("path,cmd", [c for c in COMMANDS if c[0][-1] not in NO_OUTPUT], ids=lambda c: " ".join(c) if isinstance(c, tuple) else "")
def test_command_refuses_an_empty_output_path(tmp_path, path, cmd):
    """Issue 32: `ingest -o ''` ended in a traceback; every command now names the option."""
    args, _ = _invocation(cmd, tmp_path, "same")
    args[-1] = ""
    before = sorted(p.name for p in tmp_path.rglob("*"))
    r = CliRunner().invoke(main, ["-q", *path, *args])
    assert r.exit_code == 2 and "expected a file or folder path, got an empty string" in r.stderr, (args, r.output)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_two_outputs_on_one_path_are_refused(tmp_path):
    from cdgps_cli.io.atomic import refuse_output_collisions

    refuse_output_collisions([("-o", str(tmp_path / "a"), False), ("--figure", str(tmp_path / "b"), False)])
    (tmp_path / "d").mkdir()
    with pytest.raises(Exception, match="--figure .* is the same path as -o"):
        refuse_output_collisions([("-o", str(tmp_path / "a"), False), ("--figure", f"{tmp_path}/d/../a", False)])


@pytest.mark.parametrize("path,cmd", [c for c in COMMANDS if c[0][-1] not in NO_OUTPUT], ids=lambda c: " ".join(c) if isinstance(c, tuple) else "")
def test_command_refuses_an_output_where_a_pipe_is(tmp_path, path, cmd):
    """The atomic rename replaced a device or FIFO at the output path by a regular file (run as root,
    `rtk -o /dev/full` replaced /dev/full); every command now refuses it before any work."""
    import stat

    args, _ = _invocation(cmd, tmp_path, "same")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    args[-1] = str(fifo)
    r = CliRunner().invoke(main, ["-q", *path, *args])
    assert r.exit_code == 2 and f"{fifo} is a pipe (FIFO)" in r.stderr and "refused, nothing written" in r.stderr, (args, r.output)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_atomic_writers_refuse_a_device_or_pipe(tmp_path):
    import stat

    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.io.atomic import write_bytes_atomic

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(CdgpsError, match=r"fifo is a pipe \(FIFO\): cdgps writes a complete new file"):
        write_bytes_atomic(fifo, b"x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    write_bytes_atomic(tmp_path / "plain", b"x")
    write_bytes_atomic(tmp_path / "plain", b"y")
    assert (tmp_path / "plain").read_bytes() == b"y"
