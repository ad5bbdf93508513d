"""The three golden command chains and the numbers the goldens keep from them.

Each chain runs the ``cdgps`` CLI in-process (Click's test runner) inside a working directory, with
relative output paths, so that two runs in two directories must write the same bytes.  Each returns a
:class:`Numbers`: named quantities with a unit and a tolerance, the machine-independent golden record
(tests/golden/data/<chain>.json, written by tests/golden/regenerate.py).

Tolerances (one per quantity, kept with it):

* ``EXACT`` — integers, flags, labels: integer ambiguities, ``fixed``, counts, solution kinds, event
  kinds.  Any change is a change of behaviour.
* ``FLOAT`` — every other floating-point quantity: relative 1e-9 element-wise, plus an absolute
  floor of 1e-9 × the quantity's largest magnitude (an element of a series that crosses zero is judged
  on the series' scale, not on its own).  This admits a reordering of sums or a different
  BLAS/compiler (round-off ~1e-16 grown through the filters) and nothing an intended change of
  arithmetic makes.  On another machine than the one that made the record (its fingerprint,
  ``_machine``, is stored; ``tests/_machine.py``) both are widened to ``CROSS_MACHINE_RTOL`` (1e-5):
  the real GEONET batch moved by 5.6e-6 relative (1.9e-8 m) between a Zen 1 and the AMD EPYC that made the first record.
* ``FLOAT_POSITION``, ``FLOAT_CYCLES``, ``FLOAT_RATIO`` — a GNSS float solution (position, float minus integer) and the ratio test made from it:
  ``FLOAT`` on the machine of the record, but across machines an absolute 1e-3 m / 1e-3 cycles and 1e-3
  relative for the ratio.  A float solution of a short record is ill-conditioned: the satellite positions of an
  AVX-512 and an AVX2 machine differ by 3 ULPs (1.2e-8 m; numpy's transcendental kernels are chosen by the CPU),
  and that moved GEONET's float baseline by 8.5e-7 m and its float minus integer by 1.8e-5 cycles (ratio 2.3e-5
  relative), the random-walk rover's float by 2.6e-5 m, against a σ of 4–50 mm (measured 2026-12-06: Intel
  AVX-512 against its own run with ``NPY_DISABLE_CPU_FEATURES`` and ``OPENBLAS_CORETYPE=Zen``, which reproduces
  the Zen 1 record bit for bit).  The fixed solutions, states and σ keep ``FLOAT``.
* ``PEAK`` — identified modes (spectral peak frequency, damping, MAC): relative 1e-6, because peak
  interpolation and damping fits amplify round-off (the numpy and compiled filter paths, equal to
  ~1e-13 in the states, move a peak by up to 9e-8); still far below any intended change (≥ 1e-4 here).
* ``TIME`` — epoch and event times, s: absolute 1 µs (GPS seconds are ~1e9, where 1e-9 relative
  would admit a whole second).

Chains (durations are shortened from scripts/demo.sh to keep tests/golden/ in seconds):

* ``demo`` — scripts/demo.sh parts 1–3: a 40 s free-vibration testbed simulation with a cycle slip
  and a transmitter outage → ingest → init on the first 15 s (8-start cold start, LAMBDA) →
  estimate --smooth → evaluate → spectra → report spectrum; the bundled
  static testbed run (first 120 s) → ingest → init → estimate --rest 80: --smooth → evaluate → report
  static; the 1995 two-DOF run → init on 2.4 s --no-process-noise → estimate --biases states → evaluate.
* ``gnss`` — GEONET 3040 → 0759 (real RINEX, ../shared/data) ingest → init → estimate and
  ``cdgps baseline``; a simulated random-walk rover with cycle slips → ingest → init → estimate --smooth
  → evaluate.
* ``gnss_structure`` — ``cdgps simulate-gnss-structure`` of configs/gnss-tower.toml (60 s) → ingest →
  init → estimate --structure --smooth (the modal state on satellite double differences) → evaluate.
"""

