"""RINEX observation and navigation readers on real receiver files and on crafted edge cases.

Real files live in ``tests/data`` (copies, see tests/data/README.md) and, in full, in the shared
data folder next to the repository (``../shared/data``); tests on the latter skip if it is absent.
"""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds, gps_time_str
from cdgps_cli.core.records import NAV_COLUMNS, OBS_COLUMNS
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs

DATA = Path(__file__).resolve().parents[1] / "data"
SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SHARED_RINEX = SHARED / "rinex"


def shared(name: str) -> Path:
    p = SHARED_RINEX / name
    if not p.exists():
        pytest.skip(f"shared test data not available: {p} (the ../shared/data folder beside the repository)")
    return p


def hl(body: str, label: str) -> str:
    """A RINEX header line: body in columns 1-60, label in 61-80."""
    return f"{body:<60}{label:<20}"


# ----------------------------------------------------------------------------------------------
# GEONET 0759 (RINEX 2.10, Trimble 5700)
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def geonet0759():
    return read_rinex_obs(DATA / "07590920.05o")


def _independent_parse_geonet(path: Path) -> pd.DataFrame:
    """A minimal reader for this one file's simple layout (≤ 12 satellites, 4 types, comment events)."""
    rows = []
    lines = path.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    while i < len(lines):
        ep = lines[i]
        n = int(ep[29:32])
        if ep[28] == "4":
            i += 1 + n
            continue
        assert n <= 12 and ep[28] == "0"
        yy, mo, dd, hh, mi = (int(x) for x in ep[:15].split())
        t = gps_seconds(2000 + yy, mo, dd, hh, mi, float(ep[15:26]))
        sats = [ep[32 + 3 * k : 35 + 3 * k].replace(" ", "0") for k in range(n)]
        for k, sat in enumerate(sats):
            rec = lines[i + 1 + k].ljust(64)
            l1, c1 = rec[0:14].strip(), rec[16:30].strip()
            if l1 or c1:
                rows.append((t, sat, float(l1) if l1 else math.nan, int(rec[14].strip() or 0), float(c1) if c1 else math.nan))
        i += 1 + n
    return pd.DataFrame(rows, columns=["time_gps_s", "sat", "phase_l1_cycles", "lli_l1", "pseudorange_l1_m"]).sort_values(["time_gps_s", "sat"]).reset_index(drop=True)


def test_geonet_header(geonet0759):
    h, _ = geonet0759
    assert h["version"] == pytest.approx(2.10)
    assert h["marker_name"] == "0759"
    assert h["receiver_type"] == "TRIMBLE 5700"
    assert h["antenna_type"] == "TRM29659.00"
    assert h["approx_position_xyz_m"] == (-3976219.5082, 3382372.5671, 3652512.9849)
    assert h["antenna_delta_hen_m"] == (0.0, 0.0, 0.0)
    assert h["interval_s"] == 30.0
    assert h["obs_types"] == {"*": ["L1", "C1", "L2", "P2"]}
    assert h["l1_obs_types"] == {"phase": "L1", "pseudorange": "C1", "snr": None}
    assert h["time_first_obs_gps_s"] == gps_seconds(2005, 4, 2)
    assert h["time_system"] == "GPS"
    assert h["leap_seconds"] is None  # not in this observation header
    assert h["wavelength_factor_l1"] == 1
    # teqc splices: three 'header information' events, each with one comment line
    assert [(e["flag"], e["line"], e["labels"]) for e in h["events"]] == [(4, 855, ["COMMENT"]), (4, 1058, ["COMMENT"]), (4, 1090, ["COMMENT"])]
    assert h["comments"][-1] == "RINEX FILE SPLICE; other post-header comments skipped"


def test_geonet_epochs_and_satellites(geonet0759):
    h, obs = geonet0759
    assert list(obs.columns) == list(OBS_COLUMNS)
    assert h["n_epochs"] == 120 and h["n_gps_epochs"] == 120
    t = np.unique(obs["time_gps_s"].to_numpy())
    assert len(t) == 120
    # 30 s epochs from 00:00:00 to 00:59:30 GPST; the receiver's time tags drift by whole ms
    grid = np.round((t - t[0]) / 30.0)
    np.testing.assert_array_equal(grid, np.arange(120))
    off_ms = (t - t[0] - 30.0 * grid) * 1e3
    assert off_ms.min() > -0.01 and off_ms.max() == pytest.approx(5.0, abs=1e-3)
    np.testing.assert_allclose(off_ms, np.round(off_ms), atol=1e-4)  # exact to the ms
    assert gps_time_str(t[-1]) == "2005-04-02 00:59:30.005 GPST"
    assert h["gps_satellites"] == ["G01", "G03", "G04", "G07", "G08", "G11", "G19", "G20", "G23", "G24", "G28"]
    counts = obs.groupby("sat").size().to_dict()
    assert counts["G07"] == counts["G11"] == counts["G28"] == 120
    assert counts["G23"] == 15 and counts["G03"] == 33
    assert len(obs) == 948 and h["n_records_by_system"] == {"G": 948}
    assert obs["snr_l1_dbhz"].isna().all()  # no S1 in this file
    assert obs["rx_clock_offset_s"].isna().all()
    assert (obs["epoch_flag"] == 0).all()


