"""Effects written as forces: the open part of the diagnosis' library (docs/effects.md).

A :class:`ForceEffect` is a force linear in its parameters p_j,

    F_e(x, ẋ, F, t) = Σ_j p_j · φ_j(x, ẋ, F, t)   [N],

acting on the device with the input: ẍ + aẋ = b·(F + F_e). One definition serves the whole
diagnosis:

- the **regressor**: with (1/Λ)[·] the filter bank's first output, ẍ + aẋ = bF + Σ_j (b·p_j)·φ_j
  gives one column −(1/Λ)[φ_j] per parameter (the sign convention of
  :class:`lionjax.Offset`), φ_j evaluated on the recorded x, the zero-phase velocity v̂ the
  friction candidates use, the measured F and the sample times; its coefficient is b·p_j, and
  p_j = coefficient / b is reported;
- the **windowed simulation**: φ_j(x, v, u, t) evaluated on the simulated state at each step
  (the simulator's ``extra`` term), so that the simulated gap judges the structure with the
  effect in it;
- **nonlinear parameters** (a period, a frequency): fields of the Module named in
  :attr:`~ForceEffect.nonlinear`, searched by :meth:`~ForceEffect.profile` over
  :meth:`~ForceEffect.grid` on the training record's residual sum of squares, once, on the
  effect alone; the profiled Module is then fixed in every stack.

A *measurement* effect (``acts_on = "measurement"``) is an error of the force sensor, not a
force on the device: the measured F carries a term the device never felt, F_meas = F + s(t), and
the model is ẍ + aẋ = b·(F_meas − s). Its φ_j are computed from the whole record
(:meth:`~ForceEffect.record_basis`: a line's amplitude and phase are estimated from F) and
subtracted from the input of the windowed simulation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._models import AbstractEffect, Column
from ..._record import Record
from .._search import GoldenSection, GridSearch
from ._base import AbstractCandidate, Limits, b_positive
from ._user_checks import check_definitions, checked_basis, checked_grid, traced

#: Golden-section steps of :meth:`ForceEffect.profile`'s refinement (the bracket shrinks by
#: 0.618 per step: 16 steps leave 5·10⁻⁴ of the grid's spacing).
REFINE_STEPS = 16


class ForceEffect(AbstractCandidate):
    """A candidate effect written as a force linear in its parameters (module docstring).

    Subclass it with:

    - ``name`` (ClassVar): the name the diagnosis reports;
    - ``parameters`` (ClassVar): names of the linear parameters p_j, one per basis function;
    - ``units`` (ClassVar): unit of each reported parameter (the p_j and the nonlinear ones);
    - :meth:`basis`: the φ_j [N per unit of p_j] as functions of (x [m], v [m/s], F [N],
      t [s]), written in ``jax.numpy`` (elementwise: they are called on whole records and on
      single simulated steps);
    - optionally ``nonlinear`` (ClassVar) and :meth:`grid`: fields of the Module that are
      nonlinear parameters, and the Modules (one per grid point) the profile searches;
    - optionally :meth:`implausible` (return why the fitted parameters are not physical, or
      ``""``; call ``super().implausible`` to keep the check b > 0).

    The parsimony penalty counts ``len(parameters) + len(nonlinear)`` parameters.
    """

    parameters: ClassVar[tuple[str, ...]]
    #: fields of the Module that are nonlinear parameters (profiled on :meth:`grid`)
    nonlinear: ClassVar[tuple[str, ...]] = ()

    @property
    def n_params(self) -> int:  # type: ignore[override]
        return len(self.parameters) + len(self.nonlinear)

    def basis(self, x: Array, v: Array, F: Array, t: Array) -> tuple[Array, ...]:
        """The basis functions φ_j(x, v, F, t) [N], one per parameter (same shape as x)."""
        raise NotImplementedError(
            f"{type(self).__name__}: a ForceEffect defines basis(x, v, F, t) (or, for a "
            "measurement effect, record_basis(record, v))."
        )

    def record_basis(self, record: Record, v: Array) -> tuple[Array, ...]:
        """φ_j on a whole record (T,) each; by default :meth:`basis` on the record's samples.
        A measurement effect may estimate from the whole record here (a line's phase)."""
        t = record.t0 + record.dt * jnp.arange(record.n_samples, dtype=record.x.dtype)
        return tuple(self.basis(record.x, v, record.F, t))

    def grid(self, limits: Limits) -> Sequence[ForceEffect]:
        """The Modules the profile of the nonlinear parameters searches (default: itself)."""
        return (self,)

    def profile(self, rss: Callable[[ForceEffect], float], limits: Limits) -> ForceEffect:
        """The profiled Module: the grid point of least training residual sum of squares
        ``rss(effect)`` (the effect alone on the baseline); with one nonlinear parameter, then
        refined by a golden-section search between that point's neighbours on the grid
        (:data:`REFINE_STEPS` more fits). Override for another search (it returns a new,
        immutable Module)."""
        grid = checked_grid(self, self.grid(limits))  # a user's mistake named (docs/effects.md)
        if len(grid) == 1:
            return grid[0]
        i, values = GridSearch(tuple(grid), 1).minimise(lambda g: [rss(g[0])])
        if not np.any(np.isfinite(values)):
            raise ValueError(f"{type(self).__name__}: no grid point could be fitted.")
        if len(self.nonlinear) != 1:
            return grid[i]
        (field,) = self.nonlinear
        pts = sorted(zip((float(getattr(g, field)) for g in grid), values, strict=True))
        j = pts.index((float(getattr(grid[i], field)), values[i]))
        if not 0 < j < len(pts) - 1:
            return grid[i]  # on the grid's edge: nothing to bracket
        at = {}

        def f(val: float) -> float:
            at[val] = dataclasses.replace(grid[i], **{field: val})
            return float(rss(at[val]))

        v0 = float(getattr(grid[i], field))
        best, _ = GoldenSection(REFINE_STEPS).minimise(
            f, pts[j - 1][0], pts[j + 1][0], v0, float(values[i])
        )
        return grid[i] if best == v0 else at[best]

    def profiled(self) -> bool:
        return not self.nonlinear

    def effects(self, st) -> tuple[AbstractEffect, ...]:
        return (ForceColumns(self),)

    def physical(self, phys, problem) -> dict:
        return self.nonlinear_values()

    def simulation(self, phys, problem) -> dict:
        """The device effect's force Σ p_j·φ_j(x, v, u, t) in the simulator (``"extra"``: the
        effect with its floats traced, and its coefficients), or the measurement effect's
        correction −Σ p_j·φ_j on the validation record's input (``"du"`` [N])."""
        if self.acts_on == "measurement":
            v = problem.signals("valid").v
            du = np.zeros(problem.valid.n_samples)
            for p, phi in zip(self.parameters, self.record_basis(problem.valid, v), strict=True):
                du = du + float(phys.get(p, 0.0)) * np.asarray(phi, np.float64)
            return {"du": du}
        coefs = tuple(jnp.asarray(float(phys.get(p, 0.0)), jnp.float64) for p in self.parameters)
        return {"extra": (traced(self), coefs)}

    def report(self, phys: dict[str, float]) -> dict[str, float]:
        keys = (*self.parameters, *self.nonlinear, *self.units)
        return {k: phys[k] for k in dict.fromkeys(keys) if k in phys}

    def implausible(self, phys: dict[str, float], lim: Limits) -> str:
        return b_positive(phys)

    def measured_rms(self, phys: dict[str, float], record: Record, v) -> float | None:
        """RMS [N] of Σ p_j·φ_j on ``record`` for a measurement effect (None otherwise)."""
        if self.acts_on != "measurement":
            return None
        phis = self.record_basis(record, v)
        pairs = zip(self.parameters, phis, strict=True)
        s = sum(phys[p] * np.asarray(phi, np.float64) for p, phi in pairs)
        return float(np.sqrt(np.mean(np.square(s))))

    def nonlinear_values(self) -> dict[str, float]:
        """The nonlinear parameters' values {field: value}."""
        return {f: float(getattr(self, f)) for f in self.nonlinear}

    def key(self) -> str:
        """The signal names' suffix: the name and the nonlinear parameters' values (the
        regressors cache filtered signals by name)."""
        vals = ",".join(f"{v:.12g}" for v in self.nonlinear_values().values())
        return f"{self.name}@{vals}"


def signal_names(effect: ForceEffect) -> tuple[str, ...]:
    """The raw signals' names of ``effect``'s columns (distinct per profiled value)."""
    return tuple(f"effect:{effect.key()}[{j}]" for j in range(len(effect.parameters)))


class ForceColumns(AbstractEffect):
    """The regressor columns of a :class:`ForceEffect`: −(1/Λ)[φ_j] with coefficient b·p_j
    (module docstring)."""

    effect: ForceEffect

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"b_{p}" for p in self.effect.parameters)

    def columns(self) -> tuple[Column, ...]:
        return tuple(Column(n, 0, -1.0) for n in signal_names(self.effect))

    def signals(self, rs) -> dict:
        x = jnp.asarray(rs.x)
        # a user's mistake named (docs/effects.md)
        phis = checked_basis(self.effect, rs.record, jnp.asarray(rs.v))
        out = {}
        for n, phi in zip(signal_names(self.effect), phis, strict=True):
            phi = np.asarray(jnp.broadcast_to(jnp.asarray(phi, jnp.float64), x.shape))
            # a correction of the measured F is held as F is (zero order); a force of the
            # state, as x is (first order)
            out[n] = (phi, "zoh" if self.effect.acts_on == "measurement" else "foh")
        return out

    def physical(self, theta: Array, b: Array) -> dict:
        return {p: theta[..., j] / b for j, p in enumerate(self.effect.parameters)}


class SimulatedForce(eqx.Module):
    """Σ over device effects of Σ_j p_j·φ_j(x, v, u, t): the windowed simulation's ``extra``
    force term (its arrays traced: one program per set of effect types)."""

    effects: tuple
    coefficients: tuple

    def __call__(self, x, v, u, t):
        total = jnp.zeros_like(x)
        for e, p in zip(self.effects, self.coefficients, strict=True):
            for pj, phi in zip(p, e.basis(x, v, u, t), strict=True):
                total = total + pj * phi
        return total


def check_library(candidates: Sequence[AbstractCandidate], reserved: Sequence[str]) -> None:
    """Raise :class:`~lionjax.InputError` naming the candidate, the rule of docs/effects.md and
    the fix when a ForceEffect of ``candidates`` is not usable (:mod:`._user_checks`)."""
    check_definitions([c for c in candidates if isinstance(c, ForceEffect)], reserved, ForceEffect)
