"""Position-dependent dynamics a(x), b(x) (:class:`PositionCandidate`): a polynomial in x over
the travel, or a step and a bump confined around x₀ (:class:`~lionjax.LocalizedPosition`)."""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from ..._model_effects import (
    MAX_POSITION_DEGREE,
    LocalizedPosition,
    PolynomialPosition,
    local_values,
    position_terms,
    position_values,
)
from .._lstsq import rss_with_columns
from .._search import GridSearch, PatternSearch
from .._streaming import FilteredColumns, rows, scaled
from ._base import AbstractPositionOrTime, Design

#: The localized position's parameters (four amplitudes, x₀, w), and its (x₀, w) grid: widths
#: w = R·LOCAL_WIDTHS (R the span of the training positions' LOCAL_RANGE quantiles), centres
#: across R spaced by max(w, R/LOCAL_SPACING); then a pattern search in (x₀, ln w) (LOCAL_ROUNDS
#: step halvings, at most LOCAL_STEPS rings), w within R·LOCAL_W_RANGE.
LOCAL_PARAMS = 6
LOCAL_RANGE = (0.02, 0.98)
LOCAL_WIDTHS = (1 / 40, 1 / 12, 1 / 4)
LOCAL_SPACING = 32
LOCAL_ROUNDS = 2
LOCAL_STEPS = 8
LOCAL_W_RANGE = (1 / 100, 1.0)
#: Positions on which a(x) and b(x) are checked for sign across the covered range.
RANGE_POINTS = 257


class HeldPosition(PolynomialPosition):
    """:class:`~lionjax.PolynomialPosition` with raw signals per rows, a(x), b(x) held at their
    values at ξ = ``lo``, ``hi`` beyond them where ``held`` (aₖξ_cᵏẋ = d/dt ℓ(ξ_cᵏ⁺¹/(k+1) +
    ξ_cᵏ(ξ − ξ_c)) stays exact)."""

    held: bool = False
    lo: float = -math.inf
    hi: float = math.inf

    def __init__(self, center, scale, degree, held=False, lo=-math.inf, hi=math.inf):
        super().__init__(center, scale, degree)
        self.held, self.lo, self.hi = bool(held), float(lo), float(hi)

    def signals(self, rs) -> dict:
        x, F = np.asarray(rs.x, np.float64), np.asarray(rs.F, np.float64)
        out = {}
        for k in range(1, self.degree + 1):
            g, f, _ = position_terms(k)
            out[g] = (self._raw(x, k, 0), "foh")
            out[f] = (scaled(self._raw(x, k, 1), rows(F)), "zoh")
        return out

    def _raw(self, x, k: int, which: int):
        """Per rows, the degree-``k`` raw signal ℓξ_cᵏ⁺¹/(k+1) + ℓξ_cᵏ(ξ − ξ_c) (``which`` 0) or
        F's multiplier ξ_cᵏ (1), of x [m] (T,); ξ_c = clip(ξ, lo, hi) where ``held``, else ξ."""
        c, sc, lo, hi, held = float(self.center), float(self.scale), self.lo, self.hi, self.held

        def raw(k0, k1):
            xi = (x[k0:k1] - c) / sc
            xic = np.clip(xi, lo, hi) if held else xi
            gv, mv = position_values(xic, sc, k)
            return mv if which else gv + sc * mv * (xi - xic)

        return raw


def _local_raw(x, F, c: float, w: float, j: int):
    """Per rows, raw signal ``j`` of the localized step and bump at (x₀ = ``c``, ``w``):
    w·log cosh ξ, tanh ξ·F, w·tanh ξ, sech²ξ·F."""
    raw = lambda k0, k1: local_values(x[k0:k1], c, w)[(0, 2, 1, 3)[j]]
    return scaled(raw, rows(F)) if j % 2 else raw


