"""Bad receiver pairs refused by every GNSS command (issue 28, "How it is checked"): no common epochs,
no common satellites, a base position of 0 0 0, a navigation file of another day → exit 2, one
message naming the file(s) and what is missing, no traceback, no output written.

Commands: ``rtk``, ``baseline``, ``ingest`` (which refuses these runs, so ``init`` never meets
them) and ``init`` on a GNSS RUN whose satellites are all below its mask.  The files are the first
30 epochs of the real mosaic-static pair, edited: even-numbered satellites kept at the base and
odd ones at the rover; the base header's APPROX POSITION XYZ set to 0 0 0; the 2005 GEONET file
and navigation file as another day.
"""

import pytest

from tests._shared import REPO_ROOT, run_cli

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC = SHARED / "real-pairs" / "mosaic-static"
GEO = SHARED / "rinex"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
N_EPOCHS = 30


def _cut(text: str, keep_sat=lambda s: True, zero_position: bool = False) -> str:
    """The header (APPROX POSITION XYZ zeroed if asked) and the first epochs, satellites filtered."""
    lines = text.splitlines()
    out, i = [], 0
    while "END OF HEADER" not in lines[i][60:]:
        ln = lines[i]
        if zero_position and ln[60:].strip() == "APPROX POSITION XYZ":
            ln = f"{0.0:14.4f}{0.0:14.4f}{0.0:14.4f}".ljust(60) + "APPROX POSITION XYZ"
        out.append(ln)
        i += 1
    out.append(lines[i])
    i += 1
    for _ in range(N_EPOCHS):
        n = int(lines[i][32:35])
        body = [b for b in lines[i + 1:i + 1 + n] if keep_sat(b[:3])]
        out += [lines[i][:32] + f"{len(body):3d}" + lines[i][35:], *body]
        i += 1 + n
    return "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad_pairs")
    base, rover = (MOSAIC / "base.obs").read_text(), (MOSAIC / "rover.obs").read_text()
    (d / "base.obs").write_text(_cut(base))
    (d / "rover.obs").write_text(_cut(rover))
    (d / "base_even.obs").write_text(_cut(base, lambda s: int(s[1:]) % 2 == 0))
    (d / "rover_odd.obs").write_text(_cut(rover, lambda s: int(s[1:]) % 2 == 1))
    (d / "base_000.obs").write_text(_cut(base, zero_position=True))
    return d


#: case → (base, rover, navs, words the message must hold); None: the folder's file
CASES = {
    "no common epochs": ("GEO:07590920.05o", "rover.obs", ["MOSAIC:base.nav", "GEO:07590920.05n"],
                         ["no common epochs", "07590920.05o", "rover.obs"]),
    "no common satellites": ("base_even.obs", "rover_odd.obs", ["MOSAIC:base.nav"],
                             ["no common satellites", "base_even.obs", "rover_odd.obs"]),
    "base 0 0 0": ("base_000.obs", "rover.obs", ["MOSAIC:base.nav"], ["base_000.obs", "APPROX POSITION XYZ"]),
    "nav of another day": ("base.obs", "rover.obs", ["GEO:07590920.05n"],
                           ["07590920.05n", "navigation", "2024-06-24", "2005-04"]),
}


def _path(files, name):
    if name.startswith("GEO:"):
        return GEO / name[4:]
    if name.startswith("MOSAIC:"):
        return MOSAIC / name[7:]
    return files / name


def _assert_refused(r, want, out):
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert all(w in r.stderr for w in want), (want, r.stderr)
    assert not out.exists()


@pytest.mark.parametrize("command", ["rtk", "baseline", "ingest"])
@pytest.mark.parametrize("case", list(CASES))
def test_bad_pair_exits_2_naming_the_files(files, tmp_path, command, case):
    b, rv, navs, want = CASES[case]
    base, rover, navs = _path(files, b), _path(files, rv), [_path(files, n) for n in navs]
    nav_args = [a for n in navs for a in ("--nav", n)]
    if command == "rtk":
        out = tmp_path / "out.pos"
        if case == "nav of another day":     # rtk names the file whose ephemerides are missing
            want = ["07590920.05n", "2024-06-24"]
        r = run_cli("-q", "rtk", "--base", base, "--rover", rover, *nav_args, "--signals", "G:L1", "-o", out)
    elif command == "baseline":
        out = tmp_path / "out.json"
        r = run_cli("-q", "baseline", "--rinex", f"base={base}", "--rinex", f"rover={rover}", *nav_args,
                    "--master", "base", "-o", out)
    else:
        out = tmp_path / "run.mcap"
        r = run_cli("-q", "ingest", "--rinex", f"base={base}", "--rinex", f"rover={rover}", *nav_args,
                    "--master", "base", "-o", out)
    _assert_refused(r, want, out)
    assert list(tmp_path.iterdir()) == []


def test_init_on_a_run_without_double_differences_names_the_files(files, tmp_path):
    """A run whose every satellite is below its mask (mask_deg = 89): ingest accepts it (it has no
    geometry), init refuses it naming both receivers' files and the mask."""
    cfg = tmp_path / "run.toml"
    cfg.write_text("\n".join(["[gnss]", 'master = "base"', f'nav = ["{MOSAIC / "base.nav"}"]', "mask_deg = 89.0",
                              '[gnss.antennas."base"]', f'rinex = "{files / "base.obs"}"',
                              '[gnss.antennas."rover"]', f'rinex = "{files / "rover.obs"}"', ""]))
    r = run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    out = tmp_path / "init.json"
    r = run_cli("-q", "init", tmp_path / "run.mcap", "-o", out)
    _assert_refused(r, ["no double differences", "base.obs", "rover.obs", "89° mask"], out)


def test_ingest_with_an_unreadable_config_names_its_toml_error(tmp_path):
    """A GNSS config that is not valid TOML (a key given twice) is named as such, not taken for a
    structure ingest missing its receiver CSV."""
    cfg = tmp_path / "run.toml"
    cfg.write_text('[gnss]\nmaster = "base"\n[gnss.antennas."base"]\nrinex = "a.obs"\nrinex = "b.obs"\n')
    r = run_cli("-q", "ingest", "--config", cfg, "-o", tmp_path / "run.mcap")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert "run.toml" in r.stderr and "RECEIVER_CSV" not in r.stderr, r.stderr
    assert not (tmp_path / "run.mcap").exists()


def test_init_on_an_older_run_without_common_satellites_names_the_files(files, tmp_path, monkeypatch):
    """A RUN written before ingest refused pairs without a common satellite (the check switched off
    here): init refuses it naming both receivers' files."""
    import cdgps_cli.pipeline.gnss_ingest as gi

    monkeypatch.setattr(gi, "_check_common_satellites", lambda *a, **k: None)
    r = run_cli("-q", "ingest", "--rinex", f"base={files / 'base_even.obs'}", "--rinex", f"rover={files / 'rover_odd.obs'}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    out = tmp_path / "init.json"
    r = run_cli("-q", "init", tmp_path / "run.mcap", "-o", out)
    _assert_refused(r, ["no common satellites", "base_even.obs", "rover_odd.obs"], out)
