"""`cdgps batch`: the campaign manifest, the stage graph, resume records and the campaign summary.

Nothing here schedules work: :mod:`cdgps_cli.pipeline.batch_dask` submits one dask.distributed task
per session-stage, each calling :func:`execute_stage`.

Manifest (docs/batch.md)
------------------------
A CSV file (one row per session, a header row naming the columns) or a TOML file (a ``[defaults]``
table and one ``[[session]]`` table per session).  Columns / keys:

``session``        the session's name, also its folder ``OUTDIR/<session>/`` (letters, digits, ``._-``)
``receiver_csv``   receiver phase log (CSV); or ``run_mcap``, an already ingested RUN.mcap (no ingest)
``gyro_csv``, ``actuator_csv``   optional logs given to ``cdgps ingest``
``config``         structure config TOML (with ``receiver_csv``)
``time``           when the session was recorded (ISO 8601), the x axis of the trends
``stages``         which of ingest init estimate spectra report (default: all that apply); in CSV
                   separated by spaces or ``+``
and the options of :data:`OPTIONS` (their command-line flag in brackets there).  Relative paths are
relative to the manifest's folder.  Every problem is listed at once, each with file, line and column.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from cdgps_cli import __version__
from cdgps_cli.core import heap
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.config.limits import OPTION_BOUNDS

#: the stages in the order they run; each needs the outputs of those it depends on
STAGES = ("ingest", "init", "estimate", "spectra", "report")
DEPENDS = {"ingest": (), "init": ("ingest",), "estimate": ("init",), "spectra": ("estimate",),
           "report": ("estimate",)}
#: what each stage writes into the session folder (a file or a folder of files)
OUTPUT = {"ingest": "run.mcap", "init": "init.json", "estimate": "states.mcap", "spectra": "spectra",
          "report": "report"}
INPUT_COLUMNS = ("receiver_csv", "gyro_csv", "actuator_csv", "config", "gnss_config", "run_mcap")
#: what a GNSS session (RINEX/UBX receivers) runs: no structure spectra on rover displacements
GNSS_STAGES = ("ingest", "init", "estimate")
#: the options a GNSS session takes (its other settings are its GNSS config's); init_start_s / init_duration_s: the
#: window of the record its init and estimate read (`cdgps init --start --duration`: a long record hour by hour)
GNSS_OPTIONS = ("float_only", "smooth", "init_start_s", "init_duration_s")
RECORD_DIR = ".batch"                 # OUTDIR/<session>/.batch/<stage>.json: the resume records
CAMPAIGN_FILE = ".cdgps-batch.json"   # OUTDIR/.cdgps-batch.json: which manifest owns OUTDIR
LOCK_FILE = ".cdgps-batch.lock"       # OUTDIR/.cdgps-batch.lock: the batch writing OUTDIR now (batch_lock)
ERROR_LOG = "batch-error.log"         # OUTDIR/batch-error.log: the traceback when the batch itself failed
#: files of the campaign itself in OUTDIR: no session may be called so
RESERVED = ("batch.json", "index.html", "trends.png", ERROR_LOG)
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


@dataclass(frozen=True)
class Option:
    """A per-session option: the stage it belongs to, its type, the command-line default and flag."""

    stage: str
    kind: str                 # "float", "bool", "str", "choice:a|b"
    default: object
    flag: str
    bound: str | None = None  # the command's parameter in config.limits.OPTION_BOUNDS: the same range as the flag


#: per-session options and the stage command flag each one is (defaults: the commands' defaults)
OPTIONS = {
    "init_start_s": Option("init", "float", None, "--start", "start_s"),
    "init_duration_s": Option("init", "float", None, "--duration", "duration_s"),
    "float_only": Option("init", "bool", False, "--float-only"),
    "ratio": Option("init", "float", 3.0, "--ratio", "ratio_threshold"),
    "init_sigma_m": Option("init", "float", None, "--sigma-m", "sigma_m"),
    "smooth": Option("estimate", "bool", False, "--smooth"),
    "biases": Option("estimate", "choice:fixed|states", "fixed", "--biases"),
    "process_noise_scale": Option("estimate", "float", 1.0, "--process-noise-scale", "process_noise_scale"),
    "coords": Option("spectra", "str", None, "--coords"),
    "segment_s": Option("spectra", "float", None, "--segment-s", "segment_s"),
    "date": Option("report", "str", None, "--date"),
}
#: spectra options are the report's too (`cdgps report spectrum` computes the same spectra)
SPECTRA_OPTIONS = ("coords", "segment_s")
COLUMNS = ("session", *INPUT_COLUMNS, "time", "stages", *OPTIONS)


@dataclass
class Session:
    """One session of the manifest, every path absolute.

    Attributes
    ----------
    name : str, the folder name under OUTDIR
    where : str, ``MANIFEST:LINE`` of its row / table (for messages)
    inputs : dict, {column: absolute path} of the inputs given
    time : str or None, ISO 8601 recording time (UTC)
    stages : tuple of str, the stages to run, in :data:`STAGES` order
    options : dict, {option name: value} for every option of :data:`OPTIONS`
    folder : str, ``OUTDIR/<name>`` (absolute), set by :func:`prepare_outdir`
    """

    name: str
    where: str
    inputs: dict
    time: str | None
    stages: tuple
    options: dict
    folder: str = ""
    kind: str = "structure"          # or "gnss": RINEX/UBX receivers (gnss_config, or a GNSS RUN.mcap)

    def path(self, stage: str) -> str:
        """Where ``stage``'s output is (RUN.mcap of the manifest when ingest is not run)."""
        if stage == "ingest" and "run_mcap" in self.inputs:
            return self.inputs["run_mcap"]
        return os.path.join(self.folder, OUTPUT[stage])

    def stage_options(self, stage: str) -> dict:
        names = [k for k, o in OPTIONS.items() if o.stage == stage]
        if stage == "report":
            names = [*SPECTRA_OPTIONS, *names]
        return {k: self.options[k] for k in names}

    def as_dict(self) -> dict:
        return {"session": self.name, "where": self.where, "inputs": self.inputs, "time": self.time,
                "stages": list(self.stages), "options": self.options, "folder": self.folder}


