"""The integer fixing of `cdgps rtk` per epoch: compiled LAMBDA kernels against the Python loops (issue 28 item 6).

For each case of ``bench_rtk_rtklib.py`` the command runs once in process while the inputs of every
epoch's integer fixing (``rtk_multi._CarriedDecorrelation.resolve``: the DD float ambiguities, their
covariance, the ratio threshold and success rate, per filter pass) are recorded.  Those epochs are
then resolved again, timed, with the compiled kernels (``cdgps_cli.estimation._lambdacore``: reduction,
Z, integer search) and with the Python loops (``CDGPS_NO_KERNEL=1``), rounds interleaved, medians;
both must give the same answers bit for bit (``identical``: accepted, ratio, success rate, rows of
Z and integers of every epoch).

Usage::

    python benchmarks/bench_rtk_ambiguity.py [--repeats 3] [--out docs/benchmarks/rtk_ambiguity.json]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_rtk_rtklib as peer  # noqa: E402

from cdgps_cli.estimation import ambiguity, rtk_multi  # noqa: E402

OUT = ROOT / "docs" / "benchmarks" / "rtk_ambiguity.json"


def record(c, tmp: Path) -> list:
    """Run `cdgps rtk` on case ``c`` in process; the (pass id, resolve arguments) of every epoch."""
    from cdgps_cli.cli.commands import main  # noqa: PLC0415

    calls = []
    real = rtk_multi._CarriedDecorrelation.resolve

    def spy(self, *args):
        calls.append((id(self), tuple(np.array(a, copy=True) if isinstance(a, np.ndarray) else a for a in args)))
        return real(self, *args)

    cmd, _ = peer.cdgps_command(c, tmp)
    rtk_multi._CarriedDecorrelation.resolve = spy
    try:
        with contextlib.redirect_stdout(io.StringIO()):        # the command's JSON summary
            main.main(cmd[1:], standalone_mode=False)
    finally:
        rtk_multi._CarriedDecorrelation.resolve = real
    return calls


def replay(calls) -> tuple[float, list]:
    """Seconds to resolve the recorded epochs again (one fresh carried decorrelation per pass) and the
    answers."""
    carried, out = {}, []
    t0 = time.perf_counter()
    for key, args in calls:
        out.append(carried.setdefault(key, rtk_multi._CarriedDecorrelation()).resolve(*args))
    return time.perf_counter() - t0, out


def _same(x: list, y: list) -> bool:
    def norm(r):
        return [r["accepted"], np.float64(r["ratio"]).tobytes(), np.float64(r["success_rate"]).tobytes(), r["partial"],
                None if r["rows"] is None else r["rows"].tobytes(), None if r["integers"] is None else r["integers"].tobytes()]
    return len(x) == len(y) and all(norm(a) == norm(b) for a, b in zip(x, y))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3, help="timed rounds per path (median) [3]")
    ap.add_argument("--out", type=Path, default=OUT, help=f"result JSON [{OUT}]")
    args = ap.parse_args()
    if ambiguity._kernel() is None:
        raise SystemExit("cdgps_cli.estimation._lambdacore is not compiled (make venv) or CDGPS_NO_KERNEL is set")
    res = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                       "cpus": os.cpu_count(), "load_average_1min_at_start": round(os.getloadavg()[0], 2)},
           "repeats": args.repeats, "timing": "in process, rounds interleaved (kernel, Python loops, ...), medians",
           "cases": {}}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for c in peer.cases(tmp):
            calls = record(c, tmp)
            t_k, t_p = [], []
            for _ in range(args.repeats):
                sec, ans_k = replay(calls)
                t_k.append(sec)
                os.environ["CDGPS_NO_KERNEL"] = "1"
                try:
                    sec, ans_p = replay(calls)
                finally:
                    del os.environ["CDGPS_NO_KERNEL"]
                t_p.append(sec)
            n = len(calls)
            sizes = [len(a[1]) for _, a in calls]
            row = {"epochs_resolved": n, "ambiguities_median": int(np.median(sizes)) if sizes else 0,
                   "ambiguities_max": max(sizes, default=0),
                   "kernel_ms_per_epoch": 1e3 * statistics.median(t_k) / max(n, 1),
                   "python_ms_per_epoch": 1e3 * statistics.median(t_p) / max(n, 1),
                   "identical": _same(ans_k, ans_p)}
            row["speed_up"] = row["python_ms_per_epoch"] / row["kernel_ms_per_epoch"]
            res["cases"][c["name"]] = row
            print(c["name"], json.dumps(row), flush=True)
            if not row["identical"]:
                raise SystemExit(f"{c['name']}: the kernel and the Python loops disagree")
    res["machine"]["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
