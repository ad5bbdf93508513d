#!/usr/bin/env python3
"""Fault campaign (issue 12 item 10): the installed ``cdgps`` as subprocesses over damaged inputs.

Extends ``benchmarks/traceback_sweep.py`` (its base artefacts, mutations and option cases are
reused as they are) from "no traceback" to every property of issue 12, each case run as its own
``cdgps`` process (``RLIMIT_AS`` 3 GiB, a timeout) in its own folder:

* ``mutated`` families (csv, toml, init_json, run_mcap, states_mcap, gnss_run_mcap, rinex,
  rinex_nav, ubx) and ``options`` (extreme values): the sweep's cases, plus more flips of the
  checksummed formats;
* ``overwrite``: each command with its output path = one of its inputs, spelt as is, ``d/./f``,
  through a symlink and a hard link;
* ``killed``: long-enough commands sent SIGTERM or SIGKILL after a random fraction of their clean
  run time, writing to a fresh path or over an earlier output.

Outcome of a case: ``ok`` (exit 0), ``clean`` (exit 2, a ``cdgps: error:`` or usage message),
``traceback``, ``timeout``, ``other`` (another exit status), ``killed``.  Flags counted on top:

* ``silent``: a mutated input of a corruption class that must be detected (any byte of an MCAP
  file; a UBX log, whose frames carry checksums) accepted with exit 0, a result different from the
  clean input's (stdout and output files, with the input's path and sha256 normalised) and no
  warning on stderr;
* ``destroyed``: an input file's sha256 changed;
* ``partial``: after an error or a kill, something at the output path that is neither absent, nor
  the earlier output exactly, nor the complete output of a clean run (for a folder: every file of
  one set or the other); ``temporaries``: hidden temporary files left beside the output (after a
  SIGKILL, which no process can handle: still there after the same command has run once more,
  whose write removes the stale temporaries of dead processes);
* ``nondeterministic`` (``determinism`` family): the same command run twice into the same path
  gave different bytes.

The commands of the later rounds (``report run``, ``report rtk``, ``foxglove-layout``, ``estimate
--fuse/--hold-out/--scene-exaggeration``, the sensor logs of ``simulate-gnss-structure`` and
``ingest --sensor-log``) have their own families (``pos``: an RTKLIB .pos for ``report rtk``;
``sensor_csv``: an accelerometer log; ``layout``: non-MCAP and damaged inputs of
``foxglove-layout`` and ``report run``), option cases (``new_options``), kills and determinism
cases, over inputs prepared once by :func:`extend_base`.

The inputs of the fusion round (:func:`fusion_cases`) have theirs: ``esf_ubx`` (a u-blox ESF-MEAS IMU
log for ``ingest --sensor-log``: truncated, flipped, garbage, gyro or accelerometer only, unknown data
types, time going back, no measurement, a RAWX log without ESF), ``esf_rx`` (ESF-MEAS inside a
receiver's RXM-RAWX log, ``ingest --ubx``: flips of its ESF part, the ESF frames alone), ``fuse_options``
(``--fuse`` empty, blank, an empty item, a kind twice, unknown or miscased kinds, ``--hold-out`` of an
unknown or empty name or of every fused sensor, ``--fuse strain`` without gauges, on the GNSS tower
and the pseudolite testbed), ``strain_toml`` (``[[strains]]`` with ends not in the structure, both
ends at one place, zero/negative/NaN/string sigma, a missing name, an unknown key, a table instead
of an array, for ``simulate-gnss-structure`` and ``estimate --fuse strain``).

Usage::

    python benchmarks/fault_campaign.py                          # everything (≈ 1,130 cases)
    python benchmarks/fault_campaign.py --sample 300 --seed 2 --jobs 2
    python benchmarks/fault_campaign.py --only killed,overwrite --markdown docs/hardening.md
    python benchmarks/fault_campaign.py --only esf_ubx,esf_rx,fuse_options,strain_toml --jobs 2
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import random
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traceback_sweep as sweep  # noqa: E402

ROOT = sweep.ROOT
TIMEOUT_S = 120
CDGPS = [str(Path(sys.executable).parent / "cdgps")] if (Path(sys.executable).parent / "cdgps").exists() \
    else [sys.executable, "-m", "cdgps_cli.cli.commands"]
#: families whose corruption must be detected (checksummed formats): a different result is "silent"
DETECT = {"run_mcap", "states_mcap", "gnss_run_mcap", "ubx", "esf_ubx", "esf_rx"}
#: a fixed report date (reports print the newest input's modification time otherwise)
DATE = "2026-12-04"
WARNING_WORDS = ("warning", "corrupt", "checksum", "skipped", "truncated")
FLAGS = ("silent", "destroyed", "partial", "temporaries", "nondeterministic")
KINDS = ("ok", "clean", "traceback", "timeout", "other", "killed")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, resource.getrlimit(resource.RLIMIT_AS)[1]))


# ---- one case -----------------------------------------------------------------------------------


class Case:
    """One command: argv with ``{M}`` (the mutated input, written as ``input<suffix>`` in the case
    folder) and ``{O}`` (the output stem in the case folder)."""

    def __init__(self, family, name, argv, data=None, suffix="", *, kill=None, old=None, link=None, repeat=False):
        self.family, self.name, self.argv, self.data, self.suffix = family, name, argv, data, suffix
        self.repeat = repeat    # determinism: run twice into the same path, compare the bytes
        self.kill = kill        # (signal, fraction of the clean run time) or None
        self.old = old          # "file" / a folder to copy: an earlier output at the output path
        self.link = link        # overwrite cases: how the output path spells the input
        self.detect = family in DETECT or family == "control"
        self.clean_source = None  # the unmutated input (for the reference run)
        self.benign = ()          # stderr lines with these words do not count as a warning (silent check)

    @property
    def ref_key(self) -> tuple:
        return (str(self.clean_source or ""), *self.argv)


def _paths_in(argv: list[str]) -> list[Path]:
    """Existing files an argv names (plain arguments and NAME=FILE values)."""
    out = []
    for a in argv:
        for cand in (a, a.partition("=")[2]):
            if cand and os.path.isfile(cand):
                out.append(Path(cand))
    return out


def _output_of(argv: list[str]) -> Path | None:
    for i, a in enumerate(argv[:-1]):
        if a in ("-o", "--output", "--csv", "--out"):
            return Path(argv[i + 1])
    return None


def _snapshot(out: Path | None):
    """Contents at an output path: None, bytes of a file, or {name: bytes} of a folder."""
    if out is None or not out.exists():
        return None
    if out.is_dir():
        return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file()}
    return out.read_bytes()


def _normalised(blob: bytes, d: Path, shas: list[str]) -> bytes:
    blob = blob.replace(str(d).encode(), b"<DIR>")
    for h in shas:
        blob = blob.replace(h.encode(), b"<SHA>")
    return blob


def _result_digest(out: Path | None, stdout: bytes, d: Path, shas: list[str]) -> bytes:
    """What a command produced, comparable across case folders (MCAP outputs by their contents)."""
    parts = [stdout]
    snap = _snapshot(out)
    if isinstance(snap, bytes) and out.suffix == ".mcap":
        from cdgps_cli.io.mcap import read_mcap

        c = read_mcap(out)
        snap = pickle.dumps({k: v for k, v in vars(c).items() if k != "path"}, protocol=4)
    parts.append(pickle.dumps(snap, protocol=4))
    return hashlib.sha256(_normalised(b"\0".join(parts), d, shas)).digest()


def run_case(case: Case, work: Path, idx: int, refs: dict) -> dict:
    d = work / "c" / f"{idx:06d}"          # the same path length as the references' (pickled paths)
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    m = d / f"input{case.suffix}"
    if case.data is not None:
        m.write_bytes(case.data)
    argv = [a.replace("{M}", str(m)).replace("{O}", str(d / "out")) for a in case.argv]
    out = _output_of(argv)
    if case.link and out is not None:
        argv, out = _link_output(argv, out, case.link.replace("{M}", str(m)), d)
    inputs = {p: _sha(p) for p in _paths_in(argv)}
    if case.old is not None and out is not None:
        _place_old(case.old, out)
    old = _snapshot(out)
    t0 = time.perf_counter()
    pr = subprocess.Popen(CDGPS + argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=d,
                          preexec_fn=_limit_memory)
    kind = None
    if case.kill:
        sig, frac = case.kill
        try:
            stdout, stderr = pr.communicate(timeout=max(frac * refs.get(("time",) + case.ref_key, 1.0), 0.05))
        except subprocess.TimeoutExpired:
            pr.send_signal(sig)
            stdout, stderr = pr.communicate()
            kind = "killed"
    else:
        try:
            stdout, stderr = pr.communicate(timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pr.kill()
            stdout, stderr = pr.communicate()
            kind = "timeout"
    elapsed = time.perf_counter() - t0
    err = stderr.decode(errors="replace")
    rc = pr.returncode
    if kind is None:
        kind = ("traceback" if "Traceback (most recent call last)" in err else "ok" if rc == 0
                else "clean" if rc == 2 else "other")
    flags = set()
    if case.repeat and kind == "ok":
        if not _same_twice(argv, out, stdout, d):
            flags.add("nondeterministic")
    if any(p.exists() and _sha(p) != h for p, h in inputs.items()) or any(not p.exists() for p in inputs):
        flags.add("destroyed")
    new = _snapshot(out)
    ref = refs.get(case.ref_key)
    if kind != "ok" and out is not None and new is not None and new != old:
        complete = ref is not None and ref[1] is not None and _same_output(new, ref[1], d, ref[2])
        if not complete:
            flags.add("partial")
    if _temporaries(out) and case.kill and case.kill[0] == signal.SIGKILL:
        # a SIGKILLed process cannot clean up: the contract is that the next write removes them
        subprocess.run(CDGPS + argv, capture_output=True, cwd=d, preexec_fn=_limit_memory, timeout=TIMEOUT_S)
    if _temporaries(out):
        flags.add("temporaries")
    if case.detect and kind == "ok" and ref is not None:
        shas = [h for h in inputs.values()] + [ref[3]]
        said = "\n".join(ln for ln in err.lower().splitlines() if not any(b in ln for b in case.benign))
        if _result_digest(out, stdout, d, shas) != ref[0] and not any(w in said for w in WARNING_WORDS):
            flags.add("silent")
    last = err.strip().splitlines()[-1][:200] if err.strip() else ""
    shutil.rmtree(d, ignore_errors=True)
    return {"family": case.family, "name": case.name, "argv": " ".join(case.argv[:1]), "kind": kind, "flags": sorted(flags),
            "rc": rc, "elapsed_s": elapsed, "message": last}


def _temporaries(out: Path | None) -> bool:
    """Hidden temporaries (``.*tmp*``) beside the output or inside an output folder."""
    hidden = list(out.parent.iterdir()) + (list(out.iterdir()) if out.is_dir() else []) if out is not None else []
    return any(p.name.startswith(".") and "tmp" in p.name for p in hidden)


def _same_twice(argv: list[str], out: Path | None, stdout: bytes, d: Path) -> bool:
    """Determinism: the output and stdout of a second run into the same (emptied) path are the first's."""
    first = _snapshot(out)
    if out is not None:
        shutil.rmtree(out) if out.is_dir() else out.unlink(missing_ok=True)
    r = subprocess.run(CDGPS + argv, capture_output=True, cwd=d, preexec_fn=_limit_memory, timeout=TIMEOUT_S)
    return r.returncode == 0 and r.stdout == stdout and _snapshot(out) == first


