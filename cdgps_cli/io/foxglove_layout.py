"""Foxglove layouts for STATES.mcap and RUN.mcap: the panels set up, ready to import (``Layouts → Import from file``).

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

For a RUN.mcap (``cdgps ingest``), :func:`run_layout` sets, for a **structure** run, plots of
carrier-phase channels, each antenna's first (``/cdgps/phase.phase_cycles[k]``, named
``antenna–transmitter`` after the first message's order), their lock counters (``lock[k]``: a step is a slip or lock
restart) and C/N0, the gyro rates in rad/s (``/cdgps/gyro.rate_rad_s[i]``, named), the actuator
forces in N when logged, and a raw-messages panel on ``/cdgps/phase``; for a **GNSS** run, per
receiver, the C/N0 and LLI flags of every tracked satellite
(``/cdgps/gnss/obs{receiver=="base"}.snr_dbhz[:]``) and a raw-messages panel on the observations
(its ``sat`` list: the satellites tracked).

:func:`layout_paths` lists every topic and field path a layout refers to and :func:`missing_paths`
those a given file does not hold (the shipped layouts in ``docs/foxglove/`` are checked against
STATES files written by the tests, so they cannot go stale).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from cdgps_cli.io.gnss_run import GNSS_OBS_TOPIC
from cdgps_cli.io.mcap import ACTUATOR_TOPIC, GYRO_TOPIC, PHASE_TOPIC
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
    """The paths of ``layout`` (:func:`layout_paths`) that no message of the MCAP file ``path`` holds.

    A path is ``/topic``, ``/topic.a.b``, with array indexes (``a[3]``: the message's array has an
    element 3; ``a[:]``: it has elements) and a topic filter (``/topic{receiver=="base"}.a``: only
    messages whose ``receiver`` is ``"base"`` count)."""
    from mcap.reader import make_reader  # noqa: PLC0415

    wanted = [_parse_path(p) for p in dict.fromkeys(layout_paths(layout))]
    topics = sorted({w[1] for w in wanted})
    todo = {i for i, w in enumerate(wanted) if w[3]}                            # paths with a field
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        present = {ch.topic for ch in reader.get_summary().channels.values()}      # a topic: its channel
        for _, ch, m in reader.iter_messages(topics=topics):                       # a field: in a message
            mine = [i for i in todo if wanted[i][1] == ch.topic]
            if not mine:
                continue
            msg = json.loads(m.data)
            todo -= {i for i in mine if _resolves(msg, wanted[i][2], wanted[i][3])}
    return [w[0] for i, w in enumerate(wanted) if w[1] not in present or i in todo]


_FILTER = re.compile(r'^([^{.]+)(?:\{(\w+)=="([^"]*)"\})?(?:\.(.*))?$')
_INDEX = re.compile(r"^(\w+)((?:\[(?:\d+|:)\])*)$")


def _parse_path(p: str) -> tuple:
    """(path, topic, filter (key, value) or None, field tokens)."""
    m = _FILTER.match(p)
    if m is None:
        raise ValueError(f"not a message path cdgps writes: {p}")
    topic, key, value, field = m.groups()
    return p, topic, (key, value) if key else None, field.split(".") if field else []


def _resolves(msg: dict, flt, tokens: list[str]) -> bool:
    """Does the decoded message pass the filter and hold the field ``tokens`` (with indexes)?"""
    if flt is not None and msg.get(flt[0]) != flt[1]:
        return False
    obj = msg
    for tok in tokens:
        m = _INDEX.match(tok)
        if m is None or not isinstance(obj, dict) or m.group(1) not in obj:
            return False
        obj = obj[m.group(1)]
        for idx in re.findall(r"\[(\d+|:)\]", m.group(2)):
            if not isinstance(obj, list) or not obj or (idx != ":" and int(idx) >= len(obj)):
                return False
            obj = obj[0] if idx == ":" else obj[int(idx)]
    return True


def _raw(title: str, topic: str) -> dict:
    return {"foxglovePanelTitle": title, "topicPath": topic, "diffEnabled": False, "diffMethod": "custom",
            "diffTopicPath": "", "showFullMessageForDiff": False, "expansion": "none"}


def _indexed(topic: str, field: str, names: list[str], index: list[int] | None = None) -> list[dict]:
    """Series ``<topic>.<field>[k]`` for ``k`` in ``index`` (default: all), labelled ``names[k]``."""
    return [_series(f"{topic}.{field}[{k}]", names[k]) for k in (range(len(names)) if index is None else index)]


def _one_per_antenna(channels: list[str]) -> list[int]:
    """Indexes of up to :data:`MAX_PLOTTED` phase channels: each antenna's first, then the rest in order."""
    firsts, seen = [], set()
    for k, c in enumerate(channels):
        antenna = c.split("–")[0]
        if antenna not in seen:
            seen.add(antenna)
            firsts.append(k)
    return (firsts + [k for k in range(len(channels)) if k not in firsts])[:MAX_PLOTTED]


