"""`cdgps spectra` in chunks (issue 29): the streaming path gives exactly the whole-record numbers.

* :class:`WelchAccumulator` fed in chunks (1 epoch up to more than the record, Welch segments
  straddling every boundary) equals one feed, and one feed equals the previous whole-record
  ``cross_spectral_matrix`` bit for bit (reference copy below) for two or more columns;
* :func:`spectra_of_chunks` with 37-epoch chunks equals :func:`compute_spectra` on the arrays, every
  array and every mode figure exactly, gyros included;
* :class:`PackedRows` gives the bits of :func:`unpack` in any chunking (delta orders 0-2);
* a STATES.mcap read by :class:`StatesChunks` in 37-epoch chunks writes the same psd.csv and
  peaks.json bytes as in one chunk, and within rounding of today's whole-record reader (q by BLAS).
"""

from __future__ import annotations

import numpy as np
import pytest

from cdgps_cli.analysis.spectra import (SpectraOptions, WelchAccumulator, column_means, compute_spectra,
                                        cross_spectral_matrix, spectra_of_chunks)
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.core.rowmath import rows_matmul
from cdgps_cli.io.packed_arrays import PackedRows, pack, unpack
from cdgps_cli.sim.structure import SimOptions, simulate

FS = 10.0


def _old_cross_spectral_matrix(x, fs, nperseg, overlap, nfft):
    """cross_spectral_matrix as it was before the accumulator (commit 08c940c), for the identity test."""
    step = max(nperseg - int(nperseg * overlap), 1)
    xc = x - x.mean(axis=0)
    starts = np.arange(0, x.shape[0] - nperseg + 1, step)
    seg = np.stack([xc[s:s + nperseg] for s in starts])
    seg = seg - seg.mean(axis=1, keepdims=True)
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(nperseg) / nperseg)
    X = np.fft.rfft(seg * w[None, :, None], n=nfft, axis=1)
    G = np.einsum("sfi,sfj->fij", X, X.conj()) * (1.0 / (fs * np.sum(w**2))) / seg.shape[0]
    if nfft % 2 == 0:
        G[1:-1] *= 2.0
    else:
        G[1:] *= 2.0
    return np.fft.rfftfreq(nfft, 1.0 / fs), G


def _series(n, m, seed=0):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((n, m)).cumsum(axis=0) * 0.01 + rng.standard_normal(m) * 3


@pytest.mark.parametrize("m", [1, 2, 5])
@pytest.mark.parametrize("chunk", [1, 7, 100, 333, 5000])
def test_welch_accumulator_chunks_equal_one_feed(m, chunk):
    x = _series(2011, m)
    nperseg, nfft, overlap = 256, 1024, 0.5                 # 14 segments, step 128: most straddle a chunk edge
    f1, G1 = cross_spectral_matrix(x, FS, nperseg, overlap, nfft)
    acc = WelchAccumulator(column_means(x), FS, nperseg, overlap, nfft)
    for a in range(0, len(x), chunk):
        acc.feed(x[a:a + chunk])
    f2, G2 = acc.result()
    assert acc.segments == (len(x) - nperseg) // 128 + 1
    assert np.array_equal(f1, f2) and np.array_equal(G1, G2)


@pytest.mark.parametrize("m,nperseg,overlap,nfft", [(2, 256, 0.5, 1024), (4, 300, 0.25, 2048), (3, 601, 0.5, 2405)])
def test_cross_spectral_matrix_identical_to_previous_code(m, nperseg, overlap, nfft):
    """Two or more columns: the same bits as the whole-record code it replaced (numpy sums the rows of
    an (N, m ≥ 2) array one after the other, as the accumulator does)."""
    x = _series(3001, m, seed=m)
    f0, G0 = _old_cross_spectral_matrix(x, FS, nperseg, overlap, nfft)
    f1, G1 = cross_spectral_matrix(x, FS, nperseg, overlap, nfft)
    assert np.array_equal(f0, f1) and np.array_equal(G0, G1)
    assert np.array_equal(column_means(x), x.mean(axis=0))


