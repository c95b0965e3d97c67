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

The normalised law θ̇ = −G Wᵀε / (1 + μ‖W‖²_F) is the same with G scaled per sample; μ is a
field of the stepper (``ExactStep(normalisation=μ)``).

The steppers and gains are strategy Modules with abstract methods: :class:`AbstractGain` maps
the regressors' moment matrix R to G, :class:`AbstractStepper` integrates a record
(:meth:`AbstractStepper.trajectory`), and :class:`AbstractSampleStepper` (exact, Euler) does so
by one per-interval :meth:`~AbstractSampleStepper.increment`, which the streaming kernel of
:func:`lionjax.lion_batched` applies elementwise over a batch — one law for both entry points.
"""

# No ``from __future__ import annotations``: equinox reads AbstractVar annotations at runtime.
import abc
import dataclasses
from typing import TYPE_CHECKING, ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from equinox import AbstractClassVar, AbstractVar
from jaxtyping import Array, ArrayLike, Bool, Float

from ._errors import RESULTS, InputError
from ._filters import FilterBank
from ._models import AbstractModel, Regressors
from ._phi import SERIES_BOUND, _phi_series, exact_step, materialise, phi_sym2, step_products
from ._record import Record
from ._solution_tools import by_name, convergence_time, finish, transient_mask
from ._validity import (
    MAX_MOMENT_CONDITION,
    check_duration,
    check_filter_speed,
    check_record,
    check_theta0,
    column_reference,
    default_poles,
    explain_unexcited,
    normalise,
    unexcited,
    well_conditioned,
)

if TYPE_CHECKING:  # imported where an ODE is solved: `import lionjax` stays light
    import diffrax

# ----------------------------------------------------------------------------------------------
# Gains


class AbstractGain(eqx.Module):
    """How the gain matrix G (p×p, symmetric positive definite) is chosen.

    One rule serves :func:`lion` and :func:`lionjax.lion_batched`: G is a function of
    R = mean of WₖᵀWₖ over the samples after the filter transient (p×p; W the 2×p regressors),
    which :func:`lion` forms from the stored regressors and :func:`lionjax.lion_batched` from
    its streamed least-squares statistics. A gain whose values carry a leading batch axis
    (``batch_shape == (B,)``) gives every record of a batch its own gain.
    """

    #: Whether G depends on R (then the batched estimator streams the statistics first).
    uses_data: AbstractClassVar[bool]

    @property
    @abc.abstractmethod
    def batch_shape(self) -> tuple[int, ...]:
        """``()`` for one gain, ``(B,)`` for one gain per record of a batch."""

    @abc.abstractmethod
    def __call__(
        self, R: Float[Array, "p p"], names: tuple[str, ...]
    ) -> tuple[Float[Array, "p p"], Bool[Array, ""]]:
        """(G, ok) for one record with regressor moment matrix R (``ok`` False when G cannot
        be formed, e.g. unexcited parameters). ``names`` are the p parameter names (for
        errors)."""


def _check_gain_shape(G: Array, p: int, names: tuple[str, ...]) -> Array:
    if G.ndim == 0:
        return G * jnp.eye(p, dtype=G.dtype)
    if G.shape != (p, p):
        raise InputError(
            f"FixedGain: the model has {p} parameters {names}, but G has shape {G.shape}; "
            f"pass a scalar or a {p}×{p} matrix (a batch: (B,) or (B, {p}, {p}))."
        )
    return G


class FixedGain(AbstractGain):
    """A given gain: a scalar g (G = g·I) or a full symmetric positive definite matrix G.

    Attributes:
        matrix: g, shape ``()``, or G, ``(p, p)``; one per record of a batch: ``(B,)`` or
            ``(B, p, p)`` (then :func:`lionjax.lion_batched` gives record i the gain
            ``matrix[i]``). Units: those of θ² per (regressor² · s).

    The paper uses G = 10⁴·I (with x in mm and F in mN; in SI units this converges slowly;
    see docs/method.md, "Lion's law").
    """

    matrix: Float[Array, "..."]
    uses_data: ClassVar[bool] = False

    def __init__(self, matrix: ArrayLike):
        self.matrix = jnp.asarray(matrix, dtype=jnp.result_type(float))

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.matrix.shape[:1]) if self.matrix.ndim in (1, 3) else ()

    def __check_init__(self):
        G = self.matrix
        square = G.ndim in (2, 3) and G.shape[-1] == G.shape[-2]
        if G.ndim not in (0, 1) and not square:
            raise InputError(
                f"FixedGain: expected a scalar g or a square matrix G (a batch of them: (B,) or "
                f"(B, p, p)), got shape {G.shape}."
            )
        if not isinstance(G, jax.core.Tracer):
            g = np.asarray(G, dtype=np.float64)
            if not np.all(np.isfinite(g)):
                raise InputError("FixedGain: the gain must be finite.")
            if g.ndim <= 1 and not np.all(g > 0):
                raise InputError(
                    f"FixedGain: a scalar gain must be positive, got {np.min(g):g}. Pass g > 0."
                )
            if g.ndim >= 2:
                gm = g.reshape((-1,) + g.shape[-2:])
                asym = np.max(np.abs(gm - np.swapaxes(gm, -1, -2)))
                if not np.allclose(gm, np.swapaxes(gm, -1, -2), rtol=1e-10, atol=0.0):
                    raise InputError(
                        "FixedGain: G must be symmetric positive definite, but G ≠ Gᵀ "
                        f"(max |G − Gᵀ| = {asym:.3g}). Use (G + Gᵀ)/2."
                    )
                ev = np.linalg.eigvalsh(gm)
                if ev.min() <= 0:
                    raise InputError(
                        "FixedGain: G must be symmetric positive definite, but its smallest "
                        f"eigenvalue is {ev.min():.3g}."
                    )

    def __call__(self, R, names):
        if self.batch_shape:
            raise InputError(
                f"FixedGain: this gain holds {self.batch_shape[0]} values (one per record), "
                "but one record is being estimated; use lionjax.lion_batched, or index the gain "
                "(jax.tree.map(lambda a: a[i], gain))."
            )
        G = _check_gain_shape(self.matrix.astype(R.dtype), R.shape[-1], names)
        return G, jnp.array(True)


class AutoGain(AbstractGain):
    """G = rate · R⁻¹, R = mean over the record of WₖᵀWₖ (after the filter transient).

    The averaged dynamics become θ̇ ≈ −rate·(θ − θ_LS): every parameter direction converges with
    time constant 1/rate [s], whatever the units, scales and filter gain. This is the default:
    it converges on an ordinary device record without tuning. Noise in θ(t) grows with ``rate``.

    Attributes:
        rate: [1/s], shape ``()``, or ``(B,)`` for one rate per record of a batch.
        max_condition: R (column-normalised) with a larger condition number is a failure
            (unexcited parameters: ``RESULTS.unidentifiable``). Whatever the gain,
            :func:`lion` also applies the validity layer's check with
            ``lionjax._validity.MAX_MOMENT_CONDITION`` (the same default, 1e12).
    """

    rate: float | Array = 1.0
    max_condition: float = eqx.field(static=True, default=MAX_MOMENT_CONDITION)
    uses_data: ClassVar[bool] = True

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(jnp.shape(self.rate))

    def __check_init__(self):
        if jnp.ndim(self.rate) > 1:
            raise InputError(
                f"AutoGain: rate must be a number [1/s] or one per record, shape (B,), got "
                f"shape {jnp.shape(self.rate)}."
            )
        if not isinstance(self.rate, jax.core.Tracer):
            r = np.asarray(self.rate, dtype=np.float64)
            if not np.all(np.isfinite(r) & (r > 0)):
                raise InputError(
                    f"AutoGain: rate must be positive and finite [1/s], got {r.tolist()}."
                )

    def __call__(self, R, names):
        if self.batch_shape:
            raise InputError(
                f"AutoGain: this gain holds {self.batch_shape[0]} rates (one per record), but "
                "one record is being estimated; use lionjax.lion_batched, or index the gain "
                "(jax.tree.map(lambda a: a[i], gain))."
            )
        Rn, scale = normalise(R)
        ev, V = jnp.linalg.eigh(Rn)
        ok = well_conditioned(ev, self.max_condition)[0]
        ev_safe = jnp.where(ok, ev, 1.0)
        Ginv = (V / ev_safe) @ V.T
        G = self.rate * Ginv / scale[:, None] / scale[None, :]
        return 0.5 * (G + G.T), ok


def regressor_moments(regs: Regressors, mask: Array) -> Array:
    """R = Σₖ mₖ WₖᵀWₖ / Σₖ mₖ (p×p): the mean regressor outer product over the samples with
    weight ``mask`` (1 after the filter transient), what :class:`AbstractGain` rules see."""
    W = regs.W
    return jnp.einsum("t,tip,tiq->pq", mask, W, W) / jnp.maximum(jnp.sum(mask), 1.0)


# ----------------------------------------------------------------------------------------------
# Steppers


class AbstractStepper(eqx.Module):
    """How θ̇ = −c(W)·G Wᵀ(Wθ + W₀) is integrated between samples, c = 1/(1 + μ‖W‖²_F).

    Every stepper carries the normalisation μ ≥ 0 of the normalised law (``None``: Lion's
    plain law, c = 1).
    """

    normalisation: AbstractVar[float | Array | None]

    @abc.abstractmethod
    def trajectory(
        self,
        model: AbstractModel,
        bank: FilterBank,
        record: Record,
        regs: Regressors,
        G: Float[Array, "p p"],
        theta0: Float[Array, " p"],
    ) -> tuple[Float[Array, "T p"], RESULTS]:
        """θ at every sample of one record (row 0 = ``theta0``) and a :class:`RESULTS` code.

        ``regs`` are the record's regressors W (T, 2, p), W₀ (T, 2) under ``bank``."""


