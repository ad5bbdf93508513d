"""A window of a GNSS record gives the whole record's single-difference rows, bit for bit (issue 29: the ground of
`estimate` and `init` block by block).

The baseline solver's rows (``baseline._prepare``: epoch pairing, base bridging and interpolation, receiver clocks,
satellite geometry at reception, slips) of the epochs inside a window, built from a RUN read on that window widened by
``max_age_s + sync_tol_s`` on each side, are the rows the whole record gives at those epochs.  Before, they were not:
GLONASS orbits took the call's longest number of Runge–Kutta steps for every row, and a satellite's rows iterated
Kepler's equation and the light time in lockstep (1.6e-4 m of satellite position on a real CORS → u-blox pair with
GLONASS; the rows of each epoch now depend on their own data alone).

Independent of the code under test: the whole record, read and solved as `init` and `estimate` read it.
"""

from __future__ import annotations

import json
from dataclasses import fields

import numpy as np
import pytest

from cdgps_cli.estimation import baseline
from cdgps_cli.io.gnss_run import SOLVER_COLUMNS, read_gnss_run
from cdgps_cli.pipeline import gnss
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
ROW_FIELDS = ("y_phase_m", "y_code_m", "base_model_m", "rover_sat_xyz", "rover_clk_trop_m", "el_rover", "el_base",
              "az_rover", "slip", "half", "slip_rover", "slip_base", "age_var_m2")


def _rows(run, init: dict, rover: str):
    """The solver's rows of ``rover`` with INIT's options and positions (as `estimate` builds them)."""
    stations = gnss._stations(run)
    rov = init["rovers"][rover]
    names = {f.name for f in fields(baseline.BaselineOptions)}
    opt = baseline.BaselineOptions(**{k: v for k, v in rov["options"].items() if k in names})
    master, rx = stations[run.master], stations[rover]
    if rov.get("rover_troposphere_ecef_m") is not None:
        rx = rx._replace(troposphere_xyz_m=np.asarray(rov["rover_troposphere_ecef_m"], dtype=float))
    said: list = []
    xm, xr0, _ = baseline._a_priori_positions(master, rx, run.nav, gnss._position_args(run, run.master),
                                              np.asarray(rov["nominal_ecef_m"], dtype=float), said)
    opt, _ = baseline._with_age_noise(master, rx, run.nav, opt, xm)
    return baseline._prepare(master, rx, run.nav, opt, xm, xr0, said), opt


def _inside(d, t0: float, t1: float):
    """Rows of the epochs with t0 ≤ label < t1: (row indices, their labels, their satellite-signal names)."""
    t = d.t_label[d.epoch]
    i = np.flatnonzero((t >= t0) & (t < t1))
    return i, t[i], [d.sat_names[k] for k in d.sat[i]]


def _assert_window_rows(run_path, init: dict, rover: str, windows) -> int:
    whole = read_gnss_run(run_path, columns=SOLVER_COLUMNS)
    dw, opt = _rows(whole, init, rover)
    first = min(float(rx.raw["time_gps_s"].min()) for rx in whole.receivers.values())
    margin = opt.max_age_s + opt.sync_tol_s
    n_rows = 0
    for start_s, duration_s in windows:
        t0, t1 = first + start_s, first + start_s + duration_s
        dv, _ = _rows(read_gnss_run(run_path, columns=SOLVER_COLUMNS, window=(t0 - margin, t1 + margin)), init, rover)
        iw, tw, sw = _inside(dw, t0, t1)
        iv, tv, sv = _inside(dv, t0, t1)
        assert iw.size > 0 and tw.tobytes() == tv.tobytes() and sw == sv
        for f in ROW_FIELDS:
            a, b = getattr(dw, f), getattr(dv, f)
            if a is None:
                assert b is None, f
                continue
            assert a[iw].tobytes() == b[iv].tobytes(), f
        if dw.group is not None:
            assert [dw.group_names[g] for g in dw.group[iw]] == [dv.group_names[g] for g in dv.group[iv]]
            assert np.asarray(dw.lam_m)[iw].tobytes() == np.asarray(dv.lam_m)[iv].tobytes()
        n_rows += iw.size
    return n_rows


@pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")
def test_real_multi_gnss_pair_with_glonass(tmp_path):
    """The real Septentrio mosaic-X5 pair, GPS + GLONASS + Galileo + BeiDou on two frequencies: three windows,
    one at the record's start, one inside, one at its end."""
    cfg = tmp_path / "run.toml"
    cfg.write_text("\n".join(["[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]',
                              'signals = ["G:L1", "G:L2", "R:G1", "R:G2", "E:E1", "E:E5b", "C:B1I", "C:B2I"]',
                              '[gnss.antennas."base"]', f'rinex = "{MOSAIC / "base.obs"}"',
                              '[gnss.antennas."rover"]', f'rinex = "{MOSAIC / "rover.obs"}"']) + "\n")
    assert run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap").exit_code == 0
    r = run_cli("-q", "init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 0, r.output
    init = json.loads((tmp_path / "init.json").read_text())
    n = _assert_window_rows(tmp_path / "run.mcap", init, "rover", [(0.0, 60.0), (100.0, 77.0), (240.0, 61.0)])
    assert n > 3000


def test_simulated_pair_with_a_slow_base_slips_and_raw_tags(tmp_path):
    """A 2 Hz rover against a base at 0.2 Hz (every rover epoch between two base epochs is bridged and
    interpolated), random-walking, with slips and time tags offset by the receivers' clocks."""
    sim = tmp_path / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "600", "--rate-hz", "2", "--master-rate-hz", "0.2",
                   "--slips", "12", "--raw-tags", "--random-walk", "0.002", "--seed", "3", "-o", sim).exit_code == 0
    assert run_cli("-q", "ingest", "--config", sim / "config.toml", "-o", tmp_path / "run.mcap").exit_code == 0
    r = run_cli("-q", "init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 0, r.output
    init = json.loads((tmp_path / "init.json").read_text())
    n = _assert_window_rows(tmp_path / "run.mcap", init, "rover", [(0.0, 100.0), (203.5, 150.0), (480.0, 120.0)])
    assert n > 2000
