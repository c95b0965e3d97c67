"""Lion's estimator θ̇ = −G Wᵀε, ε = Wθ + W₀ (P. M. Lion, AIAA J. 5, 1967; paper eq. 11).

Three ways to integrate it over sampled data, chosen by a *stepper* Module:

- :class:`ExactStep` (default): over each sample interval the regressors are frozen (at the
  interval's midpoint average by default) and the linear θ-dynamics are solved in closed form.
  With S = W G Wᵀ (2×2, symmetric PSD) the exact solution of θ̇ = −G Wᵀ(Wθ + W₀) over h is

      θ ← θ − G Wᵀ φ(S) (Wθ + W₀),    φ(S) = (I − e^{−hS}) S⁻¹,

  (since (GWᵀW)ⁿ = GWᵀSⁿ⁻¹W). φ is evaluated for the 2×2 S in closed form from its
  eigenvalues with guarded limits, never with a generic ``expm``: φ → hI for small S and
  φ → S⁻¹ (a projection onto ε = 0) for large S, so the step is stable for any G.
- :class:`EulerStep`: θ ← θ − h G Wᵀε — explicit Euler, only stable while h·‖GWᵀW‖ < 2; each
  step is checked and a violation is reported as ``RESULTS.unstable_step``.
- :class:`DiffraxStep`: the joint continuous-time ODE of the filter states and θ, on the
  interpolated raw signals (``foh`` linear, ``zoh`` held), solved by diffrax with an adaptive,
  stiff-capable solver (Kvaerno5 by default).

The normalised law θ̇ = −G Wᵀε / (1 + μ‖W‖²_F) is the same with G scaled per sample.
"""

from __future__ import annotations

import abc
from typing import Literal

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._errors import RESULTS, InputError
from ._filters import FilterBank
from ._models import AbstractModel, Regressors
from ._phi import phi_sym2
from ._record import Record
from ._solution import check_duration, finish, transient_mask

# ----------------------------------------------------------------------------------------------
# Gains


class AbstractGain(eqx.Module):
    """How the gain matrix G (p×p, symmetric positive definite) is chosen."""

    @abc.abstractmethod
    def __call__(self, regs: Regressors, mask: Array) -> tuple[Array, Array]:
        """Return (G, ok) for these regressors; ``ok`` is False when G cannot be formed."""


class FixedGain(AbstractGain):
    """A given gain: a scalar g (G = g·I) or a full symmetric positive definite matrix.

    The paper uses G = 10⁴·I (with x in m this converges slowly; see docs/method.md, "Lion's law").
    """

    matrix: Float[Array, "..."]

    def __init__(self, matrix: ArrayLike):
        self.matrix = jnp.asarray(matrix, dtype=jnp.result_type(float))

    def __check_init__(self):
        G = self.matrix
        if G.ndim not in (0, 2) or (G.ndim == 2 and G.shape[0] != G.shape[1]):
            raise InputError(
                f"FixedGain: expected a scalar or a square matrix, got shape {G.shape}."
            )
        if not isinstance(G, jax.core.Tracer):
            import numpy as np

            g = np.asarray(G, dtype=np.float64)
            if not np.all(np.isfinite(g)):
                raise InputError("FixedGain: the gain must be finite.")
            if g.ndim == 0 and not g > 0:
                raise InputError(f"FixedGain: a scalar gain must be positive, got {float(g)}.")
            if g.ndim == 2:
                if not np.allclose(g, g.T, rtol=1e-10, atol=0.0):
                    raise InputError(
                        "FixedGain: G must be symmetric positive definite, but G ≠ Gᵀ "
                        f"(max |G − Gᵀ| = {np.max(np.abs(g - g.T)):.3g}). Use (G + Gᵀ)/2."
                    )
                ev = np.linalg.eigvalsh(g)
                if ev.min() <= 0:
                    raise InputError(
                        "FixedGain: G must be symmetric positive definite, but its smallest "
                        f"eigenvalue is {ev.min():.3g}."
                    )

    def __call__(self, regs: Regressors, mask: Array) -> tuple[Array, Array]:
        p = regs.W.shape[-1]
        G = self.matrix
        if G.ndim == 0:
            G = G * jnp.eye(p, dtype=regs.W.dtype)
        elif G.shape != (p, p):
            raise InputError(
                f"FixedGain: the model has {p} parameters {regs.names}, but G has shape "
                f"{G.shape}; pass a scalar or a {p}×{p} matrix."
            )
        return G.astype(regs.W.dtype), jnp.array(True)


