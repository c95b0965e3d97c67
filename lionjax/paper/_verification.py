"""Sec. IV.C of the paper: the identified piecewise model (13) against a fresh open-loop twin
record under F = 3 cos(40t + 400) + 0.5t, 0 ≤ t ≤ 1.6 s.

- **NRMSE** (verification): ‖x̂ − x‖₂ / ‖x − mean(x)‖₂ over the verification record, x the
  logged (quantised) twin position and x̂ the identified model's simulated position from the same
  initial state under the same desired force; 0 is perfect, 1 is no better than the mean
  (fit % = 100·(1 − NRMSE)).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import twin
from .._errors import InputError
from .._record import Record
from ._config import PaperConfig


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
