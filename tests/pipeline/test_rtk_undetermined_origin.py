"""``rtk`` moves the rover's a-priori position only to where its data place it (``gnss_multi._static_float_offset``,
``_determined``).

The real case: DELF → ZEGV, two Dutch reference stations 35 km apart (tests/data/georust-delf-zegv), with the
navigation file of a third station that covers only two of the satellites both see in the first nine minutes.  The
static float of one satellite pair over nine minutes lands 14.6 m from ZEGV's surveyed header position with a 3-D σ of
97 m; the origin used to be moved there (its troposphere and linearization with it), and every row then sat 14.6 m
off.  RTKLIB (``rnx2rtkp`` 2.4.3) writes no row at all on these files.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from _shared import run_cli

from cdgps_cli.pipeline.gnss_multi import ORIGIN_MOVE_SIGMAS, _determined, _undetermined_note

DATA = Path(__file__).resolve().parents[1] / "data" / "georust-delf-zegv"
#: ZEGV's APPROX POSITION XYZ (an adopted ETRS89 coordinate of a reference station), ECEF m
ZEGV_XYZ_M = np.array([3908910.3663, 330932.7742, 5012262.5786])


def test_an_offset_is_taken_only_beyond_three_sigma():
    assert ORIGIN_MOVE_SIGMAS == 3.0
    off = np.array([14.0, 3.0, 3.0])                      # 14.6 m
    assert not _determined(off, np.eye(3) * 97.4**2 / 3)   # the real case: σ 97 m
    assert _determined(off, np.eye(3) * 1.0 / 3)           # σ 1 m
    edge = np.linalg.norm(off) / 3.0                       # exactly 3σ: not beyond
    assert not _determined(off, np.eye(3) * edge**2 / 3)
    assert _determined(off, np.eye(3) * (0.99 * edge) ** 2 / 3)
    assert not _determined(off, np.full((3, 3), np.nan)) and not _determined(np.full(3, np.nan), np.eye(3))
    note = _undetermined_note("its static float solution", off, np.eye(3) * 97.4**2 / 3)
    assert note.startswith("undetermined: its static float solution is 14.6 m") and "σ of 97.4 m" in note


@pytest.fixture(scope="module")
def two_satellites(tmp_path_factory):
    out = tmp_path_factory.mktemp("delf_zegv") / "zegv.csv"
    r = run_cli("rtk", "--base", DATA / "delf0010.21d", "--rover", DATA / "zegv0010.21d",
                "--nav", DATA / "cbw10010.21n.gz", "-o", out)
    return r, out


def test_two_satellites_keep_the_surveyed_header_position(two_satellites):
    r, out = two_satellites
    assert r.exit_code == 0, r.output
    got = re.search(r"zegv0010\.21d \(rover\): its static float solution is ([\d.]+) m from its a-priori position with "
                    r"a 3-D σ of ([\d.]+) m .*: its a-priori position is kept", r.output)
    assert got and 14.0 < float(got[1]) < 15.0 and float(got[2]) > 3 * float(got[1]), r.output
    assert "moved there before solving" not in r.output
    df = pd.read_csv(out, comment="#")
    assert len(df) == 11 and not df["fixed"].any() and (df["n_satellites"] == 2).all()
    away = np.linalg.norm(df[["x_m", "y_m", "z_m"]].to_numpy() - ZEGV_XYZ_M, axis=1)
    assert away.max() < 1.0, away                    # before: every row 14.6 m away


def test_the_rows_say_that_they_place_nothing(two_satellites):
    """One satellite pair per epoch places no rover: each row's σ is tens to hundreds of metres, not a promise of
    metres (the rows are written, as every epoch with a DD is; RTKLIB writes none)."""
    df = pd.read_csv(two_satellites[1], comment="#")
    sigma = df[["sigma_e_m", "sigma_n_m", "sigma_u_m"]].to_numpy()
    assert (sigma.max(axis=1) > 50.0).all(), sigma


def test_the_ionosphere_threshold_is_an_rtk_option_as_init_s_config_key(tmp_path):
    """``--iono-threshold-km`` reaches the solver (init's ``[gnss] iono_threshold_km``; one default,
    MULTI_GNSS_DEFAULTS): the 35 km pair estimates the DD ionosphere by default and neglects it above the threshold;
    a negative threshold is refused by name."""
    from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS

    assert MULTI_GNSS_DEFAULTS["iono_threshold_km"] == 10.0
    args = ("rtk", "--base", DATA / "delf0010.21d", "--rover", DATA / "zegv0010.21d", "--nav", DATA / "cbw10010.21n.gz",
            "--json", "-q")
    models = {}
    for t in (None, 100.0):
        r = run_cli(*args, "-o", tmp_path / f"{t}.csv", *(() if t is None else ("--iono-threshold-km", t)))
        assert r.exit_code == 0, r.output
        models[t] = json.loads(r.output[r.output.index("{"):])["iono_model"]
    assert models == {None: "estimated", 100.0: "neglected (short baseline)"}
    bad = run_cli(*args, "-o", tmp_path / "bad.csv", "--iono-threshold-km", -1)
    assert bad.exit_code == 2 and "--iono-threshold-km -1: outside the plausible range [0, 1e+06] km" in bad.output
    assert not (tmp_path / "bad.csv").exists()


def test_a_pos_file_says_why_a_float_line_has_a_passing_ratio():
    """(The real 35 km pair with the IGS broadcast file, kept outside the repository: 19 float lines with partial-fix
    ratios of 19 to 12 555 and no word on them.)"""
    from cdgps_cli.pipeline.gnss_multi import _partial_ratio_note

    q, ratio = np.array([1, 2, 2, 2]), np.array([8.0, 2.9, 3.0, 12555.0])
    note, = _partial_ratio_note(q, ratio, {"ratio": 3.0})
    assert note.startswith("ratio     : on 2 float (Q=2) line(s) the ratio is 3 or more while the position stays float")
    assert _partial_ratio_note(q, ratio, {"ratio": 20000.0}) == []
    assert _partial_ratio_note(np.array([1, 2]), np.array([50.0, 0.0]), {"ratio": 3.0}) == []
