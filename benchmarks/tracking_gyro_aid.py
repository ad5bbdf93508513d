"""Issue 16 item 6: why gyro-aided loops did worse than unaided ones — the aid's own error, without
IF samples or loops.

For the free-vibrating testbed (configs/testbed-1998-lumped.toml, `cdgps simulate --seed 1`), each antenna's
line-of-sight Doppler to each pseudolite is computed from the simulator's truth (exact ranges, central
difference over the 10 Hz epochs) and compared with the aid of `pipeline.if_chain.gyro_aid_hz` in
its variants:

* map: "gyro" (q̇ = G⁺ω, the kinematics alone) or "model" (q̇ = U(GU)⁺ω, the mode shapes);
* rates: the simulated gyros (bias, bias drift, noise of the config) or ideal ones (G q̇_true);
* pose: the geometry at the rest pose q = 0 (the aid before this study), or at the pose integrated by
  the gyros from the true pose at the first sample (`--pose truth.csv`);
* and the line-of-sight velocity through the true q̇ at the true pose (checks the truth Doppler).

Printed and written (docs/benchmarks/tracking-gyro-aid.json): RMS of the true Doppler and of each
aid's error over all rover and master channels (median channel and worst channel, Hz), and the fraction
of channels whose aid error exceeds the Doppler itself (the aid then does more harm than good).

    python benchmarks/tracking_gyro_aid.py [--duration 60] [--seed 1]
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.structure import load_config  # noqa: E402
from cdgps_cli.io.coordinate_columns import coordinate_table  # noqa: E402
from cdgps_cli.model.kinematics import antenna_positions, gyro_matrix  # noqa: E402
from cdgps_cli.pipeline.if_chain import gyro_aid_hz, gyro_rates  # noqa: E402
from cdgps_cli.sim.if_samples import C_M_S, L1_HZ, Transmitter, line_of_sight_range_m  # noqa: E402

CONFIG = ROOT / "configs" / "testbed-1998-lumped.toml"


def _arg(name, default):
    return sys.argv[sys.argv.index(name) + 1] if name in sys.argv else default


def main():
    duration = float(_arg("--duration", 9.0))
    seed = int(_arg("--seed", 1))
    out = ROOT / _arg("--out", "docs/benchmarks/tracking-gyro-aid.json")
    cfg = load_config(CONFIG)
    lam = C_M_S / L1_HZ
    with tempfile.TemporaryDirectory(prefix="gyro-aid-") as tmp:
        sim = Path(tmp) / "sim"
        subprocess.run([sys.executable, "-m", "cdgps_cli.cli.commands", "-q", "simulate", str(CONFIG), "--duration",
                        str(duration), "--seed", str(seed), "-o", str(sim)], check=True, cwd=ROOT)
        truth, _ = coordinate_table(pd.read_csv(sim / "truth.csv"), cfg)    # q1_m, q2_rad … → bare names
        measured = gyro_rates(cfg, sim / "gyro.csv")
    t = truth["time_s"].to_numpy()
    q = truth[list(cfg.coord_names)].to_numpy()
    qdot = np.gradient(q, t, axis=0, edge_order=2)
    ideal = (t, qdot @ gyro_matrix(cfg).T)
    p = antenna_positions(cfg, q)
    txs = [{"name": n, "prn": i + 1, "position_m": list(map(float, pos)), "far_field": cfg.transmitter_far_field}
           for i, (n, pos) in enumerate(zip(cfg.transmitter_names, cfg.transmitter_position_m))]
    man = {"start_s": float(t[0]), "transmitters": txs}
    rel = t - t[0]
    inner = slice(1, -1)
    variants = {f"{m} map, {r} gyros, {ps} pose": (m == "model", g, ps == "integrated")
                for m in ("gyro", "model") for r, g in (("simulated", measured), ("ideal", ideal))
                for ps in ("rest", "integrated")}
    rms = {"doppler": [], **{k: [] for k in variants}}
    worse = {k: 0 for k in variants}
    for a, name in enumerate(cfg.antenna_names):
        for tx in txs:
            rho = line_of_sight_range_m(Transmitter(**tx), p[:, a])
            dop = -np.gradient(rho, t, edge_order=2)[inner] / lam
            rms["doppler"].append(float(np.sqrt(np.mean(dop ** 2))))
            for k, (modes, gyro, integrated) in variants.items():
                if integrated:
                    aid = gyro_aid_hz(cfg, man, gyro, name, tx["name"], rel[inner], modes, q[0])
                else:                                                    # the aid before: geometry at q = 0
                    aid = _rest_pose_aid(cfg, man, gyro, name, tx, rel[inner], modes)
                e = float(np.sqrt(np.mean((aid - dop) ** 2)))
                rms[k].append(e)
                worse[k] += e > rms["doppler"][-1]
    n = len(rms["doppler"])
    summary = {k: {"median_hz": float(np.median(v)), "worst_hz": float(np.max(v)),
                   **({"channels_worse_than_no_aid": f"{worse[k]} of {n}"} if k in worse else {})}
               for k, v in rms.items()}
    for k, v in summary.items():
        print(f"{k:50s} {json.dumps(v)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"config": str(CONFIG.relative_to(ROOT)), "seed": seed, "duration_s": duration,
                               "q10_start_rad": float(q[0, cfg.coord_names.index("q10")]),
                               "q10_range_rad": [float(q[:, -1].min()), float(q[:, -1].max())],
                               "rms_over_channels": summary}, indent=1) + "\n")
    print(f"wrote {out}", file=sys.stderr)


def _rest_pose_aid(cfg, man, gyro, antenna, tx, time_s, modes):
    """The aid as it was before the pose was integrated: J and the line of sight at q = 0."""
    from cdgps_cli.pipeline.if_chain import gyro_coordinate_map

    t_g, w = gyro
    qd = w @ gyro_coordinate_map(cfg, modes).T
    p0, J0 = antenna_positions(cfg, np.zeros((1, cfg.n_q)), jacobian=True)
    a = list(cfg.antenna_names).index(antenna)
    u = p0[0, a] - np.asarray(tx["position_m"])
    u /= np.linalg.norm(u)
    return -np.interp(np.asarray(time_s) + man["start_s"], t_g, (qd @ J0[0, a].T) @ u) / (C_M_S / L1_HZ)


if __name__ == "__main__":
    main()
