"""E(Z) = (I − e^{−Z}) Z⁻¹ for the symmetric 2×2 Z = h·WGWᵀ, and Lion's exact step built on it.

Layer 1 (core). Over one sample interval h with frozen regressors W (2 × p), θ̇ = −cG Wᵀ(Wθ + W₀)
is linear in θ and its exact solution is θ ← θ − h·cGWᵀ E(hS)(Wθ + W₀), S = c·WGWᵀ (since
(GWᵀW)ⁿ = GWᵀSⁿ⁻¹W, the p×p matrix exponential reduces to the 2×2 E; docs/method.md, "Lion's law").
:func:`phi_sym2` evaluates E elementwise (any batch shape) in closed form; :func:`exact_step` is
the step on lists of arrays, used by :func:`lionjax.lion` (one record) and by the batched
kernel of :func:`lionjax.lion_batched` (elementwise over the batch).
"""

from __future__ import annotations

import contextlib
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

# The hot path's E: the series alone, E ≈ Σ_{n<K} (−Z)ⁿ/(n+1)!, valid while every tr(hS) ≤ r
# (tr ≥ ρ for the PSD hS): the remainder is ≤ rᴷ/(K+1)! — 1.1e-8 (float32, K = 8) and 4.7e-17
# (float64, K = 14) for r = 1/2, below the unit roundoff. Gains in practice stay below it
# (AutoGain(1) on the twin: tr(hS) ≈ 0.02; the benchmark's gain: ≤ 0.5 on all 4096 records).
# A sample beyond the bound turns its record non-finite on purpose (exact_step's guard) and
# lionjax.lion_batched re-runs those records with the closed form (phi_sym2): results never
# depend on the bound, only the run time does.
SERIES_BOUND = 0.5


def fast_series_terms(dtype) -> int:
    """Terms K of the bounded series (tr(hS) ≤ :data:`SERIES_BOUND`): 8 in float32, 14 in
    float64."""
    return 8 if jnp.dtype(dtype) == jnp.float32 else 14


def _series_terms(dtype) -> int:
    """Terms K of the series branch of :func:`phi_sym2` (ρ ≤ 1): the remainder ≤ 1/(K+1)! is
    below the unit roundoff (2.5e-8 in float32 with K = 10, 8.2e-18 in float64 with K = 18)."""
    return 10 if jnp.dtype(dtype) == jnp.float32 else 18


def phi_sym2(zp: ArrayLike, zq: ArrayLike, zr: ArrayLike) -> tuple[Array, Array, Array]:
    """E(Z) = (I − e^{−Z}) Z⁻¹ for Z = [[zp, zq], [zq, zr]] symmetric PSD, elementwise.

    Returns the entries (p, q, r) of the symmetric E. Two branches, both cheap per element:

    - ρ = m + d ≤ 1 (m = (zp + zr)/2, d² = ((zp − zr)/2)² + zq²): the series
      E = Σₙ (−Z)ⁿ/(n+1)! in Horner form, each power reduced by Cayley–Hamilton
      (Z² = tr Z·Z − det Z·I), so E = αI + βZ with scalar recurrences (9 terms in float32,
      17 in float64: truncation below the unit roundoff);
    - ρ > 1: the eigen-split E = ē I + g (Z − mI), ē = (E(m+d) + E(m−d))/2,
      g = (E(m+d) − E(m−d))/(2d), E(λ) = −expm1(−λ)/λ; for d < 0.03·m (float32; 10⁻³·m in
      float64) the Taylor limits ē ≈ E(m) + E''(m)d²/2, g ≈ E'(m) + E'''(m)d²/6.

    Values and gradients are finite everywhere on PSD inputs (including Z = 0).
    """
    zp, zq, zr = jnp.asarray(zp), jnp.asarray(zq), jnp.asarray(zr)
    dtype = jnp.result_type(zp, zq, zr)
    f32 = jnp.dtype(dtype) == jnp.float32
    m = 0.5 * (zp + zr)
    hd = 0.5 * (zp - zr)
    d2 = hd * hd + zq * zq
    d = jnp.sqrt(d2 + jnp.finfo(dtype).tiny)  # tiny: finite gradient at d = 0
    rho = m + d
    small = rho <= 1.0
    # --- series branch: M ← I + (−Z)M/k, M = aI + bZ; Z² = tr·Z − det·I.
    tr = jnp.where(small, zp + zr, 0.0)
    det = jnp.where(small, zp * zr - zq * zq, 0.0)
    a, b = _series(tr, det, _series_terms(dtype))
    s_p, s_q, s_r = a + b * zp, b * zq, a + b * zr
    # --- eigen branch (values where ρ > 1; guarded inputs elsewhere).
    mm = jnp.where(small, 2.0, m)
    dd = jnp.where(small, 0.5, d)
    lp = mm + dd
    lm = mm - dd

    def E(lam):
        tiny = lam < 1e-6
        ls = jnp.where(tiny, 1.0, lam)
        return jnp.where(tiny, 1.0 - 0.5 * lam, -jnp.expm1(-ls) / ls)

    thr = 3e-2 if f32 else 1e-3
    near = dd < thr * mm
    ddf = jnp.where(near, 1.0, dd)
    ep, em = E(lp), E(lm)
    ebar_far = 0.5 * (ep + em)
    g_far = (ep - em) / (2.0 * ddf)
    e = jnp.exp(-mm)
    im = 1.0 / mm
    E0 = (1.0 - e) * im  # m > 1/2 here: no cancellation
    E1 = (e - E0) * im
    E2 = (-e - 2.0 * E1) * im
    E3 = (e - 3.0 * E2) * im
    dn2 = jnp.where(near, dd * dd, 0.0)
    ebar = jnp.where(near, E0 + 0.5 * E2 * dn2, ebar_far)
    g = jnp.where(near, E1 + E3 * dn2 / 6.0, g_far)
    hh = jnp.where(small, 0.0, hd)
    qq = jnp.where(small, 0.0, zq)
    e_p, e_q, e_r = ebar + g * hh, g * qq, ebar - g * hh
    return (
        jnp.where(small, s_p, e_p),
        jnp.where(small, s_q, e_q),
        jnp.where(small, s_r, e_r),
    )


