"""Sec. IV.B of the paper: the closed-loop records of the twin.

Around the operating points x = −20, 0, +20 mm (``CentringPD(x_ref=point)``; the program
commands k̂·(PD + excitation) and the record logs the *desired* force F = F_cmd/k̂), four sine
inputs × three repetitions (noise seeds). Each operating point's records stay inside one region
of eq. (13).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, PRNGKeyArray

from .. import twin
from .._errors import InputError
from .._record import Record
from ._config import PaperConfig


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
