"""The paper's reproduction: settings (:class:`LionSettings`) and sizes (:class:`PaperConfig`)."""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import twin
from .._errors import InputError
from .._estimators import AbstractGain, AutoGain, FixedGain, default_bank
from .._filters import FilterBank
from .._record import Record

#: Positions of the force calibration (paper Table 1) [m].
CALIBRATION_POINTS = (-0.030, -0.015, 0.0, 0.015, 0.030)
#: Set forces Fs commanded at each calibration point [N] (paper Fig. 3 spans Fs ≈ 0–15 N).
CALIBRATION_LEVELS = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0)
#: The paper's calibration gain, eq. (12): Fs = 1.75·Fd.
PAPER_CALIBRATION_GAIN = 1.75

SETTINGS_NAMES = ("paper", "recommended")


# ---------------------------------------------------------------------------------------------
# Settings and configuration


class LionSettings(eqx.Module):
    """How Lion's law is run on a record: filter, gain, and the units the law sees.

    The law θ̇ = −G Wᵀε is not unit-invariant: G acts on regressors whose size depends on the
    units of x and F. ``position_scale`` and ``force_scale`` multiply x [m] and F [N] before the
    law runs; the estimate is converted back (a is unchanged, b → b·force_scale/position_scale),
    so results are always in SI: a [1/s], b [1/kg].

    Attributes:
        name: label (``"paper"`` or ``"recommended"``).
        bank: the filter Λ.
        gain: the gain strategy (:class:`lionjax.FixedGain` or :class:`lionjax.AutoGain`).
        position_scale: x is given to the law in units of 1/position_scale m (1e3: mm).
        force_scale: F is given to the law in units of 1/force_scale N (1e3: mN).
    """

    name: str = eqx.field(static=True)
    bank: FilterBank
    gain: AbstractGain
    position_scale: float = eqx.field(static=True, default=1.0)
    force_scale: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        for arg in ("position_scale", "force_scale"):
            v = getattr(self, arg)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise InputError(
                    f"LionSettings: {arg} must be a positive finite number, got {v!r}. Use 1e3 to "
                    "run the law in mm (position) or mN (force)."
                )

    @classmethod
    def paper(cls, position_scale: float = 1e3, force_scale: float = 1e3) -> LionSettings:
        """The paper's settings: Λ = (s + 4)³ raw (λ = 12, 48, 64), G = 10⁴·I, θ₀ = 0.

        The paper does not state its units. In SI (x in m, F in N) G = 10⁴ moves b by
        ≈ 0.02 %/s on these records: nothing converges in 10 s (docs/method.md,
        "Lion's law"). With x in mm alone
        (F in N, b then in mm/(s²·N)) a converges but b still does not. With x in mm *and* F in
        mN — which keeps a in 1/s and b in 1/kg as the paper reports them, and is equivalent to
        G = 10¹⁰ in SI — the law converges in ≈ 2 s, as in the paper's Fig. 4. That is the
        default (``position_scale = force_scale = 1e3``).
        """
        return cls(
            "paper",
            FilterBank.paper(),
            FixedGain(1e4),
            position_scale=float(position_scale),
            force_scale=float(force_scale),
        )

    @classmethod
    def recommended(cls, rate: float = 1.0) -> LionSettings:
        """The package defaults: Λ = (s + 4)³ with unit DC gain, ``AutoGain(rate)``, SI units.

        ``AutoGain`` sets G = rate·R⁻¹ (R the record's mean WᵀW), so every parameter direction
        converges with time constant 1/rate whatever the units and scales; with rate = 1/s a
        10-s record forgets θ₀ = 0 by e⁻⁷ after the filter transient, while θ(t) still averages
        the noise over ≈ 1 s.
        """
        return cls("recommended", default_bank(), AutoGain(rate))

    def scale(self, record: Record) -> Record:
        """The record in the law's units (x·position_scale, F·force_scale)."""
        if self.position_scale == 1.0 and self.force_scale == 1.0:
            return record
        return Record(
            record.x * self.position_scale, record.F * self.force_scale, record.dt, record.t0
        )

    def to_si(self, theta: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
        """(a, b) from the law's units back to SI (a [1/s], b [1/kg])."""
        return theta * jnp.array([1.0, self.force_scale / self.position_scale])


def default_sensors() -> tuple[twin.AbstractPlantEffect, ...]:
    """Realistic sensors of the twin: Falcon encoder quantisation (≈ 35 µm), 0.01 N force noise."""
    return (twin.EncoderQuantisation(), twin.ForceNoise(0.01))


@dataclasses.dataclass(frozen=True)
class PaperConfig:
    """Sizes and settings of the paper reproduction (all SI: m, N, s).

    Attributes:
        plant: the twin's base model (default ``FALCON_PAPER``, eq. 13); its a, b are the truth.
        sensors: measurement effects of every record (default :func:`default_sensors`).
        calibration_gain: the device's true force-calibration gain g (twin ``ForceCalibration``):
            the axis receives F_cmd/g. Default 1.75 (eq. 12).
        operating_points: x_ref of the three regions' experiments [m] (−20, 0, +20 mm).
        inputs: the sine inputs (default ``PAPER_SINE_SETS``, four).
        repetitions: records per input and operating point (noise seeds), default 3.
        duration: length of each identification record [s] (default 10).
        dt: sample interval [s] (1 kHz device loop).
        kp, kd: the centring PD [N/m], [N·s/m].
        bounds: region bounds of the identified piecewise model [m] (±10 mm).
        calibration_points, calibration_levels: where [m] and which set forces [N] to calibrate.
        calibration_noise: force-sensor noise σ of the calibration [N] (default 0.05 N).
        save_every: keep every n-th sample of θ(t) for the convergence figures.
    """

    plant: twin.Plant = twin.FALCON_PAPER
    sensors: tuple = dataclasses.field(default_factory=default_sensors)
    calibration_gain: float = PAPER_CALIBRATION_GAIN
    operating_points: tuple[float, ...] = twin.PAPER_OPERATING_POINTS
    inputs: tuple = twin.PAPER_SINE_SETS
    repetitions: int = 3
    duration: float = 10.0
    dt: float = 1e-3
    kp: float = 200.0
    kd: float = 1.0
    bounds: tuple[float, ...] = (-0.010, 0.010)
    calibration_points: tuple[float, ...] = CALIBRATION_POINTS
    calibration_levels: tuple[float, ...] = CALIBRATION_LEVELS
    calibration_noise: float = 0.05
    save_every: int = 10

    def __post_init__(self):
        if not isinstance(self.plant, twin.Plant):
            raise InputError(f"PaperConfig: plant must be a twin.Plant, got {type(self.plant)}.")
        if len(self.operating_points) != self.plant.n_regions:
            raise InputError(
                f"PaperConfig: operating_points needs one point per region of the plant "
                f"({self.plant.n_regions}), got {len(self.operating_points)}."
            )
        if len(self.bounds) != self.plant.n_regions - 1:
            raise InputError(
                f"PaperConfig: bounds needs {self.plant.n_regions - 1} values, got {self.bounds}."
            )
        if not (isinstance(self.repetitions, int) and self.repetitions >= 1):
            raise InputError(f"PaperConfig: repetitions must be an int ≥ 1, got {self.repetitions}")
        if not self.duration > 3.0:
            raise InputError(
                f"PaperConfig: duration must exceed 3 s (the paper filter's transient is 2.25 s), "
                f"got {self.duration}."
            )
        if len(self.inputs) < 1:
            raise InputError("PaperConfig: inputs must hold at least one excitation.")

    @classmethod
    def quick(cls, **changes) -> PaperConfig:
        """Small sizes for tests and notebooks: 8-s records, one repetition (12 records)."""
        return dataclasses.replace(cls(duration=8.0, repetitions=1, save_every=20), **changes)

    @property
    def n_samples(self) -> int:
        return int(round(self.duration / self.dt)) + 1

    @property
    def shape(self) -> tuple[int, int, int]:
        """(regions, inputs, repetitions)."""
        return (len(self.operating_points), len(self.inputs), self.repetitions)

    def device(self, *effects: twin.AbstractPlantEffect) -> twin.Plant:
        """The twin of the device: base model, calibration gain, ``effects``, then the sensors."""
        return self.plant.with_effects(
            twin.ForceCalibration(self.calibration_gain), *effects, *self.sensors
        )