def _phi_series(zp, zq, zr, terms: int):
    """E(Z) by the series alone, ``terms`` terms (valid where ρ(Z) is small; see SERIES_BOUND)."""
    a, b = _series(zp + zr, zp * zr - zq * zq, terms)
    return a + b * zp, b * zq, a + b * zr


def _series(tr, det, terms: int):
    """E(Z) = αI + βZ from Σ_{n<terms} cₙ(−Z)ⁿ, cₙ = 1/(n+1)!, in Horner form (Cayley–Hamilton).

    With Y = −Z (tr Y = −tr Z, det Y = det Z) and M = aI + bY: cₙI + YM = (cₙ − b·det)I +
    (a + b·tr Y)Y, so each term costs two products and two sums (the coefficients are constants;
    no division by n). Starts from M = c_{K−2}I + c_{K−1}Y (terms ≥ 2)."""
    c = [1.0 / math.factorial(n + 1) for n in range(terms)]
    a = jnp.full_like(tr, c[terms - 2])
    b = jnp.full_like(tr, c[terms - 1])
    for n in range(terms - 3, -1, -1):
        a, b = c[n] - b * det, a - b * tr  # tr Y = −tr Z
    return a, -b  # E = aI + bY = aI − bZ


_REAL_GUARD = [False]


@contextlib.contextmanager
def real_guard():
    """While tracing inside this context, :func:`materialise` applies the guard to each value as
    a real number (no complex pairs): for kernels without complex arithmetic
    (the Pallas kernel of :mod:`lionjax._pallas`; GPU kernels have no fusion problem to work
    around), and in the XLA kernel where the values have one consumer (no accumulator reads θ:
    there is no duplication to prevent, and XLA expands a complex division into about ten real
    ones). The guard is kept: a NaN guard still turns the element non-finite."""
    old = _REAL_GUARD[0]
    _REAL_GUARD[0] = True
    try:
        yield
    finally:
        _REAL_GUARD[0] = old


