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


def test_gnss_sessions_get_their_positions_and_a_position_trend(tmp_path):
    """GNSS sessions showed no position, "–" for NIS and an empty mode-trend table with no word (a sweep of a real
    pair's windows): each row now holds the rovers' static E/N/U ± 1σ, and a position-trend table and figure
    replace the modes' (the slope of a linear drift recovered, χ²/dof ≈ 0 for points on the line)."""
    from cdgps_cli.pipeline.batch import position_trends

    times = ["2026-11-01T00:00:00Z", "2026-11-02T00:00:00Z", "2026-11-03T00:00:00Z", "2026-11-05T00:00:00Z"]
    sessions = [{"session": f"w{i}", "time": t, "status": "done", "folder": str(tmp_path / f"w{i}"), "elapsed_s": 2.0,
                 "integers_fixed": 56, "integers": 68, "nis_per_dof": 0.16,
                 "rovers": {"rover": {"solution": "fixed",
                                      "static_enu_m": {"rover_e": 0.001 + 0.002 * d, "rover_n": 0.002, "rover_u": 0.003},
                                      "static_sigma_m": {"rover_e": 0.0003, "rover_n": 0.0003, "rover_u": 0.0007}}}}
                for i, (t, d) in enumerate(zip(times, [0, 1, 2, 4]))]
    trends = position_trends(sessions)
    by = {t["coordinate"]: t for t in trends}
    assert set(by) == {"rover_e", "rover_n", "rover_u"} and len(by["rover_e"]["sessions"]) == 4
    fit = by["rover_e"]["trend_m"]
    assert abs(fit["slope_per_day"] - 0.002) < 1e-12 and fit["chi2_per_dof"] < 1e-12     # 2 mm/day on the line
    assert by["rover_n"]["trend_m"] is None or abs(by["rover_n"]["trend_m"]["slope_per_day"]) < 1e-12
    summary = {"manifest": str(tmp_path / "m.toml"), "outdir": str(tmp_path), "started": "a", "finished": "b",
               "elapsed_s": 8.0, "workers": 2, "counts": {"sessions": 4, "done": 4}, "sessions": sessions,
               "trends": [], "position_trends": trends, "failures": []}
    write_index(summary, tmp_path)
    page = (tmp_path / "index.html").read_text()
    assert "rover: E +1.00±0.30 N +2.00±0.30 U +3.00±0.70" in page and "0.160" in page
    assert "No session identified modes" in page and "<h2>Position trends</h2>" in page
    assert "<td>+2.00 ± 0.10</td>" in page                # σ 0.3 mm / √Σ(t − t̄)² = 0.101 mm/day
    assert (tmp_path / "positions.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not (tmp_path / "trends.png").exists()


def test_position_trends_take_every_session_to_one_origin():
    """Sessions of runs with other nominal positions (a rover placed at each run's own first epochs; RINEX headers
    that differ): their E/N/U are about different points, and a review's three runs of one antenna gave slopes of
    metres a day.  Each session is taken to the first session's nominal: one static point gives one value, and a
    point 5 mm east of it 5 mm more east, whatever the runs' nominals."""
    import numpy as np

    from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix
    from cdgps_cli.pipeline.batch import position_trends

    truth = np.array([-3976219.5, 3382372.6, 3652513.0])
    R = enu_matrix(*ecef_to_geodetic(truth)[:2])
    nominals = [truth + np.array([3.0, -2.0, 4.0]), truth + np.array([-6.0, 1.0, 2.5]), truth + np.array([0.5, 5.0, -1.0])]
    east_mm = [0.0, 0.0, 5.0]
    sessions = []
    for i, (nom, e_mm) in enumerate(zip(nominals, east_mm)):
        x = truth + R[0] * e_mm * 1e-3
        enu = enu_matrix(*ecef_to_geodetic(nom)[:2]) @ (x - nom)
        sessions.append({"session": f"s{i}", "time": f"2026-11-0{i + 1}T00:00:00Z", "rovers": {"rover": {
            "static_enu_m": dict(zip(("rover_e", "rover_n", "rover_u"), enu.tolist())),
            "static_sigma_m": {"rover_e": 0.001, "rover_n": 0.001, "rover_u": 0.002}, "nominal_ecef_m": nom.tolist()}}})
    by = {t["coordinate"]: t for t in position_trends(sessions)}
    e = [p["value_m"] for p in by["rover_e"]["sessions"]]
    n = [p["value_m"] for p in by["rover_n"]["sessions"]]
    assert abs(e[1] - e[0]) < 1e-9 and abs(e[2] - e[0] - 0.005) < 1e-9 and max(n) - min(n) < 1e-9
    assert by["rover_e"]["origin_ecef_m"] == nominals[0].tolist()
