"""Batch least squares from sufficient statistics streamed in one pass:
:func:`least_squares_batched` (the statistics pass of :func:`lionjax.lion_batched` alone)."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import ArrayLike, Int

from .._errors import InputError
from .._estimators import default_bank
from .._filters import FilterBank
from .._models import AbstractModel
from .._outputs import (
    LSStatistics,
)
from .._record import Record
from .._solution_tools import finish
from .._validity import (
    batch_reference,
    check_filter_speed,
    check_padding,
    dead_columns,
    explain_unexcited,
    flag_bad_data,
    unexcited,
)
from .devices import shard_here
from .execution import DEFAULT_EXECUTION, Execution
from .solution import LSBatchedSolution, result_of
from .stream import Stream, check_batch


def least_squares_batched(
    model: AbstractModel,
    records: Record,
    *,
    bank: FilterBank | None = None,
    lengths: Int[ArrayLike, " B"] | None = None,
    transient: float | ArrayLike | None = None,
    max_condition: float = 1e7,
    execution: Execution = DEFAULT_EXECUTION,
    throw: bool = True,
) -> LSBatchedSolution:
    """Batch least squares for B records from ΦᵀΦ, Φᵀy accumulated in one streamed pass.

    The statistics pass of :func:`lion_batched` alone (``outputs=(LSStatistics(transient),)``,
    no estimate and no gain). Equals ``lionjax.least_squares(model, record,
    initial="discard", transient=...)`` for each record (the samples of the first
    ``transient`` seconds get weight 0), without storing any regressor: memory O(B). Normal
    equations are solved on the column-normalised ΦᵀΦ (its condition number is the square of
    Φ's; in float32 prefer well-excited records).

    Arguments:
        model, records, bank, lengths, execution, throw: as :func:`lion_batched` (``bank`` one
            filter or one per record).
        transient: seconds excluded at each record's start, a number or ``(B,)`` (default
            3·λₙ₋₁/λₙ of each filter).
        max_condition: bound on cond(Φ); records at or above it are ``unidentifiable``, and so
            are records with a column that is not excited at all (:mod:`lionjax._validity`;
            ``unexcited`` names the parameters), and float64 records where cond([Φ, N]) is, N
            the filter's free responses after the transient, streamed with Φ
            (``LSStatistics(free_response=True)``: what ``least_squares(initial="discard")``
            refuses, a parameter excited only through the filter's own transient).

    The validity layer as in :func:`lion_batched` (filter speed, padding without lengths,
    failed records with bad data flagged ``nonfinite``).
    """
    if bank is None:
        bank = default_bank(records.dt if isinstance(records, Record) else None)
    check_batch("least_squares_batched", model, records, bank, lengths, execution)
    if not (max_condition > 1):
        raise InputError(
            f"least_squares_batched: max_condition must be a number > 1, got {max_condition!r}."
        )
    check_filter_speed(bank, records.dt, "least_squares_batched")
    lengths = check_padding("least_squares_batched", records, lengths)
    records, shard = shard_here(records, execution.shard)
    execution = dataclasses.replace(execution, shard=shard)
    one = jnp.ones((), records.x.dtype)
    # [Φ, N]'s conditioning (N the filter's free responses) as least_squares(initial="discard")
    # checks it; float64 only: a float32 Gram cannot resolve that condition number
    ls = LSStatistics(transient, free_response=records.x.dtype == jnp.float64)
    sol = _least_squares_batched(model, records, bank, lengths, ls, execution, one, max_condition)
    sol = flag_bad_data(sol, records)
    return finish(sol, throw, what="least_squares_batched", explain=explain_unexcited)


@eqx.filter_jit
def _least_squares_batched(model, records, bank, lengths, ls, execution, one, max_condition):
    with jax.default_matmul_precision("highest"):  # as _lion_batched
        st = Stream(model, records, bank, lengths, execution, one)
        (state,) = st.statistics((ls,))
        r = ls.finalise(state, st.ctx, None)
    finite = jnp.all(jnp.isfinite(r.theta), -1)
    # the validity layer: columns not excited at all fail; ill-conditioned directions named
    ref = batch_reference(model, records, bank, lengths).astype(r.moments.dtype)
    dead = jax.vmap(dead_columns)(r.moments, ref)
    bad = jax.vmap(lambda m, f: unexcited(m, f, max_condition**2))(r.moments, ref)
    ok = (r.condition < max_condition) & ~jnp.any(dead, axis=-1)
    if r.free_condition is not None:  # a parameter excited only through the free response
        free_ok = r.free_condition < max_condition
        ok = ok & free_ok
        bad = bad | (~free_ok[:, None] & (jnp.abs(r.free_weakest[:, : st.ctx.p]) > 0.3))
    return LSBatchedSolution(
        theta=r.theta,
        covariance=r.covariance,
        std=r.std,
        condition=r.condition,
        rms=r.rms,
        n_used=r.n_used,
        names=st.ctx.names,
        result=jax.vmap(result_of)(ok, finite),
        unexcited=bad,
    )
