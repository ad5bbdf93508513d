#!/usr/bin/env python3
"""Modal estimate of a structure on GPS alone vs GPS + Galileo (+ BeiDou), single and dual frequency — issue 14 item 6.

Per seed and signal set: ``simulate_structure_gnss(signals=…)`` of configs/gnss-tower.toml (the same
structure motion for every set of a seed: the motion depends on the seed only; GPS satellites are the
same synthetic constellation, Galileo and BeiDou — GEO, IGSO and MEO — are added) → ``cdgps ingest``
→ ``cdgps init`` → the modal batch initialization (:func:`cdgps_cli.pipeline.gnss_modal.gnss_modal_init`)
on windows of 10, 15, 20, 30 and 60 s → the filter with the 60 s window's integers (:func:`gnss_modal_estimate`, smoothed) →
``cdgps evaluate`` against the truth.  Every set goes through the same multi-signal modal path (one DD
group per rover and signal, own reference, own wavelength; all integers fixed as one set).

Recorded per row: **time to first fix** = the shortest of those windows whose integers are all fixed
and all right (against the simulator's: (N_r^j − N_m^j) − (N_r^ref − N_m^ref) per signal), the
integers fixed / right / wrong in the 60 s window, the smoothed modal RMS error per coordinate
(after 20 s), and NEES/dof of the smoothed states (``cdgps evaluate``'s, after 20 s).  Rows go to OUT.partial as they
finish (removed when the table is written)::

    python benchmarks/gnss_modal_signals.py [--seeds 3] [--duration 180] [--sets NAME ...] [--out JSON]

``--sets`` picks signal sets by name (default: the three GPS/Galileo sets of the first study; the
BeiDou study ran ``--sets "GPS L1" "GPS+Galileo dual (L1 L2 E1 E5a)" "GPS+Galileo+BeiDou L1/E1/B1I"
"GPS+Galileo+BeiDou dual (L1 L2 E1 E5a B1I B2a)" --out docs/benchmarks/gnss_modal_signals_beidou.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from click.testing import CliRunner  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.cli.commands import main  # noqa: E402
from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.io.gnss_run import read_gnss_run  # noqa: E402
from cdgps_cli.pipeline.gnss_modal import gnss_modal_estimate, gnss_modal_init, simulate_structure_gnss  # noqa: E402

TOWER = ROOT / "configs" / "gnss-tower.toml"
SETS = {"GPS L1": ("G:L1",), "GPS+Galileo L1/E1": ("G:L1", "E:E1"),
        "GPS+Galileo dual (L1 L2 E1 E5a)": ("G:L1", "G:L2", "E:E1", "E:E5a"),
        "GPS+Galileo+BeiDou L1/E1/B1I": ("G:L1", "E:E1", "C:B1I"),
        "GPS+Galileo+BeiDou dual (L1 L2 E1 E5a B1I B2a)": ("G:L1", "G:L2", "E:E1", "E:E5a", "C:B1I", "C:B2a")}
DEFAULT_SETS = tuple(SETS)[:3]
WINDOWS_S = (10.0, 15.0, 20.0, 30.0, 60.0)


def _cli(*args) -> str:
    r = CliRunner().invoke(main, ["-q", *map(str, args)])
    if r.exit_code != 0:
        raise RuntimeError(f"cdgps {' '.join(map(str, args))}: {r.output}")
    return r.stdout


def _score(rec: dict, sim: dict, rovers: list, per_rover: int) -> tuple[int, int, int]:
    """(segments, right, wrong) of a modal-init record against the simulated integers."""
    ints, master = sim["integers"], sim["master"]
    right = wrong = 0
    for sg in rec.get("segments", []):
        if not sg["fixed"]:
            continue
        g, rx = sg["signal"], sim["receivers"][rovers[sg["rover_slot"] // per_rover]]
        j, k = sg["satellite"].split(":")[0], sg["reference"].split(":")[0]
        want = (ints[rx][g][j] - ints[master][g][j]) - (ints[rx][g][k] - ints[master][g][k])
        right += int(sg["integer_cycles"] == want)
        wrong += int(sg["integer_cycles"] != want)
    return int(rec.get("n_segments", 0)), right, wrong


def one_row(seed: int, name: str, signals: tuple, duration_s: float, tmp: Path) -> dict:
    cfg = load_config(TOWER)
    sim = simulate_structure_gnss(tmp, cfg, duration_s=duration_s, seed=seed, signals=signals)
    _cli("ingest", "--config", tmp / "config.toml", "-o", tmp / "run.mcap")
    _cli("init", tmp / "run.mcap", "-o", tmp / "init.json")
    run = read_gnss_run(tmp / "run.mcap")
    init = json.loads((tmp / "init.json").read_text())
    rovers = [a for a in cfg.antenna_names if a != cfg.antenna_names[cfg.master_index]]
    ttff, per_window = None, {}
    t0 = time.perf_counter()
    for w in WINDOWS_S:
        rec = gnss_modal_init(run, init, cfg, window_s=w)
        n, right, wrong = _score(rec, sim, rovers, len(signals))
        per_window[w] = {"segments": n, "fixed": int(rec.get("n_fixed", 0)), "right": right, "wrong": wrong,
                         "note": rec.get("integer_fixing", rec.get("refused"))}
        if ttff is None and n and right == n:
            ttff = w
    init_s = (time.perf_counter() - t0) / len(WINDOWS_S)
    text = (tmp / "init.json").read_text()
    gnss_modal_estimate(run, init, text, cfg, tmp / "states.mcap", smooth=True, init_window_s=60.0)
    ev = json.loads(_cli("evaluate", "--truth", tmp, "--estimate", tmp / "states.mcap", "--json", "--converge-s", 20))
    w60 = per_window[60.0]
    return {"seed": seed, "set": name, "signals": list(signals), "ttff_s": ttff, "window60": w60,
            "windows": {str(k): v for k, v in per_window.items()}, "mean_modal_init_s": init_s,
            "rms_error": ev["rms_error"], "nees_per_dof": ev["nees"]["mean"] / len(cfg.coord_names),
            "nis_per_dof": ev["nis"]["mean_per_dof"]}


def main_(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration", type=float, default=180.0)
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "gnss_modal_signals.json"))
    ap.add_argument("--sets", nargs="+", default=list(DEFAULT_SETS), choices=list(SETS), metavar="NAME")
    a = ap.parse_args(argv)
    sets = {k: SETS[k] for k in a.sets}
    part = Path(a.out + ".partial")
    part.parent.mkdir(parents=True, exist_ok=True)
    part.write_text("")
    rows = []
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    for seed in range(a.seeds):
        for name, sigs in sets.items():
            with tempfile.TemporaryDirectory() as d:
                row = one_row(seed, name, sigs, a.duration, Path(d))
            rows.append(row)
            with part.open("a") as f:
                f.write(json.dumps(row) + "\n")
            w = row["window60"]
            print(f"seed {seed} {name:32s} TTFF {row['ttff_s']} s, 60 s window {w['right']}/{w['segments']} right "
                  f"{w['wrong']} wrong, RMS " + ", ".join(f"{k} {v:.4g}" for k, v in row["rms_error"].items())
                  + f", NEES/dof {row['nees_per_dof']:.2f}", file=sys.stderr)
    summary = {}
    for name in sets:
        rs = [r for r in rows if r["set"] == name]
        summary[name] = {
            "ttff_s": [r["ttff_s"] for r in rs],
            "windows_all_right": {str(w): sum(r["windows"][str(w)]["right"] == r["windows"][str(w)]["segments"] > 0
                                              for r in rs) for w in WINDOWS_S},
            "wrong_any_window": sum(v["wrong"] for r in rs for v in r["windows"].values()),
            "segments_60s": [r["window60"]["segments"] for r in rs],
            "window60_all_right": sum(r["window60"]["right"] == r["window60"]["segments"] > 0 for r in rs),
            "window60_wrong": sum(r["window60"]["wrong"] for r in rs),
            "rms_error_mean": {k: float(np.mean([r["rms_error"][k] for r in rs])) for k in rs[0]["rms_error"]},
            "nees_per_dof": [round(r["nees_per_dof"], 3) for r in rs],
            "mean_modal_init_s": float(np.mean([r["mean_modal_init_s"] for r in rs])),
        }
    out = {"seeds": a.seeds, "duration_s": a.duration, "sets": {k: list(v) for k, v in sets.items()}, "windows_s": list(WINDOWS_S), "elapsed_s": time.perf_counter() - t0,
           "load_average_start": load0, "load_average_end": os.getloadavg(), "summary": summary, "rows": rows}
    Path(a.out).write_text(json.dumps(out, indent=2) + "\n")
    part.unlink()
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main_()
