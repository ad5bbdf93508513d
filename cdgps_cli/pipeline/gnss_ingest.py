"""``cdgps ingest`` of GNSS receiver files (docs/gnss-pipeline.md): the stage around :mod:`cdgps_cli.io.gnss_run`.

:mod:`cdgps_cli.io.gnss_run` reads the receiver and navigation files and writes the RUN.mcap; the
checks that need the GPS model — every receiver's phases covered by a healthy broadcast ephemeris
(:func:`cdgps_cli.model.gps.positioning.ephemeris_coverage`) and the epochs each rover has in
common with the master (:func:`cdgps_cli.measurement.epoch_pairing.pair_epochs`) — are made here, so
that ``io`` imports no numerics.  :func:`run_info` is ``cdgps info`` with the GNSS common-epoch
counts.  The receivers' observation table of the solvers (:func:`processing_obs`: u-blox lock
times → loss-of-lock bits) and their lock counters (:func:`lock_summary`) follow the one
lock-segment rule, :func:`cdgps_cli.measurement.channels.lock_segments`.
"""

from __future__ import annotations

from pathlib import Path


import numpy as np
import pandas as pd

from cdgps_cli.config.structure import GnssConfig
from cdgps_cli.core import heap
from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io import gnss_hours, gnss_run
from cdgps_cli.io.log_sequence import expand_paths
from cdgps_cli.core.gps_time import distinct_times, nominal_interval_s
from cdgps_cli.core.records import OBS_COLUMNS
from cdgps_cli.io.gnss_run import GnssReceiver, IngestInputs, span_text
from cdgps_cli.io.sensor_logs import sensor_attachments, sensor_log_file
from cdgps_cli.io.ubx_esf import receiver_imu_tables
from cdgps_cli.measurement.channels import FIRST, lock_segments, ubx_loss_of_lock  # noqa: F401 (ubx_loss_of_lock: re-exported)
from cdgps_cli.measurement.epoch_pairing import pair_epochs
from cdgps_cli.config.options import HEADER_CHECK_EPOCHS, HEADER_POSITION_TOL_M
from cdgps_cli.model.gps.positioning import antenna_reference_point_m, ephemeris_coverage, spp_spread
from cdgps_cli.pipeline.antenna_models import antenna_models, named_antennas_known

__all__ = ["ingest_gnss", "run_info", "processing_obs", "signal_obs", "ubx_loss_of_lock", "lock_summary", "starter_gnss_config",
           "spp_master_position"]


def ingest_gnss(cfg: GnssConfig, out_path: str | Path, *, rinex: dict | None = None, ubx: dict | None = None,
                nav_paths=None, master: str | None = None, progress=None, strict: bool = False,
                sensor_paths=None) -> dict:
    """Read receiver files and navigation data, check them, and write a GNSS RUN.mcap.

    Parameters
    ----------
    cfg : GnssConfig
        The run config (attached to the run).  Its antenna files and navigation files are used
        unless ``rinex``/``ubx`` or ``nav_paths`` are given (the command line overrides the file).
    out_path : path
        RUN.mcap to write (atomically).
    rinex, ubx : dict, optional
        ``{antenna: path}`` observation files.
    nav_paths : list of path, optional
        RINEX navigation files (merged).  None: the config's; empty: no ephemeris (a warning:
        ``cdgps init`` then needs a run ingested with navigation data).
    master : str, optional
        Master antenna (default: the config's, or the only antenna).
    strict : bool, default False
        Refuse a UBX log with corrupt or skipped data (checksum failures, undecodable RXM-RAWX,
        bytes skipped between frames, a truncated tail) instead of counting and reporting it.
    sensor_paths : list of path, optional
        Sensor CSV logs (accelerometers, tilt meters, gyros; :mod:`cdgps_cli.io.sensor_logs`) attached
        to the run for ``estimate --fuse``.  None: the config's ``[gnss] sensors``.

    Returns
    -------
    dict
        Summary (receivers, epochs, spans, common epochs, slips, ephemerides, warnings, and
        ``integrity``: per UBX receiver its file, counters and the worded losses, ``problems``; ``reading``: whether
        the files were read hour by hour (:mod:`cdgps_cli.io.gnss_hours`: ``hour_by_hour``, ``blocks``) or whole, and
        why (``why_whole``, e.g. "rover.obs.gz: compressed")).

    Raises
    ------
    CdgpsError
        Missing or unreadable files, a file without L1 carrier phase, navigation data that do not
        cover a receiver's observations, receivers without common epochs, a master without a
        position while there are rovers, an output that would overwrite an input.
    """
    say = progress or (lambda m: None)
    why: list[str] = []
    antex = _antex_checked(cfg)             # the ANTEX file and the antennas the config names: before any reading
    hourly = gnss_hours.hourly_inputs(cfg, out_path, rinex=rinex, ubx=ubx, nav_paths=nav_paths, master=master,
                                      progress=progress, why=why, strict=strict)
    if hourly is not None:
        inp, blocks, mapped = hourly
        try:
            s = _ingest_hour_by_hour(cfg, out_path, inp, blocks, sensor_paths, say, antex)
            s["reading"] = {"hour_by_hour": True, "blocks": len(blocks), "why_whole": None}
            return s
        except _ChecksRefused as exc:      # the checks the whole reading makes on the same tables: its error
            raise exc.error from None
        except gnss_hours.NotCut as exc:
            why.append(str(exc))
            say(f"reading the files whole ({exc}) …")
        except CdgpsError:                # (named by the whole reading: the file's own line, not a block's)
            why.append("an error in a block, named by the whole reading")
            say("an error in a block of the files: reading them whole, which names it …")
        except MemoryError:
            raise
        except Exception as exc:          # noqa: BLE001 (what the whole reading makes of it is what users get)
            why.append(f"the hour-by-hour reading failed ({type(exc).__name__}: {exc})")
            say(f"reading block by block failed ({type(exc).__name__}): reading the files whole …")
        finally:
            mapped.close()
    inp = gnss_run.read_ingest_inputs(cfg, out_path, rinex=rinex, ubx=ubx, nav_paths=nav_paths, master=master,
                                      progress=progress, strict=strict)
    if inp.nav is not None:
        _check_coverage(inp, cfg.signals)
    pos_src = gnss_run.nominal_positions(cfg, inp, lambda n: first_epochs_position(inp, n))
    common = _common_epochs(cfg, inp)
    say(f"writing {out_path} …")
    lock = {n: lock_summary(rx, lock_obs(rx, cfg.signals)) for n, rx in inp.receivers.items()}
    ant_att, ant_inputs = antenna_parts(cfg, inp, antex)
    att, extra_inputs, done = _sensor_parts(inp, _sensors(cfg, sensor_paths))
    s = done(gnss_run.write_gnss_run(cfg, out_path, inp, pos_src, common, lock, extra_attachments={**(att or {}), **ant_att} or None,
                                     extra_inputs={**extra_inputs, **ant_inputs}))
    s["reading"] = {"hour_by_hour": False, "blocks": None, "why_whole": "; ".join(why) or None}
    return s


