"""``glonass_fix`` through a GNSS run config (issue 28 item 3): `init` fixes the GLONASS DDs between the two
identical Septentrio mosaic-X5 receivers on the static engine and the INIT says so; `estimate` refuses that INIT
(it does not carry the GLONASS integers yet, and re-solving them as float gave the GLONASS-float baseline, 1.8 mm
away), and a setting only the batch solver serves is refused rather than silently leaving GLONASS float."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")
RTKLIB_MULTI_GNSS_L1_STATIC_ENU_M = np.array([-0.2238, -0.9651, 0.0079])    # the data's README


def _config(d: Path, *extra: str) -> Path:
    p = d / "run.toml"
    p.write_text("\n".join(["[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]',
                            'signals = ["G:L1", "R:G1"]', *extra,
                            '[gnss.antennas."base"]', f'rinex = "{MOSAIC / "base.obs"}"',
                            '[gnss.antennas."rover"]', f'rinex = "{MOSAIC / "rover.obs"}"']) + "\n")
    return p


@pytest.fixture(scope="module")
def glonass_fixed(tmp_path_factory):
    """The mosaic G+R run and its glonass_fix INIT (directory, INIT dict, init's stderr)."""
    d = tmp_path_factory.mktemp("glofix")
    assert run_cli("-q", "ingest", "--config", _config(d, "glonass_fix = true"), "-o", d / "run.mcap").exit_code == 0
    r = run_cli("init", d / "run.mcap", "-o", d / "init.json")
    assert r.exit_code == 0, r.output
    return d, json.loads((d / "init.json").read_text()), r.stderr


def test_init_fixes_glonass(glonass_fixed):
    _, init, stderr = glonass_fixed
    assert "(+6 GLONASS fixed)" in stderr
    rov = init["rovers"]["rover"]
    assert rov["solver"] == "static_engine" and rov["n_glonass_fixed_by_engine"] == 6 and rov["n_fixed"] == 8
    assert "n_float_glonass" not in rov and rov["options"]["glonass_fix"] is True
    enu = np.asarray(rov["baseline_enu_from_master_m"])
    assert np.max(np.abs(enu - RTKLIB_MULTI_GNSS_L1_STATIC_ENU_M)) < 5e-4, enu


def test_init_carries_the_glonass_integers(glonass_fixed):
    """Each GLONASS bias entry holds its DD integer against its reference (N_i − N_r, own cycles; 0 on the
    reference) and both FDMA channels; the channels are the RINEX header's (GLONASS SLOT / FRQ #)."""
    _, init, _ = glonass_fixed
    glo = [b for b in init["biases"] if b["satellite"].startswith("R")]
    header = {"R01": 1, "R03": 5, "R11": 0, "R12": -1, "R17": 4, "R18": -3, "R24": 2}     # rover.obs line 40
    assert len(glo) == 7 and sum(b.get("fixed_by_engine", False) for b in glo) == 6
    (ref,) = [b for b in glo if b["pivot"]]
    assert ref["dd_integer_cycles"] == 0 and "fixed_by_engine" not in ref
    for b in glo:
        assert isinstance(b["dd_integer_cycles"], int) and b["reference"] == ref["satellite"]
        assert b["fdma_channel"] == header[b["satellite"][:3]] and b["reference_fdma_channel"] == header["R01"]
        assert b["integer_cycles"] is None and b["fixed"] is False          # the one-wavelength SD form stays GPS's
    # the DD integers the engine fixed; the bias form of the fixed solution (float_cycles = DD + x_r·(1 − λ_r/λ_i), x_r the reference's SD ambiguity) is near them
    assert [b["dd_integer_cycles"] for b in glo if not b["pivot"]] == [5, 16, 19, 12, 18, 12]
    assert all(abs(b["float_cycles"] - b["dd_integer_cycles"]) < 0.1 for b in glo if not b["pivot"])


def test_estimate_refuses_a_glonass_fix_init_for_now(glonass_fixed, tmp_path):
    d, init, _ = glonass_fixed
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and "glonass_fix" in r.stderr and str(d / "init.json") in r.stderr, r.output
    assert "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()


def test_glonass_fix_with_a_batch_only_setting_is_refused(tmp_path):
    cfg = _config(tmp_path, "glonass_fix = true", 'weighting = "equal"')
    assert run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap").exit_code == 0
    r = run_cli("-q", "init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 2 and "glonass_fix" in r.stderr and "weighting" in r.stderr, r.output
    assert "Traceback" not in r.output and not (tmp_path / "init.json").exists()


def test_glonass_fix_must_be_a_boolean(tmp_path):
    cfg = _config(tmp_path, 'glonass_fix = "yes"')
    r = run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 2 and "glonass_fix" in r.stderr and "Traceback" not in r.output, r.output
