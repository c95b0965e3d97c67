"""Study grids: Lion's estimator over records × gains × filter poles × initial guesses.

:func:`study` flattens the whole grid — datasets (or twin records labelled by excitation,
operating point and noise seed), gains, filter pole sets and initial guesses, declared once in
:class:`lionjax.studies._grid.StudyGrid` — into the batch axis of the batched estimator
(:func:`lionjax.lion_batched` with one gain and one filter per batch element: a gain Module
whose value has shape ``(B,)`` and a :class:`~lionjax.FilterBank` whose coefficients have shape
``(B, n)``), runs it in chunks (one jitted call per chunk, every chunk the same size so it
compiles once) with a progress bar, and reshapes the answers into a labelled
:class:`StudyResult` (dims, coords, arrays of shape ``(*grid, p)``). Memory per grid point does
not grow with the record length: the estimator streams the records and keeps θ(T), the cost,
the LS statistics, the convergence time and the tail statistics (plus an optional decimated
trajectory).

:func:`study_records` (:mod:`lionjax.studies._records`) simulates seeded twin records for it,
optionally as a labelled grid over excitations × operating points × noise seeds
(:class:`StudyRecords`), whose labels become the leading dims of the :class:`StudyResult`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jaxtyping import ArrayLike

from .._batched import DEFAULT_EXECUTION, Execution, lion_batched
from .._errors import InputError, result_codes
from .._estimators import AbstractGain, AbstractSampleStepper
from .._models import AbstractModel
from .._outputs import ConvergenceTime, LSStatistics, TailStatistics, Trajectory
from .._progress import run_chunks
from .._record import Record
from ._grid import Gains, Poles, StudyGrid, refuse_gain_type, study_grid
from ._records import StudyRecords
from ._result import StudyResult

#: The arrays of a :class:`StudyResult` taken from each chunk's
#: :class:`lionjax.solutions.BatchedSolution`: field → (its value, one per parameter).
_FIELDS = {
    "theta_final": (lambda s: s.theta, True),
    "theta_ls": (lambda s: s.theta_ls, True),
    "convergence_time": (lambda s: s.t_converged, False),
    "time_outside": (lambda s: s.time_outside, False),
    "tail_std": (lambda s: s.tail_std, True),
    "final_J": (lambda s: s.J, False),
}


def study(
    model: AbstractModel,
    records: Record | Sequence[Record] | StudyRecords,
    *,
    gains: Sequence[float] | None = None,
    gain: type[AbstractGain] | AbstractGain | None = None,
    poles: Sequence[Sequence[float]] | None = None,
    unit_dc_gain: bool = True,
    theta0s: Sequence[ArrayLike] | None = None,
    dataset_names: Sequence[str] | None = None,
    stepper: AbstractSampleStepper | None = None,
    tolerance: float = 0.02,
    softness: float = 0.25,
    transient: float | None = None,
    save_every: int | None = None,
    chunk_size: int | None = None,
    progress: bool = True,
    execution: Execution = DEFAULT_EXECUTION,
    gain_type: None = None,
) -> StudyResult:
    """Lion's estimator over a grid of records × gains × filter poles × initial guesses.

    The whole grid is flattened into the batch axis of :func:`lionjax.lion_batched` — one
    gain and one filter per batch element (a gain value ``(B,)``, filter coefficients
    ``(B, n)``) — and run in
    chunks of ``chunk_size`` elements, one jitted call per chunk (every chunk the same size, so
    it compiles once). The LS answer, the convergence time to within ``tolerance`` of it, its
    smooth surrogate and the tail statistics are streamed in the same pass: memory per grid
    point is independent of the record length (plus ``(T/save_every, p)`` for a trajectory).

    Arguments:
        model: the model structure (``MassDamper()`` …).
        records: one :class:`Record` (no record axis), a batch ``(D, T)`` or a list of records
            (dim ``"dataset"``; different lengths are padded and masked), or a
            :class:`StudyRecords` (its dims, e.g. excitation × operating point × noise seed).
        gains: a grid of scalar gain values, each passed to the ``gain`` class: G = g·I
            (``gain=lionjax.FixedGain``, the default with a grid; paper: 1e4) or AutoGain rates
            [1/s] (``gain=lionjax.AutoGain``, G = rate·R⁻¹). None: no gain axis.
        gain: the gain Module class of the ``gains`` grid (default :class:`lionjax.FixedGain`),
            or, without ``gains``, one gain Module for every grid point (default
            ``AutoGain(1.0)``).
        poles: a grid of filter pole sets [rad/s], e.g. ``[(-4, -4, -4), (-8, -8, -8)]``
            (all of the same length, real, negative). None: :func:`default_bank`, no pole axis.
        unit_dc_gain: filter normalisation for ``poles`` (λₙ/Λ, as the default bank).
        theta0s: a grid of initial estimates, each ``(p,)``. None: zeros, no θ₀ axis.
        dataset_names: labels of the datasets (default "0", "1", …; dim ``"dataset"`` only).
        stepper: Lion's per-sample stepper (default ``ExactStep()``; its ``normalisation`` μ
            selects the normalised law).
        tolerance, softness: of the convergence time (:class:`lionjax.ConvergenceTime`: the
            band, default 2 %, and the width of its smooth surrogate).
        transient: [s] the start of the LS window and of AutoGain's R (None: 3·λₙ₋₁/λₙ of each
            filter; :class:`lionjax.LSStatistics`).
        execution: the performance knobs of :func:`lionjax.lion_batched`.
        gain_type: removed (an error naming the replacement): pass ``gain=lionjax.FixedGain``
            or ``gain=lionjax.AutoGain``.
        save_every: also keep θ every ``save_every`` samples (``trajectory``; records of one
            common ``dt``).
        chunk_size: grid points per batched call (default: all in one call).
        progress: print a progress bar to stderr, one step per chunk.

    Returns:
        a :class:`StudyResult`. On KeyboardInterrupt the chunks already done are returned
        (NaN elsewhere, ``complete=False``) and a warning is printed to stderr.
    """
    if not isinstance(model, AbstractModel):
        raise InputError(f"study: model must be an AbstractModel, got {type(model).__name__}.")
    refuse_gain_type(gain_type, "study")
    grid = study_grid(
        model,
        records,
        gains=gains,
        gain=gain,
        poles=poles,
        unit_dc_gain=unit_dc_gain,
        theta0s=theta0s,
        dataset_names=dataset_names,
    )
    if not (isinstance(softness, int | float) and softness > 0):
        raise InputError(f"study: softness must be a positive number, got {softness!r}.")
    dt = np.asarray(grid.records.batch.dt)
    if save_every is not None and not grid.records.common_dt:
        raise InputError(
            "study: save_every needs records of one sampling interval (the trajectory has one "
            f"time axis); got dt from {dt.min():g} to {dt.max():g} s. Resample the "
            "records (lionjax.resample) or drop save_every."
        )
    grid.records.check(model, grid.axis(Poles).banks(), transient, "study")
    outputs = (
        LSStatistics(transient),
        ConvergenceTime(tolerance=tolerance, softness=softness),
        TailStatistics(),
    ) + (() if save_every is None else (Trajectory(save_every),))

    def call(kw):
        return lion_batched(
            model, stepper=stepper, outputs=outputs, execution=execution, throw=False, **kw
        )

    arrays, complete = _run(grid, call, chunk_size, len(model.names), progress)
    K = arrays["trajectory"].shape[-2] if "trajectory" in arrays else None
    return StudyResult(
        dims=grid.dims,
        coords=grid.coords,
        names=tuple(model.names),
        **arrays,
        t_saved=None if K is None else float(dt[0]) * save_every * np.arange(1, K + 1),
        tolerance=tolerance,
        softness=float(softness),
        transient=None if transient is None else float(transient),
        complete=complete,
        gain_class=grid.axis(Gains).class_name,
    )


def _run(grid: StudyGrid, call, chunk_size, p: int, progress: bool) -> tuple[dict, bool]:
    """The grid in equal chunks of ``chunk_size`` points (default all), one batched ``call``
    (keyword arguments → :class:`lionjax.solutions.BatchedSolution`) each: the arrays of a
    :class:`StudyResult` by field, grid-shaped (NaN, result −1, where a chunk did not run),
    and whether every chunk ran."""
    N = grid.size
    chunk = N if chunk_size is None else int(chunk_size)
    if chunk < 1:
        raise InputError(f"study: chunk_size must be a positive int, got {chunk_size!r}.")
    chunk = min(chunk, N)
    jobs = [np.arange(s, min(s + chunk, N)) for s in range(0, N, chunk)]
    out = {k: np.full((N, p) if per_p else (N,), np.nan) for k, (_, per_p) in _FIELDS.items()}
    out["result"] = np.full(N, -1, int)

    def run_job(sel: np.ndarray) -> None:
        n = sel.size
        # pad a short chunk to the chunk size (repeat its last point): one compilation
        sol = call(grid.arguments(np.concatenate([sel, np.repeat(sel[-1:], chunk - n)])))
        for k, (value, _) in _FIELDS.items():
            out[k][sel] = np.asarray(value(sol))[:n]
        out["result"][sel] = result_codes(sol.result)[:n]
        if any(k is Trajectory for k in sol.kinds):
            tr = np.moveaxis(np.asarray(sol.trajectory), 1, 0)  # (B, K, p)
            out.setdefault("trajectory", np.full((N,) + tr.shape[1:], np.nan))[sel] = tr[:n]

    complete = run_chunks(jobs, run_job, label="study", total=len(jobs), progress=progress)
    return {k: a.reshape(grid.shape + a.shape[1:]) for k, a in out.items()}, complete
