"""Simulation of the device twin: records sampled by a device loop, open or closed loop."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._errors import InputError
from .._record import Record
from .._solution_tools import is_traced
from ._effects import (
    AbstractCoefficientEffect,
    AbstractForceEffect,
    AbstractFriction,
    AbstractInputEffect,
    AbstractMeasurement,
    InputDelay,
)
from ._excitation import AbstractExcitation
from ._plant import CentringPD, Plant

if TYPE_CHECKING:  # imported where a simulation starts: `import lionjax` stays light
    import diffrax


class _Axis(eqx.Module):
    """The plant's dynamics in one discrete mode (direction s, region r), with its events.

    State y = (x, ẋ, z...) with z the internal states of the force effects. Mode s ∈ {−1, 0, +1}:
    direction of motion, 0 = stuck (only with exact friction). Region r ∈ {0 … R−1}.
    """

    a: Float[Array, " R"]
    b: Float[Array, " R"]
    lower: Float[Array, " R"]
    upper: Float[Array, " R"]
    forces: tuple[AbstractForceEffect, ...]
    frictions: tuple[AbstractFriction, ...]
    coefficients: tuple[AbstractCoefficientEffect, ...]
    slices: tuple[tuple[int, int], ...] = eqx.field(static=True)

    def coef(self, x, r):
        a, b = self.a[r], self.b[r]
        for c in self.coefficients:
            a, b = c.modulate(x, a, b)
        return a, b

    def other_force(self, y, F):
        """F_applied + smooth forces [N] (everything except the exact friction)."""
        total = F
        for f, (i, j) in zip(self.forces, self.slices, strict=True):
            total = total + f.force(y[0], y[1], y[i:j])
        return total

    def breakaway(self):
        one = jnp.ones((), self.a.dtype)
        bp = sum((fr.breakaway(one) for fr in self.frictions), 0 * one)
        bm = sum((fr.breakaway(-one) for fr in self.frictions), 0 * one)
        return bp, bm

    def rhs(self, t, y, args):
        s, r, F = args
        x, v = y[0], y[1]
        a, b = self.coef(x, r)
        sf = s.astype(y.dtype)
        fric = sum((fr.kinetic(sf, v) for fr in self.frictions), 0 * v)
        dv = b * (self.other_force(y, F) + fric) - a * v
        moving = s != 0
        dz = [
            f.states_rhs(x, v, y[i:j]) for f, (i, j) in zip(self.forces, self.slices, strict=True)
        ]
        head = jnp.stack([jnp.where(moving, v, 0 * v), jnp.where(moving, dv, 0 * dv)])
        return jnp.concatenate([head, *dz])

    def resolve(self, y, F):
        """Direction of motion from rest: +1/−1 when the net force breaks away, else 0 (stuck)."""
        Fo = self.other_force(y.at[1].set(0), F)
        bp, bm = self.breakaway()
        return jnp.where(Fo > bp, 1, jnp.where(Fo < -bm, -1, 0)).astype(jnp.int32)

    def events(self, y, s, r, F):
        """Event functions, all ≥ 0 in mode (s, r); an event is any of them < 0."""
        x, v = y[0], y[1]
        g = [x - self.lower[r], self.upper[r] - x]
        if self.frictions:
            inf = jnp.asarray(jnp.inf, y.dtype)
            Fo = self.other_force(y.at[1].set(0), F)
            bp, bm = self.breakaway()
            g += [
                jnp.where(s != 0, s * v, inf),
                jnp.where(s == 0, bp - Fo, inf),
                jnp.where(s == 0, Fo + bm, inf),
            ]
        return jnp.stack(g)

    def switch(self, y, s, r, F, hit):
        """The state and mode just after the events flagged in ``hit`` (bool, as ``events``)."""
        x = jnp.where(hit[0], self.lower[r], jnp.where(hit[1], self.upper[r], y[0]))
        r = r - hit[0].astype(r.dtype) + hit[1].astype(r.dtype)
        y = y.at[0].set(x)
        if self.frictions:
            y = y.at[1].set(jnp.where(hit[2], 0, y[1]))
            s = jnp.where(hit[2], self.resolve(y, F), s)
            s = jnp.where(hit[3], 1, jnp.where(hit[4], -1, s)).astype(jnp.int32)
        return y, s, r


def _once_if(pred, fn, default):
    """``fn()`` where ``pred`` else ``default``; under vmap it costs nothing if no ``pred``."""

    def body(carry):
        return jnp.array(True), fn()

    return jax.lax.while_loop(lambda c: pred & ~c[0], body, (jnp.array(False), default))[1]


def _substep(axis, solver, y, s, r, h, F, max_events, n_bisect):
    """Integrate over [0, h] with constant applied force F, locating and applying events.

    Each pass takes one solver step to the end of the sub-step; if an event function turned
    negative, the first event instant is located by bisection on the solver's dense output, the
    step is redone up to that instant, the mode is switched and the pass repeats from there.
    """
    import diffrax

    term = diffrax.ODETerm(axis.rhs)

    def step(y, s, r, t1):
        args = (s, r, F)
        state = solver.init(term, 0.0, t1, y, args)
        y1, _, dense, _, _ = solver.step(term, 0.0, t1, y, args, state, made_jump=False)
        return y1, dense

    def cond(c):
        t, _, _, _, i = c
        return (t < h) & (i <= max_events)

    def body(c):
        t, y, s, r, i = c
        if axis.frictions:
            s = jnp.where(s == 0, axis.resolve(y, F), s)
        rem = h - t
        y1, dense = step(y, s, r, rem)
        hit = jnp.any(axis.events(y1, s, r, F) < 0) & (i < max_events)
        interp = solver.interpolation_cls(t0=jnp.zeros_like(rem), t1=rem, **dense)

        def bisect(bc):
            lo, hi, j = bc
            mid = 0.5 * (lo + hi)
            p = jnp.any(axis.events(interp.evaluate(mid), s, r, F) < 0)
            return jnp.where(p, lo, mid), jnp.where(p, mid, hi), j + 1

        _, tau, _ = jax.lax.while_loop(
            lambda bc: hit & (bc[2] < n_bisect), bisect, (jnp.zeros_like(rem), rem, 0)
        )
        y_tau = _once_if(hit, lambda: step(y, s, r, tau)[0], y1)
        flags = axis.events(interp.evaluate(tau), s, r, F) < 0
        y_e, s_e, r_e = axis.switch(y_tau, s, r, F, flags & hit)
        return (
            jnp.where(hit, t + tau, h),
            jnp.where(hit, y_e, y1),
            jnp.where(hit, s_e, s),
            jnp.where(hit, r_e, r),
            i + 1,
        )

    init = (jnp.zeros_like(h), y, s, r, jnp.array(0))
    _, y, s, r, _ = jax.lax.while_loop(cond, body, init)
    return y, s, r


def _advance(axis, solver, y, s, r, length, F, n_substeps, max_events, n_bisect):
    h = length / n_substeps

    def body(_, c):
        return _substep(axis, solver, *c, h, F, max_events, n_bisect)

    return jax.lax.fori_loop(0, n_substeps, body, (y, s, r))


#: Samples per call of the compiled scan when ``simulate`` runs outside a trace: one program per
#: plant structure serves every record length (the last chunk runs past T, and its extra
#: outputs, later in time, are dropped).
CHUNK = 1024


def _padded_samples(n: int) -> int:
    """The scan length that simulates ``n`` samples under a trace (vmap, jit): n rounded up to a
    multiple of 2^(⌊log₂ n⌋ − 3) (at most 1/8 more steps, whose outputs are dropped), so that
    records of nearby lengths share one compiled program."""
    q = 1 << max(n.bit_length() - 4, 0)
    return -(-n // q) * q


def _buffer_length(plant: Plant, dt: float) -> int:
    """Length of the delayed-command buffer: ⌈Σ max_delay/dt⌉ + 2 rounded up to a power of two
    (1 without a delay), so that nearby sample rates share one compiled program."""
    delays = [e for e in plant.effects if isinstance(e, InputDelay)]
    if not delays:
        return 1
    n = int(math.ceil(sum(d.max_delay for d in delays) / dt)) + 2
    return 1 << (n - 1).bit_length()


def _parts(plant):
    """The plant's effects by role: (inputs, delays, forces, frictions, coefficients, sensors)."""
    return tuple(
        tuple(e for e in plant.effects if isinstance(e, kind))
        for kind in (
            AbstractInputEffect,
            InputDelay,
            AbstractForceEffect,
            AbstractFriction,
            AbstractCoefficientEffect,
            AbstractMeasurement,
        )
    )