def test_geonet_exact_values_against_raw_text(geonet0759):
    _, obs = geonet0759
    first = obs[obs["time_gps_s"] == gps_seconds(2005, 4, 2)].set_index("sat")
    # lines 19-20 of the file
    assert first.loc["G03", "phase_l1_cycles"] == 55923622.160
    assert first.loc["G03", "pseudorange_l1_m"] == 24767686.375
    assert first.loc["G07", "phase_l1_cycles"] == -691177.898
    assert first.loc["G07", "pseudorange_l1_m"] == 24361933.475
    assert first.loc["G03", "lli_l1"] == 0 and first.loc["G03", "ssi_l1"] == 0
    # line 289: "  60416220.8711   25622603.521" — G03 with LLI 1 (loss of lock), L2 blank
    g03 = obs[(obs["sat"] == "G03") & (obs["time_gps_s"] == gps_seconds(2005, 4, 2, 0, 15, 0.001))].iloc[0]
    assert g03["phase_l1_cycles"] == 60416220.871 and g03["lli_l1"] == 1 and g03["pseudorange_l1_m"] == 25622603.521
    # and every row against an independent minimal parse of the text
    ref = _independent_parse_geonet(DATA / "07590920.05o")
    got = obs[["time_gps_s", "sat", "phase_l1_cycles", "lli_l1", "pseudorange_l1_m"]]
    pd.testing.assert_frame_equal(got, ref, check_exact=True)


def test_geonet_loss_of_lock_flags(geonet0759):
    _, obs = geonet0759
    lli = obs[obs["lli_l1"] > 0]
    assert sorted(set(lli["sat"])) == ["G01", "G03", "G04", "G08", "G23"]
    assert len(lli) == 10
    # all on low satellites coming and going; the phase is blank on 4 rows (C1 only)
    assert obs["phase_l1_cycles"].isna().sum() == 4


def test_geonet_pair_common_epochs():
    h1, o1 = read_rinex_obs(DATA / "07590920.05o")
    h2, o2 = read_rinex_obs(shared("30400920.05o"))
    assert h2["marker_name"] == "3040" and h2["n_epochs"] == 120
    assert "G27" in h2["gps_satellites"] and "G27" not in h1["gps_satellites"]
    t1, t2 = np.unique(o1["time_gps_s"]), np.unique(o2["time_gps_s"])
    # the stations' time tags drift in opposite directions: equal only for the first 6 minutes …
    common = np.intersect1d(t1, t2)
    assert len(common) == 12 and common[-1] == gps_seconds(2005, 4, 2, 0, 5, 30)
    # … but on the nominal 30 s grid all 120 epochs are common, tags within 10 ms of each other
    n1, n2 = np.round(t1 / 30) * 30, np.round(t2 / 30) * 30
    np.testing.assert_array_equal(n1, n2)
    assert np.max(np.abs(t1 - t2)) < 0.010
    p1, p2 = np.array(h1["approx_position_xyz_m"]), np.array(h2["approx_position_xyz_m"])
    assert np.linalg.norm(p1 - p2) == pytest.approx(3.3e3, abs=0.1e3)


# ----------------------------------------------------------------------------------------------
# every real observation / navigation file of the shared folder
# ----------------------------------------------------------------------------------------------

_SHARED_FILES = [
    "07590920.05o",
    "07590920.05n",
    "30400920.05o",
    "30400920.05n",
    "P43300USA_R_20190012056_17M_15S_MO.crx",
    "demo.10o",
    "demo3.10o",
    "14601736.18o",
    "14601736.18n",
]


@pytest.mark.parametrize("name", _SHARED_FILES)
def test_every_shared_rinex_file_is_read(name):
    p = shared(name)
    if name.endswith("n"):
        nav = read_rinex_nav(p)
        assert len(nav) > 0 and list(nav.columns) == list(NAV_COLUMNS)
        assert nav["sqrt_a_sqrt_m"].between(5000, 5300).all()
    else:
        h, obs = read_rinex_obs(p)
        assert len(obs) > 0 and h["n_epochs"] > 0
        assert obs["sat"].str.match(r"^G\d\d$").all()
        assert np.isfinite(obs["phase_l1_cycles"]).mean() > 0.9


def test_all_shared_files_are_covered():
    if not SHARED_RINEX.exists():
        pytest.skip(f"shared test data not available: {SHARED_RINEX}")
    assert sorted(p.name for p in SHARED_RINEX.iterdir()) == sorted(_SHARED_FILES)


# ----------------------------------------------------------------------------------------------
# Hatanaka / RINEX 3 with a real LLI
# ----------------------------------------------------------------------------------------------


def test_crx_subset_lli():
    h, obs = read_rinex_obs(DATA / "P433_lli_subset.crx")
    assert h["version"] == pytest.approx(3.03)
    assert h["receiver_type"] == "SEPT POLARX5" and h["marker_name"] == "p433"
    assert h["l1_obs_types"] == {"phase": "L1C", "pseudorange": "C1C", "snr": "S1C"}
    assert h["n_epochs"] == 4 and h["interval_s"] == 15.0
    assert set(h["n_records_by_system"]) == {"C", "E", "G", "R", "S"}
    lli = obs[obs["lli_l1"] > 0]
    assert len(lli) == 1
    r = lli.iloc[0]
    # raw text: "G07  25221848.514 5 132541708.01915 …" at 2019-01-01 21:10:15
    assert r["sat"] == "G07" and r["time_gps_s"] == gps_seconds(2019, 1, 1, 21, 10, 15)
    assert r["phase_l1_cycles"] == 132541708.019 and r["lli_l1"] == 1 and r["ssi_l1"] == 5
    assert r["pseudorange_l1_m"] == 25221848.514
    assert obs["snr_l1_dbhz"].between(20, 60).all()


