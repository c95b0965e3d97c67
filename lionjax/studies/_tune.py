"""Gradient tuning of Lion's gain and filter pole through the batched estimator.

Everything in the estimator is differentiable, so the two settings a designer picks — the gain
and the filter pole — can be tuned by gradient descent on a stated objective. The settings are

    G = g·I (``gain=lionjax.FixedGain``) or G = g·R⁻¹ (``gain=lionjax.AutoGain``, g the rate
    in 1/s),   Λ(s) = (s + p)ⁿ (one real pole −p of multiplicity n = ``filter_order``),

parameterised as z = (log g, log p) so that both stay positive and a unit step in z is a factor
e. The objective (:class:`TuneObjective`) is, in seconds,

    J(g, p) = (1/R) Σ_records [ T_out + κ · Σᵢ (σᵢ / (tol·|θ_LS,i|))² ],

with T_out the smooth surrogate of the time spent outside the ``tol`` band around the record's
least-squares answer θ_LS (``time_outside`` of :func:`lionjax.lion_batched`: Σₖ h·σ((log rₖ −
log tol)/s), rₖ the smooth max over parameters of |θᵢ − θ_LS,ᵢ|/|θ_LS,ᵢ|, so T_out ≈ the time to
converge to within tol and stay there) and σᵢ the standard deviation of θᵢ(t) over the last
quarter of the record (the noise the estimator lets through once converged). κ [s] prices the
noise: a parameter whose noise σᵢ fills the whole tolerance band costs κ seconds.

:func:`tune_objective` evaluates J at any (g, p) — over a grid, it is the map the tuned point
must agree with — and :func:`tune` minimises it with optimistix (BFGS by default). Both run the
same function: one :func:`lionjax.lion_batched` call (E(hS) in closed form,
``Execution(phi="closed")``; outputs :class:`lionjax.LSStatistics` with a **fixed**
``transient`` so that the LS window does not jump with p, :class:`lionjax.ConvergenceTime`
against that θ_LS — streamed in the same call with the same filter and differentiated with
it — and :class:`lionjax.TailStatistics`). Its gradient in z is
computed in forward mode (two tangents, one pass, memory independent of the record length)
behind a ``jax.custom_jvp``, so the solver's ``jax.linearize`` never stores the time loop; it is
tested against central finite differences.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._batched import DEFAULT_EXECUTION, Execution, lion_batched
from .._errors import IdentificationError, InputError, result_code, result_message
from .._estimators import AbstractGain, AbstractSampleStepper, AutoGain
from .._filters import FilterBank
from .._models import AbstractModel
from .._outputs import ConvergenceTime, LSStatistics, TailStatistics
from .._record import Record
from ._grid import Records, gain_class, refuse_gain_type
from ._records import StudyRecords
from ._result import StudyResult

if TYPE_CHECKING:  # imported where a tuning starts: `import lionjax` stays light
    import optimistix as optx


class TuneObjective(eqx.Module):
    """The tuning objective J(g, p) [s] (module docstring), as a function of estimator outputs.

    J = (1/R) Σ_records [ T_out + κ · Σᵢ (σᵢ / (tolerance·|θ_LS,i|))² ].

    Attributes:
        kappa: κ [s], the price of noise: a parameter whose tail standard deviation σᵢ equals
            the tolerance band tolerance·|θ_LS,i| adds κ seconds (default 1 s).
        tolerance: the relative band around θ_LS of T_out (default 2 %).
        softness: width s of the sigmoid of T_out in log relative error (default 0.5: smoother
            than :func:`lionjax.lion_batched`'s 0.25, for a landscape BFGS can descend).
        transient: seconds excluded from the LS window and AutoGain's R, **fixed** (default
            0.5 s): the default 3·λₙ₋₁/λₙ moves with p and the window would jump a sample at a
            time. Use at least the filter's settling time for the poles you search.
    """

    kappa: float = eqx.field(static=True, default=1.0)
    tolerance: float = eqx.field(static=True, default=0.02)
    softness: float = eqx.field(static=True, default=0.5)
    transient: float = eqx.field(static=True, default=0.5)

    def __check_init__(self):
        for name, lo in (("kappa", 0.0), ("softness", 0.0), ("transient", 0.0)):
            v = getattr(self, name)
            ok = isinstance(v, int | float) and math.isfinite(v) and v >= lo
            if not ok or (name == "softness" and v == 0):
                raise InputError(
                    f"TuneObjective: {name} must be a finite number "
                    f"{'> 0' if name == 'softness' else '>= 0'}, got {v!r}."
                )
        if not (isinstance(self.tolerance, int | float) and 0 < self.tolerance < 1):
            raise InputError(
                f"TuneObjective: tolerance must be in (0, 1) (0.02 = 2 %), got {self.tolerance!r}."
            )

    def per_record(
        self,
        time_outside: Float[ArrayLike, "*B"],
        tail_std: Float[ArrayLike, "*B p"],
        theta_ls: Float[ArrayLike, "*B p"],
    ) -> Float[Array, "*B"]:
        """T_out + κ·Σᵢ (σᵢ/(tol·|θ_LS,i|))² per record [s] (any leading shape)."""
        xp = np if isinstance(time_outside, np.ndarray) else jnp
        noise = tail_std / (self.tolerance * xp.abs(theta_ls))
        return time_outside + self.kappa * xp.sum(noise * noise, axis=-1)

    def on_study(self, result: StudyResult) -> np.ndarray:
        """J over a :class:`StudyResult`: the mean over its record dims of :meth:`per_record`.

        The study must have been run with this objective's ``tolerance``, ``softness`` and
        ``transient`` (``lj.study(..., tolerance=obj.tolerance, softness=obj.softness,
        transient=obj.transient)``); the result has the study's other dims (gain, poles, …).
        """
        if not isinstance(result, StudyResult):
            raise InputError(
                f"TuneObjective.on_study: expected a StudyResult, got {type(result).__name__}."
            )
        for name in ("tolerance", "softness", "transient"):
            have, want = getattr(result, name), getattr(self, name)
            if have is None or not math.isclose(float(have), float(want), rel_tol=1e-12):
                raise InputError(
                    f"TuneObjective.on_study: the study ran with {name}={have!r}, this objective "
                    f"uses {name}={want!r}. Run lj.study(..., {name}={want!r}) (the map must be "
                    "the same function as the tuned objective)."
                )
        if result.time_outside is None or result.tail_std is None:
            raise InputError("TuneObjective.on_study: the study has no time_outside/tail_std.")
        J = self.per_record(result.time_outside, result.tail_std, result.theta_ls)
        rec = tuple(i for i, d in enumerate(result.dims) if d not in ("gain", "poles", "theta0"))
        return np.mean(J, axis=rec) if rec else J


class TuneSolution(eqx.Module):
    """The tuned gain and filter pole from :func:`tune` (R records, p parameters).

    Attributes:
        gain_class: the gain Module class: :class:`lionjax.FixedGain` (G = gain·I) or
            :class:`lionjax.AutoGain` (G = gain·R⁻¹, gain in 1/s).
        gain: the tuned g; pole: the tuned p [rad/s] (filter Λ = (s + p)ⁿ, poles −p).
        filter_order: n; unit_dc_gain: the filter normalisation (λₙ/Λ if True).
        init_gain, init_pole: the start of the search.
        objective: J at the tuned point [s].
        gradient: ∂J/∂(log g, log p) at the tuned point [s], ``(2,)`` (≈ 0 at a minimum).
        n_steps: solver steps; success: the solver met its tolerances; message: why not.
        labels: one label per record (``"0"``, … or ``"excitation=input4, noise_seed=1"``).
        names: parameter names.
        theta: θ(T) per record with the tuned settings, ``(R, p)``; theta_ls: θ_LS, ``(R, p)``.
        convergence_time: seconds to within ``tolerance`` of θ_LS for good (inf: not), ``(R,)``.
        time_outside: T_out per record [s], ``(R,)``; tail_std: σ per record, ``(R, p)``.
        spec: the :class:`TuneObjective`.
    """

    gain_class: type[AbstractGain] = eqx.field(static=True)
    gain: float
    pole: float
    filter_order: int = eqx.field(static=True)
    unit_dc_gain: bool = eqx.field(static=True)
    init_gain: float
    init_pole: float
    objective: float
    gradient: np.ndarray
    n_steps: int
    success: bool = eqx.field(static=True)
    message: str = eqx.field(static=True)
    labels: tuple[str, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    theta: np.ndarray
    theta_ls: np.ndarray
    convergence_time: np.ndarray
    time_outside: np.ndarray
    tail_std: np.ndarray
    spec: TuneObjective

    @property
    def bank(self) -> FilterBank:
        """The tuned filter, ``FilterBank.from_poles([-pole] * filter_order, unit_dc_gain)``."""
        return FilterBank.from_poles(np.full(self.filter_order, -self.pole), self.unit_dc_gain)

    @property
    def gain_strategy(self) -> AbstractGain:
        """The tuned gain as a Module for :func:`lionjax.lion` / :func:`lionjax.lion_batched`:
        ``gain_class(gain)``."""
        return self.gain_class(self.gain)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for JSON): settings, objective values and the per-record results."""
        return {
            "gain_class": self.gain_class.__name__,
            "gain": self.gain,
            "pole": self.pole,
            "poles": [-self.pole] * self.filter_order,
            "unit_dc_gain": self.unit_dc_gain,
            "init_gain": self.init_gain,
            "init_pole": self.init_pole,
            "objective": self.objective,
            "gradient": np.asarray(self.gradient).tolist(),
            "kappa": self.spec.kappa,
            "tolerance": self.spec.tolerance,
            "softness": self.spec.softness,
            "transient": self.spec.transient,
            "n_steps": self.n_steps,
            "success": self.success,
            "message": self.message,
            "records": [
                {
                    "label": lab,
                    **{n: float(self.theta[r, j]) for j, n in enumerate(self.names)},
                    **{f"{n}_ls": float(self.theta_ls[r, j]) for j, n in enumerate(self.names)},
                    "convergence_time": float(self.convergence_time[r]),
                    "time_outside": float(self.time_outside[r]),
                }
                for r, lab in enumerate(self.labels)
            ],
        }