@dataclass
class _Problems:
    """Every problem of a manifest, each with its place."""

    path: str
    items: list = field(default_factory=list)

    def add(self, line: int | None, column: int | None, what: str, message: str) -> None:
        where = self.path + (f":{line}" if line else "") + (f":{column}" if line and column else "")
        self.items.append(f"{where}: {what}: {message}" if what else f"{where}: {message}")

    def raise_if_any(self) -> None:
        if self.items:
            n = len(self.items)
            raise CdgpsError(f"{self.path}: {n} problem{'s' if n > 1 else ''} in the batch manifest "
                             f"(nothing was run):\n  " + "\n  ".join(self.items))


# --------------------------------------------------------------------------- manifest reading

def read_manifest(path: str | Path) -> list[Session]:
    """Read and validate a batch manifest (CSV or TOML, by its suffix).

    Returns
    -------
    list of :class:`Session`, in manifest order

    Raises
    ------
    CdgpsError
        Listing every problem found, each as ``MANIFEST:LINE:COLUMN: key: message``.
    """
    p = Path(path)
    probs = _Problems(str(path))
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise CdgpsError(f"{path}: batch manifest not found") from None
    except IsADirectoryError:
        raise CdgpsError(f"{path}: is a folder; the batch manifest is a .csv or .toml file") from None
    except OSError as exc:
        raise CdgpsError(f"{path}: cannot read the batch manifest: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise CdgpsError(f"{path}: the batch manifest is not UTF-8 text (byte {exc.start})") from None
    if p.suffix.lower() == ".toml":
        rows = _toml_rows(text, probs)
    elif p.suffix.lower() == ".csv":
        rows = _csv_rows(text, probs)
    else:
        raise CdgpsError(f"{path}: a batch manifest is a .csv or a .toml file (got {p.suffix or 'no suffix'!r})")
    base = p.resolve().parent
    sessions, seen = [], {}
    for line, values, cols in rows:
        s = _session(line, values, cols, base, probs)
        if s is None:
            continue
        if s.name in seen:
            probs.add(line, cols.get("session"), "session",
                      f"{s.name!r} is given twice (first on line {seen[s.name]}); each session needs its own folder")
        seen.setdefault(s.name, line)
        sessions.append(s)
    if not rows and not probs.items:
        probs.add(None, None, "", "no session in the manifest")
    _check_configs(sessions, probs)
    probs.raise_if_any()
    return sessions


def _csv_rows(text: str, probs: _Problems) -> list:
    """[(line, {column: text}, {column: column number})] of a CSV manifest."""
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader)
    except StopIteration:
        probs.add(None, None, "", "empty manifest (expected a header row: session,receiver_csv,config,…)")
        return []
    except csv.Error as exc:
        probs.add(1, None, "", f"unreadable CSV: {exc}")
        return []
    names = [h.strip() for h in header]
    cols = {}
    for i, n in enumerate(names, 1):
        if n not in COLUMNS:
            probs.add(1, i, n or "(empty)", f"unknown column; expected some of {', '.join(COLUMNS)}")
        elif n in cols:
            probs.add(1, i, n, f"column given twice (also column {cols[n]})")
        else:
            cols[n] = i
    if "session" not in cols:
        probs.add(1, None, "session", "the header has no 'session' column")
    rows = []
    try:
        for fields in reader:
            line = reader.line_num
            if not any(f.strip() for f in fields) or fields[0].lstrip().startswith("#"):
                continue
            if len(fields) != len(names):
                probs.add(line, None, "", f"{len(fields)} fields where the header has {len(names)}")
                continue
            values = {n: fields[i - 1].strip() for n, i in cols.items() if fields[i - 1].strip() != ""}
            rows.append((line, values, cols))
    except csv.Error as exc:
        probs.add(reader.line_num, None, "", f"unreadable CSV: {exc}")
    return rows


