"""``init`` on the real mosaic pair edited as receivers damage their logs (the adversarial sweep of session 20).

* A rover whose time tags sit 30 ms after the second (its clock 30 ms off, the ranges with it, as a receiver that
  does not steer its clock writes them): every epoch was dropped ("no common epochs … within 30 s") while ``rtk``
  bridged every one; in the default "geometry" alignment an epoch up to a third of the step off its grid time is
  now labelled with it (model/gps/epoch_align.align_receiver), each receiver's geometry evaluated at its own
  reception instant as before: the solution is the unedited pair's.
* A slip the receiver did not flag: the static solution went decimetres off with sub-millimetre σ; the change of
  the phases from epoch to epoch now finds it and a new ambiguity starts there (static_engine.unflagged_slips).
"""

from __future__ import annotations

import json

import numpy as np

import pytest

from cdgps_cli.sim.rinex_edit import edit_rinex3_obs
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _init(d, rover, tag: str) -> dict:
    for args in (("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                  MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1", "-o", d / f"{tag}.toml"),
                 ("ingest", "--config", d / f"{tag}.toml", "-o", d / f"{tag}.mcap"),
                 ("init", d / f"{tag}.mcap", "-o", d / f"{tag}.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args[0], r.output)
    return json.loads((d / f"{tag}.json").read_text())


@pytest.fixture(scope="module")
def unedited(tmp_path_factory) -> dict:
    """INIT.json of the unedited mosaic pair on G:L1 (:func:`_init`), made once for the tests comparing with it."""
    return _init(tmp_path_factory.mktemp("unedited"), MOSAIC / "rover.obs", "ref")


def test_a_rover_30_ms_off_the_second_gives_the_same_solution(unedited, tmp_path):
    late = tmp_path / "rover_late.obs"
    late.write_text(edit_rinex3_obs((MOSAIC / "rover.obs").read_text(), clock_offset_s=lambda t: 0.030))
    ref, got = unedited, _init(tmp_path, late, "late")
    assert got["rovers"]["rover"]["n_fixed"] == ref["rovers"]["rover"]["n_fixed"] > 0
    assert got["rovers"]["rover"]["epochs"]["n_epochs_used"] == ref["rovers"]["rover"]["epochs"]["n_epochs_used"] == 301
    for k, v in ref["states"].items():
        assert got["states"][k] == pytest.approx(v, abs=2e-4), k


def _slip(text: str, sat: str, code: str, from_epoch: int, cycles: float, *, flagged: bool = False) -> str:
    """The RINEX 3 text with ``sat``'s ``code`` phase (e.g. "L1C") moved by ``cycles`` from epoch ``from_epoch`` on,
    without a loss-of-lock flag (a slip the receiver did not report), or with ``flagged`` the loss of lock flagged
    (LLI bit 0) at that epoch."""
    lines = text.splitlines()
    types = {}
    for ln in lines:
        if ln[60:].strip() == "SYS / # / OBS TYPES" and ln[0] != " ":
            types[ln[0]] = ln[7:58].split()
        elif ln[60:].strip() == "SYS / # / OBS TYPES":
            types[list(types)[-1]] += ln[7:58].split()
        if ln[60:].strip() == "END OF HEADER":
            break
    k = types[sat[0]].index(code)
    a, e = 3 + 16 * k, -1
    out = []
    for ln in lines:
        if ln.startswith(">"):
            e += 1
        elif e >= from_epoch and ln.startswith(sat) and ln[a:a + 14].strip():
            lli = "1" if flagged and e == from_epoch else ln[a + 14:a + 15]
            ln = ln[:a] + f"{float(ln[a:a + 14]) + cycles:14.3f}" + lli + ln[a + 15:]
        out.append(ln)
    return "\n".join(out) + "\n"


def test_a_slip_no_receiver_flagged_is_found_and_starts_an_arc(tmp_path, monkeypatch):
    """An unflagged one-cycle slip of G05 L1 from the middle of the real mosaic rover: init's static fix went 0.8 m
    off with sub-millimetre σ (session 20: only a misfit warning).  The epoch-to-epoch change of the phases now finds
    it (static_engine.unflagged_slips; its residual 0.148 m at 6σ and 3 cm thresholds), a new ambiguity starts
    there, and the solution is the unedited pair's (within 0.1 mm; one integer more), with a warning naming the
    channel and time; the unedited pair has no such warning.  estimate cuts its segments where INIT did."""
    slipped = tmp_path / "rover_slip.obs"
    slipped.write_text(_slip((MOSAIC / "rover.obs").read_text(), "G05", "L1C", 150, 1.0))
    got = {}
    for rover, tag in ((MOSAIC / "rover.obs", "ref"), (slipped, "slip")):
        r = run_cli("-q", "config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                    MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / f"{tag}.toml")
        assert r.exit_code == 0, r.output
        r = run_cli("-q", "ingest", "--config", tmp_path / f"{tag}.toml", "-o", tmp_path / f"{tag}.mcap")
        assert r.exit_code == 0, r.output
        r = run_cli("init", tmp_path / f"{tag}.mcap", "-o", tmp_path / f"{tag}.json")
        assert r.exit_code == 0, r.output
        found = [ln for ln in r.stderr.splitlines() if "that no receiver flagged" in ln]
        misfit = [ln for ln in r.stderr.splitlines() if "does not fit" in ln or "were rejected" in ln]
        got[tag] = json.loads((tmp_path / f"{tag}.json").read_text())
        assert not misfit, misfit
        if tag == "ref":
            assert not found, found
        else:
            assert len(found) == 1 and "1 cycle slip(s)" in found[0] and "G05:L1 at 2024-06-24 08:22:30" in found[0]
    ref, slip = got["ref"]["rovers"]["rover"], got["slip"]["rovers"]["rover"]
    assert slip["solution"] == ref["solution"] == "fixed" and slip["n_fixed"] == ref["n_fixed"] + 1
    for k, v in got["ref"]["states"].items():
        assert got["slip"]["states"][k] == pytest.approx(v, abs=1e-4), k
    # estimate takes INIT's arcs, the one cut where no flag was, as these data's segments (it refused them before),
    # and its events say what started that one
    import cdgps_cli.pipeline.gnss as gnss
    seen, events = [], gnss._events
    monkeypatch.setattr(gnss, "_events", lambda *a, **k: seen.extend(events(*a, **k)) or seen)
    r = run_cli("estimate", tmp_path / "slip.mcap", "--init", tmp_path / "slip.json", "-o", tmp_path / "slip_states.mcap",
                "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["mean_nis_per_dof"] < 1.0                          # measured 0.16
    g05 = [e for e in seen if e["transmitter"] == "G05:L1" and "no receiver flagged" in e["kind"]]
    assert len(g05) == 1 and g05[0]["action"].startswith("new ambiguity"), [e for e in seen if "G05" in e["transmitter"]]


def test_a_rover_header_100_km_off_is_not_taken_for_the_rover(unedited, tmp_path):
    """A rover header's APPROX POSITION XYZ 100 km off: init took the pair for a 100 km baseline and refused it
    (exit 2); a header farther than baseline.HEADER_POSITION_TOL_M from the rover's single-point position is now
    said and not used, and the integers are the unedited pair's."""
    text = (MOSAIC / "rover.obs").read_text().splitlines()
    i = next(k for k, ln in enumerate(text) if ln[60:].strip() == "APPROX POSITION XYZ")
    x, y, z = (float(v) for v in text[i][:60].split())
    text[i] = f"{x + 100e3:14.4f}{y:14.4f}{z:14.4f}" + text[i][42:]
    far = tmp_path / "rover_far.obs"
    far.write_text("\n".join(text) + "\n")
    ref, got = unedited, _init(tmp_path, far, "far")
    assert got["rovers"]["rover"]["n_fixed"] == ref["rovers"]["rover"]["n_fixed"] > 0
    assert any("is 100 km from its pseudorange single-point position" in w for w in got["rovers"]["rover"]["warnings"])
    assert not any("single-point position" in w for w in ref["rovers"]["rover"]["warnings"])
    sol = [np.asarray(d["rovers"]["rover"]["rover_ecef_m"]) for d in (ref, got)]
    assert np.linalg.norm(sol[0] - sol[1]) < 1e-3


def test_a_clock_jump_in_the_codes_alone_gives_the_same_solution(tmp_path, monkeypatch):
    """The real mosaic rover from its middle as a receiver whose clock is reset by 1 ms with its carrier kept
    continuous (session 20's D3 on the M8P pair): the signals are received 1 ms before their tags, every range takes
    its change over 1 ms (from the Doppler) and the codes 299.8 km more.  The DDs do not see the step, but the arcs'
    prior (each arc at its first (phase − code)/λ, σ 30 cycles) put every arc begun after it 1.6·10⁶ cycles from
    those before: the M8P pair's float went 0.5 m off and its fix was rejected.  The step is now taken out of the
    codes (measurement/code_steps): the solution is the unedited pair's; with the step left in, it is not.
    ``rtk`` on the same files fixes the unedited pair's epochs (it fixed 431 of 1201 on the M8P pair, 1156 unedited)."""
    from cdgps_cli.estimation import static_engine
    from cdgps_cli.sim.rinex_edit import epoch_times_gps_s
    text = (MOSAIC / "rover.obs").read_text()
    for sat in ("G05", "G13", "G15"):             # lock lost (flagged) after the jump: arcs begun after it
        text = _slip(text, sat, "L1C", 200, 7.0, flagged=True)
    mid = float(np.median(epoch_times_gps_s(text)))
    (tmp_path / "rover_lli.obs").write_text(text)
    jumped = tmp_path / "rover_jump.obs"
    jumped.write_text(edit_rinex3_obs(text, code_clock_s=lambda t: 1e-3 if t >= mid else 0.0))
    ref, got = _init(tmp_path, tmp_path / "rover_lli.obs", "ref"), _init(tmp_path, jumped, "jump")
    assert got["rovers"]["rover"]["n_fixed"] == ref["rovers"]["rover"]["n_fixed"] > 0
    said = [w for w in got["rovers"]["rover"]["warnings"] if "codes stepped while the phases did not" in w]
    assert len(said) == 1 and "+299.792 km (+1.0000 ms) in G:L1" in said[0], got["rovers"]["rover"]["warnings"]
    assert not any("codes stepped" in w for w in ref["rovers"]["rover"]["warnings"])
    for k, v in ref["states"].items():
        assert got["states"][k] == pytest.approx(v, abs=2e-4), k
    monkeypatch.setattr(static_engine, "without_code_steps", lambda rows, *a: (rows, {
        "code": np.zeros(0, np.int64), "epoch": np.zeros(0, np.int64), "step_m": np.zeros(0)}))
    left = _init(tmp_path, jumped, "left")
    off = max(abs(left["states"][k] - v) for k, v in ref["states"].items())
    assert off > 1.0, off                         # measured 4.6 m, 2 of 11 integers fixed
    monkeypatch.undo()
    fixed = {}
    for tag, rover in (("ref", tmp_path / "rover_lli.obs"), ("jump", jumped)):
        r = run_cli("rtk", "--base", MOSAIC / "base.obs", "--rover", rover, "--nav", MOSAIC / "base.nav", "--signals",
                    "G:L1", "-o", tmp_path / f"{tag}.pos", "--json")
        assert r.exit_code == 0, r.output
        fixed[tag] = json.loads(r.stdout)
    assert fixed["jump"]["fixed_epochs"] == fixed["ref"]["fixed_epochs"] > 250
    assert fixed["jump"]["code_clock_steps"]["step_m"] == [pytest.approx(299792.458, abs=1.0)]
    assert any("codes stepped while the phases did not" in w for w in fixed["jump"]["warnings"])
    assert fixed["ref"]["code_clock_steps"]["step_m"] == []