def _same_output(new, ref, d: Path, ref_dir: str) -> bool:
    """A snapshot equal to a clean run's (paths of the clean run's folder normalised)."""
    def norm(s, folder):
        if isinstance(s, bytes):
            return s.replace(folder.encode(), b"<DIR>")
        return {k: v.replace(folder.encode(), b"<DIR>") for k, v in s.items()}
    return norm(new, str(d)) == norm(ref, ref_dir)


def _place_old(old, out: Path) -> None:
    if old == "file":
        out.write_bytes(b"an earlier output\n")
    else:
        shutil.copytree(old, out)


def _link_output(argv, out: Path, link: str, d: Path):
    """Overwrite cases: argv's output replaced by a spelling of the input it names."""
    victim = Path(link.split("|", 1)[1])
    how = link.split("|", 1)[0]
    if how == "same":
        spelt = victim
    elif how == "dot":
        spelt = Path(f"{victim.parent}/./{victim.name}")
    elif how == "symlink":
        spelt = d / "link"
        spelt.symlink_to(victim)
    else:
        spelt = d / "hard"
        os.link(victim, spelt)
    argv = [str(spelt) if a == str(out) else a for a in argv]
    return argv, spelt


# ---- the case list ------------------------------------------------------------------------------


def mutated_cases(p: dict, work: Path, rng: random.Random, n_flips: int) -> list[Case]:
    out = [Case(f, n, a, data, s) for f, n, a, data, s in sweep.cases(p, work, rng, n_flips)]
    sources = {"run_mcap": p["run"], "states_mcap": p["states"], "gnss_run_mcap": p["grun"], "ubx": p["ubx"]}
    for c in out:
        c.clean_source = sources.get(c.family)
    # more flips of the checksummed formats (silent acceptances), over the whole file
    for fam, key, argvs in (("run_mcap", "run", [["info", "{M}", "--json"], ["init", "{M}", "-o", "{O}.json"]]),
                            ("states_mcap", "states", [["export", "{M}", "-o", "{O}.csv"],
                                                       ["evaluate", "--truth", str(p["sim"]), "--estimate", "{M}", "--json"]]),
                            ("gnss_run_mcap", "grun", [["info", "{M}", "--json"]]),
                            ("ubx", "ubx", [["ingest", "--ubx", "R={M}", "-o", "{O}.mcap", "--json"]])):
        raw = p[key].read_bytes()
        for name, data in sweep.flips(raw, 2 * n_flips, rng):
            for a in argvs:
                out.append(Case(fam, name, a, data, Path(p[key]).suffix))
                out[-1].clean_source = p[key]
        for a in argvs:                         # the unmutated file: must be "ok", never "silent"
            c = Case("control", f"clean {Path(p[key]).name}", a, raw, Path(p[key]).suffix)
            c.clean_source = p[key]
            out.append(c)
    return out


