"""`cdgps estimate RUN --init A --init B …` on a GNSS run (issue 29): INITs of windows of one record, each serving its
own window (read and solved alone, its rows on disk until the residual pass), into one STATES; the random walk and
the constant velocity filtered over all the windows (each starts from the previous one's last state, predicted over
the seam) and smoothed over all of them.

The independent check: the whole record's estimate from the whole record's INIT.  Where the windows' integers are
the whole record's, the two estimates differ only by where each INIT evaluated the rover's troposphere and its static
solution (the linearisation point): states within 1 µm, σ within 1e-8 relative.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.io.states import States
from tests._shared import REPO_ROOT, run_cli

DURATION_S = 900.0


def _cli_ok(*args):
    r = run_cli(*args)
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module", params=["random_walk", "constant_velocity"])
def record(request, tmp_path_factory):
    """A simulated random-walking rover at 1 Hz with slips; its RUN, the whole record's INIT and two windows'."""
    d = tmp_path_factory.mktemp(f"win-{request.param}")
    _cli_ok("-q", "simulate-gnss", "--duration", DURATION_S, "--rate-hz", "1", "--random-walk", "0.002",
            "--slips", "4", "--seed", "7", "-o", d / "sim")
    cfg = d / "sim" / "config.toml"
    cfg.write_text(cfg.read_text().replace('model = "static"', f'model = "{request.param}"'))
    _cli_ok("-q", "ingest", "--config", cfg, "-o", d / "run.mcap")
    _cli_ok("-q", "init", d / "run.mcap", "-o", d / "whole.json")
    _cli_ok("-q", "init", d / "run.mcap", "--start", "0", "--duration", "450", "-o", d / "w1.json")
    _cli_ok("-q", "init", d / "run.mcap", "--start", "450", "--duration", "450", "-o", d / "w2.json")
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", d / "whole.json", "--smooth", "-o", d / "whole.mcap")
    return d, request.param


def test_two_windows_give_the_whole_records_states(record):
    d, model = record
    r = _cli_ok("estimate", d / "run.mcap", "--init", d / "w2.json", "--init", d / "w1.json", "--smooth",
                "-o", d / "two.mcap", "--json")
    assert "2 windows" in r.stderr and "next window (INIT)" in r.stderr
    s = json.loads(r.stdout)
    assert s["windows"] == 2 and s["epochs"] == DURATION_S
    whole, two = States(d / "whole.mcap"), States(d / "two.mcap")
    assert two.time_s.tobytes() == whole.time_s.tobytes()
    assert np.max(np.abs(two.q - whole.q)) < 1e-6
    assert np.max(np.abs(two.sigma_q / whole.sigma_q - 1.0)) < 1e-8
    assert abs(np.nanmean(two.nis) - np.nanmean(whole.nis)) < 1e-4 * np.nanmean(whole.nis)
    # each window's integers and static solution: the metadata lists both, the totals add up
    rov = json.loads(two.metadata["rovers"])["rover"]
    assert [w["init"] for w in rov["windows"]] == [str(d / "w1.json"), str(d / "w2.json")]
    assert rov["n_fixed"] == sum(w["n_fixed"] for w in rov["windows"]) and rov["epochs"] == DURATION_S
    assert len(json.loads(two.metadata["init_windows"])) == 2
    assert not list(d.glob(".cdgps-estimate-*"))                 # the windows' rows: removed with the command


def test_without_smoothing_the_forward_filter_runs_on(record):
    """Filtered only: the second window's first states come from the first window's filter, not from a fresh start
    (whose σ would be the initial 10 m): they equal the whole record's forward filter."""
    d, _ = record
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", d / "w1.json", "--init", d / "w2.json", "-o", d / "f2.mcap")
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", d / "whole.json", "-o", d / "f1.mcap")
    a, b = States(d / "f1.mcap"), States(d / "f2.mcap")
    assert np.max(np.abs(a.q - b.q)) < 1e-6 and np.max(np.abs(b.sigma_q / a.sigma_q - 1.0)) < 1e-8


