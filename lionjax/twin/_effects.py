"""Effects of the device twin: switchable, parameterised, each with its equation
(docs/method.md, "Effects").

Sign convention of the augmented axis model (fixed; effects act on the force, in N):

    ẍ + a(x)·ẋ = b(x)·(F_applied + F₀ − F_friction(ẋ) − k·(x − x₀) + F_mode),
    F_applied(t) = sat(F_cmd(t − τ) / g),

with F_cmd the commanded (and logged) force. Every effect is an :class:`AbstractPlantEffect`;
its role is given by which abstract base it derives from:

* :class:`AbstractInputEffect` — memoryless map of the commanded force (calibration, saturation);
  :class:`InputDelay` — a pure delay of the commanded force;
* :class:`AbstractForceEffect` — a force that is smooth in the state, possibly with internal states
  of its own (offset, spring, smooth Coulomb friction, flexible mode);
* :class:`AbstractFriction` — friction that is *discontinuous* at ẋ = 0 (exact Coulomb with
  optional Stribeck, asymmetric friction). The simulator treats ẋ = 0 as an event: it locates the
  instant the velocity reaches zero and then either reverses, or sticks when the net other force
  lies inside the break-away band (true stick–slip);
* :class:`AbstractCoefficientEffect` — smooth modulation of a and b with position;
* :class:`AbstractMeasurement` — what the sensors make of the true signals (encoder quantisation,
  position noise, force-sensor noise), applied to each logged sample in the order given.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray, Scalar

from .._checks import check, check_finite, check_nonnegative, check_positive, concrete, param
from .._errors import InputError

#: Counts per motor revolution of the Falcon encoder: 320 lines, 4-state (quadrature) decoding.
FALCON_COUNTS_PER_REV = 4 * 320
#: Diameter of the Falcon capstan drum [m].
FALCON_DRUM_DIAMETER = 14.25e-3
#: Cable (capstan) gain between motor and main leg, leg rotation = motor rotation / 7.62.
FALCON_CABLE_GAIN = 7.62
#: End-effector position resolution of one encoder count [m] (derivation in
#: :class:`EncoderQuantisation`): π·14.25 mm / 1280 ≈ 34.97 µm.
FALCON_ENCODER_RESOLUTION = math.pi * FALCON_DRUM_DIAMETER / FALCON_COUNTS_PER_REV


class AbstractPlantEffect(eqx.Module):
    """Base of every effect of the device twin (see the module docstring for the roles).

    Effects are PyTrees: their parameters are array leaves, so a batch of twins that differ in an
    effect's magnitude is built with ``eqx.filter_vmap`` and simulated with no new code. An effect
    with magnitude 0 is switched off; leaving it out of the plant removes its cost as well.
    """


# --------------------------------------------------------------------------------------------
# Input side: the commanded force becomes the applied force.


class AbstractInputEffect(AbstractPlantEffect):
    """A memoryless map of the force on its way from the command to the axis."""

    @abc.abstractmethod
    def apply(self, F: Float[Array, "..."]) -> Float[Array, "..."]:
        """The force after this effect [N], same shape as ``F`` [N]."""


class ForceCalibration(AbstractInputEffect):
    """Force-calibration gain g: the device produces F_produced = F_cmd / g [N].

    The paper's calibration (eq. 12) reads Fs = 1.75·Fd: to obtain a desired force Fd one must set
    (command) Fs = 1.75·Fd. So a device that has not been calibrated produces 1/1.75 of what it is
    commanded; the logged (commanded) force is g times the force that acts on the axis and an
    identification on logged force returns b/g instead of b. Default ``gain = 1.75``.

    Attributes:
        gain: g, dimensionless, shape ``()``, > 0.
    """

    gain: Float[ArrayLike, ""]

    def __init__(self, gain: ArrayLike = 1.75):
        self.gain = param(gain, "gain", "ForceCalibration")

    def __check_init__(self):
        check_positive(self.gain, "gain", "ForceCalibration", "The paper's value is 1.75.")

    def apply(self, F):
        return F / self.gain


class HardSaturation(AbstractInputEffect):
    """Actuator saturation by a hard clip: F_applied = clip(F, −F_max, F_max) [N].

    The commanded force is held constant between samples (zero-order hold), so the clip only
    changes the held levels: the simulated trajectory stays exact.

    Attributes:
        f_max: F_max [N], shape ``()``, > 0.
    """

    f_max: Float[ArrayLike, ""]

    def __init__(self, f_max: ArrayLike):
        self.f_max = param(f_max, "f_max", "HardSaturation")

    def __check_init__(self):
        check_positive(self.f_max, "f_max", "HardSaturation", "The Falcon peaks near 9 N.")

    def apply(self, F):
        return jnp.clip(F, -self.f_max, self.f_max)


class SoftSaturation(AbstractInputEffect):
    """Actuator saturation, smooth: F_applied = F_max·tanh(F / F_max) [N].

    Slope 1 at F = 0, limits ±F_max; at F = F_max it already loses 24 % (tanh 1 = 0.76).

    Attributes:
        f_max: F_max [N], shape ``()``, > 0.
    """

    f_max: Float[ArrayLike, ""]

    def __init__(self, f_max: ArrayLike):
        self.f_max = param(f_max, "f_max", "SoftSaturation")

    def __check_init__(self):
        check_positive(self.f_max, "f_max", "SoftSaturation", "The Falcon peaks near 9 N.")

    def apply(self, F):
        return self.f_max * jnp.tanh(F / self.f_max)


class InputDelay(AbstractPlantEffect):
    """Input (transport) delay: the axis receives F_cmd(t − τ) [N], τ in s.

    τ need not be a multiple of the sample interval dt: with τ = (n + φ)·dt, 0 ≤ φ < 1, the held
    command F_cmd[k] acts on [t_k + τ, t_{k+1} + τ), so each sample interval is integrated in two
    pieces split at t_k + φ·dt. Before the record starts the command is 0 N.

    Attributes:
        tau: τ [s], shape ``()``, ≥ 0.
        max_delay: static upper bound on τ [s] that sizes the command buffer (default: τ itself
            when τ is concrete; pass it when building delays under ``vmap``). Simulating with
            τ > max_delay raises an error.
    """

    tau: Float[ArrayLike, ""]
    max_delay: float = eqx.field(static=True)

    def __init__(self, tau: ArrayLike, max_delay: float | None = None):
        self.tau = param(tau, "tau", "InputDelay")
        if max_delay is None:
            c = concrete(self.tau)
            if c is None:
                raise InputError(
                    "InputDelay: argument 'max_delay' is required when 'tau' is traced (built "
                    "under vmap/jit), got None. Pass max_delay=<largest tau in s> so the command "
                    "buffer has a static size."
                )
            max_delay = float(c)
        self.max_delay = float(max_delay)

    def __check_init__(self):
        check_nonnegative(self.tau, "tau", "InputDelay", "A delay cannot be negative.")
        if not (math.isfinite(self.max_delay) and self.max_delay >= 0):
            raise InputError(
                f"InputDelay: argument 'max_delay' must be a finite float >= 0, got "
                f"{self.max_delay!r}."
            )
        check(
            self.tau,
            "tau",
            "InputDelay",
            lambda a: a <= self.max_delay * (1 + 1e-12),
            f"<= max_delay = {self.max_delay}",
            "Raise max_delay.",
        )


# --------------------------------------------------------------------------------------------
# Forces that are smooth in the state.


class AbstractForceEffect(AbstractPlantEffect):
    """A force on the axis that is smooth in (x, ẋ, z), z being the effect's own states.

    Attributes:
        n_states: number of internal states z of the effect (class constant, default 0).
    """

    n_states: ClassVar[int] = 0

    @abc.abstractmethod
    def force(self, x: Scalar, v: Scalar, z: Float[Array, " n_states"]) -> Scalar:
        """Force on the axis [N] at position x [m], velocity v [m/s], internal states z."""

    def init_states(self, x0: Scalar, v0: Scalar) -> Float[Array, " n_states"]:
        """Internal states at the start of a record (effects with ``n_states > 0`` override)."""
        return jnp.zeros((0,), jnp.result_type(x0))

    def states_rhs(self, x: Scalar, v: Scalar, z: Float[Array, " n_states"]):
        """Time derivative of the internal states z."""
        return jnp.zeros((0,), jnp.result_type(x))


class ForceOffset(AbstractForceEffect):
    """Constant offset or gravity force: adds F₀ [N] to the applied force.

    ẍ + aẋ = b·(F + F₀). The EMPS offset of −3.1648 N (τ = … + offset) is F₀ = +3.1648 N.

    Attributes:
        f0: F₀ [N], shape ``()``.
    """

    f0: Float[ArrayLike, ""]

    def __init__(self, f0: ArrayLike):
        self.f0 = param(f0, "f0", "ForceOffset")

    def __check_init__(self):
        check_finite(self.f0, "f0", "ForceOffset")

    def force(self, x, v, z):
        return jnp.asarray(self.f0, jnp.result_type(x)) + 0 * x


class LinearSpring(AbstractForceEffect):
    """Spring to an equilibrium: adds −k·(x − x₀) [N].

    Attributes:
        k: stiffness k [N/m], shape ``()``, ≥ 0.
        x0: equilibrium position x₀ [m], shape ``()`` (default 0).
    """

    k: Float[ArrayLike, ""]
    x0: Float[ArrayLike, ""]

    def __init__(self, k: ArrayLike, x0: ArrayLike = 0.0):
        self.k = param(k, "k", "LinearSpring")
        self.x0 = param(x0, "x0", "LinearSpring")

    def __check_init__(self):
        check_nonnegative(self.k, "k", "LinearSpring")
        check_finite(self.x0, "x0", "LinearSpring")

    def force(self, x, v, z):
        return -self.k * (x - self.x0)


class SmoothCoulombFriction(AbstractForceEffect):
    """Coulomb friction with a smoothed sign: adds −F_c·tanh(ẋ / ε) [N].

    An approximation of :class:`CoulombFriction` without events and without sticking (the axis
    creeps at |ẋ| ≲ ε under forces below F_c). Use the exact class to simulate a device; this
    one exists to study the smoothing the identification side uses. Its deviation from the exact
    model is tested (tests/test_plant.py). The smoothed sign is stiff (slope b·F_c/ε 1/s): keep
    ``n_substeps`` ≳ dt·b·F_c/(2ε) in :func:`simulate` (e.g. 8 for F_c = 0.4 N, ε = 1e-4 m/s).

    Attributes:
        fc: F_c [N], shape ``()``, ≥ 0.
        eps: smoothing velocity ε [m/s], shape ``()``, > 0.
    """

    fc: Float[ArrayLike, ""]
    eps: Float[ArrayLike, ""]

    def __init__(self, fc: ArrayLike, eps: ArrayLike = 1e-3):
        self.fc = param(fc, "fc", "SmoothCoulombFriction")
        self.eps = param(eps, "eps", "SmoothCoulombFriction")

    def __check_init__(self):
        check_nonnegative(self.fc, "fc", "SmoothCoulombFriction")
        check_positive(self.eps, "eps", "SmoothCoulombFriction", "Try eps = 1e-3 m/s.")

    def force(self, x, v, z):
        return -self.fc * jnp.tanh(v / self.eps)


class FlexibleMode(AbstractForceEffect):
    """An unmodelled flexible mode: a second mass m₂ coupled to the axis by a spring and damper.

        F_mode = k₂·(x₂ − x) + c₂·(ẋ₂ − ẋ)  [N]  (force of m₂ on the axis),
        m₂·ẍ₂ = −F_mode,   k₂ = m₂·ω², c₂ = 2ζ·m₂·ω, ω = 2π·f.

    The logged position is the axis x (collocated with the actuator), so the mode shows as an
    anti-resonance/resonance pair near f — an effect outside the candidate library of the
    diagnosis. Internal states z = (x₂ [m], ẋ₂ [m/s]), starting at (x(0), ẋ(0)).

    Attributes:
        mass: m₂ [kg], shape ``()``, > 0.
        frequency: f [Hz] (coupling frequency of m₂ on a fixed axis), shape ``()``, > 0.
        damping_ratio: ζ, shape ``()``, ≥ 0.
    """

    n_states: ClassVar[int] = 2
    mass: Float[ArrayLike, ""]
    frequency: Float[ArrayLike, ""]
    damping_ratio: Float[ArrayLike, ""]

    def __init__(self, mass: ArrayLike, frequency: ArrayLike, damping_ratio: ArrayLike = 0.05):
        self.mass = param(mass, "mass", "FlexibleMode")
        self.frequency = param(frequency, "frequency", "FlexibleMode")
        self.damping_ratio = param(damping_ratio, "damping_ratio", "FlexibleMode")

    def __check_init__(self):
        check_positive(self.mass, "mass", "FlexibleMode")
        check_positive(self.frequency, "frequency", "FlexibleMode")
        check_nonnegative(self.damping_ratio, "damping_ratio", "FlexibleMode")

    def _kc(self):
        w = 2 * jnp.pi * self.frequency
        return self.mass * w**2, 2 * self.damping_ratio * self.mass * w

    def init_states(self, x0, v0):
        return jnp.stack([x0, v0])

    def force(self, x, v, z):
        k2, c2 = self._kc()
        return k2 * (z[0] - x) + c2 * (z[1] - v)

    def states_rhs(self, x, v, z):
        return jnp.stack([z[1], -self.force(x, v, z) / self.mass])


# --------------------------------------------------------------------------------------------
# Friction discontinuous at zero velocity (handled by events in the simulator).


class AbstractFriction(AbstractPlantEffect):
    """Friction with a jump at ẋ = 0, simulated exactly (events, true stick–slip).

    While moving in direction s = sgn ẋ ∈ {−1, +1} the friction force is ``kinetic(s, v)``, a
    smooth function of v. At ẋ = 0 the axis sticks while the net other force F_o (applied +
    smooth effects) satisfies −breakaway(−1) ≤ F_o ≤ breakaway(+1), and breaks away in the
    direction of F_o once it leaves that band. Several frictions add up.
    """

    @abc.abstractmethod
    def kinetic(self, s: Scalar, v: Scalar) -> Scalar:
        """Friction force [N] while moving in direction ``s`` (±1) at velocity v [m/s]."""

    @abc.abstractmethod
    def breakaway(self, s: Scalar) -> Scalar:
        """Static friction level [N] (≥ 0) to overcome to start moving in direction ``s``."""


class CoulombFriction(AbstractFriction):
    """Coulomb friction with optional Stribeck effect; exact sign, true stick–slip.

        F_friction = −sgn(ẋ)·[F_c + (F_s − F_c)·exp(−(ẋ/v_s)²)]  [N]   for ẋ ≠ 0,
        stick at ẋ = 0 while |F_other| ≤ F_s.

    With F_s = F_c (default) this is plain Coulomb friction F_c·sgn ẋ; F_s > F_c gives the
    Stribeck dip and stick–slip.

    Attributes:
        fc: Coulomb (kinetic) level F_c [N], shape ``()``, ≥ 0.
        fs: static level F_s [N], shape ``()``, ≥ F_c (default F_c).
        vs: Stribeck velocity v_s [m/s], shape ``()``, > 0 (default 1 mm/s).
    """

    fc: Float[ArrayLike, ""]
    fs: Float[ArrayLike, ""]
    vs: Float[ArrayLike, ""]

    def __init__(self, fc: ArrayLike, fs: ArrayLike | None = None, vs: ArrayLike = 1e-3):
        self.fc = param(fc, "fc", "CoulombFriction")
        self.fs = self.fc if fs is None else param(fs, "fs", "CoulombFriction")
        self.vs = param(vs, "vs", "CoulombFriction")

    def __check_init__(self):
        check_nonnegative(self.fc, "fc", "CoulombFriction")
        check_positive(self.vs, "vs", "CoulombFriction", "Try vs = 1e-3 m/s.")
        fc, fs = concrete(self.fc), concrete(self.fs)
        if fc is not None and fs is not None and not np.all(fs >= fc):
            raise InputError(
                f"CoulombFriction: argument 'fs' (static level) must be >= fc = {fc.tolist()}, "
                f"got {fs.tolist()}. Static friction is at least the kinetic level; omit fs for "
                "plain Coulomb friction."
            )

    def kinetic(self, s, v):
        level = self.fc + (self.fs - self.fc) * jnp.exp(-((v / self.vs) ** 2))
        return -s * level

    def breakaway(self, s):
        return jnp.asarray(self.fs) + 0 * s


class AsymmetricFriction(AbstractFriction):
    """Direction-dependent Coulomb and viscous friction; exact sign, true stick–slip.

        F_friction = −(F_c⁺ + c⁺·ẋ)  for ẋ > 0,    F_friction = F_c⁻ − c⁻·ẋ  for ẋ < 0   [N],

    on top of the base viscous term a·ẋ. At ẋ = 0 the axis sticks while
    −F_c⁻ ≤ F_other ≤ F_c⁺.

    Attributes:
        fc_pos, fc_neg: Coulomb levels F_c⁺, F_c⁻ [N], shape ``()``, ≥ 0.
        c_pos, c_neg: extra viscous coefficients c⁺, c⁻ [N·s/m], shape ``()`` (default 0).
    """

    fc_pos: Float[ArrayLike, ""]
    fc_neg: Float[ArrayLike, ""]
    c_pos: Float[ArrayLike, ""]
    c_neg: Float[ArrayLike, ""]

    def __init__(
        self,
        fc_pos: ArrayLike,
        fc_neg: ArrayLike,
        c_pos: ArrayLike = 0.0,
        c_neg: ArrayLike = 0.0,
    ):
        self.fc_pos = param(fc_pos, "fc_pos", "AsymmetricFriction")
        self.fc_neg = param(fc_neg, "fc_neg", "AsymmetricFriction")
        self.c_pos = param(c_pos, "c_pos", "AsymmetricFriction")
        self.c_neg = param(c_neg, "c_neg", "AsymmetricFriction")

    def __check_init__(self):
        check_nonnegative(self.fc_pos, "fc_pos", "AsymmetricFriction")
        check_nonnegative(self.fc_neg, "fc_neg", "AsymmetricFriction")
        check_finite(self.c_pos, "c_pos", "AsymmetricFriction")
        check_finite(self.c_neg, "c_neg", "AsymmetricFriction")

    def kinetic(self, s, v):
        return jnp.where(s > 0, -(self.fc_pos + self.c_pos * v), self.fc_neg - self.c_neg * v)

    def breakaway(self, s):
        return jnp.where(s > 0, self.fc_pos, self.fc_neg)


# --------------------------------------------------------------------------------------------
# Smooth position dependence of the coefficients.


class AbstractCoefficientEffect(AbstractPlantEffect):
    """Modulates the model coefficients a, b smoothly with position."""

    @abc.abstractmethod
    def modulate(self, x: Scalar, a: Scalar, b: Scalar) -> tuple[Scalar, Scalar]:
        """The coefficients (a [1/s], b [1/kg]) at position x [m], given the base values."""


class PositionDependence(AbstractCoefficientEffect):
    """Smooth position dependence of the coefficients.

        a(x) = a·(1 + α_a·tanh((x − x_c)/L)),   b(x) = b·(1 + α_b·tanh((x − x_c)/L)),

    with a, b the base model's coefficients (use a one-region base for a purely smooth model).

    Attributes:
        alpha_a, alpha_b: relative modulation depths, shape ``()``, |α| < 1 (keeps a, b > 0).
        length: L [m], shape ``()``, > 0 (default 20 mm).
        center: x_c [m], shape ``()`` (default 0).
    """

    alpha_a: Float[ArrayLike, ""]
    alpha_b: Float[ArrayLike, ""]
    length: Float[ArrayLike, ""]
    center: Float[ArrayLike, ""]

    def __init__(
        self,
        alpha_a: ArrayLike = 0.0,
        alpha_b: ArrayLike = 0.0,
        length: ArrayLike = 0.02,
        center: ArrayLike = 0.0,
    ):
        self.alpha_a = param(alpha_a, "alpha_a", "PositionDependence")
        self.alpha_b = param(alpha_b, "alpha_b", "PositionDependence")
        self.length = param(length, "length", "PositionDependence")
        self.center = param(center, "center", "PositionDependence")

    def __check_init__(self):
        for name in ("alpha_a", "alpha_b"):
            check(
                getattr(self, name),
                name,
                "PositionDependence",
                lambda a: np.abs(a) < 1,
                "in (-1, 1)",
                "|alpha| >= 1 would make a coefficient change sign.",
            )
        check_positive(self.length, "length", "PositionDependence")
        check_finite(self.center, "center", "PositionDependence")

    def modulate(self, x, a, b):
        w = jnp.tanh((x - self.center) / self.length)
        return a * (1 + self.alpha_a * w), b * (1 + self.alpha_b * w)


# --------------------------------------------------------------------------------------------
# Sensors.


class AbstractMeasurement(AbstractPlantEffect):
    """What a sensor makes of the true signals at one sample (applied in the order given).

    Attributes:
        random: class constant, whether :meth:`measure` draws from its PRNG key.
    """

    random: ClassVar[bool] = False

    @abc.abstractmethod
    def measure(self, x: Scalar, F: Scalar, key: PRNGKeyArray) -> tuple[Scalar, Scalar]:
        """(logged position [m], logged force [N]) from the (true position, commanded force)."""


class EncoderQuantisation(AbstractMeasurement):
    """Quantisation of the logged position by an incremental encoder: x_q = q·round(x / q).

    Falcon default q (``FALCON_ENCODER_RESOLUTION`` ≈ 34.97 µm). Derivation: the encoder has 320
    lines, read 4-state (quadrature), so 4·320 = 1280 counts per motor revolution. The motor
    drives a capstan drum of diameter d = 14.25 mm, so one count pulls π·d/1280 = 34.97 µm of
    cable. The cable gain 7.62:1 means the leg turns 1/7.62 of the motor angle, i.e. the cable
    wraps the leg at r = 7.62·d/2 = 54.3 mm. Assumption: near the workspace centre the
    end-effector moves along the axis like the point of the leg at the cable radius (unit lever
    ratio of the parallel linkage), so Δx = r·Δθ_leg = (7.62·d/2)·(2π/1280)/7.62 = π·d/1280. The
    gain cancels; a different lever ratio ρ would scale q by ρ. (Novint specifies a resolution
    better than 400 dpi = 63.5 µm, consistent.) Rounding (not flooring) keeps the error zero-mean.

    Attributes:
        resolution: q [m], shape ``()``, > 0.
    """

    resolution: Float[ArrayLike, ""]

    def __init__(self, resolution: ArrayLike = FALCON_ENCODER_RESOLUTION):
        self.resolution = param(resolution, "resolution", "EncoderQuantisation")

    def __check_init__(self):
        check_positive(self.resolution, "resolution", "EncoderQuantisation")

    def measure(self, x, F, key):
        return self.resolution * jnp.round(x / self.resolution), F


class PositionNoise(AbstractMeasurement):
    """Additive white Gaussian noise on the logged position: x_m = x + σ_x·n, n ~ N(0, 1).

    Attributes:
        std: σ_x [m], shape ``()``, ≥ 0.
    """

    random: ClassVar[bool] = True
    std: Float[ArrayLike, ""]

    def __init__(self, std: ArrayLike):
        self.std = param(std, "std", "PositionNoise")

    def __check_init__(self):
        check_nonnegative(self.std, "std", "PositionNoise")

    def measure(self, x, F, key):
        return x + self.std * jax.random.normal(key, (), jnp.result_type(x)), F


class ForceNoise(AbstractMeasurement):
    """Additive white Gaussian force-sensor noise on the logged force: F_m = F + σ_F·n.

    Attributes:
        std: σ_F [N], shape ``()``, ≥ 0.
    """

    random: ClassVar[bool] = True
    std: Float[ArrayLike, ""]

    def __init__(self, std: ArrayLike):
        self.std = param(std, "std", "ForceNoise")

    def __check_init__(self):
        check_nonnegative(self.std, "std", "ForceNoise")

    def measure(self, x, F, key):
        return x, F + self.std * jax.random.normal(key, (), jnp.result_type(F))