class _Setup(eqx.Module):
    """Everything :func:`_evaluate` needs besides z: the stacked records and static settings."""

    batch: Record
    lengths: Array | None
    model: AbstractModel = eqx.field(static=True)
    gain_class: type[AbstractGain] = eqx.field(static=True)
    filter_order: int = eqx.field(static=True)
    unit_dc_gain: bool = eqx.field(static=True)
    stepper: AbstractSampleStepper | None
    spec: TuneObjective
    execution: Execution = eqx.field(static=True)


def _evaluate(z: Float[Array, "M 2"], setup: _Setup):
    """J at M points z = (log g, log p), one lion_batched call over M × R elements.

    Returns (J (M,), the BatchedSolution of shape M·R, point-major)."""
    batch = setup.batch
    R = batch.x.shape[0]
    M = z.shape[0]
    g = jnp.repeat(jnp.exp(z[:, 0]), R)
    p = jnp.repeat(jnp.exp(z[:, 1]), R)
    rec = jnp.tile(jnp.arange(R), M)
    sub = Record(batch.x[rec], batch.F[rec], batch.dt, batch.t0)
    n, unit = setup.filter_order, setup.unit_dc_gain
    bank = jax.vmap(lambda q: FilterBank.from_poles(-q * jnp.ones(n, q.dtype), unit))(p)
    gain = setup.gain_class(g)  # one gain per element: a value of shape (M·R,)
    spec = setup.spec
    sol = lion_batched(
        setup.model,
        sub,
        bank=bank,
        gain=gain,
        stepper=setup.stepper,
        lengths=None if setup.lengths is None else setup.lengths[rec],
        outputs=(
            LSStatistics(spec.transient),
            ConvergenceTime(tolerance=spec.tolerance, softness=spec.softness),
            TailStatistics(),
        ),
        execution=setup.execution,
        throw=False,
    )
    per = spec.per_record(sol.time_outside, sol.tail_std, sol.theta_ls)
    return jnp.mean(per.reshape(M, R), axis=1), sol


