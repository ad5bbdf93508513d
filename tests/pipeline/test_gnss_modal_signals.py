"""The modal structure model on multi-GNSS, dual-frequency double differences (issue 14 items 4 and 6).

`cdgps simulate-gnss-structure --signals G:L1,G:L2,E:E1,E:E5a` writes multi-signal RINEX 3 files and
a config with ``[gnss] signals``; ingest keeps the signals (``gnss/signals/<k>.npz.zst``); the modal
path takes one DD group per rover and signal, each with its own reference satellite and wavelength,
fixes all groups' integers as one set in the model-aided batch initialization, and filters.  Checked
against the simulator's truth (integers per signal, q(t)), finite differences, and the refusals.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import main
from cdgps_cli.config.structure import load_config
from cdgps_cli.io.gnss_run import read_gnss_run
from cdgps_cli.measurement.model import SatelliteDDModal
from cdgps_cli.pipeline.gnss_modal import _modal_setup

ROOT = Path(__file__).resolve().parents[2]
TOWER = ROOT / "configs" / "gnss-tower.toml"
SIGS = "G:L1,G:L2,E:E1,E:E5a"


def run_cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def multi(tmp_path_factory, gnss_modal_chain):
    return gnss_modal_chain(tmp_path_factory.mktemp("multi"), SIGS, 150, 3)


def test_ingest_keeps_the_signals(multi):
    tmp, truth, *_ = multi
    run = read_gnss_run(tmp / "run.mcap")
    assert run.cfg.signals == tuple(SIGS.split(",")) and run.metadata["signals"] == SIGS
    for rx in run.receivers.values():
        assert set(rx.signals["signal"]) == set(SIGS.split(","))
        assert set(rx.signals["sat"].str[0]) == {"G", "E"}
    assert set(run.nav["sat"].str[0]) == {"G", "E"}


def test_every_group_has_its_own_reference_and_the_integers_are_the_truth(multi):
    """Per rover and signal a DD group; every fixed DD integer equals the simulated
    (N_r^j − N_m^j) − (N_r^ref − N_m^ref) of that signal (one lock segment per satellite here)."""
    tmp, truth, init, _ = multi
    mi = init["modal_init"]
    ints, master = truth["integers"], truth["master"]
    groups = {}
    for sg in mi["segments"]:
        groups.setdefault((sg["rover_slot"], sg["signal"]), set()).add(sg["reference"])
    assert {g for _, g in groups} == set(SIGS.split(",")) and len(groups) == 2 * 4
    assert all(len(refs) == 1 for refs in groups.values())           # one reference per group in the window
    rovers = [r for r in truth["receivers"].values() if r != master]
    n_ok = 0
    for sg in mi["segments"]:
        g, rx = sg["signal"], rovers[sg["rover_slot"] // 4]
        sat, ref = sg["satellite"].split(":")[0], sg["reference"].split(":")[0]
        assert sg["satellite"][0] == g[0]                          # within one constellation
        want = (ints[rx][g][sat] - ints[master][g][sat]) - (ints[rx][g][ref] - ints[master][g][ref])
        assert sg["fixed"] and sg["integer_cycles"] == want, sg
        n_ok += 1
    assert mi["n_fixed"] == mi["n_segments"] == n_ok >= 40


def test_modal_states_recover_the_truth(multi):
    _, _, _, ev = multi
    rms = ev["rms_error"]
    assert rms["ex"] < 0.004 and rms["ey"] < 0.004 and rms["psi"] < 4e-4
    assert 1.5 < ev["nees"]["mean"] < 4.5                                       # dof 3
    assert 0.8 < ev["nis"]["mean_per_dof"] < 1.2


def test_multi_signal_model_jacobian_and_noise(multi):
    """The multi-signal SatelliteDDModal: H = finite differences; rows of different signals are
    uncorrelated, rows of one signal of different rovers correlate through the master."""
    tmp, *_ = multi
    cfg = load_config(TOWER)
    run = read_gnss_run(tmp / "run.mcap")
    init = json.loads((tmp / "init.json").read_text())
    su = _modal_setup(run, init, cfg, None, 90.0, lambda m: None)
    raw = [dict(tb, r0=tb["r_raw"], use=np.ones(tb["seg"].size, bool), ref=tb["ref"]) for tb in su.tabs]
    from cdgps_cli.measurement.differencing import select_reference

    for tb in raw:
        tb["ref"] = select_reference(tb["d"].ptr, tb["d"].sat, tb["d"].el_rover, tb["d"].slip)
    model = SatelliteDDModal(cfg, su.R, raw, su.k_of, su.ant_idx, su.d_hdr)
    rows = model.rows(5)
    x = np.random.default_rng(1).normal(scale=0.05, size=model.n_state)
    _, H = model.predict(x, rows)
    fd = np.zeros_like(H)
    for j in range(x.size):
        dx = np.zeros(x.size)
        dx[j] = 1e-6
        fd[:, j] = (model.predict(x + dx, rows)[0] - model.predict(x - dx, rows)[0]) / 2e-6
    np.testing.assert_allclose(H, fd, atol=1e-7)
    C = rows.covariance()
    sig = np.array([lab[1].split(":")[1] for lab in rows.labels])
    slot = np.array([lab[0] for lab in rows.labels])
    assert np.all(C[sig[:, None] != sig[None, :]] == 0.0)
    cross = (sig[:, None] == sig[None, :]) & (np.array(su.slot_ants)[slot][:, None] != np.array(su.slot_ants)[slot][None, :])
    assert np.all(C[cross] != 0.0)
    # the wavelength of each group: L2 and E5a slots have their own λ
    lam = {tb["signal"]: tb["lam_m"] for tb in su.tabs}
    assert lam["G:L2"] == pytest.approx(0.2442102, abs=1e-6) and lam["E:E5a"] == pytest.approx(0.2548280, abs=1e-6)


def _write_config(tmp, src, signals):
    text = (src / "config.toml").read_text()
    lines = [ln for ln in text.splitlines() if not ln.startswith("signals")]
    i = lines.index("[gnss]") + 1
    lines.insert(i, f"signals = {signals}")
    cfg = tmp / "config.toml"
    cfg.write_text("\n".join(lines) + "\n")
    for p in src.iterdir():
        if p.suffix == ".rnx":
            (tmp / p.name).write_bytes(p.read_bytes())
    return cfg


@pytest.mark.parametrize("signals,message", [
    ('["G:L1", "E:E5b"]', "E:E5b"),                     # a signal the receivers do not track
    ('["G:L1", "C:B1I"]', "BeiDou"),                    # a system without ephemerides here
    ('["G:L1", "X:L9"]', "gnss.signals: unknown signal"),
])
def test_ingest_refuses_signals_the_receivers_do_not_share(multi, tmp_path, signals, message):
    tmp, *_ = multi
    cfg = _write_config(tmp_path, tmp, signals)
    (tmp_path / "nav.rnx").write_bytes((tmp / "nav.rnx").read_bytes())
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--config", cfg, "-o", out)
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output, r.output
    assert not out.exists() and not any(p.name.startswith(".run.mcap") for p in tmp_path.iterdir())


def test_simulate_refuses_signals_without_gps_l1(tmp_path):
    out = tmp_path / "sim"
    r = run_cli("simulate-gnss-structure", TOWER, "--duration", "20", "--signals", "E:E1,E:E5a", "--out", out)
    assert r.exit_code == 2 and "G:L1" in r.output and not out.exists(), r.output


def test_simulate_with_signals_is_deterministic(tmp_path):
    for d in ("a", "b"):
        r = run_cli("-q", "simulate-gnss-structure", TOWER, "--duration", "20", "--seed", "5", "--signals", "G:L1,E:E1",
                    "--out", tmp_path / d)
        assert r.exit_code == 0, r.output
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert "nav.rnx" in files and sum(f.endswith(".rnx") for f in files) == 4
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    cfg = (tmp_path / "a" / "config.toml").read_text()
    assert 'signals = ["G:L1", "E:E1"]' in cfg
    assert "M: MIXED" in (tmp_path / "a" / "nav.rnx").read_text().splitlines()[0]


def test_compiled_filter_equals_numpy_on_the_multi_signal_model(multi):
    """The filter takes the signal slots as it takes rovers: the compiled path (packed rows, D Σ Dᵀ per
    epoch over all slots) equals the numpy path on the multi-signal model of the run."""
    from cdgps_cli.estimation import kernel
    from cdgps_cli.estimation.model_filter import filter_dd_kernel, filter_numpy
    from cdgps_cli.model.dynamics_models import ModalZOH
    from cdgps_cli.pipeline.gnss_modal import apply_modal_record

    if not kernel.available():
        pytest.skip("compiled kernel not available")
    tmp, *_ = multi
    cfg = load_config(TOWER)
    init = json.loads((tmp / "init.json").read_text())
    su = _modal_setup(read_gnss_run(tmp / "run.mcap"), init, cfg, None, 90.0, lambda m: None)
    tabs = apply_modal_record(su.tabs, init["modal_init"])
    assert all(tb["use"].any() for tb in tabs) and len(tabs) == 8
    model = SatelliteDDModal(cfg, su.R, tabs, su.k_of, su.ant_idx, su.d_hdr)
    t = su.t_all
    x0, P0 = np.asarray(init["modal_init"]["x1"]), np.eye(model.n_state)
    ref = filter_numpy(model, ModalZOH(cfg), t, x0, P0)
    got = filter_dd_kernel(model, ModalZOH(cfg), t, x0, P0)
    np.testing.assert_allclose(got["x"], ref["x"], rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(got["P"], ref["P"], rtol=1e-7, atol=1e-15)


def test_a_segment_starting_after_the_window_is_fixed_by_a_later_window(multi):
    """A slip of +7 cycles at epoch 90 on one satellite of one group (a new lock segment the first
    window cannot see): a window opened at the slip fixes it, chained onto the datum, so its SD integer
    is the old segment's + 7 and its rows are used; the rest of the run is checked, not changed."""
    from cdgps_cli.pipeline.gnss_modal import modal_batch_initialization

    tmp, *_ = multi
    cfg = load_config(TOWER)
    init = json.loads((tmp / "init.json").read_text())
    su = _modal_setup(read_gnss_run(tmp / "run.mcap"), init, cfg, None, 90.0, lambda m: None)
    tabs = [dict(tb) for tb in su.tabs]
    tb, d = tabs[0], su.tabs[0]["d"]
    k90 = d.ptr[90]
    rows90 = np.arange(k90, d.ptr[91])
    sat = d.sat[rows90[np.argmin(d.el_rover[rows90])]]        # the lowest satellite: not the reference
    old = int(tb["seg"][rows90[d.sat[rows90] == sat][0]])
    n_seg = tb["a_seg"].size
    hit = (d.sat == sat) & (d.epoch >= 90)
    seg = np.where(hit, n_seg, tb["seg"])
    tb.update(seg=seg, r_raw=tb["r_raw"] + np.where(hit, 7 * tb["lam_m"], 0.0), a_seg=np.zeros(n_seg + 1),
              w={"known_seg": np.zeros(n_seg + 1, bool), "seg": seg, "a_seg": np.zeros(n_seg + 1)})
    out, _, rec = modal_batch_initialization(cfg, su.R, tabs, su.k_of, su.ant_idx, su.d_hdr, su.t_all, window_s=30.0)
    assert rec["window"]["epochs"] == 30
    lw = [w for w in rec["later_windows"] if "refused" not in w]
    assert lw and lw[0]["start_s"] == pytest.approx(su.t_all[90]) and lw[0]["disagree"] == 0 and lw[0]["checked"] > 10
    assert any(s["rover_slot"] == 0 and s["segment"] == n_seg for s in rec["later_segments"])
    assert out[0]["a_seg"][n_seg] == out[0]["a_seg"][old] + 7 and out[0]["use"][hit].all()


