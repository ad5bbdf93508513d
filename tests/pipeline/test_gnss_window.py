"""`init --start/--duration` on a GNSS run: init reads only its window of the record, estimate the same window
(issue 29: a long record processed window by window, each in the memory of its window).

The independent check: the INIT of a window of a RUN equals the INIT of a RUN ingested from the RINEX files cut to
that window by hand (epoch records counted in the text: the rover's in the window, the master's with the margin of
gnss.max_age_s + gnss.sync_tol_s on each side, where its pairs and bridges come from), and its STATES hold the same
states; the window crosses an archive block (an hour of GPS time).  The simulated master is tagged 4 ms before the
rover: a master cut to the window alone would lose the epoch the rover's first pairs with.
"""

import json

import numpy as np
import pytest

from tests._shared import REPO_ROOT, run_cli

START_S, DURATION_S, INTERVAL_S = 3000.0, 900.0, 2.0
MARGIN_S = 30.025                       # gnss.max_age_s + gnss.sync_tol_s (defaults)


def _cut_rinex3(src, dst, first: int, count: int) -> None:
    """A RINEX 3 observation file keeping its header and the epoch records first … first+count−1."""
    lines = src.read_text().splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    out, k = lines[:end], -1
    for ln in lines[end:]:
        if ln.startswith(">"):
            k += 1
        if first <= k < first + count:
            out.append(ln)
    dst.write_text("".join(out))


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("window")
    sim = d / "sim"
    assert run_cli("-q", "simulate-gnss", "--duration", "4000", "--rate-hz", str(1 / INTERVAL_S), "--seed", "5",
                   "-o", sim).exit_code == 0
    assert run_cli("-q", "ingest", "--config", sim / "config.toml", "-o", d / "run.mcap").exit_code == 0
    cut = d / "cut"
    cut.mkdir()
    from cdgps_cli.io.gnss_run import read_receiver_file     # noqa: PLC0415 (the epochs' tags, to count them)

    tags = {n: np.unique(read_receiver_file(n, "rinex", sim / f"{n}.rnx").raw["time_gps_s"].to_numpy())
            for n in ("base", "rover")}
    t0 = min(t[0] for t in tags.values()) + START_S
    for n, m in (("rover", 0.0), ("base", MARGIN_S)):
        keep = np.flatnonzero((tags[n] >= t0 - m) & (tags[n] < t0 + DURATION_S + m))
        assert np.all(np.diff(keep) == 1)
        _cut_rinex3(sim / f"{n}.rnx", cut / f"{n}.rnx", int(keep[0]), int(keep.size))
    cfg = (sim / "config.toml").read_text()
    (cut / "config.toml").write_text(cfg.replace('"base.rnx"', f'"{cut / "base.rnx"}"')
                                     .replace('"rover.rnx"', f'"{cut / "rover.rnx"}"')
                                     .replace('"nav.rnx"', f'"{sim / "nav.rnx"}"'))
    assert run_cli("-q", "ingest", "--config", cut / "config.toml", "-o", d / "cut.mcap").exit_code == 0
    return d


def _without(init: dict, *keys) -> dict:
    return {k: v for k, v in init.items() if k not in keys}


def test_the_init_of_a_window_is_the_init_of_the_files_cut_to_it(pair):
    r = run_cli("init", pair / "run.mcap", "--start", START_S, "--duration", DURATION_S, "-o", pair / "w.json")
    assert r.exit_code == 0, r.output
    assert "window: 2024-01-01 00:50:00 GPST – 2024-01-01 01:05:00 GPST (3000 s after" in r.stderr
    assert run_cli("-q", "init", pair / "cut.mcap", "-o", pair / "c.json").exit_code == 0
    w, c = (json.loads((pair / f).read_text()) for f in ("w.json", "c.json"))
    assert w["window"] == {"start_s": START_S, "duration_s": DURATION_S, "start_gps_s": w["window"]["start_gps_s"],
                           "end_gps_s": w["window"]["start_gps_s"] + DURATION_S, "master_margin_s": 30.025}
    assert w["rovers"]["rover"]["epochs"]["n_epochs_used"] == DURATION_S / INTERVAL_S
    assert w["n_fixed"] > 0
    skip = ("run", "run_sha256", "window", "config_sha256")       # (the cut files' config names other files)
    assert _without(w, *skip) == _without(c, *skip)