@eqx.filter_jit
def _start(plant, x0, v0, *, n_buf):
    """The scan's carry at the first sample: (y, s, r, previous measured x, command buffer)."""
    dtype = jnp.result_type(float)
    _, _, forces, frictions, _, _ = _parts(plant)
    bounds = jnp.asarray(plant.bounds, dtype)
    x0 = jnp.asarray(x0, dtype)
    v0 = jnp.asarray(v0, dtype)
    z0 = [f.init_states(x0, v0).astype(dtype) for f in forces]
    y0 = jnp.concatenate([jnp.stack([x0, v0]), *z0])
    r0 = (jnp.sum(bounds < x0) + jnp.sum((bounds == x0) & (v0 > 0))).astype(jnp.int32)
    s0 = jnp.sign(v0).astype(jnp.int32) if frictions else jnp.array(1, jnp.int32)
    return (y0, s0, r0, x0, jnp.zeros((n_buf,), dtype))


@eqx.filter_jit
def _run(plant, carry, ks, f_exc, key, closed_loop, dt, *, n_substeps, max_events, solver):
    """The scan of :func:`simulate` over the samples ``ks`` (their global indices, shape
    static) with excitation ``f_exc`` from ``carry`` (:func:`_start`'s, or a previous call's),
    ``dt`` a traced scalar array of the default float dtype (one program for every sample rate):
    (carry after the last sample, (x measured, F logged, x, v, F_cmd, F_applied) each (T,))."""
    dtype = jnp.result_type(float)
    inputs, delays, forces, frictions, coefficients, sensors = _parts(plant)
    n_buf = carry[4].shape[0]

    slices, i = [], 2
    for f in forces:
        slices.append((i, i + f.n_states))
        i += f.n_states
    bounds = jnp.asarray(plant.bounds, dtype)
    inf = jnp.full((1,), jnp.inf, dtype)
    axis = _Axis(
        a=jnp.asarray(plant.a, dtype),
        b=jnp.asarray(plant.b, dtype),
        lower=jnp.concatenate([-inf, bounds]),
        upper=jnp.concatenate([bounds, inf]),
        forces=forces,
        frictions=frictions,
        coefficients=coefficients,
        slices=tuple(slices),
    )
    n_bisect = jnp.finfo(dtype).nmant + 3

    def apply_inputs(F):
        for e in inputs:
            F = e.apply(F)
        return F

    if delays:
        tau = sum(jnp.asarray(d.tau, dtype) for d in delays)
        max_delay = sum(d.max_delay for d in delays)
        tau = eqx.error_if(
            tau,
            tau > max_delay * (1 + 1e-9),
            "InputDelay: tau exceeds max_delay; raise max_delay",
        )
        D = tau / dt
        n_del = jnp.clip(jnp.floor(D), 0, n_buf - 2).astype(jnp.int32)
        frac = jnp.clip(D - n_del, 0.0, 1.0)

    def measure(x, F, k):
        kk = jax.random.fold_in(key, k)
        for j, sensor in enumerate(sensors):
            x, F = sensor.measure(x, F, jax.random.fold_in(kk, j))
        return x, F

    def advance(y, s, r, length, F):
        return _advance(axis, solver, y, s, r, length, F, n_substeps, max_events, n_bisect)

    def body(carry, inp):
        y, s, r, xm_prev, buf = carry
        k, fe = inp
        xm, _ = measure(y[0], jnp.zeros((), dtype), k)
        if closed_loop is None:
            F_cmd = fe
        else:
            vm = jnp.where(k == 0, 0.0, (xm - xm_prev) / dt)
            F_cmd = closed_loop.command(xm, vm, fe).astype(dtype)
        _, F_log = measure(y[0], F_cmd, k)
        buf = jnp.concatenate([F_cmd[None], buf[:-1]])
        if delays:
            F_early = apply_inputs(buf[n_del + 1])
            F_late = apply_inputs(buf[n_del])
            y1, s1, r1 = advance(y, s, r, frac * dt, F_early)
            y1, s1, r1 = advance(y1, s1, r1, (1 - frac) * dt, F_late)
            F_app = jnp.where(frac > 0, F_early, F_late)
        else:
            F_app = apply_inputs(F_cmd)
            y1, s1, r1 = advance(y, s, r, dt, F_app)
        out = (xm, F_log, y[0], y[1], F_cmd, F_app)
        return (y1, s1, r1, xm, buf), out

    return jax.lax.scan(body, carry, (ks, f_exc))


