"""Effects written as forces: the open part of the diagnosis' library (docs/effects.md).

A :class:`ForceEffect` is a force linear in its parameters p_j acting with the input,
F_e(x, ẋ, F, t) = Σ_j p_j·φ_j(x, ẋ, F, t) [N], ẍ + aẋ = b·(F + F_e). Its φ_j give its columns
−(1/Λ)[φ_j] (coefficients b·p_j; φ_j of the recorded x, the zero-phase v̂, F and t), its term in
the windowed simulation (φ_j of the simulated state) and, over :meth:`~ForceEffect.grid`, the
one-time profile of its ``nonlinear`` fields. A *measurement* effect (``acts_on =
"measurement"``) is an error of the force sensor, F_meas = F + s(t): its φ_j come from the whole
record (:meth:`~ForceEffect.record_basis`) and Σ p_j·φ_j is subtracted from the simulated input.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._models import AbstractEffect, Column
from ..._record import Record
from .._search import GoldenSection, GridSearch
from ._base import AbstractCandidate, Limits
from ._user_checks import check_definitions, checked_basis, checked_grid, checked_reason, traced

#: Golden-section steps of a profile's refinement (each shrinks the bracket by 0.618: 16 leave
#: 5·10⁻⁴ of the grid's spacing).
REFINE_STEPS = 16


class ForceEffect(AbstractCandidate):
    """A candidate effect written as a force linear in its parameters (module docstring).
    Subclass it with ``name``, ``parameters`` (names of the p_j, one per basis function) and
    ``units`` (of each p_j and nonlinear field) as class variables and :meth:`basis`;
    optionally ``nonlinear`` (fields of the Module profiled on :meth:`grid`) and
    :meth:`implausible` (call ``super().implausible`` to keep the check b > 0). The parsimony
    penalty counts ``len(parameters) + len(nonlinear)`` parameters."""

    parameters: ClassVar[tuple[str, ...]]
    nonlinear: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs):
        """A user's own :meth:`implausible` is checked on every call: it returns a reason (a
        str) or None, else the rule is quoted (:func:`checked_reason`)."""
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("implausible")
        if own is None or cls.__module__.startswith("lionjax."):
            return

        @functools.wraps(own)
        def implausible(self, phys, lim):
            return checked_reason(self, own(self, phys, lim))

        cls.implausible = implausible

    @property
    def n_params(self) -> int:  # type: ignore[override]
        return len(self.parameters) + len(self.nonlinear)

    def basis(self, x: Array, v: Array, F: Array, t: Array) -> tuple[Array, ...]:
        """The φ_j(x [m], v [m/s], F [N], t [s]) [N per unit of p_j], one per parameter, each of
        x's shape: ``jax.numpy``, elementwise (called on whole records and on simulated steps)."""
        raise NotImplementedError(
            f"{type(self).__name__}: a ForceEffect defines basis(x, v, F, t) (or, for a "
            "measurement effect, record_basis(record, v))."
        )

    def record_basis(self, record: Record, v: Array) -> tuple[Array, ...]:
        """The φ_j on a whole record, (T,) each (``v``: its v̂ [m/s]); by default :meth:`basis`
        on its samples. A measurement effect may estimate from the whole record here."""
        t = record.t0 + record.dt * jnp.arange(record.n_samples, dtype=record.x.dtype)
        return tuple(self.basis(record.x, v, record.F, t))

    def grid(self, limits: Limits) -> Sequence[ForceEffect]:
        """The Modules, one per grid point, the profile searches (default: itself)."""
        return (self,)

    def profile(self, rss: Callable[[ForceEffect], float], limits: Limits) -> ForceEffect:
        """The grid point of least training RSS ``rss(effect)`` (alone on the baseline); with one
        nonlinear parameter, refined by :data:`REFINE_STEPS` golden-section steps between its
        neighbours on the grid. Override for another search (returning a new Module)."""
        grid = checked_grid(self, self.grid(limits))
        if len(grid) == 1:
            return grid[0]
        i, values = GridSearch(tuple(grid), 1).minimise(lambda g: [rss(g[0])])
        if not np.any(np.isfinite(values)):
            raise ValueError(f"{type(self).__name__}: no grid point could be fitted.")
        if len(self.nonlinear) != 1:
            return grid[i]
        (field,) = self.nonlinear
        at = lambda val: dataclasses.replace(grid[i], **{field: val})
        v0 = float(getattr(grid[i], field))
        pts = sorted(zip((float(getattr(g, field)) for g in grid), values, strict=True))
        j = pts.index((v0, values[i]))
        if not 0 < j < len(pts) - 1:
            return grid[i]  # on the grid's edge: nothing to bracket
        lo, hi = pts[j - 1][0], pts[j + 1][0]
        best, _ = GoldenSection(REFINE_STEPS).minimise(
            lambda val: float(rss(at(val))), lo, hi, v0, float(values[i])
        )
        return grid[i] if best == v0 else at(best)

    def profiled(self) -> bool:
        return not self.nonlinear

    def effects(self, st) -> tuple[AbstractEffect, ...]:
        return (ForceColumns(self),)

    def physical(self, phys, problem) -> dict:
        return self.nonlinear_values()

    def _force_on(self, phys: dict[str, float], record: Record, v) -> np.ndarray:
        """Σ p_j·φ_j [N] (T,) on ``record`` under the fitted ``phys``."""
        pairs = zip(self.parameters, self.record_basis(record, v), strict=True)
        return sum(float(phys.get(p, 0.0)) * np.asarray(phi, np.float64) for p, phi in pairs)

    def simulation(self, phys, problem) -> dict:
        """A device effect's force in the simulator (``"extra"``: the effect, its floats traced,
        and its coefficients), or a measurement effect's correction −Σ p_j·φ_j of the validation
        record's input (``"du"`` [N])."""
        if self.acts_on == "measurement":
            v = problem.signals("valid").v
            return {"du": self._force_on(phys, problem.valid, v)}
        coefs = tuple(jnp.asarray(float(phys.get(p, 0.0)), jnp.float64) for p in self.parameters)
        return {"extra": (traced(self), coefs)}

    def report(self, phys: dict[str, float]) -> dict[str, float]:
        keys = (*self.parameters, *self.nonlinear, *self.units)
        return {k: phys[k] for k in dict.fromkeys(keys) if k in phys}

    def measured_rms(self, phys: dict[str, float], record: Record, v) -> float | None:
        if self.acts_on != "measurement":
            return None
        return float(np.sqrt(np.mean(np.square(self._force_on(phys, record, v)))))

    def nonlinear_values(self) -> dict[str, float]:
        """The nonlinear parameters' values {field: value}."""
        return {f: float(getattr(self, f)) for f in self.nonlinear}


