"""Provenance of a report: the files it read (with sha256), every option, the software, a date.

A report must say where its numbers came from, and a rerun on the same inputs must give the
same bytes.  The date therefore never comes from the wall clock; in order of precedence it is

1. ``--date`` (an ISO date ``2026-12-01`` or date-time ``2026-12-01T21:40:00Z``), or
2. the ``SOURCE_DATE_EPOCH`` environment variable (integer Unix seconds; the reproducible-builds
   convention), or
3. the modification time of the newest input file, in UTC to the second — for a report made
   right after ``cdgps estimate`` that is when its STATES.mcap was written.  A copy of the inputs
   that does not keep their times (``cp`` without ``-p``) changes only this line.

The upstream chain is read from the inputs themselves: STATES.mcap records the RUN and INIT it was
estimated from (sha256), the config and the estimate options; RUN.mcap records its source logs.
"""

from __future__ import annotations

import json
import os
import platform
from datetime import datetime, timezone
from importlib import metadata as _im
from pathlib import Path

from cdgps_cli import __version__
from cdgps_cli.io.atomic import file_sha256
from cdgps_cli.core.errors import CdgpsError

DATE_ENV = "SOURCE_DATE_EPOCH"
_SOFTWARE = ("numpy", "scipy", "pandas", "matplotlib", "mcap")