def test_single_column_differs_from_previous_code_at_rounding_only():
    """One column: numpy's mean of a 1-D series is a pairwise sum over the whole length (a tree no chunked
    reader can rebuild); the sequential mean differs in the last bits only, and so does the PSD."""
    x = _series(3001, 1, seed=3)
    _, G0 = _old_cross_spectral_matrix(x, FS, 256, 0.5, 1024)
    _, G1 = cross_spectral_matrix(x, FS, 256, 0.5, 1024)
    np.testing.assert_allclose(G1.real, G0.real, rtol=0, atol=1e-13 * np.abs(G0).max())


@pytest.fixture(scope="module")
def truth(testbed_cfg):
    r = simulate(testbed_cfg, SimOptions(duration_s=400, seed=3))
    g = r.gyro.pivot_table(index="time_s", columns="gyro", values="rate_rad_s")[list(testbed_cfg.gyro_names)]
    return r, g.index.to_numpy(), g.to_numpy()


def _assert_same_result(a: dict, b: dict) -> None:
    assert np.array_equal(a["f_hz"], b["f_hz"]) and np.array_equal(a["fdd_sv"], b["fdd_sv"])
    assert list(a["psd"]) == list(b["psd"])
    for k in a["psd"]:
        assert np.array_equal(a["psd"][k], b["psd"][k], equal_nan=True), k
    assert a["modes"] == b["modes"] and a["settings"] == b["settings"] and a["peaks"] == b["peaks"]


@pytest.mark.parametrize("chunk", [37, 1000])
def test_spectra_of_chunks_equals_whole_record(testbed_cfg, truth, chunk):
    """Every array and every mode figure bit for bit, gyros included; segments of 300 epochs
    straddle the 37-epoch chunks."""
    r, gt, gr = truth
    opt = SpectraOptions(segment_s=30.0)
    whole = compute_spectra(testbed_cfg, r.time_s, r.q, gt, gr, opt)
    N = len(r.time_s)

    def chunks():
        return ((r.time_s[a:a + chunk], r.q[a:a + chunk]) for a in range(0, N, chunk))
    _assert_same_result(spectra_of_chunks(testbed_cfg, chunks, N, gt, gr, opt), whole)
    assert whole["settings"]["segments"] > 20 and any(m["gps_hz"] for m in whole["modes"])


def test_spectra_of_chunks_errors_as_whole_record(testbed_cfg, truth):
    """Bad records are refused with the whole-record messages, whichever chunk holds the fault."""
    r, _, _ = truth
    t, q = r.time_s.copy(), r.q.copy()
    q[2500, 3] = np.nan
    t2 = t.copy()
    t2[3000] = t2[2999]

    def by37(tt, qq):
        return lambda: ((tt[a:a + 37], qq[a:a + 37]) for a in range(0, len(tt), 37))
    for tt, qq, msg in ((t, q, "non-finite value (q4 at 250 s)"), (t2, r.q, "not increasing")):
        with pytest.raises(CdgpsError, match=r"" + msg.replace("(", r"\(").replace(")", r"\)")):
            compute_spectra(testbed_cfg, tt, qq)
        with pytest.raises(CdgpsError, match=r"" + msg.replace("(", r"\(").replace(")", r"\)")):
            spectra_of_chunks(testbed_cfg, by37(tt, qq), len(tt))