class ForceColumns(AbstractEffect):
    """A :class:`ForceEffect`'s columns −(1/Λ)[φ_j], coefficients b·p_j."""

    effect: ForceEffect

    @property
    def raw(self) -> tuple[str, ...]:
        """Its raw signals' names, the effect's nonlinear values in each (the regressors cache
        filtered signals by name)."""
        e = self.effect
        key = ",".join(f"{v:.12g}" for v in e.nonlinear_values().values())
        return tuple(f"effect:{e.name}@{key}[{j}]" for j in range(len(e.parameters)))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"b_{p}" for p in self.effect.parameters)

    def columns(self) -> tuple[Column, ...]:
        return tuple(Column(n, 0, -1.0) for n in self.raw)

    def signals(self, rs) -> dict:
        x = jnp.asarray(rs.x)
        phis = checked_basis(self.effect, rs.record, jnp.asarray(rs.v), fitted=rs.role == "train")
        # a correction of the measured F is held as F is (zero order), a force of the state as
        # x is (first order)
        hold = "zoh" if self.effect.acts_on == "measurement" else "foh"
        return {
            n: (np.asarray(jnp.broadcast_to(jnp.asarray(phi, jnp.float64), x.shape)), hold)
            for n, phi in zip(self.raw, phis, strict=True)
        }

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
    """Refuse a ForceEffect of ``candidates`` that is not usable (:mod:`._user_checks`)."""
    check_definitions([c for c in candidates if isinstance(c, ForceEffect)], reserved, ForceEffect)