from __future__ import annotations

import contextlib
import json
import lzma
import os
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.states import States
from tests._machine import CROSS_MACHINE_RTOL, exact_here, machine

REPO_ROOT = Path(__file__).resolve().parents[2]
CONFIGS = REPO_ROOT / "configs"
DATA = REPO_ROOT / "data"
SHARED_RINEX = REPO_ROOT.parent / "shared" / "data" / "rinex"
GEONET_OBS = SHARED_RINEX / "30400920.05o"
GOLDEN_DIR = Path(__file__).resolve().parent / "data"
REPORT_DATE = "2026-01-01"            # fixed report date: the default is the inputs' modification time

EXACT = "exact"
FLOAT = {"rtol": 1e-9, "atol_of_max": 1e-9}
PEAK = {"rtol": 1e-6, "atol_of_max": 1e-6}
FLOAT_POSITION = {**FLOAT, "cross_machine": {"atol": 1e-3}}                 # m
FLOAT_CYCLES = {**FLOAT, "cross_machine": {"atol": 1e-3}}                   # cycles
FLOAT_RATIO = {**FLOAT, "cross_machine": {"rtol": 1e-3, "atol_of_max": 1e-3}}
TIME = {"rtol": 0.0, "atol": 1e-6}     # epoch times (GPS seconds ~1e9: relative 1e-9 would be a second)
N_SAMPLES = 16                        # epochs sampled from every state series (first and last included)


class Numbers:
    """Named golden quantities: value (scalar or nested list), unit, tolerance."""

    def __init__(self) -> None:
        self.items: dict[str, dict] = {}

    def exact(self, name: str, value, unit: str = "") -> None:
        """Record an integer / boolean / string quantity compared exactly."""
        self._add(name, _plain(value), unit, EXACT)

    def close(self, name: str, value, unit: str, tol: dict = FLOAT) -> None:
        """Record a floating-point quantity compared within ``tol``; NaN is stored as null."""
        arr = np.asarray(value, dtype=float)
        self._add(name, _plain(np.where(np.isfinite(arr), arr, np.nan)), unit, tol)

    def time(self, name: str, value) -> None:
        """Record epoch or event times, s, compared within ``TIME``."""
        self.close(name, value, "s", TIME)

    def _add(self, name, value, unit, tol) -> None:
        if name in self.items:
            raise ValueError(f"golden quantity {name!r} recorded twice")
        self.items[name] = {"value": value, "unit": unit, "tolerance": tol}

    def to_json(self, chain: str) -> str:
        return json.dumps({"chain": chain, "generated_by": "tests/golden/regenerate.py", "_machine": machine(),
                           "tolerances": {"exact": "equal", "float": FLOAT, "peak": PEAK, "time": TIME,
                                          "float_position": FLOAT_POSITION, "float_cycles": FLOAT_CYCLES,
                                          "float_ratio": FLOAT_RATIO},
                           "quantities": self.items}, indent=1, sort_keys=True, allow_nan=False) + "\n"


def _plain(v):
    """JSON-ready copy of v: numpy → Python, NaN → None."""
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        return _plain(v.item())
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


def cdgps(*args) -> str:
    """Run one cdgps command in-process; raise with its output unless it exits 0."""
    r = CliRunner().invoke(main, ["-q", *[str(a) for a in args]])
    if r.exit_code != 0:
        raise AssertionError(f"cdgps {' '.join(map(str, args))} exited {r.exit_code}:\n{r.output}\n{r.exception!r}")
    return r.output


def _nanmean(a: np.ndarray) -> float:
    """Mean of the finite entries of a, NaN when there are none (a run that is one INIT window)."""
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else float("nan")


def samples(n: int) -> np.ndarray:
    """Indices of N_SAMPLES epochs spread over a series of n epochs."""
    return np.unique(np.linspace(0, n - 1, min(n, N_SAMPLES)).round().astype(int))