def test_estimate_reads_inits_window(pair):
    assert run_cli("-q", "init", pair / "run.mcap", "--start", START_S, "--duration", DURATION_S,
                   "-o", pair / "w.json").exit_code == 0
    assert run_cli("-q", "init", pair / "cut.mcap", "-o", pair / "c.json").exit_code == 0
    for run, init, out in (("run.mcap", "w.json", "w.mcap"), ("cut.mcap", "c.json", "c.mcap")):
        r = run_cli("-q", "estimate", pair / run, "--init", pair / init, "-o", pair / out)
        assert r.exit_code == 0, r.output
        assert run_cli("-q", "export", pair / out, "-o", pair / (out + ".csv")).exit_code == 0
    w, c = ((pair / f).read_text() for f in ("w.mcap.csv", "c.mcap.csv"))
    assert w == c and len(w.splitlines()) == 1 + DURATION_S / INTERVAL_S


def test_start_alone_runs_to_the_records_end_and_bad_windows_are_refused(pair):
    r = run_cli("-q", "init", pair / "run.mcap", "--start", 3900, "--json", "-o", pair / "tail.json")
    assert r.exit_code == 0, r.output
    init = json.loads(r.stdout)
    assert init["rovers"]["rover"]["epochs"]["n_epochs_used"] == 50 and init["window"]["start_s"] == 3900
    assert "after the record's last epoch" not in r.output
    # a window asked longer than the record holds: solved, and said (it printed the window as asked, silently)
    r = run_cli("init", pair / "run.mcap", "--start", 3900, "--duration", 120, "-o", pair / "past.json")
    assert r.exit_code == 0, r.output
    assert "the window ends 22 s after the record's last epoch" in r.output and "holds 98 s of data, not the 120 s" \
        in r.output, r.output
    for args, what in ((("--start", 5000), "window start_s 5000: past the record's end (the record: "),
                       (("--start", 0.01, "--duration", 0.5), "holds no observation of rover (its record: "),
                       (("--duration", 0), "duration_s > 0"),
                       (("--start", -1), "start_s ≥ 0"), (("--duration", "nan"), "'--duration'")):
        out = pair / "bad.json"
        r = run_cli("init", pair / "run.mcap", *args, "-o", out)
        assert r.exit_code == 2 and what in r.output and "Traceback" not in r.output, (args, r.output)
        assert not out.exists()
    # an INIT of a window used on the run read whole (the library) is refused, naming both
    from cdgps_cli.core.errors import CdgpsError                 # noqa: PLC0415
    from cdgps_cli.io.gnss_run import read_gnss_run              # noqa: PLC0415
    from cdgps_cli.pipeline.gnss import gnss_estimate            # noqa: PLC0415

    text = (pair / "tail.json").read_text()
    with pytest.raises(CdgpsError, match="INIT.json was made on the window .* which was read on the whole record"):
        gnss_estimate(read_gnss_run(pair / "run.mcap"), json.loads(text), text, pair / "x.mcap")
    assert not (pair / "x.mcap").exists()


def test_the_modal_estimate_of_a_structure_reads_inits_window(tmp_path):
    """`init --structure` on a window and `estimate --structure` with that INIT: the structure's modal states at the
    window's epochs only."""
    tower = REPO_ROOT / "configs" / "gnss-tower.toml"
    sim = tmp_path / "tw"
    assert run_cli("-q", "simulate-gnss-structure", tower, "--duration", "180", "--seed", "5", "--out", sim).exit_code == 0
    run = tmp_path / "run.mcap"
    assert run_cli("-q", "ingest", "--config", sim / "config.toml", "-o", run).exit_code == 0
    r = run_cli("-q", "init", run, "--start", 60, "--duration", 90, "--structure", tower, "-o", tmp_path / "i.json")
    assert r.exit_code == 0, r.output
    r = run_cli("-q", "estimate", run, "--init", tmp_path / "i.json", "--structure", tower, "-o", tmp_path / "s.mcap")
    assert r.exit_code == 0, r.output
    assert run_cli("-q", "export", tmp_path / "s.mcap", "-o", tmp_path / "s.csv").exit_code == 0
    rows = (tmp_path / "s.csv").read_text().splitlines()[1:]
    t0 = json.loads((tmp_path / "i.json").read_text())["window"]["start_gps_s"]
    times = [float(x.split(",")[0]) for x in rows]
    assert len(rows) == 90 and t0 <= times[0] < t0 + 1 and times[-1] < t0 + 90
