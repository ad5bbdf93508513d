"""The one forward driver of the estimation engine (../shared/design/architecture.md, "Next"):
``drive(dynamics, models, source, init, hooks, sink)``.

Every forward filter of the package is this loop over epochs with the measurement model(s)
injected; what differs between the pseudolite testbed, the far-field 1995 structure and the GNSS
paths is which :class:`~cdgps_cli.measurement.model.MeasurementModel` s give the rows, which
dynamics predict, and which integrity hooks run.  One epoch k:

1. ``spans(ctx, k)`` (optional): a compiled kernel runs the epochs no hook claims from k on and
   returns the first epoch that needs this loop (its stop codes are the hooks' contract);
2. ``sink.release_before(k)``: the sink may drop from memory the chunks it is done with;
3. prediction into k (k > 0): ``dynamics.step_into(k)`` → (A or None for the identity, Q, known
   input or None), :meth:`~cdgps_cli.estimation.kalman.StepFilter.predict`;
4. ``hook.before_rows(ctx, k)`` for every hook, in order (lock restart, rest / zero-velocity update);
5. ``model.prepare(k, ctx)`` for the models that have it (evaluate h(x̄) once for the epoch's
   hooks), then ``hook.prepared(ctx, k)`` (new bias states, re-bias);
6. per model, ``rows = model.rows(k)``, passed through every ``hook.gate(ctx, k, model, rows)``
   (the outlier gate; returns the rows kept or None), then the engine's information-form update
   :meth:`~cdgps_cli.estimation.kalman.StepFilter.update` (``max_iterations``: 1 is the EKF) and
   ``hook.updated(ctx, k, model, rows, nis)`` (post-fit residuals, the NIS test);
7. ``sink.write(k, x, P)`` (and ``sink.transition(k, A, Q)`` / ``sink.rows(k, rows)`` when the sink
   has them);
8. ``hook.after(ctx, k, k_next)`` → the next epoch (batch re-initialization may jump ahead).

Hooks are plain objects with any of those methods (:class:`Hook` documents them).  Several models
in one epoch are applied one after the other (sequential updates: the joint update for
independent noises), which is also how a multi-rate sensor enters: its model returns None at the
epochs where it has no rows.

Sinks: :class:`HistorySink` keeps x_k, P_k in arrays from a ``history``
(:class:`~cdgps_cli.estimation.history.MemoryHistory`, or the disk-backed
:class:`cdgps_cli.io.scratch.DiskHistory` that ``cdgps estimate`` passes), releasing chunks behind the
filter; the RTS smoother reads them back (:func:`cdgps_cli.estimation.smoother.rts_smooth` with
``chunk``).  :class:`RecordingSink` keeps the per-epoch transitions and rows too (what
:func:`cdgps_cli.estimation.model_filter.filter_numpy` returns).

Sources: an :class:`EpochGrid` gives the epoch times and the chunking; measurement models index
their rows by the source's epoch number.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cdgps_cli.estimation.history import MemoryHistory
from cdgps_cli.estimation.kalman import StepFilter

__all__ = ["EpochGrid", "Hook", "RowsGate", "DriveContext", "HistorySink", "RecordingSink", "GridDynamics", "drive"]


@dataclass
class EpochGrid:
    """The epochs a drive runs over: times (N,) s and the chunk length (epochs) of its sink."""

    time_s: np.ndarray
    chunk_epochs: int = 1 << 30

    @property
    def n_epochs(self) -> int:
        return len(self.time_s)


class Hook:
    """Integrity hook of :func:`drive` (every method optional; these defaults do nothing).

    ``before_rows(ctx, k)`` after the prediction; ``prepared(ctx, k)`` after the models' ``prepare``;
    ``gate(ctx, k, model, rows) -> rows or None`` before the update; ``updated(ctx, k, model, rows,
    nis)`` after it; ``after(ctx, k, k_next) -> k_next`` once the epoch is stored.
    """

    def before_rows(self, ctx: "DriveContext", k: int) -> None:
        return None

    def prepared(self, ctx: "DriveContext", k: int) -> None:
        return None

    def gate(self, ctx: "DriveContext", k: int, model, rows):
        return rows

    def updated(self, ctx: "DriveContext", k: int, model, rows, nis: float) -> None:
        return None

    def after(self, ctx: "DriveContext", k: int, k_next: int) -> int:
        return k_next


class RowsGate(Hook):
    """A ``rows_hook(k, rows, x, P) -> rows or None`` (e.g.
    :func:`cdgps_cli.estimation.model_filter.outlier_gate`) as a hook's ``gate``."""

    def __init__(self, fn):
        self.fn = fn

    def gate(self, ctx, k, model, rows):
        return self.fn(k, rows, ctx.x, ctx.P)