def add_states(g: Numbers, prefix: str, path: str, topic: str | None = None) -> None:
    """A STATES.mcap series: sampled times, q, σ, NIS; whole-series mean/RMS; events."""
    st = States(path) if topic is None else States(path, topic=topic)
    k = samples(len(st.time_s))
    g.exact(f"{prefix}/epochs", len(st.time_s))
    g.exact(f"{prefix}/coordinates", list(st.coord_names))
    g.time(f"{prefix}/time_s", st.time_s[k])
    g.close(f"{prefix}/q", st.q[k], "coordinate units (m or rad)")
    g.close(f"{prefix}/sigma_q", st.sigma_q[k], "coordinate units (m or rad)")
    g.close(f"{prefix}/q_mean", np.nanmean(st.q, axis=0), "coordinate units")
    g.close(f"{prefix}/q_rms", np.sqrt(np.nanmean(st.q**2, axis=0)), "coordinate units")
    if topic is None and st.nis is not None:
        g.close(f"{prefix}/nis", st.nis[samples(len(st.nis))], "1 (χ²)")
        g.close(f"{prefix}/nis_mean", _nanmean(st.nis), "1 (χ²)")
        g.exact(f"{prefix}/nis_dof", st.nis_dof[samples(len(st.nis_dof))].astype(int).tolist())
        g.exact(f"{prefix}/event_kinds", [e["kind"] for e in st.events])
        g.time(f"{prefix}/event_time_s", [e["time_s"] for e in st.events])


def add_evaluation(g: Numbers, prefix: str, ev: dict) -> None:
    """`cdgps evaluate --json`: RMS errors, NEES, NIS, bias errors."""
    g.exact(f"{prefix}/epochs", ev["epochs"])
    g.close(f"{prefix}/rms_error", [ev["rms_error"][c] for c in sorted(ev["rms_error"])], "coordinate units")
    g.close(f"{prefix}/within_3sigma_fraction", ev["within_3sigma_fraction"], "1")
    g.close(f"{prefix}/nees_mean", ev["nees"]["mean"], "1 (χ²)")
    if "nis" in ev:
        g.close(f"{prefix}/nis_mean_per_dof", ev["nis"]["mean_per_dof"], "1")
    if "bias_error" in ev:
        g.exact(f"{prefix}/wrong_integers", ev["bias_error"].get("wrong_integers"))
        g.close(f"{prefix}/bias_rms_m", ev["bias_error"]["rms_m"], "m")


def add_structure_init(g: Numbers, prefix: str, init: dict) -> None:
    """A pseudolite INIT.json: state, σ, biases, integers, LAMBDA ratio, the cold starts."""
    b = init["biases"]
    g.exact(f"{prefix}/window_epochs", init["window"]["epochs"])
    g.close(f"{prefix}/window_s", [init["window"]["start_s"], init["window"]["end_s"]], "s")
    g.exact(f"{prefix}/iterations", init["iterations"])
    g.exact(f"{prefix}/n_fixed", init["n_fixed"])
    g.close(f"{prefix}/ratio", init["ratio"] if isinstance(init["ratio"], (int, float)) else np.nan, "1")
    g.close(f"{prefix}/cost", init["cost"], "1 (weighted SSR)")
    g.close(f"{prefix}/cost_per_dof", init["cost_per_dof"], "1")
    g.close(f"{prefix}/sigma_m", init["sigma_m"], "m")
    g.close(f"{prefix}/x", init["state"]["x"], "state units (modal m, m/s)")
    g.close(f"{prefix}/sigma_x", np.sqrt(np.diag(np.asarray(init["state"]["P"], dtype=float))), "state units")
    g.exact(f"{prefix}/bias_labels", [f"{e['antenna']}/{e['transmitter']}" for e in b])
    g.exact(f"{prefix}/integer_cycles", [e["integer_cycles"] for e in b])
    g.exact(f"{prefix}/fixed", [e["fixed"] for e in b])
    g.close(f"{prefix}/bias_m", [e["bias_m"] for e in b], "m")
    g.close(f"{prefix}/float_bias_m", [e["float_bias_m"] for e in b], "m")
    g.close(f"{prefix}/float_sigma_m", [e["float_sigma_m"] for e in b], "m")
    starts = init.get("starts") or []
    g.exact(f"{prefix}/start_won", [s["won"] for s in starts])
    g.close(f"{prefix}/start_cost", [s["cost"] for s in starts], "1 (weighted SSR)")


