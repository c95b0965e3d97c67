"""Errors of the force sensor the records (x, F) reveal, each a
:class:`~._force_effect.ForceEffect` with ``acts_on = "measurement"``: F_meas = F + s(t) carries
a term s the device never felt (docs/method.md, "Force-sensor errors"). A line at a fixed
frequency that x does not answer (:class:`ForceSensorLine`) and a drift of the sensor's zero
(:class:`ForceSensorDrift`); a scale error, a constant zero error or a skew between the channels
is a change of units or origin that no record of (x, F) tells from the device's own.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..._model_effects import Offset
from ..._record import Record
from ._base import AbstractPositionOrTime, Limits
from ._force_effect import ForceEffect

#: Mains frequencies [Hz] a line is searched at, ±MAINS_TOLERANCE on MAINS_POINTS grid points
#: each; its harmonics up to MAX_HARMONIC (below 0.45·f_s); LINE_ROWS rows of its design built
#: at once; a sensor line: the device feels at most LINE_SHARE_TOL of it (|1 − share|).
MAINS_HZ = (50.0, 60.0)
MAINS_TOLERANCE = 0.01
MAINS_POINTS = 21
MAX_HARMONIC = 5
LINE_ROWS = 1 << 18
LINE_SHARE_TOL = 0.3
#: Offsets (share of f₀) of the frequencies where F's line-shaped projection is measured as the
#: record's own level beside the line (no mains there), and the false-alarm probability at which
#: a line counts as present in F (:meth:`ForceSensorLine.detection_limit`).
NULL_OFFSETS = (-0.1, -0.08, -0.06, -0.04, 0.04, 0.06, 0.08, 0.1)
LINE_FALSE_ALARM = 1e-4


def _chi2_even_quantile(dof: int, p: float) -> float:
    """x with P(χ²_dof > x) = ``p`` for an even ``dof``: the survival function there is
    e^{−x/2}·Σ_{j<dof/2} (x/2)^j/j! (closed form), solved by bisection."""

    def sf(x: float) -> float:
        term, total = 1.0, 1.0
        for j in range(1, dof // 2):
            term *= x / 2 / j
            total += term
        return float(np.exp(-x / 2) * total)

    lo, hi = 0.0, 10.0 * dof + 100.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if sf(mid) > p else (lo, mid)
    return hi


def _around(mains: float) -> np.ndarray:
    """The frequencies [Hz] a line at the mains frequency ``mains`` is searched at:
    ±:data:`MAINS_TOLERANCE` on :data:`MAINS_POINTS` points."""
    return np.linspace(mains * (1 - MAINS_TOLERANCE), mains * (1 + MAINS_TOLERANCE), MAINS_POINTS)


def _harmonics(f0: float, dt: float) -> list[int]:
    """The harmonics k = 1 … :data:`MAX_HARMONIC` of f₀ below 0.45/dt."""
    return [k for k in range(1, MAX_HARMONIC + 1) if k * f0 < 0.45 / dt]


def line_in(F: np.ndarray, t: np.ndarray, f0: float, dt: float) -> np.ndarray:
    """The line in ``F``: its least-squares projection (the mean removed) on cos and sin of
    2πk·f₀·t for the harmonics k = 1 … :data:`MAX_HARMONIC` below 0.45/dt; shape of F."""
    ks = _harmonics(f0, dt)
    if not ks:
        return np.zeros_like(F)

    def design(a: int, b: int) -> np.ndarray:
        # cos and sin of kw from the powers of e^{iw}: one complex exponential, not 2K trig calls
        z = np.exp(2j * np.pi * f0 * (t[a:b] - t[0]))
        A = np.empty((b - a, 2 * len(ks)))
        zk = np.ones_like(z)
        for i in range(len(ks)):
            zk = zk * z  # 1·z is z exactly
            A[:, 2 * i], A[:, 2 * i + 1] = zk.real, zk.imag
        return A

    # by its normal equations, in row blocks (a long record's design is never held whole): the
    # columns are near-orthogonal over the record's many periods (AᵀA ≈ T/2·I)
    Fc = F - np.mean(F)
    blocks = [(a, min(a + LINE_ROWS, F.size)) for a in range(0, F.size, LINE_ROWS)]
    G, r = 0.0, 0.0
    for a, b in blocks:
        A = design(a, b)
        G, r = G + A.T @ A, r + A.T @ Fc[a:b]
    coef, *_ = np.linalg.lstsq(G, r, rcond=None)
    out = np.empty_like(Fc)
    for a, b in blocks:
        out[a:b] = design(a, b) @ coef
    return out


class ForceSensorLine(ForceEffect):
    """A line at a mains frequency f₀ [Hz] and its harmonics in the measured force: column the
    line s(t) estimated from each record's F (:func:`line_in`), parameter ``line_unfelt`` the
    share of it the device did not feel (force −share·s; a sensor line when |1 − share| ≤
    :data:`LINE_SHARE_TOL`), f₀ profiled near 50 and 60 Hz."""

    name: ClassVar[str] = "force_sensor_line"
    acts_on: ClassVar[str] = "measurement"
    parameters: ClassVar[tuple[str, ...]] = ("line_unfelt",)
    nonlinear: ClassVar[tuple[str, ...]] = ("f_line",)
    units: ClassVar[dict[str, str]] = {"line_unfelt": "", "f_line": "Hz"}
    f_line: float = 50.0

    def record_basis(self, record: Record, v):
        F = np.asarray(record.F, np.float64)
        dt = float(record.dt)
        t = float(record.t0) + dt * np.arange(F.size)
        return (-line_in(F, t, self.f_line, dt),)

    def grid(self, limits: Limits):
        fs = 1.0 / limits.dt
        return [
            ForceSensorLine(float(f)) for m in MAINS_HZ if m < 0.45 * fs for f in _around(m)
        ] or [self]

    def mains(self, dt: float) -> np.ndarray:
        """The frequencies [Hz] F's line is sought at: around the mains frequency of
        :data:`MAINS_HZ` nearest f₀ (:func:`_around`), below 0.45/dt."""
        f = _around(min(MAINS_HZ, key=lambda h: abs(h - self.f_line)))
        return f[f < 0.45 / dt]

    def detection_limit(self, problem, generic, phys):
        """The least size of a line seen (its RMS over F's, or its share of the input term), in
        two steps. F alone tells whether it holds a line: the largest projection :func:`line_in`
        over :meth:`mains` (a projection a tenth of a hertz off cancels over ten seconds), its
        mean square against the same projection's at :data:`NULL_OFFSETS` beside it (no line
        there: χ² with 2K degrees of freedom, K harmonics), present above the quantile of
        false-alarm probability :data:`LINE_FALSE_ALARM` over the frequencies searched
        (Bonferroni); absent, the least line it would show is the limit. Present, only x tells
        whether the device felt it, through the filter, which passes the line's column at the
        gain ρ = (RMS of the filtered line / of the filtered F) / (RMS of the line / of F): the
        limit is ``generic``/ρ; and where the fit alone ``phys`` reads the share ``line_unfelt``
        within :data:`LINE_SHARE_TOL` of neither 0 nor 1, at least the line's own size."""
        rec = problem.valid
        F = np.asarray(rec.F, np.float64)
        F = F - np.mean(F)
        F_rms = float(np.sqrt(np.mean(F**2)))
        dt = float(rec.dt)
        t = float(rec.t0) + dt * np.arange(F.size)
        searched = self.mains(dt)
        if not searched.size or not F_rms > 0:  # the mains lie above 0.45/dt, or F is constant
            return None
        # the strongest line (max holds one (T,) projection beside the best)
        projections = ((float(f), line_in(F, t, float(f), dt)) for f in searched)
        f0, line = max(projections, key=lambda fs: float(np.mean(fs[1] ** 2)))
        line_ms = float(np.mean(line**2))
        K = len(_harmonics(f0, dt))  # ≥ 1, and a frequency beside f₀ lies below 0.45/dt too
        beside = [
            float(np.mean(line_in(F, t, f, dt) ** 2))
            for f in (f0 * (1 + d) for d in NULL_OFFSETS)
            if f < 0.45 / dt
        ]
        level = float(np.mean(beside))
        p = LINE_FALSE_ALARM / len(searched)
        seen = level * _chi2_even_quantile(2 * K, p) / (2 * K)
        least = float(np.sqrt(seen)) / F_rms
        if not line_ms > seen:
            return least
        ms = problem.regressors(())[1].mean_square
        passed = float(np.sqrt(ms(line, "zoh", 0) / max(ms(F, "zoh", 0), 1e-300)))
        size = float(np.sqrt(line_ms)) / F_rms
        limit = max(least, generic / max(passed / size, 1e-300))
        share = None if phys is None else phys.get("line_unfelt")
        if share is not None and min(abs(share), abs(1.0 - share)) > LINE_SHARE_TOL:
            limit = max(limit, size)
        return limit

    def implausible(self, phys, lim):
        share = phys.get("line_unfelt", 0.0)
        if not 0.5 / lim.dt > self.f_line:
            return "the mains frequencies lie above the Nyquist frequency"
        if not abs(1.0 - share) <= LINE_SHARE_TOL:
            return (
                f"the device feels {1 - share:.0%} of the line (a sensor line: none of it, "
                f"within {LINE_SHARE_TOL:.0%})"
            )
        return super().implausible(phys, lim)