def test_crx_full_file():
    h, obs = read_rinex_obs(shared("P43300USA_R_20190012056_17M_15S_MO.crx"))
    assert h["n_epochs"] == 70
    t = np.unique(obs["time_gps_s"])
    assert np.all(np.diff(t) == 15.0)
    assert gps_time_str(t[0]) == "2019-01-01 20:56:45 GPST" and gps_time_str(t[-1]) == "2019-01-01 21:14:00 GPST"
    assert len(h["gps_satellites"]) == 11
    assert h["n_records_by_system"]["R"] > 0 and h["n_records_by_system"]["E"] > 0
    lli = obs[obs["lli_l1"] > 0]
    assert lli[["sat", "time_gps_s"]].values.tolist() == [["G07", gps_seconds(2019, 1, 1, 21, 10, 15)]]
    # the subset in tests/data agrees with the full file row by row
    _, sub = read_rinex_obs(DATA / "P433_lli_subset.crx")
    m = sub.merge(obs, on=["time_gps_s", "sat"], suffixes=("", "_full"))
    assert len(m) == len(sub)
    for c in ("phase_l1_cycles", "pseudorange_l1_m", "snr_l1_dbhz", "lli_l1", "ssi_l1"):
        np.testing.assert_array_equal(m[c].to_numpy(), m[c + "_full"].to_numpy())


def test_compressed_variants_equal_plain(tmp_path):
    import hatanaka

    plain = (DATA / "07590920.05o").read_bytes()
    _, ref = read_rinex_obs(DATA / "07590920.05o")
    gz = tmp_path / "07590920.05o.gz"
    gz.write_bytes(gzip.compress(plain))
    crx_gz = tmp_path / "07590920.05d.gz"
    crx_gz.write_bytes(hatanaka.compress(plain, compression="gz"))
    crx_z = tmp_path / "07590920.05d.Z"
    crx_z.write_bytes(hatanaka.compress(plain, compression="Z"))
    crx = tmp_path / "07590920.05d"
    crx.write_bytes(hatanaka.compress(plain, compression="none"))
    assert crx.read_bytes().startswith(b"1.0                 COMPACT RINEX FORMAT")
    import ncompress  # Unix compress (.Z); installed with hatanaka

    z = tmp_path / "07590920.05o.Z"
    z.write_bytes(ncompress.compress(plain))
    for p in (gz, z, crx_gz, crx_z, crx):
        h, obs = read_rinex_obs(p)
        pd.testing.assert_frame_equal(obs, ref, check_exact=True)
        assert h["n_epochs"] == 120
    nav_gz = tmp_path / "07590920.05n.gz"
    nav_gz.write_bytes(gzip.compress((DATA / "07590920.05n").read_bytes()))
    pd.testing.assert_frame_equal(read_rinex_nav(nav_gz), read_rinex_nav(DATA / "07590920.05n"))


