"""Wrong pairings refused (:mod:`cdgps_cli.io.file_checks`).

* ``estimate RUN --init INIT`` with an INIT made from another run: exit 2, a message naming both
  files, no output; ``--allow-other-run`` runs it and says so (stderr, --json summary, STATES
  options); the same on a GNSS run;
* every command that reads a cdgps MCAP refuses a file of the wrong kind (a STATES given where a
  RUN is expected and the reverse, a CSV given as an MCAP), saying what it expected and what it got,
  with exit 2 and nothing written;
* ``estimate --rest auto`` from the command line records its segments in STATES.
"""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.io.file_checks import (GNSS_RUN, GNSS_STATES, NOT_MCAP, STRUCTURE_RUN, STRUCTURE_STATES, check_init_run,
                                   mcap_kind)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.run import write_run
from cdgps_cli.sim.structure import SimOptions, simulate, write_simulation

from _shared import REPO_ROOT as ROOT


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def nothing_written(directory, name):
    return not (directory / name).exists() and list(directory.glob(f".{name}*")) == []


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """Two 30 s testbed runs (seeds 21, 22), each with its INIT (0–20 s) and STATES."""
    d = tmp_path_factory.mktemp("pairs")
    cfg = load_config(ROOT / "configs" / "testbed-1998-lumped.toml")
    for name, seed in (("a", 21), ("b", 22)):
        write_simulation(simulate(cfg, SimOptions(duration_s=30.0, seed=seed)), d / name)
        write_run(cfg, d / name / "receiver.csv", d / name / "run.mcap", d / name / "gyro.csv")
        r = cli("-q", "init", d / name / "run.mcap", "--start", 0, "--duration", 20, "-o", d / name / "init.json")
        assert r.exit_code == 0, r.output
        r = cli("-q", "estimate", d / name / "run.mcap", "--init", d / name / "init.json", "-o", d / name / "states.mcap")
        assert r.exit_code == 0, r.output
    return d


def test_kinds(two_runs):
    assert mcap_kind(two_runs / "a" / "run.mcap") == STRUCTURE_RUN
    assert mcap_kind(two_runs / "a" / "states.mcap") == STRUCTURE_STATES
    assert mcap_kind(two_runs / "a" / "receiver.csv") == NOT_MCAP
    with pytest.raises(CdgpsError, match="no such file"):
        mcap_kind(two_runs / "missing.mcap")


def test_init_from_another_run_refused(two_runs):
    d = two_runs
    r = cli("estimate", d / "a" / "run.mcap", "--init", d / "b" / "init.json", "-o", d / "x.mcap")
    assert r.exit_code == 2, r.output
    assert f"{d / 'b' / 'init.json'} was made from another run than {d / 'a' / 'run.mcap'}" in r.stderr
    assert "--allow-other-run" in r.stderr and "Traceback" not in r.output
    assert nothing_written(d, "x.mcap")


def test_allow_other_run_is_echoed(two_runs):
    d = two_runs
    r = cli("estimate", d / "a" / "run.mcap", "--init", d / "b" / "init.json", "--allow-other-run", "--json",
            "-o", d / "other.mcap")
    assert r.exit_code == 0, r.output
    assert "used anyway (--allow-other-run)" in r.stderr
    s = json.loads(r.stdout)
    b_sha = json.loads((d / "b" / "init.json").read_text())["run_sha256"]
    assert s["init_run"]["matches"] is False and s["init_run"]["allowed"] is True
    assert s["init_run"]["init_run_sha256"] == b_sha
    opts = json.loads(read_mcap(d / "other.mcap", topics=[]).metadata["cdgps.estimate"]["options"])
    assert opts["allow_other_run"] is True and opts["init_run_sha256"] == b_sha


