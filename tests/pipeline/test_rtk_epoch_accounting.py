"""Every rover epoch of the file is accounted for (issue 28 item 2): an epoch that holds no carrier phase of the
signals used (code only, other systems only) was missing from ``epoch_pairing.rover_epochs`` and from
``dropped`` (the real M8P rover: 1201 reported of its 1202; an edited mosaic rover: 298 of 301); it is now counted
with its reason (gnss_multi._count_epochs_without_phase, the readers' ``file_epochs``)."""

from __future__ import annotations

import json

import pytest

from cdgps_cli.pipeline.gnss_multi import NO_PHASE
from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
BASE_XYZ = (-3817681.1213, 3562839.4311, 3650159.1593)
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")


def _edit_records(text: str, epochs: set, keep) -> str:
    """The RINEX 3 text with the satellite records of the epochs numbered in ``epochs`` kept where
    ``keep(records) -> [bool]`` says (each epoch's record count set to what is left)."""
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    out, e = lines[:i], 0
    while i < len(lines):
        n = int(lines[i][32:35])
        recs = lines[i + 1:i + 1 + n]
        if e in epochs:
            recs = [r for r, k in zip(recs, keep(recs)) if k]
        out += [lines[i][:32] + f"{len(recs):3d}" + lines[i][35:], *recs]
        i, e = i + 1 + n, e + 1
    return "\n".join(out) + "\n"


def _without_system(text: str, system: str, epochs: set) -> str:
    """The RINEX 3 text with the records of ``system`` removed from the epochs numbered in ``epochs``."""
    return _edit_records(text, epochs, lambda recs: [r[0] != system for r in recs])


def test_epochs_without_a_phase_of_the_signals_used_are_counted(tmp_path):
    rover = tmp_path / "rover.obs"
    rover.write_text(_without_system((MOSAIC / "rover.obs").read_text(), "E", {10, 11, 200}))
    out = {}
    for sig in ("E:E1", "G:L1"):
        r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", rover, "--nav", MOSAIC / "base.nav",
                    "--base-xyz", *BASE_XYZ, "--signals", sig, "-o", tmp_path / "x.csv", "--json")
        assert r.exit_code == 0, r.output
        out[sig] = json.loads(r.stdout)
    ep = out["E:E1"]["epoch_pairing"]
    assert ep["rover_epochs"] == 301 and ep["used"] == 298 and ep["dropped"] == {NO_PHASE: 3}
    assert any(f"3 of 301 epochs not used: 3 {NO_PHASE}" in w for w in out["E:E1"]["warnings"])
    ep = out["G:L1"]["epoch_pairing"]                    # GPS is still in those epochs: nothing to count
    assert ep["rover_epochs"] == 301 and ep["used"] == 301 and ep["dropped"] == {}


def _one_satellite_of(text: str, system: str, epochs: set) -> str:
    """The RINEX 3 text with only the first record of ``system`` left in the epochs numbered in ``epochs``."""
    def keep(recs):
        first = next(k for k, r in enumerate(recs) if r[0] == system)
        return [r[0] != system or k == first for k, r in enumerate(recs)]
    return _edit_records(text, epochs, keep)


def test_epochs_without_a_double_difference_are_not_written_and_are_counted(tmp_path):
    """An epoch whose signals leave no double difference (here one Galileo satellite at the rover for ten epochs,
    E:E1 alone) has no measurement: the filter only predicts through it.  It used to be written as a float
    solution (the neighbours' positions interpolated, ns 0; a real F9P car in Hong Kong had 29 of 200); now it has
    no line, as in RTKLIB's output, and the summary counts it in ``dropped`` with its reason."""
    import numpy as np
    import pandas as pd

    from cdgps_cli.measurement.epoch_pairing import NO_DD

    rover = tmp_path / "rover.obs"
    rover.write_text(_one_satellite_of((MOSAIC / "rover.obs").read_text(), "E", set(range(50, 60))))
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", rover, "--nav", MOSAIC / "base.nav",
                "--base-xyz", *BASE_XYZ, "--signals", "E:E1", "-o", tmp_path / "x.csv", "--json")
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    ep = s["epoch_pairing"]
    assert ep["rover_epochs"] == 301 and ep["used"] == 291 == s["epochs"] and ep["dropped"] == {NO_DD: 10}
    assert any(f"10 of 301 epochs not used: 10 {NO_DD}" in w for w in s["warnings"])
    df = pd.read_csv(tmp_path / "x.csv", comment="#")
    t0 = 1403252400.0                                    # the rover's first epoch; one line per second after it
    assert len(df) == 291 and (df["n_satellites"] >= 2).all()
    assert not set(np.round(df["time_gps_s"] - t0).astype(int)) & set(range(50, 60))


