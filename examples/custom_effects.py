"""Two effects of one's own for ``lionjax.diagnose``, written only against the public API.

    lionjax diagnose train.csv --validate valid.csv \\
        --candidates examples/custom_effects.py:QuadraticDrag,Cogging

or, in Python::

    import lionjax as lj
    from custom_effects import Cogging, QuadraticDrag

    lib = lj.diagnosis.DEFAULT_CANDIDATES + (QuadraticDrag(), Cogging())
    d = lj.diagnose(train, valid, candidates=lib)

A ``ForceEffect`` is a force Σⱼ pⱼ·φⱼ(x, v, F, t) [N] linear in its ``parameters``; the
diagnosis builds its regressor columns and its windowed-simulation term from ``basis`` alone.
See docs/effects.md.
"""

from typing import ClassVar

import jax.numpy as jnp
import numpy as np

import lionjax as lj


class QuadraticDrag(lj.diagnosis.ForceEffect):
    """Fluid drag −c₂·v|v| [N], c₂ > 0 [N·s²/m²]."""

    name: ClassVar[str] = "quadratic_drag"
    parameters: ClassVar[tuple[str, ...]] = ("c2",)
    units: ClassVar[dict[str, str]] = {"c2": "N·s²/m²"}

    def basis(self, x, v, F, t):
        return (-v * jnp.abs(v),)

    def implausible(self, phys, limits):
        if not phys["c2"] > 0:
            return "drag would push along the motion (c₂ ≤ 0)"
        return super().implausible(phys, limits)


class Cogging(lj.diagnosis.ForceEffect):
    """A force periodic in position, A·sin(2πx/p + φ) = A_s·sin(2πx/p) + A_c·cos(2πx/p) [N];
    p [m] is profiled from one cycle over train's range, where it is fitted (less is a slope
    or a bump, which a spring or an offset explains), to 64 over the range both records cover
    (at most 256 over train's), a quarter cycle apart over train's range, then refined."""

    name: ClassVar[str] = "cogging"
    parameters: ClassVar[tuple[str, ...]] = ("A_sin", "A_cos")
    nonlinear: ClassVar[tuple[str, ...]] = ("period",)
    units: ClassVar[dict[str, str]] = {"A_sin": "N", "A_cos": "N", "period": "m"}
    period: float = 1e-3

    def basis(self, x, v, F, t):
        phase = 2 * jnp.pi * x / self.period
        return (jnp.sin(phase), jnp.cos(phase))

    def grid(self, limits):
        span = limits.x_range[1] - limits.x_range[0]  # where both records go
        fit = max(limits.train_range[1] - limits.train_range[0], span)  # where it is fitted
        k_hi = min(64.0 * fit / span, 256.0)  # cycles over train's range (records may barely meet)
        return [Cogging(float(fit / k)) for k in np.arange(1.0, k_hi, 0.25)]
