"""An independent simulator of one device axis for the blind diagnosis benchmark.

Written without lionjax (numpy, scipy and numba only) so that the benchmark does not only test
the diagnosis on records of lionjax's own twin. One axis, sampled by a device loop at rate
f_s = 1/dt [Hz]:

    M₁·ẍ = u(t) − C·ẋ + F_effect(x, ẋ, internal states)        (x [m], u [N], C [N·s/m])

written per unit mass as ẍ + a·ẋ = b·(u + F_effect) with a = C/M₁ [1/s], b = 1/M₁ [1/kg]; a and
b may depend on x (:class:`PositionDependence`). At each sample k (t_k = k·dt) the loop

1. measures the position: x_m[k] = q·round(x_s(t_k)/q) + σ·n_k (encoder step q [m], white noise
   σ [m], n_k ~ N(0, 1)); x_s is the driven mass x, or the second mass for a non-collocated
   :class:`FlexibleMode`;
2. computes the command F[k] [N] — the excitation sample in open loop, or a PD on the *measured*
   position plus the excitation as a feed-forward force in closed loop (:class:`PDLoop`) — and
   logs it as the force sensor reads it: F_log[k] = F[k] + s(t_k), s a sensor artefact
   (:class:`ForceSensorLine`, :class:`ForceSensorDrift`; 0 without one) that only the log sees
   (the loop, the hold and the axis use F[k]);
3. holds F[k] over [t_k, t_{k+1}) (zero-order hold). The force reaching the axis is
   u(t) = g(F_held(t − τ)), g a memoryless input map (dead zone, then saturation); with
   τ = (n + φ)·dt (0 ≤ φ < 1) each hold interval has two pieces of constant u, split at
   t_k + φ·dt; before the record starts the command is 0 N.

Integration: classical fixed-step RK4 with ``n_sub`` sub-steps per piece, chosen per sample from
the plant's fastest rate λ so that h·λ ≤ 0.05 for the smooth dynamics (h·λ ≤ 1 for the
bristle/Dahl relaxation, which is stable for RK4 up to 2.8 and only relaxes to its quasi-steady
state). Friction with a jump at ẋ = 0 (:class:`StribeckFriction`, :class:`AsymmetricFriction`) is
a switched system: the zero crossing of ẋ inside a sub-step is located by bisection (to 1e-12 of
the sub-step), then the axis reverses or sticks (ẋ = 0, x frozen) while the net non-friction
force lies inside the break-away band; break-away is tested at every sub-step start. Accuracy of
the clean mass–damper against its exact per-interval solution is asserted by :func:`self_test`.

Everything is deterministic: the position noise is drawn from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

try:  # numba is a bench extra; without it the kernel runs as (slow) plain Python
    from numba import njit
except ImportError:  # pragma: no cover

    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f


# ---------------------------------------------------------------------------- parameter layout
# float parameters p[...]
P_A, P_B = 0, 1  # a [1/s], b [1/kg] of the driven mass
P_F0 = 2  # constant force [N]
P_K, P_XK = 3, 4  # spring stiffness [N/m], equilibrium [m]
P_AA, P_AB, P_L, P_XC = 5, 6, 7, 8  # position dependence α_a, α_b, length [m], centre [m]
P_R1, P_R2, P_R3, P_R4, P_R5 = 9, 10, 11, 12, 13  # friction parameters (meaning per kind)
P_TAU = 14  # input delay [s]
P_SAT = 15  # saturation level [N]
P_DZ = 16  # dead-zone half width [N]
P_M2, P_K2, P_C2, P_CG2, P_W = 17, 18, 19, 20, 21  # second body: m₂, k₂, c₂, c to ground, gap
P_CA, P_CP, P_CPHI = 22, 23, 24  # cogging amplitude [N], period [m], phase [rad]
P_STIFF_V = 25  # velocity-dependent stiffness of friction states [1/m] (rate = P_STIFF_V·|v|)
P_CQ = 26  # quadratic drag c₂ [N·s²/m²]
P_LA, P_LF, P_LP = 27, 28, 29  # force-sensor line: amplitude [N], f₀ [Hz], phase [rad]
P_LA2, P_LP2, P_LA3, P_LP3 = 30, 31, 32, 33  # its 2nd and 3rd harmonic: amplitude [N], phase
P_DRIFT = 34  # force-sensor drift rate [N/s]
P_FX1, P_FX2 = 35, 36  # friction acts only for x in [x1, x2] [m] (with F_FGATE)
P_KAPPA, P_TP = 37, 38  # payload: a, b scaled by κ from time t_p [s] on (with F_TIME)
P_RAMP, P_TR = 39, 40  # device force drift: r·(t − t_r)₊ [N], r [N/s], t_r [s] (with F_TIME)
P_TSCALE, P_TFORCE = 41, 42  # the kernel's current κ (1 before t_p) and drift force [N]
N_P = 43
# integer flags f[...]
F_FRIC = 0  # 0 none, 1 Stribeck–Coulomb, 2 LuGre, 3 Dahl, 4 asymmetric
F_PSHAPE = 1  # 0 none, 1 tanh, 2 bowl, 3 algebraic sigmoid
F_SAT = 2  # 0 none, 1 hard, 2 soft (tanh)
F_BODY2 = 3  # 0 none, 1 flexible mode, 2 backlash (load through a gap)
F_MEAS2 = 4  # 1: the sensor reads the second body (non-collocated)
F_FSENS = 5  # 1: the force sensor adds a line and/or a drift to the logged force
F_FGATE = 6  # 1: the switched friction acts only for x in [P_FX1, P_FX2]
F_TIME = 7  # 1: a payload and/or a device force drift, switched per sample (P_KAPPA … P_TR)
N_F = 8
# state y = (x, ẋ, z, x₂, ẋ₂): z the friction state (LuGre bristle [m] / Dahl force [N])
N_Y = 5


@njit(cache=True)
def _shape(flags, p, x):
    s = flags[F_PSHAPE]
    if s == 0:
        return 0.0
    d = (x - p[P_XC]) / p[P_L]
    if s == 1:
        return math.tanh(d)
    if s == 2:
        return 1.0 - math.exp(-d * d)
    if s == 4:  # one boundary at x_c: 0 on the side L points away from, 1 on the other
        return 1.0 if d > 0.0 else 0.0
    return d / math.sqrt(1.0 + d * d)


@njit(cache=True)
def _smooth_force(flags, p, y, u):
    """u + every force on the driven mass except friction and viscous damping [N]."""
    x = y[0]
    f = u + p[P_F0] - p[P_K] * (x - p[P_XK]) + p[P_TFORCE]
    if p[P_CA] != 0.0:
        f += p[P_CA] * math.sin(2.0 * math.pi * x / p[P_CP] + p[P_CPHI])
    body2 = flags[F_BODY2]
    if body2 == 1:
        f += p[P_K2] * (y[3] - x) + p[P_C2] * (y[4] - y[1])
    elif body2 == 2:
        f -= _gap_force(p, x - y[3], y[1] - y[4])
    return f


@njit(cache=True)
def _gap_force(p, e, de):
    """Force [N] the driven mass exerts on the load through the gap (±w), ≥ 0 pushing."""
    w = p[P_W]
    if e > w:
        return max(p[P_K2] * (e - w) + p[P_C2] * de, 0.0)
    if e < -w:
        return min(p[P_K2] * (e + w) + p[P_C2] * de, 0.0)
    return 0.0


@njit(cache=True)
def _rhs(flags, p, y, u, s, out):
    x, v = y[0], y[1]
    w = _shape(flags, p, x)
    a = p[P_A] * (1.0 + p[P_AA] * w) * p[P_TSCALE]
    b = p[P_B] * (1.0 + p[P_AB] * w) * p[P_TSCALE]
    f = _smooth_force(flags, p, y, u)
    g = _gate(flags, p, x)
    if p[P_CQ] != 0.0:  # quadratic drag (0 at rest, so it never enters the break-away test)
        f -= p[P_CQ] * v * abs(v)
    kind = flags[F_FRIC]
    out[2] = 0.0
    if kind == 1:  # Stribeck–Coulomb, switched
        if s == 0:
            f = 0.0
            v = 0.0
        else:
            f -= g * s * (p[P_R1] + (p[P_R2] - p[P_R1]) * math.exp(-((v / p[P_R3]) ** 2)))
    elif kind == 4:  # asymmetric, switched
        if s == 0:
            f = 0.0
            v = 0.0
        elif s > 0:
            f -= g * (p[P_R1] + p[P_R3] * v)
        else:
            f += g * (p[P_R2] - p[P_R4] * v)
    elif kind == 2:  # LuGre: z bristle deflection [m]
        g = p[P_R1] + (p[P_R2] - p[P_R1]) * math.exp(-((v / p[P_R3]) ** 2))
        dz = v - p[P_R4] * abs(v) * y[2] / g
        out[2] = dz
        f -= p[P_R4] * y[2] + p[P_R5] * dz
    elif kind == 3:  # Dahl: z friction force [N]
        dz = p[P_R2] * (v - abs(v) * y[2] / p[P_R1])
        out[2] = dz
        f -= y[2]
    out[0] = v
    out[1] = 0.0 if (s == 0 and (kind == 1 or kind == 4)) else b * f - a * v
    body2 = flags[F_BODY2]
    if body2 == 1:
        out[3] = y[4]
        out[4] = (-(p[P_K2] * (y[3] - y[0]) + p[P_C2] * (y[4] - y[1])) - p[P_CG2] * y[4]) / p[P_M2]
    elif body2 == 2:
        out[3] = y[4]
        out[4] = (_gap_force(p, y[0] - y[3], y[1] - y[4]) - p[P_CG2] * y[4]) / p[P_M2]
    else:
        out[3] = 0.0
        out[4] = 0.0


@njit(cache=True)
def _gate(flags, p, x):
    """1 where the switched friction acts (everywhere, or on [x1, x2] with F_FGATE), else 0."""
    if flags[F_FGATE] == 0:
        return 1.0
    return 1.0 if p[P_FX1] <= x <= p[P_FX2] else 0.0


@njit(cache=True)
def _rk4(flags, p, y, u, s, h, k1, k2, k3, k4, tmp, out):
    _rhs(flags, p, y, u, s, k1)
    for i in range(N_Y):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    _rhs(flags, p, tmp, u, s, k2)
    for i in range(N_Y):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    _rhs(flags, p, tmp, u, s, k3)
    for i in range(N_Y):
        tmp[i] = y[i] + h * k3[i]
    _rhs(flags, p, tmp, u, s, k4)
    for i in range(N_Y):
        out[i] = y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(cache=True)
def _breakaway(flags, p, y, u):
    """New direction from rest: +1/−1 if the net force breaks away, else 0 (stuck)."""
    fo = _smooth_force(flags, p, y, u)
    g = _gate(flags, p, y[0])
    if flags[F_FRIC] == 1:
        up, dn = g * p[P_R2], g * p[P_R2]
    else:
        up, dn = g * p[P_R1], g * p[P_R2]
    if fo > up:
        return 1
    if fo < -dn:
        return -1
    return 0


@njit(cache=True)
def _piece(flags, p, y, u, s, T, n_sub, work):
    """Integrate over a piece of length T with constant u; returns the friction mode s."""
    if T <= 0.0:
        return s
    k1, k2, k3, k4, tmp, yn, ym = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    switched = flags[F_FRIC] == 1 or flags[F_FRIC] == 4
    h = T / n_sub
    for _ in range(n_sub):
        rem = h
        n_ev = 0
        while rem > 0.0:
            if switched and s == 0:
                y[1] = 0.0
                s = _breakaway(flags, p, y, u)
            _rk4(flags, p, y, u, s, rem, k1, k2, k3, k4, tmp, yn)
            if switched and s != 0 and s * yn[1] < 0.0 and n_ev < 8:
                lo, hi = 0.0, rem
                for _it in range(45):
                    mid = 0.5 * (lo + hi)
                    _rk4(flags, p, y, u, s, mid, k1, k2, k3, k4, tmp, ym)
                    if s * ym[1] > 0.0:
                        lo = mid
                    else:
                        hi = mid
                _rk4(flags, p, y, u, s, hi, k1, k2, k3, k4, tmp, ym)
                for i in range(N_Y):
                    y[i] = ym[i]
                y[1] = 0.0
                rem -= hi
                s = _breakaway(flags, p, y, u)
                n_ev += 1
            else:
                for i in range(N_Y):
                    y[i] = yn[i]
                rem = 0.0
    return s


@njit(cache=True)
def _input(flags, p, F):
    """g(F): dead zone, then saturation [N]."""
    d = p[P_DZ]
    if d > 0.0:
        F = 0.0 if abs(F) <= d else F - d * (1.0 if F > 0 else -1.0)
    k = flags[F_SAT]
    if k == 1:
        F = min(max(F, -p[P_SAT]), p[P_SAT])
    elif k == 2:
        F = p[P_SAT] * math.tanh(F / p[P_SAT])
    return F


@njit(cache=True)
def _sensor_force(flags, p, Fk, t):
    """The force sensor's reading [N] of the command Fk [N] at time t [s] from the record's
    start: Fk plus the mains line (fundamental and 2nd/3rd harmonic) and the drift."""
    if flags[F_FSENS] == 0:
        return Fk
    w = 2.0 * math.pi * p[P_LF] * t
    line = p[P_LA] * math.sin(w + p[P_LP])
    line += p[P_LA2] * math.sin(2.0 * w + p[P_LP2]) + p[P_LA3] * math.sin(3.0 * w + p[P_LP3])
    return Fk + line + p[P_DRIFT] * t


@njit(cache=True)
def _kernel(flags, p, exc, noise, dt, x0, v0, q, closed, kp, kd, alpha_v, x_ref, lam, lam_v):
    T = exc.shape[0]
    p = p.copy()  # P_TSCALE, P_TFORCE change per sample (F_TIME)
    p[P_TSCALE] = 1.0
    p[P_TFORCE] = 0.0
    xm = np.empty(T)
    Fc = np.empty(T)
    Flog = np.empty(T)
    traj = np.empty((T, N_Y))
    u_log = np.empty(T)
    y = np.zeros(N_Y)
    y[0] = x0
    y[1] = v0
    y[3] = x0
    y[4] = v0
    work = np.zeros((7, N_Y))
    s = 0
    if v0 > 0:
        s = 1
    elif v0 < 0:
        s = -1
    tau = p[P_TAU]
    nd = int(math.floor(tau / dt + 1e-12))
    phi = tau / dt - nd
    if phi < 1e-12:
        phi = 0.0
    vf = 0.0
    prev = 0.0
    for k in range(T):
        xs = y[3] if flags[F_MEAS2] == 1 else y[0]
        xq = q * math.floor(xs / q + 0.5) if q > 0 else xs
        xm[k] = xq + noise[k]
        if closed:
            if k > 0:
                vf = alpha_v * vf + (1.0 - alpha_v) * (xm[k] - prev) / dt
            Fc[k] = kp * (x_ref - xm[k]) - kd * vf + exc[k]
        else:
            Fc[k] = exc[k]
        Flog[k] = _sensor_force(flags, p, Fc[k], k * dt)  # logged only: never fed back
        prev = xm[k]
        for i in range(N_Y):
            traj[k, i] = y[i]
        i1 = k - nd - 1
        i2 = k - nd
        u1 = _input(flags, p, Fc[i1]) if i1 >= 0 else 0.0
        u2 = _input(flags, p, Fc[i2]) if i2 >= 0 else 0.0
        u_log[k] = u2 if phi == 0.0 else u1
        if k == T - 1:
            break
        if flags[F_TIME] == 1:  # held over the interval, as the command is
            tk = k * dt
            p[P_TSCALE] = p[P_KAPPA] if tk >= p[P_TP] else 1.0
            p[P_TFORCE] = p[P_RAMP] * max(tk + 0.5 * dt - p[P_TR], 0.0)
        # sub-steps: smooth rate λ (h·λ ≤ 0.05) and the friction-state rate λ_v·|v| (h·rate ≤ 1)
        rate = max(lam / 0.05, lam_v * 2.0 * max(abs(y[1]), abs(y[4])))
        n_sub = max(2, int(math.ceil(dt * rate)))
        if phi > 0.0:
            n1 = max(1, int(math.ceil(n_sub * phi)))
            n2 = max(1, int(math.ceil(n_sub * (1.0 - phi))))
            s = _piece(flags, p, y, u1, s, phi * dt, n1, work)
            s = _piece(flags, p, y, u2, s, (1.0 - phi) * dt, n2, work)
        else:
            s = _piece(flags, p, y, u2, s, dt, n_sub, work)
        if not (abs(y[0]) < 1e3 and abs(y[1]) < 1e6):
            for j in range(k + 1, T):
                xm[j] = np.nan
                Fc[j] = np.nan
                Flog[j] = np.nan
                u_log[j] = np.nan
                for i in range(N_Y):
                    traj[j, i] = np.nan
            break
    return xm, Fc, Flog, traj, u_log


# ---------------------------------------------------------------------------- the plant


@dataclasses.dataclass(frozen=True)
class Axis:
    """The rigid axis ẍ + a·ẋ = b·u: a = C/M [1/s] ∈ (0, ∞), b = 1/M [1/kg] > 0.

    For :class:`FlexibleMode` and :class:`Backlash` (a, b) describe the *rigid* axis (both bodies
    locked together); the effect splits the mass (see there), so the low-frequency response is
    unchanged and the response change measures the unmodelled dynamics alone.
    """

    a: float
    b: float
    effects: tuple = ()


class Effect:
    """Base of the effects: ``fill(p, flags, axis)`` writes the parameters into the kernel's
    vectors. Each subclass documents its equation; forces in N, positions in m."""

    name = "effect"

    def fill(self, p, flags, axis):  # pragma: no cover - abstract
        raise NotImplementedError

    def rate(self, axis) -> tuple[float, float]:
        """(smooth rate λ [1/s], velocity stiffness λ_v [1/m]) for the sub-step choice."""
        return 0.0, 0.0


@dataclasses.dataclass(frozen=True)
class StribeckFriction(Effect):
    """Coulomb friction with a Stribeck hump, exact sign and stick–slip:

        F_fr = −sgn(ẋ)·[F_c + (F_s − F_c)·exp(−(ẋ/v_s)²)]   for ẋ ≠ 0,
        stuck (ẋ = 0) while |F_net,other| ≤ F_s.

    Attributes: fc = F_c [N] ≥ 0, fs = F_s [N] ≥ F_c, vs = v_s [m/s] > 0.
    """

    fc: float
    fs: float
    vs: float
    name = "stribeck"

    def fill(self, p, flags, axis):
        flags[F_FRIC] = 1
        p[P_R1], p[P_R2], p[P_R3] = self.fc, self.fs, self.vs

    def rate(self, axis):
        return 0.9 * axis.b * (self.fs - self.fc) / self.vs, 0.0


@dataclasses.dataclass(frozen=True)
class LuGreFriction(Effect):
    """LuGre friction (bristle deflection z [m]):

        ż = ẋ − σ₀·|ẋ|·z / g(ẋ),   g(ẋ) = F_c + (F_s − F_c)·exp(−(ẋ/v_s)²),
        F_fr = −(σ₀·z + σ₁·ż)   [N].

    Attributes: fc, fs [N], vs [m/s], sigma0 = σ₀ [N/m], sigma1 = σ₁ [N·s/m].
    """

    fc: float
    fs: float
    vs: float
    sigma0: float
    sigma1: float
    name = "lugre"

    def fill(self, p, flags, axis):
        flags[F_FRIC] = 2
        p[P_R1], p[P_R2], p[P_R3], p[P_R4], p[P_R5] = (
            self.fc,
            self.fs,
            self.vs,
            self.sigma0,
            self.sigma1,
        )

    def rate(self, axis):
        w = math.sqrt(self.sigma0 * axis.b)
        return max(w, self.sigma1 * axis.b), self.sigma0 / self.fc


@dataclasses.dataclass(frozen=True)
class DahlFriction(Effect):
    """Dahl friction (first order, z = friction force [N]):

        ż = σ·(ẋ − |ẋ|·z / F_c),   F_fr = −z   [N].

    Attributes: fc = F_c [N] > 0, sigma = σ [N/m] (rest stiffness; F_c/σ is the presliding
    length).
    """

    fc: float
    sigma: float
    name = "dahl"

    def fill(self, p, flags, axis):
        flags[F_FRIC] = 3
        p[P_R1], p[P_R2] = self.fc, self.sigma

    def rate(self, axis):
        return math.sqrt(self.sigma * axis.b), self.sigma / self.fc


@dataclasses.dataclass(frozen=True)
class AsymmetricFriction(Effect):
    """Direction-dependent Coulomb and viscous friction, exact sign and stick–slip:

        F_fr = −(F⁺ + c⁺·ẋ) for ẋ > 0,   F_fr = F⁻ − c⁻·ẋ for ẋ < 0   [N],
        stuck while −F⁻ ≤ F_net,other ≤ F⁺.

    Attributes: fc_pos = F⁺, fc_neg = F⁻ [N] ≥ 0; c_pos = c⁺, c_neg = c⁻ [N·s/m] ≥ 0.
    """

    fc_pos: float
    fc_neg: float
    c_pos: float
    c_neg: float
    name = "asymmetric"

    def fill(self, p, flags, axis):
        flags[F_FRIC] = 4
        p[P_R1], p[P_R2], p[P_R3], p[P_R4] = self.fc_pos, self.fc_neg, self.c_pos, self.c_neg

    def rate(self, axis):
        return axis.b * max(self.c_pos, self.c_neg), 0.0


@dataclasses.dataclass(frozen=True)
class QuadraticDrag(Effect):
    """Quadratic (aerodynamic, fluid) drag: adds −c₂·ẋ·|ẋ| [N]; c₂ [N·s²/m²] ≥ 0.

    Its linearised rate 2·b·c₂·|ẋ| sets the sub-steps (h·rate ≤ 0.05, through λ_v).
    """

    c2: float
    name = "quadratic_drag"

    def fill(self, p, flags, axis):
        p[P_CQ] = self.c2

    def rate(self, axis):
        # the kernel takes n_sub ≥ dt·λ_v·2|ẋ|: λ_v = 20·b·c₂ gives h·2b·c₂|ẋ| ≤ 0.05
        return 0.0, 20.0 * axis.b * self.c2


@dataclasses.dataclass(frozen=True)
class ForceSensorLine(Effect):
    """Mains pick-up on the force sensor, seen by the log only (the axis never feels it):

        F_log[k] = F[k] + A·sin(2π f₀ t_k + φ) + A₂·sin(4π f₀ t_k + φ₂) + A₃·sin(6π f₀ t_k + φ₃),

    t_k = k·dt from the record's start. Attributes: amplitude A [N], frequency f₀ [Hz], phase φ
    [rad]; a2, phi2, a3, phi3 the 2nd and 3rd harmonic (default 0).
    """

    amplitude: float
    frequency: float
    phase: float
    a2: float = 0.0
    phi2: float = 0.0
    a3: float = 0.0
    phi3: float = 0.0
    name = "force_sensor_line"

    def fill(self, p, flags, axis):
        flags[F_FSENS] = 1
        p[P_LA], p[P_LF], p[P_LP] = self.amplitude, self.frequency, self.phase
        p[P_LA2], p[P_LP2], p[P_LA3], p[P_LP3] = self.a2, self.phi2, self.a3, self.phi3


@dataclasses.dataclass(frozen=True)
class ForceSensorDrift(Effect):
    """A load cell zeroed at the record's start that drifts, seen by the log only:
    F_log[k] = F[k] + r·t_k with t_k = k·dt; rate_n_per_s = r [N/s] (either sign)."""

    rate_n_per_s: float
    name = "force_sensor_drift"

    def fill(self, p, flags, axis):
        flags[F_FSENS] = 1
        p[P_DRIFT] = self.rate_n_per_s


@dataclasses.dataclass(frozen=True)
class ForceOffset(Effect):
    """Constant force F₀ [N] on the axis (gravity, cable preload): adds +F₀."""

    f0: float
    name = "offset"

    def fill(self, p, flags, axis):
        p[P_F0] = self.f0


@dataclasses.dataclass(frozen=True)
class Spring(Effect):
    """Linear spring to an equilibrium: adds −k·(x − x_eq) [N]; k [N/m] ≥ 0, x_eq [m]."""

    k: float
    x_eq: float
    name = "spring"

    def fill(self, p, flags, axis):
        p[P_K], p[P_XK] = self.k, self.x_eq

    def rate(self, axis):
        return math.sqrt(self.k * axis.b), 0.0


@dataclasses.dataclass(frozen=True)
class PositionDependence(Effect):
    """Smooth position dependence of both coefficients:

        a(x) = a·(1 + α_a·w(x)),   b(x) = b·(1 + α_b·w(x)),   d = (x − x_c)/L,
        w = tanh d ("tanh"), 1 − exp(−d²) ("bowl", even in d), d/√(1 + d²) ("algebraic"),
    [d > 0] ("step": one boundary at x_c, the coefficients changed on the side L points to),

    |w| ≤ 1 so |α| < 1 keeps a, b > 0. Attributes: alpha_a, alpha_b; length L [m] > 0;
    center x_c [m]; shape.
    """

    alpha_a: float
    alpha_b: float
    length: float
    center: float
    shape: str = "tanh"
    name = "position"

    def fill(self, p, flags, axis):
        flags[F_PSHAPE] = {"tanh": 1, "bowl": 2, "algebraic": 3, "step": 4}[self.shape]
        p[P_AA], p[P_AB], p[P_L], p[P_XC] = self.alpha_a, self.alpha_b, self.length, self.center

    def rate(self, axis):
        return axis.a * (1 + abs(self.alpha_a)), 0.0


@dataclasses.dataclass(frozen=True)
class FrictionSpot(Effect):
    """Coulomb friction on part of the rail only (a rough spot), exact sign and stick–slip:

        F_fr = −sgn(ẋ)·F_c·[x₁ ≤ x ≤ x₂]   for ẋ ≠ 0,   stuck while |F_net,other| ≤ F_c there,

    (the Stribeck kernel with F_s = F_c, gated by the position). Attributes: fc = F_c [N] > 0,
    x1 < x2 [m].
    """

    fc: float
    x1: float
    x2: float
    name = "friction_spot"

    def fill(self, p, flags, axis):
        flags[F_FRIC], flags[F_FGATE] = 1, 1
        p[P_R1], p[P_R2], p[P_R3] = self.fc, self.fc, 1.0
        p[P_FX1], p[P_FX2] = self.x1, self.x2


@dataclasses.dataclass(frozen=True)
class Payload(Effect):
    """A payload m = μ·M fixed to the axis from time t_p [s] on (the record's own time, t = k·dt):
    from the first sample at or after t_p, a and b are scaled by κ = 1/(1 + μ) (the viscous
    coefficient C stays: a = C/(M + m), b = 1/(M + m)). Attributes: mass_ratio μ > 0, t_p."""

    mass_ratio: float
    t_p: float
    name = "payload"

    def fill(self, p, flags, axis):
        flags[F_TIME] = 1
        p[P_KAPPA], p[P_TP] = 1.0 / (1.0 + self.mass_ratio), self.t_p


@dataclasses.dataclass(frozen=True)
class DeviceDrift(Effect):
    """A force on the axis that drifts from time t_r [s] on: adds r·(t − t_r)₊ [N] (held per
    sample interval at its mid-point value); r [N/s], either sign (a cable's pull or a
    thermal offset that creeps)."""

    rate_n_per_s: float
    t_r: float
    name = "device_drift"

    def fill(self, p, flags, axis):
        flags[F_TIME] = 1
        p[P_RAMP], p[P_TR] = self.rate_n_per_s, self.t_r


@dataclasses.dataclass(frozen=True)
class InputDelay(Effect):
    """Transport delay of the held command: u(t) = g(F_held(t − τ)), τ [s] ≥ 0 (any real τ, not
    only multiples of dt); 0 N before the record starts."""

    tau: float
    name = "delay"

    def fill(self, p, flags, axis):
        p[P_TAU] = self.tau


@dataclasses.dataclass(frozen=True)
class HardSaturation(Effect):
    """Hard clip of the command: u = clip(F, −F_max, F_max) [N]; F_max > 0."""

    f_max: float
    name = "hard"

    def fill(self, p, flags, axis):
        flags[F_SAT] = 1
        p[P_SAT] = self.f_max


@dataclasses.dataclass(frozen=True)
class SoftSaturation(Effect):
    """Smooth saturation of the command: u = F_max·tanh(F/F_max) [N]; F_max > 0."""

    f_max: float
    name = "soft"

    def fill(self, p, flags, axis):
        flags[F_SAT] = 2
        p[P_SAT] = self.f_max


@dataclasses.dataclass(frozen=True)
class DeadZone(Effect):
    """Input dead zone: u = 0 for |F| ≤ d, else F − d·sgn F [N]; d > 0 (applied before any
    saturation)."""

    d: float
    name = "dead_zone"

    def fill(self, p, flags, axis):
        p[P_DZ] = self.d


@dataclasses.dataclass(frozen=True)
class Cogging(Effect):
    """Cogging (detent) force periodic in position: adds A·sin(2π·x/p + φ) [N]; A [N], p [m]."""

    amplitude: float
    period: float
    phase: float
    name = "cogging"

    def fill(self, p, flags, axis):
        p[P_CA], p[P_CP], p[P_CPHI] = self.amplitude, self.period, self.phase

    def rate(self, axis):
        return math.sqrt(2 * math.pi * self.amplitude / self.period * axis.b), 0.0


@dataclasses.dataclass(frozen=True)
class FlexibleMode(Effect):
    """The rigid mass M = 1/b split into the driven mass M₁ = (1 − μ)·M (actuator, viscous C =
    a·M) and a second mass m₂ = μ·M on a spring–damper:

        M₁·ẍ₁ = u − C·ẋ₁ + k₂(x₂ − x₁) + c₂(ẋ₂ − ẋ₁),   m₂·ẍ₂ = −k₂(x₂ − x₁) − c₂(ẋ₂ − ẋ₁),
        k₂ = m₂·ω², c₂ = 2ζ·m₂·ω, ω = 2π·f (m₂ on a fixed base).

    ``collocated``: the sensor reads x₁ (anti-resonance then resonance); otherwise x₂ (the
    non-collocated case: a resonance with 180° more phase lag above it). Attributes:
    mass_ratio μ ∈ (0, 1), frequency f [Hz], damping_ratio ζ, collocated.
    """

    mass_ratio: float
    frequency: float
    damping_ratio: float
    collocated: bool = True
    name = "flexible"

    def fill(self, p, flags, axis):
        M = 1 / axis.b
        m1, m2 = (1 - self.mass_ratio) * M, self.mass_ratio * M
        w = 2 * math.pi * self.frequency
        flags[F_BODY2] = 1
        flags[F_MEAS2] = 0 if self.collocated else 1
        p[P_A], p[P_B] = axis.a * M / m1, 1 / m1
        p[P_M2], p[P_K2], p[P_C2], p[P_CG2] = m2, m2 * w * w, 2 * self.damping_ratio * m2 * w, 0.0

    def rate(self, axis):
        w = 2 * math.pi * self.frequency
        return w * math.sqrt(1 + self.mass_ratio / (1 - self.mass_ratio)) * 1.5, 0.0


@dataclasses.dataclass(frozen=True)
class Backlash(Effect):
    """Play (backlash) between the driven, measured mass M₁ = (1 − μ)M and a load m_l = μM:

        e = x₁ − x_l,   F_g = max(k_g(e − w) + c_g·ė, 0) for e > w,
                        F_g = min(k_g(e + w) + c_g·ė, 0) for e < −w,   0 inside the gap,
        M₁·ẍ₁ = u − (1 − μ)C·ẋ₁ − F_g,   m_l·ẍ_l = F_g − μC·ẋ_l,

    k_g = m_r·ω², c_g = 2ζ·m_r·ω with m_r = M₁m_l/M, ω = 2π·f (contact stiffness). Total play
    2w [m]. With w = 0 and f → ∞ it is the rigid axis. Attributes: half_gap w [m],
    mass_ratio μ, frequency f [Hz], damping_ratio ζ.
    """

    half_gap: float
    mass_ratio: float
    frequency: float
    damping_ratio: float
    name = "backlash"

    def fill(self, p, flags, axis):
        M = 1 / axis.b
        C = axis.a * M
        m1, ml = (1 - self.mass_ratio) * M, self.mass_ratio * M
        mr = m1 * ml / M
        w = 2 * math.pi * self.frequency
        flags[F_BODY2] = 2
        p[P_A], p[P_B] = (1 - self.mass_ratio) * C / m1, 1 / m1
        p[P_M2], p[P_K2], p[P_C2] = ml, mr * w * w, 2 * self.damping_ratio * mr * w
        p[P_CG2], p[P_W] = self.mass_ratio * C, self.half_gap

    def rate(self, axis):
        return 2 * math.pi * self.frequency * 1.5, 0.0


# ---------------------------------------------------------------------------- loop, sensor


@dataclasses.dataclass(frozen=True)
class PDLoop:
    """Closed loop run by the device at every sample, on the *measured* position x_m:

        v_f[k] = α·v_f[k−1] + (1 − α)·(x_m[k] − x_m[k−1])/dt,   α = exp(−2π·f_v·dt), v_f[0] = 0,
        F[k] = K_p·(x_ref − x_m[k]) − K_d·v_f[k] + F_exc[k]   [N]   (excitation feed-forward).

    :meth:`design` places the rigid closed loop s² + (a + bK_d)s + bK_p at natural frequency f_c
    and damping ζ_c (K_d clipped at 0 when the plant alone is already damped beyond ζ_c).
    Attributes: kp [N/m], kd [N·s/m], velocity_hz f_v [Hz], x_ref [m].
    """

    kp: float
    kd: float
    velocity_hz: float
    x_ref: float = 0.0

    @staticmethod
    def design(a: float, b: float, fc: float, zeta: float, velocity_hz: float) -> PDLoop:
        w = 2 * math.pi * fc
        return PDLoop(w * w / b, max(2 * zeta * w - a, 0.0) / b, velocity_hz)


@dataclasses.dataclass
class SimResult:
    """A simulated record: logged x [m] (measured) and F [N] (the command as the force sensor
    reads it), dt [s]; true signals of the measured body x_true [m], v_true [m/s]; the driven
    mass x1, v1; u the applied force at the start of each interval [N] (after delay and input
    maps); F_cmd the command itself [N] (= F without a force-sensor artefact)."""

    x: np.ndarray
    F: np.ndarray
    dt: float
    x_true: np.ndarray
    v_true: np.ndarray
    x1: np.ndarray
    v1: np.ndarray
    u: np.ndarray
    F_cmd: np.ndarray | None = None

    @property
    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.F)))


def compile_axis(axis: Axis):
    """(flags, p, λ, λ_v) of the kernel for ``axis`` and its effects."""
    p = np.zeros(N_P)
    flags = np.zeros(N_F, np.int64)
    p[P_A], p[P_B] = axis.a, axis.b
    p[P_KAPPA] = 1.0  # no payload unless one sets it
    lam, lam_v = abs(axis.a), 0.0
    names = [e.name for e in axis.effects]
    fr = [
        e
        for e in axis.effects
        if isinstance(
            e,
            StribeckFriction | LuGreFriction | DahlFriction | AsymmetricFriction | FrictionSpot,
        )
    ]
    if len(fr) > 1 or sum(isinstance(e, FlexibleMode | Backlash) for e in axis.effects) > 1:
        raise ValueError(f"at most one friction and one second body, got {names}")
    if sum(isinstance(e, HardSaturation | SoftSaturation) for e in axis.effects) > 1:
        raise ValueError(f"at most one saturation, got {names}")
    for kind in (QuadraticDrag, ForceSensorLine, ForceSensorDrift, Payload, DeviceDrift):
        if sum(isinstance(e, kind) for e in axis.effects) > 1:
            raise ValueError(f"at most one {kind.name}, got {names}")
    # the mass split first: it rewrites a, b that the position dependence then modulates
    for e in sorted(axis.effects, key=lambda e: not isinstance(e, FlexibleMode | Backlash)):
        e.fill(p, flags, axis)
        r, rv = e.rate(axis)
        lam, lam_v = max(lam, r), max(lam_v, rv)
    lam = max(lam, abs(p[P_A]) * (1 + abs(p[P_AA])))
    return flags, p, lam, lam_v


def simulate(
    axis: Axis,
    excitation: np.ndarray,
    fs: float,
    *,
    loop: PDLoop | None = None,
    q: float = 0.0,
    noise_std: float = 0.0,
    seed: int = 0,
    x0: float = 0.0,
    v0: float = 0.0,
) -> SimResult:
    """Simulate one record of T = len(excitation) samples at rate ``fs`` [Hz].

    Arguments:
        axis: the plant and its effects.
        excitation: F_exc[k] [N], shape (T,): the command in open loop, the feed-forward of the
            :class:`PDLoop` in closed loop.
        fs: sample rate [Hz] (dt = 1/fs).
        loop: a :class:`PDLoop` for closed loop, ``None`` for open loop.
        q: encoder step [m] (0: no quantisation); noise_std: white position noise σ [m].
        seed: seed of the noise draw; x0, v0: initial state [m], [m/s] (both bodies).
    """
    exc = np.ascontiguousarray(excitation, np.float64)
    dt = 1.0 / float(fs)
    flags, p, lam, lam_v = compile_axis(axis)
    noise = np.random.default_rng(seed).standard_normal(exc.size) * noise_std
    closed = loop is not None
    kp, kd, fv, xr = (loop.kp, loop.kd, loop.velocity_hz, loop.x_ref) if closed else (0, 0, 1, 0)
    xm, Fc, Flog, traj, u = _kernel(
        flags,
        p,
        exc,
        noise,
        dt,
        float(x0),
        float(v0),
        float(q),
        closed,
        float(kp),
        float(kd),
        math.exp(-2 * math.pi * fv * dt),
        float(xr),
        float(lam),
        float(lam_v),
    )
    meas2 = bool(flags[F_MEAS2])
    return SimResult(
        x=xm,
        F=Flog,
        dt=dt,
        x_true=traj[:, 3] if meas2 else traj[:, 0],
        v_true=traj[:, 4] if meas2 else traj[:, 1],
        x1=traj[:, 0],
        v1=traj[:, 1],
        u=u,
        F_cmd=Fc,
    )


# ---------------------------------------------------------------------------- excitations

EXCITATIONS = ("multisine", "chirp", "steps", "noise")


def excitation(
    kind: str, rng: np.random.Generator, n: int, fs: float, rms: float, f_lo: float, f_hi: float
) -> np.ndarray:
    """Force samples [N], shape (n,), of RMS ``rms`` [N] in the band [f_lo, f_hi] Hz.

    ``multisine``: 3–10 sines, log-spaced random frequencies, random phases; ``chirp``: linear
    or logarithmic sweep f_lo → f_hi over the record; ``steps``: PRBS-like random steps, levels
    uniform in [−1, 1] (multi-level, so a saturation is not a mere gain change), hold times
    uniform in [1/(4f_hi), 1/(2f_lo)]; ``noise``: white Gaussian noise through a 2nd-order
    Butterworth band-pass [f_lo, f_hi].
    """
    t = np.arange(n) / fs
    if kind == "multisine":
        m = int(rng.integers(3, 11))
        f = np.exp(rng.uniform(math.log(f_lo), math.log(f_hi), m))
        y = np.sin(2 * np.pi * f[None, :] * t[:, None] + rng.uniform(0, 2 * np.pi, m)).sum(1)
    elif kind == "chirp":
        T = t[-1]
        if rng.random() < 0.5:
            ph = 2 * np.pi * (f_lo * t + (f_hi - f_lo) * t**2 / (2 * T))
        else:
            r = math.log(f_hi / f_lo)
            ph = 2 * np.pi * f_lo * T / r * (np.exp(r * t / T) - 1)
        y = np.sin(ph + rng.uniform(0, 2 * np.pi))
    elif kind == "steps":
        y = np.empty(n)
        i = 0
        while i < n:
            hold = max(1, int(rng.uniform(0.25 / f_hi, 0.5 / f_lo) * fs))
            y[i : i + hold] = rng.uniform(-1, 1)
            i += hold
    elif kind == "noise":
        from scipy.signal import butter, sosfiltfilt

        sos = butter(2, [f_lo, f_hi], btype="bandpass", fs=fs, output="sos")
        y = sosfiltfilt(sos, rng.standard_normal(n + 2000))[1000 : 1000 + n]
    else:
        raise ValueError(f"unknown excitation {kind!r}; expected one of {EXCITATIONS}")
    y = y - (np.mean(y) if kind == "noise" else 0.0)
    return rms * y / max(float(np.sqrt(np.mean(y**2))), 1e-300)


# ---------------------------------------------------------------------------- closed form, test


def exact_mass_damper(
    a: float, b: float, F: np.ndarray, dt: float, tau: float = 0.0, x0: float = 0.0, v0: float = 0.0
):
    """Exact x(t_k), ẋ(t_k) of ẍ + aẋ = b·u with u the held F delayed by τ (0 before the start).

    Over a piece of length h with constant u: ẋ(h) = ẋ₀e^{−ah} + (bu/a)(1 − e^{−ah}),
    x(h) = x₀ + (ẋ₀ − bu/a)(1 − e^{−ah})/a + (bu/a)·h.
    """
    nd = int(math.floor(tau / dt + 1e-12))
    phi = tau / dt - nd
    x, v = float(x0), float(v0)
    X, V = np.empty(F.size), np.empty(F.size)

    def step(x, v, u, h):
        e = math.exp(-a * h)
        vs = b * u / a
        return x + (v - vs) * (1 - e) / a + vs * h, v * e + vs * (1 - e)

    for k in range(F.size):
        X[k], V[k] = x, v
        u1 = F[k - nd - 1] if k - nd - 1 >= 0 else 0.0
        u2 = F[k - nd] if k - nd >= 0 else 0.0
        if phi > 1e-12:
            x, v = step(x, v, u1, phi * dt)
            x, v = step(x, v, u2, (1 - phi) * dt)
        else:
            x, v = step(x, v, u2, dt)
    return X, V


def self_test(tol: float = 1e-6) -> dict:
    """The clean mass–damper (no effects, no sensor) against :func:`exact_mass_damper`, open and
    closed loop, with and without a fractional delay, at 250 Hz–5 kHz; asserts max|error| ≤ tol
    × max|signal| for x and ẋ and returns the worst relative errors."""
    rng = np.random.default_rng(12345)
    worst = {"x": 0.0, "v": 0.0}
    for fs, a, b, tau, closed in [
        (250.0, 50.0, 5.0, 0.0, False),
        (1234.56, 5.0, 0.3, 0.0, True),
        (4999.0, 30.0, 2.0, 3.7e-3, False),
        (321.0, 20.0, 1.0, 6.3e-3, True),
    ]:
        n = int(3 * fs)
        exc = excitation("multisine", rng, n, fs, 2.0, 0.3, 12.0)
        effects = (InputDelay(tau),) if tau else ()
        loop = PDLoop.design(a, b, 3.0, 0.7, 80.0) if closed else None
        r = simulate(Axis(a, b, effects), exc, fs, loop=loop)
        X, V = exact_mass_damper(a, b, r.F, r.dt, tau)
        ex = float(np.max(np.abs(r.x_true - X)) / np.max(np.abs(X)))
        ev = float(np.max(np.abs(r.v_true - V)) / np.max(np.abs(V)))
        worst["x"], worst["v"] = max(worst["x"], ex), max(worst["v"], ev)
        assert ex <= tol and ev <= tol, (fs, a, b, tau, closed, ex, ev)
    return worst


if __name__ == "__main__":
    print(self_test())