def _toml_rows(text: str, probs: _Problems) -> list:
    """Rows of a TOML manifest: ``[defaults]`` merged into each ``[[session]]``; the line and
    column of a key are found by scanning the text (tomllib does not keep them)."""
    import tomllib

    from cdgps_cli.core import toml_text

    try:
        doc = toml_text.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column (\d+)\)", str(exc))
        probs.add(int(m.group(1)) if m else None, int(m.group(2)) if m else None, "", f"not valid TOML: {exc}")
        return []
    lines = text.splitlines()
    heads = [i + 1 for i, ln in enumerate(lines) if re.match(r"^\s*\[\[\s*session\s*\]\]", ln)]
    dline = next((i + 1 for i, ln in enumerate(lines) if re.match(r"^\s*\[\s*defaults\s*\]", ln)), None)
    for k in doc:
        if k not in ("defaults", "session"):
            probs.add(_key_line(lines, k, 1, len(lines))[0], None, k, "unknown table or key; expected "
                      "[defaults] and [[session]] tables")
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        probs.add(dline, None, "defaults", "must be a table")
        defaults = {}
    sessions = doc.get("session", [])
    if not isinstance(sessions, list) or not all(isinstance(s, dict) for s in sessions):
        probs.add(None, None, "session", "must be an array of tables ([[session]])")
        return []
    rows = []
    dcols = {}
    if dline:
        end = min([h for h in heads if h > dline] or [len(lines) + 1])
        for k in defaults:
            if k == "session":
                probs.add(dline, None, "session", "a session's name cannot have a default")
            dcols[k] = _key_line(lines, k, dline, end)
    for i, s in enumerate(sessions):
        start = heads[i] if i < len(heads) else None
        end = heads[i + 1] if i + 1 < len(heads) else len(lines) + 1
        values, where = {}, {}
        for k, v in {**defaults, **s}.items():
            values[k] = v
            where[k] = _key_line(lines, k, start, end) if k in s and start else dcols.get(k, (start, None))
        rows.append((start, values, where))
    return [(line, v, {k: w for k, w in cols.items()}) for line, v, cols in rows]


def _key_line(lines: list, key: str, start: int | None, end: int) -> tuple:
    """(line, column) of ``key =`` between lines start and end (1-based), else (start, None)."""
    pat = re.compile(rf"^(\s*)({re.escape(key)}|\"{re.escape(key)}\")\s*=")
    for n in range(start or 1, min(end, len(lines) + 1)):
        m = pat.match(lines[n - 1])
        if m:
            return (n, len(m.group(1)) + 1)
    return (start, None)


def _session(line: int, values: dict, cols: dict, base: Path, probs: _Problems) -> Session | None:
    """Validate one row; problems are added to ``probs`` (None when the row is unusable)."""
    def at(k):           # CSV: cols[k] is a column number; TOML: a (line, column) pair
        c = cols.get(k)
        return c if isinstance(c, tuple) else (line, c)

    def bad(k, msg):
        ln, col = at(k)
        probs.add(ln, col, k, msg)

    for k in values:
        if k not in COLUMNS:
            bad(k, f"unknown key; expected some of {', '.join(COLUMNS)}")
    name = values.get("session")
    if name is None or (isinstance(name, str) and not name.strip()):
        bad("session", "missing: every session needs a name (its folder under OUTDIR)")
        name = None
    elif not isinstance(name, str) or not _NAME.match(name):
        bad("session", f"{name!r} is not a usable folder name (letters, digits, '.', '_', '-'; at most 128)")
        name = None
    elif name in RESERVED:
        bad("session", f"{name!r} is the name of a file the batch writes into OUTDIR; choose another name")
        name = None
    inputs = {}
    for k in INPUT_COLUMNS:
        v = values.get(k)
        if v is None:
            continue
        if not isinstance(v, str):
            bad(k, f"expected a file path, got {v!r}")
            continue
        p = (base / v).resolve() if not os.path.isabs(v) else Path(v)
        if not p.is_file():
            bad(k, f"{v}: {'is a folder' if p.is_dir() else 'no such file'} (relative paths are relative to "
                   f"the manifest's folder, {base})")
            continue
        inputs[k] = str(p)
    has_rx, has_run, has_gnss = "receiver_csv" in values, "run_mcap" in values, "gnss_config" in values
    given = [k for k, h in (("receiver_csv", has_rx), ("gnss_config", has_gnss), ("run_mcap", has_run)) if h]
    if len(given) > 1:
        bad(given[1], f"give one of receiver_csv (CSV logs), gnss_config (RINEX/UBX receivers listed in a GNSS "
                      f"config) or run_mcap (already ingested), not {' and '.join(given)}")
    elif not given:
        bad("receiver_csv", "missing: give the receiver log (receiver_csv), a GNSS config (gnss_config) or a "
                            "RUN.mcap (run_mcap)")
    if given == ["receiver_csv"] and "config" not in values:
        bad("config", "missing: ingesting receiver_csv needs the structure config TOML")
    for k in ("gyro_csv", "actuator_csv", "config"):
        if k in values and not has_rx and given:
            bad(k, f"only with receiver_csv (structure logs), not with {given[0]}")
    kind = "gnss" if has_gnss or (has_run and "run_mcap" in inputs and _is_gnss_run(inputs["run_mcap"])) else "structure"
    stages = _stages(values.get("stages"), has_run, bad, kind)
    options = {}
    for k, o in OPTIONS.items():
        options[k] = _option(k, o, values.get(k), bad)
        if kind == "gnss" and k not in GNSS_OPTIONS and values.get(k) is not None:
            bad(k, f"not for a GNSS session (RINEX/UBX): {', '.join(GNSS_OPTIONS)} are; its other settings "
                   f"are those of its GNSS config")
    time = _time(values.get("time"), bad)
    if name is None or stages is None:
        return None
    return Session(name=name, where=f"{probs.path}:{line}", inputs=inputs, time=time, stages=stages, options=options,
                   kind=kind)