def _rover(init: dict, name: str) -> dict:
    """A GNSS INIT's rover entry with its ambiguity segments (from ``biases`` since they are the one record)."""
    from cdgps_cli.pipeline.gnss import rover_segments

    return dict(init["rovers"][name], ambiguities=rover_segments(init, name))


def add_gnss_rover(g: Numbers, prefix: str, rov: dict) -> None:
    """One rover of a GNSS INIT.json (or a baseline JSON's fields): states, σ, float, integers, ratio."""
    if isinstance(rov["ambiguities"], dict):          # baseline JSON: segments and ratio under "ambiguities"
        amb, ratio = rov["ambiguities"]["segments"], rov["ambiguities"]["ratio"]
    else:                                              # GNSS INIT.json rover
        amb, ratio = rov["ambiguities"], rov["ratio"]
    g.exact(f"{prefix}/solution", rov["solution"])
    g.close(f"{prefix}/states_m", [rov["states"][k] for k in sorted(rov["states"])], "m")
    if "sigma" in rov:
        g.close(f"{prefix}/sigma_m", [rov["sigma"][k] for k in sorted(rov["sigma"])], "m")
    g.close(f"{prefix}/float_enu_m", rov["float"]["enu_m"], "m", FLOAT_POSITION)
    g.close(f"{prefix}/float_sigma_enu_m", rov["float"]["sigma_enu_m"], "m")
    g.close(f"{prefix}/fixed_sigma_enu_m", rov["fixed"]["sigma_enu_m"], "m")
    g.close(f"{prefix}/unit_variance", [rov["float"]["unit_variance"], rov["fixed"]["unit_variance"]], "1")
    g.exact(f"{prefix}/segments", [f"{s['sat']} {s['first']}–{s['last']}" for s in amb])
    g.exact(f"{prefix}/pivot", [s["pivot"] for s in amb])
    g.exact(f"{prefix}/integer", [s.get("integer") for s in amb])
    g.exact(f"{prefix}/fixed", [s["fixed"] for s in amb])
    g.close(f"{prefix}/float_minus_integer_cycles",
            [np.nan if s["float_cycles"] is None else s["float_cycles"] - s["integer"] for s in amb], "cycles",
            FLOAT_CYCLES)
    g.close(f"{prefix}/sigma_cycles", [s["sigma_cycles"] for s in amb], "cycles")
    g.close(f"{prefix}/ratio", ratio, "1", FLOAT_RATIO)
    res = rov["residuals"]
    g.close(f"{prefix}/dd_phase_rms_m", res["dd_phase_rms_m"], "m")
    g.exact(f"{prefix}/n_dd_phase", res["n_dd_phase"])


@contextlib.contextmanager
def _cwd(path: Path):
    path.mkdir(parents=True, exist_ok=True)
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def _head_csv_xz(src: Path, dst: Path, end_s: float) -> None:
    """The rows of a bundled .csv.xz log with time_s ≤ end_s, written as plain CSV."""
    with lzma.open(src, "rt") as f:
        lines = f.read().splitlines(keepends=True)
    keep = [lines[0]] + [ln for ln in lines[1:] if float(ln.split(",", 1)[0]) <= end_s + 1e-9]
    dst.write_text("".join(keep))


# ----------------------------------------------------------------------------------------------
# the chains