class AbstractSampleStepper(AbstractStepper):
    """A stepper that advances θ over one sample interval h with frozen regressors.

    Its :meth:`increment` is the whole law: :func:`lion` scans it over a record's stored
    regressors, the streaming kernel of :func:`lionjax.lion_batched` applies it elementwise to
    a batch of records sample by sample.
    """

    regressors: AbstractVar[Literal["midpoint", "zoh"]]
    #: Whether :meth:`increment` reports per-step validity (else its flag is ``None``).
    reports_stability: AbstractClassVar[bool]

    @abc.abstractmethod
    def increment(
        self,
        theta: list[Array],
        W1: list[Array],
        W2: list[Array],
        y1: Array,
        y2: Array,
        G: list[list[Array]],
        h: Array,
        *,
        series: int = 0,
        one: Array | None = None,
    ) -> tuple[list[Array], Array | None]:
        """(Δθ, valid) over one interval: θ ← θ − Δθ, elementwise over any batch shape.

        Arguments:
            theta: θ, p arrays; W1, W2: the two rows of W (p arrays each); y1, y2: W₀;
            G: the p×p gain as nested lists; h: the interval [s].
            series: 0, or evaluate E(hS) by this many terms of its series alone, valid while
                tr(hS) ≤ 1/2 (elements beyond the bound come back non-finite on purpose, to
                be re-run with ``series=0``). Ignored by steppers without E.
            one: a runtime 1 (see :func:`lionjax._phi.materialise`): the increments are
                materialised once per element (the batched kernel); None leaves them as is.

        ``valid`` is None when the step cannot fail, else a boolean per element."""

    def trajectory(self, model, bank, record, regs, G, theta0):
        W, W0 = regs.W, regs.W0
        p = W.shape[-1]
        if self.regressors == "midpoint":
            Ws, W0s = 0.5 * (W[:-1] + W[1:]), 0.5 * (W0[:-1] + W0[1:])
        else:
            Ws, W0s = W[:-1], W0[:-1]
        h = record.dt.astype(W.dtype)
        Gl = [[G[i, j] for j in range(p)] for i in range(p)]

        def step(carry, inputs):
            theta, valid = carry
            Wk, W0k = inputs
            d, ok = self.increment(
                [theta[i] for i in range(p)],
                [Wk[0, i] for i in range(p)],
                [Wk[1, i] for i in range(p)],
                W0k[0],
                W0k[1],
                Gl,
                h,
            )
            theta = theta - jnp.stack(d)
            return (theta, valid if ok is None else valid & ok), theta

        (_, valid), thetas = jax.lax.scan(step, (theta0, jnp.array(True)), (Ws, W0s))
        result = RESULTS.where(valid, RESULTS.successful, RESULTS.unstable_step)
        return jnp.concatenate([theta0[None], thetas]), result


