"""``glonass_fix`` through a GNSS run config (issue 28 item 3): `init` fixes the GLONASS DDs between the two
identical Septentrio mosaic-X5 receivers on the static engine and INIT carries their DD integers; `estimate`
conditions on all of INIT's integers (GPS and GLONASS) without solving again, and refuses GLONASS integers that do
not match the run's arcs; a setting only the batch solver serves is refused rather than silently leaving GLONASS
float."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.estimation import ambiguity, baseline, static_engine
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.io.states import States
from cdgps_cli.pipeline import gnss
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")
RTKLIB_MULTI_GNSS_L1_STATIC_ENU_M = np.array([-0.2238, -0.9651, 0.0079])    # the data's README


def _config(d: Path, *extra: str, signals: str = '["G:L1", "R:G1"]') -> Path:
    p = d / "run.toml"
    p.write_text("\n".join(["[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]',
                            f"signals = {signals}", *extra,
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
    assert "14 of 14 integers fixed (6 of them GLONASS DDs, glonass_fix)" in stderr
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
    assert "GLONASS (FDMA) groups fixed too (glonass_fix" in init["dd_groups"] and "groups float" not in init["dd_groups"]


def _no_solve(monkeypatch):
    """Every batch solver, the engine's integer fixing and LAMBDA raise: estimate may only condition."""
    def boom(*a, **k):
        raise AssertionError("the baseline was solved again")
    monkeypatch.setattr(gnss, "solve_static_baseline", boom)
    for name in ("solve_static_baseline", "_float_solution", "_integer_fix", "_fixed_solution", "_lambda_fix",
                 "resolve"):
        monkeypatch.setattr(baseline, name, boom)
    monkeypatch.setattr(static_engine, "static_fix", boom)
    monkeypatch.setattr(ambiguity, "resolve", boom)


def _estimate(d: Path, init: dict, name: str):
    (d / f"{name}.json").write_text(json.dumps(init))
    return run_cli("-q", "estimate", d / "run.mcap", "--init", d / f"{name}.json", "-o", d / f"{name}.mcap")


def test_estimate_conditions_on_the_glonass_integers(glonass_fixed, monkeypatch):
    """STATES are INIT's fixed baseline bit for bit (the engine's float conditioned on the 8 GPS and 6 GLONASS
    integers, as init made it), never solved again: INIT's values are evaluated (its GLONASS values agree with its
    GLONASS integers and pivots' arc values), the engine does not run, and the states equal those of the engine
    conditioned again (an INIT without those values); a GLONASS integer changed by one no longer agrees with the
    values, so the engine conditions on it, and the states move."""
    d, init, _ = glonass_fixed
    rov = init["rovers"]["rover"]
    assert sum("pivot_arc_cycles" in b for b in init["biases"]) >= 1
    with monkeypatch.context() as mp:
        _no_solve(mp)
        mp.setattr(baseline, "_run_engine", lambda *a, **k: (_ for _ in ()).throw(AssertionError("engine ran")))
        r = _estimate(d, init, "states")
        assert r.exit_code == 0, r.output
        run = read_gnss_run(d / "run.mcap")
        res, _, _, _ = gnss.solve_with_init_integers(run, init, "rover", gnss._stations(run))
    assert res["solver"] == "given (INIT's solution, its float ambiguities too)" and res["solution"] == "fixed"
    assert res["ambiguities"]["n_glonass_fixed_by_engine"] == 6 and res["ambiguities"]["n_fixed"] == 8
    st = States(d / "states.mcap")
    assert (st.q == np.array(rov["fixed"]["enu_m"])).all()                    # bit for bit, every epoch
    assert (st.sigma_q == np.array(rov["fixed"]["sigma_enu_m"])).all()
    older = json.loads(json.dumps(init))                  # an INIT without the values: the engine conditions again
    for b in older["biases"]:
        for k in ("solution_cycles", "solution_sigma_cycles", "pivot_arc_cycles"):
            b.pop(k, None)
    with monkeypatch.context() as mp:
        _no_solve(mp)
        assert _estimate(d, older, "older").exit_code == 0
        res_old, _, _, _ = gnss.solve_with_init_integers(run, older, "rover", gnss._stations(run))
    assert res_old["solver"] == "static_engine (integers given)"
    assert res_old["ambiguities"]["n_glonass_fixed_by_engine"] == 6 and res_old["solution"] == "fixed"
    np.testing.assert_allclose(States(d / "older.mcap").q, st.q, rtol=0, atol=1e-12)
    wrong = json.loads(json.dumps(init))
    next(b for b in wrong["biases"] if b.get("fixed_by_engine"))["dd_integer_cycles"] += 1
    assert _estimate(d, wrong, "wrong").exit_code == 0
    assert np.max(np.abs(States(d / "wrong.mcap").q[0] - st.q[0])) > 1e-3       # the GLONASS integers are used