def test_matching_and_unrecorded_pairings(two_runs):
    d = two_runs
    init = json.loads((d / "a" / "init.json").read_text())
    assert check_init_run(init, "i", d / "a" / "run.mcap")["matches"] is True
    init.pop("run_sha256")
    assert check_init_run(init, "i", d / "a" / "run.mcap")["matches"] is None
    with pytest.raises(CdgpsError, match="run_sha256: expected a hex string"):
        check_init_run({"run_sha256": 3}, "i", d / "a" / "run.mcap")


@pytest.mark.parametrize("make_args, out, fragment", [
    (lambda d: ("spectra", d / "a" / "states.mcap", "--gyro", d / "b" / "states.mcap", "-o", d / "o"), "o",
     f"--gyro {{b}}/states.mcap: expected a {STRUCTURE_RUN}; this file is a {STRUCTURE_STATES}"),
    (lambda d: ("report", "static", d / "a" / "states.mcap", "--gyro", d / "a" / "states.mcap", "--angle", "q6+q10",
                "-o", d / "o"), "o", f"this file is a {STRUCTURE_STATES}"),
    (lambda d: ("report", "spectrum", d / "a" / "run.mcap", "-o", d / "o"), "o",
     f"STATES_MCAP {{a}}/run.mcap: expected a {STRUCTURE_STATES} or a {GNSS_STATES}; this file is a {STRUCTURE_RUN}"),
    (lambda d: ("evaluate", "--truth", d / "a", "--estimate", d / "a" / "run.mcap"), None,
     f"--estimate {{a}}/run.mcap: expected a {STRUCTURE_STATES}"),
    (lambda d: ("export", d / "a" / "run.mcap", "--csv", d / "o.csv"), "o.csv", f"this file is a {STRUCTURE_RUN}"),
    (lambda d: ("export", d / "a" / "states.mcap", "--kinematic", "--csv", d / "o.csv"), "o.csv",
     f"expected a {GNSS_STATES}; this file is a {STRUCTURE_STATES}"),
    (lambda d: ("estimate", d / "a" / "states.mcap", "--init", d / "a" / "init.json", "-o", d / "o.mcap"), "o.mcap",
     f"RUN_MCAP {{a}}/states.mcap: expected a {STRUCTURE_RUN} or a {GNSS_RUN}; this file is a {STRUCTURE_STATES}"),
    (lambda d: ("init", d / "a" / "states.mcap", "-o", d / "o.json"), "o.json", f"this file is a {STRUCTURE_STATES}"),
    (lambda d: ("spectra", d / "a" / "receiver.csv", "-o", d / "o"), "o", f"this file is {NOT_MCAP}"),
])
def test_wrong_kind_refused(two_runs, make_args, out, fragment):
    d = two_runs
    r = cli(*make_args(d))
    assert r.exit_code == 2, r.output
    assert fragment.format(a=d / "a", b=d / "b") in r.stderr, r.stderr
    assert "Traceback" not in r.output
    if out:
        assert nothing_written(d, out)


def test_library_readers_refuse_the_other_kind(two_runs):
    from cdgps_cli.io.run import read_run
    from cdgps_cli.io.states import States

    with pytest.raises(CdgpsError, match="is a STATES.mcap"):
        read_run(two_runs / "a" / "states.mcap", phase=False)
    with pytest.raises(CdgpsError, match="is a RUN.mcap"):
        States(two_runs / "a" / "run.mcap")


