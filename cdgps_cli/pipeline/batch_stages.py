"""The stage functions `cdgps batch` runs: each calls the library exactly as its command does
(`cdgps ingest`, `init`, `estimate [--smooth]`, `spectra`, `report spectrum`), so that a batch writes
the same bytes as the single commands of :func:`cdgps_cli.pipeline.batch.stage_argv`, and returns
the few numbers the campaign summary needs.

Structure sessions (receiver/gyro CSV logs) run every stage; GNSS sessions (RINEX/UBX receivers listed
in a GNSS run config, `cdgps ingest --config GNSS.toml`) run ingest, init and estimate [--smooth].
"""

from __future__ import annotations

import json
from pathlib import Path

from cdgps_cli.config.options import ESTIMATE_DEFAULTS


def run_stage(s, stage: str) -> dict:
    """Run ``stage`` of session ``s`` (a :class:`cdgps_cli.pipeline.batch.Session`); returns its summary."""
    return _STAGES[stage](s)


def _ingest(s) -> dict:
    if s.kind == "gnss":
        return _ingest_gnss(s)
    from cdgps_cli.config.structure import load_config
    from cdgps_cli.pipeline.ingest import ingest_structure

    cfg = load_config(s.inputs["config"])
    r = ingest_structure(cfg, s.inputs["receiver_csv"], s.path("ingest"), s.inputs.get("gyro_csv"), s.inputs.get("actuator_csv"))
    return {"epochs": r["phase_messages"], "start_s": r["start_s"], "end_s": r["end_s"], "channels": r["channels"],
            "gaps": len(r["gaps"]), "lock_restarts": r["lock_restarts"]}


def _ingest_gnss(s) -> dict:
    from cdgps_cli.config.structure import load_gnss_config
    from cdgps_cli.pipeline.gnss_ingest import ingest_gnss

    cfg = load_gnss_config(s.inputs["gnss_config"])
    r = ingest_gnss(cfg, s.path("ingest"), rinex=None, ubx=None, nav_paths=None, master=None, progress=None,
                    strict=False)
    lost = {n: g["problems"] for n, g in r["integrity"].items() if g["problems"]}
    return {"receivers": len(r["receivers"]), "ephemerides": r["ephemerides"],
            "warnings": list(r["warnings"]) + [f"{n}: corrupt UBX data skipped: {', '.join(p)}" for n, p in lost.items()]}


def _run_kind(path: str) -> str:
    from cdgps_cli.io.file_checks import RUNS, require_kind
    from cdgps_cli.io.run import run_kind

    require_kind(path, RUNS, "RUN_MCAP")
    return run_kind(path) or "structure"


def _init_gnss(s, run_mcap: str) -> dict:
    from cdgps_cli.io.atomic import write_bytes_atomic
    from cdgps_cli.io.atomic import file_sha256
    from cdgps_cli.pipeline.gnss import gnss_init
    from cdgps_cli.io.gnss_run import read_gnss_run

    o = s.options
    window_s = None if o["init_start_s"] is None and o["init_duration_s"] is None else \
        (o["init_start_s"] or 0.0, o["init_duration_s"])
    run = read_gnss_run(run_mcap, window_s=window_s)
    res = gnss_init(run, options={"fix": False} if o["float_only"] else {}, progress=None)
    res["run_sha256"] = file_sha256(run_mcap)
    write_bytes_atomic(s.path("init"), (json.dumps(res, indent=2) + "\n").encode())     # as `cdgps init`
    rov = res["rovers"].values()
    return {"integers_fixed": sum(v["n_fixed"] for v in rov), "integers": sum(v["n_estimated"] for v in rov),
            "ratio": {r: v["ratio"] for r, v in res["rovers"].items()}}


def _estimate_gnss(s, run_mcap: str, init_json: str, init: dict, init_text: str) -> dict:
    from cdgps_cli.pipeline.gnss import gnss_estimate, init_window
    from cdgps_cli.io.gnss_run import read_gnss_run

    run = read_gnss_run(run_mcap, window=init_window(init))
    w = gnss_estimate(run, init, init_text, s.path("estimate"), smooth=s.options["smooth"], progress=None,
                      extra_options=None)
    return {"events": w["events"], "nis_per_dof": w.get("mean_nis_per_dof"),
            "rovers": {r: {"solution": v["solution"], "static_enu_m": v["static_enu_m"],
                           "static_sigma_m": v["static_sigma_m"], "kinematic_rms_m": v["kinematic_rms_m"],
                           "nominal_ecef_m": (init.get("rovers", {}).get(r) or {}).get("nominal_ecef_m")}
                       for r, v in w["rovers"].items()}}