def _ingest_hour_by_hour(cfg: GnssConfig, out_path, inp, blocks, sensor_paths, say, antex=None) -> dict:
    """:func:`ingest_gnss` of receivers read block by block (:func:`cdgps_cli.io.gnss_hours.hourly_inputs`): the
    observations written as they are read, the checks made on the thin tables once the last block is in."""
    heap.map_large_blocks(1 << 20)         # each block's arrays unmapped when freed: the blocks' memory does not pile up
    sensors = _sensors(cfg, sensor_paths)
    extra_inputs = {**_sensor_inputs(sensors), **({"antex": cfg.antex} if cfg.antex else {})}
    parts = {}

    def finish():
        try:
            if inp.nav is not None:
                _check_coverage(inp, cfg.signals)
            pos_src = gnss_run.nominal_positions(cfg, inp, lambda n: first_epochs_position(inp, n))
            common = _common_epochs(cfg, inp)
            ant_att, _ = antenna_parts(cfg, inp, antex)
        except CdgpsError as exc:
            raise _ChecksRefused(exc) from None
        lock = {n: lock_summary(rx, lock_obs(rx, cfg.signals)) for n, rx in inp.receivers.items()}
        att, _, parts["done"] = _sensor_parts(inp, sensors, esf=False)
        return pos_src, common, lock, {**(att or {}), **ant_att} or None

    say(f"writing {out_path} …")
    names = [inp.master, *[n for n in inp.files if n != inp.master]]
    s = gnss_run.write_gnss_run_blocks(cfg, out_path, inp, names, blocks, finish, extra_inputs)
    return parts["done"](s)


def with_antenna_options(cfg: GnssConfig, antex=None, antenna_types: dict | None = None) -> GnssConfig:
    """``cfg`` with the command line's ANTEX file (``ingest --antex``, over ``[gnss] antex``) and antenna types
    (``--antenna NAME=TYPE``, over ``[gnss.antennas.NAME] antenna_type``; an antenna the config has no table of gets
    one).  CdgpsError for a type named without any ANTEX file (as the config's check words it)."""
    from dataclasses import replace  # noqa: PLC0415

    from cdgps_cli.config.structure import GnssAntenna  # noqa: PLC0415

    types = dict(antenna_types or {})
    antex = str(antex) if antex is not None else cfg.antex
    for name, typ in types.items():
        if typ.strip().lower() != "none" and antex is None:
            raise CdgpsError(f"--antenna {name}={typ!r}: no ANTEX file (--antex, or [gnss] antex) to take its "
                             f"calibration from")
    ants = [replace(a, antenna_type=types.pop(a.name)) if a.name in types else a for a in cfg.antennas]
    ants += [GnssAntenna(name, antenna_type=typ) for name, typ in types.items()]
    return replace(cfg, antex=antex, antennas=tuple(ants))


def _antex_checked(cfg: GnssConfig) -> dict | None:
    """``[gnss] antex``'s models, read once and checked for every ``antenna_type`` the config names (None: no file)."""
    if cfg.antex is None:
        return None
    if not Path(cfg.antex).is_file():
        raise CdgpsError(f"{cfg.path}: [gnss] antex (--antex): {cfg.antex}: cannot read: "
                         f"{'a directory' if Path(cfg.antex).is_dir() else 'no such file'}")
    return named_antennas_known(cfg.antex, {a.name: a.antenna_type for a in cfg.antennas},
                                {a.name: f"[gnss.antennas.{a.name}] antenna_type (--antenna {a.name}=TYPE)"
                                 for a in cfg.antennas})


