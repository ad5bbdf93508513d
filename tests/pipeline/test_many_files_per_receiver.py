"""``cdgps rtk`` and ``cdgps baseline`` with a receiver's consecutive files (hourly or daily logs, as CORS networks publish
them) given as one record: ``--base`` repeated or a quoted glob.

The real mosaic-static pair (RINEX 3.04, 301 epochs at 1 s) is cut into pieces: the base into
three files that overlap by 10 epochs, given out of time order; the rover into two.  The joined
solution must equal the one-file solution row for row (only the ``inp file`` header lines differ),
and files that are not one record (another receiver, interleaved epochs) are refused with exit 2,
naming the file, and nothing written.
"""

import json
import re

import pytest

from tests._shared import REPO_ROOT, run_cli

MOSAIC = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "mosaic-static"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data/real-pairs absent")
SPAN = 90          # epochs of the pair used (seconds)


def _split(text: str) -> tuple[str, list[str]]:
    """RINEX 3 observation text → (header, the epoch records, each its '>' line and body)."""
    head, body = text.split("END OF HEADER", 1)
    head += "END OF HEADER" + body[:body.index("\n") + 1]
    body = body[body.index("\n") + 1:]
    epochs = [">" + e for e in body.split("\n>")]
    epochs[0] = epochs[0][1:]
    return head, [e if e.endswith("\n") else e + "\n" for e in epochs]


def _write(path, head: str, epochs: list[str]) -> None:
    path.write_text(head + "".join(epochs))


@pytest.fixture(scope="module")
def pieces(tmp_path_factory):
    d = tmp_path_factory.mktemp("many_files")
    bh, be = _split((MOSAIC / "base.obs").read_text())
    rh, re_ = _split((MOSAIC / "rover.obs").read_text())
    be, re_ = be[:SPAN], re_[:SPAN]
    _write(d / "base.obs", bh, be)
    _write(d / "rover.obs", rh, re_)
    _write(d / "base_a.obs", bh, be[:40])
    _write(d / "base_b.obs", bh, be[30:70])       # 10 epochs repeated from base_a
    _write(d / "base_c.obs", bh, be[70:])
    _write(d / "rover_1.obs", rh, re_[:45])
    _write(d / "rover_2.obs", rh, re_[45:])
    other = bh.replace("SEPT MOSAIC-X5      4.14.4", "SEPT POLARX5        5.4.0 ")
    assert other != bh
    _write(d / "base_other_receiver.obs", other, be[70:])
    _write(d / "base_odd.obs", bh, be[0:40:2])
    _write(d / "base_even_late.obs", bh, be[1:40:2])       # epochs inside base_odd's span that it lacks
    return d


def _body(path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("%")]


def _rtk(d, out, *args):
    return run_cli("-q", "rtk", *args, "--nav", MOSAIC / "base.nav", "--signals", "G:L1", "-o", out, "--json")


def test_a_receivers_files_joined_give_the_one_file_solution(pieces, tmp_path):
    one = _rtk(pieces, tmp_path / "one.pos", "--base", pieces / "base.obs", "--rover", pieces / "rover.obs")
    assert one.exit_code == 0, one.output
    many = _rtk(pieces, tmp_path / "many.pos", "--base", pieces / "base_c.obs", "--base", pieces / "base_a.obs",
                "--base", pieces / "base_b.obs", "--rover", str(pieces / "rover_*.obs"))
    assert many.exit_code == 0, many.output
    body = _body(tmp_path / "one.pos")
    assert len(body) == SPAN and _body(tmp_path / "many.pos") == body
    s_one, s_many = (json.loads(r.stdout[r.stdout.index("{"):]) for r in (one, many))
    assert s_many["epochs"] == s_one["epochs"] == SPAN
    assert s_many["fixed_epochs"] == s_one["fixed_epochs"] > 0
    assert s_many["epoch_pairing"]["base_epochs"] == SPAN
    # every file is named as an input, in time order within each receiver
    inputs = re.findall(r"^% inp file  : (.*)$", (tmp_path / "many.pos").read_text(), re.M)
    assert [i.rsplit("/", 1)[-1] for i in inputs] == ["rover_1.obs", "rover_2.obs", "base_c.obs", "base_a.obs",
                                                       "base_b.obs", "base.nav"]