class AutoGain(AbstractGain):
    """G = rate · R⁻¹, R = mean over the record of WₖᵀWₖ (after the filter transient).

    The averaged dynamics become θ̇ ≈ −rate·(θ − θ_LS): every parameter direction converges with
    time constant 1/rate [s], whatever the units, scales and filter gain. This is the default:
    it converges on an ordinary device record without tuning. Noise in θ(t) grows with ``rate``.
    """

    rate: float | Array = 1.0
    max_condition: float = eqx.field(static=True, default=1e12)

    def __call__(self, regs: Regressors, mask: Array) -> tuple[Array, Array]:
        W = regs.W
        R = jnp.einsum("t,tip,tiq->pq", mask, W, W) / jnp.maximum(jnp.sum(mask), 1.0)
        scale = jnp.sqrt(jnp.clip(jnp.diagonal(R), jnp.finfo(W.dtype).tiny, None))
        Rn = R / scale[:, None] / scale[None, :]
        ev, V = jnp.linalg.eigh(Rn)
        ok = ev[0] > ev[-1] / self.max_condition
        ev_safe = jnp.where(ok, ev, 1.0)
        Ginv = (V / ev_safe) @ V.T
        G = self.rate * Ginv / scale[:, None] / scale[None, :]
        return 0.5 * (G + G.T), ok


# ----------------------------------------------------------------------------------------------
# Steppers


class AbstractStepper(eqx.Module):
    """How θ̇ = −c(W)·G Wᵀ(Wθ + W₀) is integrated between samples."""


class ExactStep(AbstractStepper):
    """Closed-form step over each interval with frozen regressors (module docstring).

    Attributes:
        regressors: ``"midpoint"`` (default; W over [tₖ, tₖ₊₁] is (Wₖ + Wₖ₊₁)/2, second order
            against the continuous-time law) or ``"zoh"`` (Wₖ, causal).
    """

    regressors: Literal["midpoint", "zoh"] = eqx.field(static=True, default="midpoint")

    def __check_init__(self):
        if self.regressors not in ("midpoint", "zoh"):
            raise InputError(
                f"ExactStep: regressors must be 'midpoint' or 'zoh', got {self.regressors!r}."
            )


class EulerStep(AbstractStepper):
    """Explicit Euler θ ← θ − h·c·G Wₖᵀεₖ; guarded: h·c·‖GWₖᵀWₖ‖ > 2 is reported as a failure."""


class DiffraxStep(AbstractStepper):
    """Joint continuous-time ODE (filter states + θ) on interpolated signals, solved by diffrax.

    Attributes:
        solver: a diffrax solver (default ``Kvaerno5()``, implicit: stiff gains are fine).
        rtol, atol: tolerances of the PID step-size controller; steps are clipped to the
            sample instants (where held signals jump).
        max_steps: step budget (default 64 per sample).
    """

    solver: diffrax.AbstractSolver = diffrax.Kvaerno5()
    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps_per_sample: int = eqx.field(static=True, default=64)


def _exact_update(theta, W, W0, G, h, mu):
    """One exact step for a single sample: W (2, p), W0 (2,), θ (p,)."""
    c = 1.0 / (1.0 + mu * jnp.sum(W * W))
    GW = c * (G @ W.T)  # (p, 2)
    S = W @ GW  # (2, 2)
    zp, zq, zr = phi_sym2(h * S[0, 0], h * 0.5 * (S[0, 1] + S[1, 0]), h * S[1, 1])
    eps = W @ theta + W0
    Ee = jnp.stack([zp * eps[0] + zq * eps[1], zq * eps[0] + zr * eps[1]])
    return theta - h * (GW @ Ee)


def _euler_update(theta, W, W0, G, h, mu):
    c = 1.0 / (1.0 + mu * jnp.sum(W * W))
    GW = c * (G @ W.T)
    eps = W @ theta + W0
    S = W @ GW
    # ‖G WᵀW‖ spectral radius = largest eigenvalue of S = W G Wᵀ (2×2 symmetric PSD).
    rho = 0.5 * (S[0, 0] + S[1, 1]) + jnp.sqrt(
        0.25 * (S[0, 0] - S[1, 1]) ** 2 + (0.5 * (S[0, 1] + S[1, 0])) ** 2
    )
    return theta - h * (GW @ eps), h * rho <= 2.0


