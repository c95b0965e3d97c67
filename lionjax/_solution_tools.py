"""Shared plumbing of the estimators: the transient window, the convergence time and raising
carried failures."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._errors import RESULTS, raise_if_failed
from ._filters import FilterBank
from ._record import Record


def by_name(names: Sequence[str], theta) -> dict:
    """Estimates by parameter name: ``{name: theta[..., i]}`` (the ``params()`` of every
    solution type)."""
    return {n: theta[..., i] for i, n in enumerate(names)}


def default_transient(bank: FilterBank) -> Array:
    """3·λₙ₋₁/λₙ [s]: three times the mean delay Σ 1/|pᵢ| of the filter's impulse response.

    For the paper's (s + 4)³ this is 2.25 s. Differentiable and jit-safe (no root finding).
    """
    return 3.0 * bank.coeffs[..., -2] / bank.coeffs[..., -1]


def transient_mask(record: Record, bank: FilterBank, transient=None) -> Array:
    """Weights (T,): 1 for samples at least ``transient`` seconds after the first, else 0."""
    tr = default_transient(bank) if transient is None else jnp.asarray(transient)
    elapsed = record.dt * jnp.arange(record.n_samples, dtype=record.x.dtype)
    return (elapsed >= tr).astype(record.x.dtype)


# ----------------------------------------------------------------------------------------------
# The convergence time: ONE definition, used by lionjax.lion (LionSolution.convergence_time), the
# streaming accumulator of lionjax.lion_batched (ConvergenceTime) and so by lionjax.study.


def band_scale(reference: Sequence[Array]) -> list[Array]:
    """1/|θ_refᵢ| per parameter (1 where θ_refᵢ = 0): the scale of :func:`relative_errors`,
    computed once per record (the streaming kernel keeps it out of its per-sample work)."""
    return [1.0 / jnp.where(jnp.abs(r) > 0, jnp.abs(r), 1.0) for r in reference]


def relative_errors(
    theta: Sequence[Array], reference: Sequence[Array], scale: Sequence[Array]
) -> list[Array]:
    """(θᵢ − θ_refᵢ)·scaleᵢ = (θᵢ − θ_refᵢ)/|θ_refᵢ| per parameter, elementwise.

    Lists of p arrays that broadcast together (the kernel of :func:`lionjax.lion_batched` keeps
    one ``(B,)`` array per parameter); ``scale`` from :func:`band_scale`."""
    return [(a - r) * s for a, r, s in zip(theta, reference, scale, strict=True)]


def outside_band(rel: Sequence[Array], tolerance) -> Array:
    """True where some parameter is outside the band: |θᵢ − θ_refᵢ| > tolerance·|θ_refᵢ|."""
    return functools.reduce(jnp.logical_or, [jnp.abs(r) > tolerance for r in rel])


def settle_time(last_out: Array, n_samples, seconds_at) -> Array:
    """The convergence time [s from the record start] from the index of the last sample outside
    the band (−1: none): the time of the next sample, ``inf`` if the last sample of the record
    (index ``n_samples − 1``) is still outside. ``seconds_at(i)`` is the time of sample i
    after the record's first sample."""
    dtype = jnp.result_type(seconds_at(jnp.zeros((), jnp.int32)))
    return jnp.where(
        last_out >= n_samples - 1, jnp.asarray(jnp.inf, dtype), seconds_at(last_out + 1)
    )


def convergence_time(theta: Array, reference: Array, seconds_at, tolerance: float = 0.02) -> Array:
    """Seconds from the record start after which every |θᵢ(t) − θ_refᵢ| ≤ tolerance·|θ_refᵢ|
    until the end of the record; ``inf`` if the last sample is still outside the band.

    Arguments:
        theta: θ at the samples, shape ``(T, p)`` (row 0 the initial estimate).
        reference: θ_ref, shape ``(p,)`` (e.g. the least-squares answer).
        seconds_at: time of row i after row 0 [s], a function of an int array.
        tolerance: the relative band (0.02 = 2 %).

    The streaming :class:`lionjax.ConvergenceTime` of :func:`lionjax.lion_batched` evaluates
    the same predicate sample by sample (:func:`outside_band` of :func:`relative_errors`) and
    the same :func:`settle_time`."""
    T, p = theta.shape
    ref = [reference[i] for i in range(p)]
    rel = relative_errors([theta[:, i] for i in range(p)], ref, band_scale(ref))
    out = outside_band(rel, tolerance)
    last = jnp.max(jnp.where(out, jnp.arange(T, dtype=jnp.int32), -1))
    return settle_time(last, T, seconds_at)


def is_traced(tree) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


def finish(sol, throw: bool, what: str = "identification", explain=None):
    """Raise the failures carried in ``sol.result`` when ``throw``.

    Outside a trace this raises :class:`lionjax.IdentificationError` listing each failed batch
    element (``explain(sol)`` may add detail, e.g. which parameters are unexcited); inside a
    trace it threads ``eqx``'s runtime error onto the solution.
    """
    if not throw:
        return sol
    if is_traced(sol):
        return sol.result.error_if(sol, sol.result != RESULTS.successful)
    try:
        raise_if_failed(sol, what=what)
    except Exception as e:
        if explain is not None:
            raise type(e)(f"{e}\n{explain(sol)}") from None
        raise
    return sol