def materialise(values: list, guard, multiply: bool = False) -> list:
    """The same ``values`` (arrays), computed once per element by XLA:CPU, times ``guard``.

    ``guard``: a runtime 1 (exact: v·1 = v, (a + ib)/(1 + 0i) = a + ib) that XLA cannot fold
    away, or NaN where some validity check fails, which turns those elements non-finite on
    purpose (see :func:`exact_step`); None leaves the values as they are.

    XLA:CPU has no multi-output loop fusion: a value used by several outputs of a loop step is
    re-computed inside each consumer (``optimization_barrier`` does not stop that on CPU). It
    never duplicates an expensive producer, though, so the values are packed in complex pairs
    and divided by the guard. Measured: the exact step's work per sample ≈ halved for p = 2.
    Under :func:`real_guard` they are divided by it as reals, or multiplied by it where
    ``multiply`` (the θ increments: no division at all). The LS statistics keep the division:
    with a product LLVM may contract the surrounding arithmetic differently, and their
    cancellation-prone residual moments then differed between the XLA and Pallas kernels by
    5e-5 relative in float64 (tests/test_pallas.py).
    """
    if guard is None:
        return values
    if _REAL_GUARD[0]:
        return [v * guard for v in values] if multiply else [v / guard for v in values]
    vals = list(values) + ([jnp.zeros_like(values[-1])] if len(values) % 2 else [])
    den = jax.lax.complex(guard, jnp.zeros_like(guard))
    out = []
    for a, b in zip(vals[::2], vals[1::2], strict=True):
        c = jax.lax.complex(a, b) / den
        out += [jnp.real(c), jnp.imag(c)]
    return out[: len(values)]


def step_products(theta, W1, W2, y1, y2, G, h, c=None):
    """The products every per-sample step of θ̇ = −c·G Wᵀ(Wθ + W₀) starts from, elementwise:
    the columns K₁ = c(hG)W₁ and K₂ = c(hG)W₂ (p entries each; Δθ is K₁f₁ + K₂f₂ for some f),
    hS = W·c(hG)·Wᵀ as (S11, S12, S22), and ε = Wθ + W₀ as (e1, e2). Arguments as in
    :func:`exact_step`. h is folded into the gain first (hG: scalars when G and h are shared,
    hoisted out of the per-record work), so nothing after takes a product by h."""
    p = len(theta)
    Gh = [[h * G[i][j] for j in range(p)] for i in range(p)]
    GW1 = [sum(Gh[i][j] * W1[j] for j in range(p)) for i in range(p)]
    GW2 = [sum(Gh[i][j] * W2[j] for j in range(p)) for i in range(p)]
    if c is not None:
        GW1 = [c * v for v in GW1]
        GW2 = [c * v for v in GW2]
    S11 = sum(W1[i] * GW1[i] for i in range(p))
    S12 = sum(W1[i] * GW2[i] for i in range(p))
    S22 = sum(W2[i] * GW2[i] for i in range(p))
    e1 = sum(W1[i] * theta[i] for i in range(p)) + y1
    e2 = sum(W2[i] * theta[i] for i in range(p)) + y2
    return GW1, GW2, (S11, S12, S22), (e1, e2)


def exact_step(theta, W1, W2, y1, y2, G, h, c=None, phi=None, guard=None):
    """One exact step of θ̇ = −c·G Wᵀ(Wθ + W₀) over h, elementwise over any batch shape:
    θ ← θ − h·cGWᵀ E(hS) (Wθ + W₀), S = c·WGWᵀ, E(Z) = (I − e^{−Z})Z⁻¹.

    Arguments (lists of arrays, all broadcastable): ``theta`` (p entries), ``W1``/``W2`` the
    two rows of W (p entries each), ``y1``/``y2`` = W₀, ``G`` a p×p nested list (symmetric),
    ``h`` the interval [s], ``c`` the normalisation 1/(1 + μ‖W‖²) or None, ``phi`` E's
    evaluation (default :func:`phi_sym2`), ``guard`` see :func:`materialise` (the increments
    are materialised once per sample), or a function of tr(hS) returning it. Returns the increments
    Δθ (p entries): the new θ is θ − Δθ.

    h is folded into the gain first (:func:`step_products`).
    """
    p = len(theta)
    GW1, GW2, (S11, S12, S22), (e1, e2) = step_products(theta, W1, W2, y1, y2, G, h, c)
    ep, eq, er = (phi_sym2 if phi is None else phi)(S11, S12, S22)
    f1 = ep * e1 + eq * e2
    f2 = eq * e1 + er * e2
    if callable(guard):
        guard = guard(S11 + S22)
    return materialise([GW1[i] * f1 + GW2[i] * f2 for i in range(p)], guard, multiply=True)
