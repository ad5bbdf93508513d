"""The one forward driver of the estimation engine (../shared/design/architecture.md, "Next"):
``drive(dynamics, models, source, init, hooks, sink)``.

Every forward filter of the package is this loop over epochs with the measurement model(s)
injected; what differs between the pseudolite testbed, the far-field 1995 structure and the GNSS
paths is which :class:`~cdgps_cli.measurement.model.MeasurementModel` s give the rows, which
dynamics predict, and which integrity hooks run.  One epoch k:

1. ``spans(ctx, k)`` (optional): a compiled kernel runs the epochs no hook claims from k on and
   returns the first epoch that needs this loop (its stop codes are the hooks' contract);
2. ``sink.release_before(k)``: the sink may drop from memory the chunks it is done with;
3. prediction into k (k > 0): ``dynamics.step_into(k)`` → (A or None for the identity, Q or None for
   no process noise, known input or None), :meth:`~cdgps_cli.estimation.kalman.StepFilter.predict`;
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

Sources (:class:`EpochSource`): ``n_epochs`` and ``blocks(start)``, the epochs in blocks
(:class:`EpochBlock`: first epoch, times, named arrays), read lazily.  :class:`EpochGrid` holds the
times in memory (its blocks: the sink's chunks); :class:`BlockSource` reads each block through an
injected ``read(a, b)`` (e.g. from a RUN on disk) and keeps none.  Before a block's first epoch, the
driver gives the block to every dynamics, model and hook with a ``load(block)``: a model fed by a
streaming source takes its rows from the loaded block (:class:`GridDynamics` without ``time_s``
its times), so memory is that of a block.  Models without ``load`` index whole arrays by the
source's epoch number, as before.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from cdgps_cli.estimation.history import MemoryHistory
from cdgps_cli.estimation.kalman import StepFilter

__all__ = ["EpochBlock", "EpochSource", "EpochGrid", "BlockSource", "Hook", "RowsGate", "DriveContext", "HistorySink", "RecordingSink", "GridDynamics", "drive"]


@dataclass(frozen=True)
class EpochBlock:
    """Consecutive epochs ``start`` … ``stop``−1 of a source: their times (b,) s and, by name, the
    arrays (b, …) a source reads for them (a RUN's phases, a sensor's samples; empty for a grid)."""

    start: int
    time_s: np.ndarray
    data: dict = field(default_factory=dict)

    @property
    def stop(self) -> int:
        return self.start + len(self.time_s)


@runtime_checkable
class EpochSource(Protocol):
    """Where :func:`drive` gets its epochs: ``n_epochs`` and ``blocks(start)``, the blocks from the one
    holding epoch ``start`` on, in order (read lazily: a source on disk holds one block at a time).
    The driver hands each block to the dynamics, models and hooks that have ``load(block)`` before
    its first epoch runs."""

    n_epochs: int

    def blocks(self, start: int = 0) -> Iterator[EpochBlock]:
        ...


@dataclass
class EpochGrid:
    """The epochs a drive runs over, all in memory: times (N,) s and the chunk length (epochs) of its
    sink; its blocks are the sink's chunks (times only)."""

    time_s: np.ndarray
    chunk_epochs: int = 1 << 30

    @property
    def n_epochs(self) -> int:
        return len(self.time_s)

    def blocks(self, start: int = 0) -> Iterator[EpochBlock]:
        K, N = max(int(self.chunk_epochs), 1), self.n_epochs
        a = (int(start) // K) * K
        while a < N:
            yield EpochBlock(a, self.time_s[a:a + K])
            a += K


class BlockSource:
    """An :class:`EpochSource` read a block at a time: ``read(a, b) -> (time_s (b−a,), {name: (b−a, …)})``
    for epochs a … b−1 (injected: e.g. rows of a RUN's table on disk; numerics never open files),
    ``block_epochs`` epochs a block.  Nothing is kept between blocks."""

    def __init__(self, n_epochs: int, read, block_epochs: int = 4096):
        self.n_epochs = int(n_epochs)
        self.read = read
        self.block_epochs = max(int(block_epochs), 1)

    def blocks(self, start: int = 0) -> Iterator[EpochBlock]:
        K = self.block_epochs
        a = (int(start) // K) * K
        while a < self.n_epochs:
            b = min(a + K, self.n_epochs)
            time_s, data = self.read(a, b)
            yield EpochBlock(a, np.asarray(time_s, dtype=float), dict(data))
            a = b


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
    source: EpochSource
    sink: object
    nis: np.ndarray
    nis_dof: np.ndarray
    progress: object = None
    extra: dict = field(default_factory=dict)
    block: EpochBlock | None = None        # the source's block holding the current epoch

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
            Q = np.zeros((self.n, self.n)) if Q is None else np.asarray(Q, dtype=np.float64)
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
    and the A it reports to the sink; Q None too when the dynamics has no process noise and the identity
    transition (``zero_process_noise``, e.g. :class:`~cdgps_cli.model.dynamics_models.Static`: the
    prediction leaves x and P as they are).  The last step length's (A, Q) is kept (the arrays are only
    read): evenly spaced epochs build them once.  ``time_s`` None: the times come from the source's blocks
    (``load``), the previous block's last time kept for the step into a block's first epoch."""

    def __init__(self, dyn, time_s: np.ndarray | None = None):
        self.dyn = dyn
        self.time_s = None if time_s is None else np.asarray(time_s, dtype=float)
        self.identity = bool(getattr(dyn, "identity_transition", False))
        self.still = self.identity and bool(getattr(dyn, "zero_process_noise", False))
        self._t, self._first = None, 0        # (streaming) times of epochs _first … of the loaded block
        self._last = None                     # (dt_s, A, Q) of the last step length

    def load(self, block: EpochBlock) -> None:
        if self.time_s is not None:
            return
        t = np.asarray(block.time_s, dtype=float)
        if self._t is not None and self._first + len(self._t) == block.start:
            t = np.concatenate([self._t[-1:], t])          # the previous epoch's time
            self._t, self._first = t, block.start - 1
        else:
            self._t, self._first = t, block.start

    def step_into(self, k: int):
        if self.time_s is not None:
            t1, t0 = self.time_s[k], self.time_s[k - 1]
        else:
            i = k - self._first
            if i < 1:
                raise ValueError(f"GridDynamics: epoch {k - 1}'s time is not in the loaded blocks")
            t1, t0 = self._t[i], self._t[i - 1]
        dt = float(t1 - t0)
        if self._last is None or self._last[0] != dt:       # (a new step length is checked by transition)
            A, _, Q = self.dyn.transition(dt)
            self._last = (dt, None if self.still else A, None if self.still else Q)
        return self._last[1], self._last[2], None


def _next_block(ctx: "DriveContext", blocks, k: int, loaders) -> int:
    """Every block up to the one holding epoch k, in order, to each ``load``; that block's stop."""
    for block in blocks:
        for load in loaders:
            load(block)
        if block.stop > k:
            ctx.block = block
            return block.stop
    raise ValueError(f"drive: the source's blocks end before epoch {k}")


def drive(dynamics, models, source: EpochSource, init, hooks=(), sink=None, spans=None,
          max_iterations: int = 1, progress=None, k0: int = 0, on_singular=None) -> DriveContext:
    """The forward filter over the source's epochs (module docstring: the order of one epoch).

    Parameters
    ----------
    dynamics : object
        ``step_into(k) -> (A (p, p) or None, Q (p, p) or None, known input (p,) or None)``: the
        prediction into epoch k (:class:`GridDynamics` adapts a ``transition(dt_s)`` dynamics); ``identity``
        true: A is reported but not applied (A P Aᵀ = P); A and Q None: no process noise (P̄ = P).
    models : list of MeasurementModel
        ``rows(k)`` → Rows or None and ``predict(x, rows)`` → (h, H); optional ``prepare(k, ctx)``.
    source : EpochSource
        ``n_epochs`` and ``blocks(start)`` (:class:`EpochGrid`: times in memory; :class:`BlockSource`:
        read a block at a time); each block goes to the ``load(block)`` of the dynamics, models and
        hooks that have one before its first epoch runs (every block in order, also those a span or
        a hook jumps over).
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
    loaders = [o.load for o in (dynamics, *models, *hooks) if getattr(o, "load", None) is not None]
    # (from the block of epoch k − 1: the prediction into k reads its time)
    blocks = source.blocks(max(k - 1, 0)) if hasattr(source, "blocks") else None
    block_stop = N if blocks is None else -1
    while k < N:
        if spans is not None:
            k = spans(ctx, k)
            if k >= N:
                break
        if k >= block_stop:
            block_stop = _next_block(ctx, blocks, k, loaders)
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
