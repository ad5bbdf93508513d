#!/usr/bin/env python3
"""A GNSS pair at 10 Hz, whole record against window by window: peak RSS and wall time per stage (issue 29).

For each ``--hours`` H simulates a static pair at 10 Hz (``cdgps simulate-gnss --duration 3600·H --rate-hz 10
--slips 30 --seed 1``, cached in ``--workdir``/gnss10-<H>h) and runs, each a fresh ``cdgps`` process under
``/usr/bin/time`` (benchmarks/long_records.py ``_timed``)::

    ingest          cdgps ingest --config config.toml -o run.mcap
    info            cdgps info run.mcap --json                  (answered from the summary)
    init, estimate  cdgps init run.mcap -o init.json; cdgps estimate run.mcap --init init.json -o states.mcap
    window k        cdgps init run.mcap --start k·W --duration W -o init-k.json;
                    cdgps estimate run.mcap --init init-k.json -o states-k.mcap      (W = --window-s)
    joined          cdgps estimate run.mcap --init 'init-*.json' [--smooth] -o states-joined.mcap
                    (every window's INIT into one STATES, a window at a time; --smooth with a moving model)

``--model random_walk`` (or constant_velocity) ingests the pair with that displacement model (run-<model>.mcap,
its INITs init-<model>-k.json), so that the joined estimate filters and smooths over the windows; with
``--multipath-sigma-m S`` also multipath states (``multipath = "model"``, σ S, τ 30 s; files run-<model>-mp.mcap …).

and writes ``--out`` (JSON) with a markdown table: the whole record's init and estimate grow with it, a window's
stay what a record of its length costs::

    CDGPS_SERIAL=1 python benchmarks/gnss_windows.py --hours 1 3 6 --out docs/benchmarks/gnss_windows.json

(``CDGPS_SERIAL=1``: a pair's two receivers in one process, so that its peak RSS is all the stage's memory.)
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from long_records import _timed, machine, simulated_pair, write_json  # noqa: E402  (benchmarks/long_records.py)


def _say(hours: float, what: str, r: dict) -> None:
    print(f"  {hours:g} h {what:22s} {r['wall_s']:7.1f} s {r['peak_rss_mib']:8.1f} MiB (load {r['load_1min']:.1f})"
          + ("" if not r["exit"] else f"  EXIT {r['exit']}: {r.get('stderr', '')[-300:]}"), file=sys.stderr, flush=True)


def _hourly_files(d: Path) -> Path:
    """The pair of ``d`` as a receiver writes a day: one RINEX file per hour and antenna (``files/base_HH.rnx``, cut
    at the hours by :mod:`cdgps_cli.io.rinex_hours`), and a config naming them by glob; returns the config."""
    from cdgps_cli.io.rinex_hours import rinex_hours  # noqa: PLC0415

    f = d / "files"
    cfg = f / "config.toml"
    if not cfg.exists():
        f.mkdir(exist_ok=True)
        for n in ("base", "rover"):
            h = rinex_hours(d / f"{n}.rnx", 3600.0)
            for j in range(len(h.blocks)):
                (f / f"{n}_{j:02d}.rnx").write_bytes(h.block_bytes(j)[0])
            h.close()
        text = (d / "config.toml").read_text()
        cfg.write_text(text.replace('"base.rnx"', '"base_*.rnx"').replace('"rover.rnx"', '"rover_*.rnx"')
                       .replace('"nav.rnx"', '"../nav.rnx"'))
    return cfg


def _model_config(d: Path, model: str, multipath_sigma_m: float | None = None) -> str:
    """The pair's config with ``[gnss.displacement] model`` set (config.toml itself for the simulator's static), and
    with ``multipath_sigma_m`` multipath states of that σ and τ 30 s (``multipath = "model"``)."""
    if model == "static":
        return "config.toml"
    mp = "" if multipath_sigma_m is None else (f'\nmultipath = "model"\nmultipath_sigma_m = {multipath_sigma_m!r}'
                                               f'\nmultipath_time_constant_s = 30.0')
    cfg = d / f"config-{model}{'-mp' if mp else ''}.toml"
    cfg.write_text((d / "config.toml").read_text().replace('model = "static"', f'model = "{model}"{mp}'))
    return cfg.name


def pair(workdir: Path, hours: float, window_s: float, whole: bool, windows: bool = True,
         hourly_files: bool = False, model: str = "static", multipath_sigma_m: float | None = None) -> dict:
    d = simulated_pair(workdir / f"gnss10-{hours:g}h", hours, 10.0)
    tag = ("" if model == "static" else f"-{model}") + ("" if multipath_sigma_m is None else "-mp")
    run, smooth = f"run{tag}.mcap", ([] if model == "static" else ["--smooth"])
    rec: dict = {"hours": hours, "rate_hz": 10.0, "window_s": window_s, "model": model,
                 "multipath_sigma_m": multipath_sigma_m, "stages": {}, "windows": []}
    steps = [("ingest", ["ingest", "--config", _model_config(d, model, multipath_sigma_m), "-o", run]),
             ("info", ["info", "--json", run])]
    if whole:
        steps += [("init", ["init", run, "-o", f"init{tag}.json"]),
                  ("estimate", ["estimate", run, "--init", f"init{tag}.json", *smooth, "-o", f"states{tag}.mcap"])]
    if hourly_files:
        steps.append(("ingest, hourly files", ["ingest", "--config", str(_hourly_files(d)), "-o", "run-files.mcap"]))
    for name, args in steps:
        r = _timed(args, cwd=d)
        rec["stages"][name] = r
        _say(hours, name, r)
    n_win = int(round(3600 * hours / window_s)) if windows else 0
    for k in range(n_win):
        w = {"start_s": k * window_s}
        for name, args in (("init", ["init", run, "--start", str(k * window_s), "--duration", str(window_s),
                                     "-o", f"init{tag}-{k:03d}.json"]),
                           ("estimate", ["estimate", run, "--init", f"init{tag}-{k:03d}.json", *smooth,
                                         "-o", f"states{tag}-{k}.mcap"])):
            w[name] = _timed(args, cwd=d)
            _say(hours, f"window {k} {name}", w[name])
        rec["windows"].append(w)
    if n_win:
        r = _timed(["estimate", run, "--init", f"init{tag}-[0-9][0-9][0-9].json", *smooth, "-o",
                    f"states{tag}-joined.mcap"], cwd=d)
        rec["stages"]["estimate, joined windows"] = r
        _say(hours, "estimate, joined", r)
    rec["run_mcap_mib"] = round((d / f"run{tag}.mcap").stat().st_size / 2**20, 1)
    return rec


def table(records: list[dict]) -> str:
    lines = ["| record (10 Hz) | ingest | ingest, hourly files | info | init whole | estimate whole | "
             "init, a window (max) | estimate, a window (max) | estimate, every window's INIT joined |",
             "|---|---|---|---|---|---|---|---|---|"]

    def cell(r):
        return "—" if r is None else f"{r['peak_rss_mib']:.0f} MiB / {r['wall_s']:.1f} s"
    for rec in records:
        st, ws = rec["stages"], rec["windows"]
        worst = {s: max((w[s] for w in ws), key=lambda r: r["peak_rss_mib"]) if ws else None for s in ("init", "estimate")}
        lines.append(f"| {rec['hours']:g} h | {cell(st.get('ingest'))} | {cell(st.get('ingest, hourly files'))} | "
                     f"{cell(st.get('info'))} | "
                     f"{cell(st.get('init'))} | {cell(st.get('estimate'))} | {cell(worst['init'])} | "
                     f"{cell(worst['estimate'])} | {cell(st.get('estimate, joined windows'))} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0, 3.0])
    ap.add_argument("--window-s", type=float, default=3600.0)
    ap.add_argument("--no-whole", action="store_true", help="leave out the whole record's init and estimate")
    ap.add_argument("--hourly-files", action="store_true", help="also ingest the pair cut into one file per hour and "
                    "antenna")
    ap.add_argument("--no-windows", action="store_true", help="leave out the windows' init and estimate (ingest and "
                    "info only: docs/benchmarks/gnss_ingest.json)")
    ap.add_argument("--model", choices=("static", "random_walk", "constant_velocity"), default="static",
                    help="the pair's [gnss.displacement] model (a moving one: estimate --smooth)")
    ap.add_argument("--multipath-sigma-m", type=float, default=None,
                    help="with a moving model: multipath states of this σ (multipath = \"model\", τ 30 s)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/cdgps-gnss-windows"))
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    records = [pair(a.workdir, h, a.window_s, not a.no_whole, not a.no_windows, a.hourly_files, a.model,
                    a.multipath_sigma_m) for h in a.hours]
    mp = "" if a.multipath_sigma_m is None else f", multipath states σ {a.multipath_sigma_m:g} m, τ 30 s"
    result = {"pair": f"simulate-gnss --rate-hz 10 --slips 30 --seed 1 (GPS L1; displacement model {a.model}{mp})",
              "machine": machine(), "python": platform.python_version(),
              "records": records, "table": table(records),
              "note": "peak RSS: /usr/bin/time maximum resident set size of each cdgps process; load_1min: the "
                      "1-minute load average when the stage started (times depend on it, memory does not)"}
    write_json(a.out, result)
    print(table(records))


if __name__ == "__main__":
    main()
