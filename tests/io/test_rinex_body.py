"""The byte-level, block-wise body reader of ``read_rinex_obs`` (issue 29 item 4) against the
line-by-line reader it replaced: the same table and header, to the bit, on every observation file
of the shared data and for any block size; the same outcome on bad records; ``NaN`` / ``inf``
tokens refused with the file and line."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from _rinex_edit import edited_copy as _edited
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import rinex, rinex_signals
from cdgps_cli.io import _fixed_width as _fw
from cdgps_cli.io._fixed_width import Unsupported, decimal_fields

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
OBS_FILES = sorted(p for p in SHARED.rglob("*") if p.is_file() and p.name.lower().endswith(("o", ".obs")))
pytestmark = pytest.mark.skipif(not OBS_FILES, reason="../shared/data absent")


def _read(path, fast: bool, **kw):
    rinex.FAST_PARSE = fast
    try:
        return rinex.read_rinex_obs(path, gps_l1_optional=True, **kw)
    finally:
        rinex.FAST_PARSE = True


def _outcome(path, fast: bool, **kw):
    try:
        return _read(path, fast, **kw)
    except CdgpsError as exc:
        return str(exc)


def _same(a, b):
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    (h_a, o_a), (h_b, o_b) = a, b
    assert list(h_a.items()) == list(h_b.items())
    pd.testing.assert_frame_equal(o_a, o_b, check_exact=True)
    for c in ("phase_l1_cycles", "pseudorange_l1_m"):
        assert np.array_equal(np.signbit(o_a[c]), np.signbit(o_b[c]))


def _no_fallback(path):
    data, compressed = rinex._read_bytes(path)
    return rinex._read_obs_fast(Path(path), data, compressed, True, 7)


@pytest.mark.parametrize("path", OBS_FILES, ids=lambda p: p.name)
def test_identical_on_shared_files_for_any_block_size(path):
    ref = _read(path, False)
    for block in (1, 7, rinex.RINEX_BLOCK_EPOCHS):
        _same(ref, _read(path, True, block_epochs=block))
    _same(ref, _no_fallback(path))                       # read by the fast reader, not by its fallback
    assert len(ref[1]) > 0


@pytest.mark.parametrize("variant", ["crlf", "bom", "no final newline", "gzip", "trailing blank lines"])
def test_line_endings_compression(tmp_path, variant):
    src = SHARED / "rinex" / "07590920.05o"
    data = src.read_bytes()
    data = {"crlf": lambda d: d.replace(b"\n", b"\r\n"), "bom": lambda d: b"\xef\xbb\xbf" + d,
            "no final newline": lambda d: d.rstrip(b"\n"), "gzip": gzip.compress,
            "trailing blank lines": lambda d: d + b"\n   \n\n"}[variant](data)
    path = tmp_path / src.name
    path.write_bytes(data)
    ref = _read(path, False)
    _same(ref, _read(path, True, block_epochs=5))
    _same(ref, _no_fallback(path))
    pd.testing.assert_frame_equal(_read(src, False)[1], ref[1], check_exact=True)


def _field(line: str, col: int, text: str) -> str:
    return line[:col] + text.rjust(14) + line[col + 14:]


EDITS = {
    "exponent": lambda ln, c: _field(ln, c, f"{float(ln[c:c + 14]):14.6E}".replace("E", "D")),
    "garbage": lambda ln, c: _field(ln, c, "12x45.67890"),
    "NaN": lambda ln, c: _field(ln, c, "NaN"),
    "inf": lambda ln, c: _field(ln, c, "-inf"),
    "digit groups": lambda ln, c: _field(ln, c, "1_234.500"),
    "lli letter": lambda ln, c: ln[:c + 14] + "x" + ln[c + 15:],
    "blank record": lambda ln, c: "",
}


@pytest.mark.parametrize("name,col", [("Base-static_MO_Spirent.obs", 19), ("07590920.05o", 0)])   # the L1 phase
@pytest.mark.parametrize("what", [*EDITS, "truncated", "epochs swapped", "blank line between epochs"])
def test_bad_records_same_outcome_as_line_by_line(tmp_path, name, col, what):
    src = next(p for p in OBS_FILES if p.name == name)

    def edit(lines, end):
        rec = end + 2                                     # the first record of the first epoch (1 satellite line in v2)
        if what in EDITS:
            lines[rec] = EDITS[what](lines[rec], col)
        elif what == "truncated":
            del lines[-3:]
        elif what == "blank line between epochs":
            lines.insert(next(i for i in range(rec + 1, len(lines)) if lines[i][:3] in ("> 2", " 05")), "")
        else:
            ep = [i for i in range(end + 1, len(lines)) if lines[i][:3] in ("> 2", " 05")]
            a, b, c = ep[:3]
            lines[a:c] = lines[b:c] + lines[a:b]

    path = _edited(tmp_path, src, edit)
    old, new = _outcome(path, False), _outcome(path, True, block_epochs=3)
    _same(old, new)
    if what in ("NaN", "inf", "digit groups", "garbage", "lli letter"):
        assert isinstance(new, str) and str(path) in new and "line " in new, new


@pytest.mark.parametrize("token", ["NaN", "nan", "inf", "Infinity"])
def test_non_numeric_tokens_refused_with_file_and_line(tmp_path, token):
    src = SHARED / "rinex-ge" / "Base-static_MO_Spirent.obs"
    path = _edited(tmp_path, src, lambda lines, end: lines.__setitem__(end + 2, _field(lines[end + 2], 19, token)))
    line_no = next(i for i, ln in enumerate(path.read_text(encoding="latin-1").split("\n")) if token in ln[:40]) + 1
    with pytest.raises(CdgpsError, match=rf"{path.name}, line {line_no}: malformed observation record"):
        rinex.read_rinex_obs(path)
    for fast in (True, False):
        rinex_signals.FAST_PARSE = fast
        try:
            with pytest.raises(CdgpsError, match=rf"{path.name}:{line_no}: malformed observation record"):
                rinex_signals.read_rinex_signals(path, ["G:L1", "E:E1"])
        finally:
            rinex_signals.FAST_PARSE = True


def test_nan_token_cli_exit_2(tmp_path):
    from cdgps_cli.cli.commands import main

    src = SHARED / "rinex-ge" / "Base-static_MO_Spirent.obs"
    bad = tmp_path / "in"
    bad.mkdir()
    path = _edited(bad, src, lambda lines, end: lines.__setitem__(end + 2, _field(lines[end + 2], 19, "NaN")))
    out = tmp_path / "rtk.csv"
    res = CliRunner().invoke(main, ["rtk", "--base", str(src), "--rover", str(path), "--nav",
                                    str(SHARED / "rinex-ge" / "RINEX_GN_Spirent.23N"), "-o", str(out)])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and not out.exists()
    assert f"{path.name}:" in res.output and "malformed observation record" in res.output


def test_block_epochs_must_be_positive():
    with pytest.raises(ValueError, match="block_epochs"):
        rinex.read_rinex_obs(OBS_FILES[0], block_epochs=0)


def test_few_decimal_fields_as_many():
    """The per-field path for a few fields gives what the vectorised one gives, and refuses the same."""
    rng = np.random.default_rng(5)
    vals = [f"{v:14.3f}" for v in rng.uniform(-3e8, 3e8, 600)] + [" " * 14, "  -0.000", "1.", "  .5", "+12.25"]
    f = np.frombuffer("".join(s.ljust(14)[:14] for s in vals).encode(), dtype=np.uint8).reshape(-1, 14).copy()
    many = decimal_fields(f)
    few = np.concatenate([decimal_fields(f[k:k + 10]) for k in range(0, len(f), 10)])
    assert len(f) > _fw._SMALL
    assert np.array_equal(many, few, equal_nan=True) and np.array_equal(np.signbit(many), np.signbit(few))
    for bad in ("1.2.3", "1e5", "- 5", "nan", "1_0"):
        with pytest.raises(Unsupported):
            decimal_fields(np.frombuffer(bad.ljust(14).encode(), dtype=np.uint8).reshape(1, 14).copy())


@pytest.mark.parametrize("path", [p for p in OBS_FILES if p.read_bytes()[:9].strip().startswith(b"3")], ids=lambda p: p.name)
def test_signals_from_bytes_identical(path):
    """read_rinex_signals of a RINEX 3 file walks the body in the bytes (no fallback) and gives the
    line-by-line reader's table."""
    names = rinex_signals.signals_in_file(path)
    glo = {f"R{i:02d}": 0 for i in range(1, 33)}
    rinex_signals.FAST_PARSE = False
    try:
        h_ref, ref = rinex_signals.read_rinex_signals(path, names, glonass_k=glo)
    finally:
        rinex_signals.FAST_PARSE = True
    h_new, new = rinex_signals._read_bytes_v3(path, names, glo)
    assert list(h_ref.items()) == list(h_new.items())
    pd.testing.assert_frame_equal(ref, new, check_exact=True)


def test_row_columns_in_table_order():
    assert tuple(name for _, name in rinex._ROW_COLUMNS) == tuple(rinex.OBS_COLUMNS)


def test_event_changing_the_observation_types_mid_file(tmp_path):
    """A flag-4 event whose header lines reorder the types: later records are read with the new
    layout (a new block segment), as the line-by-line reader does; a comment-only event keeps it."""
    src = SHARED / "rinex" / "07590920.05o"
    types = f"{'     4    C1    L1    L2    P2':<60}{'# / TYPES OF OBSERV':<20}"

    def edit(lines, end):
        ev = [i for i in range(end + 1, len(lines)) if lines[i].startswith(" " * 28 + "4  1")]
        lines[ev[0] + 1] = types

    path = _edited(tmp_path, src, edit)
    ref = _read(path, False)
    _same(ref, _read(path, True, block_epochs=7))
    _same(ref, _no_fallback(path))
    assert ref[0]["obs_types"]["*"][:2] == ["C1", "L1"]