def test_a_glob_and_a_gap_between_windows(record, tmp_path):
    """Windows named by a pattern, in time order whatever their names; a gap of 100 s between two windows is
    predicted over (the σ after the gap above the σ before it, the filtered states)."""
    d, _ = record
    for name, start, dur in (("b", "0", "300"), ("a", "400", "500")):
        _cli_ok("-q", "init", d / "run.mcap", "--start", start, "--duration", dur, "-o", tmp_path / f"g_{name}.json")
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", str(tmp_path / "g_*.json"), "-o", tmp_path / "gap.mcap")
    st = States(tmp_path / "gap.mcap")
    t = st.time_s - st.time_s[0]
    assert st.q.shape[0] == 800 and not np.any((t >= 300) & (t < 400))
    before, after = np.flatnonzero(t < 300)[-1], np.flatnonzero(t >= 400)[0]
    assert np.all(st.sigma_q[after] > st.sigma_q[before])


def test_the_static_model_is_each_windows_own_solution(tmp_path):
    _cli_ok("-q", "simulate-gnss", "--duration", "400", "--rate-hz", "1", "--seed", "3", "-o", tmp_path / "sim")
    _cli_ok("-q", "ingest", "--config", tmp_path / "sim" / "config.toml", "-o", tmp_path / "run.mcap")
    for k in (0, 1):
        _cli_ok("-q", "init", tmp_path / "run.mcap", "--start", 200 * k, "--duration", "200", "-o", tmp_path / f"i{k}.json")
    _cli_ok("-q", "estimate", tmp_path / "run.mcap", "--init", tmp_path / "i0.json", "--init", tmp_path / "i1.json",
            "-o", tmp_path / "s.mcap")
    st = States(tmp_path / "s.mcap")
    assert not np.array_equal(st.q[0], st.q[200])                # two static solutions, one per window
    for k, rows in ((0, slice(0, 200)), (1, slice(200, 400))):
        enu = json.loads((tmp_path / f"i{k}.json").read_text())["rovers"]["rover"]["baseline_enu_from_master_m"]
        static = json.loads(st.metadata["rovers"])["rover"]["windows"][k]["static_enu_m"]
        assert np.allclose(st.q[rows], list(static.values()), rtol=0, atol=0)
        assert np.all(np.isfinite(enu))


def test_windows_that_overlap_or_a_whole_record_init_are_refused(record, tmp_path):
    d, _ = record
    _cli_ok("-q", "init", d / "run.mcap", "--start", "400", "--duration", "100", "-o", tmp_path / "o.json")
    out = tmp_path / "x.mcap"
    r = run_cli("estimate", d / "run.mcap", "--init", d / "w1.json", "--init", tmp_path / "o.json", "-o", out)
    assert r.exit_code == 2 and "overlap" in r.output and "w1.json" in r.output and "o.json" in r.output
    r = run_cli("estimate", d / "run.mcap", "--init", d / "w1.json", "--init", d / "whole.json", "-o", out)
    assert r.exit_code == 2 and "whole.json" in r.output and "whole record" in r.output
    r = run_cli("estimate", d / "run.mcap", "--init", str(tmp_path / "nothing_*.json"), "-o", out)
    assert r.exit_code == 2 and "matches no file" in r.output
    r = run_cli("estimate", d / "run.mcap", "--init", d / "w1.json", "--init", d / "w2.json", "--structure",
                REPO_ROOT / "configs" / "gnss-tower.toml", "-o", out)
    assert r.exit_code == 2 and "several INITs" in r.output
    assert not out.exists() and "Traceback" not in r.output


