"""The report tests' simulated runs through the whole library pipeline (simulate → write_run → read_run →
initialize → estimate --smooth → write_states), files as the CLI writes them. One helper for
test_sensor_reports.py and test_run_report.py, which share the 300 s testbed free-vibration run
(conftest.py's ``testbed_free_run``) instead of computing it once per file."""

from __future__ import annotations

import json
from pathlib import Path

from cdgps_cli.config.structure import load_config
from cdgps_cli.estimation.filter import EstimateOptions, estimate
from cdgps_cli.estimation.initializer import InitOptions, initialize
from cdgps_cli.io.run import read_run, write_run
from cdgps_cli.pipeline.estimate_outputs import write_states
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "configs" / "testbed-1998-lumped.toml"


def pipeline(d: Path, sim_opt: SimOptions, rest_from_truth: bool = False, cfg_path: Path = TESTBED) -> dict:
    """The whole chain on ``cfg_path`` into folder ``d``; ``rest_from_truth``: estimate in static mode
    from the rest time the experimenter knows (``--rest START:``). Returns the folder ``dir``, the
    simulation's ``truth`` dict, its folder ``sim`` and the paths ``states`` and ``run``."""
    cfg = load_config(cfg_path)
    sim = simulate(cfg, sim_opt)
    write_simulation(sim, d / "sim")
    write_run(cfg, d / "sim" / "receiver.csv", d / "run.mcap", d / "sim" / "gyro.csv")
    run = read_run(d / "run.mcap")
    init = initialize(run, InitOptions())
    init.pop("elapsed_s", None)
    text = json.dumps(init, indent=2) + "\n"
    (d / "init.json").write_text(text)
    rest = [(s["start_s"], float("inf")) for s in sim.truth["segments"] if s["kind"] == "rest"] if rest_from_truth else []
    opt = EstimateOptions(smooth=True, rest_segments_s=tuple(rest))
    res = estimate(run, json.loads(text), opt)
    write_states(res, d / "run.mcap", json.loads(text), text, d / "states.mcap", opt.echo())
    return {"dir": d, "truth": sim.truth, "sim": d / "sim", "states": d / "states.mcap", "run": d / "run.mcap"}
