"""Friction: Coulomb and direction-dependent (asymmetric) friction, in one form shared by every
friction structure of a diagnosis (:class:`AbstractFriction`): the **sign** of the motion,
smoothed, F_c·tanh(v̂/v_ε) (v̂ the zero-phase velocity), or **Dahl's** pre-sliding state F_c·ζ
(dζ/dx = (1 − ζ·sgn ẋ)/z: the contact deflects elastically, stiffness F_c/z, before it slides),
z profiled on the training record; the force columns as recorded, or **masked where the axis
sticks** (``stick``: static friction balances every force there, which neither form describes).
The first friction candidate tried alone chooses the form by its validated score, and every
later one takes it, so that every friction structure pays the same parameters.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..._model_effects import presliding_signal
from .._search import GridSearch, ParabolaStep
from .._streaming import spans
from ._base import AbstractCandidate, Design, Limits, OneColumnEffect

#: Dahl's pre-sliding distances z [m]: PRESLIDING_PER_DECADE per decade from a tenth of the
#: position noise (at least PRESLIDING_RANGE[0]) to PRESLIDING_RANGE[1]. Metal contacts
#: pre-slide 1–10 µm, LuGre bristles F_s/σ₀ up to a few tens of µm; a longer "pre-sliding" is a
#: force that depends on position.
PRESLIDING_RANGE = (1e-7, 3e-5)
PRESLIDING_PER_DECADE = 6
#: How far below zero one direction's friction level may be fitted, as a share of the other's:
#: zero within the fit's accuracy (FRICTION_TOL); in a model that leaves an effect out, still
#: possibly asymmetric friction (FRICTION_DOUBT: Coulomb friction with an offset, the same force
#: while the axis moves, is then not told apart from it; an offset F₀ ≥ 3·F_c stands alone).
FRICTION_TOL = 0.05
FRICTION_DOUBT = 0.5


@jax.jit
def _dahl_chunk(d, zs, zeta0):
    def step(zeta, dk):
        s = jnp.sign(dk)
        zeta = s + (zeta - s) * jnp.exp(-jnp.abs(dk) / zs)
        return zeta, zeta

    end, out = jax.lax.scan(step, zeta0, d)
    return out.T, end


def dahl_chunked(v, dt: float, zs, chunk: int) -> np.ndarray:
    """(m, T) Dahl states ζ of v̂ [m/s] at the distances ``zs`` [m] (as
    :func:`lionjax._model_effects.dahl_states`: ζ → s + (ζ − s)·e^{−|d|/z} over each sample's
    displacement d = (v[k−1] + v[k])·dt/2, s = sgn d, from ζ = 0), chunk by chunk with the
    states carried, distances in batches of 1, 2, 4 or 8."""
    v = np.asarray(v, np.float64)
    d = np.concatenate([[0.0], 0.5 * (v[1:] + v[:-1]) * dt])
    zs = np.asarray(zs, np.float64)
    out = np.empty((zs.size, v.size))
    for i in range(0, zs.size, 8):
        part = zs[i : i + 8]
        b = next(b for b in (1, 2, 4, 8) if b >= part.size)
        zp = np.concatenate([part, np.repeat(part[-1:], b - part.size)])
        zeta = np.zeros(b)
        for k0, k1 in spans(v.size, chunk):
            Z, zeta = _dahl_chunk(np.pad(d[k0:k1], (0, chunk - (k1 - k0))), zp, zeta)
            out[i : i + part.size, k0:k1] = np.asarray(Z)[: part.size, : k1 - k0]
    return out


class FrictionSign(OneColumnEffect):
    """Coulomb friction F_c·s [N]: column +(1/Λ)[s], parameter b·F_c; s the smoothed sign
    tanh(v̂/v_ε) (``z`` = 0) or Dahl's state ζ at the pre-sliding distance ``z`` [m]."""

    param, phys = "bFc", "Fc"
    v_eps: float
    z: float = 0.0

    @property
    def signal(self) -> str:
        return presliding_signal(self.z) if self.z > 0 else "sgn_v"

    def raw(self, rs):
        if not self.z > 0:
            v, e = rs.v, self.v_eps
            return lambda k0, k1: np.tanh(v[k0:k1] / e)
        key = ("dahl", float(self.z))
        if key not in rs.memo:
            rs.memo[key] = dahl_chunked(rs.v, rs.dt, [self.z], rs.chunk)[0]
        return rs.memo[key]


class DirectionalFriction(OneColumnEffect):
    """The direction-dependent part of friction, −ΔF·|sgn ẋ| [N] (levels F⁺ for ẋ > 0, F⁻ for
    ẋ < 0: −F_c·sgn ẋ − ΔF·|sgn ẋ|, F_c = (F⁺ + F⁻)/2, ΔF = (F⁺ − F⁻)/2): column
    +(1/Λ)[|tanh(v̂/v_ε)|], parameter b·ΔF. (No viscous Δc·|ẋ|: it takes an offset's part.)"""

    param, phys, signal = "bdF", "dF", "abs_sgn_v"
    v_eps: float

    def raw(self, rs):
        v, e = rs.v, self.v_eps
        return lambda k0, k1: np.abs(np.tanh(v[k0:k1] / e))


