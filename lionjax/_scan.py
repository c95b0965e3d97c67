"""Linear recurrences parallel in time (``lax.associative_scan``), with small matrix products
written elementwise.

Layer 1 (core). Both recurrences of Lion's estimator are affine, xₖ₊₁ = Aₖxₖ + bₖ: the filter
bank (Aₖ = Φ, time-invariant; bₖ = Γ₀uₖ + Γ₁(uₖ₊₁ − uₖ), :mod:`lionjax._filters`) and the exact
θ step (:func:`lionjax.lion_parallel`). Their prefix compositions
(A₂, b₂)∘(A₁, b₁) = (A₂A₁, A₂b₁ + b₂) are an associative scan of depth O(log T).

The products of the small (n ≤ 4 or p×p) matrices are :func:`lionjax._linalg.matmul` and
``matvec`` (broadcast multiplies and sums, never ``dot_general``, whose float32 form runs at TF32
on a GPU by default), and so is the filter's discretisation (:func:`lionjax._linalg.expm`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from ._filters import FilterBank, check_hold
from ._linalg import matmul, matvec


def affine_compose(first, second):
    """(A₂, b₂)∘(A₁, b₁) = (A₂A₁, A₂b₁ + b₂): apply ``first`` then ``second``."""
    A1, b1 = first
    A2, b2 = second
    return matmul(A2, A1), matvec(A2, b1) + b2


def affine_scan(A: Array, b: Array, x0: Array, axis: int = 0) -> Array:
    """All states of xₖ₊₁ = Aₖxₖ + bₖ from x₀, parallel in time: returns x₁ … x_K.

    ``A``: (K, n, n) (or broadcastable to it along ``axis``), ``b``: (K, n), ``x0``: (n,);
    batch axes after the time axis are not supported (vmap for many records)."""
    A = jnp.broadcast_to(A, b.shape[:1] + A.shape[-2:])
    Acum, bcum = jax.lax.associative_scan(affine_compose, (A, b), axis=axis)
    return matvec(Acum, x0) + bcum


def filter_states(
    bank: FilterBank, u: ArrayLike, dt: ArrayLike, hold: str = "zoh", dtype=None
) -> Array:
    """The states z₀ … z_{T−1} of the filter of one sampled signal ``u`` (T,), parallel in time,
    started at the steady state of u₀ (as :meth:`FilterBank.__call__` with ``init="steady"``,
    which runs the same recurrence sequentially): returns (T, n) in ``dtype`` (default u's).

    z_{k+1} = Φz_k + Γ₀u_k + Γ₁(u_{k+1} − u_k), the exact discretisation under ``hold``."""
    check_hold(hold)
    u = jnp.asarray(u)
    dtype = u.dtype if dtype is None else dtype
    u = u.astype(dtype)
    Phi, G0, G1 = (a.astype(dtype) for a in bank.discretise(dt))
    du = (u[1:] - u[:-1]) if hold == "foh" else jnp.zeros_like(u[1:])
    b = G0[None, :] * u[:-1, None] + G1[None, :] * du[:, None]  # (T − 1, n)
    z0 = bank.steady_state(u[0]).astype(dtype)
    zs = affine_scan(Phi[None], b, z0)
    return jnp.concatenate([z0[None], zs])
