"""Sec. IV.A of the paper: force calibration, eq. (12) (Khadivar et al.).

At the five points x = −30, −15, 0, 15, 30 mm the program sets forces Fs, a force sensor (noise σ)
reads the produced force Fd, and a least-squares line Fs = k·Fd + c gives the calibration gain k
(truth: the twin's ``ForceCalibration`` gain, 1.75).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .. import twin
from .._least_squares import linear_lstsq
from ._config import PaperConfig


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
    coef = linear_lstsq(A, -set_force).coef  # min ‖A·c − F_set‖ (linear_lstsq: Φc ≈ −y)
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