class PositionCandidate(AbstractPositionOrTime):
    """a(x), b(x) polynomial in position of degree 1 … 3 (two parameters per degree), held or
    not beyond the training positions (``held``), or a step and a bump around x₀ of width w
    (``degree`` 0, :class:`~lionjax.LocalizedPosition`, x₀ and w profiled); the best validated
    form kept (``localized=False``: the polynomials only). Reports the coefficients of
    (x − x_c)ᵏ and x_c, or the amplitudes with ``x_step`` (x₀) and ``w_step`` (w)."""

    localized: bool = True
    degree: int = 1
    held: bool = False
    local: tuple = ()
    name: ClassVar[str] = "position_dependent"
    n_params: ClassVar[int] = 2  # per degree
    units: ClassVar[dict[str, str]] = {
        "da_dx": "1/(s·m)",
        "db_dx": "1/(kg·m)",
        "a_x2": "1/(s·m²)",
        "b_x2": "1/(kg·m²)",
        "a_x3": "1/(s·m³)",
        "b_x3": "1/(kg·m³)",
        "x_center": "m",
        "x_lo": "m",
        "x_hi": "m",
        "a_step": "1/s",
        "b_step": "1/kg",
        "a_bump": "1/s",
        "b_bump": "1/kg",
        "x_step": "m",
        "w_step": "m",
    }

    def effects(self, st):
        if self.degree == 0:
            if not self.local:
                raise ValueError("PositionCandidate: the localized (x₀, w) is not profiled yet")
            return (LocalizedPosition(*self.local),)
        lo, hi = ((r - st.x_center) / st.x_scale for r in st.x_range)
        return (HeldPosition(st.x_center, st.x_scale, self.degree, self.held, lo, hi),)

    def design(self, d: Design) -> Design:
        return Design(d.stick, self.held or d.held, d.tau, d.fmax)

    def params(self):
        return LOCAL_PARAMS if self.degree == 0 else self.n_params * self.degree

    def profiled(self) -> bool:
        return self.degree != 0 or bool(self.local)

    def variants(self, limits, chosen):
        # held or not where validation leaves train's range: the polynomial extrapolates right
        # for a slow dependence, wildly wrong for a saturating one (a bowl 1 − exp(−d²))
        out = [
            dataclasses.replace(self, degree=d, held=held)
            for held in ((False, True) if limits.outside else (False,))
            for d in range(1, MAX_POSITION_DEGREE + 1)
        ]
        # the localized step and bump (bounded: never held), a few % of the travel wide
        if self.localized:
            out.append(dataclasses.replace(self, degree=0, held=False))
        return out

    def profile(self, objective, limits):
        """The localized (x₀, w): least training RSS over the grid of :data:`LOCAL_WIDTHS` and
        centres (spaced by w: a narrow dip is invisible a few w away), then a pattern search."""
        if self.degree != 0 or self.local:
            return self
        rs, mask = objective.problem.signals("train"), objective.rtr.force_mask
        x = np.asarray(rs.x, np.float64)
        F = np.asarray(rs.F, np.float64)
        if mask is not None:
            F = F * mask
        lo, hi = (float(q) for q in np.quantile(x, LOCAL_RANGE))
        R = hi - lo
        if not R > 0:  # the axis does not move: nothing to localise (the fit says so)
            return dataclasses.replace(self, local=(lo, max(abs(lo), 1.0) * 1e-3))
        w_lo, w_hi = (R * f for f in LOCAL_W_RANGE)
        per = int(min(16, max(2, 2e8 // (rs.chunk * 4 * 32))))

        def rss_of(points) -> np.ndarray:
            # per point: the step's and the bump's signals, first-order hold and s/Λ for x's
            signs = (1.0, -1.0, 1.0, -1.0)
            terms = lambda c, w: [
                (_local_raw(x, F, c, w, j), (1.0, 0.0)[j % 2], 1 - j % 2, signs[j])
                for j in range(4)
            ]
            cols = FilteredColumns([terms(c, w) for c, w in points])
            return rss_with_columns(objective.rtr, objective.model, cols)

        grid = []
        for f in LOCAL_WIDTHS:
            w = R * f
            n = int(round(R / max(w, R / LOCAL_SPACING))) + 1
            grid += [(float(c), w) for c in np.linspace(lo, hi, n)]
        i, rss = GridSearch(tuple(grid), per, nan_wins=True).minimise(rss_of)
        (c, w), best = grid[i], float(rss[i])
        seen = dict(zip(grid, rss.tolist(), strict=True))

        def move(q, i, j, steps):
            return (
                min(max(q[0] + i * steps[0], lo), hi),
                min(max(q[1] * math.exp(j * steps[1]), w_lo), w_hi),
            )

        steps = (0.5 * max(w, R / LOCAL_SPACING), 0.5 * math.log(2.0))
        search = PatternSearch(LOCAL_ROUNDS, LOCAL_STEPS)
        batched = lambda pts: np.concatenate(
            [rss_of(pts[i : i + per]) for i in range(0, len(pts), per)]
        )
        (c, w), _ = search.minimise(batched, (c, w), best, steps, move, seen)
        return dataclasses.replace(self, local=(float(c), float(w)))

    def implausible(self, phys, lim) -> str:
        """Besides b ≤ 0: b(x) ≤ 0 or a(x) < 0 at a position both records cover (``x_range``,
        on :data:`RANGE_POINTS` points and at x₀): a mass and a viscous damping vary along a rail
        but stay positive (docs/method.md, "Position dependence")."""
        if why := super().implausible(phys, lim):
            return why
        lo, hi = lim.x_range
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            return ""
        x = np.linspace(lo, hi, RANGE_POINTS)
        if self.degree == 0:
            x = np.append(x, min(max(self.local[0], lo), hi))
            _, _, t, s2 = local_values(x, *self.local)
            a = phys["a"] + phys["a_step"] * t + phys["a_bump"] * s2
            b = phys["b"] + phys["b_step"] * t + phys["b_bump"] * s2
        else:
            u = x - phys["x_center"]
            a = phys["a"] + phys["da_dx"] * u
            b = phys["b"] + phys["db_dx"] * u
            for k in range(2, self.degree + 1):
                a, b = a + phys[f"a_x{k}"] * u**k, b + phys[f"b_x{k}"] * u**k
        if np.min(b) <= 0:
            i = int(np.argmin(b))
            return f"b(x) ≤ 0 at x = {x[i]:.4g} m: the input would not act there"
        if np.min(a) < 0:
            i = int(np.argmin(a))
            return f"a(x) = {a[i]:.3g} 1/s < 0 at x = {x[i]:.4g} m: a negative damping"
        return ""

    def physical(self, phys, problem) -> dict:
        if self.degree == 0:
            return {"x_step": self.local[0], "w_step": self.local[1]}
        out = {"x_center": problem.st.x_center}
        if self.held:
            out["x_lo"], out["x_hi"] = problem.st.x_range
        return out

    def simulation(self, phys, problem) -> dict:
        return {"x_lo": problem.st.x_range[0], "x_hi": problem.st.x_range[1]} if self.held else {}
