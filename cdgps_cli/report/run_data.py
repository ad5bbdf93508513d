"""A STATES.mcap read for the run report: every array a report plots, in chunks of epochs.

:class:`StatesBlocks` reads what :class:`cdgps_cli.io.states.StatesChunks` reads (the description,
``time_s`` and ``xi``) and, beside them, the position covariances, NIS and its dof, the residuals
per channel and the series' further arrays, each as a :class:`cdgps_cli.io.packed_arrays.PackedRows`
(decompressed once into an unlinked temporary file, then read a block of rows at a time): memory
holds one block, whatever the record's length.  The file's integrity is checked first, as every
cdgps reader checks it.  Files of the earlier layouts (no packed arrays) are read whole by
:class:`cdgps_cli.io.states.States` and cut.  It also serves as the ``states`` of
:func:`cdgps_cli.report.sensor_reports.spectra_result` (``chunks``, ``n_epochs``, ``cfg``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.mcap import CONFIG_ATTACHMENT, open_verified, read_span
from cdgps_cli.io.states import INIT_ATTACHMENT, STATE_TOPIC, States, coordinate_sigma, rows_q
from cdgps_cli.io.states_header import states_spans
from cdgps_cli.io.states_layout import OUTPUT_MAP_PACKED, PACKED_PREFIX, RESIDUAL_PACKED, SERIES_ATTACHMENT

#: the single-epoch (kinematic) solutions of a GNSS run, arrays only, with ``n_sat`` and ``pdop``
KINEMATIC_TOPIC = "/cdgps/kinematic"
_SMALL = (CONFIG_ATTACHMENT, SERIES_ATTACHMENT, OUTPUT_MAP_PACKED, INIT_ATTACHMENT, RESIDUAL_PACKED + "channels.json")


def from_triu(T: np.ndarray, m: int) -> np.ndarray:
    """Symmetric (k, m, m) from the upper triangles (k, m(m+1)/2), row by row."""
    i, j = np.triu_indices(m)
    P = np.empty((T.shape[0], m, m))
    P[:, i, j] = T
    P[:, j, i] = T
    return P


class StatesBlocks:
    """One state series of a STATES.mcap with its diagnostics, read in blocks of epochs.

    Attributes
    ----------
    path, kind, cfg, coord_names, coord_units, output_map, n_pos, metadata : as :class:`States`
    n_epochs : int
    channels : list of (antenna, transmitter) — the residual columns
    init : dict or None — the INIT.json the estimate started from (attached to the file)
    has_covariance : bool — P_ξ (or σ_q) is stored for the series
    """

    _describe = States._describe
    coordinate_model = States.coordinate_model
    config_name = States.config_name
    config_sha256 = States.config_sha256

    def __init__(self, path: str | Path, topic: str = STATE_TOPIC):
        from cdgps_cli.io.packed_arrays import PackedRows  # noqa: PLC0415

        self.path = str(path)
        self._rows, self._whole, self.init, self.channels = {}, None, None, []
        key = f"{PACKED_PREFIX}{topic}/"
        with open_verified(path) as (_reader, fh, info, summary):
            self.metadata, spans = states_spans(path, fh, info, summary)
            small = {n: read_span(fh, *spans[n])(spans[n][1]) for n in _SMALL if n in spans}
            self._describe(small)
            self._small_json(small)
            if key + "time_s" not in spans:
                self._whole = States(path, topic)
                self.n_epochs = len(self._whole.time_s)
                return
            wanted = {"time_s": key + "time_s", "xi": key + "xi"}
            for name in ("P_xi_triu", "P_xi", "sigma_q"):
                if key + name in spans:
                    wanted["cov"] = key + name
                    self._cov_kind = name
                    break
            for name in ("nis", "nis_dof", "residual_m"):       # the estimate's own series' (not a side series')
                if topic == STATE_TOPIC and RESIDUAL_PACKED + name in spans:
                    wanted[name] = RESIDUAL_PACKED + name
            for name in self._series.get(topic, {}).get("extra", []):
                wanted["extra:" + name] = key + name
            try:
                for name, att in wanted.items():
                    self._rows[name] = PackedRows(read_span(fh, *spans[att]), spans[att][1], f"{path}: {att}")
            except (KeyError, ValueError) as exc:
                self.close()
                raise CdgpsError(f"{path}: damaged state arrays: {exc}") from None
        self.n_epochs = self._rows["time_s"].n_rows
        bad = [n for n, r in self._rows.items() if r.n_rows != self.n_epochs]
        if bad:
            self.close()
            raise CdgpsError(f"{path}: damaged state arrays ({', '.join(bad)} not of {self.n_epochs} epochs)")

    def _small_json(self, small: dict) -> None:
        try:
            if INIT_ATTACHMENT in small:
                self.init = json.loads(small[INIT_ATTACHMENT])
            if RESIDUAL_PACKED + "channels.json" in small:
                self.channels = [tuple(c) for c in json.loads(small[RESIDUAL_PACKED + "channels.json"])]
        except ValueError as exc:
            raise CdgpsError(f"{self.path}: damaged {INIT_ATTACHMENT} or residual channel list: {exc}") from None

    @property
    def series_names(self) -> list:
        """The state series the file holds (``/cdgps/state``, ``/cdgps/state_filtered``, …)."""
        return sorted(getattr(self, "_series", {}) or {})

    @property
    def has_covariance(self) -> bool:
        return "cov" in self._rows if self._whole is None else self._whole.sigma_q is not None

    @property
    def extra_names(self) -> list:
        if self._whole is not None:
            return sorted(self._whole.extra)
        return sorted(n[len("extra:"):] for n in self._rows if n.startswith("extra:"))

    def close(self) -> None:
        """Remove the temporary files."""
        for r in self._rows.values():
            r.close()

    def __enter__(self) -> "StatesBlocks":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def chunks(self, epochs: int):
        """``(time_s (k,), q (k, n_q))`` blocks, as :meth:`cdgps_cli.io.states.StatesChunks.chunks`."""
        if self._whole is not None:
            for b in self._whole_blocks(epochs):
                yield b["time_s"], b["q"]
            return
        for t, xi in zip(self._rows["time_s"].chunks(epochs), self._rows["xi"].chunks(epochs)):
            yield t.astype(float, copy=False), rows_q(self.output_map, xi.reshape(len(t), self.n_pos))

    def blocks(self, epochs: int):
        """Consecutive blocks of at most ``epochs`` epochs, first to last: dicts with ``start``
        (index of the first epoch), ``time_s`` (k,), ``q`` (k, n_q), ``xi`` (k, n_pos), ``P_xi``
        (k, n_pos, n_pos) or None, ``sigma_q`` (k, n_q) or None, ``nis``, ``nis_dof`` (k,) or None,
        ``residual_m`` (k, C) or None and ``extra`` {name: (k, …)}."""
        if self._whole is not None:
            yield from self._whole_blocks(epochs)
            return
        names = list(self._rows)
        start = 0
        for parts in zip(*(self._rows[n].chunks(epochs) for n in names)):
            d = dict(zip(names, parts))
            k = len(d["time_s"])
            xi = d["xi"].reshape(k, self.n_pos).astype(float, copy=False)
            out = {"start": start, "time_s": d["time_s"].astype(float, copy=False), "xi": xi,
                   "q": rows_q(self.output_map, xi), "P_xi": None, "sigma_q": None,
                   "nis": d.get("nis"), "nis_dof": None if "nis_dof" not in d else d["nis_dof"].astype(float),
                   "residual_m": None if "residual_m" not in d else d["residual_m"].reshape(k, -1).astype(float),
                   "extra": {n[len("extra:"):]: v for n, v in d.items() if n.startswith("extra:")}}
            if "cov" in d:
                if self._cov_kind == "sigma_q":
                    out["sigma_q"] = d["cov"].reshape(k, -1)
                else:
                    P = from_triu(d["cov"], self.n_pos) if self._cov_kind == "P_xi_triu" else \
                        d["cov"].reshape(k, self.n_pos, self.n_pos)
                    out["P_xi"], out["sigma_q"] = P, coordinate_sigma(self.output_map, P)
            start += k
            yield out

    def _whole_blocks(self, epochs: int):
        w = self._whole
        res = None
        for a in range(0, self.n_epochs, epochs):
            s = slice(a, a + epochs)
            yield {"start": a, "time_s": w.time_s[s], "q": w.q[s], "xi": w.xi[s],
                   "P_xi": None if w.P_xi is None else w.P_xi[s],
                   "sigma_q": None if w.sigma_q is None else w.sigma_q[s],
                   "nis": None if w.nis is None else w.nis[s], "nis_dof": None if w.nis_dof is None else w.nis_dof[s],
                   "residual_m": res, "extra": {n: v[s] for n, v in w.extra.items()}}