def overwrite_cases(p: dict) -> list[Case]:
    cfg, run, init, states, sim = str(p["config"]), str(p["run"]), str(p["init"]), str(p["states"]), p["sim"]
    obs, obs2, nav = str(p["obs"]), str(p["obs2"]), str(p["nav"])
    specs = [(["init", "{M}", "-o", "{O}"], run),
             (["estimate", "{M}", "--init", init, "-o", "{O}"], run),
             (["estimate", run, "--init", "{M}", "-o", "{O}"], init),
             (["export", "{M}", "-o", "{O}"], states),
             (["ingest", str(sim / "receiver.csv"), "--config", "{M}", "-o", "{O}"], cfg),
             (["ingest", "{M}", "--config", cfg, "-o", "{O}"], str(sim / "receiver.csv")),
             (["baseline", "--rinex", "A={M}", "--rinex", f"B={obs2}", "--nav", nav, "--master", "B", "-o", "{O}"], obs),
             (["config", "--rinex", "A={M}", "-o", "{O}"], obs),
             (["baseline-config", "--rinex", f"A={obs}", "--rinex", f"B={obs2}", "--nav", "{M}", "-o", "{O}"], nav)]
    out = []
    for argv, src in specs:
        data = Path(src).read_bytes()
        suffix = Path(src).suffix
        for how in ("same", "dot", "symlink", "hardlink"):
            out.append(Case("overwrite", f"{argv[0]} -o {Path(src).name} ({how})", argv, data, suffix,
                            link=f"{how}|{{M}}"))
    return out


def killed_cases(p: dict, work: Path, rng: random.Random, per_command: int) -> list[Case]:
    cfg, run, init, states = str(p["config"]), str(p["run"]), str(p["init"]), str(p["states"])
    old = work / "old"
    specs = [(["simulate", cfg, "--duration", "120", "-o", "{O}"], old / "sim-seed1"),
             (["ingest", str(p["sim"] / "receiver.csv"), "--config", cfg, "-o", "{O}.mcap"], "file"),
             (["init", run, "-o", "{O}.json"], "file"),
             (["estimate", run, "--init", init, "--smooth", "-o", "{O}.mcap"], "file"),
             (["export", states, "-o", "{O}.csv"], "file"),
             (["spectra", states, "-o", "{O}"], old / "spectra-seg1"),
             (["simulate-gnss", "--duration", "900", "-o", "{O}"], old / "gsim-seed1")]
    out = []
    for argv, earlier in specs:
        for _ in range(per_command):
            sig = rng.choice([signal.SIGTERM, signal.SIGKILL])
            frac = rng.uniform(0.05, 0.95)
            over = rng.random() < 0.5
            out.append(Case("killed", f"{argv[0]} {sig.name} at {frac:.2f} of the run{' over an earlier output' if over else ''}",
                            argv, kill=(sig, frac), old=earlier if over else None))
    return out


# ---- the commands of the later rounds -------------------------------------------------------------