def _init(s) -> dict:
    from cdgps_cli.io.atomic import file_sha256, write_bytes_atomic
    from cdgps_cli.estimation.initializer import InitOptions, initialize
    from cdgps_cli.io.run import read_run

    run_mcap, o = s.path("ingest"), s.options
    if _run_kind(run_mcap) == "gnss":
        return _init_gnss(s, run_mcap)
    run = read_run(run_mcap)
    opt = InitOptions(start_s=o["init_start_s"], duration_s=o["init_duration_s"], process_noise=True,
                      fix_integers=not o["float_only"], ratio_threshold=o["ratio"], partial=True, starts=8,
                      max_iterations=30, sigma_m=o["init_sigma_m"], multipath_sigma_m=None,
                      multipath_time_constant_s=None, progress=None)
    res = initialize(run, opt)
    res["run_sha256"] = file_sha256(run_mcap)
    res.pop("elapsed_s", None)                      # as `cdgps init`: INIT.json byte-identical across runs
    write_bytes_atomic(s.path("init"), (json.dumps(res, indent=2) + "\n").encode())
    ratio = res["ratio"]
    return {"integers_fixed": res["n_fixed"], "integers": len(res["biases"]),
            "ratio": ratio if ratio is None or isinstance(ratio, str) else float(ratio),
            "init_cost_per_dof": res["cost_per_dof"], "init_sigma_m": res["sigma_m"],
            "warnings": list(res["noise"].get("warnings", []))}


def _estimate(s) -> dict:
    from cdgps_cli.estimation.filter import EstimateOptions, estimate
    from cdgps_cli.io.file_checks import check_init_run, read_init_json
    from cdgps_cli.io.run import read_run
    from cdgps_cli.pipeline.estimate_outputs import write_states

    run_mcap, init_json, o = s.path("ingest"), s.path("init"), s.options
    gnss = _run_kind(run_mcap) == "gnss"
    init, init_text = read_init_json(init_json)
    check_init_run(init, init_json, run_mcap, False)
    if gnss:
        return _estimate_gnss(s, run_mcap, init_json, init, init_text)
    run = read_run(run_mcap)
    defaults = {k: v for k, v in ESTIMATE_DEFAULTS.items() if k != "process_noise_scale"}   # cdgps estimate's
    opt = EstimateOptions(biases=o["biases"], smooth=o["smooth"], sigma_m=None,
                          process_noise_scale=o["process_noise_scale"], rest_segments_s=(), rest_auto=False,
                          keep_filtered_covariance="modal", init_source=str(init_json), progress=None, **defaults)
    res = estimate(run, init, opt)
    del run
    w = write_states(res, run_mcap, init, init_text, s.path("estimate"), opt.echo())
    nz = res.noise or {}
    return {"nis_per_dof": w["mean_nis_per_dof"], "events": w["events"],
            "noise_sigma_m": nz.get("sigma_m"), "innovation_sigma_m": nz.get("innovation_sigma_m")}


def _states_and_gyro(s):
    from cdgps_cli.io.file_checks import STATES, STRUCTURE_RUN, require_kind
    from cdgps_cli.io.run import read_run
    from cdgps_cli.io.states import StatesChunks

    require_kind(s.path("estimate"), STATES, "STATES_MCAP")
    require_kind(s.path("ingest"), STRUCTURE_RUN, "--gyro")
    # read in chunks as `cdgps spectra` / `report spectrum` do, so the batch writes their bytes
    return StatesChunks(s.path("estimate")), read_run(s.path("ingest"), phase=False)


def _spectra_options(s):
    from cdgps_cli.analysis.spectra import SpectraOptions

    c = s.options["coords"]
    return SpectraOptions(coords=tuple(x.strip() for x in c.split(",") if x.strip()) if c else None,
                          segment_s=s.options["segment_s"], overlap=0.5, pad=4)


_MODE_KEYS = ("mode", "model_hz", "gps_hz", "gps_hz_sigma", "damping", "damping_sigma", "seen")


def _modes(modes: list) -> dict:
    return {"modes": [{k: m.get(k) for k in _MODE_KEYS} for m in modes]}


def _spectra(s) -> dict:
    from cdgps_cli.report.sensor_reports import run_spectra

    st, run = _states_and_gyro(s)
    return _modes(run_spectra(st, run, _spectra_options(s), s.path("spectra"))["modes"])


def _report(s) -> dict:
    from cdgps_cli.report.sensor_reports import spectrum_report

    st, run = _states_and_gyro(s)
    d = spectrum_report(st, run, _spectra_options(s), s.path("report"), date=s.options["date"])
    return {**_modes(d["modes"]), "report": str(Path(s.path("report")) / "report.html")}


_STAGES = {"ingest": _ingest, "init": _init, "estimate": _estimate, "spectra": _spectra, "report": _report}
