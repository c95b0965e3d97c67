"""The candidate effects the diagnosis tries (docs/method.md, "Effects" and "Diagnosis").

Each candidate is an :class:`AbstractCandidate`: a name, a parameter count for the parsimony
penalty, and what it adds to a structure — linear effect columns (:mod:`lionjax._model_effects`)
and/or one profiled input parameter (τ of a delay, F_max of a saturation).
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx

from .._model_effects import Coulomb, LinearPosition, Offset, Spring
from .._models import AbstractEffect


class Context(eqx.Module):
    """Record-derived settings shared by the candidates (see :func:`lionjax.diagnose`).

    Attributes:
        omega_v: bandwidth [rad/s] of the zero-phase velocity filter for sgn ẋ.
        v_eps: velocity scale [m/s] of the smoothed sign.
        x_center, x_scale: mean and spread of the training positions [m].
    """

    omega_v: float
    v_eps: float
    x_center: float
    x_scale: float


class AbstractCandidate(eqx.Module):
    """One candidate effect: ``name``, ``n_params`` and what it adds to a structure."""

    name: ClassVar[str]
    n_params: ClassVar[int]
    #: the profiled input parameter it sets, ``"tau"``, ``"fmax"`` or ``None``
    profiled: ClassVar[str | None] = None

    @abc.abstractmethod
    def effects(self, ctx: Context) -> tuple[AbstractEffect, ...]:
        """Linear effect columns added to the model (may be empty)."""


class OffsetCandidate(AbstractCandidate):
    """Constant force F₀ [N]: column −(1/Λ)[1]."""

    name: ClassVar[str] = "offset"
    n_params: ClassVar[int] = 1

    def effects(self, ctx):
        return (Offset(),)


class CoulombCandidate(AbstractCandidate):
    """Coulomb friction F_c·sgn ẋ [N]: column +(1/Λ)[tanh(v̂/v_ε)]."""

    name: ClassVar[str] = "coulomb_friction"
    n_params: ClassVar[int] = 1

    def effects(self, ctx):
        return (Coulomb(ctx.omega_v, ctx.v_eps),)


class SpringCandidate(AbstractCandidate):
    """Spring −k(x − x₀) [N]: columns +(1/Λ)[x] and the offset column (equilibrium)."""

    name: ClassVar[str] = "spring"
    n_params: ClassVar[int] = 2

    def effects(self, ctx):
        return (Spring(), Offset())


class PositionCandidate(AbstractCandidate):
    """a(x), b(x) linear in position (exact §3-style columns, :class:`LinearPosition`)."""

    name: ClassVar[str] = "position_dependent"
    n_params: ClassVar[int] = 2

    def effects(self, ctx):
        return (LinearPosition(ctx.x_center, ctx.x_scale),)


class DelayCandidate(AbstractCandidate):
    """Input delay τ [s]: u = F(t − τ), τ profiled on a grid and refined."""

    name: ClassVar[str] = "delay"
    n_params: ClassVar[int] = 1
    profiled: ClassVar[str | None] = "tau"

    def effects(self, ctx):
        return ()


class SaturationCandidate(AbstractCandidate):
    """Actuator saturation F_max [N]: u = clip(F, ±F_max), F_max profiled on a grid."""

    name: ClassVar[str] = "saturation"
    n_params: ClassVar[int] = 1
    profiled: ClassVar[str | None] = "fmax"

    def effects(self, ctx):
        return ()


#: The default library, in a fixed order (ties are broken by it: simplest first).
DEFAULT_CANDIDATES: tuple[AbstractCandidate, ...] = (
    OffsetCandidate(),
    CoulombCandidate(),
    SpringCandidate(),
    DelayCandidate(),
    SaturationCandidate(),
    PositionCandidate(),
)
