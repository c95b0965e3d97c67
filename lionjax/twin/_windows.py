"""The exact-hold mass–damper: one sample step, and windowed simulation from given states.

Layer 2 (twin). Over one sample interval h, with the force held, ẍ = −aẋ + c has the exact
solution

    x(h) = x + v·φ₁ + c·φ₂,   v(h) = v·e^{−ah} + c·φ₁,
    φ₁ = (1 − e^{−ah})/a,     φ₂ = (h − φ₁)/a            (series for |ah| ≤ 10⁻²).

:func:`windowed_errors` steps the model with effects (offset F₀, spring k, Coulomb friction F_c
with sticking, position-dependent a(x), b(x): polynomial and localized) over a record,
restarting every H samples from given states: the "windowed simulation" the diagnosis scores a
model by; with a flexible mode (:class:`ModeTerm`) the axis and the mode step together, exactly
for their linear part. It is tested against
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


class ModeTerm(eqx.Module):
    """A flexible mode in the windowed simulation: the measured axis x carries a share μ of the
    mass, coupled to the rest at ω [rad/s] with damping ratio ζ, and a share κ of the input
    passes through the mode (κ = 0 collocated, 1 not). With the deflection d = x − y (y the
    load's position, ÿ = 2ζω·ḋ + ω²·d) and r = ((2ζωs + ω²)/D)[u], D = s² + 2ζωs + ω²,

        (1 − μ)·ẍ = −aẋ − Kx − μ·(2ζω·ḋ + ω²·d) + b·((1 − κ)·u + κ·r) + N,

    which is ẍ + aẋ + Kx − μ·s²(s²/D)[x] = b·(u − κ·(s²/D)[u]) + N: the diagnosis' mode
    (docs/method.md, "Flexible mode"), N the forces held over each step. States (d, ḋ, z₁, z₂)
    beside (x, v), r = ω²z₁ + 2ζω·z₂ with ż₁ = z₂, ż₂ = −ω²z₁ − 2ζω·z₂ + u. All shapes ``()``.
    """

    mu: Float[Array, ""]
    omega: Float[Array, ""]
    zeta: Float[Array, ""]
    kappa: Float[Array, ""]

    def matrices(self, a, b, K, h):
        """(Φ (6, 6), Γ_u (6,), Γ_N (6,), Φ_d (2, 2)): one interval h of the states (x, v, d, ḋ,
        z₁, z₂) with u [N] and N [m/s²] held, exactly (e^{Mh} of the system with its two inputs
        appended as states), and of (d, ḋ) while the axis is held still (ẍ = 0)."""
        mu, w, z, kap = self.mu, self.omega, self.zeta, self.kappa
        c = 1.0 / (1.0 - mu)
        zero = jnp.zeros_like(w)
        one = jnp.ones_like(w)
        acc = c * jnp.stack(
            [-K, -a, -mu * w * w, -2 * mu * z * w, b * kap * w * w, 2 * b * kap * z * w]
        )
        rows = [
            jnp.stack([zero, one, zero, zero, zero, zero]),
            acc,
            jnp.stack([zero, zero, zero, one, zero, zero]),
            acc + jnp.stack([zero, zero, -w * w, -2 * z * w, zero, zero]),
            jnp.stack([zero, zero, zero, zero, zero, one]),
            jnp.stack([zero, zero, zero, zero, -w * w, -2 * z * w]),
        ]
        Bu = jnp.stack([zero, c * b * (1 - kap), zero, c * b * (1 - kap), zero, one])
        BN = jnp.stack([zero, c, zero, c, zero, zero])
        M = jnp.zeros((8, 8), w.dtype)
        M = M.at[:6, :6].set(jnp.stack(rows)).at[:6, 6].set(Bu).at[:6, 7].set(BN)
        E = jax.scipy.linalg.expm(M * h)
        Md = jnp.stack([jnp.stack([zero, one]), jnp.stack([-w * w, -2 * z * w])])
        return E[:6, :6], E[:6, 6], E[:6, 7], jax.scipy.linalg.expm(Md * h)


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
    mode: ModeTerm | None = None,
    s_start: Float[Array, "T 4"] | None = None,
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

    ``mode``: a flexible mode (:class:`ModeTerm`), its states (d, ḋ, z₁, z₂) restarted from
    ``s_start`` (T, 4) with (x, v). Each step then advances the six states by the exact solution
    of their linear system (a, b, k, the mode) with u held, every other force (offset, friction,
    ``extra``, and a(x) − a, b(x) − b) held over the step as N; friction sticks as above, the
    mode's force and its share of the input counted among the other forces, and while the axis
    is held still the mode swings on (ẍ = 0).
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

    def coefficients(x):
        """a(x), b(x) at x."""
        dx = jnp.clip(x, x_lo, x_hi) - p["xc"]
        th = jnp.tanh((x - x_s) / w_s)
        s2 = 1.0 - th * th
        ak = a + dx * (p["da_dx"] + dx * (a2 + dx * a3)) + a_s * th + a_b * s2
        bk = b + dx * (p["db_dx"] + dx * (b2 + dx * b3)) + b_s * th + b_b * s2
        return ak, bk

    def friction(v, other):
        """(s, the friction force): s the direction of the motion, or at rest of a breakaway
        (0: held), ``other`` the other forces [N]."""
        s = jnp.sign(v)
        s = jnp.where(s == 0, (other > Fp).astype(s.dtype) - (other < -Fn).astype(s.dtype), s)
        return s, jnp.where(s > 0, Fp, jnp.where(s < 0, -Fn, 0.0))

    def sticking(x, x1, v1, s, other):
        """(x, v) after a step that reverses the velocity while the other forces stay within
        [−F⁻, F⁺] (stuck: v = 0), or starts held and does not break away (x too), and
        whether it started held."""
        stick = sticky & (s * v1 < 0) & (other <= Fp) & (other >= -Fn)
        stuck = (s == 0) & sticky
        return jnp.where(stuck, x, x1), jnp.where(stick | stuck, 0.0, v1), stuck

    def step(x, v, uk, tk):
        ak, bk = coefficients(x)
        other = uk + p["F0"] - p["k"] * x
        if extra is not None:
            other = other + extra(x, v, uk, tk)
        s, fric = friction(v, other)
        # the spring in the step's exact solution where it is not negligible (SPRING_EXACT)
        K = bk * p["k"]
        exact = jnp.abs(K) * dt * dt >= SPRING_EXACT
        safe_K = jnp.where(exact, K, 1.0)
        xs1, vs1 = exact_spring_step(x, v, bk * (other + p["k"] * x - fric), ak, safe_K, dt)
        xh1, vh1 = exact_hold_step(x, v, bk * (other - fric), ak, dt)
        x1, v1 = jnp.where(exact, xs1, xh1), jnp.where(exact, vs1, vh1)
        x1, v1, _ = sticking(x, x1, v1, s, other)
        return x1, v1

    if mode is not None:
        Phi, Gu, GN, Phi_d = mode.matrices(a, b, b * p["k"], dt)
        w, z, kap = mode.omega, mode.zeta, mode.kappa

        def step_mode(x, v, sm, uk, tk):
            # the rigid forces as in `step`, then the linear part (a, b, k, the mode) exactly
            ak, bk = coefficients(x)
            held = p["F0"] + (0.0 if extra is None else extra(x, v, uk, tk))
            d, dd, z1, z2 = (sm[..., i] for i in range(4))
            coupling = -mode.mu / b * (2 * z * w * dd + w * w * d) - kap * (
                uk - (w * w * z1 + 2 * z * w * z2)
            )
            other = uk + held - p["k"] * x + coupling
            s, fric = friction(v, other)
            N = bk * (held - fric) + (bk - b) * (uk - p["k"] * x) - (ak - a) * v
            state = jnp.concatenate([x[..., None], v[..., None], sm], -1)
            new = state @ Phi.T + Gu * uk[..., None] + GN * N[..., None]
            x1, v1, stuck = sticking(x, new[..., 0], new[..., 1], s, other)
            swing = sm[..., :2] @ Phi_d.T  # the axis held: the mode swings on
            sm1 = new[..., 2:].at[..., :2].set(jnp.where(stuck[..., None], swing, new[..., 2:4]))
            return x1, v1, sm1

    def body(carry, inp):
        x, v, sm = carry
        uk, rs, xs, vs, ss, tk = inp
        x = jnp.where(rs, xs, x)
        v = jnp.where(rs, vs, v)
        if mode is None:
            x1, v1 = step(x, v, uk, tk)
            return (x1, v1, sm), x
        sm = jnp.where(rs[..., None], ss, sm)
        x1, v1, sm1 = step_mode(x, v, sm, uk, tk)
        return (x1, v1, sm1), x

    if mode is not None and (s_start is None or s_start.shape != (T, 4)):
        raise ValueError(
            f"windowed_errors: a mode needs s_start of shape ({T}, 4) (its states at every "
            f"sample); got {None if s_start is None else s_start.shape}"
        )
    ss = None if mode is None else s_start  # no mode: no states beside (x, v)
    if span is None:
        z0 = jnp.zeros((), u.dtype)
        carry = (z0, z0, None if mode is None else jnp.zeros((4,), u.dtype))
        _, xs = jax.lax.scan(body, carry, (u, k % H == 0, x_start, v_start, ss, t))
    else:
        # sample w·H + j of window w at [w, j]; slots past the window (j ≥ H) or the record
        # are stepped on the last sample's values and dropped when scattered back
        n_w = -(-2 * T // span)
        idx = jnp.arange(n_w)[:, None] * H + jnp.arange(span)[None, :]
        keep = (jnp.arange(span)[None, :] < H) & (idx < T)
        at = jnp.minimum(idx, T - 1)
        restart = (jnp.arange(span) == 0)[:, None] & keep.T
        s_at = None if ss is None else ss[at].swapaxes(0, 1)
        inputs = (u[at].T, restart, x_start[at].T, v_start[at].T, s_at, t[at].T)
        z0 = jnp.zeros((n_w,), u.dtype)
        s0 = None if mode is None else jnp.zeros((n_w, 4), u.dtype)
        _, X = jax.lax.scan(body, (z0, z0, s0), inputs)
        xs = jnp.zeros_like(u).at[jnp.where(keep, idx, T).T].set(X, mode="drop")
    return jnp.where(k < n_valid, xs - x_meas, 0.0)


def window_span(H: int) -> int:
    """The least power of two ≥ ``H``: the static ``span`` of :func:`windowed_errors` for
    windows of H samples (one compiled program per record length and power of two)."""
    return 1 << max(int(H) - 1, 0).bit_length()
