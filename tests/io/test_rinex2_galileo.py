"""RINEX 2.11 files with Galileo, and GLONASS L2 whose code is C2 where a mixed file's P2 is blank.

``tests/data/mosaic-base-rinex211-subset.obs`` is the first three epochs of the real mosaic-X5 base
(``real-pairs/mosaic-static/base.obs``, RINEX 3.04) written as RINEX 2.11 by Debian's ``convbin -r rinex -v 2.11``
(2.4.3 b34), its header position put back: types ``C1 L1 P2 L2 C2 C5 L5 C7 L7`` for GPS, GLONASS and Galileo.  A
sweep of real files found Galileo refused there ("the file has no Galileo types") and every GLONASS L2 phase left
without a pseudorange (its records fill C2, not P2).  The independent check is the RINEX 3 file the subset was made
from: the same receiver's values, read by the RINEX 3 reader.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.io import rinex_signals
from cdgps_cli.io.rinex_signals import read_rinex_signals, signals_in_file

DATA = Path(__file__).resolve().parents[1] / "data"
SUBSET = DATA / "mosaic-base-rinex211-subset.obs"
RINEX3 = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real-pairs" / "mosaic-static" / "base.obs"
SIGNALS = ["G:L1", "G:L2", "G:L5", "E:E1", "E:E5a", "E:E5b", "R:G1", "R:G2"]
#: GLONASS frequency numbers of the satellites of the subset (RINEX 2 headers have none; the RINEX 3 file's header)
GLONASS_K = {"R01": 1, "R02": -4, "R03": 5, "R11": 0, "R12": -1, "R13": -2, "R17": 4, "R18": -3, "R24": 2}


def _read(fast: bool) -> pd.DataFrame:
    old = rinex_signals.FAST_PARSE
    rinex_signals.FAST_PARSE = fast
    try:
        return read_rinex_signals(SUBSET, SIGNALS, glonass_k=GLONASS_K)[1]
    finally:
        rinex_signals.FAST_PARSE = old


def test_galileo_and_gps_l5_of_a_rinex_2_11_file_are_read_by_both_readers():
    assert signals_in_file(SUBSET) == SIGNALS
    fast, slow = _read(True), _read(False)
    pd.testing.assert_frame_equal(fast, slow)
    per = fast.groupby("signal")["sat"].nunique().to_dict()
    assert (per["E:E1"], per["E:E5a"], per["E:E5b"], per["G:L1"], per["R:G2"]) == (9, 7, 7, 12, 9), per
    e04 = fast[(fast["sat"] == "E04") & (fast["signal"] == "E:E1")].iloc[0]
    assert e04["phase_cycles"] == 128718180.960 and e04["pseudorange_m"] == 24494249.114


def test_glonass_l2_takes_c2_where_p2_is_blank_and_gps_keeps_p2():
    t = _read(True)
    g2 = t[t["signal"] == "R:G2"]
    assert len(g2) == 27 and g2["pseudorange_m"].notna().all()
    l2 = t[t["signal"] == "G:L2"]
    assert l2["pseudorange_m"].notna().all()


def test_the_rinex_2_values_are_the_rinex_3_file_s():
    if not RINEX3.exists():
        pytest.skip("../shared/data/real-pairs absent")
    # GPS L2 aside: convbin wrote the W tracking (L2W, C2W as P2) into RINEX 2's L2, the RINEX 3 reader takes L2C (L2L)
    sigs = [s for s in SIGNALS if s != "G:L2"]
    t2 = _read(True)
    t2 = t2[t2["signal"] != "G:L2"]
    _, t3 = read_rinex_signals(RINEX3, sigs)
    t3 = t3[t3["time_gps_s"] <= t2["time_gps_s"].max()]
    both = t2.merge(t3, on=["time_gps_s", "sat", "signal"], suffixes=("_2", "_3"))
    assert len(both) == len(t2) == len(t3) and len(t2) > 150
    for col in ("phase_cycles", "pseudorange_m", "wavelength_m"):   # GLONASS L2's code: C2, the RINEX 3 C2C
        np.testing.assert_array_equal(both[f"{col}_2"], both[f"{col}_3"], err_msg=col)
    first = both["time_gps_s"] == both["time_gps_s"].min()      # convbin flags a loss of lock at its first epoch
    np.testing.assert_array_equal(both["lli_2"][~first], both["lli_3"][~first])


def test_a_galileo_name_in_a_comment_is_no_galileo_satellite(tmp_path):
    """``signals_in_file`` lists Galileo for a mixed RINEX 2 file whose observation epochs name a Galileo satellite,
    not for one whose event record's comment happens to hold "E12" in the satellite columns (a review)."""
    lines = SUBSET.read_text().splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    body = lines[end:]
    # every Galileo satellite of the subset renamed a GPS one it does not hold, then an event with a comment
    gps_only = [ln.replace("E", "G").replace("G04", "G31") if k in (0, 1, 2) else ln for k, ln in enumerate(body)]
    head = "".join(lines[:end])
    p = tmp_path / "no_galileo.obs"
    p.write_text(head + "".join(gps_only[:3]))
    assert "E:E1" not in signals_in_file(p)
    event = f" 24  6 24  8 20  0.5000000  4  1{'':36}\n{'':32}{'E12 E19':<28}COMMENT\n"   # in columns 33-68
    p.write_text(head + event + "".join(gps_only[:3]))
    assert "E:E1" not in signals_in_file(p)


def test_glonass_satellites_without_a_frequency_number_are_left_out_when_others_have_one():
    """A RINEX 2 CORS (no GLONASS SLOT / FRQ # lines) beside a u-blox rover: the numbers come from the rover's
    RXM-RAWX or the navigation records, which give one to every satellite with an ephemeris; a satellite without
    one has no ephemeris and no solver could use it, so its rows are left out and named (the default
    `config → ingest` of such a pair refused the whole file, a sweep of real files, session 30).  With no number
    at all the file is still refused, naming the satellites."""
    some = {k: v for k, v in GLONASS_K.items() if k not in ("R02", "R13")}
    _, t = read_rinex_signals(SUBSET, ["G:L1", "R:G1"], glonass_k=some)
    assert t.attrs["glonass_without_frequency"] == ["R02", "R13"]
    assert not set(t["sat"]) & {"R02", "R13"} and np.isfinite(t["wavelength_m"]).all()
    old = rinex_signals.FAST_PARSE
    rinex_signals.FAST_PARSE = False
    try:
        _, slow = read_rinex_signals(SUBSET, ["G:L1", "R:G1"], glonass_k=some)
    finally:
        rinex_signals.FAST_PARSE = old
    pd.testing.assert_frame_equal(t, slow)
    with pytest.raises(Exception, match="GLONASS frequency numbers absent for R01"):
        read_rinex_signals(SUBSET, ["R:G1"])


def test_the_frequency_numbers_of_a_table_s_glonass_rows():
    from cdgps_cli.io.gnss_run import glonass_numbers

    _, t = read_rinex_signals(SUBSET, ["G:L1", "R:G1", "R:G2"], glonass_k=GLONASS_K)
    assert glonass_numbers(t) == GLONASS_K
