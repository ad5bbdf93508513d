"""RunDDModel (the static engine's DD model laid out block by block) gives, epoch by epoch, the very
rows, whitening, H and prediction of DDGroupModel over ``static_engine._groups`` (bit for bit), on the
real DD rows of the Spirent G+E L1+L2 pair, with epochs whose groups are not adjacent in the run (a
signal seen by one satellite only) and blocks that cut the record anywhere."""

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.config.options import MULTI_GNSS_DEFAULTS
from cdgps_cli.estimation import static_engine as se
from cdgps_cli.estimation.rtk_multi import receiver_geometry
from cdgps_cli.io.rinex import read_rinex_nav
from cdgps_cli.io.rinex_signals import read_rinex_signals
from cdgps_cli.measurement.dd_signals import DDGroupModel, GroupRows, RunDDModel, paired_sd_rows, whitening_matrix
from cdgps_cli.measurement.epoch_pairing import pair_epochs
from tests._shared import REPO_ROOT

GE = REPO_ROOT / ".." / "shared" / "data" / "rinex-ge"
BASE = np.array([4157177.06580187, 671230.476590636, 4774767.03105544])
ROVER = np.array([4156857.1195929, 673209.028774142, 4774767.03105544]) + np.array([0.3, -0.2, 0.4])


@pytest.fixture(scope="module")
def run():
    if not GE.exists():
        pytest.skip("../shared/data/rinex-ge absent")
    sig = ["G:L1", "G:L2", "E:E1", "E:E5a"]
    nav = pd.concat([read_rinex_nav(GE / "RINEX_GN_Spirent.23N"), read_rinex_nav(GE / "RINEX_EN_Spirent.23L", systems=("E",))])
    _, b = read_rinex_signals(GE / "Base-static_MO_Spirent.obs", sig)
    _, r = read_rinex_signals(GE / "Rover-static-2km-east_MO_Spirent.obs", sig)
    t0 = b["time_gps_s"].min()
    b, r = b[b["time_gps_s"] < t0 + 40], r[r["time_gps_s"] < t0 + 40]
    # from 10 s on, E:E5a (between E:E1 and G:L1 in the rows) is seen by one satellite only in every other epoch: a lone row between two groups
    t = r["time_gps_s"].to_numpy()
    l2 = (r["signal"] == "E:E5a").to_numpy()
    lone = l2 & (t >= t0 + 10) & (np.round(t - t0) % 2 == 0)
    first_l2 = r[lone].groupby("time_gps_s").head(1).index
    r = r[~lone | r.index.isin(first_l2)]
    gb, gr = receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, ROVER)
    opt = {**se._static_options({}), **MULTI_GNSS_DEFAULTS}
    pairs = pair_epochs(gr["time_gps_s"].to_numpy(), gb["time_gps_s"].to_numpy(), sync_tol_s=opt["sync_tol_s"],
                        max_age_s=opt["max_age_s"])
    rows = paired_sd_rows(gb, gr, pairs, opt, mask_rover=True)
    return rows, se.arc_columns(rows, pairs.rover_time_s), pairs.rover_time_s


class _Ctx:
    def __init__(self, x):
        self.x = x


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_the_record_has_epochs_with_groups_apart(run):
    rows = run[0]
    g = rows["groups"]
    apart = [k for k in range(rows["ptr"].size - 1) if g["ptr"][k + 1] - g["ptr"][k] > 1
             and g["stop"][g["ptr"][k + 1] - 1] - g["start"][g["ptr"][k]]
             != (g["stop"] - g["start"])[g["ptr"][k]:g["ptr"][k + 1]].sum()]
    assert 5 <= len(apart) < rows["ptr"].size - 1          # both kinds of epoch are tested


@pytest.mark.parametrize("block_epochs", [1, 7, 4096])
def test_rows_and_prediction_are_ddgroupmodel_bit_for_bit(run, block_epochs):
    rows, cols, times = run
    n = int(cols.max()) + 1
    x = np.random.default_rng(3).normal(size=n) * np.r_[0.5, 0.5, 0.5, np.full(n - 3, 40.0)]
    ctx = _Ctx(x)
    old = DDGroupModel(lambda k: se._groups(rows, cols, k), BASE, ROVER)
    new = RunDDModel(rows, cols, BASE, ROVER, block_epochs=block_epochs)
    for k in range(times.size):
        old.prepare(k, ctx)
        new.prepare(k, ctx)
        a, b = old.rows(k), new.rows(k)
        assert (a is None) == (b is None)
        if a is None:
            continue
        assert _same(a.z_m, b.z_m) and _same(a.B, b.B), k
        for key in ("sat_xyz", "base_rng", "lam", "amb", "H"):
            assert _same(a.context[key], b.context[key]), (k, key)
        assert b.context["ion"] is None and a.context["ion"] is None and a.context["M"] == b.context["M"]
        (ha, Ha), (hb, Hb) = old.predict(x, a), new.predict(x, b)
        assert _same(ha, hb) and _same(Ha, Hb), k
        assert _same(a.whiten(Ha), b.whiten(Hb)) and _same(a.whiten(a.z_m - ha), b.whiten(b.z_m - hb)), k