class AbstractFriction(AbstractCandidate):
    """A friction candidate and its form: ``stick`` (force columns masked where the axis
    sticks), ``dahl`` (Dahl's form tried) and ``z`` (its distance [m]; 0: the smoothed sign)."""

    stick: bool = False
    dahl: bool = False
    z: float = 0.0

    def design(self, d: Design) -> Design:
        return Design(self.stick or d.stick, d.held, d.tau, d.fmax)

    def params(self) -> int:
        return self.n_params + (self.z > 0)  # and z, where Dahl's form is chosen

    def profiled(self) -> bool:
        return not self.dahl or self.z > 0

    def variants(self, limits: Limits, chosen) -> list:
        """Stick masked or not (where the axis sticks) × the smoothed sign or Dahl's; a later
        friction candidate takes the first's form."""
        first = next((c for c in chosen if isinstance(c, AbstractFriction)), None)
        if first is not None:
            return [self._with(first.stick, first.dahl, first.z)]
        sticks = (False, True) if limits.sticks else (self.stick,)
        return [self._with(k, d, 0.0) for k in sticks for d in (False, True)]

    def _with(self, stick: bool, dahl: bool, z: float):
        return dataclasses.replace(self, stick=stick, dahl=dahl, z=float(z))

    def profile(self, objective, limits: Limits):
        """Dahl's z: least training RSS over :data:`PRESLIDING_RANGE`, refined by a parabola in
        ln z where that lowers it; the smoothed sign where the least lies at the range's end."""
        if not self.dahl or self.z > 0:
            return self
        lo = max(0.1 * limits.position_noise, PRESLIDING_RANGE[0])
        hi = PRESLIDING_RANGE[1]
        n = max(int(round(PRESLIDING_PER_DECADE * math.log10(hi / lo))), 1) + 1
        zs = [float(z) for z in np.geomspace(min(lo, hi / 10), hi, n)]
        rs = objective.problem.signals("train")
        per = int(min(32, max(1, 2e8 // (rs.chunk * 32))))  # (per, chunk, 4) float64 at once

        def rss_of(grid) -> np.ndarray:
            Z = dahl_chunked(rs.v, rs.dt, grid, rs.chunk)
            keys = [("dahl", float(z)) for z in grid]
            rs.memo.update(zip(keys, Z, strict=True))
            try:
                return np.array([objective(self._with(self.stick, True, z)) for z in grid])
            finally:
                objective.drop([presliding_signal(z) for z in grid])
                for k in keys:
                    rs.memo.pop(k, None)

        i, rss = GridSearch(tuple(zs), per).minimise(rss_of)
        if i == len(zs) - 1:  # the smoothed sign
            return self._with(self.stick, False, 0.0)
        z = zs[i]
        v = ParabolaStep(log=True).vertex(np.asarray(zs), rss, i)
        if v is not None and rss_of([v])[0] < rss[i]:
            z = v
        return self._with(self.stick, True, z)

    def physical(self, phys, problem) -> dict:
        return {"presliding": self.z} if self.z > 0 else {}

    def simulated_gap_judges(self, stuck_share: float, crit) -> bool:
        # the simulated smoothed sign has no static friction: where the axis sticks for much of
        # the record it slides where the axis stuck, and only a diverging simulation is worse
        return stuck_share < crit.stuck_share


class CoulombCandidate(AbstractFriction):
    """Coulomb friction F_c·sgn ẋ [N] (module docstring: its forms)."""

    name: ClassVar[str] = "coulomb_friction"
    n_params: ClassVar[int] = 1
    units: ClassVar[dict[str, str]] = {"Fc": "N", "presliding": "m"}

    def effects(self, st):
        return (FrictionSign(st.v_eps, self.z),)

    def implausible(self, phys, lim):
        if not phys.get("Fc", 0) > 0:
            return "friction would push along the motion (F_c ≤ 0)"
        return super().implausible(phys, lim)


class AsymmetricFrictionCandidate(AbstractFriction):
    """Direction-dependent Coulomb friction, F⁺ for ẋ > 0 and F⁻ for ẋ < 0 [N]: the Coulomb
    column and :class:`DirectionalFriction`'s. Plausible when F⁺ + F⁻ > 0 and neither is below
    −:data:`FRICTION_TOL` times the other (a direction with almost no friction is fitted
    slightly negative as often as slightly positive)."""

    name: ClassVar[str] = "asymmetric_friction"
    n_params: ClassVar[int] = 2
    units: ClassVar[dict[str, str]] = {"Fc_pos": "N", "Fc_neg": "N", "presliding": "m"}
    subsumes: ClassVar[tuple[str, ...]] = ("coulomb_friction",)
    simpler: ClassVar[tuple[str, ...]] = ("coulomb_friction", "offset")
    excludes: ClassVar[tuple[str, ...]] = ("offset", "spring")

    def effects(self, st):
        return (FrictionSign(st.v_eps, self.z), DirectionalFriction(st.v_eps))

    def report(self, phys):
        Fc, dF = phys.get("Fc", math.nan), phys.get("dF", math.nan)
        out = {"Fc_pos": Fc + dF, "Fc_neg": Fc - dF}
        return out | ({"presliding": phys["presliding"]} if "presliding" in phys else {})

    def implausible(self, phys, lim):
        r = self.report(phys)
        lo, hi = sorted((r["Fc_pos"], r["Fc_neg"]))
        if not (hi > 0 and lo >= -FRICTION_TOL * hi):
            return "friction would push along the motion (F⁺ or F⁻ < 0)"
        return super().implausible(phys, lim)

    def stand_in_doubtful(self, params):
        lo, hi = sorted((params.get("Fc_pos", math.nan), params.get("Fc_neg", math.nan)))
        return bool(hi > 0 and lo >= -FRICTION_DOUBT * hi)
