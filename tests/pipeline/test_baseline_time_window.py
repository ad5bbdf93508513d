"""``baseline --start-time / --end-time``: the rule ``rtk`` has (measurement/time_window), on the static GPS L1
baseline.  Checked on the real mosaic-X5 pair: the window asked for gives the solution of the files cut to that window
by hand (RINEX text edited, not tables), and the rover epochs outside are counted with their reason; bad windows exit 2
naming the flag or the file, and write nothing."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.core.gps_time import gps_time_str
from cdgps_cli.measurement.time_window import OUTSIDE_WINDOW, in_window
from cdgps_cli.sim.rinex_edit import edit_rinex3_obs, epoch_times_gps_s
from tests._shared import MOSAIC_DIR, MOSAIC_T0, run_cli

#: rover epochs 08:21:00 – 08:23:00 of the 301 (1 s) the pair holds; the base read 30 s (max age) wider
START, END = MOSAIC_T0 + 60, MOSAIC_T0 + 180


def _baseline(d, name, base, rover, *window):
    out = d / f"{name}.json"
    r = run_cli("-q", "baseline", "--rinex", f"base={base}", "--rinex", f"rover={rover}", "--nav",
                MOSAIC_DIR / "base.nav", "--master", "base", *window, "-o", out)
    assert r.exit_code == 0, r.output
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    d = tmp_path_factory.mktemp("window")
    base, rover = (MOSAIC_DIR / "base.obs").read_text(), (MOSAIC_DIR / "rover.obs").read_text()
    (d / "rover_cut.obs").write_text(edit_rinex3_obs(rover, keep=lambda t: START <= t <= END))
    (d / "base_cut.obs").write_text(edit_rinex3_obs(base, keep=lambda t: START - 30 <= t <= END + 30))
    window = ("--start-time", gps_time_str(START).replace(" GPST", ""), "--end-time",
              gps_time_str(END).replace(" GPST", ""))
    return (_baseline(d, "window", MOSAIC_DIR / "base.obs", MOSAIC_DIR / "rover.obs", *window),
            _baseline(d, "cut", d / "base_cut.obs", d / "rover_cut.obs"), d)


def test_the_window_is_the_files_cut_by_hand(solved):
    win, cut, _ = solved
    assert win["solution"] == cut["solution"] == "fixed"
    assert win["states"] == cut["states"]
    assert win["ambiguities"] == cut["ambiguities"]
    assert win["fixed"] == cut["fixed"]
    assert win["epochs"]["n_epochs_used"] == cut["epochs"]["n_epochs_used"] == 121


def test_every_rover_epoch_outside_is_counted_with_its_reason(solved):
    win, cut, _ = solved
    n_file = epoch_times_gps_s((MOSAIC_DIR / "rover.obs").read_text()).size
    ep = win["epochs"]["epoch_pairing"]
    assert ep["dropped"] == {**cut["epochs"]["epoch_pairing"]["dropped"], OUTSIDE_WINDOW: n_file - 121}
    assert ep["rover_epochs"] == n_file and ep["used"] == 121
    tw = win["epochs"]["time_window"]
    assert (tw["start_gps_s"], tw["end_gps_s"], tw["rover_epochs_outside"]) == (START, END, n_file - 121)
    assert "time_window" not in cut["epochs"]


def test_tags_a_few_ms_early_belong_to_the_next_second():
    t = [START - 0.002, START - 0.03, END - 0.002, END + 0.002, END + 0.03]
    assert in_window(t, START, END, 0.025).tolist() == [True, False, True, True, False]
    assert in_window(t, None, None, 0.025).all()


@pytest.mark.parametrize("window, said", [
    (("--start-time", "2024/06/24 08:21:00", "--end-time", "2024/06/24 08:20:00"),
     "end_gps_s (--end-time): expected at or after start_gps_s"),
    (("--start-time", "2024/06/25 08:21:00"), "rover.obs (rover): no epoch in the window asked for"),
    (("--end-time", "2024-06-24T08:1x:00"), "--end-time expects a GPS date and time"),
])
def test_a_bad_window_exits_2_naming_it_and_writes_nothing(tmp_path, window, said):
    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    out = tmp_path / "bl.json"
    r = run_cli("-q", "baseline", "--rinex", f"base={MOSAIC_DIR / 'base.obs'}", "--rinex",
                f"rover={MOSAIC_DIR / 'rover.obs'}", "--nav", MOSAIC_DIR / "base.nav", "--master", "base", *window,
                "-o", out)
    assert r.exit_code == 2 and said in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()