def _scale(mu, W1, W2):
    """c = 1/(1 + μ‖W‖²_F), or None for the plain law (μ None)."""
    if mu is None:
        return None
    return 1.0 / (1.0 + mu * sum(v * v for v in list(W1) + list(W2)))


class ExactStep(AbstractSampleStepper):
    """Closed-form step over each interval with frozen regressors (module docstring):
    θ ← θ − h·cGWᵀ E(hS)(Wθ + W₀), S = c·WGWᵀ, E(Z) = (I − e^{−Z})Z⁻¹.

    Attributes:
        regressors: ``"midpoint"`` (default; W over [tₖ, tₖ₊₁] is (Wₖ + Wₖ₊₁)/2, second order
            against the continuous-time law) or ``"zoh"`` (Wₖ, causal).
        normalisation: μ ≥ 0 of θ̇ = −G Wᵀε/(1 + μ‖W‖²_F) (in 1/regressor²), or None (default:
            Lion's plain law, c = 1; the batched kernel then skips c entirely).
    """

    regressors: Literal["midpoint", "zoh"] = eqx.field(static=True, default="midpoint")
    normalisation: float | Array | None = None
    reports_stability: ClassVar[bool] = False

    def __check_init__(self):
        if self.regressors not in ("midpoint", "zoh"):
            raise InputError(
                f"ExactStep: regressors must be 'midpoint' or 'zoh', got {self.regressors!r}."
            )
        _check_mu(self.normalisation, "ExactStep")

    def increment(self, theta, W1, W2, y1, y2, G, h, *, series=0, one=None):
        c = _scale(self.normalisation, W1, W2)
        if series:  # valid while tr(hS) ≤ bound; else the guard is NaN and so is the element
            phi = lambda zp, zq, zr: _phi_series(zp, zq, zr, series)
            guard = lambda tr_hs: jnp.where(tr_hs <= SERIES_BOUND, one, jnp.nan)
        else:
            phi, guard = phi_sym2, one
        return exact_step(theta, W1, W2, y1, y2, G, h, c, phi=phi, guard=guard), None


