"""Fitting and scoring one model structure on recorded data (no twin, GUIDE §12 layer 3).

A *structure* is the mass–damper ẍ + aẋ = b·u plus linear effect columns (:mod:`lionjax._effects`)
plus an input map u = sat_Fmax(F(t − τ)) that is nonlinear in τ and F_max (profiled on a grid).

Least squares on the first equation error only. ε₁ = V₃ + aV₂ − bQ₁ + … is the filtered equation
of motion; the core's :func:`lionjax.least_squares` also stacks ε₂ = dε₁/dt (the paper's second
row), which weights the fit by frequency and, on real data with unmodelled high-frequency
dynamics, biases the viscous term (EMPS at λ = 40 Hz: Fv +86 % with both rows, +0.7 % with ε₁).
So the diagnosis solves the ε₁ rows (plus the filter's initial-state nuisance columns, as the core
does) with the core's regressors and filter bank.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._filters import FilterBank
from .._models import AbstractModel
from .._record import Record


def apply_input(F: Float[Array, " T"], dt, tau, fmax) -> Float[Array, " T"]:
    """u = sat_Fmax(F(t − τ)) at the samples, for a force held between samples [N].

    With τ = (n + φ)·dt the delayed held force averaged over each interval is
    (1 − φ)F[k − n] + φF[k − n − 1] (F before the record = F[0]); the clip is hard.
    """
    T = F.shape[-1]
    t = jnp.arange(T, dtype=F.dtype)
    Fd = jnp.interp(t - tau / dt, t, F, left=F[0], right=F[-1])
    return jnp.clip(Fd, -fmax, fmax)


def _design(model: AbstractModel, record: Record, bank: FilterBank):
    regs = model.regressors(record, bank)
    T = record.n_samples
    N = bank.free_response(record.dt, T)[:, :, 0]  # (T, n): V₁ of each free response
    return regs.W[:, 0, :], regs.W0[:, 0], N.astype(regs.W.dtype)


def _lstsq(Phi, y):
    norms = jnp.sqrt(jnp.sum(Phi * Phi, axis=0))
    scale = jnp.where(norms > 0, norms, 1.0)
    U, s, Vt = jnp.linalg.svd(Phi / scale, full_matrices=False)
    keep = s > s[0] * 1e-12
    sinv = jnp.where(keep, 1.0 / jnp.where(keep, s, 1.0), 0.0)
    coef = (Vt.T * sinv) @ (U.T @ y)
    cond = s[0] / jnp.maximum(s[-1], jnp.finfo(s.dtype).tiny)
    cov_n = (Vt.T * sinv**2) @ Vt
    return coef / scale, cov_n / scale[:, None] / scale[None, :], cond


def _fit_one(model, x, F, dt, bank):
    rec = Record(x, F, dt)
    W1, W01, N = _design(model, rec, bank)
    p = W1.shape[1]
    Phi = jnp.concatenate([W1, N], axis=1)
    coef, cov, cond = _lstsq(Phi, -W01)
    r = Phi @ coef + W01
    rss = jnp.sum(r * r)
    sigma2 = rss / jnp.maximum(r.shape[0] - Phi.shape[1], 1)
    return coef[:p], rss, sigma2 * cov[:p, :p], cond


@eqx.filter_jit
def fit_batch(
    model: AbstractModel, x: Float[Array, " T"], Fs: Float[Array, "G T"], dt, bank: FilterBank
):
    """ε₁ least squares for each force variant in ``Fs`` (the profile grid of τ or F_max).

    Returns θ ``(G, p)``, the training RSS ``(G,)``, the nominal covariance σ²(ΦᵀΦ)⁻¹
    ``(G, p, p)`` and the condition number ``(G,)`` of the column-normalised regressors.
    """
    return jax.vmap(lambda F: _fit_one(model, x, F, dt, bank))(Fs)


@eqx.filter_jit
def residual(
    model: AbstractModel, theta: Float[Array, " p"], record: Record, bank: FilterBank
) -> Float[Array, " T"]:
    """ε₁ at every sample of ``record`` for fixed θ (validation): only the filter's
    initial-state nuisance coefficients are refitted on this record."""
    W1, W01, N = _design(model, record, bank)
    r0 = W1 @ theta + W01
    eta, _, _ = _lstsq(N, -r0)
    return r0 + N @ eta


def impulse_gains(bank: FilterBank, dt, a) -> tuple[Array, Array]:
    """Σh² of ε₁'s response to unit white noise on x (foh) and on b·F (zoh).

    ε₁ ∋ (s² + as)/Λ[x] − b/Λ[F] (unit-DC-gain bank), so a noise σ_x on x and σ_F on F add
    σ_x²·Σh_x² + b²σ_F²·Σh_F² to the variance of ε₁ (the noise floor).
    """
    T = int(round(float(20 * bank.coeffs[-2] / bank.coeffs[-1] / dt))) + 64
    d = jnp.zeros((T,)).at[1].set(1.0)
    Vx = bank(d, dt, "foh", init="zero")
    VF = bank(d, dt, "zoh", init="zero")
    hx = Vx[:, 2] + a * Vx[:, 1]
    hF = VF[:, 0]
    return jnp.sum(hx * hx), jnp.sum(hF * hF)


def _step(x, v, c, a, h):
    """Exact step of ẍ = −aẋ + c over h with c held (series for small a·h)."""
    ah = a * h
    small = jnp.abs(ah) < 1e-6
    ahs = jnp.where(small, 1.0, ah)
    e = jnp.exp(-ah)
    phi1 = jnp.where(small, h * (1 - ah / 2), (1 - e) / jnp.where(small, 1.0, a))
    phi2 = jnp.where(small, h * h / 2 * (1 - ah / 3), (h - phi1) / jnp.where(small, 1.0, a))
    del ahs
    return x + v * phi1 + c * phi2, v * e + c * phi1


@eqx.filter_jit
def simulate_windows(
    p: dict[str, Array],
    u: Float[Array, " T"],
    x_meas: Float[Array, " T"],
    x_start: Float[Array, " T"],
    v_start: Float[Array, " T"],
    dt,
    H: int,
) -> Float[Array, " T"]:
    """Windowed simulation error x_sim − x_meas [m], restarting every ``H`` samples.

    Model: ẍ + a(x)ẋ = b(x)·(u + F₀ + c − F_c·sgn ẋ − k·x), a(x) = a + a'(x − x_c),
    b(x) = b + b'(x − x_c), u the mapped input (held), stepped exactly per sample with the
    nonlinear terms held over the sample. Coulomb friction sticks when the velocity would reverse
    within a step while the other forces stay inside ±F_c. Each window starts from the estimated
    state (x_start, v_start) at its first sample.
    """
    T = u.shape[0]
    nw = T // H
    Tn = nw * H
    idx = jnp.arange(Tn).reshape(nw, H)
    u_w, xm_w = u[idx], x_meas[idx]
    x0, v0 = x_start[idx[:, 0]], v_start[idx[:, 0]]
    a, b = p["a"], p["b"]
    Fc = p.get("Fc", 0.0)

    def body(carry, k):
        x, v = carry
        dx = x - p.get("xc", 0.0)
        ak = a + p.get("da_dx", 0.0) * dx
        bk = b + p.get("db_dx", 0.0) * dx
        other = u_w[:, k] + p.get("F0", 0.0) + p.get("c", 0.0) - p.get("k", 0.0) * x
        s = jnp.sign(v)
        s = jnp.where(s == 0, jnp.sign(other) * (jnp.abs(other) > Fc), s)
        x1, v1 = _step(x, v, bk * (other - Fc * s), ak, dt)
        stick = (Fc > 0) & (s * v1 < 0) & (jnp.abs(other) <= Fc)
        stuck = (s == 0) & (Fc > 0)
        v1 = jnp.where(stick | stuck, 0.0, v1)
        x1 = jnp.where(stuck, x, x1)
        return (x1, v1), x

    _, xs = jax.lax.scan(body, (x0, v0), jnp.arange(H))
    err = jnp.swapaxes(xs, 0, 1) - xm_w
    return jnp.concatenate([err.reshape(-1), jnp.zeros((T - Tn,), err.dtype)])