def test_corrupt_compressed_files(tmp_path):
    bad_gz = tmp_path / "x.05o.gz"
    bad_gz.write_bytes(gzip.compress((DATA / "07590920.05o").read_bytes())[:2000])
    with pytest.raises(CdgpsError, match=r"x\.05o\.gz: cannot decompress"):
        read_rinex_obs(bad_gz)
    crx = (DATA / "P433_lli_subset.crx").read_bytes()
    bad_crx = tmp_path / "cut.crx"
    bad_crx.write_bytes(crx[: len(crx) // 2] + b"\n#garbage\n" + crx[len(crx) // 2 + 300 :])
    with pytest.raises(CdgpsError, match=r"cut\.crx"):
        read_rinex_obs(bad_crx)


# ----------------------------------------------------------------------------------------------
# RINEX 2 vs RINEX 3 of the same data, continuation lines, clock offsets, events
# ----------------------------------------------------------------------------------------------


def test_demo_rinex2_and_rinex3_agree():
    h2, o2 = read_rinex_obs(DATA / "demo.10o")
    h3, o3 = read_rinex_obs(DATA / "demo3.10o")
    assert h2["version"] == pytest.approx(2.11) and h3["version"] == pytest.approx(3.01)
    # 14 satellites in the first epoch: a continuation line of the satellite list (RINEX 2),
    # and 7 types: a second line per satellite; 'G 7' is G07
    assert h2["n_records_by_system"] == h3["n_records_by_system"] == {"G": 15, "R": 6, "S": 1}
    assert h2["gps_satellites"] == ["G07", "G09", "G12", "G13", "G15", "G20", "G21", "G26", "G31", "G32"]
    cols = ["time_gps_s", "sat", "phase_l1_cycles", "lli_l1", "ssi_l1", "pseudorange_l1_m"]
    pd.testing.assert_frame_equal(o2[cols], o3[cols], check_exact=True)
    g07 = o2[(o2["sat"] == "G07")].iloc[0]
    assert g07["phase_l1_cycles"] == 118767195.326 and g07["ssi_l1"] == 8
    assert g07["pseudorange_l1_m"] == 22227666.760  # C1 (not P1 22600658.277)
    assert g07["snr_l1_dbhz"] == 57.0  # S1 on the continuation line
    assert h3["l1_obs_types"] == {"phase": "L1C", "pseudorange": "C1C", "snr": "S1P"}
    np.testing.assert_array_equal(o2["rx_clock_offset_s"], -0.12345)
    np.testing.assert_allclose(o3["rx_clock_offset_s"], -0.123456789012, rtol=0, atol=1e-15)
    assert h2["rcv_clock_offset_applied"] is True and h2["leap_seconds"] == 15
    assert h2["antenna_delta_hen_m"] == (0.903, 0.0, 0.0)


def test_event_flags_kinematic_and_new_site():
    h, obs = read_rinex_obs(DATA / "14601736.18o")  # CRLF line ends, flags 2 and 3
    assert [(e["flag"], e["line"]) for e in h["events"]] == [(2, 34), (3, 61), (2, 123)]
    assert h["events"][1]["labels"] == ["COMMENT", "MARKER NAME", "MARKER NUMBER", "APPROX POSITION XYZ", "ANTENNA: DELTA H/E/N"]
    assert math.isnan(h["events"][0]["time_gps_s"])
    assert h["n_epochs"] == 3
    assert h["n_records_by_system"] == {"E": 6, "G": 17, "R": 15}
    assert h["leap_seconds"] == 18
    t2 = gps_seconds(2018, 6, 22, 6, 17, 45)
    g16 = obs[obs["sat"] == "G16"].set_index("time_gps_s")
    # "  22390668.688 1 … 117663707.99211": L1 with LLI 1, SSI 1 (new satellite)
    assert g16.loc[t2, "phase_l1_cycles"] == 117663707.992
    assert (g16.loc[t2, "lli_l1"], g16.loc[t2, "ssi_l1"]) == (1, 1)
    # next epoch: C1 only
    t3 = gps_seconds(2018, 6, 22, 6, 18, 0)
    assert math.isnan(g16.loc[t3, "phase_l1_cycles"]) and g16.loc[t3, "pseudorange_l1_m"] == 22393948.930
    assert g16.loc[t3, "lli_l1"] == 0
    # every satellite starts with LLI 1 after 'start of kinematic data'
    first = obs[obs["time_gps_s"] == gps_seconds(2018, 6, 22, 6, 17, 30)]
    assert (first["lli_l1"] == 1).all() and len(first) == 5


def _obs2(values: list[tuple | None]) -> list[str]:
    """RINEX 2 observation lines for one satellite: (value, lli, ssi) or None per type."""
    fields = []
    for v in values:
        if v is None:
            fields.append(" " * 16)
        else:
            val, lli, ssi = v
            fields.append(f"{val:14.3f}{lli}{ssi}")
    return ["".join(fields[k : k + 5]).rstrip() for k in range(0, len(fields), 5)]


def _epoch2(mi: int, sec: float, flag: int, sats: list[str], clock: float | None = None) -> list[str]:
    head = f" 10  3  5  0 {mi:2d}{sec:11.7f}  {flag:1d}{len(sats):3d}"
    out = []
    for k in range(0, max(len(sats), 1), 12):
        chunk = "".join(sats[k : k + 12])
        prefix = head if k == 0 else " " * 32
        line = f"{prefix}{chunk:<36}"
        if k == 0 and clock is not None:
            line += f"{clock:12.9f}"
        out.append(line.rstrip())
    return out


def _synthetic_rinex2() -> str:
    types = ["C1", "L1", "L2", "P2", "D1", "S1", "P1"]
    lines = [
        hl("     2.11           OBSERVATION DATA    M (MIXED)", "RINEX VERSION / TYPE"),
        hl("SYNTH", "MARKER NAME"),
        hl("  -3976219.5082  3382372.5671  3652512.9849", "APPROX POSITION XYZ"),
        hl(f"{len(types):6d}" + "".join(f"{t:>6}" for t in types), "# / TYPES OF OBSERV"),
        hl("  2010     3     5     0     0    0.0000000     GPS", "TIME OF FIRST OBS"),
        hl("", "END OF HEADER"),
    ]
    sats = [f"G{k:2d}" for k in range(1, 11)] + ["R 1", "S20", "E11"]
    lines += _epoch2(0, 0.0, 0, sats, clock=0.000123456)
    for k, _ in enumerate(sats):
        lines += _obs2([(2.0e7 + k, " ", " "), (1.0e8 + k, str(k % 2), "7"), None, None, (100.0, " ", " "), (40.0 + k, " ", " "), (2.1e7, " ", " ")])
    # a power failure before epoch 2; G01 phase blank (code only); G02 both blank (dropped)
    lines += _epoch2(0, 30.0, 1, ["G 1", "G02", "G03"])
    lines += _obs2([(2.0e7, " ", " "), None, None, None, None, None, None])
    lines += _obs2([None] * 7)
    lines += _obs2([None, (5.5e7, "4", "9"), None, None, None, (45.0, " ", " "), (2.2e7, " ", " ")])
    # cycle-slip records (flag 6): observation layout, not observations
    lines += _epoch2(0, 30.0, 6, ["G03"])
    lines += _obs2([None, (1.0, " ", " "), None, None, None, None, None])
    # header information (flag 4): observation types change to L1 C1
    lines += ["                            4  2", hl("     2    L1    C1", "# / TYPES OF OBSERV"), hl("TYPES CHANGE", "COMMENT")]
    lines += _epoch2(1, 0.0, 0, ["G04", "G05"])
    lines += _obs2([(7.0e7, "1", "5"), (2.3e7, " ", " ")])
    lines += _obs2([(8.0e7, " ", " "), (2.4e7, " ", " ")])
    # external event with a time and no records
    lines += _epoch2(1, 10.0, 5, [])
    lines += _epoch2(1, 30.0, 0, ["G04"])
    lines += _obs2([(7.1e7, " ", " "), (2.31e7, " ", " ")])
    return "\n".join(lines) + "\n"


def test_synthetic_rinex2_continuations_flags_events(tmp_path):
    p = tmp_path / "synth.10o"
    p.write_text(_synthetic_rinex2())
    h, obs = read_rinex_obs(p)
    assert h["n_epochs"] == 4 and h["n_epochs_power_failure"] == 1
    assert [e["flag"] for e in h["events"]] == [6, 4, 5]
    assert h["events"][2]["time_gps_s"] == gps_seconds(2010, 3, 5, 0, 1, 10.0)
    assert h["obs_types"] == {"*": ["L1", "C1"]}  # updated by the flag-4 record
    assert h["n_records_by_system"] == {"E": 1, "G": 10 + 3 + 2 + 1, "R": 1, "S": 1}
    t0 = gps_seconds(2010, 3, 5)
    e1 = obs[obs["time_gps_s"] == t0].set_index("sat")
    assert len(e1) == 10  # 13 satellites on two lines; R, S, E not returned
    assert e1.loc["G10", "phase_l1_cycles"] == 1.0e8 + 9 and e1.loc["G10", "lli_l1"] == 1 and e1.loc["G10", "ssi_l1"] == 7
    assert e1.loc["G10", "pseudorange_l1_m"] == 2.0e7 + 9  # C1 preferred over P1
    assert e1.loc["G10", "snr_l1_dbhz"] == 49.0  # S1 from the second line of the record
    np.testing.assert_array_equal(e1["rx_clock_offset_s"], 0.000123456)
    e2 = obs[obs["time_gps_s"] == t0 + 30].set_index("sat")
    assert list(e2.index) == ["G01", "G03"]  # G02 had neither phase nor code
    assert math.isnan(e2.loc["G01", "phase_l1_cycles"]) and e2.loc["G01", "pseudorange_l1_m"] == 2.0e7
    assert e2.loc["G03", "lli_l1"] == 4 and e2.loc["G03", "ssi_l1"] == 9
    assert (e2["epoch_flag"] == 1).all()
    e3 = obs[obs["time_gps_s"] == t0 + 60].set_index("sat")
    assert e3.loc["G04", "phase_l1_cycles"] == 7.0e7 and e3.loc["G04", "pseudorange_l1_m"] == 2.3e7
    assert e3.loc["G04", "lli_l1"] == 1 and math.isnan(e3.loc["G04", "snr_l1_dbhz"])
    assert len(obs[obs["time_gps_s"] == t0 + 90]) == 1


# ----------------------------------------------------------------------------------------------
# errors
# ----------------------------------------------------------------------------------------------


def test_no_l1_phase_is_refused(tmp_path):
    text = _synthetic_rinex2().replace(hl(f"{7:6d}" + "".join(f"{t:>6}" for t in ["C1", "L1", "L2", "P2", "D1", "S1", "P1"]), "# / TYPES OF OBSERV"), hl("     3    C1    P2    S1", "# / TYPES OF OBSERV"))
    p = tmp_path / "codeonly.10o"
    p.write_text(text)
    with pytest.raises(CdgpsError, match=r"codeonly\.10o: no GPS L1 carrier-phase observation type .*the file has: C1 P2 S1"):
        read_rinex_obs(p)


def test_rinex3_without_gps_is_refused(tmp_path):
    lines = (DATA / "demo3.10o").read_text().splitlines()
    lines = [ln for ln in lines if not ln.startswith("G    7 L1C")]
    p = tmp_path / "nogps.10o"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(CdgpsError, match=r"nogps\.10o: no GPS observation types in the header .*R, S"):
        read_rinex_obs(p)


def test_malformed_observation_line_names_line(tmp_path):
    lines = (DATA / "07590920.05o").read_text().splitlines()
    assert lines[19].startswith("   -691177.898")
    lines[19] = "   -6911x7.898" + lines[19][14:]
    p = tmp_path / "bad.05o"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(CdgpsError, match=r"bad\.05o, line 20: malformed observation record for G07"):
        read_rinex_obs(p)


def test_malformed_epoch_line_names_line(tmp_path):
    lines = (DATA / "07590920.05o").read_text().splitlines()
    assert lines[26].startswith(" 05  4  2  0  0 30.0")
    lines[26] = " 05  4  2  0  0 30.0000000  x  8" + lines[26][32:]
    p = tmp_path / "bad.05o"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(CdgpsError, match=r"bad\.05o, line 27: expected an epoch line"):
        read_rinex_obs(p)


def test_truncated_epoch_and_time_order(tmp_path):
    lines = (DATA / "07590920.05o").read_text().splitlines()
    p = tmp_path / "cut.05o"
    p.write_text("\n".join(lines[:22]) + "\n")
    with pytest.raises(CdgpsError, match=r"cut\.05o, line 18: epoch 2005-04-02 00:00:00 GPST announces 8 satellites .* the file ends"):
        read_rinex_obs(p)
    swapped = lines[:17] + lines[26:35] + lines[17:26] + lines[35:]
    p2 = tmp_path / "order.05o"
    p2.write_text("\n".join(swapped) + "\n")
    # two epochs swapped are read in time order and listed (they were refused; rtk sorts them): tests/io/test_rinex_repeated.py
    hdr, obs = read_rinex_obs(p2)
    assert obs.equals(read_rinex_obs(DATA / "07590920.05o")[1])
    assert [(b["line"], b["time_gps_s"]) for b in hdr["epochs_out_of_order"]] == [(27, obs["time_gps_s"].iloc[0])]


@pytest.mark.parametrize("version", ["1.00", "5.00"])
def test_unsupported_version(tmp_path, version):
    text = (DATA / "07590920.05o").read_text().replace("     2.10           OBSERVATION", f"{version:>9}           OBSERVATION", 1)
    p = tmp_path / "v.05o"
    p.write_text(text)
    with pytest.raises(CdgpsError, match=rf"v\.05o: RINEX version {version} is not supported .*2\.xx.*3\.xx"):
        read_rinex_obs(p)


def test_wrong_kind_of_file(tmp_path):
    with pytest.raises(CdgpsError, match=r"07590920\.05n: this is a RINEX navigation file, not an observation file"):
        read_rinex_obs(DATA / "07590920.05n")
    with pytest.raises(CdgpsError, match=r"07590920\.05o: this is a RINEX observation file, not a navigation file"):
        read_rinex_nav(DATA / "07590920.05o")
    with pytest.raises(CdgpsError, match=r"pygpsdata-ESF\.log, line 1: not a RINEX file"):
        read_rinex_obs(DATA / "pygpsdata-ESF.log")
    empty = tmp_path / "empty.05o"
    empty.write_text("")
    with pytest.raises(CdgpsError, match=r"empty\.05o: empty file"):
        read_rinex_obs(empty)
    with pytest.raises(CdgpsError, match=r"missing\.05o: cannot read"):
        read_rinex_obs(tmp_path / "missing.05o")
    headonly = tmp_path / "head.05o"
    headonly.write_text("\n".join((DATA / "07590920.05o").read_text().splitlines()[:10]) + "\n")
    with pytest.raises(CdgpsError, match=r"head\.05o: no 'END OF HEADER' line"):
        read_rinex_obs(headonly)
    glo = tmp_path / "glo.05g"
    glo.write_text(hl("     2.10           G: GLONASS NAV DATA", "RINEX VERSION / TYPE") + "\n" + hl("", "END OF HEADER") + "\n")
    with pytest.raises(CdgpsError, match=r"glo\.05g: this is a RINEX 2\.10 GLONASS navigation file"):
        read_rinex_nav(glo)


# ----------------------------------------------------------------------------------------------
# navigation files
# ----------------------------------------------------------------------------------------------


def test_geonet_nav_fields_against_raw_text():
    nav = read_rinex_nav(DATA / "07590920.05n")
    assert list(nav.columns) == list(NAV_COLUMNS)
    raw = (DATA / "07590920.05n").read_text().splitlines()
    body = raw[next(k for k, ln in enumerate(raw) if "END OF HEADER" in ln) + 1 :]
    assert len(body) % 8 == 0
    assert nav.attrs["n_records_by_system"] == {"G": len(body) // 8}
    assert len(nav) == len(body) // 8 - 0  # no duplicates in this file
    assert nav.attrs["leap_seconds"] == 13
    assert nav.attrs["ion_alpha"] == [1.1180e-08, 1.4900e-08, -5.9600e-08, -5.9600e-08]
    # first record (lines 13-20): " 1 05  4  2  2  0  0.0 3.966595977540D-04 1.705302565820D-12 …"
    r = nav.iloc[0]
    assert r["sat"] == "G01" and r["line"] == 13
    assert r["toc_gps_s"] == gps_seconds(2005, 4, 2, 2)
    assert r["af0_s"] == 3.966595977540e-04 and r["af1_s_per_s"] == 1.705302565820e-12 and r["af2_s_per_s2"] == 0.0
    assert r["iode"] == 140 and r["crs_m"] == -5.218750000000e01
    assert r["delta_n_rad_per_s"] == 4.026596389650e-09 and r["m0_rad"] == 2.871534990340e00
    assert r["e"] == 5.957618006510e-03 and r["sqrt_a_sqrt_m"] == 5.153636478420e03
    assert r["toe_sow_s"] == 525600.0 and r["week"] == 1316
    assert r["toe_gps_s"] == 1316 * 604800 + 525600.0 == r["toc_gps_s"]
    assert r["omega0_rad"] == -2.493184817740e00 and r["i0_rad"] == 9.833919144490e-01
    assert r["omega_dot_rad_per_s"] == -7.889971342930e-09 and r["idot_rad_per_s"] == -8.571785642400e-12
    assert r["sv_health"] == 0 and r["tgd_s"] == -3.259629011150e-09 and r["iodc"] == 396
    assert r["transmit_sow_s"] == 519576.0 and r["transmit_gps_s"] == 1316 * 604800 + 519576.0
    assert math.isnan(r["fit_interval_h"])  # blank in this file
    assert nav["sat"].nunique() == 28
    # toc = toe here; records for Sunday 00:00 carry toe 0 of week 1317
    np.testing.assert_array_equal(nav["week"] * 604800 + nav["toe_sow_s"], nav["toc_gps_s"])
    assert sorted(nav["week"].unique()) == [1316, 1317]


def test_rinex211_nav_with_fit_interval():
    nav = read_rinex_nav(DATA / "14601736.18n")
    assert len(nav) == 7 and nav.attrs["leap_seconds"] == 18
    r = nav[nav["sat"] == "G30"].iloc[0]
    assert r["toc_gps_s"] == gps_seconds(2018, 6, 22, 8)
    assert r["af0_s"] == 0.595785677433e-04 and r["week"] == 2006 and r["fit_interval_h"] == 4.0
    assert r["sv_accuracy_m"] == 2.4 and r["iodc"] == 34


def _v2_to_v3_record(rec: list[str]) -> list[str]:
    first = rec[0]
    yy, mo, dd, hh, mi = (int(first[a:b]) for a, b in ((3, 5), (6, 8), (9, 11), (12, 14), (15, 17)))
    sec = int(float(first[17:22]))
    out = [f"G{int(first[0:2]):02d} {2000 + yy:04d} {mo:02d} {dd:02d} {hh:02d} {mi:02d} {sec:02d}" + first[22:]]
    out += [" " + ln for ln in rec[1:]]
    return out


def test_rinex3_mixed_nav_equals_rinex2(tmp_path):
    raw = (DATA / "07590920.05n").read_text().splitlines()
    start = next(k for k, ln in enumerate(raw) if "END OF HEADER" in ln) + 1
    recs = [raw[k : k + 8] for k in range(start, start + 8 * 5, 8)]
    zero = " 0.000000000000D+00"
    glo = ["R05 2005 04 02 02 15 00" + zero * 3] + ["    " + zero * 4] * 3
    gal = ["E11 2005 04 02 02 00 00" + zero * 3] + ["    " + zero * 4] * 7
    lines = [
        hl("     3.04           N: GNSS NAV DATA    M: MIXED", "RINEX VERSION / TYPE"),
        hl("GPSA   1.1180E-08  1.4900E-08 -5.9600E-08 -5.9600E-08", "IONOSPHERIC CORR"),
        hl("    13", "LEAP SECONDS"),
        hl("", "END OF HEADER"),
    ]
    for k, rec in enumerate(recs):
        lines += _v2_to_v3_record(rec)
        lines += glo if k == 1 else gal if k == 3 else []
    p = tmp_path / "mixed.rnx"
    p.write_text("\n".join(lines) + "\n")
    nav3 = read_rinex_nav(p)
    assert nav3.attrs["n_records_by_system"] == {"E": 1, "G": 5, "R": 1}
    assert nav3.attrs["ion_alpha"] == [1.1180e-08, 1.4900e-08, -5.9600e-08, -5.9600e-08]
    nav2 = read_rinex_nav(DATA / "07590920.05n")
    first5 = nav2[nav2["line"].isin([start + 1 + 8 * k for k in range(5)])]
    cols = [c for c in NAV_COLUMNS if c != "line"]
    pd.testing.assert_frame_equal(nav3[cols].sort_values(["sat", "toe_gps_s"]).reset_index(drop=True), first5[cols].sort_values(["sat", "toe_gps_s"]).reset_index(drop=True))


def test_nav_errors(tmp_path):
    raw = (DATA / "07590920.05n").read_text().splitlines()
    cut = tmp_path / "cut.05n"
    cut.write_text("\n".join(raw[:17]) + "\n")
    with pytest.raises(CdgpsError, match=r"cut\.05n, line 13: ephemeris record truncated"):
        read_rinex_nav(cut)
    bad = list(raw)
    assert bad[14].startswith("   -2.676621079440D-06")
    bad[14] = "   -2.676621O79440D-06" + bad[14][22:]
    p = tmp_path / "bad.05n"
    p.write_text("\n".join(bad) + "\n")
    with pytest.raises(CdgpsError, match=r"bad\.05n, line 15: malformed broadcast-orbit line 2 of the G01 record starting at line 13"):
        read_rinex_nav(p)
    hdr_only = tmp_path / "empty.05n"
    hdr_only.write_text("\n".join(raw[:12]) + "\n")
    with pytest.raises(CdgpsError, match=r"empty\.05n: no GPS ephemeris records"):
        read_rinex_nav(hdr_only)


def test_gps_time_helpers():
    assert gps_seconds(1980, 1, 6) == 0.0
    assert gps_seconds(2005, 4, 2) == 1316 * 604800 + 6 * 86400
    assert gps_time_str(gps_seconds(2019, 1, 1, 21, 10, 15.25)) == "2019-01-01 21:10:15.250 GPST"


# ----------------------------------------------------------------------------------------------
# RINEX 3 records are parsed in bulk; the record-by-record path stays for errors and oddities
# ----------------------------------------------------------------------------------------------


def _rinex3_records(path: Path):
    """The record-by-record parse of a RINEX 3 file (the reference for the bulk parser)."""
    from cdgps_cli.io import rinex as rx

    h, o = read_rinex_obs(path)
    lines = rx._read_lines(path)[0]
    rows = rx._new_rows()
    end = next(i for i, ln in enumerate(lines) if ln[60:80].strip() == "END OF HEADER")
    hdr = rx._ObsHeader(path, h["version"], False)
    for i in range(1, end + 1):
        hdr.apply(lines[i], i + 1)
    cols = rx._GpsL1Columns(hdr, end + 1)
    i = end + 1
    while i < len(lines):
        ln = lines[i]
        if not ln.strip():
            i += 1
            continue
        flag = int(ln[31:32].strip() or 0)
        if 2 <= flag <= 6:
            i += 1 + int(ln[32:35])
            continue
        n = int(ln[32:35])
        t = gps_seconds(int(ln[2:6]), int(ln[7:9]), int(ln[10:12]), int(ln[13:15]), int(ln[16:18]), float(ln[18:29]))
        clk = float(ln[35:]) if ln[35:].strip() else math.nan
        for rec in lines[i + 1:i + 1 + n]:
            if rec[0] == "G":
                f = (rx._obs_field(rec, cols.i_phase, 3), rx._obs_field(rec, cols.i_code, 3)[0] if cols.i_code >= 0 else None,
                     rx._obs_field(rec, cols.i_snr, 3)[0] if cols.i_snr >= 0 else None)
                rx._append_row(rows, t, rx._sat_id(rec[:3], 3.0), f, cols, clk, flag)
        i += 1 + n
    ref = pd.DataFrame({"time_gps_s": rows["t"], "sat": rows["sat"], "phase_l1_cycles": rows["phase"],
                        "lli_l1": rows["lli"], "ssi_l1": rows["ssi"], "pseudorange_l1_m": rows["code"],
                        "snr_l1_dbhz": rows["snr"]})
    return o, ref.sort_values(["time_gps_s", "sat"], kind="stable").reset_index(drop=True)


@pytest.mark.parametrize("name", ["demo3.10o", "P433_lli_subset.crx"])
def test_rinex3_bulk_parser_equals_record_by_record(name):
    o, ref = _rinex3_records(DATA / name)
    cols = list(ref.columns)
    pd.testing.assert_frame_equal(o[cols].reset_index(drop=True), ref, check_dtype=False)


def test_rinex3_bulk_parser_fallback_and_errors(tmp_path):
    lines = (DATA / "demo3.10o").read_text().splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln)
    k = next(i for i, ln in enumerate(lines) if i > end and ln.startswith("G") and ln[3:17].strip())
    # a Fortran D exponent in the L1C phase (first type): the record-by-record path takes over
    v = float(lines[k][3:17])
    d = f"{v / 1e8:.9f}D8".rjust(14)
    p = tmp_path / "d.10o"
    p.write_text("\n".join(lines[:k] + [lines[k][:3] + d + lines[k][17:]] + lines[k + 1:]) + "\n")
    _, a = read_rinex_obs(DATA / "demo3.10o")
    _, b = read_rinex_obs(p)
    np.testing.assert_allclose(b["phase_l1_cycles"].to_numpy(), a["phase_l1_cycles"].to_numpy(), rtol=1e-9, equal_nan=True)
    pd.testing.assert_frame_equal(a.drop(columns="phase_l1_cycles"), b.drop(columns="phase_l1_cycles"))
    # a malformed value or flag digit names its line
    for bad in (lines[k][:3] + "   12x45.678  " + lines[k][17:], lines[k][:17] + "x" + lines[k][18:]):
        q = tmp_path / "bad.10o"
        q.write_text("\n".join(lines[:k] + [bad] + lines[k + 1:]) + "\n")
        with pytest.raises(CdgpsError, match=rf"bad\.10o, line {k + 1}: malformed observation record for G"):
            read_rinex_obs(q)
    # a satellite record where an epoch line stands, and a malformed satellite identifier
    q = tmp_path / "sat.10o"
    q.write_text("\n".join(lines[:k] + ["X?? " + lines[k][4:]] + lines[k + 1:]) + "\n")
    with pytest.raises(CdgpsError, match=rf"sat\.10o, line {k + 1}: malformed satellite identifier"):
        read_rinex_obs(q)


def test_rinex_305_mixed_navigation_with_five_line_glonass_records():
    # RINEX 3.05 GLONASS records have a fourth broadcast-orbit line: skipping them by four lines
    # broke the GPS reading of such files ("expected the first line of an ephemeris record")
    from tests._shared import REPO_ROOT
    path = REPO_ROOT / "tests" / "data" / "MOJN00DNK_R_20201770000_subset.rnx"
    gps = read_rinex_nav(path)
    assert len(gps) == 15 and set(gps["sat"].str[0]) == {"G"}
    assert gps.attrs["n_records_by_system"] == {"C": 28, "G": 15, "R": 20}
    allsys = read_rinex_nav(path, systems=("G", "C", "R"))
    assert len(allsys) == 15 + 28 + 20 and allsys["glonass_k"].notna().sum() == 20


def test_nav_file_cut_in_a_record_of_a_system_not_read_is_refused(tmp_path):
    # a mixed navigation file cut inside its last (GLONASS, 5 lines in RINEX 3.05) record was read for GPS as if whole (ingest: exit 0)
    lines = (DATA / "MOJN00DNK_R_20201770000_subset.rnx").read_text().splitlines()
    last = max(i for i, ln in enumerate(lines) if ln[:1] == "R" and ln[1:3].isdigit())
    p = tmp_path / "cut.rnx"
    p.write_text("\n".join(lines[:last + 2]) + "\n")
    with pytest.raises(CdgpsError, match=rf"cut\.rnx, line {last + 1}: ephemeris record truncated: 5 lines expected, "
                                         r"the file ends after 2"):
        read_rinex_nav(p, systems=("G",))
    assert len(read_rinex_nav(DATA / "MOJN00DNK_R_20201770000_subset.rnx", systems=("G",))) == 15


def test_observation_file_given_as_navigation_beside_a_real_one_is_refused():
    # ingest/baseline --nav brdc.n --nav station.o skipped the observation file unseen (exit 0)
    from cdgps_cli.io.gnss_run import merge_nav
    from cdgps_cli.io.rinex import nav_file_systems

    with pytest.raises(CdgpsError, match=r"07590920\.05o: this is a RINEX observation file, not a navigation file"):
        merge_nav([DATA / "07590920.05n", DATA / "07590920.05o"])
    assert nav_file_systems(DATA / "07590920.05n") == ("G",) and nav_file_systems(DATA / "brdc3050_subset.12g") == ("R",)
    assert len(merge_nav([DATA / "07590920.05n", DATA / "brdc3050_subset.12g"])) == len(read_rinex_nav(DATA / "07590920.05n"))


@pytest.mark.parametrize("src, first, month, systems, why", [
    ("brdc3050_subset.12g", lambda ln: ln[:2].strip().isdigit(), slice(6, 8), ("R",), "GLONASS .*: month must be in 1..12"),
    ("MOJN00DNK_R_20201770000_subset.rnx", lambda ln: ln.startswith("R"), slice(9, 11), ("G", "R"),
     "GLONASS .*: month must be in 1..12"),
    ("07590920.05n", lambda ln: ln[:2].strip().isdigit(), slice(6, 8), ("G",), "first line of an ephemeris record"),
])
def test_nav_record_with_an_impossible_date_names_the_line(tmp_path, src, first, month, systems, why):
    # a GLONASS record with month 13 ended in a ValueError traceback (rtk --signals auto on the mosaic base.nav: exit 1)
    lines = (DATA / src).read_text().splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln)
    i = next(k for k in range(end + 1, len(lines)) if first(lines[k]))
    lines[i] = lines[i][:month.start] + "13" + lines[i][month.stop:]
    p = tmp_path / "bad.nav"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(CdgpsError, match=rf"bad\.nav, line {i + 1}: malformed {why}"):
        read_rinex_nav(p, systems=systems)