def _point(z: Float[Array, " 2"], setup: _Setup):
    """J at one point z and the per-record outputs (float arrays, for the solver's aux)."""
    J, sol = _evaluate(z[None], setup)
    dtype = J.dtype
    aux = {
        "theta": sol.theta,
        "theta_ls": sol.theta_ls,
        "t_converged": sol.t_converged,
        "time_outside": sol.time_outside,
        "tail_std": sol.tail_std,
        "result": result_code(sol.result).astype(dtype),
    }
    return J[0], aux


@jax.custom_jvp
def _objective(z: Float[Array, " 2"], setup: _Setup):
    """(J, aux) at one point z: what the solver minimises."""
    return _point(z, setup)


@_objective.defjvp
def _objective_jvp(primals, tangents):
    # Forward mode, both directions of z in one pass (vmap over the tangent basis): J and ∇J.
    # The tangent output ∇J·ż is linear in ż, so the solver's linearize/transpose is cheap and
    # never stores the time loop. The records are data: no derivative is taken wrt them.
    z, setup = primals
    tz = tangents[0]
    basis = jnp.eye(z.shape[0], dtype=z.dtype)
    val, grad, aux = jax.vmap(
        lambda t: jax.jvp(lambda zz: _point(zz, setup), (z,), (t,), has_aux=True),
        out_axes=(None, 0, None),
    )(basis)
    return (val, aux), (jnp.dot(grad, tz), jax.tree.map(jnp.zeros_like, aux))