def test_gnss_init_from_another_run_refused(tmp_path):
    d = tmp_path
    assert cli("-q", "simulate-gnss", "--duration", "60", "--seed", "1", "--out", d / "g").exit_code == 0
    for args in (("ingest", "--config", d / "g" / "config.toml", "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "-o", d / "init.json")):
        r = cli("-q", *args)
        assert r.exit_code == 0, r.output
    assert mcap_kind(d / "run.mcap") == GNSS_RUN
    init = json.loads((d / "init.json").read_text())
    init["run_sha256"] = "0" * 64                     # as if made from another run
    (d / "other.json").write_text(json.dumps(init))
    r = cli("estimate", d / "run.mcap", "--init", d / "other.json", "-o", d / "s.mcap")
    assert r.exit_code == 2 and f"{d / 'other.json'} was made from another run than {d / 'run.mcap'}" in r.stderr
    assert nothing_written(d, "s.mcap")
    r = cli("-q", "estimate", d / "run.mcap", "--init", d / "other.json", "--allow-other-run", "-o", d / "s.mcap")
    assert r.exit_code == 0, r.output
    assert mcap_kind(d / "s.mcap") == GNSS_STATES
    opts = json.loads(read_mcap(d / "s.mcap", topics=[]).metadata["cdgps.estimate"]["options"])
    assert opts["allow_other_run"] is True and opts["init_run_sha256"] == "0" * 64
    r = cli("spectra", d / "s.mcap", "--gyro", d / "run.mcap", "-o", d / "sp")
    assert r.exit_code == 2 and f"this file is a {GNSS_RUN}" in r.stderr and nothing_written(d, "sp")


def test_cli_rest_auto_recorded(two_runs):
    d = two_runs
    r = cli("estimate", d / "a" / "run.mcap", "--init", d / "a" / "init.json", "--rest", "auto", "--json",
            "-o", d / "auto.mcap")
    assert r.exit_code == 0, r.output
    meta = read_mcap(d / "auto.mcap", topics=[]).metadata["cdgps.estimate"]
    opts = json.loads(meta["options"])
    assert opts["rest_auto"] is True and opts["rest_window_s"] == 3.0 and opts["rest_dwell_s"] == 2.0
    det = json.loads(meta["rest_detection"])
    assert det["window_s"] == pytest.approx(3.0) and isinstance(det["segments_s"], list)
    # free vibration: no rest found, the filter never in static mode
    assert det["segments_s"] == [] and json.loads(meta["rest_active_s"]) == []
    r = cli("estimate", d / "a" / "run.mcap", "--init", d / "a" / "init.json", "--rest", "auto", "--rest", "10:",
            "-o", d / "bad.mcap")
    assert r.exit_code == 2 and "cannot be combined" in r.stderr and nothing_written(d, "bad.mcap")
    r = cli("estimate", d / "a" / "run.mcap", "--init", d / "a" / "init.json", "--rest", "auto", "--rest-window-s", "0",
            "-o", d / "bad.mcap")
    assert r.exit_code == 2 and "--rest-window-s" in r.stderr and nothing_written(d, "bad.mcap")


def test_refuse_deep_json_names_the_file_line_and_what_was_expected(tmp_path):
    from cdgps_cli.io.file_checks import MAX_JSON_DEPTH, refuse_deep_json

    refuse_deep_json('{"a": [[1], {"b": "[[[[[[["}]}', "x.json", "X")       # brackets in strings do not count
    refuse_deep_json("[" * MAX_JSON_DEPTH + "]" * MAX_JSON_DEPTH, "x.json", "X")
    with pytest.raises(CdgpsError, match=r"^x\.json, line 2: JSON nested deeper than 64 levels; expected a GAINS\.json$"):
        refuse_deep_json("{\n" + "[" * 10_000 + "]" * 10_000 + "}", "x.json", "a GAINS.json")


def test_a_track_file_is_named_as_one(tmp_path):
    """``export``/``init`` on a TRACK.mcap said "an MCAP file without cdgps metadata (not written by 'cdgps ingest' or
    'cdgps estimate')" although 'cdgps track' wrote it with its metadata (a sweep)."""
    from cdgps_cli.io.file_checks import mcap_kind
    from cdgps_cli.io.mcap import McapOut

    p = tmp_path / "track.mcap"
    with McapOut(p) as out:
        out.metadata("track", {"prn": "1"})
    assert mcap_kind(p).startswith("TRACK.mcap of receiver tracking loops (from 'cdgps track'")
