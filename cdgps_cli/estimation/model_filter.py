"""The forward filter over the engine's interfaces (a
:class:`~cdgps_cli.measurement.model.MeasurementModel` and a :class:`~cdgps_cli.model.dynamics_models.Dynamics`).

:func:`filter_numpy` is the reference path, the one driver (:func:`cdgps_cli.estimation.driver.drive`)
with this model injected: an iterated extended Kalman filter whose measurement
update is in information form on the rows whitened by their noise (diagonal σ or the Cholesky
factor of a full covariance, so R = I after whitening); its loop body is the engine's step
(:class:`cdgps_cli.estimation.kalman.StepFilter`, :func:`~cdgps_cli.estimation.kalman.iterated_update`).
Integrity is given to it as hooks on the rows of each epoch (``rows_hook``, e.g. :func:`outlier_gate`).
The smoother of its outputs (``A``, ``Q`` per epoch) is
:func:`cdgps_cli.estimation.smoother.rts_smooth_transitions`.
"""

from __future__ import annotations

import numpy as np

from cdgps_cli.estimation.driver import EpochGrid, GridDynamics, RecordingSink, RowsGate, drive
from cdgps_cli.estimation.kalman import StepFilter, iterated_update

__all__ = ["FilterResult", "filter_numpy", "iterated_update", "outlier_gate", "filter_dd_kernel"]


class FilterResult(dict):
    """The forward filter's outputs as a dict: ``x``, ``P``, ``nis``, ``nis_dof``, ``rows`` and
    ``transitions`` = (pairs [(A, Q)], pair_of (N,)) (each distinct transition once,
    :class:`~cdgps_cli.estimation.driver.RecordingSink`); ``A`` and ``Q`` (N, n, n) are built from them
    when first asked for."""

    def __init__(self, sink, ctx):
        super().__init__(x=sink.x, P=sink.P, nis=ctx.nis, nis_dof=ctx.nis_dof, rows=sink.row_list,
                         had_rows=sink.had_rows, transitions=(sink.pairs, sink.pair_of))
        self._sink = sink

    def __missing__(self, key):
        if key not in ("A", "Q"):
            raise KeyError(key)
        self[key] = value = getattr(self._sink, key)
        return value


def filter_numpy(model, dyn, time_s, x0, P0, max_iterations: int = 5, rows_hook=None, history: bool = True,
                 store=None, chunk_epochs: int = 1 << 30, keep_rows: bool = True, form: str = "information") -> dict:
    """Iterated EKF over the epochs of ``model`` (reference numpy path).

    Each epoch: predict with ``dyn.transition(Δt)``, then the measurement update on the whitened
    rows, iterated (Gauss–Newton) while the correction exceeds 1e-9 of the state, at most
    ``max_iterations`` times.

    Parameters
    ----------
    model : MeasurementModel
    dyn : Dynamics
    time_s : ndarray (N,)
        Epoch times, s.
    x0, P0 : ndarray (n,), (n, n)
        Prior at the first epoch.
    max_iterations : int
    rows_hook : callable, optional
        ``rows_hook(k, rows, x, P) -> rows or None``: integrity on the epoch's rows before the
        update (drop rows, re-bias); None keeps them.
    history : bool
        Keep every epoch's x, P, A, Q and rows (False: only the last epoch's x and P, e.g. for a
        large state of constants whose final estimate is what is wanted).
    store : object, optional
        Where x (N, n) and P (N, n, n) are kept (``empty`` / ``release``: the default
        :class:`~cdgps_cli.estimation.history.MemoryHistory`, or :class:`cdgps_cli.io.scratch.DiskHistory`),
        released every ``chunk_epochs`` epochs behind the filter.
    keep_rows : bool
        Keep every epoch's rows (False: ``rows`` is None and ``had_rows`` (N,) bool says which epochs
        had rows; the caller makes them again from the model and its gate's events).
    form : {"information", "covariance"}
        The update's form (:class:`~cdgps_cli.estimation.kalman.StepFilter`): the information form costs O(n³) an
        epoch, the covariance form O(n² m) with m rows (a large state of constants and few rows an epoch).

    Returns
    -------
    FilterResult
        ``x`` (N, n), ``P`` (N, n, n) filtered; ``transitions`` (each distinct (A, Q) once and its
        number per epoch); ``A``, ``Q`` (N, n, n) the transition into each epoch (zero at k = 0, built
        when asked for); ``nis`` (N,), ``nis_dof`` (N,) int; ``rows`` (list of Rows or None).
        Without ``history``: ``x`` (n,), ``P`` (n, n) of the last epoch, ``nis``, ``nis_dof``.
    """
    n, ns = len(time_s), len(x0)
    sink = RecordingSink(n, ns, history, store=store, chunk_epochs=chunk_epochs, keep_rows=keep_rows)
    hooks = [] if rows_hook is None else [RowsGate(rows_hook)]
    ctx = drive(GridDynamics(dyn, time_s), [model], EpochGrid(np.asarray(time_s, float)), StepFilter(x0, P0, form=form), hooks,
                sink, max_iterations=max_iterations)
    out = FilterResult(sink, ctx)
    if not history:
        out["x"], out["P"] = ctx.step.x, ctx.step.P
    return out


