"""Any single system carries the displacement path alone (issue 28 item 3): ingest → init → estimate
on the Spirent GPS + Galileo set (../shared/data/rinex-ge, first 120 s of the base and the static
rover 2 km east) with GPS only, Galileo only (Galileo navigation file only; and files with every GPS
record and observation type removed) and GPS + Galileo, dual frequency: each within 5 mm of the
true rover position.  Without ``G:L1`` among the signals, the first signal listed fixes the
receivers' epochs and clocks (``core.signals.anchor_signal``); with it, nothing changes.
"""

import json

import numpy as np
import pytest

from cdgps_cli.core.signals import anchor_signal
from cdgps_cli.io.states import States
from tests._shared import REPO_ROOT, run_cli

GE = REPO_ROOT.parent / "shared" / "data" / "rinex-ge"
pytestmark = pytest.mark.skipif(not GE.exists(), reason="../shared/data/rinex-ge absent")
BASE_XYZ = [4157177.06580187, 671230.476590636, 4774767.03105544]          # README: true ECEF
ROVER_XYZ = np.array([4156857.1195929, 673209.028774142, 4774767.03105544])
GPS_NAV, GAL_NAV = GE / "RINEX_GN_Spirent.23N", GE / "RINEX_EN_Spirent.23L"
N_EPOCHS = 120


def _cut(text: str, drop_gps: bool) -> str:
    """The header and first epochs; ``drop_gps``: without GPS records and GPS header lines."""
    lines = text.splitlines()
    out, i = [], 0
    while "END OF HEADER" not in lines[i][60:]:
        ln, label = lines[i], lines[i][60:].strip()
        i += 1
        if drop_gps and label in ("SYS / # / OBS TYPES", "SYS / PHASE SHIFT") and ln[0] == "G":
            n = int(ln[3:6]) if label == "SYS / # / OBS TYPES" else 0
            while n > 13:                                   # continuation lines of the G types
                i, n = i + 1, n - 13
            continue
        out.append(ln)
    out.append(lines[i])
    i += 1
    for _ in range(N_EPOCHS):
        n = int(lines[i][32:35])
        body = [b for b in lines[i + 1:i + 1 + n] if not (drop_gps and b[0] == "G")]
        out += [lines[i][:32] + f"{len(body):3d}" + lines[i][35:], *body]
        i += 1 + n
    return "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("one_system")
    for name, src in (("base", "Base-static_MO_Spirent.obs"), ("rover", "Rover-static-2km-east_MO_Spirent.obs")):
        text = (GE / src).read_text()
        (d / f"{name}.obs").write_text(_cut(text, False))
        (d / f"{name}_E.obs").write_text(_cut(text, True))
    return d


def _pipeline(d, tag, signals, navs, suffix=""):
    cfg = d / f"{tag}.toml"
    cfg.write_text("\n".join([
        "[gnss]", 'master = "base"', f"nav = {json.dumps([str(n) for n in navs])}", f"signals = {json.dumps(signals)}",
        '[gnss.antennas."base"]', f'rinex = "{d / f"base{suffix}.obs"}"', f"position_ecef_m = {BASE_XYZ}",
        '[gnss.antennas."rover"]', f'rinex = "{d / f"rover{suffix}.obs"}"', ""]))
    for args in (("ingest", "--config", cfg, "-o", d / f"{tag}.mcap"), ("init", d / f"{tag}.mcap", "-o", d / f"{tag}.json"),
                 ("estimate", d / f"{tag}.mcap", "--init", d / f"{tag}.json", "-o", d / f"{tag}.states.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    return json.loads((d / f"{tag}.json").read_text()), States(d / f"{tag}.states.mcap")


@pytest.mark.parametrize("tag,signals,navs,suffix", [
    ("gps", ["G:L1", "G:L2"], [GPS_NAV], ""),
    ("galileo", ["E:E1", "E:E5a"], [GAL_NAV], ""),                 # the files hold GPS too; no GPS ephemeris
    ("galileo_files", ["E:E1", "E:E5a"], [GAL_NAV], "_E"),       # no GPS anywhere
    ("gps_galileo", ["G:L1", "G:L2", "E:E1", "E:E5a"], [GPS_NAV, GAL_NAV], ""),
])
def test_each_system_alone_and_together_within_5_mm(files, tag, signals, navs, suffix):
    init, st = _pipeline(files, tag, signals, navs, suffix)
    rov = init["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["n_fixed"] == rov["n_estimated"] >= 8
    assert rov["epochs"]["n_epochs_used"] == N_EPOCHS
    err = np.array(rov["rover_ecef_m"]) - ROVER_XYZ
    assert np.linalg.norm(err) < 0.005, err
    assert {b["satellite"].split(":")[1] for b in init["biases"]} == {s.split(":")[1] for s in signals}
    q = st.q
    assert q.shape == (N_EPOCHS, 3) and np.array_equal(q[0], [rov["states"][f"rover_{c}"] for c in "enu"])


def test_the_anchor_signal():
    assert anchor_signal(None) is None and anchor_signal([]) is None
    assert anchor_signal(["E:E1", "G:L1"]) is None                 # GPS L1 present: as before
    assert anchor_signal(["E:E5a", "E:E1"]) == "E:E5a" and anchor_signal(["C:B1I"]) == "C:B1I"


MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"


@pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
@pytest.mark.parametrize("signals,ref,tol_m", [
    (["E:E1"], (-0.2275, -0.9638, 0.0079), 0.001),          # RTKLIB Galileo E1 only, kinematic fixed mean (README)
    (["C:B1I", "C:B2I"], (-0.2237, -0.9647, 0.0090), 0.003)])   # RTKLIB multi-GNSS L1+L2 static
def test_one_system_on_the_real_pair(tmp_path, signals, ref, tol_m):
    """The real Septentrio pair with Galileo alone or BeiDou alone, anchored on that system."""
    cfg = tmp_path / "run.toml"
    cfg.write_text("\n".join([
        "[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]', f"signals = {json.dumps(signals)}",
        '[gnss.antennas."base"]', f'rinex = "{MOSAIC / "base.obs"}"', "position_ecef_m = [-3817681.1213, 3562839.4311, 3650159.1593]",
        '[gnss.antennas."rover"]', f'rinex = "{MOSAIC / "rover.obs"}"', ""]))
    for args in (("ingest", "--config", cfg, "-o", tmp_path / "run.mcap"), ("init", tmp_path / "run.mcap", "-o", tmp_path / "i.json")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, (args, r.output)
    rov = json.loads((tmp_path / "i.json").read_text())["rovers"]["rover"]
    assert rov["solution"] == "fixed" and rov["epochs"]["n_epochs_used"] == 301
    assert np.all(np.abs(np.array(rov["baseline_enu_from_master_m"]) - ref) < tol_m), rov["baseline_enu_from_master_m"]