def _utc(ts: float) -> str:
    return datetime.fromtimestamp(int(ts), tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


def report_date(inputs: list[str | Path], date: str | None = None) -> dict:
    """The report's date and where it came from (see the module docstring).

    Returns
    -------
    dict ``{"date": str, "source": str}``

    Raises
    ------
    CdgpsError
        On a ``--date`` that is not ISO 8601 or a ``SOURCE_DATE_EPOCH`` that is not an integer.
    """
    if date is not None:
        try:
            d = datetime.fromisoformat(date.strip())
        except ValueError:
            raise CdgpsError(f"--date: expected an ISO date (2026-12-01) or date-time "
                             f"(2026-12-01T21:40:00Z), got {date!r}") from None
        if len(date.strip()) <= 10:
            return {"date": d.strftime("%Y-%m-%d"), "source": "--date"}
        if d.tzinfo is None:
            d = d.replace(tzinfo=timezone.utc)
        return {"date": d.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"), "source": "--date"}
    env = os.environ.get(DATE_ENV)
    if env is not None and env.strip():
        try:
            return {"date": _utc(int(env.strip())), "source": DATE_ENV}
        except (ValueError, OverflowError, OSError):
            raise CdgpsError(f"{DATE_ENV}: expected integer Unix seconds, got {env!r}") from None
    newest = max(Path(p).stat().st_mtime for p in inputs)
    return {"date": _utc(newest), "source": "modification time of the newest input"}


def software() -> dict:
    """cdgps, Python and the libraries that shape the numbers and figures, with their versions."""
    out = {"cdgps": __version__, "python": platform.python_version()}
    for name in _SOFTWARE:
        try:
            out[name] = _im.version(name)
        except _im.PackageNotFoundError:
            out[name] = None
    return out


def _file(role: str, path: str | Path) -> dict:
    p = Path(path)
    return {"role": role, "path": str(path), "bytes": p.stat().st_size, "sha256": file_sha256(p)}


def report_provenance(command: str, options: dict, states, run=None, date: str | None = None) -> dict:
    """Provenance block of a report on ``states`` (a :class:`~cdgps_cli.io.states.States`) and,
    optionally, the gyro ``run`` (a :class:`~cdgps_cli.io.run.Run`).

    Parameters
    ----------
    command : str, e.g. ``"cdgps report static"``
    options : dict, every option of the command by its command-line name (None = default / detected)
    states, run : the inputs as read; their files are hashed here (sha256 of the bytes on disk)
    date : str or None, the ``--date`` option

    Returns
    -------
    dict with ``command``, ``options``, ``inputs`` (role, path, bytes, sha256), ``estimated_from``
    (STATES' record of its RUN, INIT, config and estimate options), ``gyro_run_ingested_from``,
    ``gyro_run_is_estimate_run``, ``software`` and ``date``.
    """
    inputs = [_file("STATES.mcap", states.path)]
    if run is not None:
        inputs.append(_file("RUN.mcap (--gyro)", run.path))
    meta = dict(getattr(states, "metadata", {}) or {})
    try:
        est_opts = json.loads(meta["options"]) if "options" in meta else None
    except ValueError:
        est_opts = meta.get("options")
    est = {"run": meta.get("run"), "run_sha256": meta.get("run_sha256"), "init_sha256": meta.get("init_sha256"),
           "config": states.cfg.name if states.cfg is not None else states.config_name,
           "config_sha256": states.cfg.sha256 if states.cfg is not None else states.config_sha256,
           "cdgps_version": meta.get("cdgps_version"), "smoothed": meta.get("smoothed"), "options": est_opts}
    out = {"command": command, "options": options, "inputs": inputs, "estimated_from": est,
           "gyro_run_ingested_from": None, "gyro_run_is_estimate_run": None,
           "software": software(), **{k: v for k, v in report_date([i["path"] for i in inputs], date).items()}}
    out["date_source"] = out.pop("source")
    if run is not None:
        rm = dict(getattr(run, "metadata", {}) or {})
        out["gyro_run_ingested_from"] = {k[:-len("_sha256")]: {"file": rm.get(k[:-len("_sha256")]), "sha256": v}
                                         for k, v in sorted(rm.items()) if k.endswith("_sha256") and k != "config_sha256"}
        if est["run_sha256"]:
            out["gyro_run_is_estimate_run"] = inputs[1]["sha256"] == est["run_sha256"]
    return out


def value_text(v) -> str:
    """A recorded option's value as the reports say it: a table as ``key value`` pairs (a value of None inside:
    "per satellite" — the only such values are GLONASS signals' wavelengths, one per satellite), lists joined by
    commas, numbers to 6 significant digits."""
    if isinstance(v, dict):
        return ", ".join(f"{k} {'per satellite' if x is None else value_text(x)}" for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return ",".join(value_text(x) for x in v)
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _opt_text(v) -> str:
    if v is None:
        return "default"
    if isinstance(v, dict):
        return value_text(v)
    if isinstance(v, (list, tuple)):
        if not v:
            return "none"
        if any(isinstance(x, (list, tuple, dict)) for x in v):
            return json.dumps(v)
        return ",".join(map(str, v))
    return str(v)


def command_line(p: dict) -> str:
    """The command as it could be typed again: the STATES input and every command-line option
    that was set (``-o`` is left out: where a report is written does not change it)."""
    import shlex

    parts = [p["command"], shlex.quote(p["inputs"][0]["path"])]
    for k, v in p["options"].items():
        if not k.startswith("-") or v is None or v is False:
            continue
        parts += [k] if v is True else [k, shlex.quote(_opt_text(v))]      # a flag: its name alone
    return " ".join(parts)


def provenance_rows(p: dict) -> list[list[str]]:
    """``[[what, value], …]`` of a provenance block, for the markdown and HTML tables."""
    rows = [["date", f"{p['date']} ({p['date_source']})"]]
    sw = p["software"]
    rows.append(["software", f"cdgps {sw['cdgps']}; Python {sw['python']}; "
                 + ", ".join(f"{k} {v}" for k, v in sw.items() if k not in ("cdgps", "python") and v)])
    rows.append(["command", command_line(p)])
    rows.append(["options", "; ".join(f"{k} = {_opt_text(v)}" for k, v in p["options"].items())])
    if p.get("settings"):                       # fixed settings, no command-line option (the command row omits them)
        rows.append(["settings", "; ".join(f"{k} = {_opt_text(v)}" for k, v in p["settings"].items())])
    for f in p["inputs"]:
        rows.append([f"input {f['role']}", f"{f['path']} ({f['bytes']} bytes), sha256 {f['sha256']}"])
    e = p.get("estimated_from")                 # reports on STATES only
    if e is not None:
        rows.append(["STATES estimated from",
                     f"RUN {e['run']} sha256 {e['run_sha256']}; INIT sha256 {e['init_sha256']}; config {e['config']} "
                     f"sha256 {e['config_sha256']}; cdgps {e['cdgps_version']}"])
        if isinstance(e["options"], dict):
            rows.append(["estimate options", "; ".join(f"{k} = {_opt_text(v)}" for k, v in sorted(e["options"].items())
                                                       if v is not None)])     # (not set, or not of this model)
    if p.get("gyro_run_ingested_from"):
        rows.append(["gyro RUN ingested from", "; ".join(f"{v['file']} sha256 {v['sha256']}"
                                                        for v in p["gyro_run_ingested_from"].values())])
    if p.get("gyro_run_is_estimate_run") is not None:
        rows.append(["gyro RUN = the estimate's RUN", "yes (sha256 equal)" if p["gyro_run_is_estimate_run"]
                     else "NO: the gyro log is from another RUN.mcap than the one the states were estimated from"])
    return rows