def run_demo(work: Path, reports: bool = True) -> Numbers:
    """scripts/demo.sh parts 1–3, shortened; outputs under ``work`` (see the module docstring)."""
    g = Numbers()
    tb = CONFIGS / "testbed-1998-lumped.toml"
    with _cwd(work):
        # a cycle slip and a transmitter outage after the INIT window: the filter's lock restart and re-bias
        cdgps("simulate", tb, "--duration", 40, "--seed", 7, "--scenario", "free", "--noise-m", 0.02,
              "--disturbance-scale", 1, "--slip", "a2:PL3:25:7", "--outage", "PL5:30:3", "-o", "free/sim")
        cdgps("ingest", "free/sim/receiver.csv", "free/sim/gyro.csv", "--config", tb, "-o", "free/run.mcap")
        cdgps("init", "free/run.mcap", "--duration", 15, "-o", "free/init.json")
        cdgps("estimate", "free/run.mcap", "--init", "free/init.json", "--smooth", "-o", "free/states.mcap")
        ev = json.loads(cdgps("evaluate", "--truth", "free/sim", "--estimate", "free/states.mcap", "--json"))
        peaks = json.loads(cdgps("spectra", "free/states.mcap", "--gyro", "free/run.mcap", "-o", "free/spectra",
                                 "--json"))
        add_structure_init(g, "free/init", json.loads(Path("free/init.json").read_text()))
        add_states(g, "free/smoothed", "free/states.mcap")
        add_states(g, "free/filtered", "free/states.mcap", topic="/cdgps/state_filtered")
        add_evaluation(g, "free/evaluate", ev)
        modes = peaks["modes"]
        g.exact("free/spectra/mode_names", [m["mode"] for m in modes])
        g.exact("free/spectra/seen", [m["seen"] for m in modes])
        g.close("free/spectra/gps_hz", [m["gps_hz"] for m in modes], "Hz", PEAK)
        g.close("free/spectra/fdd_peak_hz", [m["fdd_peak_hz"] for m in modes], "Hz", PEAK)
        g.close("free/spectra/damping", [m["damping"] for m in modes], "1", PEAK)
        g.close("free/spectra/mac", [m["mac"] for m in modes], "1", PEAK)
        if reports:
            rep = json.loads(cdgps("report", "spectrum", "free/states.mcap", "--gyro", "free/run.mcap",
                                   "--date", REPORT_DATE, "-o", "free/report", "--json"))
            g.exact("free/report/seen", rep["seen"])
            g.close("free/report/gps_hz", [m["gps_hz"] for m in rep["modes"]], "Hz", PEAK)

        # the bundled static sensor test, first 120 s (motion, then rest from about 80 s)
        Path("static/truth").mkdir(parents=True, exist_ok=True)
        for name in ("receiver", "gyro"):
            _head_csv_xz(DATA / "testbed-static" / f"{name}.csv.xz", Path(f"static/{name}.csv"), 120.0)
        _head_csv_xz(DATA / "testbed-static" / "truth.csv.xz", Path("static/truth/truth.csv"), 120.0)
        Path("static/truth/truth.json").write_bytes((DATA / "testbed-static" / "truth.json").read_bytes())
        cdgps("ingest", "static/receiver.csv", "static/gyro.csv", "--config", tb, "-o", "static/run.mcap")
        cdgps("init", "static/run.mcap", "-o", "static/init.json")
        cdgps("estimate", "static/run.mcap", "--init", "static/init.json", "--rest", "80:", "--smooth",
              "-o", "static/states.mcap")
        ev = json.loads(cdgps("evaluate", "--truth", "static/truth", "--estimate", "static/states.mcap", "--json"))
        add_structure_init(g, "static/init", json.loads(Path("static/init.json").read_text()))
        add_states(g, "static/smoothed", "static/states.mcap")
        add_evaluation(g, "static/evaluate", ev)
        if reports:
            rep = json.loads(cdgps("report", "static", "static/states.mcap", "--gyro", "static/run.mcap",
                                   "--angle", "q6+q10", "--survey-deg", -1.4, "--date", REPORT_DATE,
                                   "-o", "static/report", "--json"))
            g.close("static/report/segment_s", [rep["start_s"], rep["end_s"]], "s")
            g.exact("static/report/samples", rep["samples"])
            g.close("static/report/angle_deg", [rep["mean_deg"], rep["noise_rms_deg"], rep["estimated_sigma_deg"]],
                    "deg (mean, noise RMS, estimated σ)")
            g.close("static/report/drift_deg_per_min", [rep["drift_deg_per_min"], rep["gyro_drift_deg_per_min"]],
                    "deg/min (GPS, gyro)")
            g.close("static/report/static_mode_active_fraction", rep["static_mode"]["active_fraction"], "1")

        # the 1995 two-degree-of-freedom model: biases as states
        d2 = CONFIGS / "teague-1995-2dof.toml"
        cdgps("ingest", DATA / "teague-1995" / "receiver.csv.xz", "--config", d2, "-o", "dof2/run.mcap")
        cdgps("init", "dof2/run.mcap", "--start", 0, "--duration", 2.4, "--no-process-noise", "-o", "dof2/init.json")
        cdgps("estimate", "dof2/run.mcap", "--init", "dof2/init.json", "--biases", "states", "-o", "dof2/states.mcap")
        ev = json.loads(cdgps("evaluate", "--truth", DATA / "teague-1995", "--estimate", "dof2/states.mcap", "--json"))
        add_structure_init(g, "dof2/init", json.loads(Path("dof2/init.json").read_text()))
        add_states(g, "dof2/states", "dof2/states.mcap")
        add_evaluation(g, "dof2/evaluate", ev)
    return g


