"""Shared plumbing of the estimators: the transient window and raising carried failures."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._errors import RESULTS, InputError, raise_if_failed
from ._filters import FilterBank
from ._record import Record


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


def check_duration(record: Record, bank: FilterBank, what: str) -> None:
    """Refuse a record shorter than the filter transient (when the values are concrete)."""
    if is_traced((record.dt, bank.coeffs)):
        return
    import numpy as np

    need = float(np.max(np.asarray(default_transient(bank))))
    have = float(np.min(np.asarray(record.dt))) * (record.n_samples - 1)
    if have < need:
        raise InputError(
            f"{what}: the record lasts {have:.4g} s ({record.n_samples} samples), shorter than "
            f"the filter transient {need:.4g} s (3·λₙ₋₁/λₙ of Λ with coefficients "
            f"{np.asarray(bank.coeffs).tolist()}). Use a longer record or faster filter poles."
        )


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
