"""Long baselines side by side with RTKLIB: the ionosphere and the zenith wet delays neglected or estimated.

``python benchmarks/long_baseline.py --data DIR [--antex FILE] [--out FILE]``

DIR holds the two real Dutch pairs of session 24 and their navigation file, which stay outside the repository:
``delf0010.21d``, ``zegv0010.21d``, ``eijs0010.21d`` (Hatanaka RINEX 2.11, 30 s, 2021-01-01; georust/rinex at 95c3d35,
``test_resources/CRNX/V1/``, MPL-2.0; DELF and ZEGV are also in tests/data/georust-delf-zegv) and ``brdc0010.21n``
(the IGS broadcast file of that day; rashidyreza/single-point-positioning-spp, no licence).  For each rover (ZEGV,
35 km; EIJS, 164 km) and each model — the ionosphere neglected or estimated, the zenith wet delays neglected or
estimated — ``rnx2rtkp`` (static, GPS L1 + L2, mask 15°, ratio 3, the base at its header position with its antenna
delta: ``ionoopt`` brdc / est-stec, ``tropopt`` saas / est) and ``cdgps rtk --mode static`` with the same choices
(``--iono-threshold-km``, ``--tropo-threshold-km`` 1 or 1000) run on the same files; ``cdgps rtk``'s default kinematic
(combined) run and its static float (``--float-only``) are added for its default model.  Per run: epochs, fixed
epochs, the last position's east / north / up from the rover's header coordinate (mm) and, for ours, its σ (mm) and the
wet delays' last estimates.  The header coordinates are the marker's and neither tool applies antenna phase-centre
models: mixed antennas (EIJS LEIAR25.R4 against DELF's TRM29659.00) put a right solution some centimetres from them.
With ``--antex FILE`` (RTKLIB's ``data/igs05.atx``, which has both of EIJS's and DELF's antennas; ZEGV's is newer)
EIJS is run again by both with the receiver antenna models (``cdgps rtk --antex``; ``rnx2rtkp`` with
``file-rcvantfile``, ``ant1-anttype=*``, ``ant2-anttype=*`` and ``pos1-posopt2=on`` for the variations), the default
model of each.  Writes ``docs/benchmarks/long_baseline.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "long_baseline.json"
CDGPS = str(Path(sys.executable).parent / "cdgps")
#: (label, ionosphere estimated, wet delays estimated)
MODELS = (("iono neglected, wet neglected", False, False), ("iono neglected, wet estimated", False, True),
          ("iono estimated, wet neglected", True, False), ("iono estimated, wet estimated", True, True))
ROVERS = ("zegv", "eijs")


def _header_xyz(path: Path) -> np.ndarray:
    for line in path.read_text(errors="replace").splitlines():
        if "APPROX POSITION XYZ" in line:
            return np.array(line.split()[:3], float)
        if "END OF HEADER" in line:
            break
    raise SystemExit(f"{path}: no APPROX POSITION XYZ")


def _enu_mm(ref: np.ndarray, xyz: np.ndarray) -> list:
    from cdgps_cli.model.gps.orbits import ecef_to_enu  # noqa: PLC0415
    return np.round(np.asarray(ecef_to_enu(xyz, ref)) * 1e3, 1).tolist()


def _rtklib(work: Path, rover: str, iono: bool, wet: bool, antex: Path | None = None) -> dict:
    conf = work / "c.conf"
    ant = ([f"file-rcvantfile={antex}", "ant1-anttype=*", "ant2-anttype=*", "pos1-posopt2=on"] if antex else [])
    conf.write_text("\n".join([
        "pos1-posmode=static", "pos1-frequency=l1+l2", "pos1-elmask=15", "pos1-navsys=1",
        f"pos1-ionoopt={'est-stec' if iono else 'brdc'}", f"pos1-tropopt={'est' if wet else 'saas'}",
        "pos2-armode=continuous", "pos2-arthres=3", "ant2-postype=rinexhead", "out-solformat=xyz", *ant, ""]))
    out = work / f"rtklib_{rover}.pos"
    p = subprocess.run(["rnx2rtkp", "-k", str(conf), "-o", str(out), str(work / f"{rover}0010.21o"),
                        str(work / "delf0010.21o"), str(work / "brdc0010.21n")], capture_output=True, text=True)
    rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")] if out.exists() else []
    if p.returncode != 0 or not rows:
        raise SystemExit(f"rnx2rtkp failed on {rover} ({iono=}, {wet=}): exit {p.returncode}\n{p.stderr[-2000:]}")
    q = [r[5] for r in rows]
    return {"epochs": len(rows), "fixed": q.count("1"), "last_q": int(rows[-1][5]),
            "last_enu_mm": _enu_mm(_header_xyz(work / f"{rover}0010.21o"), np.array(rows[-1][2:5], float))}


def _ours(work: Path, data: Path, rover: str, extra: list) -> dict:
    out, env = work / f"cdgps_{rover}.pos", {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    p = subprocess.run([CDGPS, "rtk", "--base", str(data / "delf0010.21d"), "--rover", str(data / f"{rover}0010.21d"),
                        "--nav", str(data / "brdc0010.21n"), "--signals", "G:L1,G:L2", "--json", "-q", "-o", str(out),
                        *extra], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        raise SystemExit(f"cdgps rtk failed on {rover} {extra}: exit {p.returncode}\n{p.stderr[-2000:]}")
    s = json.loads(p.stdout)
    rows = [ln.split() for ln in out.read_text().splitlines() if ln.strip() and not ln.startswith("%")]
    w = s["wet_troposphere"]
    return {"epochs": s["epochs"], "fixed": s["fixed_epochs"], "last_q": int(rows[-1][5]),
            "last_enu_mm": _enu_mm(_header_xyz(work / f"{rover}0010.21o"), np.array(s["last_xyz_m"])),
            "last_sigma_neu_mm": [round(float(v) * 1e3, 1) for v in rows[-1][7:10]],
            "wet": w.get("zenith_wet_m"), "wet_sigma": w.get("zenith_wet_sigma_m")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, required=True, help="the folder of the pairs' files (module docstring)")
    ap.add_argument("--antex", type=Path, default=None, help="an ANTEX file with EIJS's and DELF's antennas (docstring)")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    import hatanaka  # noqa: PLC0415
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in ("delf", *ROVERS):
            (work / f"{name}0010.21o").write_bytes(hatanaka.decompress((a.data / f"{name}0010.21d").read_bytes()))
        (work / "brdc0010.21n").write_bytes((a.data / "brdc0010.21n").read_bytes())
        runs = []
        for rover in ROVERS:
            for label, iono, wet in MODELS:
                extra = ["--mode", "static", "--iono-threshold-km", "1" if iono else "1000",
                         "--tropo-threshold-km", "1" if wet else "1000"]
                runs.append({"rover": rover, "model": label, "rtklib": _rtklib(work, rover, iono, wet),
                             "cdgps_static": _ours(work, a.data, rover, extra)})
                print(json.dumps(runs[-1]), flush=True)
            runs.append({"rover": rover, "model": "cdgps defaults (iono and wet estimated from 10 km)",
                         "cdgps_kinematic_combined": _ours(work, a.data, rover, []),
                         "cdgps_static_float": _ours(work, a.data, rover, ["--mode", "static", "--float-only"])})
            print(json.dumps(runs[-1]), flush=True)
        if a.antex is not None:
            antex = a.antex.resolve()
            runs.append({"rover": "eijs", "model": "iono and wet estimated, receiver antenna models (ANTEX)",
                         "antex": str(a.antex), "rtklib": _rtklib(work, "eijs", True, True, antex),
                         "cdgps_static": _ours(work, a.data, "eijs", ["--mode", "static", "--antex", str(antex)]),
                         "cdgps_kinematic_combined": _ours(work, a.data, "eijs", ["--antex", str(antex)])})
            print(json.dumps(runs[-1]), flush=True)
    a.out.write_text(json.dumps({"machine": {"python": platform.python_version(), "cores": os.cpu_count()},
                                 "rnx2rtkp": "Debian rtklib 2.4.3 b34", "runs": runs}, indent=1) + "\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
