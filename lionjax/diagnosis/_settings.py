"""Settings of a diagnosis adapted to the training record: the filter, the velocity filter, the
restart interval and the profile grids (:func:`settings`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._errors import InputError
from .._filters import FilterBank
from .._record import Record
from ._criteria import Criteria
from ._statistics import _feedback
from ._streaming import zero_phase


@dataclasses.dataclass(frozen=True)
class Settings:
    """Record-derived settings of a diagnosis (all SI): the filter's and the zero-phase
    velocity's corners [Hz], the smoothed sign's scale v_ε [m/s], the restart interval [s], the
    profile grids (τ [s], F_max [N], mode frequencies [Hz]) and the training positions' centre,
    scale and range [m]."""

    dt: float
    filter_hz: float
    velocity_hz: float
    v_eps: float
    window_s: float | None
    tau_grid: tuple[float, ...]
    fmax_grid: tuple[float, ...]
    mode_grid: tuple[float, ...]
    x_center: float
    x_scale: float
    x_range: tuple[float, float] = (-math.inf, math.inf)
    excited: tuple[float, float] = (0.0, math.inf)  # the force's band [Hz] (excited_band)

    def bank(self) -> FilterBank:
        w = 2 * math.pi * self.filter_hz
        return FilterBank.from_poles(np.full(3, -w), unit_dc_gain=True)


#: Upper bound of the default filter corner [Hz] (f_s/25 below): a record of the same device
#: sampled faster is weighted the same way, and the poles stay far from an encoder's noise band.
MAX_FILTER_HZ = 40.0
#: Least corner of v̂'s zero-phase filter [Hz] (below 0.3·f_s): 2.5× the filter corner cuts into
#: the excited band of slowly sampled records and moves sgn v̂'s reversals.
VELOCITY_MIN_HZ = 100.0
#: Longest delay of the default profile grid [s] (at least 60 samples).
MAX_DELAY_S = 0.03
#: Flexible-mode grid: from MODE_BAND[0]·f_filter to MODE_BAND[1]·f_filter (below 0.2·f_s) or
#: MODE_OVER_BAND × the excited band's top (below MODE_FS·f_s), MODE_N frequencies per factor
#: MODE_BAND[1]/MODE_BAND[0] (steps of 28 %, refined by the pattern search).
MODE_BAND = (0.1, 4.0)
MODE_N = 16
MODE_OVER_BAND = 1.25
MODE_FS = 0.4
#: The share of the force's power below the excited band and above it (:func:`excited_band`).
EXCITED_TAIL = 0.01
#: Soft-saturation levels in the F_max grid.
SOFT_N = 15
#: Shortest stick [s] that counts where the axis sticks (:func:`~._problem.stuck_mask`).
STICK_MIN_S = 0.01

#: Least number of windows the validation record holds (the gap's evidence counts windows).
WINDOWS_LEAST = 8


def settings(
    train: Record,
    *,
    filter_hz: float | None = None,
    window_s: float | None = None,
    feedback_share: float = Criteria.feedback_share,
) -> Settings:
    """Settings adapted to the training record; a record that cannot support one (no motion,
    no force) gets an :class:`~lionjax.InputError` naming it. ``feedback_share``: the share of
    the force's innovation the position explains from which F answers a controller
    (:attr:`~lionjax.diagnosis.Criteria.feedback_share`)."""
    dt = float(train.dt)
    fs = 1.0 / dt
    # the band the excitation covers: in closed loop the force less the controller's answer to
    # the position (F also carries the position noise fed back, broadband); in open loop F
    # itself (there C∗x fits the plant's inverse, s²/b at high frequency, and would take the
    # excitation's upper band out with it)
    x, F = np.asarray(train.x, np.float64), np.asarray(train.F, np.float64)
    share, F_ref = _feedback(x, F)
    excited = excited_band(F_ref if share >= feedback_share else F, dt)
    fh = min(fs / 25.0, MAX_FILTER_HZ) if filter_hz is None else float(filter_hz)
    if not (0 < fh < fs / 2):
        raise InputError(
            f"filter_hz: expected 0 < filter_hz < f_s/2 = {fs / 2:.6g} Hz, got {filter_hz!r}."
        )
    vh = max(min(2.5 * fh, 0.15 * fs), min(VELOCITY_MIN_HZ, 0.3 * fs))
    v = zero_phase(x, dt, 2 * math.pi * vh)[1]
    # speed scale: a record that sticks most of the time has v̂ ≈ 0 on more than half of its
    # samples (the median is then the smoothing's tail): take it over the moving samples
    va = np.abs(v)
    ok = bool(np.all(np.isfinite(va)))
    med = float(np.median(va)) if ok else math.nan
    top = float(np.quantile(va, 0.99)) if ok else math.nan
    moving = va > 0.01 * top if ok else va > 0
    if ok and not med > 0.01 * top and np.any(moving):
        med = float(np.median(va[moving]))
    if not (ok and med > 0 and np.mean(moving) >= 0.02):
        raise InputError(
            "diagnose: the training record (argument 'train') does not move enough to locate "
            "velocity reversals "
            f"(median |v̂| while moving = {med!r} m/s on {np.mean(moving):.1%} of the samples, "
            f"from a {vh:.4g} Hz zero-phase derivative filter; at least 2 % moving needed); "
            "record a motion that covers the range of interest."
        )
    v_eps = 0.02 * med
    tau_max = min(max(60 * dt, MAX_DELAY_S), 0.1 * train.n_samples * dt)
    taus = np.geomspace(0.25 * dt, max(tau_max, dt), 32)
    fq = np.quantile(np.abs(F), np.linspace(0.3, 0.995, 28))
    fq = np.unique(fq[fq > 0])
    if fq.size == 0:
        raise InputError(
            "diagnose: the train record's force F is zero everywhere; the input must excite the "
            "axis."
        )
    f_hi = max(min(MODE_BAND[1] * fh, 0.2 * fs), min(MODE_OVER_BAND * excited[1], MODE_FS * fs))
    f_lo = min(max(MODE_BAND[0] * fh, 0.5), 0.5 * f_hi)
    n_modes = max(MODE_N, int(math.ceil(MODE_N * math.log(f_hi / f_lo) / math.log(40.0))))
    return Settings(
        dt=dt,
        filter_hz=fh,
        velocity_hz=vh,
        v_eps=v_eps,
        window_s=window_s,
        tau_grid=tuple(float(t) for t in taus),
        # hard clips at the force quantiles, then soft ones (negative: |F_max|·tanh(F/|F_max|))
        # up to the plausibility limit, 4× the largest force
        fmax_grid=tuple(float(f) for f in fq)
        + tuple(-float(f) for f in np.geomspace(0.5 * fq[0], 4.0 * fq[-1], SOFT_N)),
        mode_grid=tuple(float(f) for f in np.geomspace(f_lo, f_hi, n_modes)),
        x_center=float(np.mean(x)),
        x_scale=float(max(np.std(x), 1e-12)),
        x_range=(float(np.min(x)), float(np.max(x))),
        excited=excited,
    )


def excited_band(F: np.ndarray, dt: float) -> tuple[float, float]:
    """(f_lo, f_hi) [Hz] the force excites: below and above them lies :data:`EXCITED_TAIL` of
    its power each (periodogram, Hann window, mean and linear trend removed)."""
    n = F.size
    if n < 16:
        return 0.0, 0.5 / dt
    k = np.arange(n)
    Fd = F - np.polyval(np.polyfit(k, F, 1), k)
    P = np.abs(np.fft.rfft(Fd * np.hanning(n))) ** 2
    P[0] = 0.0
    c = np.cumsum(P)
    if not c[-1] > 0:
        return 0.0, 0.5 / dt
    f = np.fft.rfftfreq(n, dt)
    lo = f[int(np.searchsorted(c, EXCITED_TAIL * c[-1]))]
    hi = f[min(int(np.searchsorted(c, (1 - EXCITED_TAIL) * c[-1])), f.size - 1)]
    return float(lo), float(hi)