class LionSolution(eqx.Module):
    """The trajectory of Lion's estimator.

    Attributes:
        t: save times, shape ``(K,)`` [s] (every ``save_every``-th sample, the last included).
        theta: estimates θ(t), shape ``(K, p)``.
        eps: equation errors ε(t) = W θ(t) + W₀, shape ``(K, 2)``.
        J: cost ½εᵀε, shape ``(K,)``.
        theta_final: θ at the last sample, shape ``(p,)``.
        gain: the gain matrix G used, ``(p, p)``.
        names: parameter names; result: a :class:`RESULTS` code.
    """

    t: Float[Array, " K"]
    theta: Float[Array, "K p"]
    eps: Float[Array, "K 2"]
    J: Float[Array, " K"]
    theta_final: Float[Array, " p"]
    gain: Float[Array, "p p"]
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS

    def params(self) -> dict[str, Array]:
        """Final estimate by name."""
        return {n: self.theta_final[..., i] for i, n in enumerate(self.names)}


def _diffrax_theta(model, bank, record, G, mu, theta0, stepper: DiffraxStep):
    """θ at every sample from the joint continuous-time ODE (see :class:`DiffraxStep`)."""
    sigs = model.signals(record)
    keys = list(sigs)
    U = jnp.stack([sigs[k][0] for k in keys]).astype(theta0.dtype)  # (S, T)
    foh = jnp.array([sigs[k][1] == "foh" for k in keys])
    A, B, C, D = bank.state_space()
    T = record.n_samples
    h = record.dt
    ts = record.t
    cols = model.columns()
    col_sig = [keys.index(c.signal) for c in cols]
    x_index = keys.index("x")

    def inputs(t):
        s = (t - record.t0) / h
        k = jnp.clip(jnp.floor(s), 0, T - 2).astype(jnp.int32)
        frac = jnp.clip(s - k, 0.0, 1.0)
        u0, u1 = U[:, k], U[:, k + 1]
        return jnp.where(foh, u0 + frac * (u1 - u0), u0)

    def regs(z, u):
        out = z @ C.T + u[:, None] * D  # (S, 4)
        W = jnp.stack(
            [c.sign * out[i, c.order : c.order + 2] for c, i in zip(cols, col_sig, strict=True)],
            axis=-1,
        )
        return W, out[x_index, 2:4]

    def field(t, y, args):
        z, theta = y
        u = inputs(t)
        dz = z @ A.T + u[:, None] * B
        W, W0 = regs(z, u)
        c = 1.0 / (1.0 + mu * jnp.sum(W * W))
        dtheta = -c * (G @ (W.T @ (W @ theta + W0)))
        return dz, dtheta

    z0 = bank.steady_state(U[:, 0])
    controller = diffrax.ClipStepSizeController(
        diffrax.PIDController(rtol=stepper.rtol, atol=stepper.atol), jump_ts=ts
    )
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        stepper.solver,
        t0=ts[0],
        t1=ts[-1],
        dt0=h / 4,
        y0=(z0, theta0),
        saveat=diffrax.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=stepper.max_steps_per_sample * T,
        throw=False,
    )
    ok = sol.result == diffrax.RESULTS.successful
    return sol.ys[1], ok