def simulate(
    plant: Plant,
    excitation: AbstractExcitation | Float[ArrayLike, " T"],
    *,
    dt: float = 1e-3,
    n_samples: int | None = None,
    duration: float | None = None,
    x0: Float[ArrayLike, ""] = 0.0,
    v0: Float[ArrayLike, ""] = 0.0,
    key: PRNGKeyArray | None = None,
    closed_loop: CentringPD | None = None,
    t0: Float[ArrayLike, ""] = 0.0,
    n_substeps: int = 1,
    max_events: int = 4,
    solver: diffrax.AbstractERK | None = None,
) -> Record:
    """Simulate one record of the device twin, sampled by a device loop at interval ``dt``.

    At each sample k (t_k = t0 + k·dt) the loop measures the position (through the plant's
    sensor effects), computes the commanded force F_cmd[k] — the excitation sample in open loop,
    or the :class:`CentringPD` command plus the excitation in closed loop — and holds it until
    t_{k+1} (zero-order hold). The axis receives F_cmd through the input effects (calibration,
    delay, saturation) and is integrated exactly per hold interval: an explicit Runge–Kutta
    solver of diffrax (default ``Tsit5``, 5th order) takes ``n_substeps`` steps per interval, and
    every discontinuity — a region bound crossed, the velocity reaching zero under exact friction
    (reversal or stick), break-away from sticking, the delayed command switching — is an event
    located to machine precision on the solver's dense output, after which the step is redone up
    to the event and continued in the new mode. So the only error is the solver's truncation
    error between events (tested against scipy ``solve_ivp``).

    Arguments:
        plant: the twin.
        excitation: an :class:`AbstractExcitation` (sampled at the t_k) or force samples [N] of
            shape ``(T,)``.
        dt: sample interval [s], a Python float (default 1 kHz). Traced: every sample rate runs
            the same compiled program.
        n_samples: number of samples T. Default: from ``duration``, else the length of the force
            samples. Every length runs one compiled program (per plant structure): the scan
            advances in chunks of :data:`CHUNK` samples, the last one run past T and its extra
            outputs dropped. Under a trace (vmap, jit) it is one scan over T rounded up to a
            multiple of 2^(⌊log₂ T⌋ − 3) (at most 1/8 more steps), a program per length bucket.
        duration: record length [s]: T = round(duration/dt) + 1 samples cover [t0, t0 + duration].
        x0, v0: initial position [m] and velocity [m/s].
        key: JAX PRNG key for the noise effects (required if the plant has any). Same key, same
            record (noise at sample k uses ``fold_in(key, k)``).
        closed_loop: a :class:`CentringPD` for closed-loop records, ``None`` for open loop.
        t0: time of the first sample [s].
        n_substeps: solver steps per sample interval (static; raise it for a stiff flexible mode).
        max_events: events handled per solver sub-step (static); later ones in the same sub-step
            are ignored (only stick–slip chatter gets there).
        solver: a diffrax explicit Runge–Kutta solver (default ``diffrax.Tsit5()``).

    Returns:
        a :class:`~lionjax.Record` with x = logged (measured) position [m], F = logged force [N]
        (the commanded force as the force sensor sees it), and extras ``x_true`` [m], ``v_true``
        [m/s] (true state at t_k), ``F_cmd`` [N] (noise-free command) and ``F_applied`` [N] (force
        acting on the axis just after t_k). Jit-compiled; ``eqx.filter_vmap`` it over keys,
        excitations or plants to get a batch.
    """
    if not isinstance(plant, Plant):
        raise InputError(
            f"simulate: argument 'plant' must be a Plant (e.g. lionjax.FALCON_PAPER), got "
            f"{type(plant).__name__}."
        )
    if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
        raise InputError(
            f"simulate: argument 'dt' must be a positive Python float [s], got {dt!r}. The "
            "sample interval fixes the record's time grid."
        )
    dt = float(dt)
    if isinstance(excitation, AbstractExcitation):
        if n_samples is None:
            if duration is None:
                raise InputError(
                    "simulate: pass 'n_samples' or 'duration' to sample an excitation Module, got "
                    "neither."
                )
            n_samples = int(round(float(duration) / dt)) + 1
    else:
        samples = jnp.asarray(excitation)
        if samples.ndim != 1:
            raise InputError(
                f"simulate: argument 'excitation' as force samples must have shape (T,), got "
                f"{samples.shape}. Pass one force [N] per sample (vmap for a batch)."
            )
        if n_samples is None:
            n_samples = samples.shape[0]
        if samples.shape[0] != n_samples:
            raise InputError(
                f"simulate: argument 'excitation' has {samples.shape[0]} samples but n_samples = "
                f"{n_samples}. Pass matching lengths."
            )
    if not (isinstance(n_samples, int) and n_samples >= 1):
        raise InputError(f"simulate: 'n_samples' must be a positive int, got {n_samples!r}.")
    for name, value in (("n_substeps", n_substeps), ("max_events", max_events)):
        if not (isinstance(value, int) and value >= 1):
            raise InputError(f"simulate: argument {name!r} must be an int >= 1, got {value!r}.")
    if closed_loop is not None and not isinstance(closed_loop, CentringPD):
        raise InputError(
            f"simulate: argument 'closed_loop' must be a CentringPD or None, got "
            f"{type(closed_loop).__name__}."
        )
    import diffrax

    solver = diffrax.Tsit5() if solver is None else solver
    if not isinstance(solver, diffrax.AbstractERK):
        raise InputError(
            f"simulate: argument 'solver' must be an explicit Runge–Kutta solver of diffrax "
            f"(e.g. diffrax.Tsit5(), diffrax.Dopri8()), got {type(solver).__name__}."
        )
    needs_key = any(isinstance(e, AbstractMeasurement) and e.random for e in plant.effects)
    if key is None:
        if needs_key:
            raise InputError(
                "simulate: argument 'key' is required because the plant has noise effects, got "
                "None. Pass key=jax.random.key(seed)."
            )
        key = jax.random.key(0)
    if isinstance(excitation, AbstractExcitation):
        f_exc = excitation.sample(n_samples, dt, t0)
    else:
        f_exc = jnp.asarray(excitation, jnp.result_type(float))
    dt_arr = jnp.asarray(dt, jnp.result_type(float))
    statics = dict(n_substeps=n_substeps, max_events=max_events, solver=solver)
    carry = _start(plant, x0, v0, n_buf=_buffer_length(plant, dt))
    if is_traced((plant, f_exc, x0, v0, key, closed_loop)):
        # under vmap or jit: one scan, inside the caller's program, per (plant structure,
        # length bucket); the force samples held at their last value over the padding
        n_pad = _padded_samples(n_samples)
        f_exc = jnp.concatenate([f_exc, jnp.broadcast_to(f_exc[-1], (n_pad - n_samples,))])
        ks = jnp.arange(n_pad)
        _, out = _run(plant, carry, ks, f_exc, key, closed_loop, dt_arr, **statics)
        xm, F_log, x_true, v_true, F_cmd, F_app = (o[:n_samples] for o in out)
    else:
        # one compiled chunk of CHUNK samples per plant structure, whatever the length; the
        # force samples held at their last value over the last chunk's padding
        n_pad = -(-n_samples // CHUNK) * CHUNK
        f = np.asarray(f_exc)
        f = np.concatenate([f, np.full(n_pad - n_samples, f[-1])])
        parts = []
        for k0 in range(0, n_pad, CHUNK):
            ks = np.arange(k0, k0 + CHUNK, dtype=jnp.result_type(int))
            carry, out = _run(
                plant, carry, ks, f[k0 : k0 + CHUNK], key, closed_loop, dt_arr, **statics
            )
            parts.append(out)
        xm, F_log, x_true, v_true, F_cmd, F_app = (
            jnp.asarray(np.concatenate([np.asarray(p[i]) for p in parts])[:n_samples])
            for i in range(6)
        )
    extras = {"x_true": x_true, "v_true": v_true, "F_cmd": F_cmd, "F_applied": F_app}
    return Record(xm, F_log, dt, t0, extras)
