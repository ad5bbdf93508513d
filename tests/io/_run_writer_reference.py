"""The whole-record RUN writer as it was before ``cdgps ingest`` streamed (issue 29 item 1), kept as
the reference the streaming writer is compared with, byte for byte (tests/io/test_run_stream.py).

Copied from ``cdgps_cli/io/run.py`` (``write_run``, ``_read_sequence``, ``_check_same_receivers``,
``_attach_phase_packed``) and ``cdgps_cli/io/logs.py`` (the typed reading of a valid log) at commit
d3fb528: every log read whole into memory, joined as tables, then written.  Valid inputs only (the
messages of invalid ones are compared in tests/io/test_log_fast_path.py; the checks of the join that only
refuse files — rate, receivers — are left out).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from cdgps_cli.core.gps_time import nominal_interval_s
from cdgps_cli.core.table import Table
from cdgps_cli.io.log_sequence import expand_paths, join_tables
from cdgps_cli.io.logs import ACTUATOR_COLUMNS, GYRO_COLUMNS, RECEIVER_COLUMNS, _header
from cdgps_cli.io.mcap import (ACTUATOR_SCHEMA, ACTUATOR_TOPIC, CONFIG_ATTACHMENT, GYRO_SCHEMA, GYRO_TOPIC, PHASE_SCHEMA,
                               PHASE_TOPIC, McapOut)
from cdgps_cli.io.run import (GYRO_ARRAYS, INFO_STRUCTURE_KEY, INGEST_METADATA, PHASE_ARRAYS, PHASE_COLUMNS,
                              PHASE_NAME_COLUMNS, PHASE_PACKED, _npy, epoch_gaps, ingest_metadata, input_keys)


def _read(path, columns, numeric, optional=()):
    """The typed reading of a valid log (old ``_fast_table``, whole file)."""
    p = Path(path)
    opener, _, _ = _header(p, columns)
    kinds = {c: (float if c in numeric or c in optional else "category") for c in columns}
    with opener(p, "rb") as fh:
        df = pd.read_csv(fh, dtype=kinds, keep_default_na=False, engine="c", na_values={c: [""] for c in optional})
    df = pd.DataFrame({c: (df[c].to_numpy(dtype=float) if kinds[c] is float else df[c]) for c in columns},
                      columns=list(columns))
    if "lock" in df:
        df["lock"] = df["lock"].astype(np.int64)
    return df


def read_receiver_log(p, cfg):
    return _read(p, RECEIVER_COLUMNS, ("time_s", "phase_cycles", "lock"), ("snr_dbhz",))


def read_gyro_log(p, cfg):
    return _read(p, GYRO_COLUMNS, ("time_s", "rate_rad_s"))


def read_actuator_log(p, cfg):
    return _read(p, ACTUATOR_COLUMNS, ("time_s", "force_n"))


def _attach_phase_packed(out: McapOut, phase: Table) -> None:
    names = {}
    for col in PHASE_NAME_COLUMNS:
        codes, words = phase.codes(col)
        names[col] = list(words)
        out.attach_packed(f"{PHASE_PACKED}{col}_code", codes.astype(np.int32))
    out.attach(PHASE_PACKED + "names.json", json.dumps(names, sort_keys=True).encode(), "application/json")
    out.attach_packed(PHASE_PACKED + "time_s", phase["time_s"].astype(float, copy=False))
    out.attach_packed(PHASE_PACKED + "phase_cycles", phase["phase_cycles"].astype(float, copy=False))
    out.attach_packed(PHASE_PACKED + "lock", phase["lock"].astype(np.int64, copy=False))
    out.attach_packed(PHASE_PACKED + "snr_dbhz", phase["snr_dbhz"].astype(float, copy=False))


def write_run(cfg, receiver_csv, out_path, gyro_csv=None, actuator_csv=None, channel_summary=None) -> dict:
    given = {"receiver_csv": receiver_csv, "gyro_csv": gyro_csv, "actuator_csv": actuator_csv}
    files = {k: expand_paths([v] if isinstance(v, (str, Path)) else list(v), k.upper())
             for k, v in given.items() if v is not None and (isinstance(v, (str, Path)) or len(v))}
    sources = {key: Path(p) for k, ps in files.items() for key, p in input_keys(k, ps)}
    out_path = Path(out_path)
    joins: dict = {}
    rx = _read_sequence(files["receiver_csv"], read_receiver_log, cfg, cfg.sample_period_s, joins, "receiver_csv")
    phase = Table.from_frame(rx[PHASE_COLUMNS], name_columns=PHASE_NAME_COLUMNS, categorical=PHASE_NAME_COLUMNS)
    gyro = _read_sequence(files["gyro_csv"], read_gyro_log, cfg, None, joins, "gyro_csv") if "gyro_csv" in files else None
    act = (_read_sequence(files["actuator_csv"], read_actuator_log, cfg, None, joins, "actuator_csv", sampled=False)
           if "actuator_csv" in files else None)
    if joins:
        sources = {key: Path(p) for k, ps in files.items() for key, p in input_keys(k, ps)}
    meta = ingest_metadata("structure", cfg, sources, sample_period_s=repr(cfg.sample_period_s))
    with McapOut(out_path, time_scale="relative") as out:
        ch = out.channel(PHASE_TOPIC, PHASE_SCHEMA, {"units": "cycles", "wavelength_m": repr(cfg.wavelength_m)})
        n_phase = out.write_table(ch, phase, PHASE_ARRAYS, ["master"])
        _attach_phase_packed(out, phase)
        n_gyro = n_act = 0
        if gyro is not None and len(gyro):
            n_gyro = out.write_table(out.channel(GYRO_TOPIC, GYRO_SCHEMA, {"units": "rad/s"}), gyro, ["gyro", "rate_rad_s"])
            codes, names = Table.from_frame(gyro[["gyro"]]).codes("gyro")
            out.attach(GYRO_ARRAYS + "time_s.npy", _npy(gyro["time_s"].to_numpy(dtype=float)), "application/x-npy")
            out.attach(GYRO_ARRAYS + "rate_rad_s.npy", _npy(gyro["rate_rad_s"].to_numpy(dtype=float)), "application/x-npy")
            out.attach(GYRO_ARRAYS + "gyro_index.npy", _npy(codes.astype(np.int64)), "application/x-npy")
            out.attach(GYRO_ARRAYS + "gyro_names.json", json.dumps(list(names)).encode(), "application/json")
        if act is not None:
            n_act = out.write_table(out.channel(ACTUATOR_TOPIC, ACTUATOR_SCHEMA, {"units": "N"}), act, ["actuator", "force_n"])
        out.attach(CONFIG_ATTACHMENT, cfg.text.encode("utf-8"), "application/toml")
        out.metadata(INGEST_METADATA, meta)
        gaps = epoch_gaps(phase["time_s"], cfg.sample_period_s)
        chans = None if channel_summary is None else channel_summary(phase, cfg.sample_period_s)
        out.info_extra[INFO_STRUCTURE_KEY] = json.dumps({"gaps": gaps, **({} if chans is None else {"channels": chans})})
    t = phase["time_s"]
    a_codes, _ = phase.codes("antenna")
    x_codes, x_names = phase.codes("transmitter")
    return {
        "output": str(out_path), "config": cfg.name, "config_sha256": cfg.sha256,
        "phase_rows": int(len(phase)), "phase_messages": n_phase,
        "gyro_rows": int(0 if gyro is None else len(gyro)), "gyro_messages": n_gyro,
        "actuator_rows": int(0 if act is None else len(act)), "actuator_messages": n_act,
        "start_s": float(t[0]), "end_s": float(t[-1]), "gaps": gaps,
        "channels": int(np.unique(a_codes.astype(np.int64) * len(x_names) + x_codes).size),
        "lock_restarts": None if chans is None else sum(len(c["lock_restarts_s"]) for c in chans),
        **({"joins": {k: j["report"] for k, j in joins.items()},
            "warnings": [w for j in joins.values() for w in j["warnings"]]} if joins else {}),
    }


def _read_sequence(paths, reader, cfg, period_s, joins, key, sampled=True):
    if len(paths) == 1:
        return reader(paths[0], cfg)
    tabs = [reader(p, cfg) for p in paths]
    names = [Path(p).name if len({Path(q).name for q in paths}) == len(paths) else str(p) for p in paths]
    period = (period_s or nominal_interval_s(np.concatenate([t["time_s"].to_numpy() for t in tabs]))) if sampled \
        else float("nan")
    tab, rep, order = join_tables(list(zip(names, tabs)), "time_s", period, what=key)
    paths[:] = [paths[i] for i in order]
    joins[key] = {"report": rep.as_dict(), "warnings": rep.warnings}
    return tab
