"""One-page figure of a :class:`~lionjax.diagnosis.Diagnosis` (layer 4; matplotlib, Agg,
imported lazily)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._errors import InputError
from .._plotting import figure, save_figure
from .._units import unit

#: The least share drawn in the "which" panel: a fit that more than doubles the gap is written.
SHRINK_LEAST = -1.0
#: The units a position or a simulation error is drawn in, by size: (factor from SI, label),
#: largest first (:func:`_scale` picks one).
_SCALES = {
    "linear": ((1.0, "m"), (1e3, "mm"), (1e6, "µm"), (1e9, "nm")),
    "rotary": ((1.0, "rad"), (1e3, "mrad"), (1e6, "µrad"), (1e9, "nrad")),
}


def _scale(values, units: str) -> tuple[float, str]:
    """The (factor, label) of ``units`` in which the largest finite |value| [SI] reads between
    1 and 1000 (the last where it is smaller; the first where larger)."""
    v = np.abs(np.asarray(values, np.float64))
    top = float(np.max(v[np.isfinite(v)], initial=0.0))
    for k, label in _SCALES[units]:
        if top * k >= 1.0:
            return k, label
    return _SCALES[units][-1]


def plot_diagnosis(diagnosis, path: str | Path):
    """Write a one-page summary of ``diagnosis`` to ``path`` (format from the extension).

    Panels: measured position vs the windowed simulations of the baseline and the stacked model
    (restarts every H s); the filtered equation error ε₁ before and after; the residual's shares
    by band (the 'where' findings); the candidates ranked by score with their shrink. The
    samples of each searched region (``diagnosis.regions``) are shaded on the error panels.
    """
    path = Path(path)
    if path.parent and not path.parent.exists():
        raise InputError(f"--plot: folder {str(path.parent)!r} does not exist; create it first.")
    if path.is_dir():
        raise InputError(
            f"--plot: {str(path)!r} is a folder; give a file name in it, e.g. "
            f"{str(path / 'diagnosis.png')!r}."
        )
    s = diagnosis.series
    t = s["t"]
    n = s["sim_base"].size
    fig = figure(12, 9, layout=None)
    grid = fig.add_gridspec(2, 2)
    top = grid[0, 0].subgridspec(2, 1, height_ratios=(2, 1), hspace=0.05)
    eps, where, which = (fig.add_subplot(grid[i, j]) for i, j in ((0, 1), (1, 0), (1, 1)))
    a = fig.add_subplot(top[0])
    e = fig.add_subplot(top[1], sharex=a)
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    kx, ux = _scale(s["x"][:n], diagnosis.units)
    ke, ue = _scale(np.concatenate([s["sim_base"], s["sim_final"]]), diagnosis.units)
    a.plot(t[:n], s["x"][:n] * kx, "k", lw=1.2, label="measured")
    a.plot(t[:n], (s["x"][:n] + s["sim_base"]) * kx, "C1", lw=0.8, label="model (baseline)")
    a.plot(t[:n], (s["x"][:n] + s["sim_final"]) * kx, "C0", lw=0.8, label="augmented model")
    a.set(
        ylabel=f"x [{ux}]",
        title=f"validation: windowed simulation, restart every {float(s['H']):.0f} samples "
        f"({float(s['H']) * dt:.3g} s)",
    )
    a.tick_params(labelbottom=False)
    # matplotlib's "best" place searches every point (slow, and it warns, on long records)
    loc = "best" if t.size <= 100_000 else "upper right"
    a.legend(fontsize=8, loc=loc)
    e.plot(t[:n], s["sim_base"] * ke, "C1", lw=0.6, label="baseline − measured")
    e.plot(t[:n], s["sim_final"] * ke, "C0", lw=0.6, label="augmented − measured")
    e.set(xlabel="t [s]", ylabel=f"sim. error [{ue}]")
    e.legend(fontsize=7, loc=loc)
    eps.plot(t, s["residual_base"], "C1", lw=0.6, label="baseline")
    eps.plot(t, s["residual_final"], "C0", lw=0.6, label="augmented")
    floor = diagnosis.noise["equation_floor"]
    eps.axhspan(-floor, floor, color="0.85", label="noise floor (±1σ)")
    _shade_regions((eps, e), diagnosis.regions, s)
    eps.set(
        xlabel="t [s]",
        ylabel=f"ε₁ [{unit('m/s²', diagnosis.units)}]",
        title="filtered equation error" + (", regions shaded" if diagnosis.regions else ""),
    )
    eps.legend(fontsize=7, loc=loc)
    bands = [w for w in diagnosis.where if w.get("share") is not None and "fraction" in w]
    labels = [f"{w['kind']}: {w['band']}" for w in bands]
    y = np.arange(len(bands))
    where.barh(y, [w["share"] for w in bands], color="C3", label="share of residual")
    where.barh(
        y, [w["fraction"] for w in bands], fill=False, edgecolor="k", label="share of samples"
    )
    where.set_yticks(y, labels, fontsize=6)
    where.invert_yaxis()
    where.set(xlabel="share", title="where: residual by band")
    where.legend(fontsize=7)
    eff = diagnosis.effects
    y = np.arange(len(eff))
    colors = ["C2" if e.significant else "0.6" for e in eff]
    # each candidate alone: the share of the equation error it removes (what the diagnosis
    # judges by) and of the simulated gap, drawn within [SHRINK_LEAST, 1] and written beyond
    for dy, key, alpha, lab in (
        (-0.2, "equation_shrink", 0.45, "equation error"),
        (0.2, "shrink", 1.0, "windowed simulation"),
    ):
        v = np.array([getattr(e, key) for e in eff], np.float64)
        shown = np.clip(np.nan_to_num(v, nan=0.0), SHRINK_LEAST, 1.0)
        which.barh(y + dy, shown, height=0.4, color=colors, alpha=alpha, label=lab)
        for yy, vv in zip(y + dy, v, strict=True):
            if not vv >= SHRINK_LEAST:
                txt = "diverges" if vv == -np.inf else f"{vv:.3g}"
                which.text(SHRINK_LEAST, yy, f" {txt}", va="center", fontsize=6)
    which.set_xlim(SHRINK_LEAST - 0.05, 1.05)
    which.set_yticks(y, [f"{e.name} (score {e.score:.3g})" for e in eff], fontsize=8)
    which.invert_yaxis()
    which.axvline(0, color="k", lw=0.5)
    which.legend(fontsize=7, loc="lower right")
    which.set(
        xlabel="share each removes alone (green: significant)",
        title=f"which: verdict {diagnosis.verdict}\nstack: {', '.join(diagnosis.stack) or '—'}",
    )
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def _shade_regions(axes, regions, s) -> None:
    """Shade, on each time axis, the samples each region covers (one colour per region)."""
    for k, region in enumerate(regions):
        for j, ax in enumerate(axes):
            ax.fill_between(
                s["t"],
                0,
                1,
                where=region.mask(s),
                transform=ax.get_xaxis_transform(),
                color=f"C{(k + 2) % 10}",
                alpha=0.15,
                lw=0,
                label=region.describe().split(":")[0] if j == 0 else None,
            )