def _gnss_ingest_init_estimate(d: str, config, *estimate_args) -> dict:
    """`cdgps ingest --config` → init → estimate [estimate_args] into directory d; the INIT dict."""
    cdgps("ingest", "--config", config, "-o", f"{d}/run.mcap")
    cdgps("init", f"{d}/run.mcap", "-o", f"{d}/init.json")
    cdgps("estimate", f"{d}/run.mcap", "--init", f"{d}/init.json", *estimate_args, "-o", f"{d}/states.mcap")
    return json.loads(Path(f"{d}/init.json").read_text())


def run_gnss(work: Path) -> Numbers:
    """GEONET 3040 → 0759 (init/estimate/baseline) and a simulated random-walk rover with slips."""
    g = Numbers()
    geonet = CONFIGS / "geonet-0759-3040.toml"
    with _cwd(work):
        init = _gnss_ingest_init_estimate("geonet", geonet)
        cdgps("baseline", "--config", geonet, "-o", "geonet/baseline.json")
        add_gnss_rover(g, "geonet/init/0759", _rover(init, "0759"))
        add_states(g, "geonet/states", "geonet/states.mcap")
        add_states(g, "geonet/kinematic", "geonet/states.mcap", topic="/cdgps/kinematic")
        bl = json.loads(Path("geonet/baseline.json").read_text())
        add_gnss_rover(g, "geonet/baseline", bl)
        kin = bl["kinematic"]["pdop_le_max"]
        g.exact("geonet/baseline/kinematic_epochs", kin["n_epochs"])
        g.close("geonet/baseline/kinematic_rms_m", [kin["rms_about_static_m"][c] for c in "enu"], "m")

        cdgps("simulate-gnss", "--duration", 240, "--seed", 5, "--random-walk", 0.001, "--slips", 2, "-o", "rw")
        init = _gnss_ingest_init_estimate("rw", "rw/config.toml", "--smooth")
        ev = json.loads(cdgps("evaluate", "--truth", "rw", "--estimate", "rw/states.mcap", "--json"))
        add_gnss_rover(g, "rw/init/rover", _rover(init, "rover"))
        add_states(g, "rw/smoothed", "rw/states.mcap")
        add_states(g, "rw/filtered", "rw/states.mcap", topic="/cdgps/state_filtered")
        add_evaluation(g, "rw/evaluate", ev)
    return g