def test_a_fast_records_json_channels_are_a_filtered_1_hz_preview(tmp_path):
    """A 10 Hz record's Foxglove channels at 1 Hz, low-pass filtered before decimation (a day of JSON messages at
    10 Hz took 390 MiB more to write); the packed arrays that cdgps reads keep every epoch.  A 1 Hz record keeps
    its JSON channels at every epoch."""
    from cdgps_cli.io.mcap import read_mcap
    from cdgps_cli.io.states import ESTIMATE_METADATA, STATE_TOPIC

    _cli_ok("-q", "simulate-gnss", "--duration", "30", "--rate-hz", "10", "--seed", "2", "-o", tmp_path / "sim")
    _cli_ok("-q", "ingest", "--config", tmp_path / "sim" / "config.toml", "-o", tmp_path / "run.mcap")
    _cli_ok("-q", "init", tmp_path / "run.mcap", "-o", tmp_path / "init.json")
    _cli_ok("-q", "estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "-o", tmp_path / "s.mcap")
    c = read_mcap(tmp_path / "s.mcap", topics=[STATE_TOPIC])
    meta = c.metadata[ESTIMATE_METADATA]
    assert meta["json_channels_every_epochs"] == "10" and "low-pass" in meta["json_channels_filter"]
    assert len(c.topics[STATE_TOPIC].times()) == 30 and States(tmp_path / "s.mcap").q.shape[0] == 300


@pytest.fixture(scope="module")
def two_rovers(tmp_path_factory):
    """The GNSS tower's two rovers (random walk, 1 Hz, 121 epochs) with the whole record's INIT and two windows' (the
    first minute, and the rest)."""
    d = tmp_path_factory.mktemp("win-tower")
    _cli_ok("-q", "simulate-gnss-structure", REPO_ROOT / "configs" / "gnss-tower.toml", "--duration", "120", "-o", d / "sim")
    _cli_ok("-q", "ingest", "--config", d / "sim" / "config.toml", "-o", d / "run.mcap")
    _cli_ok("-q", "init", d / "run.mcap", "-o", d / "whole.json")
    _cli_ok("-q", "init", d / "run.mcap", "--start", "0", "--duration", "60", "-o", d / "w0.json")
    _cli_ok("-q", "init", d / "run.mcap", "--start", "60", "-o", d / "w1.json")          # (to the record's end)
    return d


def test_two_rovers_over_two_windows(two_rovers):
    d = two_rovers
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", d / "whole.json", "--smooth", "-o", d / "whole.mcap")
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", d / "w0.json", "--init", d / "w1.json", "--smooth",
            "-o", d / "two.mcap")
    a, b = States(d / "whole.mcap"), States(d / "two.mcap")
    assert a.coord_names == b.coord_names == ["r1_e", "r1_n", "r1_u", "r2_e", "r2_n", "r2_u"]
    assert b.time_s.size == 121 and np.array_equal(a.time_s, b.time_s)
    assert np.max(np.abs(a.q - b.q)) < 1e-6 and np.max(np.abs(b.sigma_q / a.sigma_q - 1.0)) < 1e-6


