"""The input map u = sat_Fmax(F(t − τ)): a delay τ of either sign (:class:`DelayCandidate`) and an
actuator saturation F_max (:class:`SaturationCandidate`), each searched again in every structure
it joins (:class:`InputMapSearch`): the map changes every column built from F."""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import equinox as eqx
import numpy as np

from .._search import GridSearch, ParabolaStep
from ._base import AbstractCandidate, Design

#: Hard clips tried between the best one's neighbours on the quantile grid.
CLIP_REFINE = 8
#: Steps per octave, and octaves at most, by which a limit on the small end of its grid is
#: searched further down.
WIDEN_STEPS, WIDEN_OCTAVES = 4, 8


class InputMapSearch(eqx.Module):
    """τ (``which = "tau"``) or F_max (``"fmax"``) of a structure's input map: the least
    training RSS over the settings' grid (τ log-spaced, of the sign ``shape``; F_max the force's
    quantiles as hard clips, soft saturations as negative values; ``shape`` +1 or −1 keeps one,
    0 both), a hard clip refined between its grid neighbours, then the vertex of the parabola
    through the best and its neighbours (in ln |τ|; within one shape). A limit best on the small
    end of its shape's grid is searched further down first (:meth:`_widen`): the force's
    quantiles bound the grid, not the device, and a search that ends on its edge has not found
    the minimum."""

    which: str
    shape: int = 0  # τ: 0 reads as +1

    def run(self, rss_of, d: Design, st) -> Design:
        """``d`` with its τ or F_max searched; ``rss_of(inputs)``: the structure's training RSS
        for each (τ, F_max) of ``inputs``."""
        tau = self.which == "tau"
        grid = np.asarray(st.tau_grid if tau else st.fmax_grid)
        if tau and self.shape < 0:
            grid = -grid
        if not tau and self.shape:
            grid = grid[np.sign(grid) == self.shape]

        def inputs(values):
            return [(float(v), d.fmax) if tau else (d.tau, float(v)) for v in values]

        i, rss = GridSearch(tuple(grid), nan_wins=True).minimise(lambda pts: rss_of(inputs(pts)))
        if not tau:
            grid, rss = self._widen(rss_of, inputs, grid, rss, i)
            i = int(np.argmin(rss))
            if grid[i] > 0:
                grid, rss = self._refine_clip(rss_of, inputs, grid, rss, i)
                i = int(np.argmin(rss))
        best = float(grid[i])
        if 0 < i < len(grid) - 1 and len({np.sign(g) for g in grid[i - 1 : i + 2]}) == 1:
            sign = -1.0 if grid[i] < 0 and tau else 1.0
            v = ParabolaStep(log=tau).vertex(sign * grid, rss, i)  # soft: g < 0
            if v is not None:
                best = sign * v
        return dataclasses.replace(d, **{"tau" if tau else "fmax": best})

    @staticmethod
    def _merged(rss_of, inputs, grid, rss, new):
        """(grid, rss) with the points ``new`` scored and added: the hard clips (g > 0)
        ascending, then the soft limits (g < 0) by ascending |g|."""
        r = np.asarray(rss_of(inputs(new)), np.float64)
        g, r = np.concatenate([grid, new]), np.concatenate([rss, r])
        pos = g > 0
        o = np.concatenate(
            [np.flatnonzero(pos)[np.argsort(g[pos])], np.flatnonzero(~pos)[np.argsort(-g[~pos])]]
        )
        return g[o], r[o]

    @classmethod
    def _widen(cls, rss_of, inputs, grid, rss, i):
        """(grid, rss) extended below the smallest |F_max| of the best's shape, by
        :data:`WIDEN_STEPS` per octave, while the best lies there (at most
        :data:`WIDEN_OCTAVES` octaves)."""
        grid, rss = np.asarray(grid, np.float64), np.asarray(rss, np.float64)
        for _ in range(WIDEN_OCTAVES):
            same = np.flatnonzero(np.sign(grid) == np.sign(grid[i]))
            if i != same[np.argmin(np.abs(grid[same]))]:
                break
            new = grid[i] * 2.0 ** (-np.arange(1, WIDEN_STEPS + 1) / WIDEN_STEPS)
            grid, rss = cls._merged(rss_of, inputs, grid, rss, new)
            i = int(np.argmin(rss))
        return grid, rss

    @classmethod
    def _refine_clip(cls, rss_of, inputs, grid, rss, i):
        """(grid, rss) with :data:`CLIP_REFINE` more hard clips between the best one's
        neighbours: a hard clip's RSS has a kink at the truth, and the quantiles thin out at the
        force's tail (a parabola through points far apart there can land beyond the largest
        force)."""
        hard = np.flatnonzero(grid > 0)
        k = int(np.searchsorted(hard, i))
        lo = grid[hard[max(k - 1, 0)]]
        hi = grid[hard[min(k + 1, hard.size - 1)]]
        fine = np.linspace(lo, hi, CLIP_REFINE + 2)[1:-1]
        fine = fine[~np.isin(fine, grid)]
        if fine.size == 0:
            return grid, rss
        return cls._merged(rss_of, inputs, grid, rss, fine)