@pytest.mark.parametrize("bases, words", [
    (["base_a.obs", "base_other_receiver.obs"], ["base_other_receiver.obs", "receiver_type", "one receiver's record"]),
    (["base_odd.obs", "base_even_late.obs"], ["base_even_late.obs", "base_odd.obs", "not consecutive"]),
    (["base_a.obs", "base_a.obs"], ["--base", "given twice"]),
    (["base_[xyz].obs"], ["--base", "matches no file"]),
])
def test_files_that_are_not_one_record_are_refused(pieces, tmp_path, bases, words):
    out = tmp_path / "out.pos"
    args = [a for b in bases for a in ("--base", pieces / b)]
    r = _rtk(pieces, out, *args, "--rover", pieces / "rover.obs")
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    assert all(w in r.output for w in words), r.output
    assert not out.exists()


def test_an_output_that_is_one_of_the_inputs_is_refused(pieces, tmp_path):
    rover = tmp_path / "rover_2.obs"
    rover.write_text((pieces / "rover_2.obs").read_text())
    r = _rtk(pieces, rover, "--base", pieces / "base.obs", "--rover", pieces / "rover_1.obs", "--rover", rover)
    assert r.exit_code == 2 and "would overwrite an input" in r.output, r.output
    assert rover.read_text() == (pieces / "rover_2.obs").read_text()


def test_baseline_joins_a_stations_files_as_rtk_does(pieces, tmp_path):
    nav = MOSAIC / "base.nav"
    one = run_cli("-q", "baseline", "--rinex", f"base={pieces / 'base.obs'}", "--rinex", f"rover={pieces / 'rover.obs'}",
                  "--nav", nav, "--master", "base", "-o", tmp_path / "one.json")
    assert one.exit_code == 0, one.output
    many = run_cli("-q", "baseline", "--rinex", f"base={pieces / 'base_c.obs'}", "--rinex", f"base={pieces / 'base_a.obs'}",
                   "--rinex", f"base={pieces / 'base_b.obs'}", "--rinex", f"rover={pieces / 'rover_*.obs'}",
                   "--nav", nav, "--master", "base", "-o", tmp_path / "many.json")
    assert many.exit_code == 0, many.output
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("one.json", "many.json"))
    assert b["inputs"]["rinex"]["base"][0].endswith("base_c.obs") and len(b["inputs"]["rinex"]["rover"]) == 2
    for d in (a, b):
        d.pop("inputs")
        d.pop("warnings", None)
    assert a == b
    bad = run_cli("-q", "baseline", "--rinex", f"base={pieces / 'base_a.obs'}",
                  "--rinex", f"base={pieces / 'base_other_receiver.obs'}", "--rinex", f"rover={pieces / 'rover.obs'}",
                  "--nav", nav, "--master", "base", "-o", tmp_path / "bad.json")
    assert bad.exit_code == 2 and "one receiver's record" in bad.output and not (tmp_path / "bad.json").exists()


@pytest.mark.parametrize("command", ["rtk", "baseline"])
def test_an_output_matched_by_an_input_pattern_is_refused(pieces, tmp_path, command):
    """A quoted glob's files are inputs too: writing over one of them is refused, as over a named input."""
    for name in ("rover_1.obs", "rover_2.obs"):
        (tmp_path / name).write_text((pieces / name).read_text())
    victim = tmp_path / "rover_2.obs"
    before = victim.read_text()
    pattern = str(tmp_path / "rover_*.obs")
    if command == "rtk":
        r = _rtk(pieces, victim, "--base", pieces / "base.obs", "--rover", pattern)
    else:
        r = run_cli("-q", "baseline", "--rinex", f"base={pieces / 'base.obs'}", "--rinex", f"rover={pattern}",
                    "--nav", MOSAIC / "base.nav", "--master", "base", "-o", victim)
    assert r.exit_code == 2 and "would overwrite an input" in r.output, r.output
    assert victim.read_text() == before


