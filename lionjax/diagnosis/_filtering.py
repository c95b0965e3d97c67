"""The diagnosis' filters on recorded signals: the filter bank (s + λ)³ under a zero- or
first-order hold, the zero-phase velocity filter, and a flexible mode's columns (s²/D)[·], on
bucketed padded lengths (:func:`padded_length`; see :mod:`._fit` on compilation)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._filters import FilterBank, sample_hold
from .._linalg import matvec_unrolled

if TYPE_CHECKING:
    pass

#: Columns of every least-squares design (effect columns + the filter's initial-state columns).
P_MAX = 18


#: The shortest bucket (padded length) of a record.
MIN_PADDED = 1 << 12


def padded_length(n: int) -> int:
    """Bucketed length: the next power of two ≥ n + P_MAX + 2, at least :data:`MIN_PADDED`
    (short records share one bucket: a bucket costs compilations, a short record's padding
    costs little)."""
    return max(MIN_PADDED, 1 << int(math.ceil(math.log2(n + P_MAX + 2))))


def _capacity(Tp: int) -> int:
    """The most samples :func:`padded_length` puts into the bucket ``Tp``."""
    return Tp - P_MAX - 2


def edge_pad(u, Tp: int) -> np.ndarray:
    u = np.asarray(u, np.float64)
    return np.concatenate([u, np.full(Tp - u.size, u[-1] if u.size else 0.0)])


# ----------------------------------------------------------------------------- filters


@eqx.filter_jit
def _discrete(bank: FilterBank, dt):
    Phi, G0, G1 = bank.discretise(dt)  # elementwise products: full precision on any backend
    _, _, C, D = bank.state_space()
    return Phi, G0, G1, C, D, bank.coeffs[-1]


class Discrete(eqx.Module):
    """The exact sampled filter (Φ, Γ₀, Γ₁, C, D) of a bank at one dt, as arrays."""

    Phi: jax.Array
    G0: jax.Array
    G1: jax.Array
    C: jax.Array
    D: jax.Array
    c_last: jax.Array

    @classmethod
    def of(cls, bank: FilterBank, dt) -> Discrete:
        return cls(*_discrete(bank, _f(dt)))


def hold_corrected(u, foh):
    """Samples uₖ − foh·Δ²uₖ/12 (Δ²uₖ = uₖ₊₁ − 2uₖ + uₖ₋₁, repeated at both ends), whose
    first-order hold a low-pass filter sees as the smooth signal itself.

    Between samples a smooth u(t) differs from its linear interpolant by
    ½ü(t − tₖ)(t − tₖ₊₁), whose mean over the interval is −h²ü/12: a filter that averages over
    many samples sees the interpolant of u as u − (h²/12)ü, an equation error ∝ (ωh)²/12 that at
    a few hundred Hz is above an encoder's noise floor and looks like a flexible mode far above
    the excitation. Subtracting Δ²u/12 ≈ h²ü/12 first leaves an O(h⁴) error (Simpson's rule
    against the trapezoid). ``foh`` is 1.0 (smooth signal, first-order hold) or 0.0 (a
    zero-order-held input such as F: unchanged). On a padded record the last real sample's Δ²
    sees the padding (its own value repeated): one row, its correction off by up to Δx/12."""
    d2 = u[2:] - 2.0 * u[1:-1] + u[:-2]
    d2 = jnp.concatenate([d2[:1], d2, d2[-1:]])
    return u - foh * d2 / 12.0


def _powers(Phi, L: int):
    """Φʲ (L, n, n) for j = 0 … L − 1, by a scan of elementwise products."""

    def step(Z, _):
        return matvec_unrolled(Phi, Z.T).T, Z  # Φ·Z

    return jax.lax.scan(step, jnp.eye(Phi.shape[-1], dtype=Phi.dtype), None, length=L)[1]


def _recursion(Phi, inputs, drive, z0):
    """States z[k] (T, n) of z[k + 1] = Φz[k] + drive(inputs[k]), z[0] = ``z0``: every linear
    filter of the diagnosis runs through it. ``inputs`` is a tuple of arrays with leading axis
    T, ``drive`` maps their rows (batched over chunks) to the (·, n) input terms.

    In M chunks of L samples (L·M = T, L ≈ √T): the zero-state response of every chunk in
    parallel (L sequential steps), the chunks' start states by z_{m+1} = Φᴸz_m + (chunk m's end
    state) (M steps), then Φʲ·z_m added back. Linear and exact; ~2√T sequential steps instead of
    T (a scan step costs microseconds on CPU). Products elementwise
    (:func:`~lionjax._linalg.matvec_unrolled`: fused, and no TF32 dot on a GPU)."""
    n = Phi.shape[0]
    T = inputs[0].shape[0]
    L = 1 << (T.bit_length() // 2) if T & (T - 1) == 0 else T  # T a power of two: L ≈ √T
    M = T // L

    def step(z, inp):
        return matvec_unrolled(Phi, z) + drive(*inp), z

    # (L, M, …): the chunks side by side
    chunks = tuple(jnp.swapaxes(a.reshape((M, L) + a.shape[1:]), 0, 1) for a in inputs)
    zL, zs = jax.lax.scan(step, jnp.zeros((M, n), Phi.dtype), chunks)
    Pw = _powers(Phi, L)  # Φʲ, j < L
    PL = matvec_unrolled(Phi, Pw[-1].T).T  # Φᴸ = Φ·Φᴸ⁻¹

    def bstep(z, zl):
        return matvec_unrolled(PL, z) + zl, z

    _, S = jax.lax.scan(bstep, z0, zL)  # (M, n) chunk start states
    z = zs + matvec_unrolled(Pw[:, None], S[None])  # (L, M, n): + Φʲ·S_m
    return jnp.swapaxes(z, 0, 1).reshape(T, n)


def _filt(dsc: Discrete, u, foh):
    """(V₁…V₄) of one signal, as :meth:`FilterBank.__call__` with ``init="steady"``; ``foh`` is
    1.0 for a first-order hold of the :func:`hold_corrected` samples, 0.0 for a zero-order hold
    (traced): z[k+1] = Φz[k] + Γ₀u[k] + Γ₁Δu[k] by :func:`_recursion`."""
    n = dsc.Phi.shape[0]
    u_at, u = u, hold_corrected(u, foh)  # the feedthrough D·u reads the samples themselves
    z0 = jnp.zeros((n,), u.dtype).at[0].set(u[0] / dsc.c_last)
    du = foh * (jnp.concatenate([u[1:], u[-1:]]) - u)
    return filter_from(dsc, u_at, u, du, z0)[0]


def filter_from(dsc: Discrete, u_at, u, du, z0):
    """((V₁…V₄) (T, 4), the state after the last sample (n,)) of the filter from the state
    ``z0``, driven by the held samples ``u`` and their steps ``du`` (z[k+1] = Φz[k] + Γ₀u[k] +
    Γ₁du[k]), the feedthrough reading ``u_at``: :func:`_filt` on a whole record, and on each
    chunk of a streamed one (:mod:`._streaming`) with the state carried between chunks."""

    def drive(uk, duk):
        return uk[:, None] * dsc.G0 + duk[:, None] * dsc.G1

    z = _recursion(dsc.Phi, (u, du), drive, z0)
    end = matvec_unrolled(dsc.Phi, z[-1]) + drive(u[-1:], du[-1:])[0]
    return matvec_unrolled(dsc.C, z) + u_at[:, None] * dsc.D, end


@jax.jit
def _filter_many(dsc: Discrete, U, foh):
    return jax.vmap(_filt, in_axes=(None, 0, 0))(dsc, U, foh)


#: Signals filtered per call of the batched filter: the most, and the smaller batches a call may
#: take (one program per padded length and batch). The filter's cost is linear in the signals it
#: filters, and most calls filter one or two (a fixed batch of 8 spent 3/4 of the diagnosis'
#: filtering on zeros).
S_BUCKETS = (1, 2, 8)
#: Modes filtered per call of :func:`mode_columns` and :func:`mode_signals`, by the same rule.
MODE_BUCKETS = (1, 2, 4)
#: Padded lengths above this filter at most two signals (or modes) per call: a call's
#: intermediates grow with its batch (eight signals of 2²⁰ samples held about 1 GB at once), and
#: on a long record a batch buys no speed.
LONG_BATCH = 1 << 18


def _buckets(buckets: Sequence[int], Tp: int) -> Sequence[int]:
    """``buckets``, or their two smallest above :data:`LONG_BATCH` padded samples."""
    return buckets if Tp <= LONG_BATCH else buckets[:2]


def _batches(a: np.ndarray, buckets: Sequence[int]):
    """``a`` (n, …) in batches of at most ``buckets[-1]`` rows, each padded to the smallest
    bucket that holds it by repeating its last row: yields (batch, number of real rows). A
    batched program computes each row alone, so the padding rows' outputs are dropped."""
    per = buckets[-1]
    for i in range(0, len(a), per):
        chunk = a[i : i + per]
        m = len(chunk)
        b = next(b for b in buckets if b >= m)
        yield np.concatenate([chunk, np.repeat(chunk[-1:], b - m, axis=0)]), m


