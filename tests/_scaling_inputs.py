"""Generators of large reader inputs (about ``size`` bytes each) for tests/io/test_reader_scaling.py.

Each generator writes a file into a folder and returns its path; the inputs are valid where a
valid file of that size exists (the reader's normal path), or adversarial (the error path a
corrupted file takes).  All are deterministic.
"""

from __future__ import annotations

import datetime as dt
import struct
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
RECEIVER_HEADER = "time_s,receiver,master,antenna,transmitter,phase_cycles,lock,snr_dbhz"


def receiver_csv(folder: Path, size: int, cfg, *, eol: str = "\n") -> Path:
    """A valid receiver log for ``cfg`` (every rover × transmitter each epoch); ``eol="\\r"`` gives
    CR-only line endings."""
    master = cfg.antenna_names[cfg.master_index]
    pairs = [(a, t) for a in cfg.rover_names for t in cfg.transmitter_names]
    row = len(f"123.456,rx,{master},{pairs[0][0]},{pairs[0][1]},-12345.678901,12345,45.0") + 1
    n_ep = max(1, size // (row * len(pairs)))
    t = np.repeat(np.arange(n_ep) * 0.1, len(pairs))
    k = np.tile(np.arange(len(pairs)), n_ep)
    ph = np.sin(t * 0.7 + k) * 1000.0
    lines = [RECEIVER_HEADER]
    lines += [f"{ti:.3f},rx,{master},{pairs[ki][0]},{pairs[ki][1]},{pi:.6f},{i // len(pairs)},45.0"
              for i, (ti, ki, pi) in enumerate(zip(t.tolist(), k.tolist(), ph.tolist()))]
    p = folder / "receiver.csv"
    p.write_bytes((eol.join(lines) + eol).encode())
    return p


def _repeat(lines: list[str], h: int, blocks: list[list[str]], size: int, first_line, name: Path) -> Path:
    """Header ``lines[:h]``, then ``blocks`` repeated until ``size`` bytes, the first line of the
    k-th copy rewritten by ``first_line(k, line)``."""
    out, nbytes, k = lines[:h], 0, 0
    while nbytes < size:
        b = blocks[k % len(blocks)]
        out.append(first_line(k, b[0]))
        out.extend(b[1:])
        nbytes += sum(len(x) + 1 for x in b)
        k += 1
    name.write_text("\n".join(out) + "\n")
    return name


def _header_end(lines: list[str]) -> int:
    return next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1


def rinex2_obs(folder: Path, size: int) -> Path:
    """The real GEONET 0759 RINEX 2.10 file's epochs repeated (times shifted) up to ``size`` bytes."""
    lines = (SHARED / "rinex" / "07590920.05o").read_text().splitlines()
    h = _header_end(lines)
    blocks, cur = [], []
    for ln in lines[h:]:
        if len(ln) > 28 and ln[:3].strip().isdigit() and ln[3:6].strip().isdigit() and ln[26:29].strip() in "01":
            if cur:
                blocks.append(cur)
            cur = [ln]
        elif cur:
            cur.append(ln)
    blocks.append(cur)
    t0 = dt.datetime(2005, 4, 2)

    def epoch(k, line):
        t = t0 + dt.timedelta(seconds=30 * k)
        return f" {t.year % 100:02d}{t.month:3d}{t.day:3d}{t.hour:3d}{t.minute:3d}{t.second:11.7f}" + line[26:]

    return _repeat(lines, h, blocks, size, epoch, folder / "big.05o")


def rinex_nav(folder: Path, size: int) -> Path:
    """The real GEONET navigation file's records repeated, each copy's toc 2 h later."""
    lines = (SHARED / "rinex" / "07590920.05n").read_text().splitlines()
    h = _header_end(lines)
    recs = [lines[i:i + 8] for i in range(h, len(lines) - 7, 8)]

    def toc(k, line):
        copy = k // len(recs)
        return line[:2] + f" 05{4:3d}{2 + copy // 12:3d}{copy % 12 * 2:3d}{0:3d}{0.0:5.1f}" + line[22:]

    return _repeat(lines, h, recs, size, toc, folder / "big.05n")


def _fletcher(body: bytes) -> bytes:
    a = np.frombuffer(body, dtype=np.uint8).astype(np.int64)
    return bytes((int(a.sum()) & 0xFF, int(np.dot(np.arange(a.size, 0, -1), a)) & 0xFF))


def ubx_rawx(folder: Path, size: int) -> Path:
    """The real RXM-RAWX log's frames repeated with rcvTow advancing 1 s per frame (checksums
    recomputed)."""
    data = (SHARED / "ubx" / "pygpsdata-RXMRAWX.log").read_bytes()
    frames, k = [], 0
    while k < len(data):
        n = struct.unpack_from("<H", data, k + 4)[0]
        frames.append(bytearray(data[k:k + 8 + n]))
        k += 8 + n
    tow0 = struct.unpack_from("<d", frames[0], 6)[0]
    out, nbytes, i = [], 0, 0
    while nbytes < size:
        f = bytearray(frames[i % len(frames)])
        struct.pack_into("<d", f, 6, tow0 + i)
        f[-2:] = _fletcher(bytes(f[2:-2]))
        out.append(bytes(f))
        nbytes += len(f)
        i += 1
    p = folder / "big.ubx"
    p.write_bytes(b"".join(out))
    return p


def ubx_sync_noise(folder: Path, size: int, every: int = 8) -> Path:
    """Adversarial: the sync word every ``every`` bytes (at least 8), each announcing a 65 KB
    frame whose checksum fails, then one valid log at the end."""
    unit = b"\xb5\x62\x02\x15\xf0\xff" + b"\x00" * (every - 6)
    junk = unit * (size // every)
    p = folder / "noise.ubx"
    p.write_bytes(junk + (SHARED / "ubx" / "pygpsdata-RXMRAWX.log").read_bytes())
    return p


def toml_config(folder: Path, size: int, base: Path) -> Path:
    """A shipped structure config with ``size`` bytes of comment lines appended."""
    text = base.read_text()
    line = "# " + "x" * 76 + "\n"
    p = folder / "big.toml"
    p.write_text(text + line * max(1, size // len(line)))
    return p


def init_json(folder: Path, size: int) -> Path:
    """A JSON object with a long list of numbers (read_init_json: decoding, depth check, parse)."""
    n = max(1, size // 20)
    p = folder / "init.json"
    p.write_text('{"time_s": 0.0, "note": "scaling", "x": [' + ",".join(["0.1234567890123456"] * n) + "]}")
    return p


def rinex3_obs(folder: Path, size: int) -> Path:
    """A RINEX 3.04 observation file: the header cdgps writes (rinex_write) for 10 GPS
    satellites, then ``size`` bytes of 1 s epochs formatted here (the writer is slower than the
    reader; the records have its layout)."""
    import pandas as pd

    from cdgps_cli.io.rinex_write import write_rinex_obs

    sats = [f"G{k:02d}" for k in range(1, 11)]
    t0 = dt.datetime(2014, 11, 14, 11, 33, 4)
    obs = pd.DataFrame({"time_gps_s": 1.1e9, "sat": sats, "phase_l1_cycles": 1.0e8, "pseudorange_l1_m": 2.2e7,
                        "snr_l1_dbhz": 45.0})
    p = folder / "big.obs"
    write_rinex_obs(p, obs, {"approx_position_xyz_m": [-3976219.5, 3382372.6, 3652513.0]}, created="20260101 000000 UTC")
    lines = p.read_text().splitlines()
    out = lines[: next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1]
    n_ep = max(1, size // (36 + 10 * 50))
    for k in range(n_ep):
        t = t0 + dt.timedelta(seconds=k)
        out.append(f"> {t.year} {t.month:02d} {t.day:02d} {t.hour:02d} {t.minute:02d} {t.second:10.7f}  0 10")
        out.extend(f"{s}{22000000.0 + 190.0 * k:14.3f}  {1.0e8 + 1e6 * j + 1000.0 * k:14.3f} 7        45.000"
                   for j, s in enumerate(sats))
    p.write_text("\n".join(out) + "\n")
    return p


def mcap_file(folder: Path, size: int) -> Path:
    """A RUN-like MCAP with JSON messages on one channel (about ``size`` bytes uncompressed)."""
    from cdgps_cli.io.mcap import McapOut, message_schema

    schema = message_schema("cdgps.Scaling", {"v": {"type": "array", "items": {"type": "number"}}})
    p = folder / "big.mcap"
    rng = np.random.default_rng(0)
    per = 40
    n = max(1, size // (per * 20))      # about size bytes of JSON payload (zstd makes the file smaller)
    with McapOut(p) as out:
        ch = out.channel("/scaling", schema)
        for i in range(n):
            out.write(ch, i * 0.1, {"v": rng.standard_normal(per).round(6).tolist()})
        out.metadata("cdgps.ingest", {"kind": "scaling"})
    return p
