"""Searches over a candidate's nonlinear parameters: typed Modules minimising a host function
of their points (a residual sum of squares), in the pattern of optimistix's minimisers
(``GoldenSearch``, ``BestSoFarMinimiser``): the search is a value, the function its argument.
Functions take a batch of points (one pass over the record) and return one value per point.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import numpy as np

from .._progress import counted

Batch = Callable[[Sequence[Any]], np.ndarray]


class GridSearch(eqx.Module):
    """The least of ``fn`` over ``points`` (evaluated ``batch`` points per call); NaN values
    never win unless ``nan_wins`` (then the first NaN does, as ``numpy.argmin`` has it)."""

    points: tuple
    batch: int = 1 << 30
    nan_wins: bool = False

    def values(self, fn: Batch) -> np.ndarray:
        starts = range(0, len(self.points), self.batch)  # counted on a status line, if drawn
        out = [
            np.asarray(fn(self.points[i : i + self.batch]), np.float64)
            for i in counted(starts, f"searching {len(self.points)} points", "batches")
        ]
        return np.concatenate(out) if out else np.zeros(0)

    def minimise(self, fn: Batch) -> tuple[int, np.ndarray]:
        """(the index of the least value, every value)."""
        r = self.values(fn)
        return int(np.argmin(r) if self.nan_wins else np.nanargmin(r)), r


class ParabolaStep(eqx.Module):
    """The vertex −B/(2A) of the parabola Ag² + Bg + C through the grid's point ``i`` and its
    two neighbours (g the parameter or its logarithm, ``log``), held within them; None on the
    grid's edge or where the parabola does not open upward."""

    log: bool = False

    def vertex(self, grid: np.ndarray, values: np.ndarray, i: int) -> float | None:
        if not 0 < i < len(grid) - 1:
            return None
        g = np.asarray(grid[i - 1 : i + 2], np.float64)
        g0, g1, g2 = (float(v) for v in (np.log(g) if self.log else g))
        r0, r1, r2 = (float(v) for v in values[i - 1 : i + 2])
        den = (g0 - g1) * (g0 - g2) * (g1 - g2)
        A = (g2 * (r1 - r0) + g1 * (r0 - r2) + g0 * (r2 - r1)) / den
        B = (g2**2 * (r0 - r1) + g1**2 * (r2 - r0) + g0**2 * (r1 - r2)) / den
        if not A > 0:
            return None
        v = min(max(-B / (2 * A), min(g0, g2)), max(g0, g2))
        return math.exp(v) if self.log else v


class GoldenSection(eqx.Module):
    """``steps`` golden-section steps of a scalar function between ``lo`` and ``hi`` (the bracket
    shrinks by 0.618 per step): (the best point seen, its value), from ``best``, ``best_value``."""

    steps: int = 16

    def minimise(self, f: Callable[[float], float], lo: float, hi: float, best, best_value):
        g = (math.sqrt(5.0) - 1.0) / 2.0
        c, d = hi - g * (hi - lo), lo + g * (hi - lo)
        seen: dict[float, float] = {}

        def at(v: float) -> float:
            nonlocal best, best_value
            if v not in seen:
                seen[v] = float(f(v))
                if seen[v] < best_value:
                    best, best_value = v, seen[v]
            return seen[v]

        for _ in range(self.steps):
            if at(c) < at(d):
                hi, d = d, c
                c = hi - g * (hi - lo)
            else:
                lo, c = c, d
                d = lo + g * (hi - lo)
        return best, best_value


class PatternSearch(eqx.Module):
    """A compass search in two parameters: the 8 neighbours ``move(point, i, j, steps)`` (i, j ∈
    {−1, 0, 1}, held within their bounds by ``move``) of the best point so far, moving while one
    is better and halving both steps where none is (``rounds`` halvings, at most ``max_steps``
    rings). ``seen`` {point: value} is shared between searches (successive rings and the bounds
    repeat points)."""

    rounds: int
    max_steps: int

    def minimise(self, fn: Batch, start, value: float, steps, move, seen: dict):
        p, halvings = start, 0
        for _ in range(self.max_steps):
            ring = [move(p, i, j, steps) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
            todo = list(dict.fromkeys(q for q in ring if q not in seen))
            if todo:
                seen.update(zip(todo, np.asarray(fn(todo)).tolist(), strict=True))
            r = np.array([seen[q] for q in ring])
            if float(np.min(r)) < value:
                p, value = ring[int(np.argmin(r))], float(np.min(r))
                continue
            halvings += 1
            if halvings > self.rounds:
                break
            steps = tuple(0.5 * s for s in steps)
        return p, value


def best_so_far(results: Sequence[tuple[Any, float]]) -> tuple[Any, float]:
    """The (point, value) of least value among searches' results (the first on a tie)."""
    return min(results, key=lambda t: t[1])
