"""STATES.mcap files written by main before the one writer (tests/data/format-2026-12-03, made with
main's code at 0edc5a9 by the commands in its README) are still read, with the numbers today's
code computes from the same RUN and INIT:

* a structure estimate (packed arrays, no ``states.json``: described by its ``config.toml``);
* a GNSS displacement estimate (every epoch as ``.npy`` and JSON, the displacement model faked as a
  structure ``config.toml``): read as kind ``displacement`` without a structure config, and
  ``export``, ``export --kinematic`` and ``evaluate`` give the same results on it as on today's file;
* a structure on a GNSS run (``estimate --structure``, GPS time).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.states import STATE_FILTERED_TOPIC, STATE_TOPIC, States
from tests._machine import CROSS_MACHINE_RTOL, assert_json_close

ROOT = Path(__file__).resolve().parents[2]
FMT = ROOT / "tests" / "data" / "format-2026-12-03"
RUN_0212 = ROOT / "tests" / "data" / "format-2026-12-02"
KIN = "/cdgps/kinematic"


def cli(*args) -> str:
    r = CliRunner().invoke(main, ["-q", *[str(a) for a in args]])
    assert r.exit_code == 0, r.output
    return r.output


def _close(a, b, name) -> None:
    """Floats computed today against those stored: the cross-machine float tolerance (relative
    ``CROSS_MACHINE_RTOL`` plus as much of the largest magnitude; tests/_machine.py), since the stored
    numbers were made with other code on another machine (the engine's random-walk filter moved them
    by 1e-15; another CPU by up to 8e-8 relative)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    atol = CROSS_MACHINE_RTOL * float(np.nanmax(np.abs(b))) if b.size and np.isfinite(b).any() else 0.0
    np.testing.assert_allclose(a, b, rtol=CROSS_MACHINE_RTOL, atol=atol, equal_nan=True, err_msg=name)


def _same_series(new: States, old: States, topic: str) -> None:
    """The same numbers in both files within round-off (:func:`_close`); the same epochs; the forward
    filter of a smoothed run keeps its 1-σ only by default today (main's GNSS files held its P_ξ too)."""
    np.testing.assert_array_equal(new.time_s, old.time_s)
    for field in ("q", "sigma_q", "xi", "P_xi", "nis", "nis_dof"):
        a, b = getattr(new, field), getattr(old, field)
        if field == "P_xi" and topic == STATE_FILTERED_TOPIC and a is None:
            continue
        assert (a is None) == (b is None), field
        if a is not None:
            _close(a, b, field)


def test_structure_states_of_main(tmp_path):
    path = FMT / "structure-states.mcap"
    assert "states.json" not in read_mcap(path, topics=[]).attachments
    for name in ("run.mcap", "init.json"):
        shutil.copy(RUN_0212 / name, tmp_path / name)
    cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--smooth", "-o", tmp_path / "new.mcap")
    cli("estimate", tmp_path / "run.mcap", "--init", tmp_path / "init.json", "--smooth", "--covariance", "full",
        "-o", tmp_path / "full.mcap")
    for topic in (STATE_TOPIC, STATE_FILTERED_TOPIC):
        old, new = States(path, topic=topic), States(tmp_path / "new.mcap", topic=topic)
        assert old.kind == new.kind == "structure" and old.cfg.sha256 == new.cfg.sha256
        assert old.coord_names == new.coord_names and old.n_pos == new.n_pos == old.cfg.n_modes
        np.testing.assert_array_equal(old.output_map, np.asarray(old.cfg.mode_shapes))
        _same_series(new, old, topic)
        assert new.xidot is None                          # by default no ξ̇ of every epoch; on request:
        _close(States(tmp_path / "full.mcap", topic=topic).xidot, old.xidot, "xidot")
        assert new.events == old.events
    for f in (path, tmp_path / "new.mcap"):
        cli("export", f, "--points", "all", "-o", tmp_path / f"{f.name}.csv")
    a, b = pd.read_csv(tmp_path / "structure-states.mcap.csv"), pd.read_csv(tmp_path / "new.mcap.csv")
    pd.testing.assert_frame_equal(a, b, check_exact=False, rtol=CROSS_MACHINE_RTOL, atol=1e-12)


@pytest.fixture(scope="module")
def gnss(tmp_path_factory):
    """Today's estimate from the RUN and INIT main's GNSS STATES was made from."""
    d = tmp_path_factory.mktemp("gnss")
    for name in ("gnss-run.mcap", "gnss-init.json"):
        shutil.copy(FMT / name, d / name)
    cli("estimate", d / "gnss-run.mcap", "--init", d / "gnss-init.json", "--smooth", "-o", d / "new.mcap")
    return d


def test_gnss_displacement_states_of_main(gnss):
    path = FMT / "gnss-states.mcap"
    att = read_mcap(path, topics=[]).attachments
    assert "config.toml" in att and "states.json" not in att            # the faked structure config
    assert "config.toml" not in read_mcap(gnss / "new.mcap", topics=[]).attachments
    for topic in (STATE_TOPIC, STATE_FILTERED_TOPIC, KIN):
        old, new = States(path, topic=topic), States(gnss / "new.mcap", topic=topic)
        assert old.kind == new.kind == "displacement" and old.cfg is None and new.cfg is None
        assert old.coord_names == new.coord_names == ["rover_e", "rover_n", "rover_u"]
        assert old.wavelength_m == new.wavelength_m
        _same_series(new, old, topic)
        if topic == KIN:
            assert old.extra.keys() == new.extra.keys() == {"n_sat", "pdop"}
            _close(new.extra["pdop"], old.extra["pdop"], "pdop")
            np.testing.assert_array_equal(new.extra["n_sat"], old.extra["n_sat"])
    assert States(path).events == States(gnss / "new.mcap").events


@pytest.mark.parametrize("args", [(), ("--kinematic",)])
def test_gnss_export_reads_both_layouts(gnss, args):
    for f in (FMT / "gnss-states.mcap", gnss / "new.mcap"):
        cli("export", f, *args, "-o", gnss / f"{f.name}{''.join(args)}.csv")
    a = pd.read_csv(gnss / f"gnss-states.mcap{''.join(args)}.csv")
    b = pd.read_csv(gnss / f"new.mcap{''.join(args)}.csv")
    pd.testing.assert_frame_equal(a, b, check_exact=False, rtol=CROSS_MACHINE_RTOL, atol=1e-12)


def test_gnss_evaluate_reads_both_layouts(gnss):
    old, new = (json.loads(cli("evaluate", "--truth", FMT / "gnss-truth", "--estimate", f, "--json"))
                for f in (FMT / "gnss-states.mcap", gnss / "new.mcap"))
    assert old["rms_error_units"] == new["rms_error_units"] == {"rover_e": "m", "rover_n": "m", "rover_u": "m"}
    assert_json_close(new, old, "evaluate")


def test_gnss_structure_states_of_main(tmp_path):
    """``estimate --structure`` on a GNSS run (GPS time): read back, q = U ξ as in its JSON messages."""
    path = FMT / "tower-states.mcap"
    st = States(path)
    assert st.kind == "structure" and st.cfg is not None and st.time_s[0] > 1e8
    msgs = read_mcap(path).topics[STATE_TOPIC]
    k = np.searchsorted(st.time_s, msgs.times())
    q_json = np.array([[m[n] for n in st.coord_names] for m in msgs.scalars["q"]])
    np.testing.assert_allclose(st.q[k], q_json, rtol=1e-12, atol=1e-15)
    cli("export", path, "-o", tmp_path / "t.csv")
    assert len(pd.read_csv(tmp_path / "t.csv")) == len(st.time_s)
