"""Displacement states (``cdgps init`` / ``cdgps estimate``) with ``[gnss] signals`` against truth and ``cdgps rtk``
(issue 14 item 4).

    .venv/bin/python benchmarks/bench_disp_signals.py [--out docs/benchmarks/disp_signals.json]

rinex-ge (Spirent hardware simulation, 10 min at 1 Hz, base and a static rover 2 km east with true
ECEF positions): the rover's nominal position is its true one, so the static displacement is the
error.  Per signal set: ingest, init, estimate (static) as separate processes (wall clock), DD
integers fixed, |static − truth|, the single-epoch (kinematic, fixed integers) scatter against the
truth; and ``cdgps rtk --mode static`` on the same signals.  GEONET 3040 → 0759 (1 h, 30 s): the
static solution with G:L1 + G:L2 against G:L1.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
CDGPS = str(ROOT / ".venv" / "bin" / "cdgps")
DATA = ROOT.parent / "shared" / "data"
GE = DATA / "rinex-ge"
BASE_XYZ = [4157177.06580187, 671230.476590636, 4774767.03105544]
ROVER_XYZ = [4156857.1195929, 673209.028774142, 4774767.03105544]
SETS = {"GPS L1": ["G:L1"],
        "GPS L1/L2 + Galileo E1/E5a": ["G:L1", "G:L2", "E:E1", "E:E5a"],
        "GPS L1/L2/L5 + Galileo E1/E5a/E5b": ["G:L1", "G:L2", "G:L5", "E:E1", "E:E5a", "E:E5b"]}


def _run(*args) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([CDGPS, "-q", *map(str, args)], capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"cdgps {' '.join(map(str, args))} failed: {r.stderr}")
    return time.perf_counter() - t0


def _ge_config(d: Path, signals: list) -> Path:
    nav = [GE / "RINEX_GN_Spirent.23N"] + ([GE / "RINEX_EN_Spirent.23L"] if any(s[0] == "E" for s in signals) else [])
    cfg = d / "job.toml"
    cfg.write_text("[gnss]\nmaster = \"base\"\n" + (f"signals = {json.dumps(signals)}\n" if signals != ["G:L1"] else "")
                   + f"nav = {json.dumps([str(p) for p in nav])}\n"
                   + f"[gnss.antennas.base]\nrinex = \"{GE / 'Base-static_MO_Spirent.obs'}\"\nposition_ecef_m = {BASE_XYZ}\n"
                   + f"[gnss.antennas.rover]\nrinex = \"{GE / 'Rover-static-2km-east_MO_Spirent.obs'}\"\n"
                   + f"position_ecef_m = {ROVER_XYZ}\n")
    return cfg


def _pipeline(d: Path, cfg: Path) -> dict:
    t = {"ingest_s": _run("ingest", "--config", cfg, "-o", d / "run.mcap"),
         "init_s": _run("init", d / "run.mcap", "-o", d / "init.json"),
         "estimate_s": _run("estimate", d / "run.mcap", "--init", d / "init.json", "-o", d / "states.mcap")}
    _run("export", d / "states.mcap", "--kinematic", "-o", d / "kin.csv")
    init = json.loads((d / "init.json").read_text())
    return {"init": init, "kin": pd.read_csv(d / "kin.csv"), **t}


def ge_case(name: str, signals: list) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        p = _pipeline(d, _ge_config(d, signals))
        rov = p["init"]["rovers"]["rover"]
        enu = np.array(list(p["init"]["states"].values()))
        k = p["kin"][["rover_e", "rover_n", "rover_u"]].to_numpy()
        t0 = time.perf_counter()
        _run("rtk", "--base", GE / "Base-static_MO_Spirent.obs", "--rover", GE / "Rover-static-2km-east_MO_Spirent.obs",
             "--nav", GE / "RINEX_GN_Spirent.23N", "--nav", GE / "RINEX_EN_Spirent.23L", "--signals", ",".join(signals),
             "--mode", "static", "--base-xyz", *BASE_XYZ, "-o", d / "rtk.csv")
        rtk_s = time.perf_counter() - t0
        rtk = pd.read_csv(d / "rtk.csv", comment="#").iloc[-1]
        rtk_err = float(np.linalg.norm(rtk[["x_m", "y_m", "z_m"]].to_numpy(dtype=float) - np.array(ROVER_XYZ)))
    return {"set": name, "signals": signals, "dd_integers_fixed": rov["n_fixed"], "dd_integers": rov["n_estimated"],
            "ratio": rov["ratio"], "static_enu_mm": (1e3 * enu).round(3).tolist(),
            "static_error_mm": round(1e3 * float(np.linalg.norm(enu)), 3),
            "kinematic_epochs": int(len(k)),
            "kinematic_rms_h_mm": round(1e3 * float(np.sqrt(np.mean(k[:, 0] ** 2 + k[:, 1] ** 2))), 3),
            "kinematic_rms_v_mm": round(1e3 * float(np.sqrt(np.mean(k[:, 2] ** 2))), 3),
            "ingest_s": round(p["ingest_s"], 2), "init_s": round(p["init_s"], 2), "estimate_s": round(p["estimate_s"], 2),
            "rtk_static_error_mm": round(1e3 * rtk_err, 3), "rtk_fixed": bool(rtk["fixed"]), "rtk_s": round(rtk_s, 2)}


def geonet_case() -> dict:
    src = (ROOT / "configs" / "geonet-0759-3040.toml").read_text().replace("../../shared", str(DATA.parent))
    out = {}
    for name, extra in (("L1", ""), ("L1+L2", 'signals = ["G:L1", "G:L2"]\n')):
        with tempfile.TemporaryDirectory() as tmp:
            d = Path(tmp)
            cfg = d / "job.toml"
            cfg.write_text(src.replace("[gnss]\n", "[gnss]\n" + extra, 1))
            _run("ingest", "--config", cfg, "-o", d / "run.mcap")
            _run("init", d / "run.mcap", "-o", d / "init.json")
            init = json.loads((d / "init.json").read_text())
            rov = init["rovers"]["0759"]
            out[name] = {"fixed": rov["n_fixed"], "estimated": rov["n_estimated"], "ratio": rov["ratio"],
                         "enu_mm": (1e3 * np.array(list(init["states"].values()))).round(3).tolist()}
    out["difference_mm"] = round(float(np.linalg.norm(np.subtract(out["L1+L2"]["enu_mm"], out["L1"]["enu_mm"]))), 3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "disp_signals.json"))
    a = ap.parse_args()
    load0 = os.getloadavg()[0]
    res = {"rinex_ge_static_rover": [ge_case(n, s) for n, s in SETS.items()], "geonet": geonet_case()}
    res["load_average"] = [round(load0, 2), round(os.getloadavg()[0], 2)]
    Path(a.out).write_text(json.dumps(res, indent=1) + "\n")
    print("| set | integers fixed | static error (mm) | ENU (mm) | kinematic RMS H / V (mm) | init / estimate (s) | `cdgps rtk` static error (mm) |")
    print("|---|---|---|---|---|---|---|")
    for c in res["rinex_ge_static_rover"]:
        print(f"| {c['set']} | {c['dd_integers_fixed']} of {c['dd_integers']} | {c['static_error_mm']:.2f} | "
              f"{', '.join(f'{v:+.2f}' for v in c['static_enu_mm'])} | {c['kinematic_rms_h_mm']:.2f} / {c['kinematic_rms_v_mm']:.2f} | "
              f"{c['init_s']:.1f} / {c['estimate_s']:.1f} | {c['rtk_static_error_mm']:.2f} |")
    g = res["geonet"]
    print(f"GEONET: L1 {g['L1']['fixed']}/{g['L1']['estimated']} fixed {g['L1']['enu_mm']}; L1+L2 {g['L1+L2']['fixed']}/"
          f"{g['L1+L2']['estimated']} fixed {g['L1+L2']['enu_mm']}; |difference| {g['difference_mm']:.2f} mm; load {res['load_average']}")


if __name__ == "__main__":
    main()