def run_layout(description: dict) -> dict:
    """A Foxglove layout for RUN files like the one ``description`` describes.

    Parameters
    ----------
    description : dict
        From :func:`describe_run`: ``kind`` (``"structure"`` or ``"gnss"``), ``topics`` (with
        messages), ``channels`` (``antenna–transmitter`` of the first phase message's elements, in
        order), ``gyros``, ``actuators`` (names in their arrays' order), ``receivers`` (GNSS).

    Returns
    -------
    dict
        The layout (``json.dumps`` it to a file).
    """
    topics, config, column = set(description["topics"]), {}, []
    if description["kind"] == "gnss":
        for rx in description["receivers"]:
            sel = f'{GNSS_OBS_TOPIC}{{receiver=="{rx}"}}'
            config[f"Plot!cn0_{rx}"] = _plot(f"{rx}: C/N0 of every tracked satellite (dB-Hz)",
                                             [_series(f"{sel}.snr_dbhz[:]", f"{rx} C/N0")])
            config[f"Plot!lli_{rx}"] = _plot(f"{rx}: loss-of-lock flags (LLI, 1 = slip possible)",
                                             [_series(f"{sel}.lli[:]", f"{rx} LLI")])
            column.append(_split("row", [f"Plot!cn0_{rx}", f"Plot!lli_{rx}"]))
        raw = ("RawMessages!observations", "Observations (sat: the satellites tracked)", GNSS_OBS_TOPIC)
    else:
        names = description["channels"]
        index = _one_per_antenna(names)
        if PHASE_TOPIC in topics and names:
            for key, field, what in (("phase", "phase_cycles", "Carrier phase (cycles)"),
                                     ("lock", "lock", "Lock counters (a step: slip or lock restart)"),
                                     ("cn0", "snr_dbhz", "C/N0 (dB-Hz)")):
                config[f"Plot!{key}"] = _plot(f"{what}, one channel per antenna", _indexed(PHASE_TOPIC, field, names, index))
            column += [_split("row", ["Plot!phase", "Plot!lock"]), "Plot!cn0"]
        sensors = []
        if GYRO_TOPIC in topics and description["gyros"]:
            config["Plot!gyro"] = _plot("Gyro rates (rad/s)",
                                        _indexed(GYRO_TOPIC, "rate_rad_s", description["gyros"][:MAX_PLOTTED]))
            sensors.append("Plot!gyro")
        if ACTUATOR_TOPIC in topics and description["actuators"]:
            config["Plot!actuators"] = _plot("Actuator forces (N)",
                                             _indexed(ACTUATOR_TOPIC, "force_n", description["actuators"][:MAX_PLOTTED]))
            sensors.append("Plot!actuators")
        raw = ("RawMessages!phase", "Phase messages (channel order: antenna, transmitter)", PHASE_TOPIC)
        column += [_split("row", sensors + [raw[0]])] if sensors else []
    config[raw[0]] = _raw(raw[1], raw[2])
    if raw[0] not in str(column):
        column.append(raw[0])
    return {"configById": config, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1.0},
            "layout": _split("column", column)}


def describe_run(path: str | Path, kind: str) -> dict:
    """What :func:`run_layout` needs from a RUN.mcap of ``kind`` (its summary and first messages)."""
    from mcap.reader import make_reader  # noqa: PLC0415

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        d = {"kind": kind, "topics": sorted(ch.topic for cid, ch in summary.channels.items() if counts.get(cid, 0) > 0),
             "channels": [], "gyros": [], "actuators": [], "receivers": []}
        if kind == "gnss":
            meta = next((r.metadata for r in reader.iter_metadata() if r.name == "cdgps.ingest"), {})
            d["receivers"] = [r for r in meta.get("receivers", "").split(",") if r]
            if not d["receivers"]:                                              # older files: from the messages
                for k, (_, _, m) in enumerate(reader.iter_messages(topics=[GNSS_OBS_TOPIC])):
                    d["receivers"] = list(dict.fromkeys(d["receivers"] + [json.loads(m.data)["receiver"]]))
                    if k >= 64:
                        break
            return d
        first = {}
        for topic in (PHASE_TOPIC, GYRO_TOPIC, ACTUATOR_TOPIC):
            if topic in d["topics"]:
                _, _, m = next(iter(reader.iter_messages(topics=[topic])))
                first[topic] = json.loads(m.data)
    ph = first.get(PHASE_TOPIC, {})
    d["channels"] = [f"{a}–{t}" for a, t in zip(ph.get("antenna", []), ph.get("transmitter", []))]
    d["gyros"] = list(first.get(GYRO_TOPIC, {}).get("gyro", []))
    d["actuators"] = list(first.get(ACTUATOR_TOPIC, {}).get("actuator", []))
    return d


def write_layout(mcap_path: str | Path, out_path: str | Path) -> dict:
    """Write the layout of :func:`run_layout` (a RUN.mcap) or :func:`states_layout` (a STATES.mcap)
    for ``mcap_path`` to ``out_path`` (atomically); returns ``output``, ``panels`` (ids) and
    ``paths`` (:func:`layout_paths`, each once)."""
    from cdgps_cli.io.atomic import write_atomic  # noqa: PLC0415
    from cdgps_cli.io.run import run_kind  # noqa: PLC0415

    kind = run_kind(mcap_path)
    layout = run_layout(describe_run(mcap_path, kind)) if kind else states_layout(describe_states(mcap_path))
    text = json.dumps(layout, indent=2, ensure_ascii=False) + "\n"
    write_atomic(Path(out_path), lambda p: Path(p).write_text(text, encoding="utf-8"))
    return {"output": str(out_path), "panels": list(layout["configById"]),
            "paths": list(dict.fromkeys(layout_paths(layout)))}