def antenna_parts(cfg: GnssConfig, inp, antex_models: dict | None = None) -> tuple[dict, dict]:
    """(the RUN's attachment of the receivers' antenna calibrations, {name: bytes}; its hashed input, {key: path}) of
    ``[gnss] antex`` (both empty without it): each receiver's model as ``[gnss.antennas.NAME] antenna_type`` or its
    RINEX header names it (:func:`~cdgps_cli.pipeline.antenna_models.antenna_models`; ``init`` and ``estimate`` take
    them out of its observations: :func:`~cdgps_cli.io.gnss_run.read_gnss_run`'s ``antennas``).  Without the key, a
    warning in ``inp.warnings`` when the headers name antennas of different types.  ``antex_models``: the file's
    models already read (:func:`_antex_checked`)."""
    names = [inp.master, *[n for n in inp.receivers if n != inp.master]]
    named = {n: (cfg.antenna(n).antenna_type if cfg.antenna(n) is not None else None) for n in names}
    headers = {n: inp.receivers[n].header for n in names}
    paths = {n: inp.receivers[n].file for n in names}
    models = antenna_models(cfg.antex, named, headers, paths, inp.warnings,
                            {n: f"[gnss.antennas.{n}] antenna_type (--antenna {n}=TYPE)" for n in names},
                            "[gnss] antex (--antex)", antex_models)
    if cfg.antex is None:
        return {}, {}
    for n, m in models.items():
        lacking = [g for g in (cfg.signals or ("G:L1",)) if m is not None and m.frequency(g) is None]
        if lacking:
            raise CdgpsError(f"{cfg.antex}: antenna {' '.join(m.name.split())} ({paths[n]}, {n}) has no calibration for "
                             f"{', '.join(lacking)} (it has {', '.join(sorted(m.offsets_neu_mm))}); leave the signal out "
                             f"of [gnss] signals, give an ANTEX file that has it, or [gnss.antennas.{n}] antenna_type "
                             f"= \"none\"")
    name = Path(cfg.antex).name           # as the RUN's inputs name it (their sha256 beside it): no machine's path
    inp.antennas = gnss_run.antennas_info(name, models)
    return {gnss_run.ANTENNAS_ATTACHMENT: gnss_run.antennas_json(name, models)}, {"antex": cfg.antex}


class _ChecksRefused(Exception):
    """An ingest read block by block refused by the checks made on the whole record (ephemeris coverage, positions,
    common epochs): the error the whole-file ingest gives too, after the same reading (``.error``), without reading
    the files again."""

    def __init__(self, error: CdgpsError):
        super().__init__(str(error))
        self.error = error


def _sensors(cfg: GnssConfig, sensor_paths) -> list:
    return config_sensor_paths(cfg) if sensor_paths is None else [str(p) for p in sensor_paths]


def _sensor_inputs(sensors: list) -> dict:
    """The sensor logs' entries of the RUN's hashed inputs."""
    return {f"sensors[{i}]": sensor_log_file(p) for i, p in enumerate(sensors)}


def _sensor_parts(inp, sensors: list, esf: bool = True) -> tuple:
    """(the sensor logs' attachments or None, their metadata inputs, a function completing the summary with them)
    of an ingest: the ``sensors`` logs (:func:`_sensors`) and, with ``esf``, the UBX logs' ESF measurements (an
    ingest read hour by hour knows its logs have none: :func:`~cdgps_cli.io.ubx_hours.check_ubx_block`)."""
    ref_s = min(float(rx.raw["time_gps_s"].min()) for rx in inp.receivers.values())
    imu, imu_info = receiver_imu_tables({n: (inp.pieces or {}).get(n, [p]) for n, (k, p) in inp.files.items()
                                         if k == "ubx" and esf}, ref_s)
    att = sensor_attachments(sensors, ref_s, imu) if sensors or imu else None
    extra_inputs = _sensor_inputs(sensors)

    def done(s: dict) -> dict:
        if sensors or imu:
            s["sensor_logs"] = {"files": sensors + [f for a in imu_info.values() for f in a["files"]],
                                "kinds": sorted(k.split("/")[1][:-4] for k in att)}
        if imu_info:
            s["receiver_imu"] = imu_info
        return s
    return att, extra_inputs, done


def config_sensor_paths(cfg: GnssConfig) -> list:
    """The ``[gnss] sensors`` logs of a GNSS run config, resolved against its directory (globs expanded)."""
    import tomllib  # noqa: PLC0415
    from cdgps_cli.core import toml_text  # noqa: PLC0415

    from cdgps_cli.io.log_sequence import expand_paths  # noqa: PLC0415

    try:
        items = toml_text.loads(cfg.text.lstrip("\ufeff")).get("gnss", {}).get("sensors", [])
    except tomllib.TOMLDecodeError:
        return []
    items = [items] if isinstance(items, str) else items
    if not isinstance(items, list) or not all(isinstance(i, str) for i in items):
        raise CdgpsError(f"{cfg.path}: gnss.sensors: expected a file name or a list of them, got {items!r}")
    base = Path(cfg.path).parent if cfg.path and not str(cfg.path).startswith("<") else Path(".")
    return expand_paths([str(base / i) for i in items], "gnss.sensors")


