"""A structure (a list of candidates) fitted on training and scored on validation (:class:`Fitted`),
the variants a fit is chosen among, and the pattern search the profiles share."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ._candidates import (
    AbstractCandidate,
    Context,
)
from ._force_effects import ForceColumns
from ._statistics import _n_eff


@dataclasses.dataclass(frozen=True)
class Fitted:
    """One structure fitted on training and scored on validation."""

    names: tuple[str, ...]
    theta: np.ndarray
    std: np.ndarray
    physical: dict[str, float]
    tau: float
    fmax: float
    rss_train: float
    ms_valid: float  # mean square ε₁ on validation
    #: (ε₁ on validation, the windowed simulation error on validation [m]), or what recomputes
    #: them (a streamed fit holds no (T,) array: :class:`Recompute`)
    signals: tuple[np.ndarray, np.ndarray] | Recompute
    condition: float
    gap_from: int = 0  # the first sample the gap counts (the second window's)
    #: a simulated gap above this [m] is a diverging simulation (:data:`DIVERGED`)
    diverge_at: float = math.inf
    #: the fitter's variants it was fitted under (:class:`Variant`)
    variant: Variant | None = None
    #: the simulation error's samples and its rms from :attr:`gap_from` [m] (set by
    #: :meth:`of`)
    n_sim: int = 0
    gap_rms: float = math.nan
    #: the residual's effective sample count where computed when fitted (streamed fits)
    n_eff_at_fit: float | None = None

    @classmethod
    def of(cls, residual, sim_error, *, keep: bool = True, **fields) -> Fitted:
        """A fit with its validation residual and simulation error: held (``keep``), or
        summarised (their sample count, the gap, the residual's effective sample count) and
        recomputed when read (``fields["signals"]``, a :class:`Recompute`)."""
        g0 = fields.get("gap_from", 0)
        with np.errstate(over="ignore", invalid="ignore"):
            gap = float(np.sqrt(np.mean(sim_error[g0:] ** 2)))
        if keep:
            fields["signals"] = (residual, sim_error)
        else:
            fields["n_eff_at_fit"] = _n_eff(residual)
        return cls(n_sim=int(sim_error.size), gap_rms=gap, **fields)

    @property
    def residual(self) -> np.ndarray:
        """ε₁ on validation (T,)."""
        return self.signals[0] if isinstance(self.signals, tuple) else self.signals()[0]

    @property
    def sim_error(self) -> np.ndarray:
        """The windowed simulation error on validation [m] (T,)."""
        return self.signals[1] if isinstance(self.signals, tuple) else self.signals()[1]

    @property
    def gap(self) -> float:
        """rms windowed simulation error [m]; ``inf`` where the simulation diverges
        (:attr:`simulation`)."""
        g = self.gap_rms
        return g if g <= self.diverge_at else math.inf

    @property
    def simulation(self) -> str:
        """``"ok"``, or ``"diverged"``: the fitted model's windowed simulation left the record's
        range by :data:`DIVERGED`× or overflowed (an unstable fit, a < 0 or b < 0); its gap and
        shrink are then reported as ``null``, never as a number."""
        return "ok" if math.isfinite(self.gap) else "diverged"

    @property
    def equation_gap(self) -> float:
        return float(np.sqrt(self.ms_valid))

    @functools.cached_property
    def n_eff(self) -> float:
        """Effective sample count of the validation residual (:func:`_n_eff`), once per fit."""
        return self.n_eff_at_fit if self.n_eff_at_fit is not None else _n_eff(self.residual)


class Recompute:
    """What recomputes a streamed fit's (validation residual, simulation error), called when
    read (the baseline's and the final stack's are), its result kept: ``make()`` computes
    them."""

    def __init__(self, make):
        self.make, self.value = make, None

    def __call__(self) -> tuple[np.ndarray, np.ndarray]:
        if self.value is None:
            self.value = self.make()
        return self.value


def _has_position(cands: Sequence[AbstractCandidate]) -> bool:
    """Whether a structure holds the position-dependent a(x), b(x)."""
    return any(c.holds_position for c in cands)


def _has_mode(cands: Sequence[AbstractCandidate]) -> bool:
    """Whether a structure holds the flexible mode's columns."""
    return any(c.holds_mode for c in cands)


def _effects_of(cands: Sequence[AbstractCandidate], ctx: Context):
    # each effect type once (spring and offset share the offset column), each ForceEffect once
    out, seen = [], set()
    for c in cands:
        for e in c.effects(ctx):
            key = (type(e), e.effect.name if isinstance(e, ForceColumns) else None)
            if key not in seen:
                seen.add(key)
                out.append(e)
    return tuple(out)


class Variant(NamedTuple):
    """The variants a candidate's fit is chosen among, by validated score (:func:`diagnose`)."""

    degree: int  # of the position-dependent a(x), b(x); 0: the localized step and bump
    mode_input: bool  # the flexible mode's κ column (else collocated, κ = 0)
    fmax_shape: int  # the saturation's shape: +1 hard, −1 soft, 0 both
    position_clamp: bool  # a(x), b(x) held beyond the training positions
    stick: bool  # friction's force columns masked where the axis sticks
    presliding: bool  # friction's sign as Dahl's pre-sliding state (else the smoothed sign)


def _parabola_vertex(g, r) -> float | None:
    """The abscissa of the vertex of the parabola through (gₖ, rₖ), k = 0, 1, 2 (any spacing),
    held within [g₀, g₂]; None where the parabola does not open upward. A profile's minimum
    between the grid's best point and its neighbours."""
    (g0, g1, g2), (r0, r1, r2) = (float(v) for v in g), (float(v) for v in r)
    den = (g0 - g1) * (g0 - g2) * (g1 - g2)
    A = (g2 * (r1 - r0) + g1 * (r0 - r2) + g0 * (r2 - r1)) / den
    B = (g2**2 * (r0 - r1) + g1**2 * (r2 - r0) + g0**2 * (r1 - r2)) / den
    if not A > 0:
        return None
    return min(max(-B / (2 * A), min(g0, g2)), max(g0, g2))


def _pattern_search(start, best, steps, move, rss_of, seen, rounds: int, max_steps: int):
    """(point, RSS) of a pattern search in two parameters from ``start`` (its RSS ``best``): the
    8 neighbours ``move(point, i, j, steps)`` (i, j ∈ {−1, 0, 1}, clamped by ``move``) of the
    best so far, moving while one is better and halving both ``steps`` when none is (``rounds``
    halvings, at most ``max_steps`` rings). ``rss_of(points)`` gives the RSS of new points;
    ``seen`` {point: RSS} is shared across searches (successive rings and clamps repeat
    points)."""
    p, halvings = start, 0
    for _ in range(max_steps):
        ring = [move(p, i, j, steps) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
        todo = list(dict.fromkeys(q for q in ring if q not in seen))
        if todo:
            seen.update(zip(todo, np.asarray(rss_of(todo)).tolist(), strict=True))
        r = np.array([seen[q] for q in ring])
        if float(np.min(r)) < best:
            p, best = ring[int(np.argmin(r))], float(np.min(r))
            continue
        halvings += 1
        if halvings > rounds:
            break
        steps = tuple(0.5 * s for s in steps)
    return p, best