def test_static_filter_on_the_run_model_is_the_groups_model(run, monkeypatch):
    rows, cols, times = run
    x1, P1, _ = se.static_filter(rows, times, BASE, ROVER, cols=cols)
    monkeypatch.setattr(se, "_model", lambda rows, cols, b, o, iono_cols=None: DDGroupModel(lambda k: se._groups(rows, cols, k), b, o))
    x0, P0, _ = se.static_filter(rows, times, BASE, ROVER, cols=cols)
    assert _same(x0, x1) and _same(P0, P1)


def test_whitening_matrix_is_the_block_product():
    """B = (I − blockdiag(u uᵀ)) Σ^{-1/2} as GroupRows formed it from Uᵀ U, −0.0 across blocks included."""
    rng = np.random.default_rng(0)
    sizes = np.array([3, 1, 4, 2])
    var = rng.uniform(1e-6, 1e-2, sizes.sum())
    block = np.repeat(np.arange(sizes.size), sizes)
    inv = 1.0 / np.sqrt(var)
    u = inv / np.sqrt(np.add.reduceat(inv * inv, np.cumsum(sizes) - sizes)[block])
    U = np.zeros((sizes.size, u.size))
    U[block, np.arange(u.size)] = u
    B = -(U.T @ U)
    B[np.arange(u.size), np.arange(u.size)] += 1.0
    B *= inv
    assert _same(whitening_matrix(u, inv, block), B)
    assert _same(GroupRows(np.zeros(u.size), var, sizes, None).B, B)
    assert np.signbit(B[0, 5]) and np.signbit(whitening_matrix(u, inv, block)[0, 5])


def test_channel_index_is_the_sorted_key_strings():
    from cdgps_cli.measurement.dd_signals import channel_index
    rng = np.random.default_rng(1)
    names = np.array(["G01", "G11", "G1", "E05", "R24", "C01"], dtype=object)
    sats, code = names[rng.integers(0, names.size, 500)], rng.integers(0, 12, 500)
    sats[:2], code[:2] = ["G1", "G11"], [11, 1]                 # "G111" twice: one channel, as the strings say
    for s in (sats, sats.astype(str)):
        want = np.unique(np.char.add(s.astype(str), code.astype(str)), return_inverse=True)[1].ravel()
        assert np.array_equal(channel_index(s, code), want)
    assert channel_index(np.array([], dtype=object), np.array([], dtype=int)).size == 0


def test_arc_columns_and_backward_slips_as_before(run):
    """arc_columns and backward_slips on channel_index: the same as on the sat + code strings."""
    from cdgps_cli.measurement.dd_signals import backward_slips
    rows, cols, times = run
    key = np.char.add(rows["sats"].astype(str), rows["code"].astype(str))
    epoch = np.repeat(np.arange(rows["ptr"].size - 1), np.diff(rows["ptr"]))
    order = np.lexsort((epoch, key))
    nxt = np.zeros(key.size, dtype=bool)
    nxt[:-1] = (key[order][1:] == key[order][:-1]) & rows["slip"][order][1:]
    want = np.zeros(key.size, dtype=bool)
    want[order] = nxt
    assert np.array_equal(backward_slips(rows), want)
    # arc_columns as it was: channels from np.unique of the strings
    from cdgps_cli.measurement.differencing import ambiguity_segments
    channel = np.unique(key, return_inverse=True)[1].ravel()
    seg, tab = ambiguity_segments(epoch, channel, rows["slip"], epoch_time_s=times, max_gap_s=None)
    first = np.full(tab["sat"].size, key.size, dtype=np.int64)
    np.minimum.at(first, seg, np.arange(key.size))
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    assert np.array_equal(se.arc_columns(rows, times), 3 + rank[seg]) and cols.max() > 10


