"""Lion's estimator over a batch of records: :func:`lion_batched`.

Two streamed passes over the records (:class:`lionjax._batched.stream.Stream`): the statistics
pass (the accumulators that need no estimate, and the least-squares moments R when the gain or
a convergence reference needs them), then the gain G(R) and the estimation pass with the
accumulators that follow θ. The fast evaluation of E(hS) by its series re-runs the records
beyond its bound with the closed form.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import ArrayLike, Float, Int

from .._errors import InputError
from .._estimators import AbstractGain, AbstractSampleStepper, AutoGain, ExactStep, default_bank
from .._filters import FilterBank
from .._models import AbstractModel
from .._outputs import (
    AbstractOutput,
    LSResult,
    LSStatistics,
)
from .._phi import fast_series_terms
from .._record import Record
from .._solution_tools import finish
from .._validity import (
    MAX_MOMENT_CONDITION,
    batch_reference,
    check_filter_speed,
    check_padding,
    check_theta0,
    confirm_raw_unexcited,
    explain_unexcited,
    flag_bad_data,
    raw_unexcited,
    unexcited,
)
from .devices import shard_here
from .execution import DEFAULT_EXECUTION, Execution
from .solution import BatchedSolution, result_of
from .stream import Stream, check_batch


def _slab(every: int | None, chunk: int) -> tuple[int, int]:
    """(samples per slab, slabs per snapshot): the slab divides ``every`` exactly."""
    if every is None:
        return chunk, 0
    C = max(d for d in range(1, min(chunk, every) + 1) if every % d == 0)
    return C, every // C


def lion_batched(
    model: AbstractModel,
    records: Record,
    *,
    bank: FilterBank | None = None,
    gain: AbstractGain | None = None,
    stepper: AbstractSampleStepper | None = None,
    theta0: Float[ArrayLike, "*B p"] | None = None,
    lengths: Int[ArrayLike, " B"] | None = None,
    outputs: Sequence[AbstractOutput] = (),
    execution: Execution = DEFAULT_EXECUTION,
    throw: bool = True,
) -> BatchedSolution:
    """Lion's estimator over a batch of records in one streaming, fused, sharded call.

    The same law and step as ``lionjax.lion(model, record, gain=gain, stepper=stepper)`` for
    every record (tested equal), but with the regressors never stored: memory is O(B) in the
    record length T (plus ``(T/every, B, p)`` for a :class:`Trajectory`).

    Arguments:
        model: a model structure (``MassDamper()``, ``Piecewise(...)``, ``Augmented(...)``).
        records: a batch of records, ``x``/``F`` of shape ``(B, T)``, ``dt`` and ``t0`` of
            shape ``(B,)`` or ``()`` (build with :func:`stack_records`).
        bank: the filter (default :func:`lionjax.default_bank`); ``coeffs`` of shape
            ``(B, n)`` give every record its own filter (pole studies,
            :func:`lionjax.studies.stack_banks`).
        gain: an :class:`AbstractGain`: :class:`AutoGain` (default, rate 1/s; G from a first
            streamed pass of the LS statistics) or :class:`FixedGain`; a value of shape ``(B,)``
            (``FixedGain(g)``, ``AutoGain(rate)``) gives every record its own gain.
        stepper: an :class:`AbstractSampleStepper`: ``ExactStep()`` (default;
            ``regressors="midpoint"`` or ``"zoh"``, ``normalisation=μ`` for
            θ̇ = −G Wᵀε/(1 + μ‖W‖²)) or ``EulerStep()``.
        theta0: initial estimate, ``(p,)`` or ``(B, p)`` (default zeros).
        lengths: number of valid samples per record, ``(B,)``; samples at or after a record's
            length are padding and contribute nothing (θ, filter states and sums frozen).
            Without it, a batch in which a record ends in :func:`stack_records`' padding (its
            last x and F repeated exactly over more than 1 % of the samples, under a nonzero
            force) is refused (:class:`InputError`): pass the lengths ``stack_records``
            returns (or ``np.full(B, T)`` for records that really end that way).
        outputs: accumulators streamed in the same call, each at most once:
            :class:`LSStatistics` (θ_LS, condition), :class:`ConvergenceTime` (time to within
            a tolerance of θ_LS or a given reference, and its smooth surrogate),
            :class:`TailStatistics` (mean and spread of θ over the last quarter),
            :class:`Trajectory` (θ every n samples). Found on the solution by type
            (``sol.output(LSStatistics)``) or by the shortcuts (``sol.theta_ls`` …).
        execution: the performance knobs (:class:`Execution`: slab length, loops per device,
            sharding, kernel, evaluation of E); results do not depend on them beyond rounding.
        throw: raise on failure (unexcited parameters, whatever the gain; non-finite θ; an
            unstable Euler step); with False the failures are in ``result`` per record.

    The validity layer (:mod:`lionjax._validity`): a filter too fast for the sampling warns or
    is refused (default filter: :func:`lionjax.default_bank` of the largest dt), ``theta0``
    must be finite; a record whose parameters are not all identified is ``unidentifiable``
    (from the streamed statistics R when they are computed — AutoGain, LSStatistics,
    ConvergenceTime — else from windows of the raw signals, and every sample of a record they
    flag) and ``unexcited`` names them; a failed record with non-finite or out-of-range data is
    ``nonfinite``.

    Returns:
        a :class:`BatchedSolution`.
    """
    if bank is None:
        bank = default_bank(records.dt if isinstance(records, Record) else None)
    gain = AutoGain() if gain is None else gain
    stepper = ExactStep() if stepper is None else stepper
    check_batch("lion_batched", model, records, bank, lengths, execution)
    if not isinstance(gain, AbstractGain):
        raise InputError(
            f"lion_batched: gain must be an AbstractGain (lionjax.AutoGain(rate) or "
            f"lionjax.FixedGain(g)), got {type(gain).__name__}."
        )
    if not isinstance(stepper, AbstractSampleStepper):
        raise InputError(
            f"lion_batched: stepper must be an AbstractSampleStepper (lionjax.ExactStep(), "
            f"lionjax.EulerStep()), got {type(stepper).__name__}. Use lionjax.lion for "
            "DiffraxStep (it needs the continuous signals, not samples)."
        )
    B, p = records.x.shape[0], len(model.names)
    if gain.batch_shape not in ((), (B,)):
        raise InputError(
            f"lion_batched: gain must hold one value or one per record ({B},), got batch shape "
            f"{gain.batch_shape}."
        )
    check_theta0(theta0, p, model.names, "lion_batched", batch=B)
    check_filter_speed(bank, records.dt, "lion_batched")
    lengths = check_padding("lion_batched", records, lengths)
    outputs = tuple(outputs)
    for i, o in enumerate(outputs):
        if not isinstance(o, AbstractOutput):
            raise InputError(
                f"lion_batched: outputs[{i}] must be an accumulator (lionjax.LSStatistics(), "
                "ConvergenceTime(), TailStatistics(), Trajectory(every)), got "
                f"{type(o).__name__}."
            )
    kinds = [type(o) for o in outputs]
    if len(set(kinds)) != len(kinds):
        raise InputError(
            f"lion_batched: each accumulator type at most once in outputs, got "
            f"{tuple(k.__name__ for k in kinds)}."
        )
    records, shard = shard_here(records, execution.shard)
    execution = dataclasses.replace(execution, shard=shard)
    one = jnp.ones((), records.x.dtype)
    sol = _lion_batched(
        model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one
    )
    if not gain.uses_data:
        sol = confirm_raw_unexcited(sol, model, records, lengths)
    sol = flag_bad_data(sol, records)
    return finish(sol, throw, what="lion_batched", explain=explain_unexcited)


@eqx.filter_jit
def _lion_batched(model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one):
    # every matrix product traced here (the filter's expm, the gain's R⁻¹, the LS solve) at full
    # precision: float32 dots run at TF32 on GPUs otherwise (explicit in the jaxpr; tested)
    with jax.default_matmul_precision("highest"):
        return _lion_batched_body(
            model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one
        )


def _lion_batched_body(
    model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one
):
    st = Stream(model, records, bank, lengths, execution, one)
    ctx = st.ctx
    B = records.x.shape[0]
    p, dtype = ctx.p, ctx.dtype
    results: list[Any] = [None] * len(outputs)
    # the statistics pass: accumulators that need no estimate, and the LS answer when the gain
    # (R) or a convergence reference needs it
    pre = [i for i, o in enumerate(outputs) if not o.needs_theta]
    ls_at = next((i for i in pre if isinstance(outputs[i], LSStatistics)), None)
    need_ls = gain.uses_data or any(o.needs_least_squares for o in outputs)
    if pre or need_ls:
        accs = [outputs[i] for i in pre]
        if ls_at is None and need_ls:
            accs = [LSStatistics()] + accs  # the default window, not reported
        states = st.statistics(accs)
        done = [a.finalise(s, ctx, None) for a, s in zip(accs, states, strict=True)]
        for i, r in zip(pre, done[len(accs) - len(pre) :], strict=True):
            results[i] = r
        ls = next((r for r in done if isinstance(r, LSResult)), None)
        ctx = dataclasses.replace(ctx, least_squares=ls)
    R = (
        ctx.least_squares.moments
        if need_ls
        else jnp.broadcast_to(jnp.eye(p, dtype=dtype), (B, p, p))
    )
    G, ok = jax.vmap(lambda g, r: g(r, ctx.names), in_axes=(0 if gain.batch_shape else None, 0))(
        gain, R
    )
    G = G.astype(dtype)
    # the validity layer, whatever the gain: from the gain's R (after the transient), or for a
    # fixed gain (whose law uses every sample) from the raw signals of every sample
    if gain.uses_data:
        ref = batch_reference(model, records, bank, lengths).astype(dtype)
        unexc = jax.vmap(lambda r, f: unexcited(r, f, MAX_MOMENT_CONDITION))(R, ref)
    else:
        unexc = raw_unexcited(model, records, lengths)
    ok = ok & ~jnp.any(unexc, axis=-1)
    th0 = (
        jnp.zeros((B, p), dtype)
        if theta0 is None
        else jnp.broadcast_to(jnp.asarray(theta0, dtype), (B, p))
    )
    one_gain = not gain.uses_data and not gain.batch_shape  # scalars in the kernel
    # the estimation pass, with the accumulators that follow θ
    post = [i for i, o in enumerate(outputs) if o.needs_theta]
    accs = [outputs[i] for i in post]
    every = sorted({a.every for a in accs if a.every is not None})
    if len(every) > 1:
        raise InputError(f"lion_batched: one snapshot interval at most, got every={every}.")
    block, save_blocks = _slab(every[0] if every else None, execution.chunk)
    inputs = tuple(a.prepare(ctx) for a in accs)
    plan = lambda terms: st.plan(
        estimate=True,
        midpoint=stepper.regressors == "midpoint",
        block=block,
        save_blocks=save_blocks,
        series_terms=terms,
    )
    run = lambda pl, idx=None: st.run(
        pl,
        accs,
        inputs,
        theta0=th0,
        G=None if one_gain else G,
        G_shared=G[0] if one_gain else None,
        stepper=stepper,
        idx=idx,
    )
    if execution.phi == "series":
        # the short series where tr(hS) ≤ 1/2 (records beyond it come back non-finite), then the
        # closed form for those records only, gathered Bf at a time into a small batch (Bf: a
        # 16th of the batch, a multiple of the device count): one closed-form program, compiled
        # once, whatever the number of failures (a loop with no failure runs no iteration)
        o = run(plan(fast_series_terms(dtype)))
        bad = ~jnp.all(jnp.isfinite(o.theta), axis=-1)
        ndev = len(jax.local_devices()) if execution.shard else 1
        Bf = min(B, ndev * -(-max(1, B // 16) // ndev))
        closed = plan(0)

        def redo(carry):
            o, todo = carry
            idx = jnp.nonzero(todo, size=Bf, fill_value=-1)[0]
            idx = jnp.where(idx < 0, idx[0], idx)  # pad with a failed record (same values)
            sub = run(closed, idx)
            o = jax.tree.map(lambda a, b: a.at[idx].set(b), o, sub)
            return o, todo.at[idx].set(False)

        o, _ = jax.lax.while_loop(lambda c: jnp.any(c[1]), redo, (o, bad))
    else:
        o = run(plan(0))
    for i, a, s in zip(post, accs, o.outputs, strict=True):
        results[i] = a.finalise(s, ctx, o.snapshots if a.every is not None else None)
    finite = jnp.all(jnp.isfinite(o.theta), axis=-1)
    valid = o.valid
    result = (
        jax.vmap(result_of)(ok, finite, valid)
        if valid is not None
        else jax.vmap(result_of)(ok, finite)
    )
    return BatchedSolution(
        theta=o.theta,
        J=o.J,
        gain=G,
        outputs=tuple(results),
        kinds=tuple(type(a) for a in outputs),
        names=ctx.names,
        result=result,
        unexcited=unexc,
    )
