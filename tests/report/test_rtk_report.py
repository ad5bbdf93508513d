"""`cdgps report rtk` on synthetic RTKLIB .pos files (written by cdgps' own .pos writer): the rover's
motion recovered in east/north/up, the quality shares, the header as provenance, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.solution_formats import Q_FIX, Q_FLOAT, Q_SINGLE, pos_text
from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix, geodetic_to_ecef

LAT, LON, H = 35.16, 139.61, 70.0
HEADER = ["program   : test writer, ratio 3, mask 15 deg", "inp file  : rover.rnx"]


def _pos(tmp_path, frame: str):
    n = 900
    t = 1.4e9 + np.arange(n, dtype=float)
    east = 0.020 * np.sin(2 * np.pi * t / 120.0)                 # 20 mm east–west, 2 min period
    q = np.full(n, Q_FIX)
    q[300:360], q[700:705] = Q_FLOAT, Q_SINGLE
    ref = geodetic_to_ecef(np.radians(LAT), np.radians(LON), H)
    R = enu_matrix(np.radians(LAT), np.radians(LON))
    xyz = ref + east[:, None] * R[0][None, :]
    if frame == "llh":
        lat, lon, h = ecef_to_geodetic(xyz)
        coords = np.column_stack([np.degrees(lat), np.degrees(lon), h])
    else:
        coords = np.column_stack([east, 0 * east, 0 * east])
    cov = np.tile(np.diag([0.004, 0.003, 0.009]) ** 2, (n, 1, 1))
    ratio = np.where(q == Q_FIX, 50.0, 0.0)
    p = tmp_path / f"sol_{frame}.pos"
    p.write_text(pos_text(t, coords, q, np.full(n, 8), cov, np.zeros(n), ratio, frame=frame, header=HEADER))
    return p, east


@pytest.mark.parametrize("frame", ["llh", "enu"])
def test_rtk_page_recovers_the_motion_and_the_quality(tmp_path, frame):
    pos, east = _pos(tmp_path, frame)
    out = tmp_path / "rep"
    r = CliRunner().invoke(main, ["report", "rtk", str(pos), "-o", str(out), "--date", "2026-12-04", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["epochs"] == 900
    assert s["fraction"] == {"fix": pytest.approx(835 / 900), "float": pytest.approx(60 / 900),
                             "single": pytest.approx(5 / 900)}
    fixed = np.ones(900, bool)
    fixed[300:360] = fixed[700:705] = False
    assert s["fixed_scatter_mm"]["e"] == pytest.approx(1e3 * np.std(east[fixed]), abs=0.05)    # (file rounding)
    assert s["fixed_scatter_mm"]["n"] < 0.1 and s["fixed_scatter_mm"]["u"] < 0.1
    text = (out / "index.html").read_text()
    assert text.count("data:image/png;base64,") == 2 and "<script" not in text
    assert "program   : test writer, ratio 3" in text and "sha256" in text     # the solver's header as provenance
    # the reference point in the file's own frame: an east/north/up file's is no ECEF position (it said "ECEF")
    assert ("from the base)" in text and "(ECEF" not in text) if frame == "enu" else "(ECEF " in text
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "report.json"]


def test_rtk_report_refuses_a_file_that_is_not_a_pos(tmp_path):
    bad = tmp_path / "bad.pos"
    bad.write_text("2024/01/01 00:00:00.000 1 2 3\n")
    r = CliRunner().invoke(main, ["report", "rtk", str(bad), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 2 and "not an RTKLIB .pos file" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "rep").exists()


def test_rtk_page_draws_epochs_of_other_quality_flags(tmp_path):
    """RTKLIB's Q 4 (DGPS) or 6 (PPP) epochs, even all of them, are drawn as one more class (was: a
    traceback when no epoch was fix, float or single)."""
    pos, _ = _pos(tmp_path, "enu")
    lines = pos.read_text().splitlines()
    other = [ln if ln.startswith("%") else " ".join(f if i != 5 else "4" for i, f in enumerate(ln.split()))
             for ln in lines]
    pos.write_text("\n".join(other) + "\n")
    out = tmp_path / "rep"
    r = CliRunner().invoke(main, ["report", "rtk", str(pos), "-o", str(out), "--date", "2026-12-04", "--json"])
    assert r.exit_code == 0 and "Traceback" not in r.output, r.output
    assert json.loads(r.stdout)["fraction"] == {"4": 1.0}
    assert "dark grey any other flag" in (out / "index.html").read_text()


@pytest.mark.parametrize("field,value,needle", [(2, "nan", "expected finite coordinates"),
                                                 (5, "1.5", "expected whole numbers >= 0 for Q and ns"),
                                                 (6, "-3", "expected whole numbers >= 0 for Q and ns")])
def test_rtk_report_refuses_a_line_with_bad_values(tmp_path, field, value, needle):
    pos, _ = _pos(tmp_path, "enu")
    lines = pos.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("%")) + 3
    lines[k] = " ".join(f if i != field else value for i, f in enumerate(lines[k].split()))
    pos.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, ["report", "rtk", str(pos), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 2 and f"line {k + 1}: {needle}" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "rep").exists()


def test_rtk_report_refuses_a_last_line_cut_short(tmp_path):
    """A .pos with the velocity columns RTKLIB writes after ratio (out-outvel), its last line cut in the
    velocities: refused naming file and line, with the field count the header promises (was read as whole)."""
    pos, _ = _pos(tmp_path, "enu")
    vel = ["vn(m/s)", "ve(m/s)", "vu(m/s)", "sdvn", "sdve", "sdvu", "sdvne", "sdveu", "sdvun"]
    lines = [ln + "  " + " ".join(vel) if ln.startswith("%  GPST") else ln if ln.startswith("%")
             else ln + " " + " ".join(["0.0010"] * 9) for ln in pos.read_text().splitlines()]
    pos.write_text("\n".join(lines) + "\n")
    r = CliRunner().invoke(main, ["report", "rtk", str(pos), "-o", str(tmp_path / "whole"), "--date", "2026-12-04"])
    assert r.exit_code == 0, r.output
    pos.write_text("\n".join(lines)[:-30])                        # cut in the velocities, no final newline
    r = CliRunner().invoke(main, ["report", "rtk", str(pos), "-o", str(tmp_path / "rep")])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert f"{pos}, line {len(lines)}: 20 fields, the column header promises 24" in r.output, r.output
    assert not (tmp_path / "rep").exists()


def test_rtk_report_reads_a_backward_solution_in_time_order(tmp_path):
    """RTKLIB writes a backward solution (``pos1-soltype=backward``) from its last epoch: `report rtk` refused it
    ("epoch 2 is not after epoch 1"); it now reads the epochs in time order, says so, and finds the same numbers as
    for the file in time order.  Times that go back and forth are still refused."""
    pos, _ = _pos(tmp_path, "llh")
    lines = pos.read_text().splitlines(keepends=True)
    head = [ln for ln in lines if ln.startswith("%")]
    body = [ln for ln in lines if not ln.startswith("%")]
    back = tmp_path / "back.pos"
    back.write_text("".join(head + body[::-1]))
    got = {}
    for name, p in (("forward", pos), ("backward", back)):
        out = tmp_path / f"rep_{name}"
        r = CliRunner().invoke(main, ["report", "rtk", str(p), "-o", str(out), "--date", "2026-12-04", "--json"])
        assert r.exit_code == 0, r.output
        got[name] = json.loads(r.stdout)
    order = got["backward"].pop("file_epoch_order")
    assert "descending" in order and "file_epoch_order" not in got["forward"]
    assert {k: v for k, v in got["backward"].items() if k not in ("output", "outputs")} == \
        {k: v for k, v in got["forward"].items() if k not in ("output", "outputs")}
    assert "as RTKLIB writes a backward solution" in (tmp_path / "rep_backward" / "index.html").read_text()
    mixed = tmp_path / "mixed.pos"
    mixed.write_text("".join(head + body[:10] + body[20:30][::-1] + body[30:]))
    r = CliRunner().invoke(main, ["report", "rtk", str(mixed), "-o", str(tmp_path / "rep_mixed")])
    assert r.exit_code == 2 and "is not after epoch" in r.output and "decrease as in RTKLIB's backward" in r.output
    assert not (tmp_path / "rep_mixed").exists()
