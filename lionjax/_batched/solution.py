"""What the batched and parallel estimators return: :class:`BatchedSolution`,
:class:`LSBatchedSolution`, :class:`ParallelSolution`, and the result code of each record."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from .._errors import RESULTS, InputError
from .._outputs import (
    AbstractOutput,
    ConvergenceTime,
    LSStatistics,
    TailStatistics,
    Trajectory,
)
from .._solution_tools import by_name


class BatchedSolution(eqx.Module):
    """What :func:`lion_batched` returns for a batch of B records (p parameters).

    Attributes:
        theta: final estimates θ(T), shape ``(B, p)``.
        J: final cost ½εᵀε at the last sample, shape ``(B,)``.
        gain: the gain matrices G, shape ``(B, p, p)``.
        outputs: the finalised accumulators, one per ``outputs`` argument and in its order
            (:class:`lionjax.solutions.LSResult`, :class:`lionjax.solutions.ConvergenceResult`,
            :class:`lionjax.solutions.TailResult`, :class:`lionjax.solutions.TrajectoryResult`);
            by type with :meth:`output`, or through the shortcuts below.
        kinds: the accumulator types of ``outputs``.
        names: parameter names; result: a :class:`RESULTS` code per record, ``(B,)``.

    Shortcuts (each raises :class:`InputError` naming the accumulator when it was not
    requested): ``theta_ls``, ``ls_condition`` (:class:`LSStatistics`); ``theta_ref``,
    ``t_converged``, ``time_outside`` (:class:`ConvergenceTime`); ``tail_mean``, ``tail_std``
    (:class:`TailStatistics`); ``t_saved``, ``trajectory`` (:class:`Trajectory`).
    """

    theta: Float[Array, "B p"]
    J: Float[Array, " B"]
    gain: Float[Array, "B p p"]
    outputs: tuple[eqx.Module, ...]
    kinds: tuple[type, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS
    unexcited: Array | None = None  # (B, p): parameters a record does not identify

    def params(self) -> dict[str, Array]:
        """Final estimates by name, each ``(B,)``."""
        return by_name(self.names, self.theta)

    def output(self, kind: type[AbstractOutput]) -> eqx.Module:
        """The finalised accumulator of type ``kind`` (e.g. ``sol.output(lj.LSStatistics)``
        is the :class:`lionjax.solutions.LSResult`)."""
        for k, out in zip(self.kinds, self.outputs, strict=True):
            if k is kind:
                return out
        name = getattr(kind, "__name__", repr(kind))
        raise InputError(
            f"BatchedSolution: no {name} output; lion_batched ran with outputs "
            f"{tuple(k.__name__ for k in self.kinds)}. Pass outputs=(..., lionjax.{name}()) to "
            "lion_batched."
        )

    @property
    def theta_ls(self) -> Float[Array, "B p"]:
        """The streamed LS answer ``(B, p)`` (:class:`LSStatistics`)."""
        return self.output(LSStatistics).theta

    @property
    def ls_condition(self) -> Float[Array, " B"]:
        """Condition number of the column-normalised Φ, ``(B,)`` (:class:`LSStatistics`)."""
        return self.output(LSStatistics).condition

    @property
    def theta_ref(self) -> Float[Array, "B p"]:
        """The reference of the convergence time ``(B, p)`` (:class:`ConvergenceTime`)."""
        return self.output(ConvergenceTime).reference

    @property
    def t_converged(self) -> Float[Array, " B"]:
        """Convergence time [s], ``inf`` if not settled (:class:`ConvergenceTime`)."""
        return self.output(ConvergenceTime).t_converged

    @property
    def time_outside(self) -> Float[Array, " B"]:
        """Smooth surrogate of ``t_converged`` [s] (:class:`ConvergenceTime`)."""
        return self.output(ConvergenceTime).time_outside

    @property
    def tail_mean(self) -> Float[Array, "B p"]:
        """Mean of θ(t) over the last quarter of each record (:class:`TailStatistics`)."""
        return self.output(TailStatistics).mean

    @property
    def tail_std(self) -> Float[Array, "B p"]:
        """Standard deviation of θ(t) over the last quarter (:class:`TailStatistics`)."""
        return self.output(TailStatistics).std

    @property
    def t_saved(self) -> Float[Array, " K"]:
        """Times of the decimated trajectory [s] (:class:`Trajectory`)."""
        return self.output(Trajectory).t

    @property
    def trajectory(self) -> Float[Array, "K B p"]:
        """θ every ``Trajectory.every`` samples, ``(K, B, p)`` (:class:`Trajectory`)."""
        return self.output(Trajectory).theta


class LSBatchedSolution(eqx.Module):
    """Batch least squares from streamed sufficient statistics (:func:`least_squares_batched`).

    Attributes:
        theta: θ_LS = −(ΦᵀΦ)⁻¹Φᵀy, shape ``(B, p)``.
        covariance: σ²(ΦᵀΦ)⁻¹ with σ² = RSS/(N − p), N = 2·n_used rows (as
            :func:`lionjax.least_squares`), ``(B, p, p)``; std: its diagonal's square root.
        condition: condition number of the column-normalised Φ (inf if ΦᵀΦ is singular), ``(B,)``.
        rms: root-mean-square equation error, ``(B,)``; n_used: samples used, ``(B,)``;
        names; result: :class:`RESULTS` per record.
    """

    theta: Float[Array, "B p"]
    covariance: Float[Array, "B p p"]
    std: Float[Array, "B p"]
    condition: Float[Array, " B"]
    rms: Float[Array, " B"]
    n_used: Float[Array, " B"]
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS
    unexcited: Array | None = None  # (B, p): parameters a record does not identify

    def params(self) -> dict[str, Array]:
        return by_name(self.names, self.theta)


def result_of(ok, finite, valid=None):
    """The :data:`lionjax.RESULTS` code of one record: ``unidentifiable`` where the gain or the
    validity layer failed (``ok`` False), else ``unstable_step`` where an explicit step left its
    stability region (``valid`` False), else ``nonfinite`` where θ is not finite."""
    res = RESULTS.where(ok, RESULTS.successful, RESULTS.unidentifiable)
    if valid is not None:
        res = RESULTS.where(valid | ~ok, res, RESULTS.unstable_step)
    return RESULTS.where(finite | ~(res == RESULTS.successful), res, RESULTS.nonfinite)


class ParallelSolution(eqx.Module):
    """θ at every sample from :func:`lion_parallel`: ``theta`` (T, p), ``theta_final`` (p,)."""

    theta: Float[Array, "T p"]
    theta_final: Float[Array, " p"]
    names: tuple[str, ...] = eqx.field(static=True)
