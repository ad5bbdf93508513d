"""UBX/NMEA/RTCM 3 framing throughput and what it skips (issue 14 item 3; docs/gnss-pipeline.md "u-blox logs").

Run from the repository root: ``.venv/bin/python benchmarks/bench_ubx_framing.py`` (about 5 s).
Prints, per real log of ../shared/data/ubx, the frames and bytes skipped, and the split time per MB
of a 10 MB mixed stream (the real RXM-RAWX log's frames, one RTCM 3 frame and two NMEA sentences per
epoch, random garbage between) and of 10 MB of random bytes.
"""
import os
import random
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "io"))
from cdgps_cli.io.ubx_frames import split_stream
from test_ubx_frames import _nmea, _rtcm  # noqa: E402

SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "ubx")
for p in sorted(os.listdir(SHARED)):
    d = open(SHARED + "/" + p, "rb").read()
    t = time.perf_counter(); u, r, s = split_stream(d); dt = time.perf_counter() - t
    print(f"{p}: {len(d)} B, {len(u)} UBX frames, skipped {s['skipped_bytes']} B, bad checksum {s['bad_checksum_frames']}, "
          f"truncated tail {s['truncated_tail_bytes']} B, NMEA {s['nmea_sentences']} ({s['nmea_bytes']} B), RTCM {s['rtcm_frames']}; {dt*1e3:.1f} ms")
rng = random.Random(3)
log = open(SHARED + "/pygpsdata-RXMRAWX.log", "rb").read()
# a 10 MB mixed stream: the RAWX log's frames, one 1077-like RTCM frame and two NMEA sentences per epoch, 1% garbage
epoch = log + _rtcm(1077, bytes(rng.randrange(256) for _ in range(300))) + _nmea("GNGGA,1,2,3,4") * 2
parts = []
n = 0
while n < 10_000_000:
    g = bytes(rng.randrange(256) for _ in range(rng.randrange(200)))
    parts += [epoch, g]; n += len(epoch) + len(g)
data = b"".join(parts)
t = time.perf_counter(); u, r, s = split_stream(data); dt = time.perf_counter() - t
print(f"mixed {len(data)/1e6:.1f} MB: {len(u)} UBX, {sum(s['rtcm_frames'].values())} RTCM, {s['nmea_sentences']} NMEA, skipped {s['skipped_bytes']} B, bad ubx {s['bad_checksum_frames']}, bad rtcm {s['bad_crc_rtcm_frames']}: split {dt:.2f} s = {dt/(len(data)/1e6):.3f} s/MB")
noise = bytes(rng.randrange(256) for _ in range(10_000_000))
t = time.perf_counter(); u, r, s = split_stream(noise); dt = time.perf_counter() - t
print(f"random noise 10 MB: split {dt:.2f} s = {dt/10:.3f} s/MB, false UBX {len(u)}, false RTCM {len(r)}, bad ubx {s['bad_checksum_frames']}, bad rtcm {s['bad_crc_rtcm_frames']}")
