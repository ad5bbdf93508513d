"""core/table.Table: a long table as numpy columns (a run's phase, gyro and actuator tables), and the
estimate path that reads it without pandas."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.records import Run, memory_run
from cdgps_cli.core.table import Table


@pytest.fixture(scope="module")
def static_init_for_testbed(tmp_path_factory, testbed_cfg):
    """70 s of the testbed (seed 3), its receiver log in a directory (the run's path), INIT on 0–60 s."""
    from cdgps_cli.estimation.initializer import InitOptions, initialize
    from cdgps_cli.sim.structure import SimOptions, simulate

    d = tmp_path_factory.mktemp("table_run")
    sim = simulate(testbed_cfg, SimOptions(duration_s=70.0, seed=3, phase_sigma_m=0.002))
    sim.receiver.to_csv(d / "receiver.csv", index=False)
    run = memory_run(testbed_cfg, sim.receiver, name=str(d))
    return run, initialize(run, InitOptions(start_s=0.0, duration_s=60.0))


def _frame():
    return pd.DataFrame({"time_s": [0.0, 0.0, 0.1, 0.1], "antenna": ["a2", "a1", "a2", "a1"],
                         "transmitter": pd.Categorical(["PL2", "PL1", "PL2", "PL1"]),
                         "lock": np.array([3, 4, 5, 6], dtype=np.int64), "snr_dbhz": [np.nan, 44.0, 45.0, 46.0]})


def test_frame_round_trip_keeps_columns_dtypes_and_categoricals():
    df = _frame()
    t = Table.from_frame(df)
    assert len(t) == 4 and t.columns == list(df.columns) and "antenna" in t and "x" not in t
    back = t.frame()
    pd.testing.assert_frame_equal(back, df)              # object stays object, categorical stays categorical
    assert t["antenna"].tolist() == ["a2", "a1", "a2", "a1"] and t["antenna"].dtype == object
    assert t["lock"].dtype == np.int64 and np.isnan(t["snr_dbhz"][0])


def test_codes_index_the_sorted_names_whatever_order_they_came_in():
    t = Table({"v": np.arange(4.0)}, {"n": (np.array([0, 1, 2, 0]), ["c", "a", "b"])})
    codes, words = t.codes("n")
    assert words == ("a", "b", "c") and codes.tolist() == [2, 0, 1, 2]
    assert t["n"].tolist() == ["c", "a", "b", "c"]


def test_index_in_a_vocabulary_and_names_not_in_it():
    t = Table.from_frame(_frame())
    assert t.index_in("antenna", ["a1", "a2"]).tolist() == [1, 0, 1, 0]
    assert t.index_in("transmitter", ["PL1"]).tolist() == [-1, 0, -1, 0]
    assert t.names_not_in("transmitter", ["PL1"]) == ["PL2"]
    assert t.take(np.array([False, True, False, True])).names_not_in("transmitter", ["PL1"]) == []


def test_take_keeps_names_order_and_categoricals():
    t = Table.from_frame(_frame())
    sub = t.take(np.array([3, 0]))
    assert sub.columns == t.columns and sub["antenna"].tolist() == ["a1", "a2"]
    pd.testing.assert_frame_equal(sub.frame(), _frame().iloc[[3, 0]].reset_index(drop=True))


@pytest.mark.parametrize("make, words", [
    (lambda: Table({"a": np.zeros(3), "b": np.zeros(2)}), "different lengths"),
    (lambda: Table({"a": np.zeros((3, 2))}), "not 1-D"),
    (lambda: Table({}, {"n": (np.array([0, 3]), ["x", "y"])}), "codes outside its 2 names"),
    (lambda: Table({}, {"n": (np.array([0, -1]), ["x", "y"])}), "codes outside its 2 names"),
    (lambda: Table({}, {"n": (np.array([0, 1]), ["x", "x"])}), "repeated names"),
    (lambda: Table({"a": np.zeros(2)}, order=["a", "b"]), "does not list each once"),
    (lambda: Table({"a": np.zeros(2)}, categorical=["a"]), "not name columns"),
    (lambda: Table.from_frame(pd.DataFrame({"n": ["x", None]})), "missing names in rows [1]"),
])
def test_bad_tables_are_refused_naming_the_column(make, words):
    with pytest.raises(ValueError, match=words.replace("[", r"\[").replace("]", r"\]")):
        make()


def test_missing_column_is_a_key_error_listing_the_columns():
    t = Table.from_frame(_frame())
    with pytest.raises(KeyError, match="columns: time_s, antenna"):
        t["phase"]
    with pytest.raises(KeyError, match="no name column 'lock'"):
        t.codes("lock")


def test_run_takes_frames_and_none_on_construction_and_assignment(testbed_cfg):
    run = Run("<m>", testbed_cfg, _frame(), None, None, {})
    assert isinstance(run.phase, Table) and isinstance(run.gyro, Table) and isinstance(run.actuators, Table)
    assert len(run.gyro) == 0 and run.actuators.columns == ["time_s", "actuator", "force_n"]
    run.phase = _frame().iloc[:2]
    assert isinstance(run.phase, Table) and len(run.phase) == 2
    assert len(memory_run(testbed_cfg, _frame()).phase) == 4


def test_filter_names_an_antenna_the_config_lacks(testbed_cfg, static_init_for_testbed):
    from cdgps_cli.core.errors import CdgpsError
    from cdgps_cli.estimation.filter import EstimateOptions, estimate

    run, init = static_init_for_testbed
    run = memory_run(run.cfg, run.phase)
    ph = run.phase.frame()
    ph["antenna"] = ph["antenna"].astype(str).where(ph["antenna"].astype(str) != "a2", "a9")
    run.phase = ph
    with pytest.raises(CdgpsError, match="antenna/transmitter not in the config: a9"):
        estimate(run, init, EstimateOptions())


def test_cdgps_estimate_does_not_import_pandas(tmp_path, static_init_for_testbed):
    """The estimate command's path reads the RUN, filters and writes STATES without pandas (issue 13
    item 5: importing it was a third of the time outside the filter)."""
    import json

    from cdgps_cli.io.run import write_run

    run, init = static_init_for_testbed
    sim_dir = Path(run.path)
    write_run(run.cfg, sim_dir / "receiver.csv", tmp_path / "run.mcap")
    (tmp_path / "init.json").write_text(json.dumps(init))
    code = ("import sys\nfrom cdgps_cli.cli.commands import main\n"
            f"main(['--quiet', 'estimate', {str(tmp_path / 'run.mcap')!r}, '--init', {str(tmp_path / 'init.json')!r},"
            f" '--allow-other-run', '-o', {str(tmp_path / 'states.mcap')!r}], standalone_mode=False)\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'pandas')[:3])\n")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2]))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "states.mcap").stat().st_size > 0
    assert p.stdout.strip() == "[]", p.stdout


