"""Honest σ of estimate's per-epoch states with phase multipath states (``[gnss.displacement] multipath``).

For each pair: ``cdgps config`` (random walk, ``phase_noise = "auto"``), ``ingest``, ``init``, then ``estimate`` with
``multipath = "off"`` and ``"auto"``, filtered and smoothed; NEES per dof of the E/N/U states (their diagonal σ)
against a reference, the error RMS, the mean σ, and the command's wall time and peak RSS.

References: a static real pair's own static solution (the INIT's; its error is common to every epoch and is not
counted), a simulated pair's truth.csv.  Pairs:

* simulated, 1200 s at 1 Hz, random walk 1 mm/√s, 1 mm white phase noise, with and without a Gauss–Markov phase
  multipath (σ 5 mm, τ 40 s: ``simulate-gnss --multipath-m 0.005 --multipath-tau-s 40``), seeds 1–3;
* ../shared/data/real-pairs/mosaic-static (two Septentrio mosaic-X5, 5 min, GPS L1 + Galileo E1);
* ``--m8p DIR``: the u-blox M8P pair of jdesbonnet/GNSS_RTK_data (convbin's base1.obs, rover1.obs, base1.nav;
  20 min at 1 Hz, GPS L1; no licence, so not in ../shared);
* ``--f9p DIR``: a u-blox F9P pair (DIR/base/*.obs, *.nav, DIR/rover/*.obs; 4 h at 15 s, GPS L1).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/gnss_multipath.py [--m8p DIR] [--f9p DIR] --out X.json``.
"""

from __future__ import annotations

import json
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CDGPS = str(Path(sys.executable).parent / "cdgps")
MOSAIC = ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"


def _run(args: list) -> tuple[str, float, float]:
    """stdout, wall s, peak RSS MiB of ``cdgps -q ARGS`` (GNU time)."""
    t0 = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-f", "%M", CDGPS, "-q", *map(str, args)], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"cdgps {' '.join(map(str, args))} failed:\n{p.stderr}")
    rss = int(p.stderr.strip().splitlines()[-1]) / 1024.0
    return p.stdout, wall, rss


def _with(text: str, mode: str) -> str:
    text = re.sub(r"^# phase_noise = .*$", "", text, flags=re.M)
    return text.replace('model = "random_walk"', f'model = "random_walk"\nphase_noise = "auto"\nmultipath = "{mode}"', 1)


def _nees_against(states_path: Path, truth_dir: Path | None) -> dict:
    """NEES per dof (diagonal σ), error RMS and σ RMS (mm) of the rover's E/N/U states: against a simulated pair's
    truth by ``cdgps evaluate`` (``truth_dir``), else against the pair's static solution (its own INIT's)."""
    from cdgps_cli.io.states import States

    if truth_dir is not None:
        ev = json.loads(_run(["evaluate", "--truth", truth_dir, "--estimate", states_path, "--json"])[0])
        return {"rover": {"nees_per_dof": ev["nees"]["mean"] / ev["nees"]["dof"],
                          "error_rms_mm": [1e3 * v for v in ev["rms_error"].values()]}}
    st = States(states_path)
    rov = st.metadata["rovers"]
    rov = json.loads(rov) if isinstance(rov, str) else rov
    out = {}
    for r, v in rov.items():
        names = list(v["static_enu_m"])
        cols = [st.coord_names.index(n) for n in names]
        q, s = np.asarray(st.q)[:, cols], np.asarray(st.sigma_q)[:, cols]
        e = q - np.array([v["static_enu_m"][n] for n in names])
        ok = np.isfinite(e).all(axis=1) & (s > 0).all(axis=1)
        out[r] = {"epochs": int(ok.sum()), "nees_per_dof": float(np.mean((e[ok] / s[ok]) ** 2)),
                  "error_rms_mm": [float(x) for x in 1e3 * np.sqrt(np.mean(e[ok] ** 2, axis=0))],
                  "sigma_rms_mm": [float(x) for x in 1e3 * np.sqrt(np.mean(s[ok] ** 2, axis=0))]}
    return out


