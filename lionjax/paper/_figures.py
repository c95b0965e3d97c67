"""Figures of the paper reproduction (layer 4): Fig. 3–6 of Khadivar et al. and two summaries.

Each function takes results of :mod:`lionjax.paper` and returns a
``matplotlib.figure.Figure`` drawn on the Agg canvas (no pyplot, no GUI, no global state);
save it with ``fig.savefig(path)``. matplotlib is imported inside the functions, so
``import lionjax`` never needs it (install the ``plot`` extra).
"""

from __future__ import annotations

import numpy as np

from .._plotting import figure
from ._calibration import Calibration
from ._effect_study import EffectRow
from ._identification import PAPER_TRANSIENT, PaperTable
from ._reproduce import PaperResult
from ._verification import Verification


def calibration_figure(cal: Calibration):
    """Fig. 3: set force Fs against the measured produced force Fd, and the fitted line."""
    fig = figure(6.0, 4.5)
    ax = fig.add_subplot()
    x = np.asarray(cal.x)
    fd = np.asarray(cal.measured_force)
    fs = np.asarray(cal.set_force)
    for p in np.unique(x):
        m = x == p
        ax.plot(fd[m], fs[m], "o", ms=5, label=f"x = {p * 1e3:+.0f} mm")
    grid = np.linspace(0.0, fd.max() * 1.05, 50)
    k, c = float(cal.gain), float(cal.intercept)
    ax.plot(grid, k * grid + c, "k-", lw=1.2, label=f"fit: Fs = {k:.4f}·Fd {c:+.3f} N")
    ax.plot(grid, cal.truth * grid, "k:", lw=1.0, label=f"twin: Fs = {cal.truth:g}·Fd")
    ax.set_xlabel("measured (desired) force Fd [N]")
    ax.set_ylabel("set force Fs [N]")
    ax.set_title("Force calibration at five points (paper Fig. 3)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _region_index(result: PaperResult, point: float = 0.0) -> int:
    pts = np.asarray(result.config.operating_points)
    return int(np.argmin(np.abs(pts - point)))


def convergence_figure(result: PaperResult, region: int | None = None):
    """Fig. 4: a(t) and b(t) of Lion's law around one operating point (default x₂ = 0 mm).

    One column per settings, one line per input (repetition 1); the twin's values dashed.
    """
    r = _region_index(result) if region is None else region
    idns = result.identifications
    fig = figure(4.2 * len(idns), 5.5)
    axes = fig.subplots(2, len(idns), sharex=True, squeeze=False)
    ta = float(result.table.truth_a[r])
    tb = float(result.table.truth_b[r])
    xr = result.config.operating_points[r] * 1e3
    for j, idn in enumerate(idns):
        t = np.asarray(idn.t)
        th = np.asarray(idn.theta[r, :, 0])  # (I, S, 2)
        for i in range(th.shape[0]):
            axes[0, j].plot(t, th[i, :, 0], lw=1, label=f"input {i + 1}")
            axes[1, j].plot(t, th[i, :, 1], lw=1, label=f"input {i + 1}")
        axes[0, j].axhline(ta, color="k", ls="--", lw=1, label=f"twin a = {ta:g}")
        axes[1, j].axhline(tb, color="k", ls="--", lw=1, label=f"twin b = {tb:g}")
        axes[0, j].set_title(f"{idn.settings} settings, x = {xr:+.0f} mm")
        axes[0, j].set_ylim(min(0.0, 0.5 * ta), 1.6 * ta)
        axes[1, j].set_ylim(min(0.0, 0.5 * tb), 1.6 * tb)
        axes[1, j].set_xlabel("time t [s]")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
        axes[0, j].legend(fontsize=7, loc="lower right")
    axes[0, 0].set_ylabel("estimate of a [1/s]")
    axes[1, 0].set_ylabel("estimate of b [1/kg]")
    fig.suptitle("Parameter convergence of Lion's law (paper Fig. 4)")
    return fig


def tracking_error_figure(result: PaperResult, region: int | None = None, input: int = 3):
    """Fig. 5: the equation ("tracking") error ε₁(t) and its derivative ε₂(t) during the run.

    The paper's definition (filter (s+4)³ raw, x in mm, F in mN, θ(t) of the run), shown after the
    filter transient of 2.25 s, repetition 1 of ``input`` (1-based) at one operating point.
    """
    r = _region_index(result) if region is None else region
    idns = result.identifications
    i = min(input, len(result.config.inputs)) - 1
    fig = figure(4.2 * len(idns), 5.0)
    axes = fig.subplots(2, len(idns), sharex=True, squeeze=False)
    xr = result.config.operating_points[r] * 1e3
    for j, idn in enumerate(idns):
        t = np.asarray(idn.t)
        eps = np.asarray(idn.eps[r, i, 0])
        m = t >= PAPER_TRANSIENT
        axes[0, j].plot(t[m], eps[m, 0], lw=0.8)
        axes[1, j].plot(t[m], eps[m, 1], lw=0.8, color="C1")
        axes[0, j].set_title(f"{idn.settings}, x = {xr:+.0f} mm, input {i + 1}")
        axes[1, j].set_xlabel("time t [s]")
        for ax in axes[:, j]:
            ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("tracking error ε₁ [mm·s]")
    axes[1, 0].set_ylabel("its derivative ε₂ [mm]")
    fig.suptitle("Equation (tracking) error of Lion's law (paper Fig. 5)")
    return fig


def verification_figure(verifications: tuple[Verification, ...], names: tuple[str, ...]):
    """Fig. 6: the identified piecewise models against the twin under the verification input."""
    fig = figure(7.0, 6.0)
    ax, ax2, ax3 = fig.subplots(3, 1, sharex=True, height_ratios=(3, 1.4, 1.2))
    v0 = verifications[0]
    t = np.asarray(v0.t)
    ax.plot(t, np.asarray(v0.x_device) * 1e3, "k-", lw=2.0, label="twin (logged x)")
    for v, name, st in zip(verifications, names, ("--", ":"), strict=False):
        ax.plot(
            t,
            np.asarray(v.x_model) * 1e3,
            st,
            lw=1.5,
            label=f"{name} model, NRMSE {float(v.nrmse):.2%}",
        )
        ax2.plot(t, (np.asarray(v.x_model) - np.asarray(v.x_device)) * 1e3, st, lw=1.2, label=name)
    for n, b in enumerate((-10.0, 10.0)):
        ax.axhline(b, color="0.6", lw=0.8, ls="-.", label="region bounds ±10 mm" if n else None)
    ax.set_ylabel("position x [mm]")
    ax.legend(fontsize=8)
    ax.set_title("Verification: F = 3 cos(40t + 400) + 0.5t (paper Fig. 6)")
    ax2.set_ylabel("model − twin [mm]")
    ax2.legend(fontsize=7)
    ax3.plot(t, np.asarray(v0.force), "C2", lw=1)
    ax3.set_ylabel("force F [N]")
    ax3.set_xlabel("time t [s]")
    for a in (ax, ax2, ax3):
        a.grid(alpha=0.3)
    return fig


def table_figure(table: PaperTable):
    """Table 3 at a glance: error vs the twin of every record's estimate, and the summaries."""
    fig = figure(9.0, 4.0)
    axes = fig.subplots(1, 2)
    S, R = np.asarray(table.summary_a).shape
    for ax, est, summ, truth, name in (
        (axes[0], table.a, table.summary_a, table.truth_a, "a"),
        (axes[1], table.b, table.summary_b, table.truth_b, "b"),
    ):
        est, summ, truth = np.asarray(est), np.asarray(summ), np.asarray(truth)
        for s in range(S):
            err = 100 * (est[s] / truth[:, None, None] - 1)  # (R, I, K)
            for r in range(R):
                xs = r + 1 + (s - 0.5 * (S - 1)) * 0.25 + np.linspace(-0.06, 0.06, err[r].size)
                ax.plot(
                    xs,
                    err[r].ravel(),
                    "o",
                    ms=3,
                    color=f"C{s}",
                    alpha=0.6,
                    label=f"{table.settings[s]}: per record" if r == 0 else None,
                )
                ax.plot(
                    r + 1 + (s - 0.5 * (S - 1)) * 0.25,
                    100 * (summ[s, r] / truth[r] - 1),
                    "D",
                    ms=8,
                    mfc="none",
                    color=f"C{s}",
                    label=f"{table.settings[s]}: median" if r == 0 else None,
                )
        ax.axhline(0, color="k", lw=0.8)
        for lim in (-1, 1):
            ax.axhline(lim, color="k", lw=0.6, ls=":")
        ax.set_xticks(range(1, R + 1))
        ax.set_xticklabels(
            [
                f"region {r + 1}\nx = {p * 1e3:+.0f} mm"
                for r, p in enumerate(np.asarray(table.operating_points))
            ]
        )
        ax.set_ylabel(f"error of {name} vs twin [%]")
        ax.set_xlabel("region and operating point")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Identified parameters vs the twin (Table 3), dotted: ±1 %")
    return fig


def effects_figure(rows: tuple[EffectRow, ...]):
    """The validation NRMSE with one unmodelled effect on, against the baseline (log scale)."""
    fig = figure(7.5, 0.45 * len(rows) + 1.8)
    ax = fig.add_subplot()
    names = [r.name for r in rows]
    vals = [float(r.nrmse) for r in rows]
    y = np.arange(len(rows))
    ax.barh(y, vals, color="C3", alpha=0.8)
    base = float(rows[0].nrmse_baseline)
    ax.axvline(base, color="k", ls="--", lw=1, label=f"no effect: {base:.2%}")
    for yi, v, r in zip(y, vals, rows, strict=True):
        ax.text(v, yi, f" {v:.2%} (×{float(r.growth):.3g})", va="center", fontsize=8)
    ax.set_yticks(y)
    ax.set_yticklabels(names)
    ax.set_ylabel("effect switched on in the twin")
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlim(base / 3, max(vals + [base]) * 20)
    ax.set_xlabel("validation NRMSE of the identified model (verification input) [-]")
    ax.set_title("Sim-to-real gap: one unmodelled twin effect at a time")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3, axis="x")
    return fig


def paper_figures(result: PaperResult) -> dict:
    """All figures of :func:`lionjax.paper.reproduce_paper`, by file stem."""
    figs = {
        "fig3_calibration": calibration_figure(result.calibration),
        "fig4_convergence": convergence_figure(result),
        "fig5_tracking_error": tracking_error_figure(result),
        "fig6_verification": verification_figure(result.verifications, result.table.settings),
        "table3_errors": table_figure(result.table),
    }
    if result.effects:
        figs["effects_nrmse"] = effects_figure(result.effects)
    return figs


__all__ = [
    "calibration_figure",
    "convergence_figure",
    "effects_figure",
    "paper_figures",
    "table_figure",
    "tracking_error_figure",
    "verification_figure",
]