def test_deferred_columns_are_made_on_first_use_checked_and_kept():
    from cdgps_cli.core.table import Deferred

    made = []

    def make(values):
        def f():
            made.append(len(values))
            return np.asarray(values)
        return Deferred(f)

    t = Table({"t": np.arange(4.0), "snr": make([40.0, 41.0, 42.0, 43.0])},
              {"rx": (make([1, 0, 1, 1]), ["b", "a"])})              # words not sorted: renumbered on use
    assert len(t) == 4 and made == []
    sub = t.take(np.array([True, False, True, True]))
    assert made == []                                                 # still deferred after take
    assert sub["rx"].tolist() == ["a", "a", "a"] and sub["snr"].tolist() == [40.0, 42.0, 43.0]
    assert t.codes("rx")[0].tolist() == [0, 1, 0, 0] and t.codes("rx")[1] == ("a", "b")
    assert made == [4, 4]                                             # each made once, kept
    bad_len = Table({"t": np.arange(3.0), "x": make([1.0, 2.0])})
    with pytest.raises(ValueError, match="column 'x': \\[2\\] values for 3 rows"):
        bad_len["x"]
    bad_code = Table({"t": np.arange(2.0)}, {"n": (make([0, 5]), ["a"])})
    with pytest.raises(ValueError, match="codes outside its 1 names"):
        bad_code.codes("n")
    with pytest.raises(ValueError, match="every column deferred"):
        Table({"x": make([1.0])})
