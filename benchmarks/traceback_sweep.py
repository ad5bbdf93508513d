#!/usr/bin/env python3
"""Traceback sweep (issue 12 item 5): every subcommand over mutated inputs, tracebacks counted.

Builds small base artefacts once (a 6 s run of the 2-DOF structure: receiver CSV, RUN.mcap,
INIT.json, STATES.mcap; a GNSS RUN from a simulated 2-minute RINEX pair; the shipped UBX test file), then runs the CLI
in-process (Click's test runner, so the imports are paid once) over

* truncated files and seeded byte flips of the CSV log, the structure TOML, INIT.json, RINEX, UBX,
  RUN.mcap and STATES.mcap;
* value mutations: CSV fields and TOML keys replaced by extreme or wrongly typed values
  (``inf``, ``1e999``, ``1e308``, ``1e-308``, ``-1e9``, ``["C1"]``, ``{a = 1}``, ...), INIT.json
  non-UTF-8, deeply nested, with an extreme ``time_s``;
* extreme option values (``--seed -1``, ``--duration 1e12``, ``--segment-s 1e300``, ...);

plus a few cases in a subprocess (stdout to ``/dev/full`` and to a closed pipe, an output file
size limit via ``RLIMIT_FSIZE``).  The sweep process runs under an address-space limit
(``RLIMIT_AS``, 3 GiB), so a runaway allocation fails at once instead of swapping the machine.

Every case ends in one of: ``ok`` (exit 0), ``clean`` (exit 2 with a ``cdgps: error:`` or
Click usage message, no traceback), ``traceback`` (any other exception), ``timeout`` or ``other``
(another exit status).  Prints counts per family and each distinct traceback (exception type and
innermost cdgps frame) with one example::

    python benchmarks/traceback_sweep.py                   # ≈ 5–10 min on a loaded 2-core machine
    python benchmarks/traceback_sweep.py --json docs/benchmarks/traceback_sweep.json
    python benchmarks/traceback_sweep.py --only toml,options
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "teague-1995-2dof.toml"
DATA = ROOT / "tests" / "data"
UBX = DATA / "pygpsdata-RXMRAWX.log"
TIMEOUT_S = 90
EXTREME_NUMBERS = ["inf", "-inf", "nan", "1e999", "1e308", "-1e308", "1e-308", "-1e9", "1e12", "0", "-1"]
WRONG_TYPES = ['["C1"]', "{ a = 1 }", '"text"', "true"]


class _Timeout(Exception):
    pass


def _on_alarm(signum, frame):
    raise _Timeout()


# ---- base artefacts ---------------------------------------------------------------------------


def _cli(args: list[str]):
    from click.testing import CliRunner

    from cdgps_cli.cli.commands import main

    return CliRunner().invoke(main, ["-q", *args], catch_exceptions=True)


def build_base(work: Path) -> dict:
    """Base files of every family (built once per work directory)."""
    base = work / "base"
    paths = {"config": base / "struct.toml", "sim": base / "sim", "run": base / "RUN.mcap",
             "init": base / "INIT.json", "states": base / "STATES.mcap", "obs": base / "gsim" / "rover.rnx",
             "obs2": base / "gsim" / "base.rnx", "nav": base / "gsim" / "nav.rnx", "ubx": base / "rx.ubx",
             "grun": base / "GRUN.mcap"}
    if (base / "done").exists():
        return paths
    base.mkdir(parents=True, exist_ok=True)
    shutil.copy(CONFIG, paths["config"])
    shutil.copy(UBX, paths["ubx"])
    steps = [["simulate-gnss", "--duration", "120", "-o", str(base / "gsim")],
             ["simulate", str(paths["config"]), "--duration", "6", "-o", str(paths["sim"])],
             ["ingest", str(paths["sim"] / "receiver.csv"), str(paths["sim"] / "gyro.csv"), "--config",
              str(paths["config"]), "-o", str(paths["run"])],
             ["init", str(paths["run"]), "-o", str(paths["init"])],
             ["estimate", str(paths["run"]), "--init", str(paths["init"]), "-o", str(paths["states"])],
             ["ingest", "--rinex", f"A={paths['obs']}", "--rinex", f"B={paths['obs2']}", "--nav", str(paths["nav"]),
              "--master", "A", "-o", str(paths["grun"])]]
    for s in steps:
        r = _cli(s)
        if r.exit_code != 0:
            raise SystemExit(f"base step failed: {' '.join(s)}\n{r.output}\n{r.exception!r}")
    (base / "done").write_text("")
    return paths


# ---- mutations --------------------------------------------------------------------------------


def truncations(data: bytes) -> list[tuple[str, bytes]]:
    n = len(data)
    return [(f"truncate@{k}", data[:k]) for k in sorted({0, 1, n // 10, n // 2, (9 * n) // 10, n - 1}) if k < n]


def flips(data: bytes, count: int, rng: random.Random, region: tuple[int, int] | None = None) -> list[tuple[str, bytes]]:
    lo, hi = region or (0, len(data))
    out = []
    for _ in range(count):
        i = rng.randrange(lo, hi)
        x = rng.randrange(1, 256)
        b = bytearray(data)
        b[i] ^= x
        out.append((f"flip@{i}^{x:#04x}", bytes(b)))
    return out


def csv_values(text: str) -> list[tuple[str, bytes]]:
    """The second data row's numeric fields replaced by extreme / odd values."""
    lines = text.splitlines(keepends=True)
    header = lines[0].rstrip("\r\n").split(",")
    out = []
    for col in ("time_s", "phase_cycles", "lock", "snr_dbhz"):
        j = header.index(col)
        for v in EXTREME_NUMBERS + ["", "x", "1" * 400]:
            row = lines[2].rstrip("\r\n").split(",")
            row[j] = v
            mutated = lines[:2] + [",".join(row) + "\n"] + lines[3:]
            out.append((f"{col}={v[:20]}", "".join(mutated).encode()))
    out.append(("non-UTF-8 row", (text[:200] + "\xff\xfe" + text[200:]).encode("latin-1")))
    return out


