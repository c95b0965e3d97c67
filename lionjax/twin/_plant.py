"""The device twin: piecewise mass–damper base model (paper eq. 13) plus effects."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._checks import check_finite, check_nonnegative, check_positive, concrete, param
from .._errors import InputError
from ._effects import AbstractPlantEffect


class Plant(eqx.Module):
    """The device twin of one axis: a piecewise mass–damper plus switchable effects.

    Base model (paper eq. 13; docs/method.md, "Model and units"), in region i of R regions split
    by sorted ``bounds``:

        ẍ + aᵢ·ẋ = bᵢ·F_net,   region 1: x < bounds[0], …, region R: x > bounds[R−2],

    with aᵢ = Cᵢ/Mᵢ [1/s] and bᵢ = 1/Mᵢ [1/kg]. ``effects`` add to F_net, change the force on its
    way in, modulate (a, b) or act on the sensors (see :mod:`lionjax.twin._effects`):

        ẍ + a(x)·ẋ = b(x)·(F_applied + F₀ − F_friction(ẋ) − k·(x − x₀) + F_mode),
        F_applied(t) = sat(F_cmd(t − τ) / g).

    The coefficients jump where x crosses a bound; the simulator locates each crossing (it is an
    event), so the trajectory is exact up to the solver's truncation error.

    Attributes:
        a: viscous coefficients aᵢ [1/s], shape ``(R,)``.
        b: input gains bᵢ = 1/Mᵢ [1/kg], shape ``(R,)``, > 0.
        bounds: region bounds [m], shape ``(R − 1,)``, strictly increasing.
        effects: the effects, a tuple of :class:`AbstractPlantEffect`.
    """

    a: Float[ArrayLike, " R"]
    b: Float[ArrayLike, " R"]
    bounds: Float[ArrayLike, " Rm1"]
    effects: tuple[AbstractPlantEffect, ...]

    def __init__(
        self,
        a: ArrayLike,
        b: ArrayLike,
        bounds: ArrayLike = (),
        effects: Sequence[AbstractPlantEffect] = (),
    ):
        self.a = param(np.atleast_1d(a) if concrete(a) is not None else a, "a", "Plant", ndim=1)
        self.b = param(np.atleast_1d(b) if concrete(b) is not None else b, "b", "Plant", ndim=1)
        self.bounds = param(bounds, "bounds", "Plant", ndim=1)
        self.effects = tuple(effects)

    def __check_init__(self):
        R = jnp.shape(self.a)[0]
        if jnp.shape(self.b) != (R,):
            raise InputError(
                f"Plant: arguments 'a' and 'b' need one value per region, got a of shape "
                f"{jnp.shape(self.a)} and b of shape {jnp.shape(self.b)}. Pass equal lengths."
            )
        if jnp.shape(self.bounds) != (R - 1,):
            raise InputError(
                f"Plant: argument 'bounds' must have R − 1 = {R - 1} values for R = {R} regions, "
                f"got shape {jnp.shape(self.bounds)}. Pass one bound between each pair of regions."
            )
        check_finite(self.a, "a", "Plant")
        check_positive(self.b, "b", "Plant", "b = 1/M is an inverse mass.")
        bounds = concrete(self.bounds)
        if bounds is not None:
            check_finite(bounds, "bounds", "Plant")
            bad = np.flatnonzero(np.diff(bounds) <= 0)
            if bad.size:
                i = int(bad[0])
                raise InputError(
                    f"Plant: argument 'bounds' must be strictly increasing, got bounds[{i + 1}] = "
                    f"{bounds[i + 1]!r} <= bounds[{i}] = {bounds[i]!r}. Sort the bounds."
                )
        for i, e in enumerate(self.effects):
            if not isinstance(e, AbstractPlantEffect):
                raise InputError(
                    f"Plant: effects[{i}] must be an AbstractPlantEffect (e.g. CoulombFriction"
                    f"(0.2)), got {type(e).__name__}."
                )

    @property
    def n_regions(self) -> int:
        """Number of regions R."""
        return int(jnp.shape(self.a)[0])

    def with_effects(self, *effects: AbstractPlantEffect) -> Plant:
        """This plant with ``effects`` appended (the base model unchanged)."""
        return Plant(self.a, self.b, self.bounds, self.effects + tuple(effects))

    def region_of(self, x: ArrayLike) -> Int[Array, "..."]:
        """Region index (0-based) of each position: the number of bounds strictly below x."""
        return jnp.sum(jnp.asarray(x)[..., None] > jnp.asarray(self.bounds), axis=-1)


#: The paper's identified Falcon axis, eq. (13): bounds ±10 mm, a = (16.2, 22.0, 37.1) 1/s,
#: b = (2.02, 1.916, 1.289) 1/kg, no effects. Add effects with ``FALCON_PAPER.with_effects(...)``.
FALCON_PAPER = Plant(a=(16.2, 22.0, 37.1), b=(2.02, 1.916, 1.289), bounds=(-0.010, 0.010))


class CentringPD(eqx.Module):
    """A centring PD run by the device loop at the sample rate (closed-loop records).

        F_cmd[k] = K_p·(x_ref − x_m[k]) − K_d·v_m[k] + F_exc[k],   v_m[k] = (x_m[k] − x_m[k−1])/dt,

    with x_m the *measured* (quantised, noisy) position and v_m[0] = 0. F_cmd [N] is held over
    [t_k, t_{k+1}) and is what the record logs, as on a real device; the axis receives it through
    the plant's input effects. With the paper's plant, K_p = 200 N/m, K_d = 1 N·s/m give a closed
    loop of about 3 Hz, damping ratio 0.45–0.8 in the three regions.

    Attributes:
        kp: K_p [N/m], shape ``()``, ≥ 0.
        kd: K_d [N·s/m], shape ``()``, ≥ 0.
        x_ref: x_ref [m], shape ``()``: the operating point.
    """

    kp: Float[ArrayLike, ""]
    kd: Float[ArrayLike, ""]
    x_ref: Float[ArrayLike, ""]

    def __init__(self, kp: ArrayLike = 200.0, kd: ArrayLike = 1.0, x_ref: ArrayLike = 0.0):
        self.kp = param(kp, "kp", "CentringPD")
        self.kd = param(kd, "kd", "CentringPD")
        self.x_ref = param(x_ref, "x_ref", "CentringPD")

    def __check_init__(self):
        check_nonnegative(self.kp, "kp", "CentringPD", "Pass kp >= 0 [N/m].")
        check_nonnegative(self.kd, "kd", "CentringPD", "Pass kd >= 0 [N·s/m].")
        check_finite(self.x_ref, "x_ref", "CentringPD")

    def command(self, x_meas, v_meas, f_exc):
        """F_cmd [N] from the measured position [m], velocity [m/s] and excitation [N]."""
        return self.kp * (self.x_ref - x_meas) - self.kd * v_meas + f_exc