def processing_obs(rx: GnssReceiver, interval_s: float | None = None) -> pd.DataFrame:
    """The receiver's observations as the solvers' table (:data:`~cdgps_cli.core.records.OBS_COLUMNS`).

    Loss-of-lock bits come from the receiver's own flags:

    * RINEX: the LLI as recorded (bit 0 slip, bit 1 half-cycle);
    * UBX: bit 0 (a new ambiguity) where the carrier lock time restarted
      (:func:`cdgps_cli.measurement.channels.ubx_restarts`: shorter than the previous lock time plus
      the time since that observation, less half an epoch interval; lock time is capped at 64.5 s)
      and where the half-cycle ambiguity became resolved (the receiver then shifts the phase by
      half a cycle); bit 1 while it is unresolved.  Rows without a valid phase keep NaN phase.
    """
    r = rx.raw
    lli = r["lli"].to_numpy(dtype=np.int64).copy()
    if rx.format == "ubx":
        lli = ubx_loss_of_lock(r["time_gps_s"].to_numpy(), r["sat"].to_numpy(), r["phase_cycles"].to_numpy(),
                               r["lock_time_ms"].to_numpy(dtype=np.float64), r["half_cycle"].to_numpy(dtype=np.int64) == 1,
                               interval_s)
    return pd.DataFrame({
        "time_gps_s": r["time_gps_s"].to_numpy(dtype=np.float64),
        "sat": r["sat"].to_numpy(dtype=object),
        "phase_l1_cycles": r["phase_cycles"].to_numpy(dtype=np.float64),
        "lli_l1": lli,
        "ssi_l1": r["ssi"].to_numpy(dtype=np.int64),
        "pseudorange_l1_m": r["pseudorange_m"].to_numpy(dtype=np.float64),
        "snr_l1_dbhz": r["snr_dbhz"].to_numpy(dtype=np.float64),
        "rx_clock_offset_s": r["clock_offset_s"].to_numpy(dtype=np.float64),
        "epoch_flag": r["epoch_flag"].to_numpy(dtype=np.int64),
    }, columns=list(OBS_COLUMNS), copy=False)   # the columns as they are: no consolidated copy of the table


def anchor_obs(rx: GnssReceiver, signals, interval_s: float | None = None) -> pd.DataFrame:
    """The solvers' table (:data:`~cdgps_cli.core.records.OBS_COLUMNS`) of the signal that anchors each
    receiver's epochs and clock (:func:`~cdgps_cli.core.signals.anchor_signal`): :func:`processing_obs`
    (GPS L1) when the signals include ``G:L1`` or there are none; otherwise the rows of the first signal
    listed (its phase in that signal's cycles, loss of lock as in :func:`signal_obs`), with the epoch
    flags and clock offsets of the receiver's GPS rows at the same time tags (0 / NaN without any)."""
    from cdgps_cli.core.signals import anchor_signal  # noqa: PLC0415

    name = anchor_signal(signals)
    if name is None:
        return processing_obs(rx, interval_s)
    s = signal_obs(rx, interval_s)
    s = s[s["signal"].to_numpy() == name] if s is not None else pd.DataFrame(columns=["time_gps_s", "sat", "phase_cycles",
                                                                                      "pseudorange_m", "lli"])
    t = s["time_gps_s"].to_numpy(dtype=np.float64)
    raw = rx.raw.drop_duplicates("time_gps_s").sort_values("time_gps_s")
    tr = raw["time_gps_s"].to_numpy(dtype=np.float64)
    k = np.clip(np.searchsorted(tr, t), 0, max(tr.size - 1, 0))
    same = (tr[k] == t) if tr.size else np.zeros(t.size, dtype=bool)
    flag = np.where(same, raw["epoch_flag"].to_numpy(dtype=np.int64)[k] if tr.size else 0, 0)
    clk = np.where(same, raw["clock_offset_s"].to_numpy(dtype=np.float64)[k] if tr.size else np.nan, np.nan)
    return pd.DataFrame({
        "time_gps_s": t, "sat": s["sat"].to_numpy(dtype=object),
        "phase_l1_cycles": s["phase_cycles"].to_numpy(dtype=np.float64),
        "lli_l1": s["lli"].to_numpy(dtype=np.int64), "ssi_l1": np.zeros(t.size, dtype=np.int64),
        "pseudorange_l1_m": s["pseudorange_m"].to_numpy(dtype=np.float64), "snr_l1_dbhz": np.full(t.size, np.nan),
        "rx_clock_offset_s": clk, "epoch_flag": flag.astype(np.int64),
    }, columns=list(OBS_COLUMNS)).reset_index(drop=True)


def signal_obs(rx: GnssReceiver, interval_s: float | None = None) -> pd.DataFrame | None:
    """The receiver's multi-signal table for the solvers: a UBX log's ``lli`` from its lock times and
    half-cycle status per satellite and signal (:func:`ubx_loss_of_lock`); a RINEX table as recorded."""
    s = rx.signals
    if s is None or "lock_time_ms" not in s:
        return s
    key = (s["sat"].astype(str) + ":" + s["signal"].astype(str)).to_numpy()
    lli = ubx_loss_of_lock(s["time_gps_s"].to_numpy(), key, s["phase_cycles"].to_numpy(),
                           s["lock_time_ms"].to_numpy(dtype=np.float64), s["half_cycle"].to_numpy() == 1, interval_s)
    return s.assign(lli=lli)


