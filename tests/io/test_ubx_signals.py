"""UBX RXM-RAWX with ``[gnss] signals`` (issue 14 item 4): every signal the log carries, named as in
``core/signals.py``, through ingest, init and estimate.

Checked against an independent ``struct`` decoding of the real u-blox 8 log (GPS L1 C/A, Galileo
E1, BeiDou B1I, GLONASS L1), and end to end on a simulated u-blox pair (dual-frequency GPS and
Galileo, encoded here with ``struct`` as an F9 would send it): the fixed DD integers per signal
equal the simulated ones.  What a log does not carry is refused naming the signal.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.signals import wavelength_m
from cdgps_cli.io.ubx import read_ubx_signals
from cdgps_cli.pipeline.gnss import rover_segments
from tests._shared import run_cli, run_commands

DATA = Path(__file__).resolve().parents[1] / "data"
RAWX = DATA / "pygpsdata-RXMRAWX.log"
ROOT = Path(__file__).resolve().parents[2]
_SIG_ID = {"G:L1": (0, 0), "G:L2": (0, 3), "E:E1": (2, 1), "E:E5a": (2, 3)}      # as an F9 reports them
_SYS = {"G": 0, "E": 2, "C": 3, "R": 6}


def _struct_rows(data: bytes):
    """(time, gnssId, svId, sigId, freqId, cpMes, trkStat) of every RXM-RAWX measurement, by struct."""
    out, k = [], 0
    while k < len(data):
        n = struct.unpack_from("<H", data, k + 4)[0]
        if (data[k + 2], data[k + 3]) == (0x02, 0x15):
            pl = data[k + 6: k + 6 + n]
            tow, week, _, num = struct.unpack_from("<dHbB", pl, 0)
            for i in range(num):
                _, cp, _, g, sv, sig, fq, _, _, _, _, _, trk = struct.unpack_from("<ddfBBBBHBBBBB", pl, 16 + 32 * i)
                out.append((week * 604800 + tow, g, sv, sig, fq, cp, trk))
        k += 8 + n
    return out


def test_the_real_ublox8_log_gives_every_signal_it_carries():
    names = ["G:L1", "E:E1", "C:B1I", "R:G1"]
    tab = read_ubx_signals(RAWX, names)
    ref = [r for r in _struct_rows(RAWX.read_bytes()) if r[3] == 0 and r[6] & 2 and r[1] in (0, 2, 3, 6)]
    letter = {0: "G", 2: "E", 3: "C", 6: "R"}
    for name in names:
        want = sorted((t, f"{letter[g]}{sv:02d}", cp) for t, g, sv, _, _, cp, _ in ref if letter[g] == name[0])
        got = tab[tab["signal"] == name]
        assert len(got) == len(want) > 0
        assert sorted(zip(got["time_gps_s"], got["sat"], got["phase_cycles"])) == want
    glo = tab[tab["signal"] == "R:G1"]
    fq = {(t, f"R{sv:02d}"): f for t, g, sv, _, f, _, _ in ref if g == 6}
    lam = [wavelength_m("R:G1", fq[(t, s)] - 7) for t, s in zip(glo["time_gps_s"], glo["sat"])]
    assert np.allclose(glo["wavelength_m"], lam) and glo["wavelength_m"].nunique() > 1        # FDMA: per satellite
    assert (tab["lock_time_ms"] >= 0).all() and set(tab["half_cycle"]) <= {0, 1}


def test_a_signal_the_log_does_not_carry_is_refused_naming_it(tmp_path):
    with pytest.raises(CdgpsError, match="Q:L9"):
        read_ubx_signals(RAWX, ["G:L1", "Q:L9"])
    cfg = (ROOT / "configs" / "ubx-example.toml").read_text().replace("[gnss]\n", '[gnss]\nsignals = ["G:L1", "G:L2"]\n', 1)
    (tmp_path / "job.toml").write_text(cfg.replace("../../shared", str(ROOT.parent / "shared")))
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--config", tmp_path / "job.toml", "--ubx", f"ublox={RAWX}", "-o", out)
    assert r.exit_code == 2 and "no G:L2 phase observations" in r.output and "E:E1" not in r.output.split("G:L2")[0]
    assert "Traceback" not in r.output and not out.exists(), r.output


def rawx_log(obs, path: Path, sig_ids: dict | None = None) -> None:
    """RXM-RAWX frames of a simulated receiver's signal table: lock time growing from each lock
    segment's start (restarting at an LLI slip), pseudorange and phase valid, half cycle valid; ``sig_ids``:
    signal name → (gnssId, sigId) (default ``_SIG_ID``)."""
    sig_ids = _SIG_ID if sig_ids is None else sig_ids
    frames = []
    start = {}
    for t, ep in obs.groupby("time_gps_s", sort=True):
        week, tow = divmod(float(t), 604800.0)
        blocks = []
        for r in ep.itertuples():
            key = (r.sat, r.signal)
            if key not in start or (int(r.lli) & 1):
                start[key] = t
            g, sig = sig_ids[r.signal]
            lock = min(64500, int(round((t - start[key]) * 1000)))
            blocks.append(struct.pack("<ddfBBBBHBBBBBx", r.pseudorange_m, r.phase_cycles, 0.0, g, int(r.sat[1:]), sig, 0,
                                      lock, 45, 5, 2, 3, 0b0111))
        payload = struct.pack("<dHbBBB2x", tow, int(week), 18, len(blocks), 1, 1) + b"".join(blocks)
        body = bytes((0x02, 0x15)) + struct.pack("<H", len(payload)) + payload
        a = b = 0
        for byte in body:
            a = (a + byte) & 0xFF
            b = (b + a) & 0xFF
        frames.append(b"\xb5\x62" + body + bytes((a, b)))
    path.write_bytes(b"".join(frames))


@pytest.fixture(scope="module")
def ubx_pair(tmp_path_factory):
    from cdgps_cli.io.rinex_write import write_rinex_nav
    from cdgps_cli.model.gps.orbits import enu_matrix
    from cdgps_cli.model.gps.positioning import synthetic_nav
    from cdgps_cli.sim.gnss_signals import simulate_receiver_signals

    tmp = tmp_path_factory.mktemp("ubxsig")
    sigs = list(_SIG_ID)
    t0, n = 1_400_000_000.0, 120
    nav = synthetic_nav({"G", "E"}, t0, float(n), seed=4)
    write_rinex_nav(tmp / "nav.rnx", nav)
    base = np.array([3_875_000.0, 332_000.0, 5_028_000.0])
    lat, lon = math.radians(52.3), math.radians(4.9)
    rover = base + enu_matrix(lat, lon).T @ np.array([120.0, -45.0, 3.0])
    ints = {}
    for name, xyz, seed, drift in (("base", base, 1, 0.3), ("rover", rover, 2, -0.4)):
        s = simulate_receiver_signals(nav, xyz, t0, n, 1.0, sigs, seed=seed, clock_drift_ms=drift)
        rawx_log(s["obs"], tmp / f"{name}.ubx")
        amb = s["ambiguities"].drop_duplicates(["signal", "sat"])
        ints[name] = {(r.signal, r.sat): int(r.n_cycles) for r in amb.itertuples()}
    (tmp / "job.toml").write_text(
        f'[gnss]\nmaster = "base"\nsignals = {json.dumps(sigs)}\nnav = ["nav.rnx"]\n'
        f'[gnss.antennas.base]\nubx = "base.ubx"\nposition_ecef_m = {base.tolist()}\n'
        f'[gnss.antennas.rover]\nubx = "rover.ubx"\nposition_ecef_m = {rover.tolist()}\n')
    run_commands(("ingest", "--config", tmp / "job.toml", "-o", tmp / "run.mcap"),
                 ("init", tmp / "run.mcap", "-o", tmp / "init.json"),
                 ("estimate", tmp / "run.mcap", "--init", tmp / "init.json", "-o", tmp / "states.mcap"))
    return json.loads((tmp / "init.json").read_text()), ints


def test_a_ublox_pair_with_dual_frequency_gps_and_galileo_fixes_the_simulated_integers(ubx_pair):
    init, ints = ubx_pair
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] >= 12
    segs = rover_segments(init, "rover")
    assert {s["signal"] for s in segs} == set(_SIG_ID)
    for s in segs:
        if s["pivot"]:
            continue
        g, sat, ref = s["signal"], s["sat"].split(":")[0], s["reference"].split(":")[0]
        want = (ints["rover"][(g, sat)] - ints["base"][(g, sat)]) - (ints["rover"][(g, ref)] - ints["base"][(g, ref)])
        assert s["integer"] == want, s
    assert np.linalg.norm(list(init["states"].values())) < 0.01            # nominal = true position