class EulerStep(AbstractSampleStepper):
    """Explicit Euler θ ← θ − h·c·G Wₖᵀεₖ (regressors at the interval's start); guarded:
    h·c·‖GWₖᵀWₖ‖ > 2 (unstable) is reported as ``RESULTS.unstable_step``.

    Attributes:
        normalisation: μ of the normalised law, or None (plain law).
    """

    normalisation: float | Array | None = None
    regressors: ClassVar[str] = "zoh"
    reports_stability: ClassVar[bool] = True

    def __check_init__(self):
        _check_mu(self.normalisation, "EulerStep")

    def increment(self, theta, W1, W2, y1, y2, G, h, *, series=0, one=None):
        c = _scale(self.normalisation, W1, W2)
        GW1, GW2, (S11, S12, S22), (e1, e2) = step_products(theta, W1, W2, y1, y2, G, h, c)
        # h‖G WᵀW‖ = the largest eigenvalue of hS = W(hG)Wᵀ (2×2 symmetric PSD)
        rho = 0.5 * (S11 + S22) + jnp.sqrt(0.25 * (S11 - S22) ** 2 + S12 * S12)
        d = [a * e1 + b * e2 for a, b in zip(GW1, GW2, strict=True)]
        return materialise(d, one, multiply=True), rho <= 2.0


def _check_mu(mu, what: str) -> None:
    if mu is None or isinstance(mu, jax.core.Tracer):
        return
    m = np.asarray(mu, dtype=np.float64)
    if m.ndim or not (np.isfinite(m) and m >= 0):
        raise InputError(
            f"{what}: normalisation must be a number μ ≥ 0 (or None for Lion's plain law), got "
            f"{mu!r}."
        )