class ForceSensorDrift(AbstractPositionOrTime, ForceEffect):
    """A drift of the force sensor's zero at r [N/s] over each record: columns t − t_mid (the
    ramp) and the offset's (the zero at t_mid, a constant force F₀ the data cannot tell from one
    on the device). Containing the offset, a constant force alone is never a drift, while a
    sensor zeroed at each record's start (F₀ = r·(t_mid − t₁)) is explained whole; the offset
    stands in for it unless the ramp is significant with the rest of the stack (a slow trend an
    unmodelled friction leaves in ε₁ is not a drift)."""

    name: ClassVar[str] = "force_sensor_drift"
    acts_on: ClassVar[str] = "measurement"
    parameters: ClassVar[tuple[str, ...]] = ("drift_rate",)
    units: ClassVar[dict[str, str]] = {"drift_rate": "N/s", "F0": "N"}
    subsumes: ClassVar[tuple[str, ...]] = ("offset",)
    simpler: ClassVar[tuple[str, ...]] = ("offset",)

    @property
    def n_params(self) -> int:  # type: ignore[override]
        return 2  # r and F₀

    def effects(self, st):
        return (*super().effects(st), Offset())

    def record_basis(self, record: Record, v):
        n = record.n_samples
        return (-float(record.dt) * (np.arange(n, dtype=np.float64) - 0.5 * (n - 1)),)
