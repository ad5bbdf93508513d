"""Issue 12 item 5: no traceback for any user input.

One test per root cause of the fault-injection campaign: each runs the command on the bad input and
asserts exit status 2, a message naming the input (file, key, option) and no traceback.  The stream
cases (stdout to /dev/full, a closed pipe, a file-size limit) run the installed CLI in a subprocess.
"""

from __future__ import annotations

import json
import os
import re
import resource
import signal
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from cdgps_cli.cli.commands import BROKEN_PIPE_EXIT, main
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.limits import CONFIG_BOUNDS, MAX_TABLE_BYTES, OPTION_BOUNDS, config_range_problems
from cdgps_cli.io.mcap import read_mcap

CDGPS = [str(Path(sys.executable).parent / "cdgps")] if (Path(sys.executable).parent / "cdgps").exists() \
    else [sys.executable, "-m", "cdgps_cli.cli.commands"]


def _run(*args):
    return CliRunner().invoke(main, ["-q", *map(str, args)])


def assert_clean_error(r, *words):
    """Exit 2, every word in the message, no traceback (the exception is Click's SystemExit)."""
    out = r.output
    assert r.exit_code == 2, f"exit {r.exit_code}: {out}\n{r.exception!r}"
    assert isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in out
    for w in words:
        assert str(w) in out, f"{w!r} not in {out!r}"


@pytest.fixture(scope="module")
def base(tmp_path_factory, dof2_path):
    """A 6 s 2-DOF run: sim/ (CSV), RUN.mcap, INIT.json."""
    d = tmp_path_factory.mktemp("base")
    for args in (["simulate", dof2_path, "--duration", "6", "-o", d / "sim"],
                 ["ingest", d / "sim" / "receiver.csv", d / "sim" / "gyro.csv", "--config", dof2_path, "-o", d / "RUN.mcap"],
                 ["init", d / "RUN.mcap", "-o", d / "INIT.json"]):
        r = _run(*args)
        assert r.exit_code == 0, r.output
    return d


# ---- corrupted MCAP chunks, flipped indexes ----------------------------------------------------------


