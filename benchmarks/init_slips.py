"""Unflagged cycle slips inside the automatic init window (issue 32 item 2).

Per config, seed, slip size (cycles; half cycles included), epoch (fraction of the record) and
channel: ``simulate`` a free-vibration run (library functions, in memory), add the slip to the
channel's phase from that epoch on WITHOUT touching its lock count (the receiver did not flag it),
and ``initialize`` with default options (automatic window: the whole record when it is ≤ 60 s).
Each case is classified as

* ``split``    the slip was found at its epoch and the channel's segment split there; no fixed
               integer wrong and the channel's current bias right (fixed, or float within λ/4);
* ``moved``    the window does not contain the slip and no bias is wrong;
* ``refused``  ``initialize`` raised a CdgpsError;
* ``wrong``    a fixed integer is wrong, a float bias is off by more than λ/4, or the channel's
               current bias (the one ``estimate`` continues with) is the pre-slip one.

Usage: ``python benchmarks/init_slips.py [--configs teague-1995-2dof,testbed-1998] [--seeds 1,2]
[--sizes 1,2,3,5,10,20,0.5,1.5] [--fractions 0.05,0.25,0.5,0.75,0.95] [--out docs/benchmarks/init-slips.json]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.core.errors import CdgpsError  # noqa: E402
from cdgps_cli.core.records import memory_run  # noqa: E402
from cdgps_cli.estimation.initializer import InitOptions, initialize  # noqa: E402
from cdgps_cli.sim.structure import SimOptions, simulate  # noqa: E402

SETUPS = {"teague-1995-2dof": dict(duration_s=12.0, channels=[("s2", "S1"), ("s4", "S3"), ("s3", "S2"), ("s4", "S4")]),
          "testbed-1998": dict(duration_s=30.0, channels=[("a3", "PL2"), ("a5", "PL6")])}


def one(cfg, sim, channel, fraction, cycles) -> dict:
    lam, t = cfg.wavelength_m, sim.time_s
    ts = float(t[int(round(fraction * (len(t) - 1)))])
    rec = sim.receiver.copy()
    sel = (rec["time_s"] >= ts - 1e-9) & (rec["antenna"] == channel[0]) & (rec["transmitter"] == channel[1])
    rec.loc[sel, "phase_cycles"] += cycles
    out = {"channel": "/".join(channel), "slip_time_s": ts, "cycles": cycles}
    t0 = time.perf_counter()
    try:
        res = initialize(memory_run(cfg, rec), InitOptions())
    except CdgpsError as exc:
        return dict(out, outcome="refused", message=str(exc), seconds=time.perf_counter() - t0)
    truth = {(b["antenna"], b["transmitter"]): b["bias_m"] for b in sim.truth["biases"]}
    w = res["window"]
    inside = w["start_s"] <= ts <= w["end_s"]
    wrong = []
    for b in res["biases"]:
        key = (b["antenna"], b["transmitter"])
        after = key == channel and b["segment_start_s"] >= ts - 1e-9
        err = b["bias_m"] - truth[key] - (lam * cycles if after else 0.0)
        if abs(err) > (1e-6 if b["fixed"] else 0.25 * lam):
            wrong.append(f"{key[0]}/{key[1]} from {b['segment_start_s']:g} s: {err / lam:+.2f} cycles "
                         f"({'fixed' if b['fixed'] else 'float'})")
    cur = next(b for b in res["biases"] if (b["antenna"], b["transmitter"]) == channel and b["current"])
    if inside and cur["segment_start_s"] < ts - 1e-9:
        wrong.append("current bias is the pre-slip one")
    split = any(s["antenna"] == channel[0] and s["transmitter"] == channel[1] and abs(s["time_s"] - ts) < 1e-6
                for s in res.get("unflagged_slips", []))
    outcome = "wrong" if wrong else ("split" if split else ("moved" if not inside else "accepted unsplit"))
    return dict(out, outcome=outcome, wrong=wrong, n_fixed=res["n_fixed"], n_biases=len(res["biases"]),
                slips_found=[(s["antenna"] + "/" + s["transmitter"], s["time_s"], s.get("slip_cycles"))
                             for s in res.get("unflagged_slips", [])],
                multipath="multipath" in res, seconds=time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--configs", default="teague-1995-2dof")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--sizes", default="1,2,3,5,10,20,0.5,1.5")
    ap.add_argument("--fractions", default="0.05,0.25,0.5,0.75,0.95")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    rows = []
    for name in a.configs.split(","):
        cfg = load_config(ROOT / "configs" / f"{name}.toml")
        setup = SETUPS[name]
        cases = []
        for seed in [int(s) for s in a.seeds.split(",")]:
            sim = simulate(cfg, SimOptions(duration_s=setup["duration_s"], seed=seed))
            for cyc in [float(v) for v in a.sizes.split(",")]:
                cyc = int(cyc) if cyc == int(cyc) else cyc
                for frac in [float(v) for v in a.fractions.split(",")]:
                    for ch in setup["channels"]:
                        r = dict(one(cfg, sim, ch, frac, cyc), seed=seed)
                        cases.append(r)
                        print(f"{name} seed {seed} {cyc} cycles at {r['slip_time_s']:g} s on {r['channel']}: "
                              f"{r['outcome']} {r.get('wrong') or ''}{r.get('message', '')[:120]}", flush=True)
        counts = {k: sum(c["outcome"] == k for c in cases) for k in ("split", "moved", "refused", "wrong", "accepted unsplit")}
        rows.append({"config": name, "duration_s": setup["duration_s"], "cases": len(cases), **counts,
                     "seconds_per_case": sum(c["seconds"] for c in cases) / max(len(cases), 1), "runs": cases})
        print(f"{name}: {len(cases)} cases: " + ", ".join(f"{k} {v}" for k, v in counts.items()), flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
