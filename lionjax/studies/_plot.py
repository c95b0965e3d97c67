"""The designer's map of a gain × filter-pole study (layer 4; matplotlib on Agg, imported lazily).

:func:`study_figure` draws, over (gain, filter pole), heat maps of the convergence time to within
the tolerance of LS, the final bias vs LS and the noise amplification (record axes pooled by
the median), cells that never converged greyed and labelled "n.c.", optionally the tuning
objective J with its grid minimum boxed, and the gradient-tuned point as a star on every map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .._errors import InputError
from .._estimators import AbstractGain, AutoGain, FixedGain
from .._plotting import figure
from ._result import StudyResult
from ._tune import TuneSolution


def _position(value: float, grid: Sequence[float]) -> float:
    """Fractional cell index of ``value`` on a (log-spaced) axis ``grid`` (clipped to it)."""
    lg = np.log(np.asarray(grid, float))
    order = np.argsort(lg)
    return float(np.interp(math.log(value), lg[order], np.arange(len(lg))[order]))


def _pole_axis(poles: list[list[float]]) -> tuple[list[str], list[float] | None, str]:
    """(tick labels, magnitudes p if every set is one n-fold real pole else None, axis label)."""
    P = np.asarray(poles, float)
    if np.all(P == P[:, :1]):
        n = P.shape[1]
        return (
            [f"{-row[0]:.3g}" for row in P],
            list(-P[:, 0]),
            f"filter pole p [rad/s], $\\Lambda = (s + p)^{n}$",
        )
    return [",".join(f"{q:g}" for q in row) for row in P], None, "filter poles [rad/s]"


def study_figure(
    result: StudyResult,
    *,
    gain: type[AbstractGain] = FixedGain,
    objective: np.ndarray | None = None,
    tuned=None,
    reduce: str = "median",
    title: str | None = None,
):
    """Heat maps over (gain, filter pole) of a :class:`~lionjax.studies.StudyResult` (needs both
    dims); ``gain`` is the gain Module class the study ran (labels the gain axis).

    Panels: convergence time to within ``result.tolerance`` of LS [s] (n.c.: not converged by
    the end of the record, grey), final bias maxᵢ|θᵢ(T) − θ_LS,ᵢ|/|θ_LS,ᵢ| [%], noise
    amplification maxᵢ σᵢ/|θ_LS,ᵢ| [%] (σ over the last quarter of the record), each pooled over
    the other dims with ``reduce`` (log colour scales span at most two decades above the best
    cell; every cell is labelled with its value); and, if ``objective`` (a (gain, pole) array, e.g.
    ``TuneObjective.on_study(result)``) is given, the tuning objective J [s] with its grid
    minimum boxed. ``tuned`` (a :class:`~lionjax.studies.TuneSolution`, or a (gain, pole magnitude)
    pair [gain, rad/s]) is starred on every panel when the pole sets are n-fold single poles.

    Returns:
        a ``matplotlib.figure.Figure`` (Agg canvas; ``fig.savefig(path)``).
    """
    import matplotlib as mpl
    from matplotlib import colors, patches

    if not isinstance(result, StudyResult):
        raise InputError(f"study_figure: expected a StudyResult, got {type(result).__name__}.")
    if not (isinstance(gain, type) and issubclass(gain, AbstractGain)):
        raise InputError(
            f"study_figure: gain must be the gain Module class the study ran (lionjax.FixedGain "
            f"or lionjax.AutoGain), got {gain!r}."
        )
    if "gain" not in result.dims or "poles" not in result.dims:
        raise InputError(
            f"study_figure: the study needs a gain and a poles axis for the map, got dims "
            f"{result.dims}. Run lj.study(..., gains=[...], poles=[...])."
        )
    panels = [
        (
            result.map("convergence_time", reduce=reduce),
            f"convergence time to within {100 * result.tolerance:g} % of LS",
            "s",
            False,
        ),
        (
            100 * result.map("bias", reduce=reduce),
            "final bias vs LS (max over parameters)",
            "%",
            True,
        ),
        (
            100 * result.map("noise_amplification", reduce=reduce),
            "noise amplification: std of θ(t) in the last quarter / |θ_LS|",
            "%",
            True,
        ),
    ]
    if objective is not None:
        obj = np.asarray(objective, float)
        if obj.shape != panels[0][0].shape:
            raise InputError(
                f"study_figure: objective must have the (gain, pole) shape {panels[0][0].shape}, "
                f"got {obj.shape}."
            )
        panels.append((obj, "tuning objective J (mean over records)", "s", True))
    gains = result.coords["gain"]
    ticks, mags, pole_label = _pole_axis(result.coords["poles"])
    gl = "AutoGain rate g [1/s], G = g·R⁻¹" if issubclass(gain, AutoGain) else "gain g, G = g·I"
    star = None
    star_label = "tuned (lj.studies.tune)"
    if tuned is not None and mags is not None:
        g, p = (tuned.gain, tuned.pole) if isinstance(tuned, TuneSolution) else tuned
        star = (_position(float(g), gains), _position(float(p), mags))
        inside = min(gains) <= g <= max(gains) and min(mags) <= p <= max(mags)
        if not inside:
            star_label = f"tuned (g = {g:.3g}, p = {p:.3g}: outside the grid, drawn at its edge)"
    ncol = 2 if len(panels) == 4 else 3
    nrow = math.ceil(len(panels) / ncol)
    fig = figure(5.2 * ncol, 3.9 * nrow + (0.3 if title else 0.0))
    if title:
        fig.suptitle(title)
    handles = []
    for k, (z, label, unit, logscale) in enumerate(panels):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        finite = np.isfinite(z)
        zz = np.where(finite, z, np.nan)
        pos = zz[finite & (zz > 0)] if np.any(finite) else np.array([])
        norm, extend = None, "neither"
        if logscale and pos.size and pos.max() > 10 * pos.min():
            # colours resolve the two decades above the best cell; worse cells saturate
            top = min(pos.max(), 100 * pos.min())
            norm = colors.LogNorm(vmin=pos.min(), vmax=top)
            extend = "max" if pos.max() > top else "neither"
        cmap = mpl.colormaps["viridis"].with_extremes(bad="0.82")
        im = ax.imshow(zz.T, origin="lower", aspect="auto", cmap=cmap, norm=norm)
        ax.set_xticks(range(len(gains)), [f"{g:.3g}" for g in gains], fontsize=8)
        ax.set_yticks(range(len(ticks)), ticks, fontsize=8)
        ax.set_xlabel(gl, fontsize=9)
        ax.set_ylabel(pole_label, fontsize=9)
        ax.set_title(f"{label} [{unit}]", fontsize=9)
        for i in range(z.shape[0]):
            for j in range(z.shape[1]):
                v = z[i, j]
                if np.isinf(v):
                    text, color = "n.c.", "0.15"
                elif np.isnan(v):
                    text, color = "–", "0.15"
                else:
                    text = f"{v:.2g}" if abs(v) < 100 else f"{v:.0f}"
                    r, gch, b, _ = im.cmap(im.norm(v))
                    color = "k" if 0.299 * r + 0.587 * gch + 0.114 * b > 0.55 else "w"
                ax.text(i, j, text, ha="center", va="center", color=color, fontsize=7)
        if k == 3 and np.any(np.isfinite(z)):
            i, j = np.unravel_index(np.nanargmin(np.where(np.isfinite(z), z, np.nan)), z.shape)
            handles.append(
                ax.add_patch(
                    patches.Rectangle(
                        (i - 0.5, j - 0.5),
                        1,
                        1,
                        fill=False,
                        ec="tab:orange",
                        lw=2.5,
                        label="grid minimum of J",
                    )
                )
            )
        if star is not None:
            (h,) = ax.plot(
                *star, marker="o", ms=22, mfc="none", mec="r", mew=2.0, ls="", label=star_label
            )
            if k == 0:
                handles.append(h)
        fig.colorbar(im, ax=ax, label=unit, extend=extend)
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8)
    return fig