def test_an_output_directory_is_made_and_a_failing_window_is_named(two_rovers, tmp_path):
    d = two_rovers
    out = tmp_path / "not" / "yet" / "s.mcap"
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", str(d / "w[01].json"), "-o", out)
    assert out.exists() and [p.name for p in out.parent.iterdir()] == ["s.mcap"]   # (scratch files: unlinked)
    late = json.loads((d / "w1.json").read_text())
    late["window"] = dict(late["window"], start_gps_s=late["window"]["start_gps_s"] + 1e5,
                          end_gps_s=late["window"]["end_gps_s"] + 1e5)
    (tmp_path / "late.json").write_text(json.dumps(late))
    r = run_cli("estimate", d / "run.mcap", "--init", d / "w0.json", "--init", tmp_path / "late.json",
                "--allow-other-run", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and f"{tmp_path / 'late.json'}:" in r.output and "Traceback" not in r.output, r.output
    assert not (tmp_path / "x.mcap").exists()


def test_windows_whose_rover_is_placed_apart_are_refused(two_rovers, tmp_path):
    """Each window's states are offsets from the rover's nominal position: INITs that placed it differently (a rover
    without a position of its own, placed by each window's pseudoranges) would jump at the seam."""
    d = two_rovers
    moved = json.loads((d / "w1.json").read_text())
    moved["rovers"]["r2"]["nominal_ecef_m"] = [v + 2.0 for v in moved["rovers"]["r2"]["nominal_ecef_m"]]
    (tmp_path / "moved.json").write_text(json.dumps(moved))
    r = run_cli("estimate", d / "run.mcap", "--init", d / "w0.json", "--init", tmp_path / "moved.json",
                "--allow-other-run", "-o", tmp_path / "x.mcap")
    assert r.exit_code == 2 and "moved.json" in r.output and "rover r2's nominal position differs" in r.output


def test_a_window_without_fixed_integers_is_warned_about_by_name(record, tmp_path):
    """A window whose INIT fixed nothing (one epoch) among fixed ones: its warning names its INIT (the totals over
    the windows hid it)."""
    d, _ = record
    for name, start, dur in (("a", "0", "300"), ("b", "300", "1"), ("c", "301", "299")):
        _cli_ok("-q", "init", d / "run.mcap", "--start", start, "--duration", dur, "-o", tmp_path / f"{name}.json")
    one = json.loads((tmp_path / "b.json").read_text())["rovers"]["rover"]
    if one["n_fixed"]:
        pytest.skip(f"the one-epoch window fixed {one['n_fixed']} integers here")
    r = _cli_ok("estimate", d / "run.mcap", "--init", str(tmp_path / "[abc].json"), "-o", tmp_path / "s.mcap", "--json")
    warnings = json.loads(r.stdout)["warnings"]
    assert any(w.startswith(f"{tmp_path / 'b.json'}: rover: none of its") for w in warnings), warnings
    assert not any(str(tmp_path / "a.json") in w or str(tmp_path / "c.json") in w for w in warnings)


def test_phase_noise_auto_is_said_once_per_rover_with_the_windows_range(tmp_path):
    _cli_ok("-q", "simulate-gnss", "--duration", "300", "--rate-hz", "1", "--random-walk", "0.002", "--seed", "4",
            "-o", tmp_path / "sim")
    cfg = tmp_path / "sim" / "config.toml"
    cfg.write_text(cfg.read_text().replace('model = "static"', 'model = "random_walk"')
                   .replace('# phase_noise = "auto"', 'phase_noise = "auto"'))
    _cli_ok("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    for k in (0, 1, 2):
        _cli_ok("-q", "init", tmp_path / "run.mcap", "--start", 100 * k, "--duration", "100", "-o", tmp_path / f"i{k}.json")
    r = _cli_ok("estimate", tmp_path / "run.mcap", "--init", str(tmp_path / "i?.json"), "-o", tmp_path / "s.mcap", "--json")
    notes = [n for n in json.loads(r.stdout)["notes"] if "phase_noise" in n]
    assert len(notes) == 1 and "over its 3 windows" in notes[0], notes
    rov = json.loads(States(tmp_path / "s.mcap").metadata["rovers"])["rover"]
    assert len({w["phase_noise"]["factor"] for w in rov["windows"]}) == 3          # each window its own factor


def test_the_run_report_names_every_windows_init(record, tmp_path):
    """``report run`` on a STATES from several INITs: the first window's INIT as the attached one, then every window's
    INIT (file, window, sha256) and each window's integers (it showed the first window's alone)."""
    import hashlib
    import html
    import re

    d, model = record
    if model != "random_walk":
        pytest.skip("one displacement model is enough for the page")
    _cli_ok("-q", "estimate", d / "run.mcap", "--init", d / "w1.json", "--init", d / "w2.json", "-o", tmp_path / "s.mcap")
    _cli_ok("-q", "report", "run", tmp_path / "s.mcap", "-o", tmp_path / "page")
    text = re.sub(r"<[^>]+>", " ", html.unescape((tmp_path / "page" / "index.html").read_text()))
    assert "INIT.json of the first window (attached to the STATES)" in text
    sha = [hashlib.sha256((d / f"w{k}.json").read_bytes()).hexdigest()[:12] for k in (1, 2)]
    assert re.search(rf"the 2 windows' INITs \(init_windows.json attached\)\s+1\. w1\.json, window from 0 s for 450 s, "
                     rf"sha256 {sha[0]}…; 2\. w2\.json, window from 450 s for 450 s, sha256 {sha[1]}…", text)
    assert re.search(r"Integers \(each window's INIT\): rover: w1\.json \w[\w ]* \(\d+ of \d+\), w2\.json", text)