def extend_base(p: dict, work: Path) -> dict:
    """Inputs of the later commands, prepared once: an RTKLIB .pos (``cdgps rtk`` on the base GNSS
    simulation), a 10 s tower with sensor logs (simulate-gnss-structure configs/tower-fusion.toml),
    its RUN and INIT, and a ``report run`` folder and a layout as earlier outputs."""
    base = work / "base"
    fus = base / "fus"
    q = dict(p, pos=base / "rtk.pos", fus=fus, tower=sweep.ROOT / "configs" / "tower-fusion.toml",
             frun=base / "FRUN.mcap", finit=base / "FINIT.json", old_report=base / "old-report")
    q["esf_log"], q["esf_rx"] = base / "imu-esf.ubx", base / "rx-esf.ubx"
    if (base / "done-later").exists():
        return q
    steps = [["rtk", "--base", str(p["obs2"]), "--rover", str(p["obs"]), "--nav", str(p["nav"]), "-o", str(q["pos"])],
             ["simulate-gnss-structure", str(q["tower"]), "--duration", "10", "--gnss-interval", "0.1", "--seed", "2",
              "-o", str(fus)],
             ["ingest", "--config", str(fus / "config.toml"), "-o", str(q["frun"])],
             ["init", str(q["frun"]), "-o", str(q["finit"])],
             ["report", "run", str(p["states"]), "--no-spectra", "--date", "2020-01-01", "-o", str(q["old_report"])]]
    for argv in steps:
        subprocess.run(CDGPS + ["-q", *argv], check=True, capture_output=True)
    e = esf_inputs(q)
    q["esf_log"].write_bytes(e["log"])
    q["esf_rx"].write_bytes(p["ubx"].read_bytes() + e["rx"])
    (base / "done-later").write_text("")
    return q


def _short(argv: list[str]) -> str:
    return " ".join(Path(a).name if a.startswith("/") else a for a in argv)


def _fusion_estimate(q: dict, *extra: str) -> list[str]:
    return ["estimate", str(q["frun"]), "--init", str(q["finit"]), "--structure", str(q["tower"]), *extra,
            "-o", "{O}.mcap"]