_KEY_LINE = re.compile(r"^(\s*)([A-Za-z_]+)(\s*=\s*)(.+?)(\s*#.*)?$")


def toml_values(text: str, rng: random.Random, per_key: int) -> list[tuple[str, bytes]]:
    """Each ``key = value`` line's value replaced by extreme numbers and wrongly typed values."""
    lines = text.splitlines(keepends=True)
    out = []
    for i, line in enumerate(lines):
        m = _KEY_LINE.match(line.rstrip("\n"))
        if not m:
            continue
        is_number = re.fullmatch(r"-?[0-9.eE+-]+", m.group(4)) is not None
        pool = (EXTREME_NUMBERS if is_number else []) + WRONG_TYPES
        for v in rng.sample(pool, min(per_key, len(pool))):
            v = {"inf": "inf", "-inf": "-inf", "nan": "nan", "1e999": "1e999"}.get(v, v)
            new = f"{m.group(1)}{m.group(2)}{m.group(3)}{v}\n"
            out.append((f"line {i + 1} {m.group(2)} = {v}", "".join(lines[:i] + [new] + lines[i + 1:]).encode()))
    return out


def init_values(data: bytes) -> list[tuple[str, bytes]]:
    doc = json.loads(data)
    out = [("non-UTF-8", data[:40] + b"\xff\xfe" + data[40:]),
           ("deep nesting", b"[" * 100_000 + b"]" * 100_000),
           ("deep nesting in state", data.replace(b'"x":', b'"x": ' + b"[" * 50_000 + b"]" * 50_000 + b', "x_":', 1)),
           ("top-level list", b"[1, 2]")]
    for t in ("-1e9", "1e12", "1e308", "-1e308", "1e-308"):
        d = json.loads(data)
        d["state"]["time_s"] = float(t)
        out.append((f"state.time_s={t}", json.dumps(d).encode()))
        if "window" in doc:
            d = json.loads(data)
            d["window"]["start_s"] = float(t)
            out.append((f"window.start_s={t}", json.dumps(d).encode()))
    for key in ("sigma_m",):
        for t in ("1e308", "1e-308", "-1"):
            d = json.loads(data)
            d[key] = float(t)
            out.append((f"{key}={t}", json.dumps(d).encode()))
    d = json.loads(data)
    d["state"]["x"] = [1e308] * len(d["state"]["x"])
    out.append(("state.x=1e308", json.dumps(d).encode()))
    return out


# ---- cases ------------------------------------------------------------------------------------