def lock_obs(rx: GnssReceiver, signals) -> pd.DataFrame:
    """What :func:`lock_summary` counts of a receiver: the time, satellite, phase and loss-of-lock columns of
    :func:`anchor_obs`, in narrow types.  A RINEX receiver's are its anchor rows as recorded (its raw table or the
    anchor signal's rows: all a receiver read hour by hour keeps, :class:`cdgps_cli.io.gnss_hours.ThinTables`); a
    UBX receiver's loss of lock comes from its lock times (:func:`ubx_loss_of_lock` of the raw table's rows or of
    the anchor signal's, with the interval of all its signal rows, as :func:`anchor_obs` takes it), the satellites
    as integer channels (a day's rows: no string per row)."""
    if rx.format != "ubx":
        r = _anchor_rows(rx, signals)
        return pd.DataFrame({"time_gps_s": r["time_gps_s"].to_numpy(dtype=np.float64), "sat": r["sat"].array,
                             "phase_l1_cycles": r["phase_cycles"].to_numpy(), "lli_l1": r["lli"].to_numpy()}, copy=False)
    from cdgps_cli.core.signals import anchor_signal  # noqa: PLC0415

    name, interval_s, r = anchor_signal(signals), None, rx.raw
    if name is not None:
        s = rx.signals if rx.signals is not None else pd.DataFrame(
            {"time_gps_s": [], "sat": [], "signal": [], "phase_cycles": [], "lli": []})
        if "lock_time_ms" in s:
            interval_s = nominal_interval_s(s["time_gps_s"].to_numpy())
        r = s[s["signal"].to_numpy() == name]
    t = r["time_gps_s"].to_numpy(dtype=np.float64)
    if name is None or "lock_time_ms" in r:
        lli = _ubx_lli(r, t, interval_s)
    else:
        lli = r["lli"].to_numpy(dtype=np.int64)
    return pd.DataFrame({"time_gps_s": t, "sat": r["sat"].array, "phase_l1_cycles": r["phase_cycles"].to_numpy(),
                         "lli_l1": lli}, copy=False)     # (the satellites as they are: a thin table's categorical)


def _ubx_lli(r: pd.DataFrame, t: np.ndarray, interval_s: float | None) -> np.ndarray:
    """:func:`ubx_loss_of_lock` of a UBX table's rows (``t``: their times), in groups of satellites of about
    :data:`_LOCK_ROWS_PER_PASS` rows (a channel's bits are its own: a day's rows are not all sorted at once, ≈ 170
    bytes a row), with one nominal interval for all of them; int8."""
    channel = pd.factorize(r["sat"], sort=True)[0].astype(np.int32)
    phase, lock_ms, half = r["phase_cycles"].to_numpy(), r["lock_time_ms"].to_numpy(), r["half_cycle"].to_numpy()
    interval_s = nominal_interval_s(t) if interval_s is None else interval_s
    n = int(channel.max()) + 1 if channel.size else 0
    lli = np.zeros(t.size, dtype=np.int8)
    for a, b in _channel_groups(np.bincount(channel, minlength=n)):
        g = np.flatnonzero((channel >= a) & (channel < b)) if (a, b) != (0, n) else slice(None)
        lli[g] = ubx_loss_of_lock(t[g], channel[g], phase[g], lock_ms[g].astype(np.float64),
                                  half[g].astype(np.int64) == 1, interval_s)
    return lli


def lock_summary(rx: GnssReceiver, obs: pd.DataFrame | None = None) -> dict:
    """Lock counters of a receiver per satellite: phase rows, slips (LLI bit 0 after the first row:
    RINEX flags or u-blox lock-time restarts), half-cycle-flagged rows, and arcs — the lock segments
    of :func:`cdgps_cli.measurement.channels.lock_segments` over the receiver's own epochs: a slip flag, or an
    epoch the receiver logged without this satellite; an epoch it did not log at all (a base logging with gaps)
    cuts nothing.  That is the double differences' rule (``differencing.ambiguity_segments``' own outages); until
    session 29 every gap over 1.5 intervals cut an arc here (a real u-blox M8P base: 1432 arcs, G01 112 without
    a slip)."""
    o = processing_obs(rx) if obs is None else obs
    ph = np.isfinite(o["phase_l1_cycles"].to_numpy())
    t = o["time_gps_s"].to_numpy()[ph]
    lli = o["lli_l1"].to_numpy()[ph]
    codes, sats = pd.factorize(o["sat"][ph], sort=True)      # (a categorical column: its codes, no strings made)
    codes = codes.astype(np.int32)
    epoch = _epoch_index(t)                                  # the receiver's own epochs: a step of 1 within an arc
    max_step = 1.0
    n = len(sats)
    rows = np.bincount(codes, minlength=n)
    slips, half, arcs = np.zeros(n), np.bincount(codes, weights=((lli & 2) != 0).astype(float), minlength=n), np.zeros(n)
    for a, b in _channel_groups(rows):       # satellites in groups: a day's rows are not all cut at once
        g = (codes >= a) & (codes < b) if (a, b) != (0, n) else slice(None)
        c, lg = codes[g], lli[g]
        seg = lock_segments(c, epoch[g], slip=(lg & 1) != 0, max_step=max_step)
        slips += np.bincount(c, weights=(((lg & 1) != 0) & (seg.cause != FIRST)).astype(float), minlength=n)
        arcs += np.bincount(seg.channel, minlength=n)
    return {str(s): {"rows": int(rows[i]), "slips": int(slips[i]), "half_cycle_rows": int(half[i]), "arcs": int(arcs[i])}
            for i, s in enumerate(sats)}


def _epoch_index(t: np.ndarray) -> np.ndarray:
    """Each row's index among the distinct times ``t`` holds (rows in time order: one pass; else sorted)."""
    if t.size and bool(np.all(t[1:] >= t[:-1])):
        return np.searchsorted(distinct_times(t), t).astype(np.int64)
    return np.unique(t, return_inverse=True)[1].astype(np.int64)


_LOCK_ROWS_PER_PASS = 500_000
"""Rows :func:`lock_summary` cuts into lock segments, and :func:`_ubx_lli` gives :func:`ubx_loss_of_lock`, at a time
(whole satellites; ≈ 60 and ≈ 170 bytes a row)."""


