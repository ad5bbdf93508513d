#!/usr/bin/env python3
"""Where the time of a whole ``cdgps rtk`` run goes, per case of ``bench_rtk_rtklib.py`` (issue 28 item 6).

Each case runs once in a child process under cProfile (``python -m cProfile -m cdgps_cli.cli.commands
rtk ...``, bytecode caches warm); the stages are the cumulative times of the functions that carry
them: imports (``import`` of the CLI and pipeline modules), reading the observation files
(``read_rinex_signals``; a u-blox log: ``_ubx_decoded``, its RXM-RAWX and SFRBX) and navigation
files (``read_rinex_nav``), satellite geometry
(``receiver_geometry``: ephemeris selection, orbits, az/el, troposphere), the filter passes
(``_filter_pass``; of which ambiguity resolution ``_fix``), and the output.  Profiling adds its own
overhead (≈ ×1.5–2 on the Python-heavy parts): the shares, not the seconds, are the figures.
Writes ``docs/benchmarks/rtk_profile.json``::

    PYTHONPATH=. python benchmarks/profile_rtk.py
"""

from __future__ import annotations

import json
import os
import pstats
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_rtk_rtklib import USER_ENV, cases, cdgps_command  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "rtk_profile.json"
STAGES = {"read_observations": ("rinex_signals.py", "read_rinex_signals"),
          "read_navigation": ("rinex.py", "read_rinex_nav"),
          "read_ubx_log_signals_and_sfrbx": ("gnss_multi.py", "_ubx_decoded"),
          "geometry": ("rtk_multi.py", "receiver_geometry"),
          "filter_passes": ("rtk_multi.py", "_filter_pass"),
          "of_which_ambiguity_fix": ("rtk_multi.py", "_fix"),
          "write_solution": ("gnss_multi.py", "solution_text"),
          "whole_rtk_command": ("gnss_commands.py", "rtk")}


def profile_case(c, tmp: Path) -> dict:
    cmd, _ = cdgps_command(c, tmp)
    prof = tmp / "rtk.prof"
    args = [sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "cdgps_cli.cli.commands", *cmd[1:]]
    subprocess.run(args, capture_output=True, env=USER_ENV, check=True)       # warm-up: bytecode caches
    subprocess.run(args, capture_output=True, env=USER_ENV, check=True)
    st = pstats.Stats(str(prof))
    cum = {}
    for (file, _, func), (_, _, _, ct, _) in st.stats.items():
        for stage, (fname, fn) in STAGES.items():
            if func == fn and file.endswith(fname):
                cum[stage] = cum.get(stage, 0.0) + ct
    top = sorted(((v[2], f"{Path(k[0]).name}:{k[2]}") for k, v in st.stats.items()), reverse=True)[:8]
    whole = cum.get("whole_rtk_command", 0.0)
    return {"profiled_total_s": round(st.total_tt, 3),
            "stages_s": {k: round(v, 3) for k, v in cum.items()},
            "stage_share_of_rtk_command": {k: round(v / whole, 3) for k, v in cum.items() if whole},
            "outside_rtk_command_s (imports, start-up)": round(st.total_tt - whole, 3),
            "top_self_time": [[round(t, 3), name] for t, name in top]}


def main() -> None:
    res = {"load_average_1min_at_start": round(os.getloadavg()[0], 2), "cases": {}}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for c in cases(tmp):
            res["cases"][c["name"]] = row = profile_case(c, tmp)
            print(c["name"], json.dumps(row), flush=True)
    res["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    OUT.write_text(json.dumps(res, indent=1) + "\n")
    print("wrote", OUT)


if __name__ == "__main__":
    main()
