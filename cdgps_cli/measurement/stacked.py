"""Several measurement models as one (architecture.md "Next": measurement models stack).

Each part keeps its own epochs (multi-rate: an epoch where a part has no rows contributes nothing
of it) and its own state columns, a prefix of the stacked state (the satellite DDs on [ξ, ξ̇], a
sensor also on d and its bias columns, :func:`cdgps_cli.measurement.sensor.place`); H of a part is
padded with zeros to ``n_state``.  The noise of one epoch is block-diagonal over the parts
(independent sensors): diagonal σ when every part's is, else the Cholesky factor of the blocks.
Rows are labelled (part name, *the part's label*); segment columns are numbered in order of first
appearance of (part, part's column).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from cdgps_cli.measurement.model import MeasurementModel, Rows

__all__ = ["Stacked"]


class Stacked(MeasurementModel):
    """Parameters: ``parts`` list of (name, MeasurementModel) with equal ``n_epochs``; ``n_state``
    (default: the largest part's)."""

    def __init__(self, parts, n_state: int | None = None):
        self.names = [str(n) for n, _ in parts]
        self.parts = [m for _, m in parts]
        sizes = {m.n_epochs for m in self.parts}
        if len(sizes) != 1:
            raise ValueError(f"Stacked: the parts cover different numbers of epochs {sorted(sizes)}")
        self.n_epochs = sizes.pop()
        self.n_state = max(m.n_state for m in self.parts) if n_state is None else int(n_state)
        if any(m.n_state > self.n_state for m in self.parts):
            raise ValueError("Stacked: a part has more states than the stack")
        self.segment_keys: list = []
        self._col: dict = {}

    def _column(self, p: int, c: int) -> int:
        if c < 0:
            return -1
        key = (p, c)
        if key not in self._col:
            self._col[key] = len(self.segment_keys)
            self.segment_keys.append((self.names[p], self.parts[p].segment_keys[c]))
        return self._col[key]

    def rows(self, k: int) -> Rows | None:
        got = [(p, r) for p, m in enumerate(self.parts) if (r := m.rows(k)) is not None and r.z_m.size]
        if not got:
            return None
        part = np.concatenate([np.full(r.z_m.size, p) for p, r in got])
        local = np.concatenate([np.arange(r.z_m.size) for _, r in got])
        subs = np.empty(part.size, dtype=object)
        i = 0
        for _, r in got:
            for j in range(r.z_m.size):
                subs[i + j] = r
            i += r.z_m.size
        labels = [(self.names[p], *(lb if isinstance(lb, tuple) else (lb,))) for p, r in got for lb in r.labels]
        seg = np.array([self._column(p, int(s)) for p, r in got for s in r.segment], dtype=np.int64)
        z = np.concatenate([r.z_m for _, r in got])
        if all(r.chol_m is None for _, r in got):
            return Rows(z, labels, seg, sigma_m=np.concatenate([r.sigma_m for _, r in got]), context=(part, local, subs))
        L = block_diag(*[r.chol_m if r.chol_m is not None else np.diag(r.sigma_m) for _, r in got])
        return Rows(z, labels, seg, chol_m=L, context=(part, local, subs))

    def predict(self, x, rows: Rows):
        part, local, subs = rows.context
        x = np.asarray(x, dtype=float)
        h = np.zeros(part.size)
        H = np.zeros((part.size, self.n_state))
        for p in dict.fromkeys(part.tolist()):
            sel = np.flatnonzero(part == p)
            sub = subs[sel[0]]
            mine = local[sel]
            if mine.size != sub.z_m.size or np.any(mine != np.arange(sub.z_m.size)):
                sub = sub.subset(mine)
            m = self.parts[p]
            hp, Hp = m.predict(x[:m.n_state], sub)
            h[sel] = hp
            H[np.ix_(sel, np.arange(Hp.shape[1]))] = Hp
        return h, H
