"""Foxglove layouts for STATES.mcap: the panels set up, ready to import (``Layouts → Import from file``).

A layout is the JSON Foxglove exports and imports: ``configById`` (each panel's settings under an id
``<PanelType>!<name>``), ``layout`` (the split tree of panel ids: ``first``, ``second``,
``direction`` row / column, ``splitPercentage``), ``globalVariables``, ``userNodes`` and
``playbackConfig``.  :func:`states_layout` builds one from what a STATES.mcap holds:

* a **3-D** panel following the scene frame (``/cdgps/scene``, ``/cdgps/scene_fixed``: the
  structure and its transmitters, :mod:`cdgps_cli.analysis.scene`), when the file has a scene;
* **plots** of the main coordinates — the section angles in degrees (``/cdgps/angles_deg``) when
  there are any, and the coordinates in metres (``/cdgps/state.q.<name>``) — each beside a plot of
  its ±1-σ envelope (``sigma_<name>`` and ``sigma_<name>.@negative``; Foxglove draws no bands);
* **NIS** against its two-sided 95 % chi-square interval (``/cdgps/residuals.nis``,
  ``nis_lower95``, ``nis_upper95``);
* a **raw messages** panel on the events (``/cdgps/events``).

:func:`layout_paths` lists every topic and field path a layout refers to and :func:`missing_paths`
those a given file does not hold (the shipped layouts in ``docs/foxglove/`` are checked against
STATES files written by the tests, so they cannot go stale).
"""

from __future__ import annotations

import json
from pathlib import Path

from cdgps_cli.io.states import (ANGLES_TOPIC, EVENT_TOPIC, RESIDUAL_TOPIC, SCENE_FIXED_TOPIC, SCENE_TOPIC,
                                 STATE_TOPIC)

MAX_PLOTTED = 6
"""At most this many series per plot (the first angles / coordinates in the file's order)."""


def _series(path: str, label: str) -> dict:
    return {"value": path, "enabled": True, "timestampMethod": "receiveTime", "label": label}


def _plot(title: str, series: list[dict]) -> dict:
    return {"foxglovePanelTitle": title, "paths": series, "showXAxisLabels": True, "showYAxisLabels": True,
            "showLegend": True, "legendDisplay": "floating", "showPlotValuesInLegend": True, "isSynced": True,
            "xAxisVal": "timestamp", "sidebarDimension": 240}


def _value_and_sigma(value: str, sigma: str, names: list[str], unit: str, what: str) -> tuple[dict, dict]:
    """A plot of the values ``<value><name>`` and one of their ±1-σ envelopes ``<sigma><name>``."""
    values = _plot(f"{what} ({unit})", [_series(f"{value}{n}", n) for n in names])
    sig = []
    for n in names:
        sig += [_series(f"{sigma}{n}", f"+σ {n}"), _series(f"{sigma}{n}.@negative", f"−σ {n}")]
    return values, _plot(f"±1σ of the {what.lower()} ({unit})", sig)


def _three_d(frame_id: str, size_m: float, topics: list[str]) -> dict:
    return {"foxglovePanelTitle": "Structure (3-D)", "followMode": "follow-pose", "followTf": frame_id,
            "cameraState": {"perspective": True, "distance": round(2.5 * size_m, 3), "phi": 60.0, "thetaOffset": 45.0,
                            "target": [0, 0, 0], "targetOffset": [0, 0, 0], "targetOrientation": [0, 0, 0, 1],
                            "fovy": 45.0, "near": 0.01, "far": round(max(5000.0, 100 * size_m), 1)},
            "scene": {}, "transforms": {}, "topics": {t: {"visible": True} for t in topics},
            "layers": {"grid": {"layerId": "foxglove.Grid", "visible": True, "frameId": frame_id,
                                "size": round(2 * size_m, 3), "divisions": 20}}}


def _split(direction: str, items: list, percent: float | None = None):
    """A split tree of ``items`` (panel ids or trees) in ``direction``, equal shares by default."""
    if len(items) == 1:
        return items[0]
    first_share = percent if percent is not None else 100.0 / len(items)
    return {"direction": direction, "first": items[0], "second": _split(direction, items[1:]),
            "splitPercentage": round(first_share, 3)}


