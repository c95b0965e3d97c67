"""Measurement candidates: errors of the force sensor that the records (x, F) reveal.

A sensor error is not dynamics: the measured force F_meas = F + s(t) carries a term s the device
never felt. The model sees ẍ + aẋ = b·F_meas − b·s, so s appears in the equation error like a
force, and without a candidate of its own it is given a mechanical name (a mains line at 50 Hz
can be named ``flexible_mode``: the mode's columns (s²/D)[F] pass a narrow band around the
line). Each candidate here is a :class:`~._force_effect.ForceEffect` with
``acts_on = "measurement"``: its columns are estimated from each record's own F, and the windowed
simulation subtracts the fitted s from the input.

What the records can and cannot reveal (docs/effects.md):

- **a line at a fixed frequency** in F with no response in x (:class:`ForceSensorLine`): the
  line's share the device does not feel is fitted; a sensor line has 1 (all of it), a real force
  ripple 0 (x answers it, and the baseline already explains it);
- **a drift** of the sensor's zero over a record (:class:`ForceSensorDrift`): a force growing
  linearly in time that x does not follow (with the zero's mean over the record, F₀);
- **not** a pure scale error F_meas = (1 + ε)·F (it rescales the fitted b to b/(1 + ε), and every
  prediction of x from F_meas stays right), **not** a constant zero error (it is a constant force,
  reported as ``offset``: F₀ is the sum of both), **not** a constant time skew between the x and F
  channels (it is an input delay, reported as ``delay``) — each is a change of units or origin
  that no record of (x, F) alone can tell from the device's own.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..._model_effects import Offset
from ..._record import Record
from ._base import Limits
from ._force_effect import ForceEffect

#: Mains frequencies [Hz] a force-sensor line is searched at, each within ±MAINS_TOLERANCE.
MAINS_HZ = (50.0, 60.0)
MAINS_TOLERANCE = 0.01
#: Grid points per mains frequency (then a golden-section refinement between neighbours).
MAINS_POINTS = 21
#: Highest harmonic of the line estimated from F (below 0.45·f_s).
MAX_HARMONIC = 5
#: Rows of :func:`line_in`'s design built at once.
LINE_ROWS = 1 << 18
#: A sensor line: the device feels at most this share of the line in F (|1 − share|).
LINE_SHARE_TOL = 0.3


def line_in(F: np.ndarray, t: np.ndarray, f0: float, dt: float) -> np.ndarray:
    """The line in ``F``: its least-squares projection (the mean removed) on cos and sin of
    2πk·f₀·t for the harmonics k = 1 … :data:`MAX_HARMONIC` below 0.45/dt; shape of F."""
    ks = [k for k in range(1, MAX_HARMONIC + 1) if k * f0 < 0.45 / dt]
    if not ks:
        return np.zeros_like(F)

    def design(a: int, b: int) -> np.ndarray:
        # cos and sin of kw (k = 1 … K, as ks) from the powers of e^{iw}: one complex
        # exponential, not 2K trig calls (a profile over the mains frequencies builds ~60 of
        # these per record)
        z = np.exp(2j * np.pi * f0 * (t[a:b] - t[0]))
        A = np.empty((b - a, 2 * len(ks)))
        zk = z
        for i in range(len(ks)):
            if i:
                zk = zk * z
            A[:, 2 * i], A[:, 2 * i + 1] = zk.real, zk.imag
        return A

    # by its normal equations: the columns are near-orthogonal over the record's many periods
    # (AᵀA ≈ T/2·I), and a profile over the mains frequencies solves ~60 of these per record;
    # rows in blocks of LINE_ROWS (a long record's design is never held whole)
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
    """A line at a mains frequency f₀ [Hz] (and its harmonics) in the measured force that the
    device does not feel. Column: the line s(t) estimated from each record's F
    (:func:`line_in`); parameter ``line_unfelt``, the share of it the device did not feel
    (force −share·s). Plausible as a sensor artefact when |1 − share| ≤
    :data:`LINE_SHARE_TOL`; f₀ profiled within ±1 % of 50 and 60 Hz on the training record."""

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
            ForceSensorLine(float(f))
            for m in MAINS_HZ
            if m < 0.45 * fs
            for f in np.linspace(m * (1 - MAINS_TOLERANCE), m * (1 + MAINS_TOLERANCE), MAINS_POINTS)
        ] or [self]

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


class ForceSensorDrift(ForceEffect):
    """A drift of the force sensor's zero at r [N/s] over each record, that the device does not
    feel. Columns: the time from the record's midpoint, t − t_mid (the ramp alone), and the
    offset's constant: the zero's value at t_mid is a constant force F₀, which the data cannot
    tell from one on the device, and is reported as F₀. Contains the offset (two parameters):
    a constant force alone is never taken for a drift, while a sensor zeroed at each record's
    start (F₀ = r·(t_mid − t₁)) is explained whole. The offset stands in for it unless the ramp
    is significant on validation with the rest of the stack (a slow trend that an unmodelled
    friction or saturation leaves in ε₁ is not a drift)."""

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