def one_pair(name: str, cfg_text: str, work: Path, truth: Path | None) -> dict:
    rows = {}
    for mode in ("off", "auto"):
        cfg = work / f"{mode}.toml"
        cfg.write_text(_with(cfg_text, mode))
        _run(["ingest", "--config", cfg, "-o", work / f"run_{mode}.mcap"])
        _run(["init", work / f"run_{mode}.mcap", "-o", work / f"init_{mode}.json"])
        for smooth in (False, True):
            tag = f"{mode}{'_smoothed' if smooth else '_filtered'}"
            out, wall, rss = _run(["estimate", work / f"run_{mode}.mcap", "--init", work / f"init_{mode}.json",
                                   *(["--smooth"] if smooth else []), "-o", work / f"{tag}.mcap", "--json"])
            summary = json.loads(out)
            rows[tag] = {"wall_s": round(wall, 3), "peak_rss_mib": round(rss, 1),
                         "states": _nees_against(work / f"{tag}.mcap", truth),
                         "multipath": {r: v.get("multipath") for r, v in summary["rovers"].items()}}
            print(name, tag, json.dumps({r: round(v["nees_per_dof"], 2) for r, v in rows[tag]["states"].items()}),
                  f"{wall:.2f} s", flush=True)
    return rows


def main() -> None:
    out_path = Path(sys.argv[sys.argv.index("--out") + 1]) if "--out" in sys.argv else None
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for seed in (1, 2, 3):
            for mp in (0.0, 0.005):
                d = tmp / f"sim{seed}_{mp}"
                _run(["simulate-gnss", "--duration", 1200, "--seed", seed, "--phase-noise-m", 0.001, "--random-walk",
                      0.001, "--multipath-m", mp, "--multipath-tau-s", 40, "-o", d])
                name = f"simulated seed {seed}, multipath {mp * 1e3:g} mm / 40 s"
                results[name] = one_pair(name, (d / "config.toml").read_text(), d, d)
        pairs = {}
        if MOSAIC.exists():
            pairs["mosaic-static (G:L1, E:E1)"] = (["--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex",
                                                    f"rover={MOSAIC / 'rover.obs'}", "--nav", MOSAIC / "base.nav",
                                                    "--signals", "G:L1,E:E1"])
        if "--m8p" in sys.argv:
            m = Path(sys.argv[sys.argv.index("--m8p") + 1])
            pairs["u-blox M8P pair (G:L1)"] = ["--rinex", f"base={m / 'base1.obs'}", "--rinex",
                                               f"rover={m / 'rover1.obs'}", "--nav", m / "base1.nav", "--signals", "G:L1"]
        if "--f9p" in sys.argv:
            f = Path(sys.argv[sys.argv.index("--f9p") + 1])
            pairs["u-blox F9P pair, 15 s (G:L1)"] = ["--rinex", f"base={next((f / 'base').glob('*.obs'))}", "--rinex",
                                                     f"rover={next((f / 'rover').glob('*.obs'))}", "--nav",
                                                     next((f / 'base').glob('*.nav')), "--signals", "G:L1"]
        for name, args in pairs.items():
            d = tmp / re.sub(r"\W+", "_", name)
            d.mkdir()
            _run(["config", *args, "--master", "base", "--displacement", "random_walk", "-o", d / "c.toml"])
            results[name] = one_pair(name, (d / "c.toml").read_text(), d, None)
    doc = {"benchmark": "benchmarks/gnss_multipath.py", "machine": platform.processor() or platform.machine(),
           "python": platform.python_version(), "reference": "simulated: truth.csv; real: the static solution",
           "results": results}
    text = json.dumps(doc, indent=1) + "\n"
    if out_path:
        out_path.write_text(text)
    else:
        print(text)


if __name__ == "__main__":
    main()
