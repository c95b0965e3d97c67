"""The paper's experiments (Khadivar et al., Sec. IV) reproduced on the device twin (layer 3).

Composes the core (filters, models, Lion's estimator, least squares) with the twin
(:mod:`lionjax.twin`); no plotting, no files. The steps, each a pure function returning a result
Module:

1. :func:`calibrate_force` — Sec. IV.A, eq. (12): at the five points x = −30, −15, 0, 15, 30 mm
   the program sets forces Fs, a force sensor (noise σ) reads the produced force Fd, and a
   least-squares line Fs = k·Fd + c gives the calibration gain k (truth: the twin's
   ``ForceCalibration`` gain, 1.75).
2. :func:`paper_records` — Sec. IV.B: closed-loop records of the twin around the operating points
   x = −20, 0, +20 mm (``CentringPD(x_ref=point)``; the program commands k̂·(PD + excitation) and
   the record logs the *desired* force F = F_cmd/k̂), four sine inputs × three repetitions (noise
   seeds). Each operating point's records stay inside one region of eq. (13).
3. :func:`identify_records` — Lion's law on every record with one :class:`LionSettings` (the
   paper's, or the recommended), batched with ``vmap``; :func:`paper_table` — both settings, all
   regions: the Table 3-like numbers.
4. :func:`verify` — Sec. IV.C: the identified piecewise model (13) against a fresh open-loop twin
   record under F = 3 cos(40t + 400) + 0.5t, 0 ≤ t ≤ 1.6 s; NRMSE.
5. :func:`effect_study` — the first picture of the sim-to-real gap: the same identification with
   one unmodelled twin effect switched on at a realistic size, validated the same way.

:func:`reproduce_paper` runs all of it.

Definitions used in the outputs:

- **var_mm2** (the paper's "var (mm²)", Table 3): the sample variance, over the samples at least
  3·λ₂/λ₃ = 2.25 s after the start of the record, of the equation ("tracking") error
  ε₁ = V₃ + â·V₂ − b̂·Q₁ computed with the *paper's* filter Λ = (s + 4)³ (raw, 1/Λ) on x in mm
  and F in mN, with the record's final estimates (â in 1/s, b̂ in 1/kg). The same definition for
  both settings, so the column is comparable. (Strictly ε₁ has the unit mm·s, since 1/Λ
  integrates three times; the paper writes mm.) It equals 10⁶ × the same variance in SI units.
- **NRMSE** (verification): ‖x̂ − x‖₂ / ‖x − mean(x)‖₂ over the verification record, x the
  logged (quantised) twin position and x̂ the identified model's simulated position from the same
  initial state under the same desired force; 0 is perfect, 1 is no better than the mean
  (fit % = 100·(1 − NRMSE)).
- **summary estimate** per region and settings (``input = repetition = "all"``): the median over
  the region's inputs × repetitions of the per-record final estimates, separately for a and b. The
  median is robust to the one-sine records whose estimates are noisier (a single frequency
  determines two parameters exactly, with no redundancy against noise).
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from . import twin
from ._errors import InputError, raise_if_failed
from ._estimators import AbstractGain, AutoGain, FixedGain, default_bank, lion
from ._filters import FilterBank
from ._models import MassDamper
from ._record import Record

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


# ---------------------------------------------------------------------------------------------
# 1. Force calibration


class Calibration(eqx.Module):
    """Result of :func:`calibrate_force`: points and the fitted line Fs = gain·Fd + intercept.

    Attributes:
        x: position of each reading [m], shape ``(N,)``.
        set_force: Fs, the force set in the program [N], shape ``(N,)``.
        measured_force: Fd, the force-sensor reading [N], shape ``(N,)``.
        gain: fitted slope k (dimensionless), the paper's 1.75.
        intercept: fitted intercept c [N].
        residual_std: standard deviation of the fit residuals [N].
        truth: the twin's calibration gain.
    """

    x: Float[Array, " N"]
    set_force: Float[Array, " N"]
    measured_force: Float[Array, " N"]
    gain: Float[Array, ""]
    intercept: Float[Array, ""]
    residual_std: Float[Array, ""]
    truth: float = eqx.field(static=True)


def _apply_input_effects(plant: twin.Plant, F: Array) -> Array:
    for e in plant.effects:
        if isinstance(e, twin.AbstractInputEffect):
            F = e.apply(F)
    return F


def calibrate_force(config: PaperConfig | None = None, *, key: PRNGKeyArray) -> Calibration:
    """Calibrate the commanded force (paper Sec. IV.A, eq. 12, Fig. 3).

    At each point x in ``config.calibration_points`` the program sets each force Fs in
    ``config.calibration_levels``; the axis is held against a force sensor, which reads the
    produced force Fd = sat(Fs/g) (the twin's input effects) plus Gaussian noise
    σ = ``config.calibration_noise`` (the twin's ``ForceNoise`` sensor). A least-squares line
    Fs = k·Fd + c through all readings gives the gain k the program must apply (Fs = k·Fd).

    Arguments:
        config: sizes (default :class:`PaperConfig`).
        key: PRNG key of the sensor noise.
    """
    config = PaperConfig() if config is None else config
    device = config.plant.with_effects(twin.ForceCalibration(config.calibration_gain))
    xs, fs = np.meshgrid(config.calibration_points, config.calibration_levels, indexing="ij")
    x = jnp.asarray(xs.ravel(), jnp.result_type(float))
    set_force = jnp.asarray(fs.ravel(), x.dtype)
    produced = _apply_input_effects(device, set_force)
    sensor = twin.ForceNoise(config.calibration_noise)
    keys = jax.random.split(key, x.shape[0])
    measured = jax.vmap(lambda xi, F, k: sensor.measure(xi, F, k)[1])(x, produced, keys)
    A = jnp.stack([measured, jnp.ones_like(measured)], axis=-1)
    coef, *_ = jnp.linalg.lstsq(A, set_force)
    res = set_force - A @ coef
    return Calibration(
        x=x,
        set_force=set_force,
        measured_force=measured,
        gain=coef[0],
        intercept=coef[1],
        residual_std=jnp.sqrt(jnp.sum(res**2) / max(x.shape[0] - 2, 1)),
        truth=float(config.calibration_gain),
    )


# ---------------------------------------------------------------------------------------------
# 2. Records


def paper_records(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    calibration_gain: float | Array | None = None,
    effects: Sequence[twin.AbstractPlantEffect] = (),
) -> Record:
    """The identification records of Sec. IV.B from the twin, batch shape ``(R, I, K)``.

    Record (r, i, k): the device twin ``config.device(*effects)`` in closed loop with
    ``CentringPD(k̂·kp, k̂·kd, x_ref = operating point r)``, started at rest at x_ref, excitation
    k̂·input i, noise seed k (the program multiplies every desired force by the calibration gain
    k̂, as eq. 12 says). The record logs x (measured) and the *desired* force F = F_logged/k̂.

    Arguments:
        config: sizes and settings (default :class:`PaperConfig`).
        key: PRNG key (split into one key per record; the same key as :func:`twin_runs`).
        calibration_gain: k̂ used by the program (default: the twin's true gain, i.e. a perfect
            calibration); pass :attr:`Calibration.gain` to carry the calibration's error.
        effects: unmodelled twin effects to switch on (default none).

    Returns:
        a :class:`lionjax.Record` with arrays of shape ``(R, I, K, T)``.
    """
    records, _ = twin_runs(config, key=key, calibration_gain=calibration_gain, effects=[effects])
    return jax.tree.map(lambda z: z[0], records)


def verification_record(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    calibration_gain: float | Array | None = None,
    effects: Sequence[twin.AbstractPlantEffect] = (),
) -> Record:
    """A fresh open-loop record of the device under the paper's verification input (Sec. IV.C).

    The device twin ``config.device(*effects)`` starts at rest at x = 0 and is commanded
    k̂·F(t), F(t) = 3 cos(40t + 400) + 0.5t [N], 0 ≤ t ≤ 1.6 s. The record logs x (measured) and
    the desired force F(t). Same ``key`` as :func:`paper_records`: the record of
    :func:`twin_runs`.
    """
    _, ver = twin_runs(config, key=key, calibration_gain=calibration_gain, effects=[effects])
    return jax.tree.map(lambda z: z[0], ver)


#: Effects that have an exactly neutral value, so devices that differ only in them can share one
#: compiled, batched simulation (see :func:`twin_runs`).
def _neutral(effect):
    if isinstance(effect, twin.ForceOffset):
        return twin.ForceOffset(0.0)
    if isinstance(effect, twin.LinearSpring):
        return twin.LinearSpring(0.0)
    if isinstance(effect, twin.InputDelay):
        return twin.InputDelay(0.0, max_delay=effect.max_delay)
    if isinstance(effect, twin.ForceCalibration):
        return twin.ForceCalibration(1.0)
    if isinstance(effect, twin.HardSaturation):
        return twin.HardSaturation(1e12)
    if isinstance(effect, twin.SoftSaturation):
        return twin.SoftSaturation(1e12)
    if isinstance(effect, twin.PositionDependence):
        return twin.PositionDependence(0.0, 0.0, effect.length, effect.center)
    return None


def _batchable(effects) -> bool:
    return len(effects) == 1 and _neutral(effects[0]) is not None


def _device_batch(config: PaperConfig, effect_sets) -> twin.Plant:
    """Devices with one leading batch axis, one per effect set; all must share a structure.

    Sets of one batchable effect are padded with the neutral versions of the others' effects
    (ForceOffset(0), LinearSpring(0), InputDelay(0), ForceCalibration(1), saturation at 10¹² N,
    PositionDependence(0, 0): each exactly no effect), so all devices have the same PyTree.
    """
    sets = [tuple(e) for e in effect_sets]
    if len(sets) > 1 and all(_batchable(s) for s in sets):
        kinds = []
        for s in sets:
            e = s[0]
            if not any(type(k) is type(e) for k in kinds):
                kinds.append(e)
        max_delay = max(
            [e.max_delay for s in sets for e in s if isinstance(e, twin.InputDelay)] + [0.0]
        )
        devices = []
        for s in sets:
            row = []
            for k in kinds:
                if type(k) is type(s[0]):
                    e = s[0]
                    if isinstance(e, twin.InputDelay):
                        e = twin.InputDelay(e.tau, max_delay=max_delay)
                else:
                    e = _neutral(k)
                    if isinstance(e, twin.InputDelay):
                        e = twin.InputDelay(0.0, max_delay=max_delay)
                row.append(e)
            devices.append(config.device(*row))
    else:
        devices = [config.device(*s) for s in sets]
    structs = {jax.tree.structure(d) for d in devices}
    if len(structs) != 1:
        raise InputError(
            "twin_runs: the effect sets give devices of different structure; pass sets of one "
            "batchable effect each (offset, spring, delay, calibration, saturation, position "
            "dependence), or one set at a time."
        )
    return jax.tree.map(lambda *z: jnp.stack([jnp.asarray(v) for v in z]), *devices)


def twin_runs(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    calibration_gain: float | Array | None = None,
    effects: Sequence[Sequence[twin.AbstractPlantEffect]] = ((),),
) -> tuple[Record, Record]:
    """All twin records of the experiments, for one or more devices, in one batched simulation.

    For each effect set D (a device ``config.device(*set)``): the ``(R, I, K)`` identification
    records of :func:`paper_records` and the open-loop verification record of
    :func:`verification_record` (the latter simulated as one more closed-loop run with
    K_p = K_d = 0, which is exactly open loop). Several sets are simulated together when each is
    one effect with an exactly neutral value (see :func:`_device_batch`); otherwise pass one set.

    Returns:
        ``(records, verification)`` with batch shapes ``(D, R, I, K)`` and ``(D,)``; records are
        ``T = config.n_samples`` long, verification records 1.6 s.
    """
    config = PaperConfig() if config is None else config
    k_hat = config.calibration_gain if calibration_gain is None else calibration_gain
    dtype = jnp.result_type(float)
    k_hat = jnp.asarray(k_hat, dtype)
    devices = _device_batch(config, effects)
    R, I, K = config.shape
    N = R * I * K
    T = config.n_samples
    Tv = int(round(twin.VERIFICATION_DURATION / config.dt)) + 1
    exc = jnp.stack([e.sample(T, config.dt) for e in config.inputs])  # (I, T)
    fv = twin.VerificationInput().sample(Tv, config.dt)
    fv = jnp.concatenate([fv, jnp.zeros((T - Tv,), dtype)])
    xr = jnp.asarray(config.operating_points, dtype)
    x_ref = jnp.concatenate(
        [jnp.broadcast_to(xr[:, None, None], (R, I, K)).reshape(-1), jnp.zeros(1)]
    )
    f_cmd = k_hat * jnp.concatenate(
        [jnp.broadcast_to(exc[None, :, None, :], (R, I, K, T)).reshape(N, T), fv[None]]
    )
    on = jnp.concatenate([jnp.ones(N), jnp.zeros(1)]) * k_hat
    k_rec, k_ver = jax.random.split(key)
    keys = jnp.concatenate([jax.random.split(k_rec, N), k_ver[None]])
    rec = _simulate_batch(devices, x_ref, f_cmd, keys, on * config.kp, on * config.kd, T, config.dt)
    D = rec.x.shape[0]
    records = Record(
        rec.x[:, :N].reshape(D, R, I, K, T),
        (rec.F[:, :N] / k_hat).reshape(D, R, I, K, T),
        jnp.full((D, R, I, K), config.dt, dtype),
        jnp.zeros((D, R, I, K), dtype),
    )
    ver = Record(
        rec.x[:, N, :Tv], rec.F[:, N, :Tv] / k_hat, jnp.full((D,), config.dt, dtype), jnp.zeros(D)
    )
    return records, ver


@eqx.filter_jit
def _simulate_batch(devices, x_ref, f_cmd, keys, kp, kd, T, dt):
    """Twin records for D devices (leading axis of ``devices``) × N runs; T, dt static."""

    def one(device, x_ref, f, key, kp, kd):
        pd = twin.CentringPD(kp, kd, x_ref)
        return twin.simulate(device, f, n_samples=T, dt=dt, x0=x_ref, key=key, closed_loop=pd)

    runs = jax.vmap(one, in_axes=(None, 0, 0, 0, 0, 0))
    return jax.vmap(runs, in_axes=(0, None, None, None, None, None))(
        devices, x_ref, f_cmd, keys, kp, kd
    )


# ---------------------------------------------------------------------------------------------
# 3. Identification


class Identification(eqx.Module):
    """Lion's estimator on a batch of records (result of :func:`identify_records`).

    Attributes:
        settings: the settings' name.
        t: save times [s], shape ``(S,)``.
        theta: θ(t) = (a(t) [1/s], b(t) [1/kg]), shape ``(*batch, S, 2)``.
        a, b: final estimates [1/s], [1/kg], shape ``batch``.
        var_mm2: variance of the paper's equation error ε₁ (module docstring), shape ``batch``.
        eps: the paper's (ε₁, ε₂)(t) with θ(t) [mm·s, mm], shape ``(*batch, S, 2)`` (Fig. 5).
    """

    settings: str = eqx.field(static=True)
    t: Float[Array, " S"]
    theta: Float[Array, "*batch S 2"]
    a: Float[Array, "*batch"]
    b: Float[Array, "*batch"]
    var_mm2: Float[Array, "*batch"]
    eps: Float[Array, "*batch S 2"]


#: Transient excluded from var_mm2: 3·λ₂/λ₃ of the paper's filter [s].
PAPER_TRANSIENT = 3.0 * 48.0 / 64.0


def _paper_regressors(record: Record):
    """Regressors of the paper's definition of ε: Λ = (s+4)³ raw, x in mm, F in mN."""
    rec = Record(record.x * 1e3, record.F * 1e3, record.dt, record.t0)
    return MassDamper().regressors(rec, FilterBank.paper())


@eqx.filter_jit
def _identify_batch(records: Record, settings: LionSettings, save_every: int):
    return jax.vmap(lambda r: _identify_one(r, settings, save_every))(records)


def _identify_one(record: Record, settings: LionSettings, save_every: int):
    model = MassDamper()
    sol = lion(
        model,
        settings.scale(record),
        bank=settings.bank,
        gain=settings.gain,
        save_every=save_every,
        throw=False,
    )
    theta_t = settings.to_si(sol.theta)
    theta_f = settings.to_si(sol.theta_final)
    regs = _paper_regressors(record)
    T = record.n_samples
    idx = np.unique(np.concatenate([np.arange(0, T, save_every), [T - 1]]))
    eps_t = jnp.einsum("sip,sp->si", regs.W[idx], theta_t) + regs.W0[idx]
    eps1 = regs.W[:, 0, :] @ theta_f + regs.W0[:, 0]
    elapsed = record.dt * jnp.arange(T, dtype=record.x.dtype)
    w = (elapsed >= PAPER_TRANSIENT).astype(eps1.dtype)
    n = jnp.sum(w)
    mean = jnp.sum(w * eps1) / n
    var = jnp.sum(w * (eps1 - mean) ** 2) / (n - 1)
    return sol.t, theta_t, theta_f, var, eps_t, sol.result


def identify_records(
    records: Record, settings: LionSettings | None = None, *, save_every: int = 10
) -> Identification:
    """Run Lion's law (one ``MassDamper`` per record) on a batch of records.

    Arguments:
        records: a :class:`lionjax.Record` with any batch shape ``(*batch, T)`` (one region's
            records each; the paper identifies each region from its own experiments).
        settings: :meth:`LionSettings.paper` or :meth:`LionSettings.recommended` (default).
        save_every: keep every n-th sample of θ(t).

    Returns:
        an :class:`Identification` (estimates in SI units whatever the settings' units).

    Raises:
        lionjax.IdentificationError: naming every failed record (e.g. not excited).
    """
    settings = LionSettings.recommended() if settings is None else settings
    if not isinstance(records, Record):
        raise InputError(f"identify_records: records must be a Record, got {type(records)}.")
    if not isinstance(settings, LionSettings):
        raise InputError(
            f"identify_records: settings must be a LionSettings (e.g. LionSettings.paper()), got "
            f"{type(settings).__name__}."
        )
    batch = records.x.shape[:-1]
    T = records.x.shape[-1]
    n = int(np.prod(batch)) if batch else 1
    flat = Record(
        records.x.reshape(n, T),
        records.F.reshape(n, T),
        jnp.broadcast_to(records.dt, batch).reshape(n),
        jnp.broadcast_to(records.t0, batch).reshape(n),
    )
    t, theta_t, theta_f, var, eps_t, result = _identify_batch(flat, settings, save_every)
    raise_if_failed(types.SimpleNamespace(result=result), what=f"Lion ({settings.name} settings)")
    S = theta_t.shape[1]
    return Identification(
        settings=settings.name,
        t=t[0],
        theta=theta_t.reshape(*batch, S, 2),
        a=theta_f[:, 0].reshape(batch),
        b=theta_f[:, 1].reshape(batch),
        var_mm2=var.reshape(batch),
        eps=eps_t.reshape(*batch, S, 2),
    )


class PaperTable(eqx.Module):
    """Table 3 reproduced: per record and summary estimates, for each settings.

    Arrays of shape ``(n_settings, R, I, K)`` unless stated; settings in the order of ``settings``.

    Attributes:
        settings: settings names.
        a, b: final estimates [1/s], [1/kg].
        var_mm2: paper's equation-error variance (module docstring).
        summary_a, summary_b: median over inputs × repetitions, shape ``(n_settings, R)``.
        summary_var_mm2: median var_mm2, shape ``(n_settings, R)``.
        truth_a, truth_b: the twin's a, b per region, shape ``(R,)``.
        operating_points: x_ref per region [m], shape ``(R,)``.
    """

    settings: tuple[str, ...] = eqx.field(static=True)
    a: Float[Array, "S R I K"]
    b: Float[Array, "S R I K"]
    var_mm2: Float[Array, "S R I K"]
    summary_a: Float[Array, "S R"]
    summary_b: Float[Array, "S R"]
    summary_var_mm2: Float[Array, "S R"]
    truth_a: Float[Array, " R"]
    truth_b: Float[Array, " R"]
    operating_points: Float[Array, " R"]

    def rows(self) -> list[dict]:
        """The table as JSON-ready rows (schema of ``table.json``; see the CLI ``reproduce``).

        Each row: ``region`` (1-based), ``operating_point_mm``, ``settings``, ``input``
        (1-based or ``"all"``), ``repetition`` (1-based or ``"all"``), ``a`` [1/s], ``b``
        [1/kg], ``var_mm2``, ``a_err_pct``, ``b_err_pct`` (100·(estimate/truth − 1)),
        ``a_true``, ``b_true``. The ``"all"`` rows hold the summary (median) estimate.
        """
        a, b, v = (np.asarray(z) for z in (self.a, self.b, self.var_mm2))
        sa, sb, sv = (np.asarray(z) for z in (self.summary_a, self.summary_b, self.summary_var_mm2))
        ta, tb = np.asarray(self.truth_a), np.asarray(self.truth_b)
        xp = np.asarray(self.operating_points)
        out = []
        S, R, I, K = a.shape

        def row(s, r, i, k, av, bv, vv):
            return {
                "region": r + 1,
                "operating_point_mm": round(float(xp[r]) * 1e3, 6),
                "settings": self.settings[s],
                "input": i,
                "repetition": k,
                "a": float(av),
                "b": float(bv),
                "var_mm2": float(vv),
                "a_err_pct": float(100 * (av / ta[r] - 1)),
                "b_err_pct": float(100 * (bv / tb[r] - 1)),
                "a_true": float(ta[r]),
                "b_true": float(tb[r]),
            }

        for s in range(S):
            for r in range(R):
                for i in range(I):
                    for k in range(K):
                        out.append(
                            row(s, r, i + 1, k + 1, a[s, r, i, k], b[s, r, i, k], v[s, r, i, k])
                        )
                out.append(row(s, r, "all", "all", sa[s, r], sb[s, r], sv[s, r]))
        return out


def paper_table(
    records: Record,
    config: PaperConfig | None = None,
    settings: Sequence[LionSettings] | None = None,
    *,
    identifications: Sequence[Identification] | None = None,
) -> PaperTable:
    """Table 3 from the ``(R, I, K, T)`` records of :func:`paper_records`.

    Arguments:
        records: the records (batch shape ``(R, I, K)``).
        config: the configuration the records came from (for the truth and operating points).
        settings: the settings to run (default: paper and recommended).
        identifications: already computed :func:`identify_records` results for ``records``, one
            per settings (skips the estimation).
    """
    config = PaperConfig() if config is None else config
    if identifications is None:
        settings = (
            (LionSettings.paper(), LionSettings.recommended()) if settings is None else settings
        )
        identifications = [
            identify_records(records, s, save_every=config.save_every) for s in settings
        ]
    if records.x.ndim != 4:
        raise InputError(
            f"paper_table: records must have batch shape (regions, inputs, repetitions), got "
            f"x of shape {records.x.shape}."
        )
    a = jnp.stack([idn.a for idn in identifications])
    b = jnp.stack([idn.b for idn in identifications])
    v = jnp.stack([idn.var_mm2 for idn in identifications])
    S, R = a.shape[:2]
    med = lambda z: jnp.median(z.reshape(S, R, -1), axis=-1)
    return PaperTable(
        settings=tuple(idn.settings for idn in identifications),
        a=a,
        b=b,
        var_mm2=v,
        summary_a=med(a),
        summary_b=med(b),
        summary_var_mm2=med(v),
        truth_a=jnp.asarray(np.asarray(config.plant.a, float)),
        truth_b=jnp.asarray(np.asarray(config.plant.b, float)),
        operating_points=jnp.asarray(config.operating_points, float),
    )


# ---------------------------------------------------------------------------------------------
# 4. Verification


class Verification(eqx.Module):
    """The identified model against a fresh twin record (paper Sec. IV.C, Fig. 6).

    Attributes:
        t: times [s], shape ``(T,)``.
        force: desired force F(t) [N] (the verification input), shape ``(T,)``.
        x_device: the twin's logged position [m], shape ``(T,)``.
        x_model: the identified piecewise model's simulated position [m], shape ``(T,)``.
        nrmse: ‖x_model − x_device‖ / ‖x_device − mean‖ (module docstring).
        a, b: the identified model's coefficients per region, shape ``(R,)``.
    """

    t: Float[Array, " T"]
    force: Float[Array, " T"]
    x_device: Float[Array, " T"]
    x_model: Float[Array, " T"]
    nrmse: Float[Array, ""]
    a: Float[Array, " R"]
    b: Float[Array, " R"]


def nrmse(x_model: Array, x_measured: Array) -> Array:
    """‖x_model − x_measured‖₂ / ‖x_measured − mean(x_measured)‖₂ (dimensionless)."""
    x_model, x_measured = jnp.asarray(x_model), jnp.asarray(x_measured)
    d = x_measured - jnp.mean(x_measured, axis=-1, keepdims=True)
    return jnp.linalg.norm(x_model - x_measured, axis=-1) / jnp.linalg.norm(d, axis=-1)


def verify(
    a: Float[Array, " R"],
    b: Float[Array, " R"],
    record: Record,
    config: PaperConfig | None = None,
) -> Verification:
    """Validate an identified piecewise model (13) against a verification record (Sec. IV.C).

    The model ``Plant(a, b, config.bounds)`` (noise-free, no effects) is simulated open loop from
    rest at the record's first logged position under the record's (desired) force, and compared
    with the logged position.

    Arguments:
        a, b: identified coefficients per region [1/s], [1/kg], shape ``(R,)``.
        record: a single record, e.g. :func:`verification_record`.
        config: the configuration (bounds).
    """
    config = PaperConfig() if config is None else config
    if record.x.ndim != 1:
        raise InputError(
            f"verify: record must be a single record (x of shape (T,)), got {record.x.shape}."
        )
    model = twin.Plant(a, b, config.bounds)
    x_model = _simulate_model(model, record.F, record.x[0], float(record.dt))
    return Verification(
        t=record.t,
        force=record.F,
        x_device=record.x,
        x_model=x_model,
        nrmse=nrmse(x_model, record.x),
        a=jnp.asarray(a),
        b=jnp.asarray(b),
    )


@eqx.filter_jit
def _simulate_model(model, F, x0, dt):
    return twin.simulate(model, F, dt=dt, x0=x0).extras["x_true"]


# ---------------------------------------------------------------------------------------------
# 5. One unmodelled effect at a time


@dataclasses.dataclass(frozen=True)
class EffectCase:
    """One effect of the gap study: a name, the twin effect and a one-line description."""

    name: str
    effect: twin.AbstractPlantEffect
    description: str


def realistic_effects() -> tuple[EffectCase, ...]:
    """The effects of the gap study, each at a size plausible for a Falcon axis.

    Sizes are judgement, not measurement (the paper reports none): friction and offset a few %
    of the ≈ 4 N verification force, the spring of the leg's cable-tensioning spring, a delay of a
    few 1-kHz loop periods (the paper's force path runs over a 9600-baud serial link), a
    current limit the verification input reaches, a 10 % drift of the calibration, ±15 %/±10 % of
    a and b over ±20 mm, a cable mode at 25 Hz.
    """
    return (
        EffectCase("coulomb_friction", twin.CoulombFriction(0.1), "Coulomb friction F_c = 0.1 N"),
        EffectCase("offset", twin.ForceOffset(0.2), "constant offset/gravity F₀ = 0.2 N"),
        EffectCase("spring", twin.LinearSpring(20.0), "spring k = 20 N/m to x₀ = 0"),
        EffectCase("delay", twin.InputDelay(0.005), "input delay τ = 5 ms"),
        EffectCase("saturation", twin.HardSaturation(2.5), "hard saturation at 2.5 N"),
        EffectCase(
            "calibration_error",
            twin.ForceCalibration(1.10),
            "force-calibration drift: the device gives 1/1.10 of the calibrated force",
        ),
        EffectCase(
            "position_dependent",
            twin.PositionDependence(alpha_a=0.15, alpha_b=0.10, length=0.02),
            "smooth position dependence a·(1 ± 15 %), b·(1 ± 10 %), tanh(x/20 mm)",
        ),
        EffectCase(
            "flexible_mode",
            twin.FlexibleMode(mass=0.05, frequency=25.0, damping_ratio=0.05),
            "flexible mode m₂ = 50 g at 25 Hz, ζ = 0.05",
        ),
    )


class EffectRow(eqx.Module):
    """The identification and validation with one effect switched on (:func:`effect_study`).

    Attributes:
        name, description: the effect.
        a, b: summary estimates per region [1/s], [1/kg], shape ``(R,)``.
        a_err_pct, b_err_pct: 100·(estimate/truth − 1), shape ``(R,)``.
        nrmse: validation NRMSE with the effect; nrmse_baseline: the same without it.
        growth: nrmse / nrmse_baseline.
    """

    name: str = eqx.field(static=True)
    description: str = eqx.field(static=True)
    a: Float[Array, " R"]
    b: Float[Array, " R"]
    a_err_pct: Float[Array, " R"]
    b_err_pct: Float[Array, " R"]
    nrmse: Float[Array, ""]
    nrmse_baseline: Float[Array, ""]
    growth: Float[Array, ""]

    def as_dict(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "a": np.asarray(self.a).tolist(),
            "b": np.asarray(self.b).tolist(),
            "a_err_pct": np.asarray(self.a_err_pct).tolist(),
            "b_err_pct": np.asarray(self.b_err_pct).tolist(),
            "nrmse": float(self.nrmse),
            "nrmse_baseline": float(self.nrmse_baseline),
            "growth": float(self.growth),
        }


def identify_regions(
    records: Record, settings: LionSettings | None = None, *, save_every: int = 10
) -> tuple[Array, Array, Identification]:
    """Per-region summary (a, b): median of Lion's final estimates over each region's records.

    ``records`` has batch shape ``(R, I, K)``; returns ``(a (R,), b (R,), identification)``.
    """
    idn = identify_records(records, settings, save_every=save_every)
    R = records.x.shape[0]
    return (
        jnp.median(idn.a.reshape(R, -1), axis=-1),
        jnp.median(idn.b.reshape(R, -1), axis=-1),
        idn,
    )


def effect_study(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    cases: Sequence[EffectCase] | None = None,
    baseline_nrmse: float | Array | None = None,
    calibration_gain: float | Array | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[EffectRow, ...]:
    """Identify (recommended settings) and validate with one twin effect on at a time.

    For each case: the records of :func:`paper_records` from ``config.device(effect)``, the
    per-region summary model (:func:`identify_regions`), and :func:`verify` on the fresh
    verification record of the same device. The same ``key`` serves every case (and the
    baseline), so the rows differ only by the effect. The baseline — the same pipeline without
    effects — is computed unless ``baseline_nrmse`` is given (:func:`reproduce_paper` passes the
    main table's, obtained with the same key).

    Cases whose effect has an exactly neutral value (offset, spring, delay, calibration,
    saturation, position dependence) are simulated together in one batch; the others one by one.
    """
    config = PaperConfig() if config is None else config
    cases = realistic_effects() if cases is None else tuple(cases)
    settings = LionSettings.recommended()
    say = progress or (lambda s: None)
    truth_a = np.asarray(config.plant.a, float)
    truth_b = np.asarray(config.plant.b, float)

    def evaluate(effect_sets):
        recs, vers = twin_runs(
            config, key=key, calibration_gain=calibration_gain, effects=effect_sets
        )
        out = []
        for d in range(recs.x.shape[0]):
            rec_d = jax.tree.map(lambda z, d=d: z[d], recs)
            ver_d = jax.tree.map(lambda z, d=d: z[d], vers)
            a, b, _ = identify_regions(rec_d, settings, save_every=config.save_every)
            out.append((a, b, verify(a, b, ver_d, config).nrmse))
        return out

    if baseline_nrmse is None:
        say("effects: baseline (no effect)")
        baseline_nrmse = evaluate([()])[0][2]
    batched = [c for c in cases if _batchable((c.effect,))]
    groups = ([batched] if len(batched) > 1 else []) + [
        [c] for c in cases if not (len(batched) > 1 and c in batched)
    ]
    results = {}
    for group in groups:
        say("effects: " + ", ".join(f"{c.name} ({c.description})" for c in group))
        for c, r in zip(group, evaluate([(c.effect,) for c in group]), strict=True):
            results[c.name] = r
    rows = []
    for case in cases:
        a, b, e = results[case.name]
        rows.append(
            EffectRow(
                name=case.name,
                description=case.description,
                a=a,
                b=b,
                a_err_pct=100 * (a / truth_a - 1),
                b_err_pct=100 * (b / truth_b - 1),
                nrmse=e,
                nrmse_baseline=jnp.asarray(baseline_nrmse),
                growth=e / baseline_nrmse,
            )
        )
    return tuple(rows)


# ---------------------------------------------------------------------------------------------
# Everything


class PaperResult(eqx.Module):
    """Everything of the reproduction (:func:`reproduce_paper`).

    Attributes:
        calibration: :class:`Calibration`.
        table: :class:`PaperTable`.
        identifications: one :class:`Identification` per settings (θ(t), ε(t) for the figures),
            batch shape ``(R, I, K)``.
        verifications: one :class:`Verification` per settings (same fresh record).
        effects: the :class:`EffectRow` s (empty if not run).
        config: the :class:`PaperConfig`.
    """

    calibration: Calibration
    table: PaperTable
    identifications: tuple[Identification, ...]
    verifications: tuple[Verification, ...]
    effects: tuple[EffectRow, ...]
    config: PaperConfig


def reproduce_paper(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    effects: bool | Sequence[EffectCase] = True,
    progress: Callable[[str], None] | None = None,
) -> PaperResult:
    """Run the paper's Sec. IV on the twin: calibration, Table 3, verification, effects.

    The identification records use the *fitted* calibration gain (the calibration's error
    propagates into b, as on the device). Both settings see the same records and the same fresh
    verification record. The effect study (``effects=True``: :func:`realistic_effects`) runs the
    recommended settings with the same records' key, so its baseline is the main table's.

    Arguments:
        config: sizes (default :class:`PaperConfig`; :meth:`PaperConfig.quick` for tests).
        key: PRNG key (everything is deterministic given it).
        effects: ``True`` (the realistic effects), ``False`` (none) or a sequence of
            :class:`EffectCase`.
        progress: called with a short message before each step (e.g. print to stderr).
    """
    config = PaperConfig() if config is None else config
    say = progress or (lambda s: None)
    k_cal, k_run = jax.random.split(key)
    say(
        f"calibration: {len(config.calibration_points)} points × "
        f"{len(config.calibration_levels)} set forces"
    )
    cal = calibrate_force(config, key=k_cal)
    R, I, K = config.shape
    say(
        f"twin records: {R} operating points × {I} inputs × {K} repetitions of "
        f"{config.duration:g} s, and the verification record"
    )
    recs, vers = twin_runs(config, key=k_run, calibration_gain=cal.gain)
    recs = jax.tree.map(lambda z: z[0], recs)
    ver = jax.tree.map(lambda z: z[0], vers)
    idns = []
    for s in (LionSettings.paper(), LionSettings.recommended()):
        say(f"identification: Lion's law, {s.name} settings, {R * I * K} records")
        idns.append(identify_records(recs, s, save_every=config.save_every))
    table = paper_table(recs, config, identifications=idns)
    say("verification: identified models vs the fresh twin record (1.6 s)")
    verifications = tuple(
        verify(table.summary_a[i], table.summary_b[i], ver, config)
        for i in range(len(table.settings))
    )
    rows: tuple[EffectRow, ...] = ()
    if effects is not False:
        rows = effect_study(
            config,
            key=k_run,
            cases=None if effects is True else effects,
            baseline_nrmse=verifications[table.settings.index("recommended")].nrmse,
            calibration_gain=cal.gain,
            progress=say,
        )
    return PaperResult(
        calibration=cal,
        table=table,
        identifications=tuple(idns),
        verifications=verifications,
        effects=rows,
        config=config,
    )