def _chunk_data_offset(path: Path) -> int:
    """File offset of the compressed bytes of the first chunk (after its record header)."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        ci = make_reader(fh).get_summary().chunk_indexes[0]
    comp = ci.compression.encode()
    return ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(comp) + 8


def _recompute_crcs(data: bytearray) -> bytearray:
    """The file with its data-section and summary CRCs recomputed, so that the damage reaches the
    readers behind them (as in a file of another tool that writes no data-section CRC)."""
    import zlib

    summary_start, = struct.unpack("<Q", data[-8 - 4 - 8 - 8:-8 - 4 - 8])
    data_end = summary_start - 13
    data[data_end + 9:data_end + 13] = struct.pack("<I", zlib.crc32(bytes(data[:data_end])))
    data[-8 - 4:-8] = struct.pack("<I", zlib.crc32(bytes(data[summary_start:-8 - 4])))
    return data


def test_corrupt_zstd_chunk_is_a_clean_error(base, tmp_path):
    data = bytearray((base / "RUN.mcap").read_bytes())
    off = _chunk_data_offset(base / "RUN.mcap")
    for i in range(off + 20, off + 60):
        data[i] ^= 0x5A
    bad = tmp_path / "run.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(CdgpsError, match="data section fails its CRC check"):
        read_mcap(bad)
    bad.write_bytes(bytes(_recompute_crcs(data)))           # behind the CRC: the decompressor's error
    with pytest.raises(CdgpsError, match="corrupt"):
        read_mcap(bad)
    # info --deep decompresses and decodes the messages; plain info checks the data-section CRC (recomputed
    # here, as a forger would) and the indexes, not each chunk's CRC (docs/hardening.md, "MCAP integrity")
    assert_clean_error(_run("info", bad, "--json", "--deep"), bad, "not a valid MCAP file")
    # init reads the phase table from its packed arrays (their own CRCs hold): the messages' damage
    # does not reach it, and its solution is that of the intact file
    r = _run("init", bad, "-o", tmp_path / "i.json")
    assert r.exit_code == 0, r.output
    got, want = json.loads((tmp_path / "i.json").read_text()), json.loads((base / "INIT.json").read_text())
    assert got["biases"] == want["biases"] and got["state"] == want["state"]


def test_flipped_record_length_is_bounded_by_the_file_size(base, tmp_path):
    """A summary record whose length field says 2**62 bytes: no MemoryError/OverflowError."""
    data = bytearray((base / "RUN.mcap").read_bytes())
    summary_start = struct.unpack("<Q", data[-8 - 4 - 8 - 8:-8 - 4 - 8])[0]   # footer: start, offsets start, crc
    assert 0 < summary_start < len(data)
    data[summary_start + 1:summary_start + 9] = struct.pack("<Q", 2**62)
    bad = tmp_path / "run.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(CdgpsError, match="summary section fails its CRC check"):
        read_mcap(bad)
    bad.write_bytes(bytes(_recompute_crcs(data)))           # behind the CRC: bounded by the file size
    with pytest.raises(CdgpsError, match="not a valid MCAP file"):
        read_mcap(bad)
    assert_clean_error(_run("info", bad), bad)


# ---- disk full, stdout to a full device or a closed pipe -------------------------------------------


def _limit_file_size(size: int):
    def f():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
    return f


@pytest.mark.parametrize("command", ["ingest", "estimate"])
def test_file_size_limit_during_output_is_a_clean_error(base, tmp_path, dof2_path, command):
    out = tmp_path / "out.mcap"
    args = (["ingest", base / "sim" / "receiver.csv", "--config", dof2_path, "-o", out] if command == "ingest"
            else ["estimate", base / "RUN.mcap", "--init", base / "INIT.json", "-o", out])
    r = subprocess.run(CDGPS + ["-q", *map(str, args)], capture_output=True, text=True,
                       preexec_fn=_limit_file_size(4096), timeout=300)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert str(out) in r.stderr and "file too large" in r.stderr
    assert not out.exists() and not list(tmp_path.glob(".*tmp*"))      # nothing half-written


def test_no_space_while_writing_an_mcap_is_named(base, tmp_path, monkeypatch):
    """ENOSPC (monkeypatched into the MCAP writer's file) is reported with the output path."""
    import errno

    import cdgps_cli.io.mcap as mio

    real_open = open

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def write(self, b):
            raise OSError(errno.ENOSPC, "No space left on device")

        def __getattr__(self, name):
            return getattr(self.fh, name)

    monkeypatch.setattr(mio, "open", lambda p, mode="r", *a, **k: Full(real_open(p, mode, *a, **k)) if "w" in mode
                        else real_open(p, mode, *a, **k), raising=False)
    real_anonymous = mio.open_anonymous             # the unnamed (O_TMPFILE) file, where the system has it
    monkeypatch.setattr(mio, "open_anonymous", lambda d: (lambda fh: None if fh is None else Full(fh))(real_anonymous(d)))
    out = tmp_path / "STATES.mcap"
    r = _run("estimate", base / "RUN.mcap", "--init", base / "INIT.json", "-o", out)
    assert_clean_error(r, out, "no space left on the device")
    assert not out.exists()


def test_stdout_to_a_full_device(base):
    with open("/dev/full", "w") as full:
        r = subprocess.run(CDGPS + ["info", str(base / "RUN.mcap"), "--json"], stdout=full, stderr=subprocess.PIPE,
                           text=True, timeout=300)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "standard output" in r.stderr


def test_stdout_to_a_closed_pipe_exits_quietly(base):
    rd, wr = os.pipe()
    os.close(rd)                                       # the reader (`| head`) has gone
    try:
        r = subprocess.run(CDGPS + ["info", str(base / "RUN.mcap"), "--json"], stdout=wr, stderr=subprocess.PIPE,
                           text=True, timeout=300)
    finally:
        os.close(wr)
    assert r.returncode == BROKEN_PIPE_EXIT
    assert r.stderr == ""


# ---- out-of-range floats in CSV ------------------------------------------------------------------------


@pytest.mark.parametrize("column,value,words", [
    ("snr_dbhz", "inf", "column snr_dbhz: outside the plausible range"),
    ("phase_cycles", "1e999", "column phase_cycles: outside the plausible range"),
    ("time_s", "1e12", "column time_s: outside the plausible range"),
    ("lock", "inf", "column lock"),
])
def test_out_of_range_csv_values(base, tmp_path, dof2_path, column, value, words):
    lines = (base / "sim" / "receiver.csv").read_text().splitlines()
    header = lines[0].split(",")
    last = lines[-1].split(",")
    last[header.index(column)] = value
    bad = tmp_path / "receiver.csv"
    bad.write_text("\n".join(lines[:-1] + [",".join(last)]) + "\n")
    r = _run("ingest", bad, "--config", dof2_path, "-o", tmp_path / "r.mcap")
    assert_clean_error(r, f"{bad}, line {len(lines)}", words)


# ---- wrongly typed config keys; extreme but accepted numbers -----------------------------------------


@pytest.mark.parametrize("old,new,key", [
    ('section = "hub1"', 'section = ["C1"]', "antennas[0].section"),
    ('kind = "rotation"', "kind = { a = 1 }", "coordinates[0].kind"),
])
def test_wrongly_typed_config_key_is_named(tmp_path, dof2_text, old, new, key):
    bad = tmp_path / "s.toml"
    bad.write_text(dof2_text.replace(old, new, 1))
    assert_clean_error(_run("simulate", bad, "--duration", "2", "-o", tmp_path / "sim"), bad, key)


@pytest.mark.parametrize("old,new,key", [
    ("position_m = [1.0, 0.0, 0.0]", "position_m = [1e308, 0.0, 0.0]", "antennas[0].position_m[0]"),
    ("sample_period_s = 0.12", "sample_period_s = 1e-308", "model.sample_period_s"),
    ("time_constant_s = 150.0", "time_constant_s = 1e-9", "modes[0].time_constant_s"),
])
def test_implausible_config_number_is_refused_up_front(tmp_path, dof2_text, old, new, key):
    bad = tmp_path / "s.toml"
    bad.write_text(dof2_text.replace(old, new, 1))
    assert old in dof2_text
    r = _run("simulate", bad, "--duration", "2", "-o", tmp_path / "sim")
    assert_clean_error(r, bad, key, "outside the plausible range")


def test_bounds_are_documented_and_accept_the_shipped_configs(repo_root):
    from cdgps_cli.config.structure import config_kind, load_config

    doc = (repo_root / "docs" / "config-format.md").read_text()
    for key in CONFIG_BOUNDS:
        assert f"`{key}`" in doc, key
    for name in OPTION_BOUNDS:
        assert f"`{name}`" in doc, name
    import tomllib
    for f in sorted((repo_root / "configs").glob("*.toml")):
        if config_kind(f.read_text()) == "structure":
            assert config_range_problems(tomllib.loads(f.read_text())) == [], f
            load_config(f)


# ---- INIT.json: non-UTF-8, deeply nested, a time before the run --------------------------------------


@pytest.mark.parametrize("kind,words", [("non-UTF-8", "not UTF-8"), ("nested", "nested deeper")])
def test_unreadable_init_json(base, tmp_path, kind, words):
    raw = (base / "INIT.json").read_bytes()
    bad = tmp_path / "INIT.json"
    bad.write_bytes(raw[:50] + b"\xff" + raw[50:] if kind == "non-UTF-8" else b"[" * 100_000 + b"]" * 100_000)
    r = _run("estimate", base / "RUN.mcap", "--init", bad, "-o", tmp_path / "s.mcap", "--allow-other-run")
    assert_clean_error(r, bad, "line ", words)


# ---- TOML and JSON nested hundreds of levels deep: tomllib and json recurse until RecursionError --------


DEEP_TOML = "a = " + "[" * 5000 + "]" * 5000 + "\n"
DEEP_JSON = "{\"format\": " + "[" * 100_000 + "]" * 100_000 + "}"


@pytest.mark.parametrize("command", ["ingest", "simulate", "baseline", "batch", "control"])
def test_deeply_nested_toml_is_a_toml_error_naming_the_file(base, tmp_path, command):
    # each died with "RecursionError: maximum recursion depth exceeded" (batch: exit 4, "the batch itself failed")
    deep = tmp_path / "deep.toml"
    deep.write_text(DEEP_TOML)
    out = tmp_path / "out"
    argv = {"ingest": ["ingest", base / "sim" / "receiver.csv", "--config", deep, "-o", out],
            "simulate": ["simulate", deep, "--duration", 1, "-o", out],
            "baseline": ["baseline", "--config", deep, "-o", out],
            "batch": ["batch", deep, "-o", out],
            "control": ["control", "design", deep, "-o", out]}[command]
    r = _run(*argv)
    assert_clean_error(r, deep, "not valid TOML", "nested too deeply")
    assert not out.exists()


@pytest.mark.parametrize("what", ["if.json", "GAINS.json", "truth.json"])
def test_deeply_nested_json_inputs_are_named_with_the_line(base, tmp_path, dof2_path, what):
    # track-structure, simulate --controller, report control and evaluate died with a RecursionError
    deep = tmp_path / ("truth" if what == "truth.json" else "") / what
    deep.parent.mkdir(exist_ok=True)
    deep.write_text(DEEP_JSON)
    out = tmp_path / "out"
    if what == "if.json":
        r = _run("track-structure", deep, "--config", dof2_path, "-o", out)
    elif what == "GAINS.json":
        r = _run("report", "control", deep, "--open", base / "sim", "--closed", base / "sim", "-o", out)
    else:
        (deep.parent / "truth.csv").write_bytes((base / "sim" / "truth.csv").read_bytes())
        states = tmp_path / "states.mcap"
        assert _run("estimate", base / "RUN.mcap", "--init", base / "INIT.json", "-o", states).exit_code == 0
        r = _run("evaluate", "--truth", deep.parent, "--estimate", states)
    assert_clean_error(r, deep, "line 1: JSON nested deeper than 64 levels", what)
    assert not out.exists()


def test_init_time_before_the_run_is_refused_not_allocated(base, tmp_path):
    """time_s = -1e9 s would size the filter grid at ~8e9 epochs (74.5 GiB in the campaign)."""
    init = json.loads((base / "INIT.json").read_text())
    init["state"]["time_s"] = -1e9
    bad = tmp_path / "INIT.json"
    bad.write_text(json.dumps(init))
    r = _run("estimate", base / "RUN.mcap", "--init", bad, "-o", tmp_path / "s.mcap", "--allow-other-run")
    assert_clean_error(r, "state.time_s", "before the first epoch")


def test_implausible_init_state_is_refused(base, tmp_path):
    """state.x = 1e308 used to reach the filter and fail writing NaN states (ValueError)."""
    init = json.loads((base / "INIT.json").read_text())
    init["state"]["x"] = [1e308] * len(init["state"]["x"])
    bad = tmp_path / "INIT.json"
    bad.write_text(json.dumps(init))
    r = _run("estimate", base / "RUN.mcap", "--init", bad, "-o", tmp_path / "s.mcap", "--allow-other-run")
    assert_clean_error(r, "state.x", "outside the plausible range")


# ---- options ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("args,words", [
    (["simulate", "{cfg}", "--seed", "-1"], ["--seed", "outside the plausible range"]),
    (["simulate", "{cfg}", "--duration", "1e12"], ["--duration", "outside the plausible range"]),
    (["simulate", "{cfg}", "--duration", "1e9"], ["--duration", "would need about", "TiB"]),
    (["simulate-gnss", "--duration", "1e9"], ["--duration", "would need about", "TiB"]),
    (["simulate-gnss", "--duration", "86400", "--rate-hz", "100"], ["--rate-hz 100", "would need about", "GiB"]),
    (["init", "{run}", "--ratio", "nan"], ["--ratio", "not a finite number"]),
    (["init", "{run}", "--starts", "1000000000"], ["--starts", "outside the plausible range"]),
    (["spectra", "{run}", "--segment-s", "inf"], ["--segment-s", "not a finite number"]),
    (["spectra", "{run}", "--pad", "1000000000"], ["--pad", "outside the plausible range"]),
])
def test_extreme_option_values(base, tmp_path, dof2_path, args, words):
    args = [str(a).replace("{cfg}", str(dof2_path)).replace("{run}", str(base / "RUN.mcap")) for a in args]
    assert_clean_error(_run(*args, "-o", tmp_path / "out"), *words)


def test_memory_bound_is_the_documented_one(dof2_cfg):
    """The simulate bound is epochs x channels x bytes against MAX_TABLE_BYTES (independent count)."""
    from cdgps_cli.sim.structure import SIM_BYTES_PER_VALUE, SimOptions, simulate

    per_s = len(dof2_cfg.channels) * SIM_BYTES_PER_VALUE / dof2_cfg.sample_period_s
    limit_s = MAX_TABLE_BYTES / per_s
    with pytest.raises(CdgpsError, match=r"--duration .*would need about"):
        simulate(dof2_cfg, SimOptions(duration_s=limit_s * 1.01))
    assert re.search(r"GiB|TiB", str(pytest.raises(CdgpsError, simulate, dof2_cfg,
                                                   SimOptions(duration_s=limit_s * 2)).value))


# ---- the last line of defence does not hide programming errors ---------------------------------------


def test_programming_errors_keep_their_traceback(base, monkeypatch):
    import cdgps_cli.io.run as run_mod

    monkeypatch.setattr(run_mod, "summary_info", lambda *a, **k: {}["missing"])     # (info tries it first)
    r = _run("info", base / "RUN.mcap")
    assert r.exit_code == 1 and isinstance(r.exception, KeyError)
