"""What real command runs load (issue 29 item 3): `cdgps info` and `cdgps rtk` pay for neither
plotting, nor dask, nor scipy; `info` reads an MCAP without pandas or the MCAP writer; `rtk` writes CSV without the MCAP
library.  Each run is a fresh interpreter that lists ``sys.modules`` after the command."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from _shared import REPO_ROOT, run_commands

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
NEVER = ("matplotlib", "dask", "distributed", "scipy")


def _loaded_by(args: list[str]) -> set[str]:
    """Modules in ``sys.modules`` (and their top-level packages) after ``cdgps ARGS`` ran (it must succeed)."""
    code = ("import sys, json\nfrom cdgps_cli.cli.commands import main\n"
            f"try:\n    main({args!r})\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "print(json.dumps(sorted(sys.modules)))")
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    names = set(json.loads(p.stdout.strip().splitlines()[-1]))
    return names | {m.split('.')[0] for m in names}


def test_info_loads_no_pandas_plotting_dask_or_scipy(tmp_path, dof2_path):
    run_commands(("simulate", dof2_path, "--duration", 5, "--seed", 1, "--out", tmp_path / "s"),
                 ("ingest", tmp_path / "s/receiver.csv", tmp_path / "s/gyro.csv", "--config", dof2_path,
                  "-o", tmp_path / "run.mcap"))
    loaded = _loaded_by(["-q", "info", str(tmp_path / "run.mcap")])
    assert "mcap" in loaded and "cdgps_cli" in loaded                   # the probe itself works
    assert not [m for m in NEVER + ("pandas", "mcap.writer") if m in loaded], sorted(loaded)


def test_rtk_loads_no_plotting_dask_scipy_or_mcap(tmp_path):
    loaded = _loaded_by(["-q", "rtk", "--base", str(MOSAIC / "base.obs"), "--rover", str(MOSAIC / "rover.obs"),
                         "--nav", str(MOSAIC / "base.nav"), "--signals", "G:L1",
                         "--base-xyz", "-3817681.1213", "3562839.4311", "3650159.1593", "-o", str(tmp_path / "r.csv")])
    assert "numpy" in loaded and (tmp_path / "r.csv").is_file()
    # nor the structure-config reader (TOML, schema, validation): rtk takes its options from the command line
    assert not [m for m in NEVER + ("mcap", "zstandard", "cdgps_cli.config.structure", "tomllib") if m in loaded], \
        sorted(loaded)


def test_rtk_on_a_ublox_log_loads_neither_the_ingest_pipeline_nor_mcap(tmp_path):
    """A UBX base's loss-of-lock bits come from measurement.channels, not from the ingest pipeline
    (whose imports, the MCAP run reader/writer and the structure config, are another command's)."""
    walk = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "ublox-walk"
    loaded = _loaded_by(["-q", "rtk", "--base", str(walk / "gnss_1730.ubx"), "--rover", str(walk / "gnss_1730_convbin.obs"),
                         "--signals", "G:L1,E:E1", "--base-xyz", "-1276975.6547", "-4717238.8712", "4087235.6076",
                         "-o", str(tmp_path / "r.csv")])
    assert "cdgps_cli.io.ubx" in loaded and (tmp_path / "r.csv").is_file()      # the probe itself works
    assert not [m for m in NEVER + ("mcap", "zstandard", "cdgps_cli.pipeline.gnss_ingest", "cdgps_cli.io.gnss_run",
                                    "cdgps_cli.config.structure", "tomllib") if m in loaded], sorted(loaded)
