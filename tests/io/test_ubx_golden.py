"""The u-blox reader's output frozen (issue 29 item 4, made faster without changing a result): every UBX log of
../shared/data and damaged copies of the walk and pygpsdata logs (a byte flipped in an RXM-RAWX frame and in an
RXM-SFRBX frame, noise with false sync words inserted, a truncated tail, a frame repeated, gzip, ``strict``)
read by :func:`read_ubx_log` (its ephemerides with GLONASS since session 28) and :func:`read_ubx_signals` give the tables,
``info`` and error messages recorded in ``ubx_golden.json`` before the reader was rewritten, digest for digest.

Recorded again in session 28, for two changes only, checked case by case against the previous record: the reader's
ephemerides and their counters are now those the record held of the decoder with GLONASS (``glonass_nav``,
``glonass_stats``: GLONASS strings are a navigation source), and ``--strict``'s refusal ends with where the first
loss is (its byte and the epoch before it).

``python tests/io/test_ubx_golden.py --write`` records them (only ever from a reader known to be right).
"""

from __future__ import annotations

import functools
import gzip
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import ubx

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
GOLDEN = Path(__file__).with_name("ubx_golden.json")
WALK = SHARED / "real-pairs" / "ublox-walk" / "gnss_1730.ubx"
PYGPS = SHARED / "ubx" / "pygpsdata-RXMRAWX.log"


def _frame_at(data: bytes, cls: int, mid: int, nth: int) -> int:
    """Offset of the ``nth`` UBX frame of class/id in ``data`` (clean logs: every sync word starts a frame)."""
    k, seen = -1, -1
    while seen < nth:
        k = data.index(bytes((0xB5, 0x62, cls, mid)), k + 1)
        seen += 1
    return k


def _flip(data: bytes, at: int) -> bytes:
    return data[:at] + bytes((data[at] ^ 0x5A,)) + data[at + 1:]


@functools.lru_cache(maxsize=1)
def cases() -> dict[str, tuple[bytes, bool]]:
    """{name: (log bytes, strict)}: the shared logs and damaged copies, built the same way every time."""
    out = {p.relative_to(SHARED).as_posix(): (p.read_bytes(), False)
           for p in sorted(SHARED.rglob("*")) if p.is_file() and p.suffix.lower() in (".ubx", ".log")}
    for name, p in (("walk", WALK), ("pygps", PYGPS)):
        d = p.read_bytes()
        rawx, sfrbx = _frame_at(d, 2, 0x15, 3), _frame_at(d, 2, 0x13, 1) if b"\xb5\x62\x02\x13" in d else None
        noise = bytes(np.random.default_rng(7).integers(0, 256, 300, dtype=np.uint8)) + b"\xb5\x62\x02\x15\x10\x00$GP,\xd3\x00"
        mid = _frame_at(d, 2, 0x15, 5)
        out[f"{name}:flip-rawx-payload"] = (_flip(d, rawx + 30), False)
        out[f"{name}:flip-rawx-length"] = (_flip(d, rawx + 4), False)
        if sfrbx is not None:
            out[f"{name}:flip-sfrbx"] = (_flip(d, sfrbx + 20), False)
        out[f"{name}:noise"] = (d[:mid] + noise + d[mid:], False)
        out[f"{name}:truncated"] = (d[: len(d) - 37], False)
        out[f"{name}:repeated-frame"] = (d[:mid] + d[rawx:_frame_at(d, 2, 0x15, 4)] + d[mid:], False)
        out[f"{name}:gzip"] = (gzip.compress(d, mtime=0), False)
        out[f"{name}:strict-clean"] = (d, True)
        out[f"{name}:strict-damaged"] = (_flip(d, rawx + 30), True)
        end = rawx + 8 + int.from_bytes(d[rawx + 4:rawx + 6], "little")
        out[f"{name}:forged-nummeas"] = (d[:rawx] + _reframed(d[rawx:end], 17, 3) + d[end:], False)
        out[f"{name}:forged-repeat-signal"] = (d[:rawx] + _reframed(d[rawx:end], 22 + 32, d[rawx + 22:rawx + 54]) + d[end:], False)
    return out


def _reframed(frame: bytes, at: int, new) -> bytes:
    """``frame`` with byte ``at`` changed by ``new`` (int: added to numMeas; bytes: written there) and its
    checksum made right again (a frame the receiver could not have written but that passes the checksum)."""
    b = bytearray(frame)
    if isinstance(new, int):
        b[at] = (b[at] + new) & 0xFF
    else:
        b[at:at + len(new)] = new
    ck_a = ck_b = 0
    for v in b[2:-2]:
        ck_a = (ck_a + v) & 0xFF
        ck_b = (ck_b + ck_a) & 0xFF
    b[-2:] = bytes((ck_a, ck_b))
    return bytes(b)


