#!/usr/bin/env python3
"""Single-byte mutation campaign over cdgps MCAP files (issue 12 item 2), and the cost of checking.

Builds, with the CLI, a structure RUN.mcap / INIT.json / STATES.mcap (20 s of the 2-DOF model) and a
GNSS RUN.mcap / INIT.json (30 s ``simulate-gnss`` + ``ingest``).  Then, for each of the three MCAP
files, replaces single bytes (every offset, or ``--sample N`` offsets drawn without replacement;
the new value is drawn uniformly among the 255 others) and runs on each mutated copy the project's
readers and the commands that consume the file, in-process (Click's test runner):

* RUN.mcap: ``read_mcap``, ``read_run``, ``info --json``, ``estimate --init INIT.json``;
* STATES.mcap: ``read_mcap``, ``States``, ``evaluate --json``, ``spectra`` (psd.csv, peaks.json),
  ``info --json``;
* GNSS RUN.mcap: ``read_mcap``, ``read_gnss_run``, ``info --json``, ``estimate --init INIT.json``.

Each (mutation, consumer) case is classified against the clean file's result (stdout and the
bytes of every output file; a reader's result as a digest of what it returned):

* ``identical``  exit 0, same result;
* ``clean``      exit 2 with a ``cdgps: error:`` message naming the file, no traceback
  (a reader: a CdgpsError naming the file);
* ``traceback``  any other exception;
* ``different``  exit 0 with a different result (silently accepted corruption);
* ``other``      any other exit status, or a clean error that does not name the file.

Target: 0 ``different``, 0 ``traceback``, 0 ``other``.  ``--speed`` also measures the verification
throughput (MiB/s) on a large file and ``estimate`` on a 1 h testbed run with and without the
data-section / summary CRC pass.  Usage::

    python benchmarks/mcap_mutation.py --sample 1500 --json docs/benchmarks/mcap_mutation.json
    python benchmarks/mcap_mutation.py --speed --json docs/benchmarks/mcap_speed.json
    python benchmarks/mcap_mutation.py --sample 300 --no-check     # the checks off: 'different' > 0
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from cdgps_cli.io import mcap as mcap_io
from cdgps_cli.cli.commands import main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.io.mcap_integrity import Integrity, verify_file
from cdgps_cli.io.run import read_run
from cdgps_cli.io.states import States

REPO = Path(__file__).resolve().parent.parent
DOF2 = REPO / "configs" / "teague-1995-2dof.toml"
TESTBED = REPO / "configs" / "testbed-1998-lumped.toml"
CLASSES = ("identical", "clean", "traceback", "different", "other")


def cli(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


def build(d: Path) -> None:
    """The base files, made with the CLI."""
    steps = [["simulate", DOF2, "--duration", "20", "-o", d / "sim"],
             ["ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", DOF2, "-o", d / "RUN.mcap"],
             ["init", d / "RUN.mcap", "--duration", "5", "-o", d / "INIT.json"],
             ["estimate", d / "RUN.mcap", "--init", d / "INIT.json", "-o", d / "STATES.mcap"],
             ["simulate-gnss", "--duration", "30", "--seed", "2", "--out", d / "gsim"],
             ["ingest", "--config", d / "gsim" / "config.toml", "-o", d / "GRUN.mcap"],
             ["init", d / "GRUN.mcap", "-o", d / "GINIT.json"]]
    for s in steps:
        r = cli(*s)
        if r.exit_code != 0:
            raise SystemExit(f"setup step {s[0]} failed: {r.output}")


def _digest(obj) -> str:
    """A digest of what a reader returned (arrays by their bytes, the rest by repr)."""
    h = hashlib.sha256()

    def feed(x):
        if isinstance(x, np.ndarray):
            h.update(str(x.dtype).encode() + str(x.shape).encode())
            h.update(x.tobytes() if x.dtype != object else repr(x.tolist()).encode())
        elif isinstance(x, dict):
            for k in sorted(x, key=repr):
                feed(repr(k))
                feed(x[k])
        elif isinstance(x, (list, tuple)):
            for v in x:
                feed(v)
        elif hasattr(x, "to_numpy") and hasattr(x, "columns"):        # DataFrame
            for c in x.columns:
                feed(str(c))
                feed(x[c].to_numpy())
        elif isinstance(x, mcap_io.TopicColumns):
            feed(x.scalars)
            feed({k: np.frombuffer(v, dtype="i4" if v.typecode == "i" else "f8") for k, v in x._buf.items()})
            feed(x._vocab)
            feed(x.counts)
        elif hasattr(x, "__dict__") and not isinstance(x, type):
            feed({k: v for k, v in vars(x).items() if k not in ("path", "text")})
        else:
            h.update(repr(x).encode())
    feed(obj)
    return h.hexdigest()


def consumers(d: Path, kind: str, target: Path, out: Path):
    """(name, callable returning (status, result)) for one file kind; status 'ok' or a class."""
    def reader(fn):
        def run():
            try:
                return "ok", _digest(fn(target))
            except CdgpsError as exc:
                return ("clean" if str(target) in str(exc) else "other"), str(exc)[:300]
        return run

    def command(*args, outputs=()):
        def run():
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            r = cli(*args)
            if r.exit_code == 0:
                h = hashlib.sha256(r.output.encode())
                for o in outputs:
                    p = out / o
                    h.update(p.read_bytes() if p.exists() else b"<missing>")
                return "ok", h.hexdigest()
            if r.exception is not None and not isinstance(r.exception, SystemExit):
                return "traceback", f"{type(r.exception).__name__}: {r.exception}"[:300]
            if r.exit_code == 2 and "Traceback" not in r.output and str(target) in r.output:
                return "clean", r.output.strip()[-300:]
            return "other", f"exit {r.exit_code}: {r.output.strip()[-300:]}"
        return run

    if kind == "RUN":
        return [("read_mcap", reader(mcap_io.read_mcap)), ("read_run", reader(read_run)),
                ("info", command("info", target, "--json")),
                ("estimate", command("estimate", target, "--init", d / "INIT.json", "-o", out / "S.mcap",
                                     outputs=["S.mcap"]))]
    if kind == "STATES":
        return [("read_mcap", reader(mcap_io.read_mcap)), ("States", reader(States)),
                ("evaluate", command("evaluate", "--truth", d / "sim", "--estimate", target, "--json")),
                ("spectra", command("spectra", target, "-o", out / "sp", outputs=["sp/psd.csv", "sp/peaks.json"])),
                ("info", command("info", target, "--json"))]
    return [("read_mcap", reader(mcap_io.read_mcap)), ("read_gnss_run", reader(read_gnss_run)),
            ("info", command("info", target, "--json")),
            ("estimate", command("estimate", target, "--init", d / "GINIT.json", "-o", out / "S.mcap",
                                 outputs=["S.mcap"]))]


def campaign(d: Path, kind: str, src: Path, sample: int | None, rng) -> dict:
    data = src.read_bytes()
    case_dir = d / f"case_{kind}"
    case_dir.mkdir(exist_ok=True)
    target, out = case_dir / src.name, case_dir / "out"
    target.write_bytes(data)
    cons = consumers(d, kind, target, out)
    base = {}
    for name, fn in cons:
        st, res = fn()
        if st != "ok":
            raise SystemExit(f"clean {kind} file: {name} failed: {res}")
        base[name] = res
    offsets = np.arange(len(data)) if sample is None or sample >= len(data) else \
        np.sort(rng.choice(len(data), size=sample, replace=False))
    counts = {n: dict.fromkeys(CLASSES, 0) for n, _ in cons}
    examples: dict = {}
    t0 = time.perf_counter()
    for i, off in enumerate(offsets):
        mutated = bytearray(data)
        mutated[off] = (data[off] + int(rng.integers(1, 256))) % 256
        target.write_bytes(bytes(mutated))
        for name, fn in cons:
            st, res = fn()
            cls = ("identical" if res == base[name] else "different") if st == "ok" else st
            counts[name][cls] += 1
            if cls not in ("clean", "identical"):
                examples.setdefault(f"{name}/{cls}", []).append({"offset": int(off), "byte": mutated[off],
                                                                 "result": res})
        if (i + 1) % 500 == 0:
            print(f"  {kind}: {i + 1}/{len(offsets)} mutations, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    total = dict.fromkeys(CLASSES, 0)
    for c in counts.values():
        for k, v in c.items():
            total[k] += v
    return {"file": src.name, "bytes": len(data), "mutations": int(len(offsets)), "cases": int(sum(total.values())),
            "total": total, "per_consumer": counts, "examples": {k: v[:5] for k, v in examples.items()},
            "wall_s": round(time.perf_counter() - t0, 1)}


def speed(d: Path) -> dict:
    """Verification MiB/s on a 1 h testbed RUN and its STATES; estimate with and without it."""
    steps = [["simulate", TESTBED, "--duration", "3600", "--seed", "1", "-o", d / "big"],
             ["ingest", d / "big" / "receiver.csv", "--config", TESTBED, "-o", d / "BIG_RUN.mcap"],
             ["init", d / "BIG_RUN.mcap", "--start", "0", "--duration", "60", "-o", d / "BIG_INIT.json"],
             ["estimate", d / "BIG_RUN.mcap", "--init", d / "BIG_INIT.json", "--smooth", "-o", d / "BIG_STATES.mcap"]]
    for s in steps:
        r = cli(*s)
        if r.exit_code != 0:
            raise SystemExit(f"speed setup {s[0]} failed: {r.output}")
    out = {}
    for name in ("BIG_RUN.mcap", "BIG_STATES.mcap"):
        p = d / name
        times = []
        for _ in range(5):
            with open(p, "rb") as fh:
                t = time.perf_counter()
                verify_file(fh, p)
                times.append(time.perf_counter() - t)
        mib = p.stat().st_size / 2**20
        out[name] = {"mib": round(mib, 1), "verify_best_s": round(min(times), 4),
                     "mib_per_s": round(mib / min(times), 0)}
    real = mcap_io.verify_file
    spent = []

    def timed(fh, path):
        t = time.perf_counter()
        try:
            return real(fh, path)
        finally:
            spent.append(time.perf_counter() - t)

    walls = {}
    for arm in ("with_check", "without_check"):
        # without: no magic / footer / CRC checks at all (the A/B is noisy on a shared machine;
        # the time spent inside the checks, measured directly, is the figure that counts)
        mcap_io.verify_file = timed if arm == "with_check" else (lambda fh, path: Integrity("cdgps", True, True))
        t = time.perf_counter()
        r = cli("estimate", d / "BIG_RUN.mcap", "--init", d / "BIG_INIT.json", "--smooth", "-o", d / "S2.mcap")
        walls[arm] = round(time.perf_counter() - t, 2)
        mcap_io.verify_file = real
        assert r.exit_code == 0, r.output
    out["estimate_smooth_wall_s"] = walls
    out["verifications_per_estimate"] = len(spent)
    out["verify_s_in_estimate"] = round(sum(spent), 4)
    out["verify_fraction_of_estimate_pct"] = round(100 * sum(spent) / walls["with_check"], 3)
    t = time.perf_counter()
    r = cli("evaluate", "--truth", d / "big", "--estimate", d / "BIG_STATES.mcap", "--json")
    out["evaluate_big_states_wall_s"] = round(time.perf_counter() - t, 2)
    assert r.exit_code == 0, r.output
    return out


def disable_checks() -> None:
    """Readers as before issue 12 item 2: chunk and attachment CRCs only (shows the campaign can fail)."""
    mcap_io.verify_file = lambda fh, path: Integrity("cdgps", True, True)
    mcap_io.check_records = lambda records, info, path: {
        m.name: {k: v for k, v in m.metadata.items() if k != "record_sha256"} for m in records}


def main_(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sample", type=int, default=None, help="mutations per file (default: every byte)")
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--only", default="RUN,STATES,GNSS", help="comma-separated file kinds")
    ap.add_argument("--speed", action="store_true", help="measure verification speed instead")
    ap.add_argument("--no-check", action="store_true",
                    help="disable the summary / data-section CRC and record_sha256 checks (the 'before' figures)")
    ap.add_argument("--json", type=Path, help="write the results here")
    ap.add_argument("--workdir", type=Path, help="keep the files here (default: a temporary folder)")
    a = ap.parse_args(argv)
    tmp = None
    if a.workdir is None:
        tmp = tempfile.TemporaryDirectory()
        d = Path(tmp.name)
    else:
        d = a.workdir
        d.mkdir(parents=True, exist_ok=True)
    try:
        if a.speed:
            res = {"speed": speed(d)}
        else:
            build(d)
            if a.no_check:
                disable_checks()
            rng = np.random.default_rng(a.seed)
            files = {"RUN": d / "RUN.mcap", "STATES": d / "STATES.mcap", "GNSS": d / "GRUN.mcap"}
            res = {"command": "python benchmarks/mcap_mutation.py " + " ".join(argv if argv is not None else sys.argv[1:]),
                   "seed": a.seed, "files": {}}
            for k in a.only.split(","):
                res["files"][k] = campaign(d, k, files[k], a.sample, rng)
                f = res["files"][k]
                print(f"{k} ({f['file']}, {f['bytes']} bytes): {f['mutations']} mutations, {f['cases']} cases: "
                      + ", ".join(f"{c} {f['total'][c]}" for c in CLASSES))
        if a.json:
            a.json.parent.mkdir(parents=True, exist_ok=True)
            a.json.write_text(json.dumps(res, indent=1) + "\n")
        if a.speed:
            print(json.dumps(res, indent=1))
    finally:
        if tmp is not None:
            tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main_())