def cases(p: dict, work: Path, rng: random.Random, n_flips: int) -> list[tuple[str, str, list[str], bytes | None, str]]:
    """(family, mutation, argv with '{M}' for the mutated file and '{O}' for an output, data, suffix)."""
    out = []
    cfg, run, init, states, sim = str(p["config"]), str(p["run"]), str(p["init"]), str(p["states"]), p["sim"]

    def add(family, muts, argvs, suffix):
        for name, data in muts:
            for argv in argvs:
                out.append((family, name, argv, data, suffix))

    csv = (sim / "receiver.csv").read_bytes()
    ingest_csv = ["ingest", "{M}", str(sim / "gyro.csv"), "--config", cfg, "-o", "{O}.mcap"]
    add("csv", truncations(csv) + flips(csv, n_flips, rng) + csv_values(csv.decode()), [ingest_csv], ".csv")

    toml = p["config"].read_bytes()
    toml_cmds = [["ingest", str(sim / "receiver.csv"), "--config", "{M}", "-o", "{O}.mcap"],
                 ["simulate", "{M}", "--duration", "2", "-o", "{O}"]]
    add("toml", truncations(toml) + flips(toml, n_flips, rng), toml_cmds[:1], ".toml")
    add("toml", toml_values(toml.decode(), rng, 4), toml_cmds, ".toml")

    ij = p["init"].read_bytes()
    add("init_json", truncations(ij)[:3] + flips(ij, n_flips // 2, rng) + init_values(ij),
        [["estimate", run, "--init", "{M}", "-o", "{O}.mcap"]], ".json")

    rb = p["run"].read_bytes()
    run_cmds = [["info", "{M}", "--json"], ["init", "{M}", "-o", "{O}.json"]]
    add("run_mcap", truncations(rb) + flips(rb, n_flips, rng) + flips(rb, n_flips, rng, (len(rb) - 2000, len(rb))),
        run_cmds, ".mcap")

    sb = p["states"].read_bytes()
    add("states_mcap", truncations(sb) + flips(sb, n_flips, rng) + flips(sb, n_flips // 2, rng, (len(sb) - 3000, len(sb))),
        [["export", "{M}", "-o", "{O}.csv"], ["evaluate", "--truth", str(sim), "--estimate", "{M}"]], ".mcap")

    gb = p["grun"].read_bytes()
    add("gnss_run_mcap", truncations(gb)[:3] + flips(gb, n_flips, rng), [["info", "{M}"], ["init", "{M}", "-o", "{O}.json"]],
        ".mcap")

    ob = p["obs"].read_bytes()
    add("rinex", truncations(ob) + flips(ob, n_flips, rng),
        [["ingest", "--rinex", "A={M}", "--rinex", f"B={p['obs2']}", "--nav", str(p["nav"]), "--master", "B",
          "-o", "{O}.mcap"]], ".rnx")
    nb = p["nav"].read_bytes()
    add("rinex_nav", truncations(nb)[:3] + flips(nb, n_flips // 2, rng),
        [["ingest", "--rinex", f"A={p['obs']}", "--rinex", f"B={p['obs2']}", "--nav", "{M}", "--master", "A",
          "-o", "{O}.mcap"]], ".rnx")

    ub = p["ubx"].read_bytes()
    add("ubx", truncations(ub) + flips(ub, n_flips, rng), [["ingest", "--ubx", "R={M}", "-o", "{O}.mcap"]], ".ubx")

    opts = [
        ["simulate", cfg, "--seed", "-1", "-o", "{O}"], ["simulate", cfg, "--seed", str(2 ** 70), "-o", "{O}"],
        ["simulate", cfg, "--duration", "1e12", "-o", "{O}"], ["simulate", cfg, "--duration", "1e-308", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--noise-m", "1e308", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--multipath-m", "1e308", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--disturbance-scale", "1e308", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--random-slips", "1000000000", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--slip", "s2:S1:1e308:1", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--slip", "s2:S1:1:1e308", "-o", "{O}"],
        ["simulate", cfg, "--duration", "2", "--outage", "S1:0:1e308", "-o", "{O}"],
        ["init", run, "--ratio", "1e308", "-o", "{O}.json"], ["init", run, "--ratio", "-1", "-o", "{O}.json"],
        ["init", run, "--duration", "1e12", "-o", "{O}.json"], ["init", run, "--start", "-1e9", "-o", "{O}.json"],
        ["init", run, "--start", "1e308", "-o", "{O}.json"], ["init", run, "--sigma-m", "1e-308", "-o", "{O}.json"],
        ["init", run, "--sigma-m", "1e308", "-o", "{O}.json"], ["init", run, "--starts", "-1", "-o", "{O}.json"],
        ["init", run, "--starts", "1000000000", "-o", "{O}.json"], ["init", run, "--max-iterations", "-1", "-o", "{O}.json"],
        ["estimate", run, "--init", init, "--sigma-m", "1e308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--sigma-m", "1e-308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--process-noise-scale", "1e308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--process-noise-scale", "-1", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--rest-process-noise-scale", "1e308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--outlier-sigma", "1e308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--rest", "0:1e308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--rest", "auto", "--rest-window-s", "1e308", "-o", "{O}.mcap"],
        ["estimate", run, "--init", init, "--rest-retry-s", "1e308", "--rest", "1:3", "-o", "{O}.mcap"],
        ["spectra", states, "--segment-s", "1e300", "-o", "{O}"], ["spectra", states, "--segment-s", "1e-300", "-o", "{O}"],
        ["spectra", states, "--overlap", "1e308", "-o", "{O}"], ["spectra", states, "--pad", "1000000000", "-o", "{O}"],
        ["spectra", states, "--pad", "-1", "-o", "{O}"],
        ["evaluate", "--truth", str(sim), "--estimate", states, "--converge-s", "1e308"],
        ["report", "static", states, "--angle", "q1", "--survey-deg", "1e308", "-o", "{O}"],
        ["report", "static", states, "--angle", "q1", "--start", "-1e308", "--end", "1e308", "-o", "{O}"],
        ["report", "spectrum", states, "--segment-s", "1e300", "-o", "{O}"],
        ["simulate-gnss", "--duration", "1e12", "-o", "{O}"], ["simulate-gnss", "--rate-hz", "1e308", "-o", "{O}"],
        ["simulate-gnss", "--duration", "10", "--seed", "-1", "-o", "{O}"],
        ["simulate-gnss", "--duration", "10", "--random-walk", "1e308", "-o", "{O}"],
        ["simulate-gnss", "--duration", "10", "--phase-noise-m", "1e308", "-o", "{O}"],
        ["simulate-gnss", "--duration", "10", "--displacement", "1e308,0,0", "-o", "{O}"],
        ["simulate-gnss", "--duration", "10", "--master-xyz", "1e308,0,0", "-o", "{O}"],
        ["simulate-gnss-structure", cfg, "--duration", "1e12", "-o", "{O}"],
        ["simulate-gnss-structure", cfg, "--duration", "10", "--seed", "-1", "-o", "{O}"],
        ["baseline", "--rinex", f"A={p['obs']}", "--rinex", f"B={p['obs2']}", "--nav", str(p["nav"]), "--master", "A",
         "--mask-deg", "1e308", "-o", "{O}.json"],
        ["baseline", "--rinex", f"A={p['obs']}", "--rinex", f"B={p['obs2']}", "--nav", str(p["nav"]), "--master", "A",
         "--ratio", "1e308", "-o", "{O}.json"],
        ["config", "--rinex", f"A={p['obs']}", "--displacement", "random_walk", "--sigma", "1e308", "-o", "{O}.toml"],
    ]
    out += [("options", " ".join(a[1:]) if a[0] != "report" else " ".join(a[:2] + a[3:]), a, None, "") for a in opts]
    return out


def _signature(exc: BaseException, tb) -> str:
    frames = traceback.extract_tb(tb)
    own = [f for f in frames if "cdgps_cli" in f.filename] or frames
    f = own[-1] if own else None
    where = f"{Path(f.filename).name}:{f.lineno} {f.name}" if f else "?"
    return f"{type(exc).__module__}.{type(exc).__name__} @ {where}"


def run_case(argv: list[str], work: Path, idx: int, data: bytes | None, suffix: str) -> tuple[str, str]:
    d = work / "cases" / str(idx)
    d.mkdir(parents=True, exist_ok=True)
    m = d / f"input{suffix}"
    if data is not None:
        m.write_bytes(data)
    argv = [a.replace("{M}", str(m)).replace("{O}", str(d / "out")) for a in argv]
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(TIMEOUT_S)
    try:
        r = _cli(argv)
    except _Timeout:
        return "timeout", ""
    finally:
        signal.alarm(0)
        shutil.rmtree(d, ignore_errors=True)
    exc = r.exception
    if isinstance(exc, _Timeout):
        return "timeout", ""
    if exc is not None and not isinstance(exc, SystemExit):
        return "traceback", _signature(exc, r.exc_info[2]) + f" | {str(exc)[:160]}"
    if r.exit_code == 0:
        return "ok", ""
    if r.exit_code == 2:
        return "clean", ""
    return "other", f"exit {r.exit_code}: {r.output[-200:]}"


def stream_cases(p: dict, work: Path) -> list[tuple[str, str, str, str]]:
    """Subprocess cases: stdout to /dev/full and a closed pipe, an output size limit (RLIMIT_FSIZE)."""
    script = Path(sys.executable).parent / "cdgps"
    exe = [str(script)] if script.exists() else [sys.executable, "-m", "cdgps_cli.cli.commands"]
    run, init, sim, cfg = str(p["run"]), str(p["init"]), p["sim"], str(p["config"])
    specs = [("stdout /dev/full", exe + ["info", run, "--json"], "full", None),
             ("stdout /dev/full (text)", exe + ["info", run], "full", None),
             ("stdout closed pipe", exe + ["info", run, "--json"], "pipe", None),
             ("ingest, 20 kB file limit", exe + ["ingest", str(sim / "receiver.csv"), "--config", cfg, "-o",
                                                  str(work / "fs.mcap")], None, 20_000),
             ("estimate, 20 kB file limit", exe + ["estimate", run, "--init", init, "-o", str(work / "fs2.mcap")], None, 20_000),
             ("simulate, 20 kB file limit", exe + ["simulate", cfg, "--duration", "6", "-o", str(work / "fs3")], None, 20_000)]
    out = []
    for name, argv, stdout, fsize in specs:
        def limit(fsize=fsize):
            if fsize:
                signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
                resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
        if stdout == "full":
            with open("/dev/full", "w") as fh:
                r = subprocess.run(argv, stdout=fh, stderr=subprocess.PIPE, preexec_fn=limit, timeout=300)
            err, rc = r.stderr.decode(errors="replace"), r.returncode
        elif stdout == "pipe":
            pr = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
            pr.stdout.read(10)
            pr.stdout.close()
            err = pr.stderr.read().decode(errors="replace")
            rc = pr.wait(300)
        else:
            r = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=limit, timeout=300)
            err, rc = r.stderr.decode(errors="replace"), r.returncode
        kind = "traceback" if "Traceback" in err else ("ok" if rc == 0 else "clean" if rc in (2, 141) or stdout == "pipe" else "other")
        last = err.strip().splitlines()[-1] if err.strip() else ""
        out.append(("streams", name, kind, f"rc {rc}: {last[:200]}" if kind != "ok" else ""))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", default=None, help="Work directory (default: a temporary one, removed after).")
    ap.add_argument("--flips", type=int, default=12, help="Random byte flips per file and command [12].")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--only", default=None, help="Comma-separated families (csv, toml, init_json, run_mcap, ...).")
    ap.add_argument("--json", default=None, help="Also write the counts and signatures as JSON to this file.")
    args = ap.parse_args(argv)
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, hard))
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="cdgps-sweep-"))
    t0 = time.perf_counter()
    try:
        p = build_base(work)
        rng = random.Random(args.seed)
        todo = cases(p, work, rng, args.flips)
        only = set(args.only.split(",")) if args.only else None
        results = []
        for i, (family, name, cmd, data, suffix) in enumerate(todo):
            if only and family not in only:
                continue
            kind, detail = run_case(cmd, work, i, data, suffix)
            results.append((family, f"{cmd[0]} {name}", kind, detail))
        if not only or "streams" in only:
            results += stream_cases(p, work)
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
    counts = defaultdict(Counter)
    sigs = {}
    for family, name, kind, detail in results:
        counts[family][kind] += 1
        counts["total"][kind] += 1
        if kind in ("traceback", "timeout", "other"):
            key = detail.split(" | ")[0] if kind == "traceback" else f"{kind}: {family} {name[:40]}"
            sigs.setdefault(key, []).append(f"{family}: {name}" + (f" | {detail.split(' | ', 1)[-1]}" if detail else ""))
    kinds = ["ok", "clean", "traceback", "timeout", "other"]
    print(f"{'family':<15}" + "".join(f"{k:>10}" for k in kinds) + f"{'cases':>8}")
    for fam, c in counts.items():
        print(f"{fam:<15}" + "".join(f"{c[k]:>10}" for k in kinds) + f"{sum(c.values()):>8}")
    for sig, ex in sorted(sigs.items(), key=lambda kv: -len(kv[1])):
        print(f"\n[{len(ex)}] {sig}\n    e.g. {ex[0][:300]}")
    print(f"\n{time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"counts": {f: dict(c) for f, c in counts.items()},
                                               "signatures": {s: len(e) for s, e in sigs.items()},
                                               "examples": {s: e[:3] for s, e in sigs.items()}}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