def test_channel_index_takes_signal_names_and_codes_as_strings():
    from cdgps_cli.measurement.dd_signals import _sorted_codes, channel_index
    rng = np.random.default_rng(2)
    sats = np.array(["G05", "E11", "G5", "R01"], dtype=object)[rng.integers(0, 4, 300)]
    sig = np.array(["G:L1", "E:E5a", "5G:L1", "R:G1"], dtype=object)[rng.integers(0, 4, 300)]
    sats[:2], sig[:2] = ["G05", "G0"], ["G:L1", "5G:L1"]           # "G05G:L1" twice: one channel, as the strings say
    want = np.unique(sats.astype(str) + sig.astype(str), return_inverse=True)[1].ravel()
    assert np.array_equal(channel_index(sats, sig), want)
    names, code = np.unique(sig.astype(str), return_inverse=True)
    got = _sorted_codes(sig)
    assert np.array_equal(got[0], names) and np.array_equal(got[1], code.ravel())


def test_a_base_every_5_s_is_interpolated_to_the_rover_epochs():
    """``paired_sd_rows(base_xyz_m=…)``: a 1 Hz rover against a base every 5 s takes, at each bridged epoch, the base's
    observation minus model interpolated between the base epochs around it.  Every satellite's phase and range are
    given a drift of its own at both receivers (a satellite clock departing from its broadcast drift by up to
    1 mm/s: the same at both receivers at the same instant), which simultaneous double differences cancel.  Against
    the same rover with the full 1 Hz base, the DD phases of the bridged epochs (those between two base epochs) are
    off by up to 4.4 mm with the nearest base epoch alone and by 0.28 mm interpolated (the RINEX phase's resolution);
    with one satellite missing from a base epoch, its group's epochs next to it are not interpolated (the receiver
    clock's share would no longer cancel)."""
    if not GE.exists():
        pytest.skip("../shared/data/rinex-ge absent")
    sig = ["G:L1"]
    nav = read_rinex_nav(GE / "RINEX_GN_Spirent.23N")
    _, b = read_rinex_signals(GE / "Base-static_MO_Spirent.obs", sig)
    _, r = read_rinex_signals(GE / "Rover-static-2km-east_MO_Spirent.obs", sig)
    t0 = b["time_gps_s"].min()
    b, r = b[b["time_gps_s"] < t0 + 60].copy(), r[r["time_gps_s"] < t0 + 60].copy()
    rng = np.random.default_rng(5)
    drift = dict(zip(sorted(set(b["sat"])), rng.uniform(-1e-3, 1e-3, 40)))          # m/s per satellite
    for df in (b, r):
        d_m = df["sat"].map(drift).to_numpy() * (df["time_gps_s"].to_numpy() - t0)
        df["pseudorange_m"] += d_m
        df["phase_cycles"] += d_m / df["wavelength_m"].to_numpy()
    gb_all, gr = receiver_geometry(b, nav, BASE), receiver_geometry(r, nav, ROVER)
    opt = {**se._static_options({}), **MULTI_GNSS_DEFAULTS}

    def rows_of(gb, **kw):
        pairs = pair_epochs(gr["time_gps_s"].to_numpy(), gb["time_gps_s"].to_numpy(), sync_tol_s=opt["sync_tol_s"],
                            max_age_s=opt["max_age_s"])
        return paired_sd_rows(gb, gr, pairs, opt, mask_rover=True, **kw)

    def dd(rows):                       # each epoch's SD phases (minus modelled ranges) less the epoch's first satellite
        los_r = np.linalg.norm(rows["sat_xyz"] - ROVER, axis=1)
        los_b = np.linalg.norm(rows["sat_base_xyz"] - BASE, axis=1)
        v = rows["phase_sd_m"] - (los_r - los_b)
        out = {}
        for k in range(rows["ptr"].size - 1):
            a, z = rows["ptr"][k], rows["ptr"][k + 1]
            for s, x in zip(rows["sats"][a:z], v[a:z] - v[a]):
                out[(k, s)] = x
        return out

    tb = gb_all["time_gps_s"].to_numpy()
    every5 = np.isclose((tb - tb.min()) % 5.0, 0.0)
    full, nearest, interp = (dd(rows_of(gb_all)), dd(rows_of(gb_all[every5])),
                             dd(rows_of(gb_all[every5], base_xyz_m=BASE)))
    tr = gr["time_gps_s"].drop_duplicates().sort_values().to_numpy()
    inside = tr <= tb[every5].max()                 # after the last base epoch: nothing to interpolate towards
    keys = sorted(k for k in set(full) & set(nearest) & set(interp) if inside[k[0]])
    err_near = np.array([abs(nearest[k] - full[k]) for k in keys])
    err_int = np.array([abs(interp[k] - full[k]) for k in keys])
    # (measured 4.4 mm and 0.28 mm: the RINEX phase's last digit is 0.001 cycle, 0.19 mm)
    assert err_near.max() > 2e-3 and err_int.max() < 5e-4, (err_near.max(), err_int.max())
    # one satellite missing from one base epoch t₁: the rover epochs that interpolate towards t₁ (2.5–5 s from it) keep
    # their nearest base epoch alone; those whose nearest base epoch is t₁ (≤ 2 s) lack that satellite and interpolate
    t_cut = tb[every5][3]
    sat_cut = sorted(set(gb_all["sat"][gb_all["time_gps_s"] == t_cut]) & set(gr["sat"]))[0]
    cut = gb_all[every5 & ~((gb_all["time_gps_s"].to_numpy() == t_cut) & (gb_all["sat"].to_numpy() == sat_cut))]
    holed, near_rows = rows_of(cut, base_xyz_m=BASE), rows_of(cut)
    for k in np.flatnonzero((np.abs(tr - t_cut) > 0.5) & (np.abs(tr - t_cut) < 4.5)):
        sl = slice(holed["ptr"][k], holed["ptr"][k + 1])
        if abs(tr[k] - t_cut) > 2.5:
            assert sat_cut in holed["sats"][sl] and np.array_equal(holed["phase_sd_m"][sl], near_rows["phase_sd_m"][sl])
        else:
            assert sat_cut not in holed["sats"][sl] and not np.array_equal(holed["phase_sd_m"][sl], near_rows["phase_sd_m"][sl])
    # the count the summaries report: every bridged rover epoch with a base epoch on both sides; fewer with the hole
    bridged_inside = int(np.sum(inside & ~np.isin(tr, tb[every5])))
    assert rows_of(gb_all[every5], base_xyz_m=BASE)["interpolated_epochs"] == bridged_inside
    assert rows_of(gb_all[every5])["interpolated_epochs"] == 0
    assert holed["interpolated_epochs"] < bridged_inside