def _channel_groups(rows: np.ndarray, per_pass: int | None = None) -> list:
    """Consecutive channel ranges [a, b) holding about ``per_pass`` rows each (default
    :data:`_LOCK_ROWS_PER_PASS`; a channel is never split: its lock segments are its own)."""
    per_pass = _LOCK_ROWS_PER_PASS if per_pass is None else per_pass
    out, a, acc = [], 0, 0
    for i, r in enumerate(rows.tolist()):
        if acc and acc + r > per_pass:
            out.append((a, i))
            a, acc = i, 0
        acc += r
    return out + [(a, rows.size)]


def _anchor_rows(rx: GnssReceiver, signals) -> pd.DataFrame:
    """The rows (``time_gps_s``, ``sat``, ``phase_cycles``) that anchor the receiver's epochs: its GPS L1
    table, or the rows of :func:`~cdgps_cli.core.signals.anchor_signal`."""
    from cdgps_cli.core.signals import anchor_signal  # noqa: PLC0415

    name = anchor_signal(signals)
    if name is None or rx.signals is None:
        return rx.raw
    return rx.signals[rx.signals["signal"].to_numpy() == name]


def _check_coverage(inp: IngestInputs, signals=()) -> None:
    """Refuse a receiver none of whose phases has a healthy ephemeris; warn about the rows without one."""
    receivers, nav, files, warnings = inp.receivers, inp.nav, inp.files, inp.warnings
    for n, rx in receivers.items():
        a = _anchor_rows(rx, signals)
        r = a[np.isfinite(a["phase_cycles"].to_numpy(dtype=float))]
        cov = ephemeris_coverage(nav, r["sat"].to_numpy(), r["time_gps_s"].to_numpy())
        if not cov.any():
            tn = nav["toe_gps_s"].to_numpy()
            raise CdgpsError(
                f"the navigation data do not cover the observations of {n} ({files[n][1]}): observations "
                f"{span_text(r['time_gps_s'])}, broadcast ephemerides with toe {span_text(tn)} (each is used within ±2 h of "
                f"its toe, healthy satellites only) in {', '.join(map(str, inp.nav_list)) or inp.nav_source or 'the run'}; give the "
                f"navigation file(s) of that day")
        if not cov.all():
            miss = pd.Series(r["sat"].to_numpy()[~cov]).value_counts()
            warnings.append(f"{n}: {int(miss.sum())} of {len(r)} phase observations ({', '.join(sorted(miss.index)[:8])}"
                            f"{' …' if len(miss) > 8 else ''}) have no healthy ephemeris within ±2 h; they will not be used")


def _pairing(tm, tr, cfg: GnssConfig) -> dict:
    """A rover's epochs paired with the master's (:func:`~cdgps_cli.measurement.epoch_pairing.pair_epochs`:
    the rover drives, master epochs within ``sync_tol_s`` simultaneous, bridged up to ``max_age_s``)."""
    return pair_epochs(tr, tm, sync_tol_s=cfg.sync_tol_s, max_age_s=cfg.max_age_s).summary


def _common_epochs(cfg: GnssConfig, inp: IngestInputs) -> dict:
    """Rover → its epochs paired with the master's; refuses a rover with none, warns about every
    rover epoch that will not be used (with the reason)."""
    receivers, master, files, warnings = inp.receivers, inp.master, inp.files, inp.warnings
    rovers = [n for n in receivers if n != master]
    tm = distinct_times(_anchor_rows(receivers[master], cfg.signals)["time_gps_s"].to_numpy())
    common = {}
    for n in rovers:
        tr = distinct_times(_anchor_rows(receivers[n], cfg.signals)["time_gps_s"].to_numpy())
        ps = _pairing(tm, tr, cfg)
        if ps["used"] == 0:
            raise CdgpsError(
                f"no common epochs: master {master} ({files[master][1]}) has {tm.size} epochs ({span_text(tm)}), rover {n} "
                f"({files[n][1]}) has {tr.size} ({span_text(tr)}); no rover epoch has a master epoch within "
                f"{cfg.max_age_s:g} s (gnss.max_age_s)")
        _check_common_satellites(master, n, receivers, files)
        common[n] = {"common_epochs": ps["used"], "master_epochs": int(tm.size), "rover_epochs": int(tr.size),
                     "tolerance_ms": cfg.sync_tol_s * 1e3, "pairing": ps}
        if ps["dropped"]:
            warnings.append(f"{n}: {sum(ps['dropped'].values())} of {tr.size} epochs have no master epoch within "
                            f"{cfg.max_age_s:g} s (gnss.max_age_s) and will not be used: "
                            + "; ".join(f"{k} {why}" for why, k in ps["dropped"].items()))
    return common


def _phase_satellites(rx: GnssReceiver) -> set:
    """Satellites with a carrier phase in a receiver's raw (L1) table or its signal table."""
    out = set()
    for t in (rx.raw, rx.signals):
        if t is not None and len(t):
            sats = t["sat"].to_numpy()[np.isfinite(t["phase_cycles"].to_numpy(dtype=float))]
            out |= {str(s) for s in pd.unique(sats)}        # (a day's rows: their few names, not a string each)
    return out


def _check_common_satellites(master: str, rover: str, receivers: dict, files: dict) -> None:
    """Refuse a rover that has carrier phase of no satellite the master also tracks (no double difference
    can ever be formed), naming both files and what each tracks."""
    sm, sr = _phase_satellites(receivers[master]), _phase_satellites(receivers[rover])
    if sm and sr and not sm & sr:
        def few(s):
            s = sorted(s)
            return " ".join(s[:12]) + (f" … ({len(s)})" if len(s) > 12 else "")
        raise CdgpsError(f"no common satellites: master {master} ({files[master][1]}) has carrier phase of {few(sm)}; "
                         f"rover {rover} ({files[rover][1]}) of {few(sr)}; a double difference needs satellites "
                         f"tracked by both receivers")


