"""The HTML index of a batch campaign (cdgps_cli.report.batch_index): rows, escaping, the trend figure
spaced by session time."""

from __future__ import annotations

from datetime import datetime

from cdgps_cli.report.batch_index import _session_axis, write_index


def _mode(hz, sigma):
    return {"mode": "bending-1", "model_hz": 0.132, "gps_hz": hz, "gps_hz_sigma": sigma, "damping": 0.01,
            "damping_sigma": 0.002, "seen": True}


def _summary(tmp_path, times):
    names = ["s1", "s<2>", "s3"]
    sessions = [{"session": n, "time": t, "status": "done", "folder": str(tmp_path / f"f{i}"), "elapsed_s": 7.0,
                 "integers_fixed": 36, "integers": 36, "nis_per_dof": 0.97, "noise_sigma_m": 0.01,
                 "modes": [_mode(0.132 + 0.001 * i, 0.0005)]} for i, (n, t) in enumerate(zip(names, times))]
    trends = [{"mode": "bending-1", "model_hz": 0.132,
               "sessions": [{"session": s["session"], "time": s["time"], "gps_hz": s["modes"][0]["gps_hz"],
                             "gps_hz_sigma": 0.0005, "damping": 0.01, "damping_sigma": 0.002, "seen": True}
                            for s in sessions],
               "frequency_trend_hz": None, "damping_trend": None}]
    return {"manifest": str(tmp_path / "m.csv"), "outdir": str(tmp_path), "started": "a", "finished": "b",
            "elapsed_s": 21.0, "workers": 2, "counts": {"sessions": 3, "done": 3}, "sessions": sessions,
            "trends": trends, "failures": [{"session": "s3", "error": "bad <data>"}]}


def test_sessions_are_placed_at_their_times_dates_and_zoned_times_mixed(tmp_path):
    s = _summary(tmp_path, ["2026-11-01", "2026-11-02T00:00:00Z", "2026-11-10T12:00:00+00:00"])
    x = _session_axis(s["trends"])
    assert all(isinstance(v, datetime) for v in x.values())
    assert (x["s<2>"] - x["s1"]).total_seconds() == 86400.0
    assert (x["s3"] - x["s<2>"]).total_seconds() == 8.5 * 86400.0
    write_index(s, tmp_path)
    assert (tmp_path / "trends.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (tmp_path / "index.html").read_text()
    assert "s&lt;2&gt;" in page and "s<2>" not in page and "bad &lt;data&gt;" in page
    assert "36 of 36" in page and 'src="trends.png"' in page


def test_sessions_without_times_fall_back_to_manifest_order(tmp_path):
    s = _summary(tmp_path, [None, None, None])
    assert _session_axis(s["trends"]) == {"s1": "s1", "s<2>": "s<2>", "s3": "s3"}
    write_index(s, tmp_path)
    assert (tmp_path / "trends.png").is_file()
