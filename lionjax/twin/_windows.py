"""The exact-hold mass–damper: one sample step, and windowed simulation from given states.

Layer 2 (twin). Over one sample interval h, with the force held, ẍ = −aẋ + c has the exact
solution

    x(h) = x + v·φ₁ + c·φ₂,   v(h) = v·e^{−ah} + c·φ₁,
    φ₁ = (1 − e^{−ah})/a,     φ₂ = (h − φ₁)/a            (series for |ah| ≤ 10⁻²).

:func:`windowed_errors` steps the model with effects (offset F₀, spring k, Coulomb friction F_c
with sticking, position-dependent a(x), b(x): polynomial and localized) over a record,
restarting every H samples from given states: the "windowed simulation" the diagnosis scores a
model by. It is tested against
:func:`lionjax.twin.simulate` (one window, linear model) and against scipy's exact ZOH
discretisation (restarts from arbitrary states).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

#: Smallest K·h² (K = b·k [1/s²]) for which a step takes the spring in its exact solution
#: (:func:`exact_spring_step`); below it the spring force is held over the step with the input
#: (error ~ K·h²: at most 10⁻⁶ relative), which avoids dividing by a vanishing K. Held over a
#: step, a stiff spring diverged: one at 60 Hz sampled at 250 Hz (ω_k·dt = 1.5) did.
SPRING_EXACT = 1e-6

#: The parameters :func:`windowed_errors` reads (SI: 1/s, 1/kg, N, N, N, N/m, m, 1/(s·m),
#: 1/(kg·m), then the coefficients of (x − x_c)² and (x − x_c)³ in a(x) and b(x), then the
#: localized step and bump of a(x), b(x) [1/s, 1/kg, 1/s, 1/kg] at x_step [m] of width w_step
#: [m]: :class:`lionjax.LocalizedPosition`).
WINDOW_PARAMETERS = (
    "a",
    "b",
    "Fc",
    "dF",
    "F0",
    "k",
    "xc",
    "da_dx",
    "db_dx",
    "a_x2",
    "b_x2",
    "a_x3",
    "b_x3",
    "a_step",
    "b_step",
    "a_bump",
    "b_bump",
    "x_step",
    "w_step",
)


def exact_hold_step(x, v, c, a, h):
    """(x, v) after one interval h of ẍ = −aẋ + c with c held; any broadcastable shapes.

    φ₁ = −expm1(−ah)/a (no cancellation); φ₂ = (h − φ₁)/a loses digits as ah → 0, so for
    |ah| ≤ 10⁻² it is the series h²(1/2 − ah/6 + (ah)²/24 − (ah)³/120) (truncation ≤ 2·10⁻¹¹
    relative); a = 0 gives φ₁ = h, φ₂ = h²/2."""
    ah = a * h
    small = jnp.abs(ah) <= 1e-2
    safe_a = jnp.where(a == 0, 1.0, a)
    phi1 = jnp.where(a == 0, h, -jnp.expm1(-ah) / safe_a)
    series = h * h * (0.5 - ah / 6 + ah * ah / 24 - ah * ah * ah / 120)
    phi2 = jnp.where(small, series, (h - phi1) / safe_a)
    return x + v * phi1 + c * phi2, v * jnp.exp(-ah) + c * phi1


def exact_spring_step(x, v, c, a, K, h):
    """(x, v) after one interval h of ẍ = −aẋ − Kx + c with c held, exactly (K ≠ 0):
    the deviation from the equilibrium x* = c/K evolves by e^{Mh}, M = [[0, 1], [−K, −a]],
    e^{Mh} = e^{−ah/2}·(C·I + S·(M + (a/2)·I)), with d² = a²/4 − K, C = cosh(dh), S = sinh(dh)/d
    (cos and sin of |d|h where d² < 0; S → h as d → 0)."""
    d2 = 0.25 * a * a - K
    w = jnp.sqrt(jnp.abs(d2))
    wh = w * h
    tiny = wh < 1e-4
    safe_w = jnp.where(tiny, 1.0, w)
    C = jnp.where(d2 >= 0, jnp.cosh(wh), jnp.cos(wh))
    S = jnp.where(
        tiny, h * (1.0 + d2 * h * h / 6.0), jnp.where(d2 >= 0, jnp.sinh(wh), jnp.sin(wh)) / safe_w
    )
    e = jnp.exp(-0.5 * a * h)
    xe = x - c / K
    x1 = e * (C * xe + S * (0.5 * a * xe + v))
    v1 = e * (C * v + S * (-K * xe - 0.5 * a * v))
    return x1 + c / K, v1


@eqx.filter_jit
def windowed_errors(
    p: dict,
    u: Float[Array, " T"],
    x_meas: Float[Array, " T"],
    x_start: Float[Array, " T"],
    v_start: Float[Array, " T"],
    dt: Float[Array, ""],
    H: Int[Array, ""],
    n_valid: Int[Array, ""],
    extra=None,
    t: Float[Array, " T"] | None = None,
    *,
    span: int | None = None,
) -> Float[Array, " T"]:
    """Windowed simulation error x_sim − x_meas [m]: 0 from sample ``n_valid`` on.

    Model: ẍ + a(x)ẋ = b(x)·(u + F₀ − F_c·sgn ẋ − ΔF·|sgn ẋ| − k·x), a(x) = a + a'd + a₂d² +
    a₃d³, b(x) = b + b'd + b₂d² + b₃d³, d = clip(x, x_lo, x_hi) − x_c, with ``p`` holding
    :data:`WINDOW_PARAMETERS` (``dF`` optional, 0 when absent; and optionally ``x_lo``,
    ``x_hi`` [m]: ±∞ when absent); u the applied force [N], held over each sample; each step is
    :func:`exact_hold_step` with the nonlinear terms held over the sample. Friction has the level
    F⁺ = F_c + ΔF while ẋ > 0 and F⁻ = F_c − ΔF while ẋ < 0; it sticks when the velocity would
    reverse within a step while the other forces stay inside [−F⁻, F⁺], and breaks away when they
    leave it. Every H samples (k % H == 0) the state
    restarts from (x_start[k], v_start[k]). Everything is traced: one program per record length.

    ``extra``: an optional force term [N], a callable ``extra(x, v, u, t)`` (an equinox Module:
    its arrays are traced, so one program serves every value of its parameters) added to the
    forces b(x) multiplies, evaluated at each step's start state, with ``t`` [s] the samples'
    times. The spring enters each step in its exact solution (:func:`exact_spring_step`,
    where b(x)·k·dt² ≥ :data:`SPRING_EXACT`), so that a stiff one stays stable and exact.

    ``span`` (static): where given, a bound with span/2 < H ≤ span (:func:`window_span`); the
    windows are then stepped side by side, (⌈2T/span⌉, span) samples in ``span`` sequential
    steps, instead of the record in T (a scan step costs about a microsecond on a CPU, whatever
    it computes; windows are independent). The steps are the same, so the result is too. Without
    it the record is one scan of T steps. ``extra`` must then be elementwise in its arguments.
    """
    dt = jnp.asarray(dt, u.dtype)
    T = u.shape[0]
    k = jnp.arange(T)
    a, b, Fc = p["a"], p["b"], p["Fc"]
    Fp, Fn = Fc + p.get("dF", 0.0), Fc - p.get("dF", 0.0)  # the levels while ẋ > 0, ẋ < 0
    sticky = Fp + Fn > 0
    a2, a3, b2, b3 = p["a_x2"], p["a_x3"], p["b_x2"], p["b_x3"]
    # optional: a(x), b(x) held at their values at x_lo, x_hi beyond them
    x_lo, x_hi = p.get("x_lo", -jnp.inf), p.get("x_hi", jnp.inf)
    # optional: the localized step and bump (LocalizedPosition)
    a_s, b_s, a_b, b_b = (p.get(k, 0.0) for k in ("a_step", "b_step", "a_bump", "b_bump"))
    x_s, w_s = p.get("x_step", 0.0), p.get("w_step", 1.0)
    w_s = jnp.where(w_s > 0, w_s, 1.0)

    t = jnp.zeros_like(u) if t is None else t

    def step(x, v, uk, tk):
        dx = jnp.clip(x, x_lo, x_hi) - p["xc"]
        th = jnp.tanh((x - x_s) / w_s)
        s2 = 1.0 - th * th
        ak = a + dx * (p["da_dx"] + dx * (a2 + dx * a3)) + a_s * th + a_b * s2
        bk = b + dx * (p["db_dx"] + dx * (b2 + dx * b3)) + b_s * th + b_b * s2
        other = uk + p["F0"] - p["k"] * x
        if extra is not None:
            other = other + extra(x, v, uk, tk)
        s = jnp.sign(v)
        s = jnp.where(s == 0, (other > Fp).astype(s.dtype) - (other < -Fn).astype(s.dtype), s)
        fric = jnp.where(s > 0, Fp, jnp.where(s < 0, -Fn, 0.0))
        # the spring in the step's exact solution where it is not negligible (SPRING_EXACT)
        K = bk * p["k"]
        exact = jnp.abs(K) * dt * dt >= SPRING_EXACT
        safe_K = jnp.where(exact, K, 1.0)
        xs1, vs1 = exact_spring_step(x, v, bk * (other + p["k"] * x - fric), ak, safe_K, dt)
        xh1, vh1 = exact_hold_step(x, v, bk * (other - fric), ak, dt)
        x1, v1 = jnp.where(exact, xs1, xh1), jnp.where(exact, vs1, vh1)
        stick = sticky & (s * v1 < 0) & (other <= Fp) & (other >= -Fn)
        stuck = (s == 0) & sticky
        v1 = jnp.where(stick | stuck, 0.0, v1)
        x1 = jnp.where(stuck, x, x1)
        return x1, v1

    def body(carry, inp):
        x, v = carry
        uk, rs, xs, vs, tk = inp
        x = jnp.where(rs, xs, x)
        v = jnp.where(rs, vs, v)
        x1, v1 = step(x, v, uk, tk)
        return (x1, v1), x

    if span is None:
        z = jnp.zeros((), u.dtype)
        _, xs = jax.lax.scan(body, (z, z), (u, k % H == 0, x_start, v_start, t))
    else:
        # sample w·H + j of window w at [w, j]; slots past the window (j ≥ H) or the record
        # are stepped on the last sample's values and dropped when scattered back
        n_w = -(-2 * T // span)
        idx = jnp.arange(n_w)[:, None] * H + jnp.arange(span)[None, :]
        keep = (jnp.arange(span)[None, :] < H) & (idx < T)
        at = jnp.minimum(idx, T - 1)
        restart = (jnp.arange(span) == 0)[:, None] & keep.T
        inputs = (u[at].T, restart, x_start[at].T, v_start[at].T, t[at].T)
        z = jnp.zeros((n_w,), u.dtype)
        _, X = jax.lax.scan(body, (z, z), inputs)
        xs = jnp.zeros_like(u).at[jnp.where(keep, idx, T).T].set(X, mode="drop")
    return jnp.where(k < n_valid, xs - x_meas, 0.0)


def window_span(H: int) -> int:
    """The least power of two ≥ ``H``: the static ``span`` of :func:`windowed_errors` for
    windows of H samples (one compiled program per record length and power of two)."""
    return 1 << max(int(H) - 1, 0).bit_length()