def outlier_gate(model, outlier_sigma: float, events: list, time_s=None):
    """A ``rows_hook`` of :func:`filter_numpy`: rows whose innovation at the predicted state exceeds
    ``outlier_sigma`` standard deviations (S_ii = H_i P H_iᵀ + C_ii) are dropped, the worst first, one
    at a time (a full noise covariance couples the others' statistics to it); each drop is appended
    to ``events`` as ``{"epoch", "time_s", "label", "kind": "outlier", "sigmas"}``."""

    def hook(k, rows, x, P):
        while rows is not None and rows.z_m.size:
            h, H = model.predict(x, rows)
            S = np.einsum("ij,jk,ik->i", H, P, H) + np.diag(rows.covariance())
            t = np.abs(rows.z_m - h) / np.sqrt(S)
            i = int(np.argmax(t))
            if not t[i] > outlier_sigma:
                return rows
            events.append({"epoch": int(k), "time_s": None if time_s is None else float(time_s[k]),
                           "label": rows.labels[i], "kind": "outlier", "sigmas": float(t[i])})
            keep = np.delete(np.arange(rows.z_m.size), i)
            rows = rows.subset(keep) if keep.size else None
        return rows

    return hook


def filter_dd_kernel(model, dyn, time_s, x0, P0, max_iterations: int = 5, outlier_sigma: float = np.inf,
                     events: list | None = None) -> dict:
    """:func:`filter_numpy` on a :class:`~cdgps_cli.measurement.model.SatelliteDDModal` through the
    compiled kernel's whitened full-noise path (``_ekfcore.dd_span``).

    The rows of every epoch are packed once (:func:`~cdgps_cli.measurement.model.pack_dd`, vectorized);
    the kernel runs the epochs no hook claims and hands back the others to the numpy update of this
    module: an epoch whose spacing differs from the first one's (another transition), and an epoch
    with an innovation beyond ``outlier_sigma`` (:func:`outlier_gate` drops the rows).  Same outputs
    as :func:`filter_numpy` (to rounding; tested), ``rows`` only where Python handled the epoch.
    """
    from cdgps_cli.estimation import kernel  # noqa: PLC0415
    from cdgps_cli.measurement.model import pack_dd  # noqa: PLC0415

    if not kernel.available():
        raise RuntimeError("the compiled kernel is not available")
    events = [] if events is None else events
    pk = pack_dd(model)
    N, ns, C = len(time_s), len(x0), pk.z_m.shape[1]
    cfg = model.cfg
    gi, gf = kernel.pack_geometry(cfg, np.full(C, cfg.master_index), np.zeros(C, dtype=int))
    gi = gi.copy()
    gi[6] = 1                                                  # far field: the rows carry s_j − s_r
    dt = np.diff(np.asarray(time_s, float))
    dt0 = float(dt[0]) if dt.size else 1.0
    stop = np.zeros(N, dtype=np.int8)
    stop[1:][np.abs(dt - dt0) > 1e-9 * max(dt0, 1.0)] = 1
    A, _, Q = dyn.transition(dt0)
    sink = RecordingSink(N, ns)
    sink.fill_transitions(A, Q)
    f, i64 = kernel._f64, kernel._i64
    arrays = (f(pk.L), f(pk.z_m), f(pk.var_m2), f(pk.srows), i64(pk.ant), f(pk.hconst_m), i64(pk.m), stop)
    csr_A, f_Q = kernel.csr(A), f(Q)

    def spans(ctx, k):
        """The kernel from epoch k (it steps x, P in place) to the first epoch a hook or a new spacing claims."""
        step = ctx.step
        step.x, step.P = np.array(step.x, dtype=float), np.array(step.P, dtype=float)
        k, reason = kernel._ekfcore.dd_span(gi, gf, *csr_A, f_Q, *arrays, step.x, step.P, sink.x, sink.P,
                                            ctx.nis, ctx.nis_dof, N, ns, C, k, N, int(max_iterations),
                                            float(outlier_sigma))
        if k < N and reason not in (1, 3):                     # a Cholesky failure: not a hook's epoch
            raise np.linalg.LinAlgError(f"modal filter: covariance not positive definite at epoch {k}")
        return k

    ctx = drive(GridDynamics(dyn, time_s), [model], EpochGrid(np.asarray(time_s, float)), StepFilter(x0, P0),
                [RowsGate(outlier_gate(model, outlier_sigma, events, time_s))], sink, spans=spans,
                max_iterations=max_iterations)
    return FilterResult(sink, ctx)
