"""`cdgps rtk` on a real 10 Hz receiver's files (data/real/reach-m2-static, see its README): a zero
baseline of one Emlid Reach M2 against its copy with pseudorange gaps, and a malformed excerpt."""

import json

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.pipeline.gnss_multi import NO_GEOMETRY, _observed_signals, is_ubx_log
from tests._shared import REPO_ROOT, run_cli

DATA = REPO_ROOT / "data" / "real" / "reach-m2-static"
OBS = DATA / "reach-m2-01_raw_202306291111.23d.gz"
GAPS = DATA / "reach-m2-01_raw_202306291111_psrGaps.23d.gz"
NAV = DATA / "reach-m2-01_raw_202306291111.nav.gz"
HEADER_XYZ = np.array([4157198.3767, 671195.0626, 4774772.0490])


@pytest.fixture(scope="module")
def zero_baseline(tmp_path_factory):
    out = tmp_path_factory.mktemp("reach") / "zero.csv"
    r = run_cli("rtk", "--base", OBS, "--rover", GAPS, "--nav", NAV, "-o", out, "--json")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output[r.output.index("{"):])
    return summary, pd.read_csv(out, comment="#")


def test_compressed_rinex_is_not_taken_for_a_ublox_log():
    # the gzip bytes of each file hold the UBX sync word 0xB5 0x62 by chance
    assert not any(is_ubx_log(p) for p in (OBS, GAPS, NAV))


def test_auto_signals_drop_a_header_signal_no_record_holds(zero_baseline):
    summary, _ = zero_baseline
    assert "C:B2I" not in summary["signals"]
    assert {"G:L1", "G:L2", "E:E1", "E:E5b", "C:B1I"} <= set(summary["signals"])
    assert any(w.startswith("C:B2I not used") for w in summary["warnings"])


def test_every_rover_epoch_is_used_or_counted_with_its_reason(zero_baseline):
    summary, sol = zero_baseline
    ep = summary["epoch_pairing"]
    assert ep["rover_epochs"] == 610                       # every epoch of the file
    assert ep["dropped"] == {NO_GEOMETRY: 1}               # 11:12:42.394: phases, no pseudorange at all
    assert ep["used"] + sum(ep["dropped"].values()) == ep["rover_epochs"]
    assert len(sol) == summary["epochs"] == 609
    dt = np.diff(sol["time_gps_s"])
    assert np.all((dt > 0.099) & (dt < 0.301))             # 10 Hz; the one missing epoch leaves 0.2 s
    assert np.allclose(np.mod(sol["time_gps_s"], 0.1), 0.094 % 0.1, atol=1e-3)  # the receiver's own tags


def test_zero_baseline_is_fixed_at_the_base(zero_baseline):
    summary, sol = zero_baseline
    assert summary["fixed_pct"] == 100.0
    xyz = np.c_[sol["x_m"], sol["y_m"], sol["z_m"]]
    assert np.max(np.linalg.norm(xyz - HEADER_XYZ, axis=1)) < 1e-3


def test_no_shared_phase_signal_is_refused_naming_both_files():
    b = pd.DataFrame({"signal": ["G:L1"]})
    r = pd.DataFrame({"signal": ["E:E1"]})
    with pytest.raises(CdgpsError, match="b.obs \\(base\\) and r.obs \\(rover\\) share no signal"):
        _observed_signals(["G:L1", "E:E1"], b, r, {"base": "b.obs", "rover": "r.obs"}, [])


def test_a_miscounted_epoch_is_refused_with_file_and_line(tmp_path):
    out = tmp_path / "bad.csv"
    r = run_cli("rtk", "--base", OBS, "--rover", DATA / "noDoppler_excerpt.23o.gz", "--nav", NAV, "-o", out)
    assert r.exit_code == 2
    # line 62's epoch announces 35 satellites and holds 34: line 97, the next epoch line, is where the 35th was due
    assert "noDoppler_excerpt.23o.gz:97: an epoch line where satellite record 35 of 35 of the epoch at line 62" \
        in r.output and "Traceback" not in r.output
    assert not out.exists() and not list(tmp_path.iterdir())
