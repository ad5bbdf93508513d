"""A receiver's clock in the displacement path (``init``) of a multi-signal run comes from every system's codes.

The batch tables place each row at its true reception instant, tag − clock.  The clock was estimated from the
GPS L1 (anchor) codes alone, and an epoch without a usable one took it interpolated (held, before the first):
a real F9P pair whose GPS ephemerides begin 34 min into the record had its clock 88 µs off there, and the
Galileo rows' satellites moved by centimetres in the double differences (DD phase rms 25 → 10 mm with the
fix, 20 of 24 → 22 of 24 integers fixed, 3.7 → 0.9 mm from RTKLIB's static solution).

Here the real mosaic-static pair (G + E) is edited (:func:`cdgps_cli.sim.rinex_edit.edit_rinex3_obs`): the
rover's clock drifts 20 µs/s and resets by 1 ms every minute, as a u-blox clock does, and its GPS L1 codes
are blanked for the first 60 epochs.  The double differences are those of the real pair, so ``init`` must
give the real pair's solution.
"""

import json
import math

import numpy as np
import pytest

from cdgps_cli.core.gps_time import gps_seconds
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
T0 = 1403252400.0          # the pair's first epoch, GPS s
BLANK_S = 60.0


def _clock_s(t: float) -> float:
    """A u-blox-like rover clock: 20 µs/s of drift, back by 1 ms every 60 s."""
    return 20e-6 * ((t - T0) % 60.0) - 0.6e-3


def _blank_gps_l1_code(text: str) -> str:
    """The GPS C1C field (the header's second GPS type) blanked in every epoch before T0 + BLANK_S."""
    out, blank = [], False
    for ln in text.splitlines():
        if ln.startswith(">"):
            y, mo, d, h, mi = (int(x) for x in ln[1:].split()[:5])
            s = float(ln[1:].split()[5])
            blank = gps_seconds(y, mo, d, h, mi, s) < T0 + BLANK_S
        elif blank and ln.startswith("G"):
            ln = ln[:19] + " " * 16 + ln[35:] if len(ln) > 19 else ln
        out.append(ln)
    return "\n".join(out) + "\n"


def _run(d, rover, name, base=MOSAIC / "base.obs"):
    cfg = d / f"{name}.toml"
    cfg.write_text(f'[gnss]\nname = "{name}"\nmaster = "base"\nnav = ["{MOSAIC / "base.nav"}"]\n'
                   f'signals = ["G:L1", "E:E1"]\n\n[gnss.antennas.base]\nrinex = "{base}"\n\n'
                   f'[gnss.antennas.rover]\nrinex = "{rover}"\n')
    r = run_cli("-q", "ingest", "--config", cfg, "-o", d / f"{name}.mcap")
    assert r.exit_code == 0, r.output
    r = run_cli("-q", "init", d / f"{name}.mcap", "-o", d / f"{name}.json")
    assert r.exit_code == 0, r.output
    return json.loads((d / f"{name}.json").read_text())["rovers"]["rover"]


def test_a_clock_the_gps_codes_cannot_give_is_taken_from_the_galileo_codes(tmp_path):
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs

    edited = edit_rinex3_obs((MOSAIC / "rover.obs").read_text(), clock_offset_s=_clock_s,
                             keep=lambda t: t <= T0 + 180)
    (tmp_path / "rover_edited.obs").write_text(_blank_gps_l1_code(edited))
    (tmp_path / "rover_plain.obs").write_text(edit_rinex3_obs((MOSAIC / "rover.obs").read_text(),
                                                              keep=lambda t: t <= T0 + 180))
    plain = _run(tmp_path, tmp_path / "rover_plain.obs", "plain")
    got = _run(tmp_path, tmp_path / "rover_edited.obs", "edited")
    assert plain["residuals"]["dd_phase_rms_m"] < 0.01
    # the same double differences: the same residuals and solution (the GPS codes of a minute are missing)
    assert got["residuals"]["dd_phase_rms_m"] < 1.2 * plain["residuals"]["dd_phase_rms_m"], got["residuals"]
    assert got["n_fixed"] == plain["n_fixed"]
    gap_mm = 1e3 * np.linalg.norm(np.subtract(got["rover_ecef_m"], plain["rover_ecef_m"]))
    assert gap_mm < 1.0, gap_mm
    assert math.isfinite(gap_mm)


def test_a_master_epoch_bridged_to_several_rover_epochs_keeps_one_clock(tmp_path):
    """A master logging every 5 s with the u-blox-like clock, the rover at 1 s: each master epoch serves five rover
    epochs and is one measurement instant, so one clock (a clock per rover epoch, from rows given to one of them
    only, put the DDs decimetres off: DD phase rms 73 mm against 2.5 mm)."""
    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs

    keep = lambda t: t <= T0 + 180 and round(t - T0) % 5 == 0          # noqa: E731
    base = (MOSAIC / "base.obs").read_text()
    (tmp_path / "base_plain.obs").write_text(edit_rinex3_obs(base, keep=keep))
    (tmp_path / "base_clock.obs").write_text(edit_rinex3_obs(base, clock_offset_s=_clock_s, keep=keep))
    (tmp_path / "rover.obs").write_text(edit_rinex3_obs((MOSAIC / "rover.obs").read_text(), keep=lambda t: t <= T0 + 180))
    plain = _run(tmp_path, tmp_path / "rover.obs", "plain", base=tmp_path / "base_plain.obs")
    got = _run(tmp_path, tmp_path / "rover.obs", "clock", base=tmp_path / "base_clock.obs")
    assert plain["epochs"]["epoch_pairing"]["bridged"] > 100
    assert got["residuals"]["dd_phase_rms_m"] < 1.2 * plain["residuals"]["dd_phase_rms_m"], got["residuals"]
    assert got["n_fixed"] == plain["n_fixed"]