def _filtered_batches(dsc: Discrete, U: np.ndarray, foh: np.ndarray):
    """The (m, Tp, 4) filtered signals of each batch of :data:`S_BUCKETS` (of two signals at
    most above :data:`LONG_BATCH` padded samples, :func:`_buckets`; the compiled filter's own
    buffer, read-only), in order."""
    buckets = _buckets(S_BUCKETS, U.shape[-1])
    for (u, m), (f, _) in zip(_batches(U, buckets), _batches(foh, buckets), strict=True):
        yield np.asarray(_filter_many(dsc, u, f))[:m]


def filter_signals(dsc: Discrete, U: np.ndarray, foh: np.ndarray) -> np.ndarray:
    """(S, Tp, 4) filtered signals, in the batches of :func:`_filtered_batches`; read-only where
    one batch holds them (the compiled filter's own buffer, not copied)."""
    out = list(_filtered_batches(dsc, U, foh))
    return out[0] if len(out) == 1 else np.concatenate(out)  # one batch: no copy


@jax.jit
def _zero_phase(dsc: Discrete, x, T, dt):
    Tp = x.shape[0]
    k = jnp.arange(Tp)
    rev = jnp.where(k < T, T - 1 - k, 0)
    fwd = _filt(dsc, x, 1.0)[:, 0]
    bwd = _filt(dsc, fwd[rev], 1.0)[:, 0]
    sm = bwd[rev]
    sm = jnp.where(k < T, sm, sm[T - 1])
    nxt = jnp.concatenate([sm[1:], sm[-1:]])
    prv = jnp.concatenate([sm[:1], sm[:-1]])
    g = (nxt - prv) / (2 * dt)
    g = jnp.where(k == 0, (sm[1] - sm[0]) / dt, g)
    g = jnp.where(k == T - 1, (sm[T - 1] - sm[T - 2]) / dt, g)
    g = jnp.where(k < T, g, g[T - 1])
    return sm, g