def _is_gnss_run(path: str) -> bool:
    from cdgps_cli.io.run import run_kind

    try:
        return run_kind(path) == "gnss"
    except CdgpsError:            # not a readable MCAP: the init stage says so, naming the file
        return False


def _stages(v, has_run: bool, bad, kind: str = "structure") -> tuple | None:
    allowed = GNSS_STAGES if kind == "gnss" else STAGES
    every = tuple(s for s in allowed if not (has_run and s == "ingest"))
    if v is None:
        return every
    if isinstance(v, str):
        items = [t for t in re.split(r"[\s+]+", v.strip()) if t]
    elif isinstance(v, list) and all(isinstance(t, str) for t in v):
        items = v
    else:
        bad("stages", f"expected stage names ({' '.join(STAGES)}), got {v!r}")
        return None
    unknown = [t for t in items if t not in STAGES]
    if unknown:
        bad("stages", f"unknown stage{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}; "
                      f"expected some of {' '.join(STAGES)}")
        return None
    if has_run and "ingest" in items:
        bad("stages", "ingest with run_mcap: the RUN.mcap is already ingested")
        return None
    if kind == "gnss" and set(items) - set(GNSS_STAGES):
        bad("stages", f"a GNSS session (RINEX/UBX) runs {' '.join(GNSS_STAGES)}; "
                      f"{' '.join(sorted(set(items) - set(GNSS_STAGES)))} are for structure sessions")
        return None
    chosen = set(items)
    for s in items:
        for d in DEPENDS[s]:
            if d not in chosen and not (d == "ingest" and has_run):
                bad("stages", f"{s} needs {d} (its input); add {d} to the stages")
                return None
    if not items:
        bad("stages", "empty: name at least one stage")
        return None
    return tuple(s for s in STAGES if s in chosen)


def _option(k: str, o: Option, v, bad):
    if v is None:
        return o.default
    if o.kind == "bool":
        if isinstance(v, bool):
            return v
        t = str(v).strip().lower()
        if t in ("true", "yes", "1"):
            return True
        if t in ("false", "no", "0"):
            return False
        bad(k, f"expected true or false, got {v!r}")
        return o.default
    if o.kind == "float":
        try:
            x = float(v) if not isinstance(v, bool) else None
        except (TypeError, ValueError):
            x = None
        if x is None or not math.isfinite(x):
            bad(k, f"expected a finite number ({o.flag}), got {v!r}")
            return o.default
        if k != "init_start_s" and x <= 0:
            bad(k, f"must be > 0 ({o.flag}), got {v!r}")
            return o.default
        if o.bound is not None and not OPTION_BOUNDS[o.bound].contains(x):      # what the command refuses
            bad(k, f"outside the plausible range {OPTION_BOUNDS[o.bound].text()} ({o.flag}), got {v!r}")
            return o.default
        return x
    if not isinstance(v, str):
        bad(k, f"expected text ({o.flag}), got {v!r}")
        return o.default
    if o.kind.startswith("choice:"):
        choices = o.kind[7:].split("|")
        if v not in choices:
            bad(k, f"expected one of {', '.join(choices)}, got {v!r}")
            return o.default
    if k == "date":
        from cdgps_cli.io.provenance import report_date

        try:
            report_date([], v)
        except CdgpsError as exc:
            bad(k, str(exc).replace("--date: ", ""))
            return o.default
    return v


def _time(v, bad) -> str | None:
    if v is None:
        return None
    if isinstance(v, datetime):
        d = v
    else:
        try:
            d = datetime.fromisoformat(str(v).strip())
        except ValueError:
            bad("time", f"expected an ISO 8601 date or date-time (2026-12-01T06:00:00Z), got {v!r}")
            return None
    if d.tzinfo is None:
        d = d.replace(tzinfo=timezone.utc)
    return d.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _check_configs(sessions: list, probs: _Problems) -> None:
    """Each distinct config is loaded once, up front: a broken config is a manifest problem."""
    from cdgps_cli.config.structure import load_config, load_gnss_config

    seen = {}
    for s in sessions:
        for key, load in (("config", load_config), ("gnss_config", load_gnss_config)):
            c = s.inputs.get(key)
            if c is None:
                continue
            if (key, c) not in seen:
                try:
                    load(c)
                    seen[key, c] = None
                except CdgpsError as exc:
                    seen[key, c] = str(exc)
            if seen[key, c] is not None:
                probs.add(int(s.where.rsplit(":", 1)[1]) or None, None, key, seen[key, c])


# --------------------------------------------------------------------------- the campaign folder

def manifest_identity(manifest: str | Path) -> dict:
    """What owns an OUTDIR: the manifest's absolute path (its content may change: that is a resume)."""
    return {"manifest": str(Path(manifest).resolve())}