@eqx.filter_jit
def _evaluate_jit(z, setup):
    return _evaluate(z, setup)


@eqx.filter_jit
def _point_jit(z, setup):
    return _point(z, setup)


@eqx.filter_jit
def _solve(z0, setup, solver, max_steps):
    import optimistix as optx

    return optx.minimise(
        _objective, solver, z0, setup, has_aux=True, max_steps=max_steps, throw=False
    )


def _prepare(
    model, records, gain, filter_order, unit_dc_gain, stepper, objective, execution, what
) -> tuple[_Setup, tuple[str, ...]]:
    if not isinstance(model, AbstractModel):
        raise InputError(f"{what}: model must be an AbstractModel, got {type(model).__name__}.")
    gain = gain_class(gain, what)
    if not isinstance(gain, type):
        raise InputError(
            f"{what}: gain must be the gain Module class whose value is tuned "
            f"(lionjax.AutoGain: the rate; lionjax.FixedGain: g of G = g·I), got the Module "
            f"{gain!r}; pass gain={type(gain).__name__}."
        )
    if stepper is not None and not isinstance(stepper, AbstractSampleStepper):
        raise InputError(
            f"{what}: stepper must be an AbstractSampleStepper (lionjax.ExactStep(...)), got "
            f"{type(stepper).__name__}."
        )
    if not isinstance(execution, Execution):
        raise InputError(
            f"{what}: execution must be a lionjax.Execution, got {type(execution).__name__}."
        )
    if not (isinstance(filter_order, int) and filter_order >= 3):
        raise InputError(
            f"{what}: filter_order must be an int >= 3 (the model needs V₁…V₄), got "
            f"{filter_order!r}."
        )
    spec = TuneObjective() if objective is None else objective
    if not isinstance(spec, TuneObjective):
        raise InputError(
            f"{what}: objective must be a lionjax.studies.TuneObjective, got {type(spec).__name__}."
        )
    rec = Records(records, what=what)
    batch, lengths, dims = rec.batch, rec.lengths, rec.dims
    T = batch.x.shape[1]
    dt = np.asarray(batch.dt)
    if not np.all(dt == dt[0]):
        raise InputError(
            f"{what}: records must share one sampling interval (one filter discretisation per "
            f"pole), got dt from {dt.min():g} to {dt.max():g} s. Resample them "
            "(lionjax.resample)."
        )
    shortest = float(dt[0]) * (int(np.min(lengths)) - 1)
    if spec.transient >= 0.75 * shortest:
        raise InputError(
            f"{what}: objective.transient = {spec.transient:g} s leaves too little of the "
            f"shortest record ({shortest:.4g} s) for the LS answer and the tail statistics. "
            "Use longer records or TuneObjective(transient=...) below 3/4 of the record."
        )
    if isinstance(records, StudyRecords):
        labels = tuple(", ".join(f"{k}={v}" for k, v in lab.items()) for lab in records.labels())
    elif dims:
        labels = tuple(str(i) for i in range(batch.x.shape[0]))
    else:
        labels = ("0",)
    setup = _Setup(
        batch=Record(batch.x, batch.F, batch.dt[0], batch.t0[0]),
        lengths=None if np.all(lengths == T) else jnp.asarray(lengths, jnp.int32),
        model=model,
        gain_class=gain,
        filter_order=filter_order,
        unit_dc_gain=bool(unit_dc_gain),
        stepper=stepper,
        spec=spec,
        # the closed-form E: one program for the value and its forward-mode gradient
        execution=dataclasses.replace(execution, phi="closed"),
    )
    return setup, labels