def test_glonass_alone_is_fixed_and_estimate_keeps_it(tmp_path, monkeypatch):
    """GLONASS G1 alone with glonass_fix: the engine's 6 DDs make the solution fixed (it was reported float, the
    fix dropped: 82 mm from RTKLIB's G+R static), within 6 mm of RTKLIB's multi-GNSS L1 static; estimate gives it
    bit for bit without solving."""
    cfg = _config(tmp_path, "glonass_fix = true", signals='["R:G1"]')
    assert run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap").exit_code == 0
    r = run_cli("init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    assert r.exit_code == 0 and "6 of 6 integers fixed (6 of them GLONASS DDs" in r.stderr, r.stderr
    init = json.loads((tmp_path / "init.json").read_text())
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_glonass_fixed_by_engine"] == 6 and rov["accepted"]
    enu = np.asarray(rov["baseline_enu_from_master_m"])
    assert np.max(np.abs(enu - RTKLIB_MULTI_GNSS_L1_STATIC_ENU_M)) < 6e-3, enu
    with monkeypatch.context() as mp:
        _no_solve(mp)
        assert _estimate(tmp_path, init, "states").exit_code == 0
    st = States(tmp_path / "states.mcap")
    assert (st.q == np.array(rov["fixed"]["enu_m"])).all() and (st.sigma_q == np.array(rov["fixed"]["sigma_enu_m"])).all()


@pytest.mark.parametrize("edit, what", [
    (lambda b: b.update(segment_start_s=b["segment_start_s"] + 60), "no entry for R03:G1 from"),
    (lambda b: b.update(fdma_channel=b["fdma_channel"] - 1), "R03:G1 from 2024-06-24 08:20:00 GPST has FDMA channel 4"),
    (lambda b: b.update(reference="R11:G1"), "is against R11:G1 in INIT, R01:G1 in this run"),
    (lambda b: b.update(dd_integer_cycles=5.5), "dd_integer_cycles: expected an integer"),
])
def test_glonass_integers_that_do_not_match_the_run_are_refused(glonass_fixed, tmp_path, edit, what):
    d, init, _ = glonass_fixed
    bad = json.loads(json.dumps(init))
    edit(next(b for b in bad["biases"] if b["satellite"] == "R03:G1"))
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", tmp_path / "bad.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and str(tmp_path / "bad.json") in r.stderr and what in r.stderr, r.output
    assert "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()


def test_a_glonass_fix_init_written_before_it_carried_the_integers(glonass_fixed, tmp_path):
    """An INIT from before (no dd_integer_cycles) stays readable: refused with what to do, never re-solved float."""
    d, init, _ = glonass_fixed
    old = json.loads(json.dumps(init))
    for b in old["biases"]:
        for k in ("dd_integer_cycles", "fdma_channel", "reference_fdma_channel"):
            b.pop(k, None)
    (tmp_path / "old.json").write_text(json.dumps(old))
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", tmp_path / "old.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and str(tmp_path / "old.json") in r.stderr and "run 'cdgps init' again" in r.stderr
    assert "dd_integer_cycles" in r.stderr and "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()


def test_glonass_fix_with_a_batch_only_setting_is_refused(glonass_fixed):
    """A setting only the batch solver serves (since weighting = "equal" is the engine's too, and a run with
    [gnss] signals refuses epoch_alignment = "doppler", only a non-default max_iterations of the library's
    options): refused naming glonass_fix and the setting, not solved with GLONASS float."""
    from cdgps_cli.core.errors import CdgpsError
    d, _, _ = glonass_fixed
    with pytest.raises(CdgpsError, match=r"glonass_fix[\s\S]*max_iterations"):
        gnss.gnss_init(read_gnss_run(d / "run.mcap"), options={"max_iterations": 3})


def test_glonass_fix_must_be_a_boolean(tmp_path):
    cfg = _config(tmp_path, 'glonass_fix = "yes"')
    r = run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 2 and "glonass_fix" in r.stderr and "Traceback" not in r.output, r.output


def _edited_estimate(glonass_fixed, tmp_path, edit):
    """``estimate`` on a copy of the glonass_fix INIT changed by ``edit(init)``: (result, the INIT's path, STATES path)."""
    d, init, _ = glonass_fixed
    bad = json.loads(json.dumps(init))
    edit(bad)
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    out = tmp_path / "s.mcap"
    return run_cli("-q", "estimate", d / "run.mcap", "--init", tmp_path / "bad.json", "-o", out), tmp_path / "bad.json", out


def _entry(init, system, key, pivot=False):
    return next(b for b in init["biases"] if b["satellite"].startswith(system) and b["pivot"] == pivot
                and b.get(key) is not None)


@pytest.mark.parametrize("name, edit, says", [
    # an integer beyond int64 gave an OverflowError traceback (review of this session's merges)
    ("GLONASS DD beyond int64", lambda i: _entry(i, "R", "dd_integer_cycles").update(dd_integer_cycles=10**30),
     "dd_integer_cycles: expected an integer"),
    ("GPS integer beyond int64", lambda i: _entry(i, "G", "integer_cycles").update(integer_cycles=10**30),
     "integer_cycles: expected an integer"),
    # a fixed entry without its integer: estimate conditioned on 5 of 6 and moved 1.2 mm, silently
    ("fixed entry without its integer", lambda i: _entry(i, "R", "dd_integer_cycles").update(dd_integer_cycles=None),
     "missing, but the entry says fixed_by_engine"),
    # the rover's count zeroed: estimate gave the GLONASS-float baseline (1.8 mm off), silently
    ("count zeroed", lambda i: i["rovers"]["rover"].update(n_glonass_fixed_by_engine=0), "disagree"),
    ("count too large", lambda i: i["rovers"]["rover"].update(n_glonass_fixed_by_engine=99), "disagree"),
    ("pivot not 0", lambda i: _entry(i, "R", "dd_integer_cycles", pivot=True).update(dd_integer_cycles=3),
     "where it is 0 by definition"),
])
def test_an_inconsistent_glonass_fix_init_is_refused(glonass_fixed, tmp_path, name, edit, says):
    """Exit 2 naming the INIT file and what is wrong, no traceback, no STATES; never a silent GLONASS-float or
    partly conditioned solution."""
    r, path, out = _edited_estimate(glonass_fixed, tmp_path, edit)
    assert r.exit_code == 2 and str(path) in r.stderr and says in r.stderr, (name, r.output)
    assert "Traceback" not in r.output and not out.exists()


def test_glonass_only_fixed_rover_is_not_called_unfixed(tmp_path):
    """GLONASS G1 alone with glonass_fix and a random-walk rover: its 6 integers are GLONASS DDs (``n_fixed`` counts
    GPS-like integers only, 0 here); estimate must neither say that none is fixed nor count its epochs as blind
    (a review found both)."""
    cfg = _config(tmp_path, "glonass_fix = true", signals='["R:G1"]')
    text = cfg.read_text().replace('[gnss.antennas."base"]', '[gnss.displacement]\nmodel = "random_walk"\n'
                                   'sigma_m_per_sqrt_s = 0.001\n[gnss.antennas."base"]')
    cfg.write_text(text)
    assert run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap").exit_code == 0
    assert run_cli("-q", "init", tmp_path / "run.mcap", "-o", tmp_path / "init.json").exit_code == 0
    r = run_cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "-o", tmp_path / "s.mcap",
                "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    rov = s["rovers"]["rover"]
    assert rov["n_fixed"] == 0 and rov["n_fixed_with_glonass"] == 6
    assert rov["epochs_without_fixed_dd"] < 0.1 * rov["epochs"] and s["warnings"] == [], s["warnings"]
    assert "warning" not in r.stderr, r.stderr


def test_glonass_dds_a_solution_fixed_feed_the_states(tmp_path):
    """A random-walk rover with glonass_fix: estimate's states take the GLONASS DDs whose integers INIT holds, not only
    the GPS ones (they were left out: correct, but information lost) — every epoch has the GLONASS satellites' DDs
    more than with GLONASS float, the σ are smaller, and the DDs still fit (mean NIS per DoF of the same order)."""
    runs = {}
    for tag, extra in (("float", ()), ("fix", ("glonass_fix = true",))):
        d = tmp_path / tag
        d.mkdir()
        cfg = _config(d, *extra)
        cfg.write_text(cfg.read_text().replace('[gnss.antennas."base"]', '[gnss.displacement]\nmodel = "random_walk"\n'
                                               'sigma_m_per_sqrt_s = 0.001\n[gnss.antennas."base"]'))
        assert run_cli("-q", "ingest", "--config", cfg, "-o", d / "run.mcap").exit_code == 0
        assert run_cli("-q", "init", d / "run.mcap", "-o", d / "init.json").exit_code == 0
        r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "-o", d / "s.mcap", "--json")
        assert r.exit_code == 0, r.output
        runs[tag] = (json.loads(r.stdout), States(d / "s.mcap"))
    (s_float, st_float), (s_fix, st_fix) = runs["float"], runs["fix"]
    assert s_fix["rovers"]["rover"]["n_fixed_with_glonass"] > s_float["rovers"]["rover"]["n_fixed_with_glonass"]
    extra_dof = st_fix.nis_dof - st_float.nis_dof
    assert extra_dof.min() >= 0 and np.median(extra_dof) >= 3, np.unique(extra_dof)
    assert np.median(st_fix.sigma_q) < 0.9 * np.median(st_float.sigma_q)
    assert s_fix["mean_nis_per_dof"] < 3 * max(s_float["mean_nis_per_dof"], 0.3), (s_fix["mean_nis_per_dof"],
                                                                                   s_float["mean_nis_per_dof"])