WALK = REPO_ROOT.parent / "shared" / "data" / "real-pairs" / "ublox-walk"


@pytest.mark.skipif(not WALK.exists(), reason="../shared/data/real-pairs/ublox-walk absent")
def test_consecutive_ubx_logs_are_one_byte_stream(tmp_path):
    """A real u-blox log cut into three files at arbitrary bytes (frames cut in two, as a logger rotating its
    files does): given out of order, they are decoded as one stream, so the solution is the whole log's (decoded
    one by one, a frame cut at each boundary was lost)."""
    log = (WALK / "gnss_1730.ubx").read_bytes()
    cuts = [0, len(log) // 3 + 7, 2 * len(log) // 3 + 3, len(log)]
    for i in range(3):
        (tmp_path / f"part{i}.ubx").write_bytes(log[cuts[i]:cuts[i + 1]])
    args = ["--rover", WALK / "gnss_1730_convbin.obs", "--signals", "G:L1,E:E1",
            "--base-xyz", "-1276975.6547", "-4717238.8712", "4087235.6076"]
    one = run_cli("-q", "rtk", "--base", WALK / "gnss_1730.ubx", *args, "-o", tmp_path / "one.csv")
    many = run_cli("-q", "rtk", "--base", tmp_path / "part2.ubx", "--base", tmp_path / "part0.ubx",
                   "--base", tmp_path / "part1.ubx", *args, "-o", tmp_path / "many.csv")
    assert one.exit_code == 0 and many.exit_code == 0, (one.output, many.output)
    body = [ln for ln in (tmp_path / "one.csv").read_text().splitlines() if not ln.startswith("#")]
    assert len(body) > 100
    assert [ln for ln in (tmp_path / "many.csv").read_text().splitlines() if not ln.startswith("#")] == body


def test_a_gap_between_files_of_a_base_logging_with_gaps_counts_its_epochs_at_its_sampling(tmp_path):
    """A base that logs with gaps (1–8 s apart, sampled at 1 s) in two files with 60 s between them: the epochs
    missing are counted at the interval the receiver samples at, not at its median spacing (a sweep of real
    u-blox files: "gap of 313 s (103 epochs missing)" for a 1 s log)."""
    import re

    from cdgps_cli.sim.rinex_edit import edit_rinex3_obs
    from tests._shared import MOSAIC_DIR, MOSAIC_T0, write_gappy_mosaic_pair

    if not MOSAIC_DIR.exists():
        pytest.skip("../shared/data/real-pairs absent")
    base, rover = write_gappy_mosaic_pair(tmp_path)
    text = base.read_text()
    first = edit_rinex3_obs(text, keep=lambda t: t < MOSAIC_T0 + 100)
    second = edit_rinex3_obs(text, keep=lambda t: t >= MOSAIC_T0 + 160)
    (tmp_path / "b1.obs").write_text(first)
    (tmp_path / "b2.obs").write_text(second)
    r = run_cli("ingest", "--rinex", f"base={tmp_path / 'b1.obs'}", "--rinex", f"base={tmp_path / 'b2.obs'}",
                "--rinex", f"rover={rover}", "--nav", MOSAIC_DIR / "base.nav", "--master", "base", "-o",
                tmp_path / "run.mcap", "--json", "-q")
    assert r.exit_code == 0, r.output
    gap = [w for w in json.loads(r.stdout)["warnings"] if "gap of" in w]
    assert len(gap) == 1, gap
    g, missing = (float(x) for x in re.search(r"gap of ([\d.]+) s \((\d+) epochs missing\)", gap[0]).groups())
    assert missing == round(g) - 1, gap[0]                 # at 1 s, whatever the base's median spacing


def test_config_takes_a_quoted_glob_of_an_antenna_s_files(tmp_path):
    """`cdgps config --rinex 'A=PATTERN'`: the header read from the first file, the pattern written into the config
    (which `ingest` then joins); it said "cannot read: No such file" of the pattern (a sweep of real files)."""
    shared = REPO_ROOT.parent / "shared" / "data" / "rinex"
    if not (shared / "30400920.05o").exists():
        pytest.skip("../shared/data/rinex absent")
    out = tmp_path / "cfg.toml"
    r = run_cli("config", "--rinex", f"a={shared}/3040*.05o", "--rinex", f"b={shared / '07590920.05o'}", "--nav",
                shared / "30400920.05n", "-o", out, "-q")
    assert r.exit_code == 0, r.output
    assert re.search(r'rinex = ".*3040\*\.05o"', out.read_text()), out.read_text()
    r = run_cli("ingest", "--config", out, "-o", tmp_path / "run.mcap", "-q")
    assert r.exit_code == 0, r.output


def test_config_chooses_the_signals_of_every_file_a_glob_matches(pieces, tmp_path):
    """`cdgps config --signals auto` with an antenna's files as a quoted glob chooses the signals as with one file (it
    chose GPS L1 alone, silently: a sweep of real files, where init then fixed 18 integers instead of 76), and its
    comments say how many files the pattern matches; a repeated antenna is refused with the pattern named as the way."""
    def config(out, *rinex):
        r = run_cli("-q", "config", *sum((("--rinex", x) for x in rinex), ()), "--nav", MOSAIC / "base.nav",
                    "--master", "base", "-o", out, "--json")
        assert r.exit_code == 0, r.output
        return json.loads(r.stdout)["config"]["signals"], out.read_text()

    one, _ = config(tmp_path / "one.toml", f"base={pieces / 'base.obs'}", f"rover={pieces / 'rover.obs'}")
    many, text = config(tmp_path / "many.toml", f"base={pieces / 'base_[abc].obs'}", f"rover={pieces / 'rover_*.obs'}")
    assert len(one) > 1 and many == one, (one, many)
    assert "the first of 3 files matching" in text and "the first of 2 files matching" in text, text
    r = run_cli("config", "--rinex", f"base={pieces / 'base_a.obs'}", "--rinex", f"base={pieces / 'base_b.obs'}",
                "--rinex", f"rover={pieces / 'rover.obs'}", "-o", tmp_path / "twice.toml")
    assert r.exit_code == 2 and "given twice" in r.output and "base='PATTERN'" in r.output, r.output
    assert not (tmp_path / "twice.toml").exists()


def test_ingest_without_a_config_chooses_the_signals_config_chooses(pieces, tmp_path):
    """``ingest --rinex … --rinex …`` without --config took GPS L1 alone where ``config`` and ``rtk`` take every signal
    both files hold (the same files gave two pipelines by the route taken); now its --signals defaults to auto, the
    RUN's config says which (``info --json``), and --signals beside --config is refused."""
    r = run_cli("-q", "config", "--rinex", f"base={pieces / 'base.obs'}", "--rinex", f"rover={pieces / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / "c.toml", "--json")
    assert r.exit_code == 0, r.output
    chosen = json.loads(r.stdout)["config"]["signals"]
    assert len(chosen) > 1, chosen
    r = run_cli("-q", "ingest", "--rinex", f"base={pieces / 'base_[abc].obs'}", "--rinex", f"rover={pieces / 'rover.obs'}",
                "--nav", MOSAIC / "base.nav", "--master", "base", "-o", tmp_path / "run.mcap")
    assert r.exit_code == 0, r.output
    r = run_cli("-q", "info", tmp_path / "run.mcap", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["gnss"]["config"]["signals"] == chosen
    r = run_cli("ingest", "--config", tmp_path / "c.toml", "--signals", "G:L1", "-o", tmp_path / "again.mcap")
    assert r.exit_code == 2 and "[gnss] signals" in r.output and not (tmp_path / "again.mcap").exists(), r.output