def _positive(value, name: str, what: str) -> np.ndarray:
    v = np.asarray(value, float)
    if v.size == 0 or not np.all(np.isfinite(v)) or not np.all(v > 0):
        raise InputError(f"{what}: {name} must be positive finite numbers, got {value!r}.")
    return v


def tune_objective(
    model: AbstractModel,
    records: Record | Sequence[Record] | StudyRecords,
    gains: Float[ArrayLike, "*M"],
    poles: Float[ArrayLike, "*M"],
    *,
    objective: TuneObjective | None = None,
    gain: type[AbstractGain] = AutoGain,
    filter_order: int = 3,
    unit_dc_gain: bool = True,
    stepper: AbstractSampleStepper | None = None,
    execution: Execution = DEFAULT_EXECUTION,
    gain_type: None = None,
) -> np.ndarray:
    """The tuning objective J(g, p) [s] (see :class:`TuneObjective`) at given points.

    The same function :func:`tune` minimises, evaluated at every (gain, pole) pair in one
    batched call: use it for the grid map the tuned point is compared with.

    Arguments:
        model, records: as :func:`tune`.
        gains: g (``gain=lionjax.FixedGain``: G = g·I; ``lionjax.AutoGain``: the rate [1/s]),
            any shape.
        poles: p [rad/s] of the filter Λ = (s + p)ⁿ, broadcast against ``gains``.
        objective, gain, filter_order, unit_dc_gain, stepper, execution, gain_type: as
            :func:`tune`.

    Returns:
        J of shape ``broadcast(gains, poles)`` [s], a numpy array.
    """
    what = "tune_objective"
    refuse_gain_type(gain_type, what)
    g = _positive(gains, "gains", what)
    p = _positive(poles, "poles", what)
    try:
        g, p = np.broadcast_arrays(g, p)
    except ValueError:
        raise InputError(
            f"{what}: gains {g.shape} and poles {p.shape} do not broadcast; pass arrays of one "
            "shape (e.g. from numpy.meshgrid)."
        ) from None
    setup, _ = _prepare(
        model, records, gain, filter_order, unit_dc_gain, stepper, objective, execution, what
    )
    z = jnp.stack([jnp.log(g.ravel()), jnp.log(p.ravel())], axis=1).astype(setup.batch.x.dtype)
    J, _ = _evaluate_jit(z, setup)
    return np.asarray(J).reshape(g.shape)