def later_cases(q: dict, rng: random.Random, n_flips: int, per_kill: int) -> list[Case]:
    """Mutated inputs, options, overwrites, kills and determinism of the later commands."""
    out = []
    states, run, init, pos = str(q["states"]), str(q["run"]), str(q["init"]), str(q["pos"])
    garbage = [("empty file", b""), ("text", b"not a file of this kind\n"), ("binary", bytes(range(256)) * 4),
               ("MCAP magic only", b"\x89MCAP0\r\n")]
    pb = q["pos"].read_bytes()
    for name, data in sweep.truncations(pb) + sweep.flips(pb, n_flips, rng) + garbage[:3] + [
            ("header only", b"".join(l for l in pb.splitlines(keepends=True) if l.startswith(b"%"))),
            ("a NaN latitude", pb.replace(b"   35.", b"   nan", 1)),
            ("epochs reversed", b"".join([l for l in pb.splitlines(keepends=True) if l.startswith(b"%")]
                                         + [l for l in pb.splitlines(keepends=True) if not l.startswith(b"%")][::-1]))]:
        out.append(Case("pos", name, ["report", "rtk", "{M}", "--date", DATE, "-o", "{O}"], data, ".pos"))
    acc = (q["fus"] / "accel.csv").read_bytes()
    for name, data in sweep.truncations(acc) + sweep.flips(acc, n_flips, rng) + garbage[:2]:
        out.append(Case("sensor_csv", name, ["ingest", "--config", str(q["fus"] / "config.toml"), "--sensor-log", "{M}",
                                              "-o", "{O}.mcap"], data, ".csv"))
    sb = q["states"].read_bytes()
    layout_inputs = sweep.truncations(sb)[:3] + garbage + [("a RUN", q["run"].read_bytes()),
                                                           ("a GNSS RUN", q["grun"].read_bytes())]
    for name, data in layout_inputs:
        for argv in (["foxglove-layout", "{M}", "-o", "{O}.json"],
                     ["report", "run", "{M}", "--no-spectra", "--date", DATE, "-o", "{O}"]):
            out.append(Case("layout", name, argv, data, ".mcap"))
    for name, data in sweep.flips(sb, n_flips // 2, rng):     # damaged STATES: detected, never a silent page
        for argv in (["foxglove-layout", "{M}", "-o", "{O}.json"],
                     ["report", "run", "{M}", "--no-spectra", "--date", DATE, "-o", "{O}"]):
            c = Case("states_mcap", name, argv, data, ".mcap")
            c.clean_source = q["states"]
            out.append(c)
    for argv in (["foxglove-layout", "{M}", "-o", "{O}.json"],
                 ["report", "run", "{M}", "--no-spectra", "--date", DATE, "-o", "{O}"]):
        c = Case("control", "clean STATES.mcap", argv, sb, ".mcap")
        c.clean_source = q["states"]
        out.append(c)
    est = ["estimate", run, "--init", init]
    opts = [
        [*est, "--scene-exaggeration", "-1", "-o", "{O}.mcap"], [*est, "--scene-exaggeration", "nan", "-o", "{O}.mcap"],
        [*est, "--scene-exaggeration", "x", "-o", "{O}.mcap"], [*est, "--scene-exaggeration", "inf", "-o", "{O}.mcap"],
        [*est, "--scene-exaggeration", "0", "-o", "{O}.mcap"], [*est, "--scene-exaggeration", "1e308", "-o", "{O}.mcap"],
        [*est, "--fuse", "bogus", "-o", "{O}.mcap"], [*est, "--hold-out", "acc-top", "-o", "{O}.mcap"],
        _fusion_estimate(q, "--fuse", "bogus"), _fusion_estimate(q, "--fuse", ""),
        _fusion_estimate(q, "--fuse", "accel,accel,strain"), _fusion_estimate(q, "--hold-out", "acc-top"),
        _fusion_estimate(q, "--fuse", "accel", "--hold-out", "nope"),
        _fusion_estimate(q, "--fuse", "accel", "--hold-out", "acc-top", "--hold-out", "acc-mid"),
        _fusion_estimate(q, "--fuse", "gyro", "--scene-exaggeration", "nan"),
        _fusion_estimate(q, "--scene-exaggeration", "1e308"),
        ["estimate", str(q["grun"]), "--init", init, "--fuse", "accel", "-o", "{O}.mcap"],
        ["ingest", "--config", str(q["fus"] / "config.toml"), "--sensor-log", str(q["fus"] / "nope.csv"), "-o", "{O}.mcap"],
        ["ingest", "--config", str(q["fus"] / "config.toml"), "--sensor-log", str(q["pos"]), "-o", "{O}.mcap"],
        ["ingest", str(q["sim"] / "receiver.csv"), "--config", str(q["config"]), "--sensor-log",
         str(q["fus"] / "accel.csv"), "-o", "{O}.mcap"],
        ["simulate-gnss-structure", str(q["tower"]), "--duration", "1e12", "-o", "{O}"],
        ["simulate-gnss-structure", str(q["tower"]), "--duration", "2", "--gnss-interval", "0", "-o", "{O}"],
        ["simulate-gnss-structure", str(q["tower"]), "--duration", "2", "--gnss-interval", "nan", "-o", "{O}"],
        ["report", "run", states, "--segment-s", "1e300", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--segment-s", "-1", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--overlap", "1", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--pad", "0", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--coords", "nope", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--angle", "q1", "--survey-deg", "nan", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--angle", "zz9", "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--gyro", str(q["grun"]), "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--truth", str(q["fus"]), "--date", DATE, "-o", "{O}"],
        ["report", "run", states, "--date", "yesterday", "-o", "{O}"],
        ["report", "rtk", pos, "--date", "13/13/13", "-o", "{O}"],
        ["report", "rtk", states, "-o", "{O}"],
        ["foxglove-layout", run, "-o", "{O}.json"], ["foxglove-layout", pos, "-o", "{O}.json"],
    ]
    out += [Case("new_options", _short(a), a) for a in opts]
    for argv, src, suffix in ((["foxglove-layout", "{M}", "-o", "{O}"], q["states"], ".mcap"),
                              (["report", "run", "{M}", "--no-spectra", "-o", "{O}"], q["states"], ".mcap"),
                              (["report", "rtk", "{M}", "-o", "{O}"], q["pos"], ".pos"),
                              (["ingest", "--config", str(q["fus"] / "config.toml"), "--sensor-log", "{M}", "-o", "{O}"],
                               q["fus"] / "accel.csv", ".csv")):
        for how in ("same", "symlink"):
            out.append(Case("overwrite", f"{' '.join(argv[:2])} -o {src.name} ({how})", argv, src.read_bytes(), suffix,
                            link=f"{how}|{{M}}"))
    kills = [(["report", "run", states, "--date", DATE, "-o", "{O}"], q["old_report"]),
             (["foxglove-layout", states, "-o", "{O}.json"], "file"),
             (["report", "rtk", pos, "--date", DATE, "-o", "{O}"], q["old_report"]),
             (_fusion_estimate(q, "--fuse", "accel,gyro", "--smooth"), "file")]
    for argv, earlier in kills:
        for _ in range(per_kill):
            sig = rng.choice([signal.SIGTERM, signal.SIGKILL])
            frac, over = rng.uniform(0.05, 0.95), rng.random() < 0.5
            out.append(Case("killed", f"{' '.join(argv[:2])} {sig.name} at {frac:.2f} of the run"
                                      f"{' over an earlier output' if over else ''}",
                            argv, kill=(sig, frac), old=earlier if over else None))
    det = [["report", "run", states, "--date", DATE, "-o", "{O}"],
           ["report", "run", states, "--gyro", run, "--truth", str(q["sim"]), "--date", DATE, "-o", "{O}"],
           ["report", "rtk", pos, "--date", DATE, "-o", "{O}"],
           ["foxglove-layout", states, "-o", "{O}.json"],
           _fusion_estimate(q, "--fuse", "accel,gyro", "--hold-out", "acc-mid", "--scene-exaggeration", "20"),
           ["simulate-gnss-structure", str(q["tower"]), "--duration", "5", "--seed", "3", "-o", "{O}"],
           ["ingest", "--config", str(q["fus"] / "config.toml"), "-o", "{O}.mcap"],
           ["export", states, "-o", "{O}.csv"], ["evaluate", "--truth", str(q["sim"]), "--estimate", states, "--json"],
           ["report", "spectrum", states, "-o", "{O}"],
           ["estimate", run, "--init", init, "--smooth", "-o", "{O}.mcap"]]
    out += [Case("determinism", _short(a), a, repeat=True) for a in det]
    return out


#: RXM-RAWX log of the ``ubx`` family's receiver (2024-08-13 14:09:53–14:10:06 GPST)
RAWX_TOW0_S = 2 * 86400 + 14 * 3600 + 9 * 60 + 53


def esf_frame(tag_ms: int, data, calib_ms: int | None = None, pid: int = 0) -> bytes:
    """One UBX-ESF-MEAS frame: ``data`` [(dataType, signed 24-bit value)], calibTtag when given."""
    flags = len(data) << 11 | (0x8 if calib_ms is not None else 0)
    payload = tag_ms.to_bytes(4, "little") + flags.to_bytes(2, "little") + pid.to_bytes(2, "little")
    payload += b"".join(((t << 24) | (v & 0xFFFFFF)).to_bytes(4, "little") for t, v in data)
    if calib_ms is not None:
        payload += calib_ms.to_bytes(4, "little")
    body = b"\x10\x02" + len(payload).to_bytes(2, "little") + payload
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


def esf_inputs(q: dict) -> dict:
    """ESF-MEAS logs: the tower's top accelerometer (accel.csv, 2^-10 m/s^2, GPS time of week in
    ms) with a gyro triad beside it; ESF frames for the RAWX receiver log's 13 s."""
    from cdgps_cli.io.sensor_logs import read_sensor_csv  # noqa: PLC0415

    _, acc = read_sensor_csv(q["fus"] / "accel.csv")
    acc = acc[acc["sensor"] == acc["sensor"].iloc[0]]
    frames = []
    for t, *v in acc[["time_s", "accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].itertuples(index=False):
        tow_ms = int(round((t % 604800.0) * 1000))
        frames.append(esf_frame(0, [(16 + j, int(round(x * 1024))) for j, x in enumerate(v) if x == x], calib_ms=tow_ms))
        frames.append(esf_frame(0, [(14, 40), (13, -40), (5, 4096)], calib_ms=tow_ms + 1))
    rx = b"".join(esf_frame(0, [(16, 10), (17, 20), (18, 10035)], calib_ms=(RAWX_TOW0_S + i) * 1000)
                  + esf_frame(0, [(14, 4096), (13, 0), (5, -4096)], calib_ms=(RAWX_TOW0_S + i) * 1000 + 5)
                  for i in range(10))
    return {"log": b"".join(frames), "frames": frames, "rx": rx}


def fusion_cases(p: dict, q: dict, rng: random.Random, n_flips: int) -> list[Case]:
    """The ESF-MEAS reader, --fuse/--hold-out and [[strains]] (families esf_ubx, esf_rx, fuse_options,
    strain_toml)."""
    out = []
    e = esf_inputs(q)
    log, frames = e["log"], e["frames"]
    tag0 = int.from_bytes(frames[0][-6:-2], "little")
    gyro = b"".join(f for f in frames[1::2])
    accel = b"".join(f for f in frames[0::2])
    edge = [("clean", log), ("gyro only", gyro), ("accel only", accel),
            ("unknown data types only", b"".join(esf_frame(0, [(11, 5), (63, 1)], calib_ms=tag0 + i) for i in range(20))),
            ("time going back", frames[2] + frames[0] + b"".join(frames[4:])),
            ("a sample repeated", frames[0] + log),
            ("numMeas 0", esf_frame(0, [], calib_ms=tag0)),
            ("a data type twice", esf_frame(0, [(16, 1), (16, 2)], calib_ms=tag0) + log),
            ("RAWX without ESF", p["ubx"].read_bytes()), ("empty", b""), ("text", b"imu log\n" * 20),
            ("gzip magic", b"\x1f\x8b" + log[:100]), ("one byte", log[:1])]
    ing = ["ingest", "--config", str(q["fus"] / "config.toml"), "--sensor-log", "mast={M}", "-o", "{O}.mcap", "--json"]
    for name, data in edge + sweep.truncations(log)[1:] + sweep.flips(log, 2 * n_flips, rng):
        c = Case("esf_ubx", name, ing, data, ".ubx")
        c.clean_source = q["esf_log"]
        c.detect = name not in ("gyro only", "accel only")      # valid logs: a different result is right
        out.append(c)
    raw = p["ubx"].read_bytes()
    rx_log = raw + e["rx"]
    rx_argv = ["ingest", "--ubx", "A={M}", "-o", "{O}.mcap", "--json"]
    rx_cases = [("clean", rx_log), ("ESF frames alone, no RAWX", e["rx"]), ("ESF first", e["rx"] + raw),
                ("ESF time going back", raw + e["rx"][len(e["rx"]) // 2:] + e["rx"][:len(e["rx"]) // 2])]
    for name, data in rx_cases + sweep.flips(rx_log, 2 * n_flips, rng, region=(len(raw), len(rx_log))):
        c = Case("esf_rx", name, rx_argv, data, ".ubx")
        c.clean_source = q["esf_rx"]
        c.benign = ("has no position",)       # said by every run of this log, damaged or not
        out.append(c)
    tb = ["estimate", str(p["run"]), "--init", str(p["init"])]
    fuse_opts = [["--fuse", ""], ["--fuse", " "], ["--fuse", ","], ["--fuse", "accel,,gyro"], ["--fuse", "accel,accel"],
                 ["--fuse", "wind"], ["--fuse", "Accel"], ["--fuse", "accel", "--hold-out", ""],
                 ["--fuse", "accel", "--hold-out", "zz"], ["--fuse", "accel", "--hold-out", "acc-top", "--hold-out", "acc-mid"],
                 ["--fuse", "strain"], ["--hold-out", "acc-top"], ["--fuse", "accel", "--hold-out", "acc-top,acc-mid"]]
    for o in fuse_opts:
        out.append(Case("fuse_options", _short(["tower", *o]), _fusion_estimate(q, *o)))
    for o in (["--fuse", ""], ["--fuse", "gyro,gyro"], ["--fuse", "accel"], ["--fuse", "strain"],
              ["--fuse", "gyro", "--hold-out", "nope"], ["--fuse", "gyro", "--no-fix-biases"]):
        out.append(Case("fuse_options", _short(["testbed", *o]), [*tb, *o, "-o", "{O}.mcap"]))
    base = q["tower"].read_text()
    gauge = '\n[[strains]]\nname = "s1"\npoint_a = "base"\npoint_b = "mid"\nsigma_strain = 1.0e-6\n'
    twin = '\n[[points]]\nname = "mid2"\nposition_m = [0.0, 0.0, 100.0]\n'
    variants = [("clean", gauge), ("point_b not in the structure", gauge.replace('"mid"', '"roof"')),
                ("point_a = point_b", gauge.replace('"base"', '"mid"')),
                ("both ends at one place", gauge.replace('"base"', '"mid2"') + twin),
                ("sigma 0", gauge.replace("1.0e-6", "0.0")), ("sigma negative", gauge.replace("1.0e-6", "-1.0e-6")),
                ("sigma nan", gauge.replace("1.0e-6", "nan")), ("sigma a string", gauge.replace("1.0e-6", '"x"')),
                ("no name", gauge.replace('name = "s1"\n', "")), ("name empty", gauge.replace('"s1"', '""')),
                ("unknown key", gauge + "length_m = 3.0\n"), ("point an integer", gauge.replace('"mid"', "3")),
                ("bias sigma negative", gauge + "bias_sigma_strain = -1.0\n"),
                ("sample period inf", gauge + "sample_period_s = inf\n"), ("two gauges one name", gauge + gauge),
                ("a table, not an array", '\n[strains]\nname = "s1"\n'), ("an array of numbers", "\nstrains = [1, 2]\n"),
                ("name of an accelerometer", gauge.replace('"s1"', '"acc-top"'))]
    est = ["estimate", str(q["frun"]), "--init", str(q["finit"]), "--structure", "{M}", "--fuse", "strain", "-o", "{O}.mcap"]
    sim = ["simulate-gnss-structure", "{M}", "--duration", "2", "--gnss-interval", "0.5", "-o", "{O}"]
    for name, text in variants:
        for argv in (sim, est):
            out.append(Case("strain_toml", name, argv, (base + text).encode(), ".toml"))
    return out


def build_old_outputs(p: dict, work: Path) -> None:
    """Earlier outputs for the killed-over cases: another seed or another option than the case's."""
    old = work / "old"
    if (old / "done").exists():
        return
    old.mkdir(exist_ok=True)
    for argv in (["simulate", str(p["config"]), "--duration", "120", "--seed", "1", "-o", str(old / "sim-seed1")],
                 ["spectra", str(p["states"]), "--segment-s", "2", "-o", str(old / "spectra-seg1")],
                 ["simulate-gnss", "--duration", "900", "--seed", "1", "-o", str(old / "gsim-seed1")]):
        subprocess.run(CDGPS + ["-q", *argv], check=True, capture_output=True)
    (old / "done").write_text("")


def references(cases: list[Case], p: dict, work: Path) -> dict:
    """Clean runs: (result digest, output snapshot, case folder, input sha) per argv template of the
    detect families, the killed and the mutated-with-output cases; run time for the killed ones."""
    refs = {}
    todo = {}
    for c in cases:
        if c.detect or c.family == "killed":
            todo.setdefault(c.ref_key, c)
    for i, (key, c) in enumerate(todo.items()):
        d = work / "r" / f"{i:06d}"
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        m = d / f"input{c.suffix}"
        src = c.clean_source
        if src is not None:
            shutil.copy(src, m)
        argv = [a.replace("{M}", str(m)).replace("{O}", str(d / "out")) for a in c.argv]
        out = _output_of(argv)
        t0 = time.perf_counter()
        r = subprocess.run(CDGPS + argv, capture_output=True, cwd=d, preexec_fn=_limit_memory, timeout=600)
        refs[("time",) + key] = time.perf_counter() - t0
        if r.returncode != 0:
            continue
        in_sha = _sha(m) if m.exists() else ""
        shas = [h for h in (in_sha,) if h] + [_sha(q) for q in _paths_in(argv) if q != m]
        refs[key] = (_result_digest(out, r.stdout, d, shas), _snapshot(out), str(d), in_sha)
    return refs


def reader_flips(p: dict, work: Path, rng: random.Random, n: int) -> list[dict]:
    """``n`` single-byte flips of each of RUN, STATES and GNSS RUN read in-process by read_mcap:
    ``clean`` (refused), ``ok`` (the same contents) or ``ok`` + ``silent`` (different contents)."""
    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.io.mcap import read_mcap

    def contents(path):
        c = read_mcap(path)
        return pickle.dumps({k: v for k, v in vars(c).items() if k != "path"}, protocol=4)

    out = []
    m = work / "reader-flip.mcap"
    for key in ("run", "states", "grun"):
        raw = p[key].read_bytes()
        ref = contents(p[key])
        for name, data in sweep.flips(raw, n, rng):
            m.write_bytes(data)
            try:
                same = contents(m) == ref
                kind, flags, msg = "ok", ([] if same else ["silent"]), ""
            except CdgpsError as exc:
                kind, flags, msg = "clean", [], str(exc).splitlines()[0][:200]
            except Exception as exc:               # noqa: BLE001 — a reader traceback is a finding
                kind, flags, msg = "traceback", [], f"{type(exc).__name__}: {exc}"[:200]
            out.append({"family": f"read_mcap {p[key].name}", "name": name, "argv": "read_mcap", "kind": kind,
                        "flags": flags, "rc": 0, "elapsed_s": 0.0, "message": msg})
    return out


# ---- report -------------------------------------------------------------------------------------


def summarise(results: list[dict]) -> tuple[dict, list[dict]]:
    counts = defaultdict(Counter)
    for r in results:
        for key in (r["family"], "total"):
            counts[key]["cases"] += 1
            counts[key][r["kind"]] += 1
            for f in r["flags"]:
                counts[key][f] += 1
    findings = [r for r in results if r["kind"] in ("traceback", "timeout", "other") or r["flags"]]
    return counts, findings


def table(counts: dict) -> str:
    cols = ["cases", "ok", "clean", "traceback", "timeout", "other", "killed", *FLAGS]
    order = [f for f in counts if f != "total"] + ["total"]
    lines = ["| family | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
    for fam in order:
        lines.append(f"| {fam} | " + " | ".join(str(counts[fam][c]) for c in cols) + " |")
    return "\n".join(lines)


def write_markdown(path: Path, counts: dict, findings: list[dict], command: str, runtime_s: float,
                   section: str = "Fault campaign") -> None:
    """Replace (or append) the self-contained ``## <section>`` of ``path``."""
    lines = [f"## {section}", "",
             f"`{command}` — {runtime_s:.0f} s on this machine (2 cores shared with other jobs).", "",
             "Each case is one `cdgps` process (benchmarks/fault_campaign.py: outcomes and flags defined in its "
             "docstring). *silent*: a damaged MCAP or UBX input accepted with a different result and no warning; "
             "*destroyed*: an input's sha256 changed; *partial*: after an error or a kill, an output that is neither "
             "absent, the earlier one, nor a complete one; *temporaries*: hidden temporaries left beside the output "
             "(after a SIGKILL: still there once the same command has run again); *nondeterministic*: the same "
             "command run twice into the same path gave different bytes.",
             *(["", "*read_mcap* rows: single-byte flips read in-process by `read_mcap` (no subprocess); *silent*: "
                 "read without an error but with contents different from the clean file's."]
               if any(f.startswith("read_mcap") for f in counts) else []),
             "", table(counts), "",
             "The fast guard of the same properties is the hypothesis suite `tests/fuzz/` (part of `make test`, "
             "about 40 s; `CDGPS_FUZZ_EXAMPLES=300` for a longer local run): every reader and every command's "
             "numeric options give a result or a clean error naming the file/line/key/option, inputs unchanged, "
             "nothing left at an output path after an error.", ""]
    if findings:
        lines += ["Findings (first 40):", ""]
        for r in findings[:40]:
            lines.append(f"- {r['family']}: `{r['argv']} {r['name'][:80]}` → {r['kind']}"
                         f"{' [' + ', '.join(r['flags']) + ']' if r['flags'] else ''}: {r['message'][:160]}")
        lines.append("")
    body = "\n".join(lines)
    text = path.read_text() if path.exists() else "# Hardening\n\n"
    head = f"## {section}\n"
    start = 0 if text.startswith(head) else text.find("\n" + head) + 1
    if start > 0 or text.startswith(head):
        end = text.find("\n## ", start + 3)
        text = text[:start] + body + (text[end + 1:] if end >= 0 else "")
    else:
        text = text.rstrip("\n") + "\n\n" + body
    path.write_text(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workdir", default=None, help="Work directory (default: a temporary one, removed after).")
    ap.add_argument("--flips", type=int, default=12, help="Random byte flips per file and command [12].")
    ap.add_argument("--kills", type=int, default=4, help="Killed runs per command [4].")
    ap.add_argument("--sample", type=int, default=None,
                    help="Run a random sample of N mutation/option cases (default: all); the killed, overwrite and "
                         "control cases always run.")
    ap.add_argument("--seed", type=int, default=1, help="Seed of the mutations, kill times and the sample [1].")
    ap.add_argument("--jobs", type=int, default=1, help="Cases run at once [1].")
    ap.add_argument("--only", default=None, help="Comma-separated families (csv, ubx, killed, overwrite, ...).")
    ap.add_argument("--reader-flips", type=int, default=0,
                    help="Also N single-byte flips of each MCAP read in-process (silent acceptances) [0].")
    ap.add_argument("--section", default="Fault campaign", help="Section title in the --markdown file.")
    ap.add_argument("--json", default=None, help="Write every case's result as JSON to this file.")
    ap.add_argument("--markdown", default=None, help="Write the counts into this file's 'Fault campaign' section.")
    args = ap.parse_args(argv)
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="cdgps-campaign-"))
    t0 = time.perf_counter()
    try:
        p = sweep.build_base(work)
        rng = random.Random(args.seed)
        cases = mutated_cases(p, work, rng, args.flips) + overwrite_cases(p) + killed_cases(p, work, rng, args.kills)
        q = extend_base(p, work)
        cases += later_cases(q, rng, args.flips, args.kills)
        cases += fusion_cases(p, q, random.Random(args.seed + 1), args.flips)
        if args.only:
            keep = set(args.only.split(","))
            cases = [c for c in cases if c.family in keep]
        if args.sample is not None:             # killed, overwrite and control cases always run in full
            full = [c for c in cases if c.family in ("killed", "overwrite", "control", "determinism")]
            rest = [c for c in cases if c not in full]
            cases = full + random.Random(args.seed).sample(rest, min(args.sample, len(rest)))
        if any(c.family == "killed" for c in cases):
            build_old_outputs(p, work)
        refs = references(cases, p, work)
        print(f"{len(cases)} cases, {args.jobs} at once …", file=sys.stderr)
        with ThreadPoolExecutor(max(1, args.jobs)) as pool:
            results = list(pool.map(lambda ic: run_case(ic[1], work, ic[0], refs), enumerate(cases)))
        if args.reader_flips:
            results += reader_flips(p, work, random.Random(args.seed), args.reader_flips)
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)
    runtime = time.perf_counter() - t0
    counts, findings = summarise(results)
    print(table(counts))
    for r in findings:
        print(f"- {r['family']}: {r['argv']} {r['name'][:80]} -> {r['kind']} {r['flags']} rc {r['rc']}: {r['message'][:200]}")
    print(f"\n{runtime:.0f} s")
    command = shlex.join(["python", "benchmarks/fault_campaign.py", *(argv if argv is not None else sys.argv[1:])])
    if args.json:
        Path(args.json).write_text(json.dumps({"command": command, "runtime_s": runtime,
                                               "counts": {k: dict(v) for k, v in counts.items()},
                                               "results": results}, indent=1) + "\n")
    if args.markdown:
        write_markdown(Path(args.markdown), counts, findings, command.strip(), runtime, args.section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