def test_baseline_and_init_count_the_epochs_without_a_double_difference_as_rtk_does(tmp_path):
    """The same accounting in the static solution of ``baseline`` and ``init`` (``baseline._prepare``): the real M8P
    pair's rover epoch with codes and no phase was used by the pairing (1202 of 1202) and by no double difference
    (1201), without a word.  Here GPS L1 with one satellite left at the rover for ten epochs."""
    from cdgps_cli.measurement.epoch_pairing import NO_DD

    rover = tmp_path / "rover.obs"
    rover.write_text(_one_satellite_of((MOSAIC / "rover.obs").read_text(), "G", set(range(50, 60))))
    out = tmp_path / "b.json"
    r = run_cli("baseline", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                MOSAIC / "base.nav", "--master", "base", "-o", out)
    assert r.exit_code == 0, r.output
    e = json.loads(out.read_text())["epochs"]
    assert e["n_epochs_common"] == 301 and e["n_epochs_used"] == 291
    assert e["epoch_pairing"]["used"] == 291 and e["epoch_pairing"]["dropped"] == {NO_DD: 10}
    assert f"rover: 10 of 301 paired epochs not used: {NO_DD}" in " ".join(r.output.split())


def _split(text: str, at: int, overlap: int) -> tuple[str, str]:
    """The RINEX 3 text cut into two files of one record: epochs ``0 … at + overlap − 1`` and ``at …`` (the second
    repeating ``overlap`` epochs of the first), each with the header."""
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    head, starts = lines[:i], []
    while i < len(lines):
        starts.append(i)
        i += 1 + int(lines[i][32:35])
    starts.append(len(lines))
    first = head + lines[starts[0]:starts[at + overlap]]
    second = head + lines[starts[at]:]
    return "\n".join(first) + "\n", "\n".join(second) + "\n"


def test_a_rover_in_several_files_counts_its_epochs_without_phase_too(tmp_path):
    """Found by a sweep of real files: the M8P rover cut into two files that overlap by 5 epochs reported 1201 rover
    epochs and nothing dropped, where the one file reports 1202 and its code-only epoch (session 30)."""
    text = _without_system((MOSAIC / "rover.obs").read_text(), "E", {10, 11, 200})
    parts = _split(text, 150, 5)
    for k, part in enumerate(parts):
        (tmp_path / f"rover_{k}.obs").write_text(part)
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", tmp_path / "rover_0.obs", "--rover",
                tmp_path / "rover_1.obs", "--nav", MOSAIC / "base.nav", "--base-xyz", *BASE_XYZ, "--signals", "E:E1",
                "-o", tmp_path / "x.csv", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    ep = out["epoch_pairing"]
    assert ep["rover_epochs"] == 301 and ep["used"] == 298 and ep["dropped"] == {NO_PHASE: 3}, ep
    assert any("repeats 5 epoch(s)" in w for w in out["warnings"]), out["warnings"]


def test_an_epoch_both_files_hold_without_phase_counts_once(tmp_path):
    """A review's case: the two files overlap on epochs 150–159 and epoch 155, in both, holds no satellite; counted
    over the files' own epochs (their union), not as each file's count less the phase table's overlap (302)."""
    text = _edit_records((MOSAIC / "rover.obs").read_text(), {155}, lambda recs: [False] * len(recs))
    for k, part in enumerate(_split(text, 150, 10)):
        (tmp_path / f"rover_{k}.obs").write_text(part)
    r = run_cli("-q", "rtk", "--base", MOSAIC / "base.obs", "--rover", tmp_path / "rover_0.obs", "--rover",
                tmp_path / "rover_1.obs", "--nav", MOSAIC / "base.nav", "--base-xyz", *BASE_XYZ, "--signals", "G:L1",
                "-o", tmp_path / "x.csv", "--json")
    assert r.exit_code == 0, r.output
    ep = json.loads(r.stdout)["epoch_pairing"]
    assert ep["rover_epochs"] == 301 and ep["dropped"] == {NO_PHASE: 1}, ep
