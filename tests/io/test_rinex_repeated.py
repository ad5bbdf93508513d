"""An epoch a logger wrote twice in a row (the same time tag) is read once, the first record, and noted in the
header's ``repeated_epochs`` (io/rinex.py); ``config``/``ingest`` refused such a file ("repeats the previous epoch")
where ``rtk`` warned and used it (the adversarial sweep of session 20, D11).  Epochs written out of time order are
read in time order and listed in ``epochs_out_of_order`` (they were refused too), as rtk reads them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdgps_cli.io.rinex import read_rinex_obs
from cdgps_cli.io.rinex_signals import first_of_repeated_epochs, read_rinex_signals
from tests._shared import REPO_ROOT, run_cli

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC = SHARED / "real-pairs" / "mosaic-static"
GEONET_V2 = SHARED / "rinex" / "07590920.05o"
pytestmark = pytest.mark.skipif(not MOSAIC.exists(), reason="../shared/data absent")


def _epochs(text: str):
    """(header lines, [epoch blocks of lines]) of a RINEX 3 or 2 observation text."""
    lines = text.splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if ln[60:].strip() == "END OF HEADER") + 1
    head, body = lines[:end], lines[end:]
    if head[0][:9].strip().startswith("3"):
        starts = [i for i, ln in enumerate(body) if ln.startswith(">")]
        return head, [body[a:b] for a, b in zip(starts, starts[1:] + [len(body)])]
    n_types = next(int(ln[:6]) for ln in head if ln[60:].strip() == "# / TYPES OF OBSERV")
    per_sat, blocks, i = -(-n_types // 5), [], 0
    while i < len(body):
        nsat = int(body[i][29:32])
        size = 1 + (nsat - 1) // 12 + nsat * per_sat
        blocks.append(body[i:i + size])
        i += size
    return head, blocks


def _edited(src, tmp_path, how: str, k: int = 40):
    head, blocks = _epochs(src.read_text())
    if how == "repeat":
        blocks.insert(k + 1, list(blocks[k]))
    else:                                                  # two epochs swapped
        blocks[k], blocks[k + 1] = blocks[k + 1], blocks[k]
    p = tmp_path / f"{how}_{src.name}"
    p.write_text("".join(head) + "".join("".join(b) for b in blocks))
    return p, len(head) + sum(len(b) for b in blocks[:k + 1]) + 1


def _read_edited(src, tmp_path, how: str):
    """(the edited file, the edited epoch's line, the header read from it, the unedited file's epoch 40 time), the
    tables of both read and checked equal, with the same count of epochs."""
    if not src.exists():
        pytest.skip(f"{src} absent")
    p, line = _edited(src, tmp_path, how)
    hdr0, obs0 = read_rinex_obs(src)
    hdr, obs = read_rinex_obs(p)
    assert obs.equals(obs0) and hdr["n_epochs"] == hdr0["n_epochs"]
    assert "repeated_epochs" not in hdr0 and "epochs_out_of_order" not in hdr0
    return p, line, hdr, obs0["time_gps_s"].unique()[40]


@pytest.mark.parametrize("src", [MOSAIC / "rover.obs", GEONET_V2], ids=["rinex3", "rinex2"])
def test_an_epoch_written_twice_is_read_once(tmp_path, src):
    p, line, hdr, t40 = _read_edited(src, tmp_path, "repeat")
    assert [(r["line"], r["time_gps_s"]) for r in hdr["repeated_epochs"]] == [(line, t40)]
    if src.suffix == ".obs":                               # the signal reader's table, kept once the same way
        sig0 = read_rinex_signals(src, ["G:L1", "G:L2"])[1]
        sig, times, n_rows = first_of_repeated_epochs(read_rinex_signals(p, ["G:L1", "G:L2"])[1])
        assert sig.equals(sig0) and times.size == 1 and n_rows > 0


@pytest.mark.parametrize("src", [MOSAIC / "rover.obs", GEONET_V2], ids=["rinex3", "rinex2"])
def test_two_epochs_swapped_are_read_in_time_order(tmp_path, src):
    """Epochs 40 and 41 written in the other order: the table is the unedited one, the header lists the epoch that
    came back (as rtk's reader does, which sorts and warns)."""
    p, line, hdr, t40 = _read_edited(src, tmp_path, "swap")
    assert [(b["line"], b["time_gps_s"]) for b in hdr["epochs_out_of_order"]] == [(line, t40)]


def test_an_earlier_file_appended_reads_each_time_once(tmp_path):
    """The rover's first 60 epochs written again after the whole file (a logger that appended an older piece): the
    table is the file's, each time once with its first record; the 60 are listed as written more than once, each
    with the line of its first record (session 30: they were listed as out of time order, and a sweep of real files
    found ingest then warning that a block written twice was "read in time order")."""
    head, blocks = _epochs((MOSAIC / "rover.obs").read_text())
    p = tmp_path / "appended.obs"
    p.write_text("".join(head) + "".join("".join(b) for b in blocks + blocks[:60]))
    hdr0, obs0 = read_rinex_obs(MOSAIC / "rover.obs")
    hdr, obs = read_rinex_obs(p)
    assert obs.equals(obs0) and hdr["n_epochs"] == hdr0["n_epochs"] and "epochs_out_of_order" not in hdr
    rep = hdr["repeated_epochs"]
    first = len(head) + 1 + np.cumsum([0] + [len(b) for b in blocks[:59]])
    assert len(rep) == 60 and [r["first_line"] for r in rep] == first.tolist()
    assert rep[0]["line"] == len(head) + sum(len(b) for b in blocks) + 1


def test_a_block_written_again_after_a_later_epoch_is_said_repeated_not_reordered(tmp_path):
    """Epochs 100–109 written a second time right after 109: ten repeats (the last of them right after its first
    record, the others after later epochs), no epoch out of time order; the table is the file's."""
    head, blocks = _epochs((MOSAIC / "rover.obs").read_text())
    p = tmp_path / "block.obs"
    p.write_text("".join(head) + "".join("".join(b) for b in blocks[:110] + blocks[100:110] + blocks[110:]))
    hdr0, obs0 = read_rinex_obs(MOSAIC / "rover.obs")
    hdr, obs = read_rinex_obs(p)
    assert obs.equals(obs0) and hdr["n_epochs"] == hdr0["n_epochs"] and "epochs_out_of_order" not in hdr
    assert [r["time_gps_s"] for r in hdr["repeated_epochs"]] == obs0["time_gps_s"].unique()[100:110].tolist()


def _chain(rover, d, tag) -> tuple[str, dict]:
    """config → ingest → init of the mosaic base with ``rover`` in ``d``: (ingest's stderr, INIT.json)."""
    for args in (("config", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={rover}", "--nav",
                  MOSAIC / "base.nav", "--master", "base", "-o", d / f"{tag}.toml"),
                 ("ingest", "--config", d / f"{tag}.toml", "-o", d / f"{tag}.mcap"),
                 ("init", d / f"{tag}.mcap", "-o", d / f"{tag}.json")):
        r = run_cli(*args)
        assert r.exit_code == 0, (args[0], r.output)
        if args[0] == "ingest":
            stderr = r.stderr
    return stderr, json.loads((d / f"{tag}.json").read_text())


@pytest.fixture(scope="module")
def unedited(tmp_path_factory):
    """The unedited pair through the same chain, once for both cases below."""
    return _chain(MOSAIC / "rover.obs", tmp_path_factory.mktemp("unedited"), "ref")


@pytest.mark.parametrize("how, said_as", [("repeat", "written more than once"), ("swap", "out of time order")])
def test_config_ingest_init_take_a_rover_with_epochs_out_of_place(unedited, tmp_path, how, said_as):
    """The real mosaic pair, the rover's epoch 40 written twice, or epochs 40 and 41 swapped: config → ingest → init
    exit 0, ingest warns naming the file (and the line of a repeat), and INIT's states are the unedited pair's."""
    p, line = _edited(MOSAIC / "rover.obs", tmp_path, how)
    got = {"ref": unedited, "rep": _chain(p, tmp_path, "rep")}
    for tag, (stderr, _) in got.items():
        said = [ln for ln in stderr.splitlines() if said_as in ln]
        assert len(said) == (tag == "rep") and (tag == "ref" or how == "swap" or f"line {line};" in said[0]), stderr
    assert got["rep"][1]["states"] == got["ref"][1]["states"]


def test_rtk_s_reader_says_a_block_written_again_is_repeated_not_out_of_order(tmp_path):
    """The signal reader (``rtk``'s) on epochs 100–109 written again after 109: ten epochs written more than once
    and none out of time order (it used to say one was, the jump back to the first repeat)."""
    head, blocks = _epochs((MOSAIC / "rover.obs").read_text())
    p = tmp_path / "block.obs"
    p.write_text("".join(head) + "".join("".join(b) for b in blocks[:110] + blocks[100:110] + blocks[110:]))
    sig = read_rinex_signals(p, ["G:L1"])[1]
    assert "epochs_out_of_order" not in sig.attrs
    kept, times, n_rows = first_of_repeated_epochs(sig)
    assert times.size == 10 and n_rows > 0 and kept.equals(read_rinex_signals(MOSAIC / "rover.obs", ["G:L1"])[1])
    swapped = tmp_path / "swap.obs"                       # a true reordering is still said
    swapped.write_text("".join(head) + "".join("".join(b) for b in blocks[:40] + [blocks[41], blocks[40]] + blocks[42:]))
    assert read_rinex_signals(swapped, ["G:L1"])[1].attrs["epochs_out_of_order"][0] == 1


def test_ingest_says_how_many_epochs_hold_nothing_it_keeps(tmp_path):
    """An epoch of no satellite (and one of Galileo alone, in a GPS L1 run) is not in the run, and ``ingest`` now says
    so with the count (a sweep of real files found it dropped unsaid, where ``rtk`` counts it)."""
    head, blocks = _epochs((MOSAIC / "rover.obs").read_text())
    empty = [blocks[50][0][:32] + "  0" + blocks[50][0][35:]]               # epoch 50 emptied: its line alone
    galileo = [blocks[60][0][:32] + f"{sum(r[0] == 'E' for r in blocks[60][1:]):3d}" + blocks[60][0][35:]] + \
        [r for r in blocks[60][1:] if r[0] == "E"]
    p = tmp_path / "rover_empty.obs"
    p.write_text("".join(head) + "".join("".join(b) for b in blocks[:50] + [empty] + blocks[51:60] + [galileo]
                                         + blocks[61:]))
    out = tmp_path / "run.mcap"
    r = run_cli("ingest", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={p}", "--nav",
                MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1", "-o", out, "-q", "--json")
    assert r.exit_code == 0, r.output
    warn = json.loads(r.stdout)["warnings"]
    assert any(w.startswith(f"{p} (rover): 2 of its 301 observation epochs hold no observation") for w in warn), warn
    # the rover in two files that follow one another: the same count (it was left unsaid for joined files)
    edited = [empty if i == 50 else galileo if i == 60 else b for i, b in enumerate(blocks)]
    parts = (tmp_path / "rover_1.obs", tmp_path / "rover_2.obs")
    parts[0].write_text("".join(head) + "".join("".join(b) for b in edited[:150]))
    parts[1].write_text("".join(head) + "".join("".join(b) for b in edited[150:]))
    r = run_cli("ingest", "--rinex", f"base={MOSAIC / 'base.obs'}", "--rinex", f"rover={parts[0]}", "--rinex",
                f"rover={parts[1]}", "--nav", MOSAIC / "base.nav", "--master", "base", "--signals", "G:L1",
                "-o", tmp_path / "run2.mcap", "-q", "--json")
    assert r.exit_code == 0, r.output
    warn = json.loads(r.stdout)["warnings"]
    assert any("(rover): 2 of its 301 observation epochs hold no observation" in w for w in warn), warn