class DelayCandidate(AbstractCandidate):
    """The recorded force out of step with the motion by τ [s]: u = F(t − τ), τ of the sign
    ``shape``, both tried alone and on each stack. τ > 0: a force acting late (a drive's
    latency); τ < 0: a recorded force lagging the force acting (a filtered current reading, a
    channel sampled late). In closed loop at the noise floor (``Limits.loop_noise``)
    it must also remove :data:`LOOP_NOISE_SHRINK` of the simulated gap: F(t − τ) − F(t) ≈ −τḞ,
    and Ḟ carries the controller's answer to the position noise, which cancels the noise's path
    through x in ε₁ — a gain on noise only the simulation, driven by the measured F, tells from a
    delay."""

    shape: int = 1
    name: ClassVar[str] = "delay"
    n_params: ClassVar[int] = 1
    units: ClassVar[dict[str, str]] = {"tau": "s", "tau_samples": ""}
    LOOP_NOISE_SHRINK: ClassVar[float] = 0.1

    def search(self):
        return InputMapSearch("tau", self.shape)

    def stack_variants(self):
        return [DelayCandidate(k) for k in (1, -1)]

    def physical(self, phys, problem) -> dict:
        """τ in sample intervals: −½ is a force sampled at instants and read as held over each
        interval (the mean force over interval k is F at its middle, half a sample after the
        sample F[k] stands for)."""
        return {"tau_samples": phys.get("tau", 0.0) / problem.st.dt}

    def implausible(self, phys, lim):
        if not phys.get("tau", 0):
            return "no delay"
        return super().implausible(phys, lim)

    def refusal(self, lim, gap_before: float, gap_after: float) -> str:
        s = self.LOOP_NOISE_SHRINK
        if lim.loop_noise and not gap_after <= (1 - s) * gap_before:
            return (
                "closed loop at the noise floor: it cancels the position noise the controller "
                f"feeds into F and removes less than {s:.0%} of the simulated gap "
                f"({gap_after:.3g} m against {gap_before:.3g} m)"
            )
        return ""


class SaturationCandidate(AbstractCandidate):
    """Actuator saturation F_max [N], hard u = clip(F, ±F_max) (``shape`` +1) or soft
    u = F_max·tanh(F/F_max) (−1), the shape chosen alone and again on each stack. Plausible when
    it acts on both records: a hard F_max below the largest force each reaches, a soft one below
    four times it (tanh still compresses it by ≥ 2 %); a clip validation never reaches gains
    only from a and b refitted on train's clipped peaks."""

    shape: int = 0
    name: ClassVar[str] = "saturation"
    n_params: ClassVar[int] = 1  # F_max; the shape is one binary choice
    units: ClassVar[dict[str, str]] = {"Fmax": "N", "soft": ""}

    def search(self):
        return InputMapSearch("fmax", self.shape)

    def stack_variants(self):
        return [SaturationCandidate(k) for k in (1, -1)]

    def report(self, phys):
        f = phys.get("Fmax", math.inf)
        return {"Fmax": abs(f), "soft": float(f < 0)}

    def implausible(self, phys, lim):
        f = phys.get("Fmax", math.inf)
        if not (0 < f < 0.99 * lim.F_abs_max or -4.0 * lim.F_abs_max < f < 0):
            return "F_max is not below the largest force"
        return super().implausible(phys, lim)
