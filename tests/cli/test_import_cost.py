"""What a command pays before it starts (issue 13 item 5): the CLI module imports only click and
cdgps' light modules, each subcommand imports its own dependencies in its body, and `cdgps estimate`
on a structure run never loads plotting, dask or the sparse-matrix code."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("numpy", "pandas", "scipy", "matplotlib", "dask", "distributed", "mcap", "zstandard")


def _modules_after(code: str) -> set[str]:
    """Top-level and dotted module names loaded by a fresh interpreter after ``code``."""
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys, json; print(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True)
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_cli_module_and_help_import_nothing_heavy():
    for code in ("import cdgps_cli.cli.commands",
                 "from cdgps_cli.cli.commands import main\n"
                 "try:\n    main(['--help'])\nexcept SystemExit:\n    pass",
                 "from cdgps_cli.cli.commands import main\n"
                 "try:\n    main(['estimate', '--help'])\nexcept SystemExit:\n    pass"):
        loaded = _modules_after(code)
        assert not [m for m in HEAVY if m in loaded], (code, [m for m in HEAVY if m in loaded])


def test_estimate_path_loads_no_plotting_dask_sparse_or_pandas():
    """The modules `cdgps init` / `cdgps estimate` import on a structure run (initializer, filter, RUN
    reader, STATES writer); a run's tables are numpy columns (core/table.Table), so no pandas."""
    loaded = _modules_after("import cdgps_cli.estimation.filter, cdgps_cli.io.run, cdgps_cli.io.states, "
                            "cdgps_cli.pipeline.estimate_outputs, cdgps_cli.model.kinematics, "
                            "cdgps_cli.estimation.initializer, cdgps_cli.io.file_checks, cdgps_cli.analysis.preview\n"
                            "from cdgps_cli.estimation.chi2 import chi2_quantile\n"
                            "chi2_quantile(0.999, [1, 2, 30])\n"
                            "cdgps_cli.analysis.preview.preview_filter(10)")
    assert "numpy" in loaded and "cdgps_cli.estimation.filter" in loaded        # the probe itself works
    for name in ("matplotlib", "dask", "distributed", "scipy.sparse", "scipy.stats", "scipy.optimize", "pandas",
                 "scipy.special"):
        assert name not in loaded, name


def test_the_collector_threshold_is_raised_while_a_command_runs_and_restored():
    import gc

    from click.testing import CliRunner

    from cdgps_cli.cli import commands
    seen = []
    before = gc.get_threshold()
    real = commands._Group.invoke

    def spy(self, ctx):
        seen.append(gc.get_threshold())
        return real(self, ctx)

    commands._Group.invoke = spy
    try:
        r = CliRunner().invoke(commands.main, ["info", "--help"])
    finally:
        commands._Group.invoke = real
    assert r.exit_code == 0, r.output
    assert seen and seen[0] == commands._GC_THRESHOLDS
    assert gc.get_threshold() == before