def run_info(path: str | Path, deep: bool = False) -> dict:
    """``cdgps info``: :func:`cdgps_cli.io.run.run_info` with the model's counts: for a structure run
    each channel's lock restarts (:func:`cdgps_cli.pipeline.ingest.channel_summary`), for a GNSS run
    each receiver's lock counters (:func:`lock_summary`) and the epochs each rover has in common
    with the master (``gnss.common_epochs``: rover → count).  ``deep``: decode every message
    (``cdgps info --deep``)."""
    from cdgps_cli.io.run import run_info as file_info  # noqa: PLC0415

    from cdgps_cli.pipeline.ingest import channel_summary  # noqa: PLC0415

    return file_info(path, gnss_common_epochs=_run_common_epochs,
                     gnss_lock_summary=lambda rx, signals: lock_summary(rx, anchor_obs(rx, signals)),
                     channel_summary=channel_summary, deep=deep)


def _run_common_epochs(run: gnss_run.GnssRun) -> dict:
    """Rover → its epoch pairing with the master of a GNSS run read back (epochs used, bridged, dropped)."""
    tm = np.unique(_anchor_rows(run.receivers[run.master], run.cfg.signals)["time_gps_s"].to_numpy())
    common = {}
    for n in run.rovers:
        tr = np.unique(_anchor_rows(run.receivers[n], run.cfg.signals)["time_gps_s"].to_numpy())
        common[n] = _pairing(tm, tr, run.cfg)
    return common


def starter_gnss_config(rinex: dict, ubx: dict | None = None, nav_paths=(), master: str | None = None, *,
                        signals="auto", **kwargs) -> str:
    """:func:`cdgps_cli.io.gnss_run.starter_gnss_config` with a single-point position for a UBX
    master whose log has no RTCM 1005/1006 (:func:`spp_master_position`) and ``signals``: "auto" — every
    signal all receivers hold whose system has ephemerides in the navigation files (or the u-blox logs'
    RXM-SFRBX), as ``cdgps rtk --signals auto`` (:func:`cdgps_cli.pipeline.gnss_multi.common_signals`;
    systems without ephemerides named in ``kwargs["warnings"]``) — or a list of signal names."""
    signals = chosen_signals(signals, rinex, ubx, nav_paths, kwargs.get("warnings"))
    return gnss_run.starter_gnss_config(rinex, ubx, nav_paths, master, master_position=spp_master_position,
                                        master_header_check=master_header_check, receiver_position=receiver_position,
                                        signals=signals, **kwargs)


def chosen_signals(signals, rinex: dict | None, ubx: dict | None, nav_paths, warnings: list | None) -> list | None:
    """A ``--signals`` option of ``config`` and ``ingest``: "auto" (:func:`auto_signals`), or a list of known,
    distinct signal names (CdgpsError naming what is not)."""
    if signals == "auto":
        return auto_signals(rinex, ubx, nav_paths, warnings)
    from cdgps_cli.core.signals import SIGNALS  # noqa: PLC0415

    bad = [x for x in signals or () if x not in SIGNALS]
    if bad or not signals:
        raise CdgpsError(f"--signals: expected 'auto' or signal names, got {', '.join(map(repr, bad)) or 'none'} "
                         f"(known: {', '.join(SIGNALS)})")
    twice = sorted({x for x in signals if list(signals).count(x) > 1})
    if twice:
        raise CdgpsError(f"--signals: {', '.join(twice)} given twice")
    return list(signals)


def auto_signals(rinex: dict | None, ubx: dict | None, nav_paths, warnings: list | None) -> list | None:
    """``--signals auto`` of ``config`` and of ``ingest`` without a config: every signal all receivers hold whose
    system has ephemerides in the navigation files (or the u-blox logs' RXM-SFRBX) and whose phase their records
    hold, as ``cdgps rtk --signals auto`` (:func:`cdgps_cli.pipeline.gnss_multi.common_signals`,
    :func:`~cdgps_cli.pipeline.gnss_multi.recorded_signals`); an antenna's files (a list, a quoted glob pattern) are
    read together.  None when no signal has ephemerides (the GPS L1 path, whose checks then say what is missing);
    what is left out is said in ``warnings``."""
    from cdgps_cli.pipeline.gnss_multi import common_signals, recorded_signals  # noqa: PLC0415

    files = {n: expand_paths([str(q) for q in (p if isinstance(p, (list, tuple)) else [p])], f"--{kind} {n}")
             for kind, d in (("rinex", rinex), ("ubx", ubx)) for n, p in (d or {}).items()}
    said: list = []
    try:
        signals = common_signals(files, list(nav_paths), said) if files else None
        if signals:
            signals = recorded_signals({n: files[n] for n in rinex or {}}, signals, said)
    except CdgpsError:
        signals, said = None, []
    if warnings is not None:
        warnings.extend(said)
    return signals