def states_layout(description: dict) -> dict:
    """A Foxglove layout for STATES files like the one ``description`` describes.

    Parameters
    ----------
    description : dict
        From :func:`describe_states`: ``topics`` (the topics with messages), ``angles`` (angle names
        of ``/cdgps/angles_deg`` in order), ``coordinates`` and ``units`` (of ``/cdgps/state.q``),
        ``nis_bounds`` (bool), and for a scene ``frame_id`` and ``size_m``.

    Returns
    -------
    dict
        The layout (``json.dumps`` it to a file).
    """
    topics = set(description["topics"])
    config, column = {}, []
    if ANGLES_TOPIC in topics and description["angles"]:
        a, s = _value_and_sigma(f"{ANGLES_TOPIC}.", f"{ANGLES_TOPIC}.sigma_", description["angles"][:MAX_PLOTTED],
                                "deg", "Angles")
        config["Plot!angles"], config["Plot!angles_sigma"] = a, s
        column.append(_split("row", ["Plot!angles", "Plot!angles_sigma"]))
    metres = [n for n, u in zip(description["coordinates"], description["units"]) if u == "m"][:MAX_PLOTTED]
    if STATE_TOPIC in topics and metres:
        v, s = _value_and_sigma(f"{STATE_TOPIC}.q.", f"{STATE_TOPIC}.sigma_q.", metres, "m", "Coordinates")
        config["Plot!coordinates"], config["Plot!coordinates_sigma"] = v, s
        column.append(_split("row", ["Plot!coordinates", "Plot!coordinates_sigma"]))
    if RESIDUAL_TOPIC in topics:
        nis = [_series(f"{RESIDUAL_TOPIC}.nis", "NIS")]
        if description.get("nis_bounds"):
            nis += [_series(f"{RESIDUAL_TOPIC}.nis_lower95", "2.5 % point"),
                    _series(f"{RESIDUAL_TOPIC}.nis_upper95", "97.5 % point")]
        config["Plot!nis"] = _plot("NIS and its 95 % chi-square interval", nis)
        config["RawMessages!events"] = {"foxglovePanelTitle": "Events (slips, outliers, rest)",
                                        "topicPath": EVENT_TOPIC, "diffEnabled": False, "diffMethod": "custom",
                                        "diffTopicPath": "", "showFullMessageForDiff": False, "expansion": "all"}
        column.append(_split("row", ["Plot!nis", "RawMessages!events"]))
    plots = _split("column", column) if column else None
    if SCENE_TOPIC in topics:
        shown = [t for t in (SCENE_TOPIC, SCENE_FIXED_TOPIC) if t in topics]
        config["3D!structure"] = _three_d(description["frame_id"], description["size_m"], shown)
        root = _split("row", ["3D!structure", plots], 45.0) if plots else "3D!structure"
    else:
        root = plots
    return {"configById": config, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1.0},
            "layout": root}


def describe_states(path: str | Path) -> dict:
    """What :func:`states_layout` needs from a STATES.mcap (its summary, schemas and first messages)."""
    from mcap.reader import make_reader  # noqa: PLC0415

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        channels = {ch.topic: ch for cid, ch in summary.channels.items() if counts.get(cid, 0) > 0}
        schemas = {ch.topic: json.loads(summary.schemas[ch.schema_id].data) for ch in channels.values()}
    d = {"topics": sorted(channels), "angles": [], "coordinates": [], "units": [], "nis_bounds": False}
    if ANGLES_TOPIC in schemas:
        d["angles"] = [k for k in schemas[ANGLES_TOPIC]["properties"]
                       if k not in ("timestamp", "time_s") and not k.startswith("sigma_")]
    if RESIDUAL_TOPIC in schemas:
        d["nis_bounds"] = "nis_upper95" in schemas[RESIDUAL_TOPIC]["properties"]
    from cdgps_cli.io.states import StatesChunks  # noqa: PLC0415

    with StatesChunks(path) as st:
        d["coordinates"], d["units"] = list(st.coord_names), list(st.coord_units)
    if SCENE_TOPIC in channels:
        meta = channels[SCENE_TOPIC].metadata
        d["frame_id"], d["size_m"] = meta["frame_id"], float(meta["size_m"])
    return d


def layout_paths(layout: dict) -> list[str]:
    """Every topic or ``/topic.field.sub`` path the layout's panels refer to (function suffixes such
    as ``.@negative`` taken off), in panel order."""
    out = []
    for cfg in layout["configById"].values():
        for p in cfg.get("paths", []):
            out.append(p["value"].split(".@")[0])
        if "topicPath" in cfg:
            out.append(cfg["topicPath"])
        out += list(cfg.get("topics", {}))
    return out


def missing_paths(layout: dict, path: str | Path) -> list[str]:
    """The paths of ``layout`` (:func:`layout_paths`) that no message of the MCAP file ``path`` holds."""
    from mcap.reader import make_reader  # noqa: PLC0415

    wanted = layout_paths(layout)
    topics = {p.split(".")[0] for p in wanted}
    found: dict[str, set] = {t: set() for t in topics}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        present = {ch.topic for ch in reader.get_summary().channels.values()}      # a topic: its channel
        for _, ch, m in reader.iter_messages(topics=sorted(topics)):               # a field: in a message
            _collect(json.loads(m.data), "", found[ch.topic])
    out = []
    for p in wanted:
        topic, _, field = p.partition(".")
        if topic not in present or (field and field not in found[topic]):
            out.append(p)
    return out


def _collect(obj, prefix: str, into: set) -> None:
    """Field paths (``a.b``) of a decoded message's objects."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            name = f"{prefix}.{k}" if prefix else k
            into.add(name)
            _collect(v, name, into)


def write_layout(states_path: str | Path, out_path: str | Path) -> dict:
    """Write the layout of :func:`states_layout` for ``states_path`` to ``out_path`` (atomically);
    returns ``output``, ``panels`` (ids) and ``paths`` (:func:`layout_paths`, each once)."""
    from cdgps_cli.io.atomic import write_atomic  # noqa: PLC0415

    layout = states_layout(describe_states(states_path))
    text = json.dumps(layout, indent=2, ensure_ascii=False) + "\n"
    write_atomic(Path(out_path), lambda p: Path(p).write_text(text, encoding="utf-8"))
    return {"output": str(out_path), "panels": list(layout["configById"]),
            "paths": list(dict.fromkeys(layout_paths(layout)))}
