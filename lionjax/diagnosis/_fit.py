"""Fitting and scoring one model structure on recorded data (no twin: layer 3 of the package).

A *structure* is the mass–damper ẍ + aẋ = b·u plus linear effect columns
(:mod:`lionjax._model_effects`) plus an input map u = sat_Fmax(F(t − τ)) that is nonlinear in τ
and F_max (profiled on a grid).

Least squares on the first equation error only. ε₁ = V₃ + aV₂ − bQ₁ + … is the filtered equation
of motion; the core's :func:`lionjax.least_squares` also stacks ε₂ = dε₁/dt (the paper's second
row), which weights the fit by frequency and, on real data with unmodelled high-frequency
dynamics, biases the viscous term (EMPS at λ = 40 Hz: Fv +86 % with both rows, +0.7 % with ε₁).
So the diagnosis solves the ε₁ rows (plus the filter's initial-state nuisance columns, as the core
does) with the core's regressors and filter bank.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._filters import FilterBank
from .._least_squares import linear_lstsq
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


@eqx.filter_jit
def _filter(bank: FilterBank, u, dt, hold: str):
    return bank(u, dt, hold)


@eqx.filter_jit
def _filter_batch(bank: FilterBank, U, dt, hold: str):
    return jax.vmap(lambda u: bank(u, dt, hold))(U)


@eqx.filter_jit
def free_response(bank: FilterBank, dt, T: int):
    return bank.free_response(dt, T)[:, :, 0]


class Regressors:
    """ε₁ regressors of :class:`~lionjax.Augmented` structures on one record, built from the
    models' own :meth:`signals`/:meth:`columns` (as :meth:`AbstractModel.regressors` does), with
    every raw signal filtered once and cached: many structures and profile grids share them.

    The input u = sat_Fmax(F(t − τ)) replaces F in every signal that uses it (``"F"`` and the
    position-dependent ``ξ·F``); ``variants`` holds the filtered grid of such signals.
    """

    def __init__(self, record: Record, bank: FilterBank):
        self.record, self.bank = record, bank
        self.cache: dict = {}
        self.N = np.asarray(free_response(bank, record.dt, record.n_samples))

    def filtered(self, model: AbstractModel, inputs: Sequence[tuple[float, float]]):
        """{signal: (G, T, 4)} for each input map (τ, F_max) in ``inputs``."""
        rec = self.record
        out = {}
        base = model.signals(rec)
        F_dep = {"F", "xiF", "F_1"}
        for name, (u, hold) in base.items():
            if name not in F_dep:
                key = (name, None)
                if key not in self.cache:
                    self.cache[key] = np.asarray(_filter(self.bank, u, rec.dt, hold))[None]
                out[name] = np.broadcast_to(
                    self.cache[key], (len(inputs),) + self.cache[key].shape[1:]
                )
        need = [n for n in base if n in F_dep]
        for n in need:
            missing = [i for i in inputs if (n, i) not in self.cache]
            if missing:
                us = [apply_input(rec.F, rec.dt, t, f) for t, f in missing]
                sigs = [model.signals(Record(rec.x, uu, rec.dt))[n] for uu in us]
                U = jnp.stack([sg[0] for sg in sigs])
                V = np.asarray(_filter_batch(self.bank, U, rec.dt, sigs[0][1]))
                for i, v in zip(missing, V, strict=True):
                    self.cache[(n, i)] = v
            out[n] = np.stack([self.cache[(n, i)] for i in inputs])
        return out

    def design(self, model: AbstractModel, inputs: Sequence[tuple[float, float]]):
        """(W₁ (G, T, p), W₀₁ (T,)) for the first equation error."""
        filt = self.filtered(model, inputs)
        cols = [c.sign * filt[c.signal][:, :, c.order] for c in model.columns()]
        return np.stack(cols, axis=-1), filt["x"][0, :, 2]


def fit_batch(regs: Regressors, model: AbstractModel, inputs):
    """ε₁ least squares on the training record for each input map (τ, F_max) in ``inputs``.

    Returns θ ``(G, p)``, the RSS ``(G,)``, σ²(ΦᵀΦ)⁻¹ ``(G, p, p)`` and condition numbers.
    """
    W, W0 = regs.design(model, inputs)
    p = W.shape[-1]
    th, rss, cov, cond = [], [], [], []
    for g in range(W.shape[0]):
        Phi = np.concatenate([W[g], regs.N], axis=1)
        fit = linear_lstsq(jnp.asarray(Phi), jnp.asarray(W0))
        coef, c = np.asarray(fit.coef), np.asarray(fit.gram_inverse)
        rs = float(fit.rss)
        s2 = rs / max(Phi.shape[0] - Phi.shape[1], 1)
        th.append(coef[:p])
        rss.append(rs)
        cov.append(s2 * c[:p, :p])
        cond.append(float(fit.condition))
    return np.array(th), np.array(rss), np.array(cov), np.array(cond)


def residual(regs: Regressors, model: AbstractModel, theta, inp) -> np.ndarray:
    """ε₁ on ``regs.record`` for fixed θ (validation): only the filter's initial-state
    nuisance coefficients are refitted on this record."""
    W, W0 = regs.design(model, [inp])
    r0 = W[0] @ theta + W0
    eta = np.asarray(linear_lstsq(jnp.asarray(regs.N), jnp.asarray(r0)).coef)
    return r0 + regs.N @ eta


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
    e = jnp.exp(-ah)
    phi1 = jnp.where(small, h * (1 - ah / 2), (1 - e) / jnp.where(small, 1.0, a))
    phi2 = jnp.where(small, h * h / 2 * (1 - ah / 3), (h - phi1) / jnp.where(small, 1.0, a))
    return x + v * phi1 + c * phi2, v * e + c * phi1


def simulate_windows(
    p: dict[str, float],
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
    return _simulate_windows(p, u, x_meas, x_start, v_start, dt, H)


@eqx.filter_jit
def _simulate_windows(p, u, x_meas, x_start, v_start, dt, H):
    T = u.shape[0]
    nw = T // H
    Tn = nw * H
    idx = jnp.arange(Tn).reshape(nw, H)
    u_w, xm_w = u[idx], x_meas[idx]
    x0, v0 = x_start[idx[:, 0]], v_start[idx[:, 0]]
    a, b, Fc = p["a"], p["b"], p["Fc"]

    def body(carry, k):
        x, v = carry
        dx = x - p["xc"]
        ak = a + p["da_dx"] * dx
        bk = b + p["db_dx"] * dx
        other = u_w[:, k] + p["F0"] - p["k"] * x
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