class DiffraxStep(AbstractStepper):
    """Joint continuous-time ODE (filter states + θ) on interpolated signals, solved by diffrax.

    Attributes:
        solver: a diffrax solver (default ``Kvaerno5()``, implicit: stiff gains are fine).
        rtol, atol: tolerances of the PID step-size controller; steps are clipped to the
            sample instants (where held signals jump).
        max_steps_per_sample: step budget (default 64 per sample).
        normalisation: μ of the normalised law, or None (plain law).
    """

    solver: "diffrax.AbstractSolver" = eqx.field(default_factory=lambda: _kvaerno5())
    rtol: float = 1e-8
    atol: float = 1e-10
    max_steps_per_sample: int = eqx.field(static=True, default=64)
    normalisation: float | Array | None = None

    def __check_init__(self):
        _check_mu(self.normalisation, "DiffraxStep")

    def trajectory(self, model, bank, record, regs, G, theta0):
        mu = jnp.asarray(0.0 if self.normalisation is None else self.normalisation, G.dtype)
        thetas, ok = _diffrax_theta(model, bank, record, G, mu, theta0, self)
        return thetas, RESULTS.where(ok, RESULTS.successful, RESULTS.nonfinite)


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
        unexcited: True for each parameter the record does not identify (``(p,)``; the
            validity layer's check, whatever the gain: see :mod:`lionjax._validity`).
    """

    t: Float[Array, " K"]
    theta: Float[Array, "K p"]
    eps: Float[Array, "K 2"]
    J: Float[Array, " K"]
    theta_final: Float[Array, " p"]
    gain: Float[Array, "p p"]
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS
    unexcited: Bool[Array, " p"] | None = None

    def params(self) -> dict[str, Array]:
        """Final estimate by name."""
        return by_name(self.names, self.theta_final)

    def convergence_time(
        self, reference: Float[ArrayLike, " p"], tolerance: float = 0.02
    ) -> Float[Array, ""]:
        """Seconds from the record start after which every |θᵢ(t) − θ_refᵢ| ≤
        tolerance·|θ_refᵢ| until the end (``inf``: still outside at the last sample).

        The definition of :class:`lionjax.ConvergenceTime` (and so of
        :func:`lionjax.lion_batched` and :func:`lionjax.study`), evaluated on the saved
        trajectory: exact with ``save_every=1`` (the default), else resolved to the saved
        samples. ``reference`` is θ_ref ``(p,)``, typically the least-squares answer
        ``lionjax.least_squares(model, record, initial="discard").theta``.
        """
        ref = jnp.asarray(reference, self.theta.dtype)
        if ref.shape != self.theta.shape[-1:]:
            raise InputError(
                f"LionSolution.convergence_time: reference must have shape "
                f"({self.theta.shape[-1]},) for parameters {self.names}, got {ref.shape}."
            )
        return convergence_time(self.theta, ref, lambda i: self.t[i] - self.t[0], tolerance)


def _kvaerno5():
    import diffrax

    return diffrax.Kvaerno5()


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
    import diffrax

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
    normalisation: float | Array | None = None,
    theta0: ArrayLike | None = None,
    save_every: int = 1,
    transient: float | Array | None = None,
    throw: bool = True,
) -> LionSolution:
    """Run Lion's estimator θ̇ = −G Wᵀε / (1 + μ‖W‖²) over a record.

    Arguments:
        model: the model structure (e.g. ``MassDamper()``, ``Piecewise((-0.01, 0.01))``).
        record: the data (one record; ``jax.vmap`` this function for many).
        bank: the filter Λ (default :func:`default_bank` of the record's dt: the paper's poles
            (s + 4)³ with unit DC gain, slowed for records sampled below 200 Hz). A filter
            with max|pole|·dt above 0.1 warns (:class:`lionjax.solutions.FilterSpeedWarning`),
            above 0.25 is refused (:mod:`lionjax._validity` states the measured bias).
        gain: :class:`AutoGain` (default, rate 1/s) or :class:`FixedGain` (the paper:
            ``FixedGain(1e4)`` with ``FilterBank.paper()``); G is the gain's rule applied to
            R = mean WᵀW after ``transient`` (the same rule as :func:`lionjax.lion_batched`).
        stepper: :class:`ExactStep` (default), :class:`EulerStep` or :class:`DiffraxStep`; its
            ``normalisation`` μ selects the normalised law (``ExactStep(normalisation=μ)``).
        normalisation: shorthand for the stepper's μ (``lion(..., normalisation=μ)`` is
            ``lion(..., stepper=ExactStep(normalisation=μ))``); give it in one place only.
        theta0: initial estimate, shape ``(p,)`` (default zeros, as in the paper).
        save_every: keep every n-th sample of the trajectory (the last sample always kept).
        transient: seconds excluded when forming data-dependent gains (default 3·λₙ₋₁/λₙ, three
            times the filter's mean delay).
        throw: raise on failure (unexcited parameters, whatever the gain; unstable Euler;
            NaN); with ``False`` the failure is carried in ``result`` (use under ``vmap``,
            then :func:`lionjax.raise_if_failed`).

    Returns:
        A :class:`LionSolution`.

    Raises:
        InputError: a bad argument (naming it): ``theta0`` not finite or of the wrong shape, a
            filter too fast for the sampling, a record shorter than the filter transient,
            non-finite or out-of-range samples.
        IdentificationError: (``throw``) the record does not identify every parameter (the
            message names each one), an unstable Euler step, a non-finite estimate.
    """
    bank = default_bank(record.dt if isinstance(record, Record) else None) if bank is None else bank
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
    if bank.batch_shape:
        raise InputError(
            f"lion: bank holds {bank.batch_shape[0]} filters (coeffs of shape "
            f"{bank.coeffs.shape}), but lion runs one record with one filter; use "
            "lionjax.lion_batched for one filter per record."
        )
    if normalisation is not None:
        if stepper.normalisation is not None:
            raise InputError(
                "lion: normalisation is given twice, as an argument and as "
                f"{type(stepper).__name__}.normalisation; give it in the stepper only."
            )
        stepper = dataclasses.replace(stepper, normalisation=normalisation)
    check_theta0(theta0, len(model.names), model.names, "lion")
    check_filter_speed(bank, record.dt, "lion")
    check_duration(record, bank, "lion")
    check_record(record, "lion")
    sol = _lion(model, record, bank, gain, stepper, theta0, save_every, transient)
    return finish(sol, throw, what="lion", explain=explain_unexcited)


@eqx.filter_jit
def _lion(model, record, bank, gain, stepper, theta0, save_every, transient):
    regs = model.regressors(record, bank)
    W, W0 = regs.W, regs.W0
    T, _, p = W.shape
    dtype = W.dtype
    theta0 = jnp.zeros((p,), dtype) if theta0 is None else jnp.asarray(theta0, dtype)
    # R for every gain: the gain's rule may use it, the validity layer always does, over the
    # samples the rule sees (after the transient for a data gain; a fixed gain's law uses all)
    R = regressor_moments(regs, transient_mask(record, bank, transient if gain.uses_data else 0.0))
    G, ok = gain(R, regs.names)
    bad = unexcited(R, column_reference(model, record, bank).astype(dtype), MAX_MOMENT_CONDITION)
    ok = ok & ~jnp.any(bad)
    thetas, result = stepper.trajectory(model, bank, record, regs, G, theta0)
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
        unexcited=bad,
    )
    return sol


def default_bank(dt: ArrayLike | None = None) -> FilterBank:
    """The default filter (s + p)³ with unit DC gain, sampling-aware.

    p = 4 rad/s (the paper's poles) whenever 4·dt ≤ 0.02, i.e. for every record sampled at
    200 Hz or faster (and when ``dt`` is not given); for slower sampling p = 0.02/dt, so that
    max|pole|·dt stays at 0.02 (bias of b about 1e-4; :mod:`lionjax._validity` gives the
    measurement). ``dt`` [s]: a number, or one per record (the largest decides); a traced
    ``dt`` (under ``jit``/``vmap``) gives the same value through ``jnp.minimum``.
    """
    p = default_poles(dt)
    return FilterBank.from_poles(-p * jnp.ones(3), unit_dc_gain=True)
