"""Peak memory and speed of `cdgps track` against the IF file's length (issue 29).

Simulates one long IF file in the bundled real file's format (4 MHz complex baseband, int8 I/Q pairs
of 2-bit levels ±1, ±3, I − jQ): six GPS satellites at 41-46 dB-Hz, static Dopplers -3.5 to +2.8 kHz
(:func:`cdgps_cli.sim.if_samples.antenna_blocks`, far-field sources, white noise, seed fixed).  Files of
each length are that file's first bytes.  Each run is a fresh `cdgps track` process (acquisition of
32 PRNs, tracking of every satellite acquired, TRACK.mcap written); its peak RSS and CPU time come from
``os.wait4`` (the kernel's accounting of that process alone), the wall time from the clock.

``--before TREE`` also runs the code of another source tree (e.g. ``git archive`` of the commit before
the change, with its compiled ``_trackcore`` copied in) on the lengths ``--before-durations`` (the old
path holds the whole file as complex128 and refuses beyond 8 GiB of samples) and checks that the two
write the same TRACK.mcap bytes.

``structure`` (``--only structure``): `cdgps track-structure` on the testbed config's simulated IF files
(`cdgps simulate` + `cdgps simulate-if`, 7 antennas × 6 pseudolites, 2.2 MHz), ``--structure-durations``
seconds, with the new and (``--before``) the old code, and whether the two receiver logs are identical.

    python benchmarks/track_memory.py [--only track,structure] [--durations 10,30,60]
        [--before /tmp/old --before-durations 2,5,10] [--structure-durations 5,20]

Writes docs/benchmarks/track_memory.json (the studies not run are kept).  The per-channel real-time
factor is duration × channels / wall time (the channels run one after the other on one core).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdgps_cli.config.options import TRACK_BLOCK_SAMPLES  # noqa: E402
from cdgps_cli.sim.if_samples import IfOptions, Transmitter, antenna_blocks  # noqa: E402
from cdgps_cli.tracking.ca_code import ca_code  # noqa: E402

FS_HZ = 4e6
#: (PRN, C/N0 dB-Hz, Doppler Hz) of the simulated satellites
SATELLITES = ((3, 46.0, -2200.0), (7, 44.0, 1300.0), (12, 42.0, -300.0), (19, 45.0, 2800.0), (24, 41.0, -3500.0),
              (31, 43.0, 600.0))
CLI = "import sys; from cdgps_cli.cli.commands import main; sys.exit(main())"


def simulate(path: Path, duration_s: float) -> None:
    """``duration_s`` of 2-bit int8 I/Q samples at 4 MHz, written block by block."""
    txs = [Transmitter(name=f"G{p}", prn=p, position_m=(0.0, 0.0, 1.0), far_field=True, cn0_dbhz=c,
                       frequency_offset_hz=f) for p, c, f in SATELLITES]
    n = int(round(duration_s * FS_HZ))
    delay = np.zeros((int(duration_s / 1e-3) + 2, len(txs)))
    opt = IfOptions(fs_hz=FS_HZ, bits=2, iq_sign="minus", seed=1, block_s=0.05)
    with open(path, "wb") as fh:
        for blk in antenna_blocks(delay, txs, {t.prn: ca_code(t.prn) for t in txs}, n, opt, np.random.default_rng(5)):
            fh.write(blk.tobytes())


def prefix(src: Path, dst: Path, duration_s: float) -> None:
    """The first ``duration_s`` of ``src`` (2 bytes per sample) as a file of its own."""
    left = int(round(duration_s * FS_HZ)) * 2
    with open(src, "rb") as fi, open(dst, "wb") as fo:
        while left:
            chunk = fi.read(min(left, 1 << 24))
            fo.write(chunk)
            left -= len(chunk)


def run_track(tree: Path, iq: Path, out: Path) -> dict:
    """One fresh `cdgps track` process of ``tree``'s code: peak RSS, wall and CPU time, its JSON summary."""
    import cdgps_cli

    assert tree.resolve() != Path(cdgps_cli.__file__).resolve().parents[1] or tree.resolve() == ROOT
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, "-c", CLI, "-q", "track", str(iq), "--format", "int8-iq", "--fs", "4000000",
           "-o", str(out), "--json"]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as err:
        # cwd: not a source tree (``python -c`` puts the working directory first on sys.path)
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=err, cwd=out.parent)
        stdout = proc.stdout.read()
        _, status, ru = os.wait4(proc.pid, 0)
        err.seek(0)
        stderr = err.read()
    wall = time.perf_counter() - t0
    row = {"peak_rss_mb": ru.ru_maxrss / 1024, "wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime,
           "exit": os.waitstatus_to_exitcode(status)}
    if row["exit"] != 0:
        row["error"] = stderr.decode(errors="replace").strip().splitlines()[-1:]
        return row
    s = json.loads(stdout)
    row["channels"] = len(s["satellites"])
    row["prns"] = [x["prn"] for x in s["satellites"]]
    return row