def prepare_outdir(sessions: list, manifest: str | Path, outdir: str | Path, claim: bool = True) -> Path:
    """Claim OUTDIR for this manifest and set each session's folder (``claim=False``: only check).

    Refuses a folder that holds another manifest's campaign, or other files (a batch never mixes
    its outputs with foreign ones).

    Raises
    ------
    CdgpsError
    """
    out = Path(outdir).resolve()
    ident = manifest_identity(manifest)
    rec = out / CAMPAIGN_FILE
    if out.exists() and not out.is_dir():
        raise CdgpsError(f"{outdir}: exists and is not a folder")
    if rec.is_file():
        try:
            old = json.loads(rec.read_text())
        except (OSError, ValueError):
            old = {}
        if old.get("manifest") != ident["manifest"]:
            raise CdgpsError(f"{outdir}: holds the outputs of another batch manifest ({old.get('manifest')}); "
                             f"refusing to mix them with {ident['manifest']}'s (choose another -o OUTDIR)")
    elif out.is_dir() and any(not f.name.startswith(LOCK_FILE) for f in out.iterdir()):
        raise CdgpsError(f"{outdir}: not empty and not a batch output folder (no {CAMPAIGN_FILE}); refusing to "
                         f"write a campaign into it (choose a new or empty -o OUTDIR)")
    from cdgps_cli.io.atomic import write_bytes_atomic

    if claim:
        write_bytes_atomic(rec, (json.dumps(ident, indent=2) + "\n").encode())
    for s in sessions:
        s.folder = str(out / s.name)
    return out


# --------------------------------------------------------------------------- resume records

def _sha256(path: str) -> str:
    from cdgps_cli.io.atomic import file_sha256

    return file_sha256(path)


def stage_inputs(s: Session, stage: str) -> dict:
    """{role: absolute path} of the files ``stage`` reads."""
    if stage == "ingest" and s.kind == "gnss":
        from cdgps_cli.config.structure import load_gnss_config

        cfg = load_gnss_config(s.inputs["gnss_config"])          # the receiver and navigation files it lists
        files = {f"{a.name}": a.rinex or a.ubx for a in cfg.antennas if a.rinex or a.ubx}
        files.update({f"nav{i}": str(n) for i, n in enumerate(cfg.nav)})
        if cfg.antex:                                            # the antenna calibrations the RUN keeps
            files["antex"] = cfg.antex
        from cdgps_cli.pipeline.gnss_ingest import config_sensor_paths  # noqa: PLC0415

        files.update({f"sensor{i}": p for i, p in enumerate(config_sensor_paths(cfg))})    # the sensor logs it attaches
        return {"gnss_config": s.inputs["gnss_config"], **files}
    if stage == "ingest":
        return {k: s.inputs[k] for k in ("receiver_csv", "gyro_csv", "actuator_csv", "config") if k in s.inputs}
    if stage == "init":
        return {"run_mcap": s.path("ingest")}
    if stage == "estimate":
        return {"run_mcap": s.path("ingest"), "init_json": s.path("init")}
    return {"states_mcap": s.path("estimate"), "gyro_run_mcap": s.path("ingest")}


def stage_key(s: Session, stage: str) -> str:
    """sha256 of what a stage's outputs are a function of: its name, options, input files' bytes,
    the output paths (outputs record them) and the software version."""
    ident = {"stage": stage, "cdgps": __version__, "options": s.stage_options(stage),
             "inputs": {k: [p, _sha256(p)] for k, p in stage_inputs(s, stage).items()},
             "output": s.path(stage)}
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()


def _output_files(s: Session, stage: str) -> dict:
    p = Path(s.path(stage))
    if p.is_dir():
        return {f"{p.name}/{f.name}": _sha256(str(f)) for f in sorted(p.iterdir())
                if f.is_file() and not f.name.startswith(".")}
    return {p.name: _sha256(str(p))} if p.is_file() else {}


def record_path(s: Session, stage: str) -> Path:
    return Path(s.folder) / RECORD_DIR / f"{stage}.json"


def valid_record(s: Session, stage: str) -> dict | None:
    """The record of a finished stage if it still holds: same key and outputs unchanged; else None."""
    rp = record_path(s, stage)
    try:
        rec = json.loads(rp.read_text())
    except (OSError, ValueError):
        return None
    try:
        if rec.get("key") != stage_key(s, stage):
            return None
    except OSError:                # an input vanished: the stage is redone (and fails there, named)
        return None
    outs = _output_files(s, stage)
    if not outs or outs != rec.get("outputs"):
        return None
    return rec


def write_record(s: Session, stage: str, summary: dict) -> dict:
    """Record a finished stage (written atomically, after its outputs)."""
    from cdgps_cli.io.atomic import write_bytes_atomic

    rec = {"stage": stage, "session": s.name, "key": stage_key(s, stage), "outputs": _output_files(s, stage),
           "summary": summary}
    write_bytes_atomic(record_path(s, stage), (json.dumps(rec, indent=2, sort_keys=True) + "\n").encode())
    return rec


def forget_record(s: Session, stage: str) -> None:
    try:
        record_path(s, stage).unlink()
    except FileNotFoundError:
        pass


# --------------------------------------------------------------------------- one session-stage

#: test hook (docs/batch.md, "Testing faults"): a folder; its file ``faults`` lists lines
#: ``SESSION/STAGE KIND N``: the first N attempts of that session-stage fail (KIND ``raise``: a
#: RuntimeError, ``input``: a CdgpsError, ``oserror``, ``memory``: a MemoryError) or kill their worker
#: process (KIND ``kill``).  Attempts are counted in files of that folder, so that the
#: count survives the worker's death.  Unset (the normal case): nothing is read.
FAULT_ENV = "CDGPS_BATCH_FAULTS"