def tune(
    model: AbstractModel,
    records: Record | Sequence[Record] | StudyRecords,
    *,
    objective: TuneObjective | None = None,
    gain: type[AbstractGain] = AutoGain,
    init_gain: float = 1.0,
    init_pole: float = 4.0,
    filter_order: int = 3,
    unit_dc_gain: bool = True,
    stepper: AbstractSampleStepper | None = None,
    solver: optx.AbstractMinimiser | None = None,
    max_steps: int = 64,
    execution: Execution = DEFAULT_EXECUTION,
    throw: bool = True,
    gain_type: None = None,
) -> TuneSolution:
    """Tune Lion's gain g and filter pole p by gradient descent on J(g, p) (module docstring).

    Minimises J over z = (log g, log p) with ``optx.minimise`` (default
    ``optx.BFGS(rtol=1e-3, atol=1e-3)``: it stops when a step changes z by less than about
    0.1 % of g and p and J by less than 1e-3 s), from (``init_gain``, ``init_pole``). The
    gradient is exact (forward-mode through :func:`lionjax.lion_batched`, the LS reference
    included); J is a smooth surrogate, so the answer is a *local* minimum: start from the best
    cell of a coarse grid (:func:`tune_objective` or :meth:`TuneObjective.on_study`) when the
    landscape has several valleys.

    Arguments:
        model: the model structure (``MassDamper()`` …).
        records: one :class:`Record`, a list of records (padded and masked if of different
            lengths; one common ``dt``) or a :class:`StudyRecords`; J averages over them.
        objective: the :class:`TuneObjective` (default κ = 1 s, tolerance 2 %, softness 0.5,
            transient 0.5 s).
        gain: the gain Module class whose value g is tuned: :class:`lionjax.AutoGain`
            (default): G = g·R⁻¹, g the rate [1/s]; :class:`lionjax.FixedGain`: G = g·I (the
            paper's form, G = 10⁴·I).
        init_gain, init_pole: the start, g and p [rad/s] (filter poles −p, n-fold).
        filter_order: n of Λ = (s + p)ⁿ (default 3, the paper's).
        unit_dc_gain: filter normalisation (λₙ/Λ, the package default).
        stepper: Lion's per-sample stepper (default ``ExactStep()``; ``normalisation=μ`` for the
            normalised law).
        solver: an optimistix minimiser.
        max_steps: solver step limit.
        execution: the performance knobs of :func:`lionjax.lion_batched` (E(hS) is always
            evaluated in closed form here).
        throw: raise :class:`lionjax.IdentificationError` if the solver fails or the tuned
            estimator does not give finite estimates; with False see ``success``/``message``.
        gain_type: removed (an error naming the replacement): pass ``gain=lionjax.AutoGain``
            or ``gain=lionjax.FixedGain``.

    Returns:
        a :class:`TuneSolution`.
    """
    what = "tune"
    refuse_gain_type(gain_type, what)
    g0 = float(_positive(init_gain, "init_gain", what).reshape(-1)[0])
    p0 = float(_positive(init_pole, "init_pole", what).reshape(-1)[0])
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise InputError(f"{what}: max_steps must be a positive int, got {max_steps!r}.")
    import optimistix as optx

    solver = optx.BFGS(rtol=1e-3, atol=1e-3) if solver is None else solver
    if not isinstance(solver, optx.AbstractMinimiser):
        raise InputError(
            f"{what}: solver must be an optimistix minimiser (e.g. optx.BFGS(rtol=1e-3, "
            f"atol=1e-3)), got {type(solver).__name__}."
        )
    setup, labels = _prepare(
        model, records, gain, filter_order, unit_dc_gain, stepper, objective, execution, what
    )
    dtype = setup.batch.x.dtype
    z0 = jnp.asarray([math.log(g0), math.log(p0)], dtype)
    sol = _solve(z0, setup, solver, max_steps)
    zf = sol.value
    # J, ∇J and the per-record outputs at the answer. Quasi-Newton solvers (BFGS) keep them
    # for the accepted point in their state (sol.aux lags one accepted step behind sol.value);
    # any other solver: one more evaluation.
    info = getattr(sol.state, "f_info", None)
    grad = getattr(info, "grad", None)
    aux = getattr(sol.state, "aux", None)
    if grad is not None and isinstance(aux, dict):
        J = float(info.f)
    else:
        J, aux = _point_jit(zf, setup)
        J = float(J)
        grad = jnp.full((2,), jnp.nan, dtype)
    success = bool(sol.result == optx.RESULTS.successful)
    message = "" if success else result_message(result_code(sol.result), optx.RESULTS)
    codes = np.asarray(aux["result"]).astype(int)
    if success and (np.any(codes != 0) or not math.isfinite(J)):
        success = False
        bad = [labels[i] for i in np.flatnonzero(codes != 0)]
        message = (
            f"the estimator failed at the tuned settings for records {bad} "
            f"({result_message(int(codes[codes != 0][0])) if bad else 'J not finite'})"
        )
    out = TuneSolution(
        gain_class=setup.gain_class,
        gain=float(np.exp(zf[0])),
        pole=float(np.exp(zf[1])),
        filter_order=filter_order,
        unit_dc_gain=bool(unit_dc_gain),
        init_gain=g0,
        init_pole=p0,
        objective=J,
        gradient=np.asarray(grad),
        n_steps=int(sol.stats["num_steps"]),
        success=success,
        message=message,
        labels=labels,
        names=tuple(model.names),
        theta=np.asarray(aux["theta"]),
        theta_ls=np.asarray(aux["theta_ls"]),
        convergence_time=np.asarray(aux["t_converged"]),
        time_outside=np.asarray(aux["time_outside"]),
        tail_std=np.asarray(aux["tail_std"]),
        spec=setup.spec,
    )
    if throw and not success:
        raise IdentificationError(
            f"tune: the search from gain={g0:g}, pole={p0:g} did not finish: {message}. "
            f"It stopped at gain={out.gain:.4g}, pole={out.pole:.4g} after {out.n_steps} steps "
            "(J = {:.4g} s). Raise max_steps, start nearer the grid optimum "
            "(tune_objective on a coarse grid), or pass throw=False.".format(out.objective)
        )
    return out
