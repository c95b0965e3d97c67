"""Where the gap lies: regions of the validation record searched in the data, at a stated
family-wise error rate (:func:`find_regions`, :class:`Region`).

A region is a half-line or an interval of one variable z ∈ {x, v, |v|, F, |F|, t} where the
dynamics depart from the rest of the record, found by model-based recursive partitioning of the
baseline's ε₁ (Zeileis, Hothorn & Hornik 2008, partykit's ``mob``; the statistic and its null
are :mod:`._region_scan`'s) and the iterative scan for several regions. docs/diagnosis.md,
"Where the gap lies", states the method: why a half-line is reported on its minority side, why
``gap_share`` is less the selection's bias, why a region must explain ``min_explained``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np
from threadpoolctl import threadpool_limits

from .._errors import InputError
from .._units import unit
from ._region_scan import Found, Settings, covariate, points, refine, step, within

#: Each variable's unit on a linear axis (:func:`lionjax._units.unit` rewrites it for a rotary one).
UNITS = {"x": "m", "v": "m/s", "|v|": "m/s", "F": "N", "|F|": "N", "t": "s"}
#: the shortest block of the time permutation [s]
BLOCK_S = 0.25
#: the fewest samples a search needs: 20 points per side of the smallest region
MIN_SAMPLES = 200


@dataclasses.dataclass(frozen=True)
class Region:
    """One region of the validation record where the dynamics depart from the rest.

    Attributes:
        variable: ``x``, ``v``, ``|v|``, ``F``, ``|F|`` or ``t``.
        low, high: the bounds in the record's units (t in the validation record's own time);
            ``None`` for an open side. The region is low ≤ z < high.
        gap_share: its share of the baseline's validation misfit Σε₁², less the selection's bias.
        sample_share: its share of the validation samples. A later region's shares count the
            samples the earlier regions leave (the later steps search those).
        p_value: adjusted for all variables, candidates and earlier steps.
        stack_removes: 1 − Σε₁²(stack)/Σε₁²(baseline) over its samples: how far the verdict's
            stack shrinks the misfit there (``None``: no stack).
        simulation_share: its share of the baseline's windowed-simulation error Σe_sim², or None.
        statistic: its Lagrange-multiplier (Chow) statistic Λ (:mod:`._region_scan`).
        units: the record's unit system, ``"linear"`` or ``"rotary"``, which its texts state.
    """

    variable: str
    low: float | None
    high: float | None
    gap_share: float
    sample_share: float
    p_value: float
    stack_removes: float | None
    simulation_share: float | None
    statistic: float
    units: str = "linear"

    def mask(self, signals: Mapping[str, np.ndarray]) -> np.ndarray:
        """The samples of ``signals`` (arrays t, x, v, F) the region covers, bool (T,)."""
        return within(covariate(self.variable, signals), self.low, self.high)

    def to_json(self) -> dict:
        """The JSON fields; ``units`` is the unit of ``variable`` (``N``, ``rad/s`` …)."""
        return {**dataclasses.asdict(self), "units": unit(UNITS[self.variable], self.units)}

    def describe(self) -> str:
        """One line, e.g. ``|F| > 0.71 N: 24 % of samples, 68 % of the gap, p < 0.001; the
        stack removes 81 % of it``."""
        u, z, lo, hi = unit(UNITS[self.variable], self.units), self.variable, self.low, self.high
        if lo is not None and hi is not None:
            where = f"{lo:.3g} ≤ {z} < {hi:.3g} {u}"
        else:
            where = f"{z} > {lo:.3g} {u}" if lo is not None else f"{z} < {hi:.3g} {u}"
        p = "p < 0.001" if self.p_value < 0.001 else f"p = {self.p_value:.3f}"
        head = (
            f"{where}: {100 * self.sample_share:.0f} % of samples, "
            f"{100 * self.gap_share:.0f} % of the gap, {p}"
        )
        if self.stack_removes is None:
            return f"{head}; no effect is stacked"
        if self.stack_removes < 0:
            return f"{head}; the stack adds {-100 * self.stack_removes:.0f} % to it"
        return f"{head}; the stack removes {100 * self.stack_removes:.0f} % of it"


def find_regions(
    signals: Mapping[str, np.ndarray],
    *,
    alpha: float = 0.05,
    seed: int = 0,
    filter_hz: float | None = None,
    min_explained: float = 0.05,
    n_resamples: int = 199,
    max_regions: int = 3,
    bins: int = 32,
    min_share: float = 0.05,
    n_points: int = 2048,
) -> list[Region]:
    """The regions of the validation record where the dynamics depart from the rest, strongest
    first, each significant at the family-wise level ``alpha`` (docs/diagnosis.md, "Where the gap
    lies").

    Arguments:
        signals: arrays of one length T: ``t`` [s], ``x`` [m], ``v`` [m/s], ``F`` [N] of the
            validation record and ``residual_base`` (the baseline's ε₁ [m/s²]); optionally
            ``residual_final`` (the stacked model's ε₁, for ``stack_removes``) and ``sim_base``
            (the baseline's windowed-simulation error [m], ≤ T samples; ignored where it is not
            finite: a diverged simulation). Other keys are ignored.
        alpha: the family-wise error rate over variables, candidates and steps.
        seed: the resamples' seed (the same inputs and seed give the same answer).
        filter_hz: the corner of ε₁'s filter [Hz] (default min(f_s/25, 40 Hz), the diagnosis').
        min_explained: the least share of the first step's misfit Σr₀² a region's own
            correction removes to be reported.
        n_resamples: resamples per step.
        max_regions: the most regions reported.
        bins: quantile bins of each variable (the candidates' grid before the edges are refined).
        min_share: the least share of the points on each side of a candidate.
        n_points: the most points searched (blocks of ⌈T/n_points⌉ samples averaged).

    Returns:
        a list of :class:`Region` (``[]``: none is significant).
    """
    cfg = _checked(
        Settings(alpha, min_explained, n_resamples, max_regions, bins, min_share, n_points)
    )
    sig = _validated(signals)
    dt = float(sig["t"][-1] - sig["t"][0]) / (sig["t"].size - 1)
    fh = min(1.0 / (25.0 * dt), 40.0) if filter_hz is None else filter_hz
    if not (isinstance(fh, int | float) and math.isfinite(fh) and fh > 0):
        raise InputError(f"find_regions: expected filter_hz > 0 [Hz], got {filter_hz!r}.")
    # thin products (resamples × points by a few hundred columns): one BLAS thread is fastest
    with threadpool_limits(limits=1, user_api="blas"):
        return _search(sig, float(fh), np.random.default_rng(seed), cfg)


def _checked(cfg: Settings) -> Settings:
    if not (isinstance(cfg.alpha, int | float) and 0 < cfg.alpha < 1):
        raise InputError(
            f"find_regions: expected 0 < alpha < 1 (a family-wise level), got {cfg.alpha!r}."
        )
    for name, val, least in (
        ("n_resamples", cfg.P, 19),
        ("max_regions", cfg.max_regions, 1),
        ("bins", cfg.bins, 4),
        ("n_points", cfg.n_points, 64),
    ):
        if not (isinstance(val, int) and val >= least):
            raise InputError(f"find_regions: expected an integer {name} ≥ {least}, got {val!r}.")
    if not 0 < cfg.min_share < 0.5:
        raise InputError(f"find_regions: expected 0 < min_share < 0.5, got {cfg.min_share!r}.")
    if not 0 <= cfg.min_explained < 1:
        raise InputError(
            f"find_regions: expected 0 ≤ min_explained < 1, got {cfg.min_explained!r}."
        )
    return cfg


_REQUIRED = ("t", "x", "v", "F", "residual_base")


def _validated(signals) -> dict[str, np.ndarray]:
    """The signals as float64 arrays, checked: finite, 1-D, of one length T (sim_base ≤ T, or
    left out where it is not finite)."""
    if not isinstance(signals, Mapping):
        raise InputError(
            "find_regions: argument 'signals' must be a mapping of arrays (t, x, v, F, "
            f"residual_base; optionally residual_final, sim_base), got {type(signals).__name__}."
        )
    missing = [k for k in _REQUIRED if signals.get(k) is None]
    if missing:
        raise InputError(
            f"find_regions: signals lack {missing[0]!r}; expected the arrays t [s], x [m], "
            "v [m/s], F [N] and residual_base (ε₁ [m/s²]) of one length."
        )
    out = {}
    for k in (*_REQUIRED, "residual_final", "sim_base"):
        if signals.get(k) is None:
            continue
        a = out[k] = np.asarray(signals[k], np.float64)
        bad = np.flatnonzero(~np.isfinite(a))
        if k == "sim_base" and bad.size:  # a diverged simulation: no simulation_share
            del out[k]
            continue
        if a.ndim != 1:
            raise InputError(f"find_regions: signals[{k!r}] must be 1-D, got shape {a.shape}.")
        if bad.size:
            raise InputError(
                f"find_regions: signals[{k!r}] holds {bad.size} non-finite values (first at "
                f"sample {int(bad[0])}); remove or repair them before the search."
            )
        if not (a.size <= out["t"].size if k == "sim_base" else a.size == out["t"].size):
            raise InputError(
                f"find_regions: signals[{k!r}] has {a.size} samples, t has {out['t'].size}; "
                "pass arrays of one length (sim_base may be shorter: whole windows)."
            )
    if out["t"].size < MIN_SAMPLES:
        raise InputError(
            f"find_regions: needs at least {MIN_SAMPLES} samples, got {out['t'].size}."
        )
    if not np.all(np.diff(out["t"]) > 0):
        raise InputError("find_regions: signals['t'] must increase strictly (sample times [s]).")
    return out


def _search(sig: dict, filter_hz: float, rng, cfg: Settings) -> list[Region]:
    """The iterative scan (Zhang, Assunção & Kulldorff 2010): a region per step, its points and
    the filter's lag after them set aside for the next, until a step's p-value (kept
    non-decreasing) exceeds alpha or its region explains less than ``min_explained`` of the first
    step's misfit Σr₀²."""
    pts = points(sig, filter_hz, cfg.n_points)
    block = max(8, int(math.ceil(max(BLOCK_S, 20.0 / pts.lam) / pts.h)))
    active = np.ones(pts.r.size, bool)
    out: list[Region] = []
    total, taken = None, np.zeros(sig["t"].size, bool)
    for _ in range(cfg.max_regions):
        found = step(pts, active, rng, cfg, block)
        if found is None:
            break
        total = found.total if total is None else total
        p = max(found.p_value, out[-1].p_value) if out else found.p_value
        if p > cfg.alpha or found.explained < cfg.min_explained * total:
            break
        low, high = _beside(found.name, *refine(pts, active, found), out)
        out.append(_region(sig, found, low, high, p, taken))
        taken |= out[-1].mask(sig)
        gone = within(pts.z[found.name], low, high)
        for j in range(1, pts.lag + 1):  # the filter carries an effect into ε₁ for its lag
            gone[j:] |= gone[:-j].copy()
        active &= ~gone
    return out


def _beside(name: str, low, high, earlier: list[Region]):
    """The bounds less an earlier half-line of the same variable they overlap (v < 0.04 after
    v < −0.02 is −0.02 ≤ v < 0.04): a later step searches the samples earlier ones leave."""
    for r in earlier:
        if r.variable != name or (r.low is None) == (r.high is None):
            continue
        if r.low is None and (low is None or low < r.high) and (high is None or high > r.high):
            low = r.high
        elif r.high is None and (high is None or high > r.low) and (low is None or low < r.low):
            high = r.low
    return low, high


def _region(sig: dict, found: Found, low, high, p_value: float, taken: np.ndarray) -> Region:
    """The region's shares over the samples the earlier regions (``taken``) left."""
    inside = within(covariate(found.name, sig), low, high) & ~taken
    e = sig["residual_base"] ** 2
    removes = sim = None
    if "residual_final" in sig:
        ef = sig["residual_final"][inside] ** 2
        removes = float(1.0 - ef.sum() / max(e[inside].sum(), 1e-300))
    if "sim_base" in sig and sig["sim_base"].size:
        es = sig["sim_base"] ** 2
        sim = float(es[inside[: es.size]].sum() / max(es.sum(), 1e-300))
    return Region(
        variable=found.name,
        low=low,
        high=high,
        gap_share=float(np.clip(e[inside].sum() / max(e.sum(), 1e-300) - found.bias, 0.0, 1.0)),
        sample_share=float(np.mean(inside)),
        p_value=p_value,
        stack_removes=removes,
        simulation_share=sim,
        statistic=found.statistic,
    )