class InjectedFault(RuntimeError):
    """The failure asked for by :data:`FAULT_ENV` (tests only)."""


class InjectedInputError(CdgpsError):
    """An input error asked for by :data:`FAULT_ENV` (tests only): failed at once, never retried."""


def _raise_fault(kind: str, what: str) -> None:
    """KIND ``raise`` (RuntimeError), ``input`` (CdgpsError), ``oserror``, ``memory``, ``kill``."""
    if kind == "kill":
        os.kill(os.getpid(), 9)
    if kind == "input":
        raise InjectedInputError(what)
    if kind == "oserror":
        raise OSError(5, what)
    if kind == "memory":
        raise MemoryError(what)
    raise InjectedFault(what)


def _inject_fault(session: str, stage: str) -> None:
    folder = os.environ.get(FAULT_ENV)
    if not folder:
        return
    try:
        lines = (Path(folder) / "faults").read_text().splitlines()
    except FileNotFoundError:
        return
    for line in lines:
        target, kind, n = line.split()
        if target != f"{session}/{stage}":
            continue
        counter = Path(folder) / f"{session}-{stage}.attempts"
        with open(counter, "a") as fh:
            fh.write(f"{os.getpid()}\n")
        attempt = len(counter.read_text().split())
        if attempt <= int(n):
            _raise_fault(kind, f"injected failure of {session}/{stage} (attempt {attempt}; the first {n} fail)")


def execute_stage(s: Session, stage: str, resume: bool, *upstream) -> dict:
    """Run (or, with ``resume``, skip when its record holds) one stage of one session.

    ``upstream`` are the results of the stages it depends on (only their order matters to dask).

    Returns
    -------
    dict with ``session``, ``stage``, ``status`` ("done" or "skipped"), ``elapsed_s`` (wall),
    ``cpu_s`` (this process's CPU time during the stage), ``peak_rss_mb`` (the process's peak resident
    memory during the stage, Linux; else None), ``rss_mb`` (resident memory after the stage, once its
    memory was released), ``worker`` (host:pid), ``blas_threads`` (the thread variables seen by the
    worker) and ``summary``.
    """
    import socket
    import time

    from cdgps_cli.pipeline import batch_stages

    t0, c0 = time.perf_counter(), time.process_time()
    _reset_peak_rss()
    started = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    who = {"worker": f"{socket.gethostname()}:{os.getpid()}",
           "blas_threads": {k: os.environ.get(k) for k in BLAS_ENV}}
    rec = valid_record(s, stage) if resume else None
    status, summary = ("skipped", rec["summary"]) if rec is not None else ("done", None)
    if rec is None:
        forget_record(s, stage)
        _inject_fault(s.name, stage)
        summary = batch_stages.run_stage(s, stage)
        write_record(s, stage, summary)
    peak_mb = _proc_status_mb("VmHWM")
    release_memory()
    return {"session": s.name, "stage": stage, "status": status, "started": started,
            "elapsed_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "peak_rss_mb": peak_mb,
            "rss_mb": _proc_status_mb("VmRSS"), "summary": summary, **who}


def release_memory() -> None:
    """Give the memory freed by a finished stage back to the system (between the tasks of a worker).

    ``gc.collect()`` frees the cycles the stage left, then glibc's ``malloc_trim(0)`` returns the free
    pages of the heap, which a long-lived worker would otherwise keep, fragmented, from session to
    session (its resident memory grew by ≈ 40-60 MB over the first sessions without it; see
    docs/batch.md).  A no-op where there is no glibc.
    """
    import gc

    gc.collect()
    heap.trim()


def _reset_peak_rss() -> None:
    """Reset this process's peak resident memory (Linux ``/proc/self/clear_refs``), so that the peak
    read after a stage is the stage's own; elsewhere nothing happens."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def _proc_status_mb(key: str) -> float | None:
    """A memory figure of ``/proc/self/status`` (``VmRSS``, ``VmHWM``) in MB, None if unavailable."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        pass
    return None


#: one BLAS / OpenMP thread per worker process: the parallelism is one task per core
BLAS_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
            "VECLIB_MAXIMUM_THREADS": "1", "NUMEXPR_NUM_THREADS": "1"}


def stage_argv(s: Session, stage: str) -> list:
    """The single command that writes the same bytes as ``stage`` of ``s`` (``cdgps`` omitted)."""
    if stage == "ingest" and s.kind == "gnss":
        return ["ingest", "--config", s.inputs["gnss_config"], "-o", s.path("ingest")]
    if stage == "ingest":
        argv = ["ingest", s.inputs["receiver_csv"]]
        if "gyro_csv" in s.inputs:
            argv.append(s.inputs["gyro_csv"])
        if "actuator_csv" in s.inputs:
            argv += ["--actuators", s.inputs["actuator_csv"]]
        return argv + ["--config", s.inputs["config"], "-o", s.path("ingest")]
    run = s.path("ingest")
    if stage == "init":
        argv = ["init", run]
    elif stage == "estimate":
        argv = ["estimate", run, "--init", s.path("init")]
    elif stage == "spectra":
        argv = ["spectra", s.path("estimate"), "--gyro", run]
    else:
        argv = ["report", "spectrum", s.path("estimate"), "--gyro", run]
    for k, v in s.stage_options(stage).items():
        opt = OPTIONS[k]
        if v == opt.default:
            continue
        argv += [opt.flag] if opt.kind == "bool" else [opt.flag, f"{v:g}" if isinstance(v, float) else str(v)]
    return argv + ["-o", s.path(stage)]


