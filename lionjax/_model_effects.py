"""Candidate *regressor* effects for identification and diagnosis (layer 1;
docs/method.md, "Effects").

Sign convention of the augmented model (fixed; effects act on the force, in N):

    ẍ + aẋ = b·(F_applied + F₀ − F_c·sgn(ẋ) − k·(x − x₀)),   F_applied = sat_Fmax(F(t − τ)).

Every effect here is linear in its parameters and adds :class:`~lionjax.extend.Column` s to the
model through :class:`~lionjax.Augmented`; its parameters are b times the physical ones, and
:meth:`physical` divides by b (on a ``Piecewise`` base, one copy per region: bᵢ times the physical
ones, names suffixed ``_i``; ``PolynomialPosition`` excepted, it modulates a and b). With
ε₁ = V₃ + aV₂ − bQ₁ + … (docs/method.md, "Equation errors"), the columns are

- offset (:class:`Offset`): −(1/Λ)[1], parameter b·F₀;
- Coulomb (:class:`Coulomb`): +(1/Λ)[sgñ v̂], parameter b·F_c;
- Coulomb with Dahl's pre-sliding (:class:`PreslidingFriction`): +(1/Λ)[ζ], ζ Dahl's state of
  v̂'s displacement over the pre-sliding distance z, parameter b·F_c;
- spring (:class:`Spring`): +(1/Λ)[x], parameter b·k; with an equilibrium add the offset
  column, whose parameter is then b·(F₀ + k·x₀);
- position (:class:`PolynomialPosition`, degree K ≤ 3, default 1):
  +(s/Λ)[ℓξᵏ⁺¹/(k+1)], −(1/Λ)[ξᵏ·F], ξ = (x − x_c)/ℓ, parameters aₖ, bₖ of
  a(x) = a + Σ aₖξᵏ, b(x) = b + Σ bₖξᵏ (exact: ξᵏẋ = d/dt(ℓξᵏ⁺¹/(k+1)), the §3 construction);
- localized position (:class:`LocalizedPosition`, a step and a bump at x₀ of width w):
  +(s/Λ)[w·log cosh ξ], −(1/Λ)[tanh ξ·F], +(s/Λ)[w·tanh ξ], −(1/Λ)[sech²ξ·F], ξ = (x − x₀)/w.

sgñ v̂ = tanh(v̂/v_ε) is a smoothed sign of a zero-phase derivative-filter velocity v̂: x is
passed forward and backward through the low-pass λₙ/Λ_v(s) = (ω/(s + ω))³ and differentiated by
central differences. Delay and saturation are not linear in their parameter; the diagnosis
profiles them (:mod:`lionjax.diagnosis`).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._checks import concrete
from ._errors import InputError
from ._filters import FilterBank, Hold
from ._models import AbstractEffect, Column, Offset
from ._record import Record

__all__ = [
    "Coulomb",
    "LocalizedPosition",
    "Offset",
    "PolynomialPosition",
    "PreslidingFriction",
    "Spring",
    "dahl_states",
    "zero_phase_lowpass",
    "zero_phase_velocity",
]


@eqx.filter_jit
def zero_phase_lowpass(
    x: Float[Array, " T"], dt: ArrayLike, omega: ArrayLike
) -> Float[Array, " T"]:
    """x low-passed forward and backward by (ω/(s + ω))³ (unit DC gain, first-order hold):
    the zero-phase smoother |ω²/(s² + ω²)|³ [same unit as x]; ω in rad/s."""
    bank = FilterBank.from_poles(-jnp.full((3,), omega), unit_dc_gain=True)
    fwd = bank(x, dt, "foh")[:, 0]
    return bank(fwd[::-1], dt, "foh")[::-1, 0]


@eqx.filter_jit
def zero_phase_velocity(
    x: Float[Array, " T"], dt: ArrayLike, omega: ArrayLike
) -> Float[Array, " T"]:
    """Velocity [m/s] of x [m] by a zero-phase derivative filter.

    x is smoothed by :func:`zero_phase_lowpass` (forward and backward through (ω/(s + ω))³),
    then differentiated by central differences: no phase lag, so reversals are located without
    delay.

    Arguments:
        x: positions, shape ``(T,)`` [m]; dt: sample interval [s]; omega: ω [rad/s] > 0.
    """
    return jnp.gradient(zero_phase_lowpass(x, dt, omega), dt)


class Coulomb(AbstractEffect):
    """Coulomb friction F_c·sgn(ẋ) [N]: column +(1/Λ)[tanh(v̂/v_ε)], parameter b·F_c.

    Attributes:
        omega: bandwidth ω [rad/s] of the zero-phase velocity filter (:func:`zero_phase_velocity`).
        v_eps: velocity scale v_ε [m/s] of the smoothed sign.
    """

    omega: Float[Array, ""]
    v_eps: Float[Array, ""]

    def __init__(self, omega: ArrayLike, v_eps: ArrayLike):
        self.omega = jnp.asarray(omega, jnp.result_type(float))
        self.v_eps = jnp.asarray(v_eps, jnp.result_type(float))
        for name in ("omega", "v_eps"):
            c = concrete(getattr(self, name))
            if c is not None and not np.all(c > 0):
                raise InputError(
                    f"Coulomb: argument {name!r} must be > 0 (omega in rad/s, v_eps in m/s), "
                    f"got {c.tolist()}."
                )

    @property
    def names(self) -> tuple[str, ...]:
        return ("bFc",)

    def columns(self) -> tuple[Column, ...]:
        return (Column("sgn_v", 0, 1.0),)

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        v = zero_phase_velocity(record.x, record.dt, self.omega)
        return {"sgn_v": (jnp.tanh(v / self.v_eps), "foh")}

    def physical(self, theta: Array, b: Array) -> dict[str, Array]:
        return {"Fc": theta[..., 0] / b}


@jax.jit
def dahl_states(
    v: Float[Array, " T"], dt: ArrayLike, zs: Float[ArrayLike, " m"]
) -> Float[Array, "m T"]:
    """Dahl's friction state ζ ∈ [−1, 1] for each pre-sliding distance ``zs`` [m], driven by
    the velocity ``v`` [m/s] sampled every ``dt`` [s]: dζ/dx = (1 − ζ·sgn ẋ)/z, integrated
    exactly over each sample's displacement d = (v[k−1] + v[k])·dt/2 (ζ → s + (ζ − s)·e^{−|d|/z},
    s = sgn d), from ζ = 0 at the first sample. Friction F_c·ζ deflects the contact elastically
    (stiffness F_c/z) under a force below F_c and slides at F_c·sgn ẋ after a travel of a few z
    (Dahl 1968; LuGre's bristles with σ₀ = F_c/z)."""
    d = jnp.concatenate([jnp.zeros((1,), v.dtype), 0.5 * (v[1:] + v[:-1]) * dt])
    zs = jnp.asarray(zs, v.dtype)

    def step(zeta, dk):
        s = jnp.sign(dk)
        zeta = s + (zeta - s) * jnp.exp(-jnp.abs(dk) / zs)
        return zeta, zeta

    _, out = jax.lax.scan(step, jnp.zeros_like(zs), d)
    return out.T


def presliding_signal(z: float) -> str:
    """The raw signal name of :class:`PreslidingFriction`'s ζ at the distance ``z`` [m]."""
    return f"dahl@{float(z):.9g}"


class PreslidingFriction(AbstractEffect):
    """Coulomb friction with Dahl's pre-sliding, F_c·ζ [N] (:func:`dahl_states`): ζ follows the
    displacement of v̂ and saturates at ±1 after a travel of a few ``z``, so that a force below
    F_c deflects the contact elastically instead of sliding. Column +(1/Λ)[ζ], parameter b·F_c,
    as :class:`Coulomb`'s (whose smoothed sign is the sliding limit z → 0).

    Attributes:
        omega: bandwidth ω [rad/s] of the zero-phase velocity filter (:func:`zero_phase_velocity`).
        z: the pre-sliding distance [m] (F_c/σ₀ for a contact stiffness σ₀ [N/m]): a number,
            since it names the column's signal.
    """

    omega: float
    z: float

    def __check_init__(self):
        for name, unit in (("omega", "rad/s"), ("z", "m")):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(
                    f"PreslidingFriction: argument {name!r} must be a finite number > 0 "
                    f"[{unit}], got {v!r}."
                )

    @property
    def names(self) -> tuple[str, ...]:
        return ("bFc",)

    def columns(self) -> tuple[Column, ...]:
        return (Column(presliding_signal(self.z), 0, 1.0),)

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        v = zero_phase_velocity(record.x, record.dt, self.omega)
        zeta = dahl_states(v, record.dt, jnp.asarray([self.z], v.dtype))[0]
        return {presliding_signal(self.z): (zeta, "foh")}

    def physical(self, theta: Array, b: Array) -> dict[str, Array]:
        return {"Fc": theta[..., 0] / b}


class Spring(AbstractEffect):
    """Spring force −k·x [N]: column +(1/Λ)[x], parameter b·k.

    With an equilibrium, −k(x − x₀) = −kx + kx₀: the constant kx₀ is an :class:`Offset` column,
    so a spring with equilibrium is ``(Spring(), Offset())`` and x₀ = F₀/k when no separate
    offset is assumed (a spring's equilibrium and a constant force are the same column).
    """

    @property
    def names(self) -> tuple[str, ...]:
        return ("bk",)

    def columns(self) -> tuple[Column, ...]:
        return (Column("x_spring", 0, 1.0),)

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        return {"x_spring": (record.x, "foh")}

    def physical(self, theta: Array, b: Array) -> dict[str, Array]:
        return {"k": theta[..., 0] / b}


#: Highest degree of :class:`PolynomialPosition`.
MAX_POSITION_DEGREE = 3


def position_terms(k: int) -> tuple[str, str, str]:
    """Raw signal names of :class:`PolynomialPosition`'s degree-k term: its a-signal
    ℓξᵏ⁺¹/(k+1), its b-signal ξᵏ·F and that signal's multiplier ξᵏ of F (degree 1:
    ``g_pos``, ``xiF``, ``xi``)."""
    return ("g_pos", "xiF", "xi") if k == 1 else (f"g_pos{k}", f"xi{k}F", f"xi{k}")


def position_values(xi, scale, k: int):
    """(ℓξᵏ⁺¹/(k+1), ξᵏ) of the degree-k term, numpy or jax arrays (see :func:`position_terms`)."""
    return scale * xi ** (k + 1) / (k + 1), xi**k


def position_physical_names(degree: int) -> tuple[str, ...]:
    """Physical names of :class:`PolynomialPosition` of ``degree``: ``da_dx``, ``db_dx``, then
    ``a_x2``, ``b_x2``, ``a_x3``, ``b_x3`` (coefficients of (x − x_c)ᵏ)."""
    out = ["da_dx", "db_dx"]
    for k in range(2, degree + 1):
        out += [f"a_x{k}", f"b_x{k}"]
    return tuple(out)


class PolynomialPosition(AbstractEffect):
    """Position-dependent coefficients, polynomial in ξ = (x − x_c)/ℓ of degree K ≤ 3:
    a(x) = a + Σₖ aₖξᵏ, b(x) = b + Σₖ bₖξᵏ (k = 1 … K).

    Exact columns (docs/method.md, "Exact regressors across regions"): aₖξᵏẋ =
    d/dt(ℓξᵏ⁺¹/(k+1)) → +(s/Λ)[ℓξᵏ⁺¹/(k+1)]; bₖξᵏF → −(1/Λ)[ξᵏF]. Parameters (a₁, b₁, a₂, b₂,
    …); :meth:`physical` reports the coefficients of (x − x_c)ᵏ: da/dx = a₁/ℓ [1/(s·m)],
    db/dx = b₁/ℓ [1/(kg·m)], then a_xk = aₖ/ℓᵏ [1/(s·mᵏ)], b_xk = bₖ/ℓᵏ [1/(kg·mᵏ)].
    Degree 1 (the default) is a(x), b(x) linear in x (this effect's former name,
    ``LinearPosition``).

    Attributes:
        center: x_c [m]; scale: ℓ [m] > 0 (the diagnosis uses the training record's mean and
            std); degree: K, 1 (default) … :data:`MAX_POSITION_DEGREE`.
    """

    acts_on_force: ClassVar[bool] = False  # it modulates a and b: added once, b not divided

    center: Float[Array, ""]
    scale: Float[Array, ""]
    degree: int = eqx.field(static=True)

    def __init__(self, center: ArrayLike, scale: ArrayLike, degree: int = 1):
        self.center = jnp.asarray(center, jnp.result_type(float))
        self.scale = jnp.asarray(scale, jnp.result_type(float))
        c = concrete(self.scale)
        if c is not None and not np.all(c > 0):
            raise InputError(
                f"{type(self).__name__}: argument 'scale' must be > 0 [m], got {c.tolist()}; "
                "pass the spread of the record's positions."
            )
        if not (isinstance(degree, int | np.integer) and 1 <= degree <= MAX_POSITION_DEGREE):
            raise InputError(
                f"PolynomialPosition: argument 'degree' must be an int in 1 … "
                f"{MAX_POSITION_DEGREE}, got {degree!r}."
            )
        self.degree = int(degree)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(n for k in range(1, self.degree + 1) for n in (f"a{k}", f"b{k}"))

    def columns(self) -> tuple[Column, ...]:
        out = []
        for k in range(1, self.degree + 1):
            g, f, _ = position_terms(k)
            out += [Column(g, 1, 1.0), Column(f, 0, -1.0)]
        return tuple(out)

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        xi = (record.x - self.center) / self.scale
        out = {}
        for k in range(1, self.degree + 1):
            g, f, _ = position_terms(k)
            gv, m = position_values(xi, self.scale, k)
            out[g] = (gv, "foh")
            out[f] = (m * record.F, "zoh")
        return out

    def physical(self, theta: Array, b: Array) -> dict[str, Array]:
        names = position_physical_names(self.degree)
        return {n: theta[..., j] / self.scale ** (j // 2 + 1) for j, n in enumerate(names)}


#: Name prefixes of :class:`LocalizedPosition`'s F-dependent signals (tanh ξ·F, sech²ξ·F) and
#: of their multipliers (tanh ξ, sech²ξ); the rest of a name is its (x₀, w).
LOCAL_F_MULTIPLIERS = {"lstepF@": "lstep@", "lbumpF@": "lbump@"}


def local_signal_names(center: float, width: float) -> tuple[str, str, str, str, str, str]:
    """Raw signal names of :class:`LocalizedPosition` at (x₀, w): its two a-signals
    w·log cosh ξ and w·tanh ξ, its two b-signals tanh ξ·F and sech²ξ·F, and those signals'
    multipliers tanh ξ and sech²ξ of F (one set per (x₀, w): a profile holds many)."""
    key = f"{float(center):.12g},{float(width):.12g}"
    (fs, ms), (fb, mb) = LOCAL_F_MULTIPLIERS.items()
    return f"lstep_g@{key}", f"lbump_g@{key}", fs + key, fb + key, ms + key, mb + key


def local_values(x, center, width):
    """(w·log cosh ξ, w·tanh ξ, tanh ξ, sech²ξ) of ξ = (x − x₀)/w, numpy or jax arrays (see
    :func:`local_signal_names`); log cosh ξ = |ξ| + log1p(e^{−2|ξ|}) − log 2 (no overflow)."""
    xp = jnp if isinstance(x, jnp.ndarray) else np
    xi = (x - center) / width
    t = xp.tanh(xi)
    ax = xp.abs(xi)
    logcosh = ax + xp.log1p(xp.exp(-2 * ax)) - np.log(2.0)
    return width * logcosh, width * t, t, 1.0 - t * t


@jax.jit
def _local_signals(x, F, center, width):
    """(w·log cosh ξ, w·tanh ξ, tanh ξ·F, sech²ξ·F) under a trace, (x₀, w) traced (concrete
    records take local_values' numpy path)."""
    vs, vb, ms, mb = local_values(x, center, width)
    return vs, vb, ms * F, mb * F


class LocalizedPosition(AbstractEffect):
    """A change of a and b confined around x₀ (width w): a step and a bump in
    ξ = (x − x₀)/w,

        a(x) = a + a_s·tanh ξ + a_b·sech²ξ,   b(x) = b + b_s·tanh ξ + b_b·sech²ξ,

    the §3 two-region structure made smooth (a step of 2a_s, 2b_s over ~2w at x₀) and a local
    dip or hump (a detent, a worn spot, a magnet's field) that a polynomial in x over the whole
    travel cannot follow.

    Exact columns (docs/method.md, "Exact regressors across regions"): tanh ξ·ẋ =
    d/dt(w·log cosh ξ) → +(s/Λ)[w·log cosh ξ]; sech²ξ·ẋ = d/dt(w·tanh ξ) → +(s/Λ)[w·tanh ξ];
    b_s tanh ξ·F → −(1/Λ)[tanh ξ·F]; b_b sech²ξ·F → −(1/Λ)[sech²ξ·F]. Parameters
    (a_s, b_s, a_b, b_b), reported as ``a_step`` [1/s], ``b_step`` [1/(kg)], ``a_bump`` [1/s],
    ``b_bump`` [1/kg] (not divided by b: it modulates a and b). x₀ and w are not fitted here:
    the diagnosis profiles them.

    Attributes:
        center: x₀ [m]; width: w [m] > 0.
    """

    acts_on_force: ClassVar[bool] = False  # it modulates a and b: added once, b not divided

    center: float = eqx.field(static=True)
    width: float = eqx.field(static=True)

    def __init__(self, center: float, width: float):
        c, w = float(center), float(width)
        if not np.isfinite(c):
            raise InputError(f"LocalizedPosition: argument 'center' must be finite [m], got {c}.")
        if not (np.isfinite(w) and w > 0):
            raise InputError(
                f"LocalizedPosition: argument 'width' must be > 0 [m], got {w}; pass the width "
                "of the transition (tanh((x − x₀)/w) goes from −0.76 to 0.76 over 2w)."
            )
        self.center, self.width = c, w

    @property
    def names(self) -> tuple[str, ...]:
        return ("a_s", "b_s", "a_b", "b_b")

    def columns(self) -> tuple[Column, ...]:
        gs, gb, fs, fb, _, _ = local_signal_names(self.center, self.width)
        return (Column(gs, 1, 1.0), Column(fs, 0, -1.0), Column(gb, 1, 1.0), Column(fb, 0, -1.0))

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        gs, gb, fs, fb, _, _ = local_signal_names(self.center, self.width)
        x, F = concrete(record.x), concrete(record.F)
        if x is None or F is None:
            vs, vb, us, ub = _local_signals(record.x, record.F, self.center, self.width)
        else:  # concrete: numpy (no program compiled per record length)
            vs, vb, ms, mb = local_values(x, self.center, self.width)
            us, ub = ms * F, mb * F
        return {gs: (vs, "foh"), gb: (vb, "foh"), fs: (us, "zoh"), fb: (ub, "zoh")}

    def physical(self, theta: Array, b: Array) -> dict[str, Array]:
        return {n: theta[..., j] for j, n in enumerate(("a_step", "b_step", "a_bump", "b_bump"))}
