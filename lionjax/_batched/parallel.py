"""Lion's exact-step estimator for one record, parallel in time.

θₖ₊₁ = Aₖθₖ + cₖ is linear, Aₖ = I − hGWₖᵀE Wₖ, cₖ = −hGWₖᵀE W₀ₖ, so
:func:`lion_parallel` composes the affine maps with ``lax.associative_scan`` (O(log T) depth,
for long records on accelerators; it stores the regressors, built from the plan the streamed
kernel uses, :func:`lionjax._batched.stream.plan_for`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .._errors import IdentificationError, InputError
from .._estimators import default_bank
from .._filters import FilterBank
from .._linalg import matmul, matvec
from .._models import AbstractModel
from .._phi import phi_sym2
from .._record import Record
from .._scan import affine_scan, filter_states
from .._solution_tools import is_traced, transient_mask
from .._validity import (
    MAX_MOMENT_CONDITION,
    check_duration,
    check_filter_speed,
    check_record,
    check_theta0,
    column_reference,
    not_identified,
    unexcited,
    unexcited_names,
)
from .solution import ParallelSolution
from .stream import plan_for


def lion_parallel(
    model: AbstractModel,
    record: Record,
    G: Float[ArrayLike, "p p"],
    *,
    bank: FilterBank | None = None,
    theta0: ArrayLike | None = None,
    midpoint: bool = True,
) -> ParallelSolution:
    """Lion's exact-step estimator for one record, parallel in time (``lax.associative_scan``).

    Both recurrences are parallel: the filter bank (z_{k+1} = Φz_k + Γu, time-invariant:
    :func:`lionjax._scan.filter_states`) and the estimate, θₖ₊₁ = Aₖθₖ + cₖ,
    Aₖ = I − h·GWₖᵀE(hSₖ)Wₖ, cₖ = −h·GWₖᵀE(hSₖ)W₀ₖ (Wₖ the midpoint regressors, as
    :class:`lionjax.ExactStep`), a prefix product of affine maps composed pairwise:
    (A₂, c₂)∘(A₁, c₁) = (A₂A₁, A₂c₁ + c₂). Depth O(log T) — for long records on accelerators;
    on a CPU the sequential :func:`lion_batched` is faster. Stores the regressors (memory
    O(T·p²)). The regressors are built as :func:`lion_batched` builds them (the model's signals,
    holds and columns); every small matrix product is elementwise (:mod:`lionjax._linalg`), so
    float32 runs at float32 precision on every backend. ``G`` is the gain matrix (p×p), e.g.
    from ``lionjax.lion(...).gain``. vmap it for many records.

    The validity layer runs on concrete arguments (skipped under ``jit``/``vmap``): ``theta0``
    finite, the filter's speed against dt (default :func:`lionjax.default_bank` of dt), the
    record's duration and data (:class:`InputError`), and every parameter identified
    (:class:`lionjax.IdentificationError` naming the others), as :func:`lionjax.lion`.
    """
    if bank is None and isinstance(record, Record):
        bank = default_bank(record.dt)
    if isinstance(record, Record) and isinstance(bank, FilterBank) and not bank.batch_shape:
        check_theta0(theta0, len(model.names), model.names, "lion_parallel")
        check_filter_speed(bank, record.dt, "lion_parallel")
        check_duration(record, bank, "lion_parallel")
        check_record(record, "lion_parallel")
    sol, bad = _lion_parallel_jit(model, record, G, bank, theta0, midpoint)
    if not is_traced(bad) and np.any(np.asarray(bad)):
        raise IdentificationError(
            f"lion_parallel: {not_identified(unexcited_names(sol.names, bad))} Use a richer "
            "excitation, fewer parameters, or region bounds the record visits."
        )
    return sol


@eqx.filter_jit
def _lion_parallel_jit(model, record, G, bank, theta0, midpoint):
    with jax.default_matmul_precision("highest"):  # any dot a model traces (tests/test_parallel)
        return _lion_parallel(model, record, G, bank, theta0, midpoint)


def _lion_parallel(model, record, G, bank, theta0, midpoint):
    bank = default_bank(record.dt) if bank is None else bank
    if bank.batch_shape:
        raise InputError(
            "lion_parallel: one record, one filter (coeffs (n,)); vmap lion_parallel over "
            f"records and banks for many, got coeffs of shape {bank.coeffs.shape}."
        )
    dtype = jnp.asarray(record.x).dtype
    plan = plan_for(model, record, bank, masked=False, block=1)
    sigs = model.signals(record)
    h = jnp.asarray(record.dt, dtype)

    def outputs(name, hold):  # V₁ … V_{n+1} at every sample, (T, n + 1)
        u = jnp.asarray(sigs[name][0]).astype(dtype)
        z = filter_states(bank, u, record.dt, hold, dtype)
        lam_rev = bank.coeffs[::-1].astype(dtype)
        V = jnp.concatenate([z, (u - jnp.sum(z * lam_rev, -1))[:, None]], -1)
        return V * bank.coeffs[-1].astype(dtype) if bank.unit_dc_gain else V

    V = [outputs(name, hold) for name, hold in plan.signals]
    W = jnp.stack(
        [
            jnp.stack([sign * V[s][:, order + r] for s, order, sign in plan.columns], -1)
            for r in (0, 1)
        ],
        1,
    )  # (T, 2, p)
    W0 = V[plan.x_index][:, 2:4]  # (T, 2)
    p = W.shape[-1]
    if midpoint:
        Ws, W0s = 0.5 * (W[:-1] + W[1:]), 0.5 * (W0[:-1] + W0[1:])
    else:
        Ws, W0s = W[:-1], W0[:-1]
    G = jnp.asarray(G, dtype)
    GW = matmul(G, jnp.swapaxes(Ws, -1, -2))  # (T-1, p, 2)
    S = matmul(Ws, GW)  # (T-1, 2, 2)
    ep, eq, er = phi_sym2(h * S[:, 0, 0], h * 0.5 * (S[:, 0, 1] + S[:, 1, 0]), h * S[:, 1, 1])
    E = jnp.stack([jnp.stack([ep, eq], -1), jnp.stack([eq, er], -1)], -2)
    K = h * matmul(GW, E)  # (T-1, p, 2)
    A = jnp.eye(p, dtype=dtype) - matmul(K, Ws)
    c = -matvec(K, W0s)
    th0 = jnp.zeros((p,), dtype) if theta0 is None else jnp.asarray(theta0, dtype)
    thetas = jnp.concatenate([th0[None], affine_scan(A, c, th0)])
    # the validity layer (as lion): R after the transient, every parameter identified
    mask = transient_mask(record, bank).astype(dtype)
    R = jnp.sum(mask[:, None, None] * jnp.sum(W[:, :, :, None] * W[:, :, None, :], 1), 0)
    R = R / jnp.maximum(jnp.sum(mask), 1.0)
    bad = unexcited(R, column_reference(model, record, bank).astype(dtype), MAX_MOMENT_CONDITION)
    sol = ParallelSolution(theta=thetas, theta_final=thetas[-1], names=tuple(model.names))
    return sol, bad