def test_a_slip_no_receiver_flagged_is_cut_where_init_cut_it(tmp_path):
    """The tower on G:L1 + E:E1, one rover's G03 L1 phase one cycle up from 100 s with no loss-of-lock flag.  INIT
    cuts G03's arc there (the slip search); the structure's signal path ignored INIT's arcs and rejected that DD as an
    outlier at every epoch from 100 s (51 events).  Its segments now start where INIT's do: a later window fixes the
    new segment (its SD integer one cycle from the first's), no DD is rejected, and the states are the unedited
    record's.  An INIT whose modal_init was made on other segments is refused by name."""
    import shutil

    from tests.pipeline.test_init_real_edits import _slip
    out = {}
    r = run_cli("-q", "simulate-gnss-structure", TOWER, "--duration", 150, "--seed", 3, "--signals", "G:L1,E:E1",
                "--out", tmp_path / "ref")
    assert r.exit_code == 0, r.output
    shutil.copytree(tmp_path / "ref", tmp_path / "slip")     # the same simulation (same seed: the same bytes), then edited
    assert "/" not in "".join(ln for ln in (tmp_path / "ref" / "config.toml").read_text().splitlines()
                              if ln.startswith(("rinex", "nav")))                  # its files named relative to it
    for tag in ("ref", "slip"):
        d = tmp_path / tag
        if tag == "slip":
            (d / "r1.rnx").write_text(_slip((d / "r1.rnx").read_text(), "G03", "L1C", 100, 1.0))
        for args in (("ingest", "--config", d / "config.toml", "-o", d / "run.mcap"),
                     ("init", d / "run.mcap", "--structure", TOWER, "-o", d / "init.json")):
            r = run_cli("-q", *args)
            assert r.exit_code == 0, (args, r.output)
        r = run_cli("-q", "estimate", d / "run.mcap", "--init", d / "init.json", "--structure", TOWER, "-o",
                    d / "states.mcap", "--json")
        assert r.exit_code == 0, r.output
        out[tag] = (json.loads((d / "init.json").read_text()), json.loads(r.stdout))
    init, est = out["slip"]
    assert [b["segment_start_s"] - b["segment_end_s"] < 0 for b in init["biases"]
            if b["rover"] == "r1" and b["satellite"] == "G03:L1"] == [True, True]          # INIT cut G03 there
    later = init["modal_init"]["later_segments"]
    assert len(later) == 1 and later[0]["rover_slot"] == 0 and later[0]["satellite"] == "G03:L1"
    assert later[0]["first_s"] == init["modal_init"]["window"]["start_s"] + 100.0
    first = next(s for s in init["modal_init"]["segments"] if s["rover_slot"] == 0 and s["satellite"] == "G03:L1")
    assert later[0]["a_cycles"] - first["integer_cycles"] == 1.0          # the slip: one cycle on the datum
    assert est["events"] == out["ref"][1]["events"] == 0
    assert est["integers"]["r1"]["signals"]["G:L1"] == {"fixed": 12, "estimated": 12}
    assert est["mean_nis_per_dof"] == pytest.approx(out["ref"][1]["mean_nis_per_dof"], rel=1e-6)
    # a modal_init made on other segments (here: INIT's G03 cut taken out of its biases) is refused
    stale = dict(init, biases=[b for b in init["biases"] if not (b["rover"] == "r1" and b["satellite"] == "G03:L1"
                                                                   and b["segment_start_s"] > init["biases"][0]["segment_start_s"] + 50)])
    (tmp_path / "stale.json").write_text(json.dumps(stale))
    r = run_cli("-q", "estimate", tmp_path / "slip" / "run.mcap", "--init", tmp_path / "stale.json", "--structure",
                TOWER, "-o", tmp_path / "stale.mcap")
    assert r.exit_code == 2 and "modal_init does not match this run's lock segments" in r.output, r.output
    assert not (tmp_path / "stale.mcap").exists()
    # a later segment stored with another start (the same satellite's segments numbered otherwise) is refused too
    moved = json.loads(json.dumps(init))
    moved["modal_init"]["later_segments"][0]["first_s"] += 1.0
    (tmp_path / "moved.json").write_text(json.dumps(moved))
    r = run_cli("-q", "estimate", tmp_path / "slip" / "run.mcap", "--init", tmp_path / "moved.json", "--structure",
                TOWER, "-o", tmp_path / "moved.mcap")
    assert r.exit_code == 2 and "begins at" in r.output and not (tmp_path / "moved.mcap").exists(), r.output
    moved["modal_init"]["later_segments"][0]["first_s"] = float("nan")            # and one that is no time
    (tmp_path / "moved.json").write_text(json.dumps(moved))
    r = run_cli("-q", "estimate", tmp_path / "slip" / "run.mcap", "--init", tmp_path / "moved.json", "--structure",
                TOWER, "-o", tmp_path / "moved.mcap")
    assert r.exit_code == 2 and "first_s = nan" in r.output and not (tmp_path / "moved.mcap").exists(), r.output