def test_rows_matmul_is_chunk_invariant():
    rng = np.random.default_rng(5)
    a, b = rng.standard_normal((1001, 7)), rng.standard_normal((7, 11))
    whole = rows_matmul(a, b)
    assert np.array_equal(np.vstack([rows_matmul(a[i:i + 3], b) for i in range(0, 1001, 3)]), whole)
    np.testing.assert_allclose(whole, a @ b, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("delta", [0, 1, 2])
@pytest.mark.parametrize("dtype", [np.float64, np.int32, np.float32])
def test_packed_rows_equal_unpack(delta, dtype):
    rng = np.random.default_rng(delta)
    arr = (rng.standard_normal((503, 3, 2)).cumsum(axis=0) * 100).astype(dtype)
    data = pack(arr, delta)
    pos = [0]

    def read(n):
        out = data[pos[0]:pos[0] + n]
        pos[0] += len(out)
        return out
    rows = PackedRows(read, len(data))
    try:
        for chunk in (1, 10, 64, 1000):
            got = np.concatenate(list(rows.chunks(chunk)))
            assert got.dtype == arr.dtype and np.array_equal(got.view(np.uint8), unpack(data).view(np.uint8))
    finally:
        rows.close()


def test_packed_rows_refuse_damaged_bytes():
    data = bytearray(pack(np.arange(1000.0), 2))
    cut = bytes(data[:-20])
    with pytest.raises(ValueError, match="truncated|bytes of content|damaged"):
        PackedRows(_reader(cut), len(data))
    data[-5] ^= 0xFF
    with pytest.raises(ValueError):
        PackedRows(_reader(bytes(data)), len(data))


def _reader(data: bytes):
    pos = [0]

    def read(n):
        out = data[pos[0]:pos[0] + n]
        pos[0] += len(out)
        return out
    return read


@pytest.fixture(scope="module")
def states_file(tmp_path_factory, testbed_cfg):
    """A STATES.mcap of 120 s of simulator truth (states written by the estimate writer)."""
    from cdgps_cli.estimation.filter import EstimateResult
    from cdgps_cli.io.mcap import McapOut
    from cdgps_cli.pipeline.estimate_outputs import write_states

    d = tmp_path_factory.mktemp("states")
    r = simulate(testbed_cfg, SimOptions(duration_s=120, seed=11))
    N, n = r.x.shape
    P = np.broadcast_to(np.eye(n) * 1e-6, (N, n, n)).copy()
    res = EstimateResult(testbed_cfg, r.time_s, r.x, P, None, None, [("a", "b")], np.full((N, 1), 0.001),
                         np.ones(N), np.ones(N, dtype=int))
    with McapOut(d / "run.mcap") as out:                     # stand-in RUN: only its ingest record
        out.metadata("cdgps.ingest", {"kind": "structure"})
    write_states(res, d / "run.mcap", {}, "{}", d / "states.mcap", {})
    return d / "states.mcap"


def test_states_chunks_read_the_arrays(states_file, testbed_cfg):
    from cdgps_cli.io.states import States, StatesChunks, rows_q

    st = States(states_file, diagnostics=False)
    with StatesChunks(states_file) as sc:
        assert sc.n_epochs == len(st.time_s) and sc.cfg.sha256 == st.cfg.sha256 and sc.coord_names == st.coord_names
        parts = list(sc.chunks(37))
        assert len(parts) == -(-len(st.time_s) // 37)
        assert np.array_equal(np.concatenate([p[0] for p in parts]), st.time_s)
        q = np.concatenate([p[1] for p in parts])
        assert np.array_equal(q, rows_q(st.output_map, st.xi))
        np.testing.assert_allclose(q, st.q, rtol=0, atol=1e-14 * np.abs(st.q).max())


def test_spectra_files_do_not_depend_on_the_chunk(states_file, tmp_path, monkeypatch):
    """run_spectra on StatesChunks: 37-epoch chunks and one chunk write the same psd.csv, peaks.json
    (figures not drawn here: seconds each); today's whole-record reader (q by BLAS) agrees within rounding."""
    from cdgps_cli.io.states import States, StatesChunks
    from cdgps_cli.report import sensor_reports
    from cdgps_cli.report.sensor_reports import run_spectra

    monkeypatch.setattr(sensor_reports, "plot_psd", lambda *a: None)
    monkeypatch.setattr(sensor_reports, "plot_fdd", lambda *a: None)
    monkeypatch.setattr(sensor_reports, "_save_fig", lambda fig, path: str(path))

    opt = SpectraOptions(segment_s=10.0)
    out = {}
    for chunk in (37, 10**6):
        with StatesChunks(states_file) as sc:
            run_spectra(sc, None, opt, tmp_path / str(chunk), chunk_epochs=chunk)
        out[chunk] = {n: (tmp_path / str(chunk) / n).read_bytes() for n in ("psd.csv", "peaks.json")}
    assert out[37] == out[10**6]
    st = States(states_file, diagnostics=False)
    old = compute_spectra(st.cfg, st.time_s, st.q, opt=opt)
    with StatesChunks(states_file) as sc:
        new = spectra_of_chunks(sc.cfg, lambda: sc.chunks(37), sc.n_epochs, opt=opt)
    for k in old["psd"]:
        np.testing.assert_allclose(new["psd"][k], old["psd"][k], rtol=0, atol=1e-9 * np.abs(old["psd"][k]).max())
    for a, b in zip(old["modes"], new["modes"]):
        assert a["mode"] == b["mode"] and a["seen"] == b["seen"]
        if a["gps_hz"] is not None:
            assert b["gps_hz"] == pytest.approx(a["gps_hz"], rel=1e-6)


def test_column_scratch_round_trip_and_spectra(testbed_cfg, truth):
    """The modal series kept on disk (ColumnScratch) give the in-memory result bit for bit."""
    from cdgps_cli.io.column_scratch import ColumnScratch

    s = ColumnScratch(10, 3)
    block = np.arange(30.0).reshape(10, 3)
    s.write(0, block[:4])
    s.write(4, block[4:])
    assert np.array_equal(s.column(2), block[:, 2])
    with pytest.raises(ValueError):
        s.write(8, block[:4])
    s.close()
    r, gt, gr = truth
    opt = SpectraOptions(segment_s=30.0)
    N = len(r.time_s)

    def chunks():
        return ((r.time_s[a:a + 500], r.q[a:a + 500]) for a in range(0, N, 500))
    _assert_same_result(spectra_of_chunks(testbed_cfg, chunks, N, gt, gr, opt, columns=ColumnScratch),
                        compute_spectra(testbed_cfg, r.time_s, r.q, gt, gr, opt))


@pytest.mark.parametrize("name", ["format-2026-12-03/structure-states.mcap", "format-2026-12-03/gnss-states.mcap",
                                  "format-2026-12-02/states.mcap"])
def test_states_chunks_read_earlier_layouts(name):
    """Files of the earlier layouts (packed arrays described by config.toml; .npy attachments): the
    chunks hold the reader's times and the coordinates of the packed ξ (or, without packed arrays,
    the reader's own q)."""
    from pathlib import Path

    from cdgps_cli.io.states import States, StatesChunks, rows_q

    path = Path(__file__).resolve().parents[1] / "data" / name
    st = States(path, diagnostics=False)
    with StatesChunks(path) as sc:
        assert sc.n_epochs == len(st.time_s) and sc.coord_names == st.coord_names and sc.kind == st.kind
        parts = list(sc.chunks(50))
    assert np.array_equal(np.concatenate([p[0] for p in parts]), st.time_s)
    q = np.concatenate([p[1] for p in parts])
    want = rows_q(st.output_map, st.xi) if sc._whole is None else st.q
    assert np.array_equal(q, want, equal_nan=True)
    np.testing.assert_allclose(q, st.q, rtol=0, atol=1e-13 * np.nanmax(np.abs(st.q)))


def test_states_chunks_refuse_a_run_and_a_damaged_file(states_file, tmp_path):
    from cdgps_cli.io.states import StatesChunks

    with pytest.raises(CdgpsError, match="RUN.mcap"):
        StatesChunks(states_file.parent / "run.mcap")
    data = bytearray(states_file.read_bytes())
    data[len(data) // 3] ^= 0x55
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(CdgpsError, match="bad.mcap"):
        StatesChunks(bad)
