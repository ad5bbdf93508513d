"""RINEX 4.00 observation and navigation files are read as 3.05 ones (``rinex._RINEX_BELOW``): the body and the header records the
readers use are laid out as in 3.05.  Before, ``ingest`` refused them ("RINEX version 4.00 is not supported").

The real file: KMS3 (Denmark), 2022-06-08 10:00–10:09 GPST, 30 s, Compact RINEX of a RINEX 4.00 mixed observation
file (georust/rinex test_resources, MPL-2.0, tests/data/georust-rinex4).  Independent check: every GPS L1C phase and C1C
code of the file, cut out of the text by column (F14.3 + LLI + SSI per observation type, in the order of the header's
``SYS / # / OBS TYPES``) after the ``hatanaka`` package's decompression, equals what the readers return."""

from __future__ import annotations

import json
from pathlib import Path

import hatanaka
import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.gps_time import gps_seconds
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.rinex_signals import read_rinex_signals
from tests._shared import run_cli

DATA = Path(__file__).resolve().parents[1] / "data" / "georust-rinex4"
FILE, NAV = DATA / "KMS300DNK_R_20221591000_01H_30S_MO.crx", DATA / "KMS300DNK_R_20221591000_01H_MN.rnx.gz"


def _by_columns() -> dict:
    """(time s, satellite) → (L1C cycles, LLI, C1C m) cut from the decompressed text by column."""
    text = hatanaka.decompress(FILE.read_bytes()).decode()
    lines = text.splitlines()
    end = next(i for i, ln in enumerate(lines) if ln[60:].startswith("END OF HEADER"))
    types = next(ln for ln in lines[:end] if ln.startswith("G ") and ln[60:].startswith("SYS / # / OBS TYPES"))
    codes = types[7:60].split()
    assert int(types[1:6]) == len(codes)          # one line: 11 types
    i_l1, i_c1 = codes.index("L1C"), codes.index("C1C")
    out, t = {}, None
    for ln in lines[end + 1:]:
        if ln.startswith(">"):
            y, mo, d, h, mi = (int(v) for v in ln[2:24].split()[:5])
            t = float(gps_seconds(y, mo, d, h, mi, float(ln[19:29])))
        elif ln.startswith("G"):
            def field(i):
                f = ln[3 + 16 * i: 3 + 16 * i + 14]
                return float(f) if f.strip() else np.nan
            lli = ln[3 + 16 * i_l1 + 14: 3 + 16 * i_l1 + 15]
            out[(t, ln[:3])] = (field(i_l1), int(lli) if lli.strip() else 0, field(i_c1))
    return out


def test_a_rinex_4_observation_file_is_read_as_its_columns_say():
    hdr, obs = read_rinex_obs(FILE)
    assert hdr["version"] == 4.0 and hdr["marker_name"].startswith("KMS3")
    want = {k: v for k, v in _by_columns().items() if np.isfinite(v[0]) or np.isfinite(v[2])}
    assert len(want) == len(obs) == 173 and obs["time_gps_s"].nunique() == 19
    assert int(obs["phase_l1_cycles"].notna().sum()) == 171          # G09's code without a phase, twice
    got = {(float(r.time_gps_s), r.sat): (r.phase_l1_cycles, int(r.lli_l1), r.pseudorange_l1_m)
           for r in obs.itertuples()}
    assert got.keys() == want.keys()
    same = lambda a, b: a == b or (np.isnan(a) and np.isnan(b))            # noqa: E731
    for k, (phase, lli, code) in want.items():
        assert same(got[k][0], phase) and same(got[k][2], code), (k, got[k], want[k])
        assert np.isnan(phase) or got[k][1] == lli
    _, sig = read_rinex_signals(FILE, ["G:L1", "G:L2", "E:E1", "C:B1I"])
    g1 = sig[sig["signal"] == "G:L1"]
    l1 = obs["phase_l1_cycles"].dropna().to_numpy()
    assert np.array_equal(np.sort(g1["phase_cycles"].dropna().to_numpy()), np.sort(l1))
    assert set(sig["signal"]) == {"G:L1", "G:L2", "E:E1", "C:B1I"}


def test_a_rinex_4_navigation_file_gives_its_legacy_ephemerides():
    """RINEX 4 navigation (``> EPH G05 LNAV`` before each record, laid out as in 3.05): GPS/QZSS LNAV, Galileo I/NAV
    and F/NAV, BeiDou D1/D2 and GLONASS FDMA read; SBAS, the STO and ION messages passed over.  The file's message
    counts (its ``>`` lines): 31 LNAV (30 GPS, 1 QZSS), 55 INAV + 53 FNAV, 33 D1 + 3 D2, 24 FDMA, 158 SBAS."""
    nav = read_rinex_nav(NAV, systems=("G", "E", "C", "R"))
    assert nav.attrs["n_records_by_system"] == {"G": 30, "J": 1, "E": 108, "C": 36, "R": 24}
    g05 = nav[nav["sat"] == "G05"].iloc[0]                 # the record's own text (the file's third LNAV message)
    assert g05["sqrt_a_sqrt_m"] == 5.153730890274e03 and g05["e"] == 6.032018922269e-03 and g05["toe_sow_s"] == 2.952e05
    assert g05["toc_gps_s"] == gps_seconds(2022, 6, 8, 10, 0, 0) and g05["af0_s"] == -8.477037772536e-05


def test_the_rinex_4_pair_of_a_station_solves_its_zero_baseline(tmp_path):
    """The station's own RINEX 4 observation and navigation files as base and rover: every epoch fixed, on every signal
    both hold, at the base's position."""
    r = run_cli("-q", "rtk", "--base", FILE, "--rover", FILE, "--nav", NAV, "-o", tmp_path / "z.csv", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["epochs"] == s["fixed_epochs"] == 19 and {"G:L1", "G:L2", "E:E1", "C:B1I", "R:G1"} <= set(s["signals"])
    out = pd.read_csv(tmp_path / "z.csv", comment="#")
    assert np.abs(out[["e_m", "n_m", "u_m"]].to_numpy()).max() < 1e-4


def test_a_rinex_5_file_is_refused_by_name(tmp_path):
    nav = tmp_path / "v5.rnx"
    nav.write_text("     5.00           N: GNSS NAV DATA    M: MIXED            RINEX VERSION / TYPE\n"
                   "                                                            END OF HEADER\n")
    with pytest.raises(CdgpsError, match=r"v5.rnx: RINEX version 5.00 is not supported for navigation files "
                                         r"\(supported: 2.xx, i.e. 2.10/2.11, 3.xx and 4.xx\)"):
        read_rinex_nav(nav)