def test_the_signal_tables_take_the_run_s_antenna_calibrations(multi, tmp_path):
    """``[gnss] antex`` on a multi-signal structure run: the modal set-up's SD tables of the calibrated rover move by
    its correction, the other rover's do not (a review of session 30 found these tables built from the receivers as
    ingested, the models left out: the states bit for bit those without the file)."""
    from tests.io.test_antex import antenna_block, write_antex

    src, *_ = multi
    run0 = read_gnss_run(src / "run.mcap")
    rover = run0.rovers[0]
    write_antex(tmp_path / "r.atx", [antenna_block("ROVERANT        NONE",
                                                   {f: ((0.0, 0.0, 100.0), np.zeros(19)) for f in ("G01", "G02")})])
    lines = (src / "config.toml").read_text().splitlines()
    lines.insert(lines.index("[gnss]") + 1, 'antex = "r.atx"')
    for n in run0.receivers:                       # its calibration for one rover, none for the others
        lines.insert(lines.index(f'[gnss.antennas."{n}"]') + 1,
                     f'antenna_type = "{"ROVERANT NONE" if n == rover else "none"}"')
    (tmp_path / "config.toml").write_text("\n".join(lines) + "\n")
    for p in src.iterdir():
        if p.suffix == ".rnx":
            (tmp_path / p.name).write_bytes(p.read_bytes())
    r = run_cli("-q", "ingest", "--config", tmp_path / "config.toml", "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    run1 = read_gnss_run(tmp_path / "run.mcap")
    assert run1.antennas[rover] is not None and all(run1.antennas[n] is None for n in run1.receivers if n != rover)
    cfg = load_config(TOWER)
    init = json.loads((src / "init.json").read_text())
    setups = [_modal_setup(run, dict(init, config_sha256=run.cfg.sha256), cfg, None, 90.0, lambda m: None)
              for run in (run0, run1)]
    moved = {}
    for ant, a, b in zip(setups[0].slot_ants, setups[0].tabs, setups[1].tabs):
        assert a["signal"] == b["signal"] and np.array_equal(a["d"].t_label, b["d"].t_label)
        moved.setdefault(setups[0].mapping[ant], []).append(np.abs(b["d"].r_raw_m - a["d"].r_raw_m))
    got = np.concatenate(moved.pop(rover))         # G and E rows alike (E1, E5a served by G01, G02 as RTKLIB does)
    assert got.max() <= 0.1 + 1e-9 and np.count_nonzero(got > 0.02) > got.size // 2, (got.min(), got.max())
    assert all(np.all(x == 0.0) for xs in moved.values() for x in xs)       # the other rover's tables as ingested