# --------------------------------------------------------------------------- the campaign summary

def session_summary(s: Session, results: dict, errors: dict) -> dict:
    """One session's entry of batch.json from its stages' results and errors ({stage: ...})."""
    stages, status, failed_at = {}, "done", None
    for st in s.stages:
        if st in results:
            r = results[st]
            stages[st] = {"status": r["status"], "started": r.get("started"), "elapsed_s": round(r["elapsed_s"], 3),
                          "cpu_s": _round(r.get("cpu_s"), 3), "peak_rss_mb": r.get("peak_rss_mb"), "rss_mb": r.get("rss_mb"),
                          "worker": r.get("worker"), "blas_threads": r.get("blas_threads")}
        elif st in errors and failed_at is None:
            failed_at = st
            stages[st] = {"status": "failed", "error": errors[st]}
        else:
            stages[st] = {"status": "not run", "reason": f"{failed_at} failed" if failed_at else "interrupted"}
    if failed_at or len(results) < len(s.stages):
        status = "failed"
    elif all(results[st]["status"] == "skipped" for st in s.stages):
        status = "up to date"
    summ = {k: v for st in s.stages if st in results for k, v in results[st]["summary"].items()}
    out = {"session": s.name, "time": s.time, "status": status, "folder": s.folder, "stages": stages,
           "elapsed_s": round(sum(r["elapsed_s"] for r in results.values()), 3)}
    if failed_at:
        out["error"] = f"{failed_at}: {errors[failed_at]}"
    out.update(summ)
    return out


def _round(v, digits: int):
    return None if v is None else round(v, digits)


#: a σ below this fraction of the values' magnitude is no measured uncertainty (a fixed, clamped or
#: degenerate estimate, e.g. a damping ratio with σ ≈ 1e-15): such a series gets no trend
TREND_SIGMA_FLOOR = 1e-9
#: what the index and batch.json say instead of a trend that cannot be fitted
NO_SPREAD = "not enough spread"


def trend_fit(t_day, y, sigma) -> tuple:
    """Weighted least-squares line y = a + b t (weights 1/σ²) with the slope's σ from the weights, or
    why there is none.

    Points whose time, value or σ is not finite, or whose σ is not > 0, are left out.  No line is
    fitted (never an exception) with fewer than 3 points left, a single time, identical values, or a
    σ below :data:`TREND_SIGMA_FLOOR` × the values' magnitude.  The fit is the centred closed form
    with weights scaled by the smallest σ, so that no matrix is inverted and no weight overflows.

    Parameters
    ----------
    t_day, y, sigma : sequences (n,) of days, values, 1σ

    Returns
    -------
    (fit, note) : ``fit`` a dict ``{"slope_per_day", "slope_sigma_per_day", "intercept",
        "chi2_per_dof", "n"}`` and ``note`` None; or ``fit`` None and ``note`` a sentence beginning
        with :data:`NO_SPREAD`.
    """
    import numpy as np

    t, y, s = (np.asarray(a, float).ravel() for a in (t_day, y, sigma))
    ok = np.isfinite(t) & np.isfinite(y) & np.isfinite(s) & (s > 0)
    t, y, s = t[ok], y[ok], s[ok]
    n = len(t)
    if n < 3:
        return None, f"{NO_SPREAD}: {n} session{'s' if n != 1 else ''} with a finite value and σ > 0 (a line needs 3)"
    if np.ptp(t) == 0:
        return None, f"{NO_SPREAD}: all {n} sessions at the same time"
    s_min = float(s.min())
    if s_min <= TREND_SIGMA_FLOOR * float(np.abs(y).max()):
        return None, f"{NO_SPREAD}: σ ≈ 0 ({s_min:.1g} for values of {np.abs(y).max():.3g}); no real uncertainty"
    if np.ptp(y) == 0:
        return None, f"{NO_SPREAD}: the same value ({y[0]:.6g}) in all {n} sessions"
    w = (s_min / s) ** 2                               # relative weights in (0, 1]
    tw, yw = (w * t).sum() / w.sum(), (w * y).sum() / w.sum()
    dt = t - tw
    stt = float((w * dt**2).sum())
    slope = float((w * dt * (y - yw)).sum() / stt) if stt > 0 else float("nan")
    fit = {"slope_per_day": slope, "slope_sigma_per_day": s_min / math.sqrt(stt) if stt > 0 else float("nan"),
           "intercept": float(yw - slope * tw), "chi2_per_dof": float((((y - yw - slope * dt) / s) ** 2).sum() / (n - 2)),
           "n": int(n)}
    if not all(math.isfinite(v) for v in fit.values()):
        return None, f"{NO_SPREAD}: the {n} sessions do not determine a finite line"
    return fit, None