@jax.jit
def _filter_systems(dsc: Discrete, U, foh):
    """Each signal through its own filter (a batch of :class:`Discrete`, leading axis)."""
    return jax.vmap(_filt)(dsc, U, foh)


def mode_bank(omega: float, zeta: float) -> FilterBank:
    """Λ'(s) = (s + ω)(s² + 2ζωs + ω²): h = (s²/D)[u] = V₄ + ωV₃ of this bank, exactly."""
    w, z = float(omega), float(zeta)
    wd = w * math.sqrt(max(1.0 - z * z, 0.0))
    return FilterBank.from_poles(np.asarray([-w + 0j, -z * w + 1j * wd, -z * w - 1j * wd]))


def mode_output(V, omega):
    """h = (s²/D)[u] = V₄ + ωV₃ from the outputs ``V`` (…, 4) of :func:`mode_bank`'s filter."""
    return V[..., 3] + omega * V[..., 2]


def mode_signals(
    record_x, record_F, dt: float, modes, Tp: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(h_x, h_F) of a record for each mode (ω [rad/s], ζ) in ``modes``: h = (s²/D)[·],
    D = s² + 2ζωs + ω², x under the first-order hold of its :func:`hold_corrected` samples, F
    under a zero-order hold, through :func:`mode_bank` and
    :func:`mode_output`, on bucketed shapes: each mode's x and F
    through its own filter, modes in batches of :data:`MODE_BUCKETS`
    (:meth:`~lionjax.diagnosis.effects.ModeColumns.signals` calls it)."""
    T = np.asarray(record_x).size
    xp, Fp = edge_pad(record_x, Tp), edge_pad(record_F, Tp)
    out = []
    for chunk, m in _batches(np.asarray(modes, np.float64).reshape(-1, 2), MODE_BUCKETS):
        ds = [Discrete.of(mode_bank(w, z), dt) for w, z in chunk for _ in (0, 1)]
        dsc = jax.tree.map(lambda *a: np.stack(a), *ds)  # (x's, F's) of each mode
        U = np.stack([u for _ in chunk for u in (xp, Fp)])
        foh = np.tile([1.0, 0.0], len(chunk))
        V = np.asarray(_filter_systems(dsc, U, foh), np.float64)
        for j, (w, _) in enumerate(chunk[:m]):
            h = mode_output(V[2 * j : 2 * j + 2, :T], float(w))
            out.append((h[0], h[1]))
    return out


def mode_free_responses(modes, dt: float, T: int, k0: int = 0) -> np.ndarray:
    """(m, 2, T) :func:`mode_free_responses` of each mode (ω [rad/s], ζ) in ``modes`` (m, 2), in
    one pass (the mode profile asks for a few hundred); rows k0 … T − 1 (a streamed chunk's)."""
    modes = np.asarray(modes, np.float64).reshape(-1, 2)
    w, z = modes[:, :1], modes[:, 1:]
    t = np.arange(k0, T) * float(dt)
    wd = w * np.sqrt(np.maximum(1.0 - z * z, 0.0))
    env = np.exp(-z * w * t)
    return np.stack([env * np.cos(wd * t), env * np.sin(wd * t)], 1)


@jax.jit
def _seed_discretes(lam, dt) -> Discrete:
    """Two exact sampled filters of Λ₅ = (s + λ)⁵ (a batch, leading axis): outputs
    λ⁵s^k/Λ₅ for k = 1…4 (x's) and k = 0…3 (F's), for :func:`~._streaming.mode_seed`."""
    p = jnp.full((5,), -lam + 0j)
    bank = FilterBank.from_poles(p)
    Phi, G0, G1 = bank.discretise(dt)
    c = bank.coeffs
    eye = jnp.eye(5, dtype=c.dtype) * lam**5
    D = jnp.zeros((4,), c.dtype)
    one = lambda rows: Discrete(Phi, G0, G1, eye[rows], D, c[-1])
    return jax.tree.map(lambda *a: jnp.stack(a), one(jnp.arange(1, 5)), one(jnp.arange(4)))


def seed_design(X, Fv):
    """(A (T, 6), y (T,)) of :func:`~._streaming.mode_seed`'s fit from the filtered x (s¹…s⁴) and F
    (s⁰…s³), (T, 4) each."""
    A = np.stack([-X[:, 2], -X[:, 1], -X[:, 0], Fv[:, 2], Fv[:, 1], Fv[:, 0]], 1)
    return A, X[:, 3]


def seed_mode(c) -> tuple[float, float] | None:
    """(ω, ζ) of :func:`~._streaming.mode_seed`'s coefficients ``c`` (6,), or None."""
    c1, c2, c3, _, c5, c6 = (float(v) for v in c)
    with np.errstate(all="ignore"):
        r = c5 / c6
        W = c3 / (c1 + r * r * c3 - r * c2)
        zeta = r * math.sqrt(W) / 2 if W > 0 else math.nan
    if not (math.isfinite(W) and W > 0 and math.isfinite(zeta) and zeta > 0):
        return None
    return math.sqrt(W), zeta


def _mode_stage(omega, zeta, lam, dt, drive: int):
    """(Φ_pp (2, 2), Φ_pv (2, 3), Γ₀ (2,), Γ₁ (2,)) of the exact sampled cascade: the diagnosis
    filter λ³/(s + λ)³ in balanced states v̂ⱼ = Vⱼ₊₁/λʲ (v̂ = (V₁, V₂/λ, V₃/λ²): v̂₀' = λv̂₁,
    v̂₁' = λv̂₂, v̂₂' = λ(u − 3v̂₂ − 3v̂₁ − v̂₀)), followed by the mode stage p = (p₀, p₁),
    p₀ = ω²/D[v̂_drive], p₁ = p₀'/ω (p₀' = ωp₁, p₁' = ω(v̂_drive − p₀ − 2ζp₁)). The pair is one
    linear system of order 5 whose exact first-order-hold sampling (:func:`sample_hold`) is
    block-triangular: the rows of p are all the mode needs, since v̂ is
    the diagnosis filter's own (already computed) output. Every entry of the matrix is O(λh) or
    O(ωh): balanced for any pole."""
    A = jnp.zeros((5, 5), omega.dtype)
    A = A.at[0, 1].set(lam).at[1, 2].set(lam)
    A = A.at[2, 0].set(-lam).at[2, 1].set(-3 * lam).at[2, 2].set(-3 * lam)
    A = A.at[3, 4].set(omega)
    A = A.at[4, drive].set(omega).at[4, 3].set(-omega).at[4, 4].set(-2 * zeta * omega)
    B = jnp.zeros((5,), omega.dtype).at[2].set(lam)
    Phi, G0, G1 = sample_hold(A * dt, B * dt)
    return Phi[3:5, 3:5], Phi[3:5, :3], G0[3:5], G1[3:5]


@jax.jit
def _mode_stages(omega, zeta, lam, dt):
    """:func:`_mode_stage` of x's (driven by v̂₂) and F's (by v̂₀) for each mode (m,): arrays
    with leading axes (m, 2)."""

    def one(w, z):
        return jax.tree.map(
            lambda a, b: jnp.stack([a, b]),
            _mode_stage(w, z, lam, dt, 2),
            _mode_stage(w, z, lam, dt, 0),
        )

    return jax.vmap(one)(omega, zeta)


def mode_cascade_from(stages, zeta, lam, Vx, u, du, VF, F, p0):
    """(x's columns (m, T), F's columns (m, T), the stages' states after the last sample
    (2m, 2)) of the mode stages from the states ``p0`` (2m, 2: x's of each mode, then F's),
    given the diagnosis filter's outputs ``Vx``, ``VF`` (T, 4), x's held samples ``u`` and
    steps ``du``, and F's samples: :func:`_mode_cascade` on a whole record, and on each chunk
    of a streamed one (:mod:`._streaming`) with the states carried between chunks."""
    Ppp, Ppv, G0, G1 = stages
    scale = jnp.stack([jnp.ones_like(lam), lam, lam * lam])
    vx, vF = Vx[:, :3] / scale, VF[:, :3] / scale
    bx = (
        matvec_unrolled(Ppv[:, 0, None], vx[None])  # (m, T, 2)
        + u[:, None] * G0[:, 0, None]
        + du[:, None] * G1[:, 0, None]
    )
    bF = matvec_unrolled(Ppv[:, 1, None], vF[None]) + F[:, None] * G0[:, 1, None]
    m = zeta.shape[0]
    Phis = jnp.concatenate([Ppp[:, 0], Ppp[:, 1]])
    b = jnp.concatenate([bx, bF])
    P = jax.vmap(lambda Phi, b, z0: _recursion(Phi, (b,), lambda bk: bk, z0))(Phis, b, p0)
    end = jax.vmap(lambda Phi, p, bk: matvec_unrolled(Phi, p) + bk)(Phis, P[:, -1], b[:, -1])
    px, pF = P[:m], P[m:]
    z = zeta[:, None]
    # (s²/D)[V₃] = λ²(s²/D)[v̂₂] = λ²(v̂₂ − p₀ − 2ζp₁), and (s²/D)[V₁] = V₁ − p₀ − 2ζp₁
    return (
        Vx[None, :, 2] - lam * lam * (px[:, :, 0] + 2 * z * px[:, :, 1]),
        VF[None, :, 0] - (pF[:, :, 0] + 2 * z * pF[:, :, 1]),
        end,
    )


def impulse_gains(bank: FilterBank, dt, a) -> tuple[float, float]:
    """Σh² of ε₁'s response to unit white noise on x (foh) and on b·F (zoh).

    ε₁ ∋ (s² + as)/Λ[x] − b/Λ[F] (unit-DC-gain bank), so a noise σ_x on x and σ_F on F add
    σ_x²·Σh_x² + b²σ_F²·Σh_F² to the variance of ε₁ (the noise floor).
    """
    c = np.asarray(bank.coeffs)
    T = int(round(float(20 * c[-2] / c[-1] / dt))) + 64
    Tp = padded_length(T)
    d = np.zeros((2, Tp))
    d[:, 1] = 1.0
    V = filter_signals(Discrete.of(bank, dt), d, np.array([1.0, 0.0]))[:, :T]
    hx = V[0, :, 2] + a * V[0, :, 1]
    hF = V[1, :, 0]
    return float(np.sum(hx * hx)), float(np.sum(hF * hF))


def _f(v):
    return np.asarray(v, np.float64)


def _i(v):
    return np.asarray(v, np.int64)
