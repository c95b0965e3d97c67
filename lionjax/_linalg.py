"""Small dense matrices (n ≤ 6) written elementwise: products and the matrix exponential.

Layer 0 (core). The products are broadcast multiplies and sums, never ``dot_general``:

- a float32 dot on a GPU runs at TF32 by default (10-bit mantissa); composed over 10⁶ samples
  that error made ``lion_parallel``'s final θ differ from ``lion_batched``'s by 16 % (issue 11),
  while elementwise products are exact float32 whatever the backend's matmul precision;
- ``jax.vmap(jax.scipy.linalg.expm)`` (LAPACK solves, dots) over records laid out over two CPU
  host devices stopped XLA:CPU for some batch sizes (B = 4000–4096; benchmarks/README.md,
  "Known problem"); :func:`expm` of the same matrices runs there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

#: Taylor terms of :func:`expm` after scaling to ‖M/2ˢ‖₁ ≤ 1/2: the remainder is below
#: (1/2)¹⁹/19! ≈ 2e-23, far under float64 rounding.
EXPM_ORDER = 18
#: at most this many squarings: ‖M‖₁ up to 2³⁹ (the filter's ω₀h is O(1) in use).
EXPM_MAX_SQUARINGS = 40


def matmul(A: Array, B: Array) -> Array:
    """A @ B over the last two axes (batch axes broadcast), as multiplies and a sum."""
    return jnp.sum(A[..., :, :, None] * B[..., None, :, :], axis=-2)


def matvec(A: Array, v: Array) -> Array:
    """A @ v over the last axes (batch axes broadcast), as multiplies and a sum."""
    return jnp.sum(A * v[..., None, :], axis=-1)


def matvec_unrolled(A: Array, v: Array) -> Array:
    """A @ v over the last axes (batch axes broadcast), as n multiply-adds unrolled over the
    static last axis of A (v₀A[…, :, 0] + v₁A[…, :, 1] + …, in that order): v (…, n),
    A (…, k, n) → (…, k).

    The same product as :func:`matvec`, for the long recursions of the diagnosis' filters, which
    run it on (chunks × n) states at every scan step: unrolled, it fuses with the terms around
    it (no broadcast (…, k, n) intermediate and reduction), where a ``dot_general`` calls the
    host's matrix product per step (the ten records of ``benchmarks/diagnosis_speed.py``:
    14.0 s compiled against 16.0 s with a dot, the same verdicts,
    ``benchmarks/results/2026-11-28_cold_start_filters.md``)."""
    return sum(v[..., b : b + 1] * A[..., :, b] for b in range(A.shape[-1]))


def expm(M: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """e^M of one small square matrix by scaling and squaring: s = ⌈log₂(2‖M‖₁)⌉ (0 at least),
    the Taylor polynomial of M/2ˢ to order :data:`EXPM_ORDER` by Horner's rule, then s
    squarings (a fixed loop of :data:`EXPM_MAX_SQUARINGS` steps that squares while i < s).
    Products by :func:`matmul`; jit-, vmap- and grad-safe. Agrees with ``scipy.linalg.expm``
    to float rounding (tests/test_filters.py). NaN if ‖M‖₁ > 2³⁹."""
    n = M.shape[-1]
    norm = jnp.max(jnp.sum(jnp.abs(M), axis=-2))
    tiny = jnp.finfo(M.dtype).tiny
    s = jnp.ceil(jnp.log2(jnp.maximum(norm, tiny) * 2.0))
    s = jnp.clip(s, 0.0, None)
    X = M * jnp.exp2(-s)
    eye = jnp.eye(n, dtype=M.dtype)
    E = eye
    for k in range(EXPM_ORDER, 0, -1):
        E = eye + matmul(X, E) / k
    E = jax.lax.fori_loop(0, EXPM_MAX_SQUARINGS, lambda i, E: jnp.where(i < s, matmul(E, E), E), E)
    return jnp.where(s > EXPM_MAX_SQUARINGS, jnp.nan, E)