def weighted_trend(t_day, y, sigma) -> dict | None:
    """The line of :func:`trend_fit`, None when there is none."""
    return trend_fit(t_day, y, sigma)[0]


def mode_trends(entries: list) -> list:
    """Per mode: frequency and damping of every session that identified it, in time order, with
    weighted linear trends over time (days) when the sessions carry times."""
    by_mode = {}
    for i in _time_order(entries):
        e = entries[i]
        for m in e.get("modes", []):
            by_mode.setdefault(m["mode"], {"mode": m["mode"], "model_hz": m["model_hz"], "sessions": []})
            by_mode[m["mode"]]["sessions"].append(
                {"session": e["session"], "time": e["time"], "gps_hz": m["gps_hz"], "gps_hz_sigma": m["gps_hz_sigma"],
                 "damping": m["damping"], "damping_sigma": m["damping_sigma"], "seen": m["seen"]})
    out = []
    for mode in sorted(by_mode.values(), key=lambda d: (not math.isfinite(_num(d["model_hz"])), _num(d["model_hz"]))):
        for q, sq, name in (("gps_hz", "gps_hz_sigma", "frequency_trend_hz"), ("damping", "damping_sigma", "damping_trend")):
            mode[name], mode[name + "_note"] = _trend_over_sessions(mode["sessions"], q, sq, "mode")
        out.append(mode)
    return out


def _time_order(entries: list) -> list:
    """The sessions' indexes in time order (those without a time last, in manifest order)."""
    return sorted(range(len(entries)), key=lambda i: (entries[i]["time"] is None, entries[i]["time"] or "", i))


def _trend_over_sessions(points: list, value_key: str, sigma_key: str, what: str) -> tuple:
    """:func:`trend_fit` of ``points`` (sessions' dicts with ``time``) against their time in days from the first; the
    note of a series without any time."""
    pts = [p for p in points if p["time"] is not None]
    t0 = _days(pts[0]["time"]) if pts else 0.0
    fit, note = trend_fit([_days(p["time"]) - t0 for p in pts], [_num(p[value_key]) for p in pts],
                          [_num(p[sigma_key]) for p in pts])
    return fit, (note if pts else f"{NO_SPREAD}: no session of this {what} has a time")


def position_trends(entries: list) -> list:
    """Per GNSS rover coordinate (``rover_e`` …): the static position of every session that estimated it, in time
    order, with its σ, and the weighted linear trend over time (m/day, :func:`trend_fit`; χ²/dof ≫ 1: the sessions
    scatter more than their σ say, as a low-cost receiver's multipath makes them): a settlement or a thermal drift
    as the modes' trends show a stiffness change.  Each session's E/N/U are about its own run's nominal position
    (``nominal_ecef_m``); sessions of runs with other nominals are taken to the rover's first session's (a review:
    three runs of one antenna, each placed at its own first epochs, gave slopes of metres a day), and each point
    says the origin it is about (``origin_ecef_m``)."""
    by, origin = {}, {}
    for i in _time_order(entries):
        e = entries[i]
        for r, v in (e.get("rovers") or {}).items():
            sig = v.get("static_sigma_m") or {}
            enu = _about_origin(v, origin.setdefault(r, v.get("nominal_ecef_m")))
            for c, x in enu.items():
                by.setdefault(c, {"coordinate": c, "rover": r, "origin_ecef_m": origin[r], "sessions": []})[
                    "sessions"].append({"session": e["session"], "time": e["time"], "value_m": x,
                                        "sigma_m": sig.get(c)})
    out = []
    for c in sorted(by):
        tr = by[c]
        tr["trend_m"], tr["trend_m_note"] = _trend_over_sessions(tr["sessions"], "value_m", "sigma_m", "rover")
        out.append(tr)
    return out


def _about_origin(v: dict, origin) -> dict:
    """A session's static E/N/U (``v["static_enu_m"]``, about its run's ``nominal_ecef_m``) about ``origin`` (ECEF m;
    None or the same nominal: as they are)."""
    enu = dict(v.get("static_enu_m") or {})
    nominal = v.get("nominal_ecef_m")
    if origin is None or nominal is None or np.array_equal(np.asarray(origin, float), np.asarray(nominal, float)):
        return enu
    if len(enu) != 3 or not all(_num(x) == _num(x) for x in enu.values()):
        return {c: float("nan") for c in enu}                 # (a partial or NaN position cannot be moved)
    from cdgps_cli.model.gps.orbits import ecef_to_geodetic, enu_matrix  # noqa: PLC0415

    def frame(x):
        lat, lon, _ = ecef_to_geodetic(np.asarray(x, dtype=np.float64))
        return enu_matrix(lat, lon)

    xyz = np.asarray(nominal, float) + frame(nominal).T @ np.array([_num(x) for x in enu.values()])
    return dict(zip(enu, (frame(origin) @ (xyz - np.asarray(origin, float))).tolist()))


def _num(v) -> float:
    try:
        return float("nan") if v is None else float(v)
    except (TypeError, ValueError):
        return float("nan")


def finite_json(obj):
    """``obj`` with every non-finite float (NaN, ±inf) replaced by None: batch.json stays strict JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    return obj


def _days(iso: str) -> float:
    return datetime.fromisoformat(iso.replace("Z", "+00:00")).timestamp() / 86400.0