def _digest_frame(df: pd.DataFrame) -> str:
    h = hashlib.sha256(repr((list(df.columns), [str(t) for t in df.dtypes], df.shape)).encode())
    for c in df.columns:
        v = df[c].to_numpy()
        h.update(v.tobytes() if v.dtype != object else "\0".join(map(repr, v.tolist())).encode())
    return h.hexdigest()


def _json(v):
    return json.loads(json.dumps(v, default=lambda o: o.item() if hasattr(o, "item") else repr(o)))


def outcome(data: bytes, strict: bool, tmp: Path) -> dict:
    """What the reader gives for one log: digests of its tables, its ``info``, or its error."""
    p = tmp / "log.ubx"
    p.write_bytes(data)
    ubx._LAST_DECODED.clear()
    try:
        info, obs, nav = ubx.read_ubx_log(p, strict=strict)
    except CdgpsError as exc:
        return {"error": str(exc).replace(str(p), "FILE")}
    info = {k: (v if k != "path" else "FILE") for k, v in info.items()}
    sig = ubx.read_ubx_signals(p, list(ubx.UBX_SIGNALS), strict=strict)
    from cdgps_cli.io.sfrbx import sfrbx_ephemerides  # noqa: PLC0415
    from cdgps_cli.io.ubx_frames import split_stream  # noqa: PLC0415
    raw = gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data
    glo, glo_stats = sfrbx_ephemerides(split_stream(raw)[0], info["week"], glonass=True)
    return {"info": _json(info), "obs": _digest_frame(obs), "nav": _digest_frame(nav),
            "signals": _digest_frame(sig), "glonass_nav": _digest_frame(glo), "glonass_stats": _json(glo_stats)}


def legacy_sfrb() -> dict:
    """The ephemerides of the legacy RXM-SFRB log (refused for its RXM-RAW, but its subframes decode)."""
    from cdgps_cli.io.sfrbx import sfrbx_ephemerides  # noqa: PLC0415
    from cdgps_cli.io.ubx_frames import split_stream  # noqa: PLC0415
    nav, stats = sfrbx_ephemerides(split_stream((SHARED / "ubx" / "ubx_20080526.ubx").read_bytes())[0], 1480, glonass=True)
    return {"nav": _digest_frame(nav), "stats": _json(stats)}


def all_outcomes() -> dict:
    with tempfile.TemporaryDirectory() as d:
        out = {name: outcome(data, strict, Path(d)) for name, (data, strict) in cases().items()}
    out["legacy-sfrb-ephemerides"] = legacy_sfrb()
    return out


@pytest.fixture(scope="module")
def golden():
    if not WALK.exists() or not GOLDEN.exists():
        pytest.skip("shared data or golden not available")
    return json.loads(GOLDEN.read_text())


def test_golden_covers_every_case(golden):
    assert sorted(golden) == sorted([*cases(), "legacy-sfrb-ephemerides"])
    assert any("error" in v for v in golden.values()) and sum("obs" in v for v in golden.values()) >= 10


def test_legacy_sfrb_ephemerides_unchanged(golden):
    assert legacy_sfrb() == golden["legacy-sfrb-ephemerides"]


@pytest.mark.parametrize("name", sorted(cases()) if WALK.exists() else [])
def test_reader_output_unchanged(golden, name, tmp_path):
    data, strict = cases()[name]
    assert outcome(data, strict, tmp_path) == golden[name]


if __name__ == "__main__" and "--write" in sys.argv:
    GOLDEN.write_text(json.dumps(all_outcomes(), indent=1, sort_keys=True) + "\n")
    print("wrote", GOLDEN)


@pytest.mark.parametrize("name", ["real-pairs/ublox-walk/gnss_1730.ubx", "walk:noise", "pygps:truncated",
                                  "walk:strict-damaged", "walk:forged-repeat-signal"])
def test_numpy_framer_gives_the_same(golden, name, tmp_path, monkeypatch):
    """Without the compiled walk (``_ubxcore`` not built), the numpy framer gives the golden output too."""
    from cdgps_cli.io import ubx_frames  # noqa: PLC0415

    monkeypatch.setattr(ubx_frames, "USE_COMPILED", False)
    data, strict = cases()[name]
    assert outcome(data, strict, tmp_path) == golden[name]