def run_cli(tree: Path, args: list, cwd: Path) -> dict:
    """One fresh `cdgps` process of ``tree``'s code: exit code, peak RSS (MiB), wall and CPU time (s)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, "-c", CLI, "-q", *map(str, args)], env=env,
                                stdout=subprocess.DEVNULL, stderr=err, cwd=cwd)
        _, status, ru = os.wait4(proc.pid, 0)
    return {"exit": os.waitstatus_to_exitcode(status), "peak_rss_mb": ru.ru_maxrss / 1024,
            "wall_s": time.perf_counter() - t0, "cpu_s": ru.ru_utime + ru.ru_stime}


def study_structure(durations: list, before: Path | None, work: Path) -> dict:
    """`cdgps track-structure` on the testbed (7 antennas × 6 pseudolites, 2.2 MHz IF files from
    `cdgps simulate-if`), after and (with ``before``) before, and whether the receiver logs are identical."""
    cfg = ROOT / "configs" / "testbed-1998-lumped.toml"
    assert run_cli(ROOT, ["simulate", cfg, "--duration", max(durations) + 1, "--seed", 1, "-o", work / "sim"],
                   work)["exit"] == 0
    rows = []
    for d in durations:
        ifd = work / f"if{d:g}"
        assert run_cli(ROOT, ["simulate-if", cfg, work / "sim", "--duration", d, "--fs", 2.2e6, "--seed", 2,
                              "-o", ifd], work)["exit"] == 0
        logs = {}
        for label, tree in (("after", ROOT), ("before", before)):
            if tree is None:
                continue
            logs[label] = work / f"rx_{label}_{d:g}.csv"
            r = run_cli(tree, ["track-structure", ifd / "if.json", "--config", cfg, "-o", logs[label]], work)
            rows.append({"code": label, "duration_s": d, "if_files_mb": sum(f.stat().st_size for f in ifd.glob("*.bin"))
                         / 2**20, **r})
            print(json.dumps(rows[-1]), flush=True)
        if len(logs) == 2:
            rows[-1]["receiver_log_identical_to_after"] = logs["after"].read_bytes() == logs["before"].read_bytes()
        shutil.rmtree(ifd)
    return {"what": "peak RSS and time of `cdgps track-structure` on the testbed's simulated IF files",
            "format": "int8-iq, 8-bit, 2.2 MHz, 7 antennas × 6 pseudolites at 45 dB-Hz", "runs": rows}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="track,structure", help="studies to run: track, structure")
    ap.add_argument("--durations", default="10,30,60", help="file lengths, s (comma-separated)")
    ap.add_argument("--before", type=Path, default=None, help="source tree of the old code to compare with")
    ap.add_argument("--before-durations", default="2,5,10")
    ap.add_argument("--structure-durations", default="5,20", help="track-structure: simulated lengths, s")
    ap.add_argument("--workdir", type=Path, default=None, help="where the IF files go (default: a temporary folder)")
    args = ap.parse_args()
    out_path = ROOT / "docs" / "benchmarks" / "track_memory.json"
    res = json.loads(out_path.read_text()) if out_path.exists() else {}
    work = Path(tempfile.mkdtemp(prefix="track_memory_", dir=args.workdir))
    try:
        if "track" in args.only.split(","):
            res.update(study_track(args, work))
        if "structure" in args.only.split(","):
            load_start = os.getloadavg()
            res["track_structure"] = study_structure([float(v) for v in args.structure_durations.split(",")],
                                                     args.before, work)
            res["track_structure"]["load_average_1_5_15_min"] = {"start": load_start, "end": os.getloadavg()}
            res["track_structure"]["command"] = "python benchmarks/track_memory.py " + " ".join(sys.argv[1:])
        out_path.parent.mkdir(parents=True, exist_ok=True)
        out_path.write_text(json.dumps(res, indent=2) + "\n")
        print(f"wrote {out_path}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


def study_track(args, work: Path) -> dict:
    """`cdgps track` on simulated files of ``args.durations`` (and of ``args.before_durations`` with the
    old code): the top-level entries of the JSON."""
    durations = [float(v) for v in args.durations.split(",")]
    before = [float(v) for v in args.before_durations.split(",")] if args.before else []
    load_start = os.getloadavg()
    longest = max(durations + before)
    full = work / f"if_{longest:g}s.bin"
    t0 = time.perf_counter()
    simulate(full, longest)
    print(f"simulated {longest:g} s in {time.perf_counter() - t0:.0f} s", flush=True)
    rows = []
    for label, tree, lengths in (("after", ROOT, durations), ("before", args.before, before)):
        for d in lengths:
            iq = work / f"if_{d:g}s.bin"
            if not iq.exists():
                prefix(full, iq, d)
            r = run_track(tree, iq, work / f"{label}_{d:g}.mcap")
            r = {"code": label, "duration_s": d, "file_mb": iq.stat().st_size / 2**20, **r}
            if r.get("channels"):
                r["real_time_factor_per_channel"] = d * r["channels"] / r["wall_s"]
                r["real_time_factor_per_channel_cpu"] = d * r["channels"] / r["cpu_s"]
            rows.append(r)
            print(json.dumps(r), flush=True)
    same = {}
    for d in before:
        a, b = work / f"after_{d:g}.mcap", work / f"before_{d:g}.mcap"
        if a.exists() and b.exists():
            same[f"{d:g}"] = a.read_bytes() == b.read_bytes()
    return {"what": "peak RSS and time of a fresh `cdgps track` process against the IF file's length",
            "format": "int8-iq, 2-bit levels, 4 MHz (the bundled real file's)",
            "satellites": [{"prn": p, "cn0_dbhz": c, "doppler_hz": f} for p, c, f in SATELLITES],
            "block_samples": TRACK_BLOCK_SAMPLES, "machine": platform.machine(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__,
            "command": "python benchmarks/track_memory.py " + " ".join(sys.argv[1:]),
            "load_average_1_5_15_min": {"start": load_start, "end": os.getloadavg()},
            "runs": rows, "before_after_track_mcap_identical": same}


if __name__ == "__main__":
    main()