@dataclass
class DriveContext:
    """What the hooks see: the filter's step (x, P), the source, the sink, per-epoch NIS and its dof."""

    step: StepFilter
    source: EpochGrid
    sink: object
    nis: np.ndarray
    nis_dof: np.ndarray
    progress: object = None
    extra: dict = field(default_factory=dict)

    @property
    def x(self) -> np.ndarray:
        return self.step.x

    @x.setter
    def x(self, value) -> None:
        self.step.x = value

    @property
    def P(self) -> np.ndarray:
        return self.step.P

    @P.setter
    def P(self, value) -> None:
        self.step.P = value


class HistorySink:
    """x_k (N, p) and P_k (N, p, p) in arrays of a ``history`` (in memory or on disk), released chunk
    by chunk behind the filter (``chunk_epochs``); the smoother reads them back.  Its ``nis`` (N,) and
    ``nis_dof`` (N,) are the drive's (a compiled span writes them too)."""

    def __init__(self, n_epochs: int, p: int, history=None, chunk_epochs: int = 1 << 30, lead: int = 0):
        self.history = history if history is not None else MemoryHistory()
        self.on_disk = bool(getattr(self.history, "on_disk", False))
        self.chunk = max(int(chunk_epochs), 1)
        # in memory, ``lead`` rows before the first epoch for what the caller puts in front (INIT's
        # window): xs_lead / Ps_lead hold them and xs / Ps are the epochs' rows (views, C-contiguous)
        lead = 0 if self.on_disk else int(lead)
        self.xs_lead = self.history.empty((lead + n_epochs, p))
        self.Ps_lead = self.history.empty((lead + n_epochs, p, p))
        self.xs, self.Ps = self.xs_lead[lead:], self.Ps_lead[lead:]
        self.nis = np.full(n_epochs, np.nan)
        self.nis_dof = np.zeros(n_epochs, dtype=np.int64)
        self.released_to = 0
        self.also = ()          # further (N, …) arrays the owner keeps on the history, released alike

    def write(self, k: int, x: np.ndarray, P: np.ndarray) -> None:
        self.xs[k] = x
        self.Ps[k] = P

    def release_before(self, k: int) -> None:
        """Drop from memory the chunks before epoch k's (their values stay in the history)."""
        start = (k // self.chunk) * self.chunk
        if start > self.released_to:
            self.history.release(self.xs, 0, start)
            self.history.release(self.Ps, 0, start)
            for arr in self.also:
                self.history.release(arr, 0, start)
            self.released_to = start


class RecordingSink:
    """Every epoch's x, P, the transition (A, Q) into it and its rows (``history=False``: only the
    last x, P).

    Transitions are stored once per distinct (A, Q) pair (:attr:`pairs`) with the pair's number per
    epoch (:attr:`pair_of` (N,), −1 at k = 0: no transition); :attr:`A` and :attr:`Q` build the
    (N, n, n) arrays on demand (zero at k = 0).  x (N, n) and P (N, n, n) are arrays of ``store``
    (``empty(shape)`` / ``release(arr, start, stop)``: :class:`~cdgps_cli.estimation.history.MemoryHistory`
    by default, or the disk-backed :class:`cdgps_cli.io.scratch.DiskHistory`), released in chunks of
    ``chunk_epochs`` behind the filter.  ``keep_rows=False``: only whether epoch k had rows
    (:attr:`had_rows` (N,) bool), for an owner that makes them again from the model (memory).
    """

    def __init__(self, n_epochs: int, n: int, history: bool = True, store=None, chunk_epochs: int = 1 << 30,
                 keep_rows: bool = True):
        m = n_epochs if history else 0
        self.keep = history
        self.store = store if store is not None else MemoryHistory()
        self.chunk = max(int(chunk_epochs), 1)
        self.released_to = 0
        self.x, self.P = self.store.empty((m, n)), self.store.empty((m, n, n))
        if not getattr(self.store, "on_disk", False):
            self.x[...], self.P[...] = 0.0, 0.0            # (as before: epochs never written read as zero)
        self.n = n
        self.pairs: list = []
        self.pair_of = np.full(m, -1, dtype=np.int64)
        self._lookup: dict = {}
        self.keep_rows = keep_rows
        self.row_list = [None] * m if keep_rows else None
        self.had_rows = np.zeros(m, dtype=bool)
        self.last = None

    def write(self, k, x, P) -> None:
        if self.keep:
            self.x[k], self.P[k] = x, P
        else:
            self.last = (x, P)

    def _pair(self, A, Q, prev: int) -> int:
        """The number of pair (A, Q): the previous epoch's when equal (``==`` on every element), else
        the stored pair with the same bytes, else a new one (never ``prev`` when unequal to it)."""
        if prev >= 0 and np.array_equal(self.pairs[prev][0], A) and np.array_equal(self.pairs[prev][1], Q):
            return prev
        key = (A.tobytes(), Q.tobytes())
        i = self._lookup.get(key, -1)
        if i < 0 or i == prev:
            i = len(self.pairs)
            self.pairs.append((A.copy(), Q.copy()))
            self._lookup[key] = i
        return i

    def transition(self, k, A, Q) -> None:
        if self.keep:
            A = np.eye(self.n) if A is None else np.asarray(A, dtype=np.float64)
            Q = np.asarray(Q, dtype=np.float64)
            self.pair_of[k] = self._pair(A, Q, int(self.pair_of[k - 1]) if k > 0 else -1)

    def fill_transitions(self, A, Q) -> None:
        """The same (A, Q) into every epoch k ≥ 1 (a constant epoch spacing)."""
        if self.keep and self.pair_of.size > 1:
            self.pair_of[1:] = self._pair(np.asarray(A, dtype=np.float64), np.asarray(Q, dtype=np.float64), -1)

    def _expand(self, j: int) -> np.ndarray:
        out = np.zeros((self.pair_of.size, self.n, self.n))
        for i, pair in enumerate(self.pairs):
            out[self.pair_of == i] = pair[j]
        return out

    @property
    def A(self) -> np.ndarray:
        """(N, n, n) the transition matrix into each epoch (zero at k = 0), built from :attr:`pairs`."""
        return self._expand(0)

    @property
    def Q(self) -> np.ndarray:
        """(N, n, n) the process noise into each epoch (zero at k = 0), built from :attr:`pairs`."""
        return self._expand(1)

    def rows(self, k, rows) -> None:
        if self.keep:
            self.had_rows[k] = True
            if self.keep_rows:
                self.row_list[k] = rows

    def release_before(self, k) -> None:
        """Drop from memory the chunks of x, P before epoch k's (their values stay in the store)."""
        start = (k // self.chunk) * self.chunk
        if self.keep and start > self.released_to:
            self.store.release(self.x, 0, start)
            self.store.release(self.P, 0, start)
            self.released_to = start


class GridDynamics:
    """A :class:`~cdgps_cli.model.dynamics_models.Dynamics` (``transition(dt_s) -> (A, B, Q)``) on the
    source's epoch times: ``step_into(k)`` → (A, or None when the transition is the identity, Q, None)
    and the A it reports to the sink."""

    def __init__(self, dyn, time_s: np.ndarray):
        self.dyn, self.time_s = dyn, np.asarray(time_s, dtype=float)
        self.identity = bool(getattr(dyn, "identity_transition", False))

    def step_into(self, k: int):
        A, _, Q = self.dyn.transition(float(self.time_s[k] - self.time_s[k - 1]))
        return A, Q, None


def drive(dynamics, models, source: EpochGrid, init, hooks=(), sink=None, spans=None,
          max_iterations: int = 1, progress=None, k0: int = 0, on_singular=None) -> DriveContext:
    """The forward filter over the source's epochs (module docstring: the order of one epoch).

    Parameters
    ----------
    dynamics : object
        ``step_into(k) -> (A (p, p) or None, Q (p, p), known input (p,) or None)``: the prediction
        into epoch k (:class:`GridDynamics` adapts a ``transition(dt_s)`` dynamics); ``identity``
        true: A is reported but not applied (A P Aᵀ = P).
    models : list of MeasurementModel
        ``rows(k)`` → Rows or None and ``predict(x, rows)`` → (h, H); optional ``prepare(k, ctx)``.
    source : EpochGrid
    init : StepFilter or (x0 (p,), P0 (p, p))
        The state entering epoch ``k0`` (a StepFilter is stepped in place).
    hooks : sequence of Hook
    sink : HistorySink, RecordingSink or any object with ``write(k, x, P)`` and ``release_before(k)``
    spans : callable, optional
        ``spans(ctx, k) -> k_stop``: runs epochs k … k_stop−1 elsewhere (the compiled kernel),
        leaving ``ctx.step`` the state entering k_stop.
    max_iterations : int
        Gauss–Newton iterations of each update (1: the extended Kalman update).
    progress : object, optional
        A bar with ``update_to(k)``.
    k0 : int
        The first epoch.
    on_singular : callable, optional
        ``on_singular(k)`` is called (and should raise) when the update of epoch k meets a covariance
        that is not positive definite; without it numpy's LinAlgError propagates.

    Returns
    -------
    DriveContext
        The final step, the sink, NIS (N,) and its dof (N,).
    """
    step = init if isinstance(init, StepFilter) else StepFilter(*init)
    N = source.n_epochs
    sink = sink if sink is not None else RecordingSink(N, len(step.x))
    nis = getattr(sink, "nis", None)
    ctx = DriveContext(step, source, sink, np.full(N, np.nan) if nis is None else nis,
                       np.zeros(N, dtype=np.int64) if nis is None else sink.nis_dof, progress)
    identity = bool(getattr(dynamics, "identity", False))
    write_transition = getattr(sink, "transition", None)
    write_rows = getattr(sink, "rows", None)
    k = int(k0)
    while k < N:
        if spans is not None:
            k = spans(ctx, k)
            if k >= N:
                break
        sink.release_before(k)
        if k > 0:
            A, Q, u = dynamics.step_into(k)
            if write_transition is not None:
                write_transition(k, A, Q)
            step.predict(None if identity else A, Q, u)
        for h in hooks:
            h.before_rows(ctx, k)
        for m in models:
            prep = getattr(m, "prepare", None)
            if prep is not None:
                prep(k, ctx)
        for h in hooks:
            h.prepared(ctx, k)
        for m in models:
            rows = m.rows(k)
            for h in hooks:
                if rows is None:
                    break
                rows = h.gate(ctx, k, m, rows)
            if rows is None:
                continue
            try:
                nis = step.update(m, rows, max_iterations)
            except np.linalg.LinAlgError:
                if on_singular is None:
                    raise
                on_singular(k)
                raise
            ctx.nis[k] = nis if np.isnan(ctx.nis[k]) else ctx.nis[k] + nis
            ctx.nis_dof[k] += rows.z_m.size
            if write_rows is not None:
                write_rows(k, rows)
            for h in hooks:
                h.updated(ctx, k, m, rows, nis)
        sink.write(k, step.x, step.P)
        k_next = k + 1
        for h in hooks:
            k_next = h.after(ctx, k, k_next)
        k = k_next
        if progress is not None:
            progress.update_to(k)
    return ctx
