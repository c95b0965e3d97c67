"""The diagnosis' filter kernels: the bank (s + λ)³ sampled exactly (:class:`Discrete`) under a
zero- or first-order hold, its linear recursion in about 2√T sequential steps, and a flexible
mode's stages (s²/D)[·] after it. :mod:`._streaming` runs them chunk by chunk; every compiled
program sees bucketed lengths (:func:`padded_length`) and traced settings."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._filters import FilterBank, sample_hold
from .._linalg import matvec_unrolled

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


def _powers(Phi, L: int):
    """Φʲ (L, n, n) for j = 0 … L − 1, by a scan of elementwise products."""

    def step(Z, _):
        return matvec_unrolled(Phi, Z.T).T, Z  # Φ·Z

    return jax.lax.scan(step, jnp.eye(Phi.shape[-1], dtype=Phi.dtype), None, length=L)[1]


def _recursion(Phi, inputs, drive, z0):
    """States z[k] (T, n) of z[k + 1] = Φz[k] + drive(inputs[k]), z[0] = ``z0`` (``inputs``
    arrays of leading axis T, ``drive`` mapping their rows to (·, n) input terms).

    In M blocks of L samples (L·M = T, L ≈ √T): every block's zero-state response in parallel
    (L steps), the blocks' start states z_{m+1} = Φᴸz_m + (block m's end state) (M steps), then
    Φʲ·z_m added back: exact, ~2√T sequential steps instead of T. Products elementwise
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


def filter_from(dsc: Discrete, u_at, u, du, z0):
    """(outputs Cz + D·u_at (T, r), the state after the last sample (n,)) of
    z[k+1] = Φz[k] + Γ₀u[k] + Γ₁du[k] from ``z0``: one chunk of :class:`~._streaming.Filters`."""

    def drive(uk, duk):
        return uk[:, None] * dsc.G0 + duk[:, None] * dsc.G1

    z = _recursion(dsc.Phi, (u, du), drive, z0)
    end = matvec_unrolled(dsc.Phi, z[-1]) + drive(u[-1:], du[-1:])[0]
    return matvec_unrolled(dsc.C, z) + u_at[:, None] * dsc.D, end


def mode_free_responses(modes, dt: float, T: int, k0: int = 0) -> np.ndarray:
    """(m, 2, T − k0) free responses e^{−ζωt}(cos ω_d t, sin ω_d t) of each mode (ω [rad/s], ζ)
    of ``modes`` (m, 2) at rows k0 … T − 1, ω_d = ω√(1 − ζ²)."""
    modes = np.asarray(modes, np.float64).reshape(-1, 2)
    w, z = modes[:, :1], modes[:, 1:]
    t = np.arange(k0, T) * float(dt)
    wd = w * np.sqrt(np.maximum(1.0 - z * z, 0.0))
    env = np.exp(-z * w * t)
    return np.stack([env * np.cos(wd * t), env * np.sin(wd * t)], 1)


@jax.jit
def seed_discrete(lam, dt) -> Discrete:
    """The exact sampled filter of Λ₅ = (s + λ)⁵ with the five outputs λ⁵sᵏ/Λ₅, k = 0 … 4."""
    bank = FilterBank.from_poles(jnp.full((5,), -lam + 0j))
    Phi, G0, G1 = bank.discretise(dt)
    c = bank.coeffs
    return Discrete(Phi, G0, G1, jnp.eye(5, dtype=c.dtype) * lam**5, jnp.zeros(5, c.dtype), c[-1])


def _mode_stage(omega, zeta, lam, dt, drive: int):
    """(Φ_pp (2, 2), Φ_pv (2, 3), Γ₀ (2,), Γ₁ (2,)) of the exact sampled cascade: the filter
    λ³/(s + λ)³ in balanced states v̂ = (V₁, V₂/λ, V₃/λ²) (v̂₀' = λv̂₁, v̂₁' = λv̂₂,
    v̂₂' = λ(u − 3v̂₂ − 3v̂₁ − v̂₀)), then the mode stage p₀ = ω²/D[v̂_drive], p₁ = p₀'/ω
    (p₁' = ω(v̂_drive − p₀ − 2ζp₁)). Its first-order-hold sampling is block-triangular: p's rows
    are all the mode needs, v̂ being the filter's own output. Entries O(λh) or O(ωh): balanced."""
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
    """:func:`_mode_stage` of x's (driven by v̂₂) and F's (by v̂₀) for each mode: (m, 2, …)."""

    def one(w, z):
        return jax.tree.map(
            lambda a, b: jnp.stack([a, b]),
            _mode_stage(w, z, lam, dt, 2),
            _mode_stage(w, z, lam, dt, 0),
        )

    return jax.vmap(one)(omega, zeta)


def mode_cascade_from(stages, zeta, lam, Vx, u, du, VF, F, p0):
    """(x's columns (m, T), F's columns (m, T), the states after the last sample (2m, 2)) of
    the mode stages from ``p0`` (x's of each mode, then F's), given the filter's outputs ``Vx``,
    ``VF`` (T, 4), x's held samples ``u`` and steps ``du``, and F: one chunk of
    :class:`~._streaming.ModeStages`."""
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


def _f(v):
    return np.asarray(v, np.float64)


def _i(v):
    return np.asarray(v, np.int64)