def lion(
    model: AbstractModel,
    record: Record,
    *,
    bank: FilterBank | None = None,
    gain: AbstractGain | None = None,
    stepper: AbstractStepper | None = None,
    normalisation: float | Array = 0.0,
    theta0: ArrayLike | None = None,
    save_every: int = 1,
    transient: float | Array | None = None,
    throw: bool = True,
) -> LionSolution:
    """Run Lion's estimator θ̇ = −G Wᵀε / (1 + μ‖W‖²) over a record.

    Arguments:
        model: the model structure (e.g. ``MassDamper()``, ``Piecewise((-0.01, 0.01))``).
        record: the data (one record; ``jax.vmap`` this function for many).
        bank: the filter Λ (default ``FilterBank.from_poles([-4, -4, -4], unit_dc_gain=True)``,
            the paper's poles with unit DC gain).
        gain: :class:`AutoGain` (default, rate 1/s) or :class:`FixedGain` (the paper:
            ``FixedGain(1e4)`` with ``FilterBank.paper()``).
        stepper: :class:`ExactStep` (default), :class:`EulerStep` or :class:`DiffraxStep`.
        normalisation: μ ≥ 0 of the normalised law (0: Lion's plain law).
        theta0: initial estimate, shape ``(p,)`` (default zeros, as in the paper).
        save_every: keep every n-th sample of the trajectory (the last sample always kept).
        transient: seconds excluded when forming data-dependent gains (default 3·λₙ₋₁/λₙ, three
            times the filter's mean delay).
        throw: raise on failure (unexcited parameters for ``AutoGain``, unstable Euler, NaN);
            with ``False`` the failure is carried in ``result`` (use under ``vmap``, then
            :func:`lionjax.raise_if_failed`).

    Returns:
        A :class:`LionSolution`.
    """
    bank = default_bank() if bank is None else bank
    gain = AutoGain() if gain is None else gain
    stepper = ExactStep() if stepper is None else stepper
    if not isinstance(save_every, int) or save_every < 1:
        raise InputError(f"lion: save_every must be a positive integer, got {save_every!r}.")
    for arg, val, typ in (
        ("model", model, AbstractModel),
        ("record", record, Record),
        ("bank", bank, FilterBank),
        ("gain", gain, AbstractGain),
        ("stepper", stepper, AbstractStepper),
    ):
        if not isinstance(val, typ):
            raise InputError(f"lion: {arg} must be a {typ.__name__}, got {type(val).__name__}.")
    check_duration(record, bank, "lion")
    sol = _lion(model, record, bank, gain, stepper, normalisation, theta0, save_every, transient)
    return finish(sol, throw, what="lion")


@eqx.filter_jit
def _lion(model, record, bank, gain, stepper, normalisation, theta0, save_every, transient):
    regs = model.regressors(record, bank)
    W, W0 = regs.W, regs.W0
    T, _, p = W.shape
    dtype = W.dtype
    theta0 = jnp.zeros((p,), dtype) if theta0 is None else jnp.asarray(theta0, dtype)
    if theta0.shape != (p,):
        raise InputError(
            f"lion: theta0 must have shape ({p},) for parameters {regs.names}, got {theta0.shape}."
        )
    mu = jnp.asarray(normalisation, dtype)
    mask = transient_mask(record, bank, transient)
    G, gain_ok = gain(regs, mask)
    h = record.dt.astype(dtype)
    ok = gain_ok
    if isinstance(stepper, DiffraxStep):
        thetas, solver_ok = _diffrax_theta(model, bank, record, G, mu, theta0, stepper)
        result = RESULTS.where(solver_ok, RESULTS.successful, RESULTS.nonfinite)
    else:
        if isinstance(stepper, ExactStep) and stepper.regressors == "midpoint":
            Ws, W0s = 0.5 * (W[:-1] + W[1:]), 0.5 * (W0[:-1] + W0[1:])
        else:
            Ws, W0s = W[:-1], W0[:-1]
        if isinstance(stepper, EulerStep):

            def step(carry, inputs):
                theta, stable = carry
                theta, st = _euler_update(theta, *inputs, G, h, mu)
                return (theta, stable & st), theta

            (_, stable), thetas = jax.lax.scan(step, (theta0, jnp.array(True)), (Ws, W0s))
            result = RESULTS.where(stable, RESULTS.successful, RESULTS.unstable_step)
        elif isinstance(stepper, ExactStep):

            def step(theta, inputs):
                theta = _exact_update(theta, *inputs, G, h, mu)
                return theta, theta

            _, thetas = jax.lax.scan(step, theta0, (Ws, W0s))
            result = RESULTS.successful
        else:
            raise InputError(f"lion: unknown stepper {type(stepper).__name__}.")
        thetas = jnp.concatenate([theta0[None], thetas])
    eps = jnp.einsum("tip,tp->ti", W, thetas) + W0
    J = 0.5 * jnp.sum(eps * eps, axis=-1)
    idx = np.unique(np.concatenate([np.arange(0, T, save_every), [T - 1]]))
    finite = jnp.all(jnp.isfinite(thetas))
    result = RESULTS.where(ok, result, RESULTS.unidentifiable)
    result = RESULTS.where(finite | ~(result == RESULTS.successful), result, RESULTS.nonfinite)
    sol = LionSolution(
        t=record.t[idx],
        theta=thetas[idx],
        eps=eps[idx],
        J=J[idx],
        theta_final=thetas[-1],
        gain=G,
        names=regs.names,
        result=result,
    )
    return sol


def default_bank() -> FilterBank:
    """The default filter: the paper's poles (s + 4)³ with unit DC gain."""
    return FilterBank.from_poles(jnp.array([-4.0, -4.0, -4.0]), unit_dc_gain=True)