def test_one_single_difference_one_ephemeris_and_no_interpolation_across_a_change():
    """Galileo's broadcast ephemerides change every 10 min; with a base every 5 s (the real mosaic pair, G + E L1),
    a bridged rover epoch near a change paired its rover row (new ephemeris) with a base row of the old one, and
    the interpolation took M₁ − M₀ across the change: E1 double differences 128 mm (nearest) and 102 mm
    (interpolated) off those of the full 1 Hz base.  Now a single difference whose two rows have different
    ephemerides is not formed, and a group whose base epochs t₀, t₁ differ in ephemeris keeps its nearest epoch:
    11 and 7 mm (the receivers' own noise and multipath: the same bound holds for GPS, whose ephemerides did not
    change)."""
    from cdgps_cli.estimation.baseline import header_position_m
    ms = REPO_ROOT / ".." / "shared" / "data" / "real-pairs" / "mosaic-static"
    if not ms.exists():
        pytest.skip("../shared/data/real-pairs/mosaic-static absent")
    sig = ["E:E1", "G:L1"]
    nav = read_rinex_nav(ms / "base.nav", systems=("G", "E"))
    (hb, b), (hr, r) = read_rinex_signals(ms / "base.obs", sig), read_rinex_signals(ms / "rover.obs", sig)
    xb, xr = header_position_m(hb), header_position_m(hr)
    gb, gr = receiver_geometry(b, nav, xb), receiver_geometry(r, nav, xr)
    opt = {**se._static_options({}), **MULTI_GNSS_DEFAULTS}

    def dd(base, **kw):                  # (epoch, signal, reference, satellite) → DD phase minus modelled range, m
        pairs = pair_epochs(gr["time_gps_s"].to_numpy(), base["time_gps_s"].to_numpy(), sync_tol_s=opt["sync_tol_s"],
                            max_age_s=opt["max_age_s"])
        rows = paired_sd_rows(base, gr, pairs, opt, mask_rover=True, **kw)
        v = rows["phase_sd_m"] - (np.linalg.norm(rows["sat_xyz"] - xr, axis=1)
                                  - np.linalg.norm(rows["sat_base_xyz"] - xb, axis=1))
        g, out = rows["groups"], {}
        for a, z, ref in zip(g["start"], g["stop"], g["ref"]):
            ep = int(np.searchsorted(rows["ptr"], a, side="right") - 1)
            for i in range(a, z):
                if i != ref:
                    out[(ep, rows["names"][rows["code"][a]], rows["sats"][ref], rows["sats"][i])] = v[i] - v[ref]
        return out

    tb = gb["time_gps_s"].to_numpy()
    every5 = gb[np.isclose((tb - tb.min()) % 5.0, 0.0)]
    full, near, interp = dd(gb), dd(every5), dd(every5, base_xyz_m=xb)
    for got in (near, interp):
        keys = set(full) & set(got)
        assert len(keys) > 2000
        worst = max(abs(got[k] - full[k]) for k in keys)
        assert worst < 0.03, worst                    # (measured 18 mm, GPS nearest; before: 128 mm)
