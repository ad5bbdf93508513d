"""cdgps_cli/estimation/filter.py: the one pass over a RUN's phase rows (kept rows, channel-pair counts,
unknown names) against a brute-force count over the rows' names."""
from types import SimpleNamespace

import numpy as np

from cdgps_cli.core.table import Table
from cdgps_cli.estimation.filter import _kept_rows, _scan_phase_rows

CFG = SimpleNamespace(antenna_names=["m", "a1", "a2"], transmitter_names=["PL1", "PL2", "PL3", "PL4"])


def _table(seed, extra_antenna=None):
    rng = np.random.default_rng(seed)
    n = 500
    ants = list(CFG.antenna_names) + ([extra_antenna] if extra_antenna else [])
    a = rng.integers(0, len(ants) - (1 if extra_antenna else 0), n)
    if extra_antenna:
        a[rng.integers(0, n)] = len(ants) - 1
    tx = ["PL3", "PL1", "PL4"]                     # PL2 never seen; words not in config order
    t_codes = rng.integers(0, len(tx), n)
    time_s = np.sort(rng.uniform(0.0, 50.0, n))
    time_s[[30, 400]] = time_s[[400, 30]]          # one row out of time order
    return Table({"time_s": time_s}, {"antenna": (a, ants), "transmitter": (t_codes, tx)})


def _brute(tab, t0):
    keep = tab["time_s"] >= t0 - 1e-9
    counts = np.zeros(len(CFG.antenna_names) * len(CFG.transmitter_names), int)
    for an, tn in zip(tab["antenna"][keep], tab["transmitter"][keep]):
        counts[CFG.antenna_names.index(an) * len(CFG.transmitter_names) + CFG.transmitter_names.index(tn)] += 1
    return keep, counts


def test_scan_counts_every_kept_row_of_every_pair_and_the_last_time():
    tab = _table(1)
    for t0 in (0.0, 12.5, 49.0):
        blocks = [slice(a, min(a + 64, len(tab))) for a in range(0, len(tab), 64)]
        scan = _scan_phase_rows(tab, blocks, t0, CFG)
        keep, counts = _brute(tab, t0)
        np.testing.assert_array_equal(scan.pair_counts, counts)
        assert scan.t_last == tab["time_s"][keep].max() and not scan.unknown_names
        kept = np.concatenate([np.arange(len(tab))[_kept_rows(tab["time_s"], b, t0)] for b in blocks])
        np.testing.assert_array_equal(kept, np.flatnonzero(keep))        # slices and indices alike
        pair = scan.pair_of_joint[scan.joint(kept)]
        want = [CFG.antenna_names.index(a) * 4 + CFG.transmitter_names.index(t)
                for a, t in zip(tab["antenna"][kept], tab["transmitter"][kept])]
        np.testing.assert_array_equal(pair, want)


def test_a_name_the_config_lacks_is_seen_even_before_t0():
    tab = _table(2, extra_antenna="zz")
    scan = _scan_phase_rows(tab, [slice(0, len(tab))], 60.0, CFG)
    assert scan.unknown_names and scan.t_last == -np.inf
