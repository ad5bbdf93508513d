"""The modal structure model with BeiDou (issue 14 item 6): `simulate-gnss-structure --signals
G:L1,C:B1I,C:B2a` (synthetic BeiDou GEO, IGSO and MEO satellites, BDT records in the navigation file)
→ ingest → init → estimate; every BeiDou DD group has its own reference and wavelength and its fixed
integers are the simulator's; the modal states match the truth; same seed → same files."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.io.gnss_run import read_gnss_run

SIGS = "G:L1,C:B1I,C:B2a"


@pytest.fixture(scope="module")
def bds(tmp_path_factory, gnss_modal_chain):
    return gnss_modal_chain(tmp_path_factory.mktemp("bds"), SIGS, 120, 4)


def test_beidou_signals_reach_the_run_with_their_ephemerides(bds):
    tmp, *_ = bds
    run = read_gnss_run(tmp / "run.mcap")
    assert set(run.nav["sat"].str[0]) == {"G", "C"}
    for rx in run.receivers.values():
        assert set(rx.signals["signal"]) == set(SIGS.split(","))
        sats = set(rx.signals.loc[rx.signals["signal"] == "C:B1I", "sat"])
        assert sats & {"C01", "C02", "C03", "C04", "C05"} and sats & {"C06", "C07", "C08"}   # GEO and IGSO tracked


def test_beidou_dd_integers_are_the_truth(bds):
    tmp, truth, init, _ = bds
    mi = init["modal_init"]
    ints, master = truth["integers"], truth["master"]
    rovers = [r for r in truth["receivers"].values() if r != master]
    refs = {}
    n_bds = 0
    for sg in mi["segments"]:
        g, rx = sg["signal"], rovers[sg["rover_slot"] // 3]
        sat, ref = sg["satellite"].split(":")[0], sg["reference"].split(":")[0]
        refs.setdefault((sg["rover_slot"], g), set()).add(ref)
        assert sat[0] == ref[0] == g[0]
        want = (ints[rx][g][sat] - ints[master][g][sat]) - (ints[rx][g][ref] - ints[master][g][ref])
        assert sg["fixed"] and sg["integer_cycles"] == want, sg
        n_bds += g[0] == "C"
    assert {g for _, g in refs} == set(SIGS.split(",")) and all(len(v) == 1 for v in refs.values())
    assert n_bds >= 2 * 2 * 8 and mi["n_fixed"] == mi["n_segments"]


def test_modal_states_recover_the_truth_with_beidou(bds):
    _, _, _, ev = bds
    rms = ev["rms_error"]
    assert rms["ex"] < 0.004 and rms["ey"] < 0.004 and rms["psi"] < 4e-4
    assert 1.0 < ev["nees"]["mean"] < 5.0                                       # dof 3


def test_beidou_simulation_is_deterministic(tmp_path, gnss_tower):
    for d in ("a", "b"):
        r = CliRunner().invoke(main, ["-q", "simulate-gnss-structure", str(gnss_tower), "--duration", "10", "--seed", "2",
                                      "--signals", "G:L1,C:B1I,C:B2I", "--out", str(tmp_path / d)])
        assert r.exit_code == 0, r.output
    for f in sorted(p.name for p in (tmp_path / "a").iterdir()):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert any(ln.startswith("C01 ") for ln in (tmp_path / "a" / "nav.rnx").read_text().splitlines())
