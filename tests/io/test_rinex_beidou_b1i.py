"""BeiDou B1I in RINEX 3.02 files: band 1 there (``C1I L1I``), band 2 from 3.03 on (band 1 became B1C).

A Trimble NetR9's RINEX 3.02 base (tests/data/matrtklib-2018-static, MIT) lists ``C1I L1I S1I``; before, its B1I was
never read: `--signals auto` left it out and `--signals C:B1I` was refused as absent.  On that pair GPS L1 alone fixes
none of the first 60 epochs; with B1I every one, at the repository's mean rover position.
"""

import json

import numpy as np
import pytest

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S
from cdgps_cli.io.rinex import _beidou_b1i_types
from cdgps_cli.io.rinex_signals import read_rinex_signals
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "tests" / "data" / "matrtklib-2018-static"
BASE_XYZ = (-3937776.1063, 3354867.8075, 3718445.0835)        # the repository's base_position.txt
ROVER_LLH = (35.89114782, 139.57004698, 46.0975)             # its rover_mean_position.txt (deg, deg, m)


def test_band_1_types_of_a_3_02_file_are_b1i():
    info = {}
    assert _beidou_b1i_types(["C1I", "L1I", "S1I", "C7I", "L7I"], 3.02, info) == ["C2I", "L2I", "S2I", "C7I", "L7I"]
    assert info["beidou_b1i_band1"] == {"C1I": "C2I", "L1I": "L2I", "S1I": "S2I"}
    assert _beidou_b1i_types(["C1X", "L1X"], 3.02, {}) == ["C2X", "L2X"]       # 3.02: X is B1 I+Q
    info = {}
    assert _beidou_b1i_types(["C1X", "L1X", "C2I", "L2I"], 3.04, info) == ["C1X", "L1X", "C2I", "L2I"]  # 3.04: B1C
    assert "beidou_b1i_band1" not in info
    assert _beidou_b1i_types(["C1I", "L1I"], 3.04, {}) == ["C2I", "L2I"]       # I and Q are B1I in any version
    assert _beidou_b1i_types(["L1I", "L2I"], 3.02, {}) == ["L1I", "L2I"]       # both named: nothing renamed


def _first_epoch_phase(path, sat: str, type_name: str) -> float:
    """The ``type_name`` value of ``sat`` in the file's first epoch, cut from its columns by hand."""
    import gzip

    lines = gzip.open(path, "rt").read().splitlines()
    types = next(ln[7:60].split() for ln in lines if ln.startswith("C") and "SYS / # / OBS TYPES" in ln)
    start = next(i for i, ln in enumerate(lines) if ln.startswith(">"))
    rec = next(ln for ln in lines[start + 1:] if ln.startswith(sat))
    k = types.index(type_name)
    return float(rec[3 + 16 * k:3 + 16 * k + 14])


def test_the_3_02_base_gives_its_l1i_column_as_b1i():
    head, df = read_rinex_signals(DATA / "base_60s.obs.gz", ["C:B1I"])
    first = df[df["time_gps_s"] == df["time_gps_s"].min()]
    row = first[first["sat"] == "C01"].iloc[0]
    assert row["phase_cycles"] == _first_epoch_phase(DATA / "base_60s.obs.gz", "C01", "L1I")
    assert row["wavelength_m"] == pytest.approx(SPEED_OF_LIGHT_M_S / 1561.098e6, rel=1e-12)
    assert head["beidou_b1i_band1"]["L1I"] == "L2I"
    assert df["sat"].nunique() >= 6 and (df["signal"] == "C:B1I").all()


def test_b1i_fixes_the_pair_gps_l1_alone_cannot(tmp_path):
    got = {}
    for signals in ("G:L1", "G:L1,C:B1I"):
        out = tmp_path / f"{signals.replace(':', '').replace(',', '_')}.csv"
        r = run_cli("rtk", "--base", DATA / "base_60s.obs.gz", "--rover", DATA / "rover_60s.obs.gz",
                    "--nav", DATA / "base.nav.gz", "--base-xyz", *BASE_XYZ, "--signals", signals, "-o", out, "--json")
        assert r.exit_code == 0, r.output
        got[signals] = json.loads(r.stdout), out
    assert got["G:L1"][0]["fixed_epochs"] == 0
    s, out = got["G:L1,C:B1I"]
    assert s["fixed_epochs"] == s["epochs"] == 60
    import pandas as pd

    d = pd.read_csv(out, comment="#")
    xyz = d[["x_m", "y_m", "z_m"]].to_numpy()
    lat, lon, h = np.radians(ROVER_LLH[0]), np.radians(ROVER_LLH[1]), ROVER_LLH[2]
    a, e2 = 6378137.0, 6.69437999014e-3
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    ref = np.array([(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon),
                    (n * (1 - e2) + h) * np.sin(lat)])
    enu = (xyz - ref) @ enu_matrix(*ecef_to_geodetic(ref)[:2]).T
    assert np.abs(enu.mean(axis=0)).max() < 0.02, enu.mean(axis=0)       # within 2 cm of the repository's mean (-2.6, -1.0, -7.9 mm)