def run_gnss_structure(work: Path) -> Numbers:
    """simulate-gnss-structure (gnss-tower, 60 s) → ingest → init → estimate --structure --smooth."""
    g = Numbers()
    tower = CONFIGS / "gnss-tower.toml"
    with _cwd(work):
        cdgps("simulate-gnss-structure", tower, "--duration", 60, "--seed", 3, "-o", "tw")
        init = _gnss_ingest_init_estimate("tw", "tw/config.toml", "--structure", tower, "--smooth")
        ev = json.loads(cdgps("evaluate", "--truth", "tw", "--estimate", "tw/states.mcap", "--json",
                              "--converge-s", 10))
        for name in sorted(init["rovers"]):
            add_gnss_rover(g, f"tw/init/{name}", _rover(init, name))
        add_states(g, "tw/smoothed", "tw/states.mcap")
        add_states(g, "tw/filtered", "tw/states.mcap", topic="/cdgps/state_filtered")
        add_evaluation(g, "tw/evaluate", ev)
    return g


CHAINS = {"demo": run_demo, "gnss": run_gnss, "gnss_structure": run_gnss_structure}


def golden_path(chain: str) -> Path:
    return GOLDEN_DIR / f"{chain}.json"


def _widened(tol: dict) -> dict:
    """A float tolerance for numbers recorded on another machine: :data:`CROSS_MACHINE_RTOL`, or the quantity's own
    ``cross_machine`` tolerance where it has one (a GNSS float solution: ill-conditioned numbers)."""
    plain = {k: (max(v, CROSS_MACHINE_RTOL) if k in ("rtol", "atol_of_max") and v else v)
             for k, v in tol.items() if k != "cross_machine"}
    return {**plain, **tol.get("cross_machine", {})}


def compare(chain: str, got: Numbers, same_machine: bool | None = None) -> list[str]:
    """Differences between a fresh run and the stored golden, one message per failing quantity.
    ``same_machine`` (default: the stored fingerprint is this machine's) keeps the stored tolerances;
    otherwise the relative ones are widened to :data:`CROSS_MACHINE_RTOL`."""
    record = json.loads(golden_path(chain).read_text())
    stored = record["quantities"]
    if same_machine is None:
        same_machine = exact_here(record.get("_machine"))
    fails = []
    missing, extra = sorted(set(stored) - set(got.items)), sorted(set(got.items) - set(stored))
    if missing or extra:
        fails.append(f"quantities changed: missing {missing}, new {extra} (regenerate only if intended)")
    for name in sorted(set(stored) & set(got.items)):
        ref, new = stored[name], got.items[name]
        if (ref["unit"], ref["tolerance"]) != (new["unit"], new["tolerance"]):
            fails.append(f"{name}: unit/tolerance changed from {ref['unit']!r}/{ref['tolerance']} "
                         f"to {new['unit']!r}/{new['tolerance']}")
            continue
        try:
            if new["tolerance"] == EXACT:
                assert new["value"] == ref["value"], f"expected {ref['value']!r}\n got {new['value']!r}"
            else:
                want = np.asarray(ref["value"], dtype=float)
                have = np.asarray(new["value"], dtype=float)
                scale = float(np.nanmax(np.abs(want))) if np.isfinite(want).any() else 0.0
                tol = new["tolerance"] if same_machine else _widened(new["tolerance"])
                atol = tol["atol"] if "atol" in tol else tol["atol_of_max"] * scale
                np.testing.assert_allclose(have, want, rtol=tol["rtol"], atol=atol,
                                           err_msg=f"{name} [{ref['unit']}]")
        except AssertionError as exc:
            fails.append(f"{name}: {exc}")
    return fails


def output_files(work: Path) -> dict[str, bytes]:
    """Every file a chain wrote under ``work``, by relative path."""
    return {p.relative_to(work).as_posix(): p.read_bytes() for p in sorted(work.rglob("*")) if p.is_file()}
