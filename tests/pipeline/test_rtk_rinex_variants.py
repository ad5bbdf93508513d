"""`cdgps rtk` on legal variants of real RINEX files gives the solution of the plain files, line for line.

Held-out files come from receivers and converters we have not seen; RTKLIB reads all of these forms.
Each variant here combines several edits a real writer makes, none of which changes an observation:

* RINEX 3 (the Septentrio mosaic pair): CRLF line ends, trailing blanks stripped, an event-flag-4
  block of header records between two epochs, a receiver clock offset in every epoch line, the
  satellites of each epoch in another order; and the same files Hatanaka-compressed and gzipped.
* RINEX 2.11 (the GEONET pair): CRLF, trailing blanks stripped, and eight more observation types, so
  every satellite's record runs over three lines.
"""

from __future__ import annotations

import gzip
import random

import pytest

from cdgps_cli.pipeline.gnss_multi import rtk_from_files
from tests._shared import REPO_ROOT

SHARED = REPO_ROOT.parent / "shared" / "data"
MOSAIC, GEONET = SHARED / "real-pairs" / "mosaic-static", SHARED / "rinex"
MOSAIC_XYZ = (-3817681.1213, 3562839.4311, 3650159.1593)
pytestmark = pytest.mark.skipif(not MOSAIC.exists() or not GEONET.exists(), reason="../shared/data absent")


def _solution_lines(path) -> list:
    return [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]


def _rinex3_variant(lines: list) -> list:
    """Flag-4 block mid-file, clock offset field in every epoch line, satellites shuffled, blanks stripped."""
    head = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln)
    out, i, rnd, k = lines[:head + 1], head + 1, random.Random(1), 0
    while i < len(lines):
        n = int(lines[i][32:35])
        recs = lines[i + 1:i + 1 + n]
        rnd.shuffle(recs)
        if k == 150:
            out += [">                              4  2", "A COMMENT BETWEEN TWO EPOCHS".ljust(60) + "COMMENT",
                    "SEPT".ljust(60) + "MARKER NAME"]
        out += [lines[i][:41].ljust(41) + f"{0.000123456789:15.12f}"] + recs     # columns 42-56
        i, k = i + 1 + n, k + 1
    return [ln.rstrip() for ln in out]


def _rinex2_more_types(lines: list, extra=("S1", "S2", "D1", "D2", "C2", "L5", "C5", "S5")) -> list:
    """Eight observation types more (values made up), so each satellite's record takes three lines."""
    head = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln)
    t = next(i for i, ln in enumerate(lines) if "# / TYPES OF OBSERV" in ln)
    types = lines[t][6:60].split()
    new = types + list(extra)
    hdr = [((f"{len(new):6d}" if k == 0 else " " * 6) + "".join(f"{x:>6}" for x in new[k:k + 9])).ljust(60)
           + "# / TYPES OF OBSERV" for k in range(0, len(new), 9)]
    out, i, per = lines[:t] + hdr + lines[t + 1:head + 1], head + 1, 1 + (len(types) - 1) // 5
    while i < len(lines):
        n, flag = int(lines[i][29:32]), int(lines[i][28])
        if flag > 1:                                    # special records: n lines, kept as they are
            out += lines[i:i + 1 + n]
            i += 1 + n
            continue
        n_list = 1 + (n - 1) // 12
        out += lines[i:i + n_list]
        i += n_list
        for _ in range(n):
            rec = "".join(lines[i + j][:80].ljust(80) for j in range(per))
            i += per
            fields = [rec[16 * j:16 * j + 16] for j in range(len(types))] + \
                [f"{40.0 + j:14.3f}  " for j in range(len(extra))]
            out += ["".join(fields[j:j + 5]).rstrip() for j in range(0, len(fields), 5)]
    return out


def _write(path, lines, newline="\r\n"):
    path.write_text(newline.join(lines) + newline, newline="")
    return path


def test_rinex3_variants_give_the_plain_files_solution(tmp_path):
    import hatanaka

    ref = tmp_path / "plain.csv"
    kw = dict(base_xyz_m=MOSAIC_XYZ, options={"signals": ("G:L1", "E:E1")})
    rtk_from_files(MOSAIC / "base.obs", MOSAIC / "rover.obs", [MOSAIC / "base.nav"], ref, **kw)
    edited, crx = {}, {}
    for who in ("base", "rover"):
        text = (MOSAIC / f"{who}.obs").read_text()
        edited[who] = _write(tmp_path / f"{who}_edited.obs", _rinex3_variant(text.splitlines()))
        crx[who] = tmp_path / f"{who}.crx.gz"
        crx[who].write_bytes(gzip.compress(hatanaka.rnx2crx(text.encode()), mtime=0))
    raw = edited["base"].read_bytes()
    assert b"\r\n>                              4  2\r\n" in raw and b"  0.000123456789\r\n" in raw
    for name, files in (("edited", edited), ("crx.gz", crx)):
        out = tmp_path / f"{name}.csv"
        s = rtk_from_files(files["base"], files["rover"], [MOSAIC / "base.nav"], out, **kw)
        assert s["epochs"] == 301 and _solution_lines(out) == _solution_lines(ref), name


def test_rinex2_records_over_three_lines_give_the_plain_files_solution(tmp_path):
    ref = tmp_path / "plain.csv"
    nav = [GEONET / "07590920.05n"]
    opt = {"signals": ("G:L1", "G:L2")}
    rtk_from_files(GEONET / "07590920.05o", GEONET / "30400920.05o", nav, ref, options=opt)
    files = [_write(tmp_path / f.name, [ln.rstrip() for ln in _rinex2_more_types((GEONET / f.name).read_text().splitlines())])
             for f in (GEONET / "07590920.05o", GEONET / "30400920.05o")]
    assert "    12    L1    C1    L2    P2    S1    S2    D1    D2    C2# / TYPES OF OBSERV" in files[0].read_text()
    out = tmp_path / "three_lines.csv"
    s = rtk_from_files(files[0], files[1], nav, out, options=opt)
    assert s["epochs"] == 120 and _solution_lines(out) == _solution_lines(ref)
