"""No quadratic surprises (issue 12 item 8): every reader is linear in its input.

Each reader gets about 1 MB and about 10 MB of input generated here (tests/_scaling_inputs.py):
the 10 MB read must finish in bounded time and take less than 15 times the 1 MB read (linear:
about 10×; a per-line rescan, quadratic: about 100×).  The small read is timed twice (the best
counts) and given 0.1 s of slack, so that start-up costs do not fail the test; times are the
process's CPU time, so that other processes on a busy machine do not either.
Figures at the time of writing (2-core machine, s for 1 MB / 10 MB): receiver CSV 0.2/1.6,
RINEX 2 0.28/2.1, RINEX 3 0.09/1.6–2.3, RINEX nav 0.18/2.1, UBX 0.16/1.2 (81 s at 10 MB before
the vectorised decoder), TOML config 0.07/0.73, INIT.json 0.09/1.0, MCAP 0.14/1.6.
"""

from __future__ import annotations

import time

import pytest

import _scaling_inputs as gen
from cdgps_cli.config.structure import load_config
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.file_checks import read_init_json
from cdgps_cli.io.logs import read_receiver_log
from cdgps_cli.io.mcap import read_mcap
from cdgps_cli.io.rinex import read_rinex_nav, read_rinex_obs
from cdgps_cli.io.ubx import read_ubx_rawx

SMALL, LARGE = 1_000_000, 10_000_000
MAX_LARGE_S = 10.0        # absolute bound, CPU s, for a 10 MB read
MAX_RATIO = 15.0
SLACK_S = 0.1


def _read(fn, path) -> str:
    try:
        fn(path)
        return "ok"
    except CdgpsError as exc:
        return str(exc)


def _timed(fn, path, repeat: int = 1) -> tuple[float, str]:
    best, out = float("inf"), ""
    for _ in range(repeat):
        t0 = time.process_time()           # CPU time: other processes on the machine do not count
        out = _read(fn, path)
        best = min(best, time.process_time() - t0)
    return best, out


def _readers(testbed_path, testbed_cfg):
    return {
        "receiver_csv": (lambda d, n: gen.receiver_csv(d, n, testbed_cfg), lambda p: read_receiver_log(p, testbed_cfg), "ok"),
        "receiver_csv_cr_only": (lambda d, n: gen.receiver_csv(d, n, testbed_cfg, eol="\r"),
                                 lambda p: read_receiver_log(p, testbed_cfg), "CR only"),
        "rinex2_obs": (gen.rinex2_obs, read_rinex_obs, "ok"),
        "rinex3_obs": (gen.rinex3_obs, read_rinex_obs, "ok"),
        "rinex_nav": (gen.rinex_nav, read_rinex_nav, "ok"),
        "ubx_rawx": (gen.ubx_rawx, read_ubx_rawx, "ok"),
        "ubx_false_syncs": (lambda d, n: gen.ubx_sync_noise(d, n, every=64), read_ubx_rawx, "ok"),
        "toml_config": (lambda d, n: gen.toml_config(d, n, testbed_path), load_config, "ok"),
        "init_json": (gen.init_json, read_init_json, "ok"),
        "mcap": (gen.mcap_file, read_mcap, "ok"),
    }


NAMES = ["receiver_csv", "receiver_csv_cr_only", "rinex2_obs", "rinex3_obs", "rinex_nav", "ubx_rawx",
         "ubx_false_syncs", "toml_config", "init_json", "mcap"]


@pytest.mark.parametrize("name", NAMES)
def test_reader_is_linear(tmp_path, testbed_path, testbed_cfg, name):
    if not gen.SHARED.exists() and name.startswith(("rinex2", "rinex_nav", "ubx")):
        pytest.skip(f"shared test data not available: {gen.SHARED}")
    make, read, expect = _readers(testbed_path, testbed_cfg)[name]
    (tmp_path / "s").mkdir()
    (tmp_path / "l").mkdir()
    small, large = make(tmp_path / "s", SMALL), make(tmp_path / "l", LARGE)
    size_ratio = large.stat().st_size / small.stat().st_size
    assert 8.0 < size_ratio < 12.0, size_ratio
    t_small, out_small = _timed(read, small, repeat=2)
    t_large, out_large = _timed(read, large)
    for out in (out_small, out_large):
        assert (out == "ok") if expect == "ok" else (expect in out), out[:300]
    assert t_large < MAX_LARGE_S, (t_small, t_large)
    assert t_large < MAX_RATIO * (t_small + SLACK_S), (t_small, t_large)