def spp_master_position(name: str, path, rx: "gnss_run.GnssReceiver", nav_paths, ubx_rx: dict) -> tuple:
    """Mean single-point position of a UBX master without RTCM 1005/1006, from the nav files or
    the logs' SFRBX ephemerides; an error naming both sources when there are no ephemerides."""
    if nav_paths:
        nav = gnss_run.merge_nav(nav_paths)
    else:
        navs = [r.nav for r in ubx_rx.values() if r.nav is not None and len(r.nav)]
        if not navs:
            raise CdgpsError(f"{path}: no base position for master {name}: the log has no RTCM 1005/1006 message, and "
                             f"no ephemerides for a single-point position (no RXM-SFRBX GPS subframes in the UBX logs "
                             f"and no --nav file); give --nav, or write position_ecef_m in the config yourself")
        nav = gnss_run._merge_nav_tables(navs)
    return tuple(float(v) for v in _raw_single_point(rx.raw, nav, f"{path} ({name})"))


def _raw_single_point(raw: pd.DataFrame, nav: pd.DataFrame, what: str, x0=None,
                      max_epochs: int | None = None) -> np.ndarray:
    """A receiver's static single-point position (ECEF m, :func:`~cdgps_cli.model.gps.positioning.spp_spread`) from
    the GPS L1 pseudoranges of its raw table (:data:`~cdgps_cli.io.gnss_run.RAW_COLUMNS`)."""
    x = spp_spread(raw["sat"].to_numpy(), raw["time_gps_s"].to_numpy(), raw["pseudorange_m"].to_numpy(), nav,
                   x0_ecef_m=x0, max_epochs=max_epochs, what=what)
    if x is None:
        raise CdgpsError(f"{what}: no L1 pseudorange covered by the navigation data for a single-point position")
    return x


def first_epochs_position(inp: "gnss_run.IngestInputs", name: str) -> np.ndarray | None:
    """A rover's nominal position at ingest when neither the config nor its header gives one: the pseudorange
    single-point position of its record's first :data:`HEADER_CHECK_EPOCHS` epochs (ECEF m; good to a few metres),
    seeded at the master's position, so that every window of the run (``init --start``, ``cdgps batch``) refers its
    displacement states to the same point (each window's own single-point position moved them by metres: a sweep
    of the real M8P pair's 5-minute windows); None without navigation data or a solution (``init`` then places it)."""
    if inp.nav is None or name not in inp.receivers:
        return None
    raw = (inp.first_rows or {}).get(name)
    raw = gnss_run.first_epoch_rows(inp.receivers[name].raw, HEADER_CHECK_EPOCHS) if raw is None else raw
    if not len(raw):
        return None
    mh = inp.receivers[inp.master].header
    x0 = antenna_reference_point_m(mh, str(inp.files[inp.master][1])) if isinstance(mh, dict) else None
    try:
        return _raw_single_point(raw, inp.nav, f"{inp.files[name][1]} ({name})", x0)
    except CdgpsError:
        return None


def _spp_near(rx: "gnss_run.GnssReceiver", nav_paths, x0, what: str):
    """The receiver's single-point position (ECEF m) over its first :data:`HEADER_CHECK_EPOCHS` epochs, seeded at
    ``x0`` and, when that fails, at the Earth's centre (a header thousands of km off leaves too few satellites above
    the mask seen from there); None without navigation files, GPS L1 pseudoranges or a solution."""
    if not nav_paths or not len(rx.raw):
        return None
    nav = gnss_run.merge_nav(nav_paths)
    for seed in (x0, None):
        try:
            return _raw_single_point(rx.raw, nav, what, seed, HEADER_CHECK_EPOCHS)
        except CdgpsError:
            continue
    return None


def receiver_position(name: str, path, rx: "gnss_run.GnssReceiver", nav_paths):
    """Where ``init`` puts a receiver's antenna before it solves (ECEF m, or None): its header position (APPROX
    POSITION XYZ plus ANTENNA: DELTA H/E/N), else — or when that is more than
    :data:`~cdgps_cli.config.options.HEADER_POSITION_TOL_M` from it — its single-point position."""
    xh = antenna_reference_point_m(rx.header, str(path)) if isinstance(rx.header, dict) else None
    spp = _spp_near(rx, nav_paths, xh, f"{path} ({name})")
    if spp is None or (xh is not None and float(np.linalg.norm(spp - xh)) <= HEADER_POSITION_TOL_M):
        return xh
    return spp


def master_header_check(name: str, path, rx: "gnss_run.GnssReceiver", nav_paths) -> tuple | None:
    """For ``cdgps config``: a warning when a RINEX master's antenna position from its header (APPROX POSITION XYZ
    plus ANTENNA: DELTA H/E/N) is more than :data:`~cdgps_cli.config.options.HEADER_POSITION_TOL_M` from its
    single-point position (:data:`~cdgps_cli.config.options.HEADER_CHECK_EPOCHS` epochs) — ``init`` and ``rtk``
    refuse such a master — (the warning, the config's comment) —; None when it is within, or when no single-point
    position can be made (no navigation files, no GPS L1 pseudoranges they cover)."""
    xm = antenna_reference_point_m(rx.header, str(path))
    if xm is None:
        return None
    spp = _spp_near(rx, nav_paths, xm, f"{path} ({name})")
    if spp is None:
        return None
    off = float(np.linalg.norm(spp - xm))
    if off <= HEADER_POSITION_TOL_M:
        return None
    where = f"is {off / 1e3:.4g} km from its pseudorange single-point position ({' '.join(f'{v:.1f}' for v in spp)})"
    return (f"{path} ({name}, the master): its header position (APPROX POSITION XYZ) {where}; 'cdgps init' and "
            f"'cdgps rtk' refuse such a master: write its surveyed position as position_ecef_m in "
            f"[gnss.antennas.\"{name}\"] (the single-point position is good to a few metres)",
            f"the header's APPROX POSITION XYZ {where}: init and rtk refuse it; write the surveyed position_ecef_m "
            f"below")
