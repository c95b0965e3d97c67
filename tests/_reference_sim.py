"""An independent simulator of model (13) for the tests: closed form per held-force interval.

Within a region with constant F the model ẍ + aẋ = bF has the exact solution
v(τ) = v∞ + (v₀ − v∞)e^{−aτ}, x(τ) = x₀ + v∞τ + (v₀ − v∞)(1 − e^{−aτ})/a, v∞ = bF/a.
Region crossings inside an interval are located with ``scipy.optimize.brentq``. Pure numpy/scipy:
it shares no code with lionjax.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

PAPER_BOUNDS = (-0.010, 0.010)
PAPER_A = (16.2, 22.0, 37.1)
PAPER_B = (2.02, 1.916, 1.289)


def _flow(x0, v0, a, b, F, tau):
    vinf = b * F / a
    e = np.exp(-a * tau)
    return x0 + vinf * tau + (v0 - vinf) * (1.0 - e) / a, vinf + (v0 - vinf) * e


def _region(x, v, bounds):
    r = int(np.searchsorted(bounds, x, side="left"))
    # exactly on a bound: the region the motion is heading into
    if r < len(bounds) and x == bounds[r] and v > 0:
        r += 1
    return r


def simulate(F, dt, *, a=PAPER_A, b=PAPER_B, bounds=PAPER_BOUNDS, x0=0.0, v0=0.0):
    """Positions at the sample instants for the held force samples ``F`` (shape (T,))."""
    bounds = np.asarray(bounds, float)
    F = np.asarray(F, float)
    x = np.empty_like(F)
    xk, vk = float(x0), float(v0)
    for k in range(F.size):
        x[k] = xk
        rem = dt
        while rem > 0:
            r = _region(xk, vk, bounds)
            x1, v1 = _flow(xk, vk, a[r], b[r], F[k], rem)
            lo = bounds[r - 1] if r > 0 else -np.inf
            hi = bounds[r] if r < len(bounds) else np.inf
            if lo <= x1 <= hi:
                xk, vk, rem = x1, v1, 0.0
                continue
            edge = hi if x1 > hi else lo
            tc = brentq(
                lambda s: _flow(xk, vk, a[r], b[r], F[k], s)[0] - edge,
                0.0,
                rem,
                xtol=1e-15,
                rtol=1e-15,
            )
            xc, vc = _flow(xk, vk, a[r], b[r], F[k], tc)
            xk, vk, rem = edge, vc, rem - tc
            if tc == 0.0 and rem > 0:  # numerically stuck on the edge: nudge across
                xk = edge + np.sign(vc) * 1e-15
    return x


def multisine(t, freqs, amps, phases=None, bias=0.0):
    phases = np.zeros(len(freqs)) if phases is None else phases
    return bias + sum(A * np.sin(2 * np.pi * f * t + p) for f, A, p in zip(freqs, amps, phases))


def sampled_force_axis(seed, *, n=8000, dt=1e-3, a=6.0, b=2.5, noise=0.0):
    """(x, F) of ẍ = −aẋ + bF(t) under a smooth multisine F(t) (7 lines, 0.7–29 Hz, amplitudes
    and phases drawn with ``seed``), integrated by scipy's DOP853 (rtol 10⁻¹¹) and both read at
    the instants k·dt — a force sampled, not held — x with white noise of std ``noise``."""
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(seed)
    f = np.array([0.7, 1.9, 3.3, 6.1, 11.0, 17.0, 29.0])
    amp, phase = rng.uniform(0.5, 1.0, f.size), rng.uniform(0, 2 * np.pi, f.size)

    def force(t):
        t = np.atleast_1d(t)
        return np.sum(amp[:, None] * np.sin(2 * np.pi * f[:, None] * t + phase[:, None]), 0)

    t = np.arange(n) * dt
    ode = solve_ivp(
        lambda t, y: [y[1], -a * y[1] + b * force(t)[0]],
        (0, t[-1]),
        [0.0, 0.0],
        t_eval=t,
        rtol=1e-11,
        atol=1e-13,
        method="DOP853",
    )
    return ode.y[0] + noise * rng.standard_normal(n), force(t)


def forced_axis(F, dt, *, a, b, force=None, substeps=8, x0=0.0, v0=0.0):
    """Positions of ẍ = −aẋ + b·(F + force(x, v)) for the held force samples ``F`` (T,):
    classical RK4 with ``substeps`` steps per sample interval (``force`` numpy, scalar)."""
    force = (lambda x, v: 0.0) if force is None else force
    h = dt / substeps
    x = np.empty(len(F))
    xk, vk = float(x0), float(v0)

    def acc(xx, vv, Fk):
        return -a * vv + b * (Fk + force(xx, vv))

    for i, Fk in enumerate(np.asarray(F, float)):
        x[i] = xk
        for _ in range(substeps):
            k1x, k1v = vk, acc(xk, vk, Fk)
            k2x, k2v = vk + h / 2 * k1v, acc(xk + h / 2 * k1x, vk + h / 2 * k1v, Fk)
            k3x, k3v = vk + h / 2 * k2v, acc(xk + h / 2 * k2x, vk + h / 2 * k2v, Fk)
            k4x, k4v = vk + h * k3v, acc(xk + h * k3x, vk + h * k3v, Fk)
            xk += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
            vk += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return x


def stick_slip_axis(F, dt, *, a, b, Fc, Fs, vs, substeps=32):
    """Positions of ẍ = −aẋ + b·(F − f) with Stribeck friction and true sticking (Karnopp):
    while stuck (v = 0) the axis stays until |F| exceeds the static level Fs; sliding, the
    friction is f = (Fc + (Fs − Fc)·exp(−(v/vs)²))·sgn v, and a velocity that reaches zero under
    |F| ≤ Fs sticks. Semi-implicit Euler with ``substeps`` steps per held force sample."""
    h = dt / substeps
    x = np.empty(len(F))
    xk, vk = 0.0, 0.0
    for i, Fk in enumerate(np.asarray(F, float)):
        x[i] = xk
        for _ in range(substeps):
            if vk == 0.0:
                if abs(Fk) <= Fs:
                    continue
                s = np.sign(Fk)
            else:
                s = np.sign(vk)
            f = (Fc + (Fs - Fc) * np.exp(-((vk / vs) ** 2))) * s
            v1 = vk + h * (-a * vk + b * (Fk - f))
            if vk != 0.0 and np.sign(v1) != s and abs(Fk) <= Fs:
                v1 = 0.0  # the motion stops within the step and sticks
            xk += h * v1
            vk = v1
    return x
