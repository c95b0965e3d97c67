"""Excitation signals: force inputs F(t) [N] for the device twin (and for real experiments).

Every excitation is an :class:`AbstractExcitation` Module: ``exc(t)`` evaluates the force at any
times ``t`` [s] (any shape, elementwise) and ``exc.sample(n_samples, dt, t0)`` gives the samples at
``t0 + k·dt`` that a 1 kHz device loop holds between samples. Parameters are array leaves, so a
batch of excitations (phases, seeds, amplitudes) is built and simulated with ``eqx.filter_vmap``.

Holding the axis near an operating point. The base model ẍ + aẋ = bF has a free integrator: a
zero-mean force makes the position drift (its mean depends on the initial phase) and no bias force
can hold it. The paper's experiments around x = −20, 0, +20 mm therefore need feedback; lionjax
uses the centring PD :class:`~lionjax._plant.CentringPD` (K_p = 200 N/m, K_d = 1 N·s/m, x_ref = the
operating point), with the excitation added to its command. :data:`PAPER_SINE_SETS` are designed for
that loop: with the paper's plant each moves the axis by about ±4–5 mm around the operating point,
so a record stays inside one region of eq. (13).
"""

from __future__ import annotations

import abc
import math
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from .._checks import check_finite, check_positive, concrete, param
from .._errors import InputError


def _atleast_1d(value):
    return np.atleast_1d(value) if concrete(value) is not None else jnp.atleast_1d(value)


def _broadcast(value, n):
    if concrete(value) is not None:
        arr = np.asarray(value, dtype=np.float64)
        return np.broadcast_to(arr, (n,)).copy() if arr.ndim == 0 else arr
    return jnp.broadcast_to(value, (n,)) if jnp.ndim(value) == 0 else value


class AbstractExcitation(eqx.Module):
    """A force input F(t) [N] defined for all real t [s]."""

    @abc.abstractmethod
    def __call__(self, t: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
        """The force [N] at times ``t`` [s], elementwise (same shape as ``t``)."""

    def sample(
        self, n_samples: int, dt: float, t0: Float[ArrayLike, ""] = 0.0
    ) -> Float[Array, " n_samples"]:
        """The force at the sample times ``t0 + k·dt``, k = 0 … n_samples − 1, shape ``(T,)``."""
        n = int(n_samples)
        if n < 1:
            raise InputError(f"sample: argument 'n_samples' must be >= 1, got {n_samples!r}.")
        if not (isinstance(dt, int | float) and dt > 0 and math.isfinite(dt)):
            raise InputError(f"sample: argument 'dt' must be a positive float [s], got {dt!r}.")
        dtype = jnp.result_type(float)
        t = jnp.asarray(t0, dtype) + dt * jnp.arange(n, dtype=dtype)
        return self(t)


class SineSum(AbstractExcitation):
    """A sum of sines: F(t) = F_off + Σⱼ Aⱼ·sin(2π·fⱼ·t + φⱼ) [N].

    Attributes:
        amplitudes: Aⱼ [N], shape ``(n,)``.
        frequencies: fⱼ [Hz], shape ``(n,)``, > 0.
        phases: φⱼ [rad], shape ``(n,)`` (default 0).
        offset: F_off [N], shape ``()`` (default 0).
    """

    amplitudes: Float[ArrayLike, " n"]
    frequencies: Float[ArrayLike, " n"]
    phases: Float[ArrayLike, " n"]
    offset: Float[ArrayLike, ""]

    def __init__(
        self,
        amplitudes: ArrayLike,
        frequencies: ArrayLike,
        phases: ArrayLike = 0.0,
        offset: ArrayLike = 0.0,
    ):
        f = param(_atleast_1d(frequencies), "frequencies", "SineSum", ndim=1)
        n = jnp.shape(f)[0]
        self.frequencies = f
        self.amplitudes = param(_broadcast(amplitudes, n), "amplitudes", "SineSum", ndim=1)
        self.phases = param(_broadcast(phases, n), "phases", "SineSum", ndim=1)
        self.offset = param(offset, "offset", "SineSum")

    def __check_init__(self):
        n = jnp.shape(self.frequencies)[0]
        for name in ("amplitudes", "phases"):
            if jnp.shape(getattr(self, name)) != (n,):
                raise InputError(
                    f"SineSum: argument {name!r} must have one value per frequency, shape ({n},),"
                    f" got {jnp.shape(getattr(self, name))}."
                )
        check_positive(self.frequencies, "frequencies", "SineSum", "Frequencies are in Hz, > 0.")
        check_finite(self.amplitudes, "amplitudes", "SineSum")
        check_finite(self.phases, "phases", "SineSum")
        check_finite(self.offset, "offset", "SineSum")

    def __call__(self, t):
        t = jnp.asarray(t, jnp.result_type(float))
        arg = 2 * jnp.pi * self.frequencies * t[..., None] + self.phases
        return self.offset + jnp.sum(self.amplitudes * jnp.sin(arg), axis=-1)


def multisine(
    frequencies: ArrayLike,
    amplitudes: ArrayLike,
    *,
    phases: Literal["random", "schroeder"] = "random",
    key: PRNGKeyArray | None = None,
    offset: ArrayLike = 0.0,
) -> SineSum:
    """A multisine F(t) = F_off + Σⱼ Aⱼ·sin(2π fⱼ t + φⱼ) with random or Schroeder phases.

    Arguments:
        frequencies: fⱼ [Hz], shape ``(n,)``; use multiples of 1/T_record for a periodic record.
        amplitudes: Aⱼ [N], scalar or shape ``(n,)``.
        phases: ``"random"``: φⱼ ~ U[0, 2π) drawn from ``key`` (seeded, vmappable over keys);
            ``"schroeder"``: φⱼ = −π·j(j − 1)/n, j = 1 … n (Schroeder 1970, low crest factor for
            equal amplitudes; deterministic, ``key`` unused).
        key: JAX PRNG key, required for random phases.
        offset: F_off [N].

    Returns:
        a :class:`SineSum`.
    """
    f = _atleast_1d(frequencies)
    n = jnp.shape(f)[0]
    if phases == "random":
        if key is None:
            raise InputError(
                "multisine: argument 'key' is required for phases='random', got None. Pass "
                "key=jax.random.key(seed), or phases='schroeder'."
            )
        phi = jax.random.uniform(key, (n,), jnp.result_type(float), 0.0, 2 * jnp.pi)
    elif phases == "schroeder":
        j = np.arange(1, n + 1, dtype=np.float64)
        phi = -np.pi * j * (j - 1) / n
    else:
        raise InputError(
            f"multisine: argument 'phases' must be 'random' or 'schroeder', got {phases!r}."
        )
    return SineSum(amplitudes, f, phi, offset)


class Chirp(AbstractExcitation):
    """A swept sine over [0, T]: F(t) = F_off + A·sin(ψ(t) + φ) for 0 ≤ t ≤ T, F_off outside.

    Linear sweep: f(t) = f₀ + (f₁ − f₀)·t/T,    ψ(t) = 2π·(f₀t + (f₁ − f₀)t²/(2T)).
    Log sweep:    f(t) = f₀·(f₁/f₀)^(t/T),      ψ(t) = 2π·f₀T/ln(f₁/f₀)·((f₁/f₀)^(t/T) − 1).

    Attributes:
        amplitude: A [N], shape ``()``.
        f0, f1: start and end frequencies [Hz], shape ``()``, > 0 (f₀ ≠ f₁ for a log sweep).
        duration: T [s], shape ``()``, > 0.
        kind: ``"linear"`` or ``"log"`` (static).
        phase: φ [rad], shape ``()`` (default 0).
        offset: F_off [N], shape ``()`` (default 0).
    """

    amplitude: Float[ArrayLike, ""]
    f0: Float[ArrayLike, ""]
    f1: Float[ArrayLike, ""]
    duration: Float[ArrayLike, ""]
    kind: Literal["linear", "log"] = eqx.field(static=True)
    phase: Float[ArrayLike, ""]
    offset: Float[ArrayLike, ""]

    def __init__(
        self,
        amplitude: ArrayLike,
        f0: ArrayLike,
        f1: ArrayLike,
        duration: ArrayLike,
        kind: Literal["linear", "log"] = "linear",
        phase: ArrayLike = 0.0,
        offset: ArrayLike = 0.0,
    ):
        self.amplitude = param(amplitude, "amplitude", "Chirp")
        self.f0 = param(f0, "f0", "Chirp")
        self.f1 = param(f1, "f1", "Chirp")
        self.duration = param(duration, "duration", "Chirp")
        self.kind = kind
        self.phase = param(phase, "phase", "Chirp")
        self.offset = param(offset, "offset", "Chirp")

    def __check_init__(self):
        if self.kind not in ("linear", "log"):
            raise InputError(
                f"Chirp: argument 'kind' must be 'linear' or 'log', got {self.kind!r}."
            )
        check_positive(self.f0, "f0", "Chirp", "Frequencies are in Hz, > 0.")
        check_positive(self.f1, "f1", "Chirp", "Frequencies are in Hz, > 0.")
        check_positive(self.duration, "duration", "Chirp")
        check_finite(self.amplitude, "amplitude", "Chirp")
        if self.kind == "log":
            f0, f1 = concrete(self.f0), concrete(self.f1)
            if f0 is not None and f1 is not None and np.any(f0 == f1):
                raise InputError(
                    f"Chirp: a log sweep needs f0 != f1, got f0 = f1 = {f0.tolist()}. Use "
                    "SineSum for a single frequency."
                )

    def phase_at(self, t: Float[ArrayLike, "*shape"]) -> Float[Array, "*shape"]:
        """The sweep phase ψ(t) [rad] (without φ)."""
        t = jnp.asarray(t, jnp.result_type(float))
        T = self.duration
        if self.kind == "linear":
            return 2 * jnp.pi * (self.f0 * t + (self.f1 - self.f0) * t**2 / (2 * T))
        ratio = self.f1 / self.f0
        return 2 * jnp.pi * self.f0 * T / jnp.log(ratio) * jnp.expm1(t / T * jnp.log(ratio))

    def __call__(self, t):
        t = jnp.asarray(t, jnp.result_type(float))
        inside = (t >= 0) & (t <= self.duration)
        tc = jnp.clip(t, 0, self.duration)
        return self.offset + jnp.where(
            inside, self.amplitude * jnp.sin(self.phase_at(tc) + self.phase), 0.0
        )


# Feedback taps (1-based, XOR Fibonacci LFSR) of maximal-length sequences, from the standard
# tables (e.g. Xilinx XAPP052); each gives period 2**order − 1.
_LFSR_TAPS = {
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 6, 4, 1),
    13: (13, 4, 3, 1),
    14: (14, 5, 3, 1),
    15: (15, 14),
    16: (16, 15, 13, 4),
}


def _mls(order: int, key: PRNGKeyArray) -> Int[Array, " P"]:
    """One period of a maximal-length sequence (bits 0/1) from an LFSR seeded by ``key``."""
    taps = np.asarray(_LFSR_TAPS[order]) - 1
    seed = jax.random.randint(key, (), 1, 2**order)  # any non-zero register state
    state = (seed >> jnp.arange(order)) & 1

    def step(reg, _):
        new = jnp.bitwise_xor.reduce(reg[taps]) if len(taps) > 1 else reg[taps[0]]
        return jnp.concatenate([new[None], reg[:-1]]), reg[-1]

    _, bits = jax.lax.scan(step, state, None, length=2**order - 1)
    return bits.astype(jnp.int32)


class PRBS(AbstractExcitation):
    """Pseudo-random binary sequence: F(t) = F_off ± A, switching only at multiples of the clock.

    One period of a maximal-length LFSR sequence of the given order (period P = 2^order − 1
    clock periods, P/2 + 1/2 ones: nearly flat spectrum up to about 0.4/clock_period Hz), repeated.
    The key picks the initial register (a cyclic shift of the sequence), so it is seeded and
    deterministic. The level at time t is bit ⌊t/T_c⌋ mod P, with sample times within a few
    rounding errors of a switching instant counted as after it.

    Attributes:
        amplitude: A [N], shape ``()``.
        clock_period: T_c [s], shape ``()``, > 0 (use a multiple of the sample interval).
        bits: one period of the sequence, shape ``(P,)``, values 0/1.
        offset: F_off [N], shape ``()`` (default 0).
    """

    amplitude: Float[ArrayLike, ""]
    clock_period: Float[ArrayLike, ""]
    bits: Int[Array, " P"]
    offset: Float[ArrayLike, ""]

    def __init__(
        self,
        amplitude: ArrayLike,
        clock_period: ArrayLike,
        key: PRNGKeyArray,
        order: int = 10,
        offset: ArrayLike = 0.0,
    ):
        if order not in _LFSR_TAPS:
            raise InputError(
                f"PRBS: argument 'order' must be one of {sorted(_LFSR_TAPS)}, got {order!r}."
            )
        self.amplitude = param(amplitude, "amplitude", "PRBS")
        self.clock_period = param(clock_period, "clock_period", "PRBS")
        self.bits = _mls(order, key)
        self.offset = param(offset, "offset", "PRBS")

    def __check_init__(self):
        check_positive(self.clock_period, "clock_period", "PRBS", "e.g. 0.02 s.")
        check_finite(self.amplitude, "amplitude", "PRBS")
        check_finite(self.offset, "offset", "PRBS")

    def __call__(self, t):
        dtype = jnp.result_type(float)
        u = jnp.asarray(t, dtype) / self.clock_period
        guard = (jnp.abs(u) + 1) * 16 * jnp.finfo(dtype).eps
        idx = jnp.floor(u + guard).astype(jnp.int32) % self.bits.shape[0]
        return self.offset + self.amplitude * (2 * self.bits[idx] - 1).astype(dtype)


#: Duration of the paper's verification experiment [s].
VERIFICATION_DURATION = 1.6


class VerificationInput(AbstractExcitation):
    """The paper's verification input (sec. IV.C): F(t) = A·cos(ω·t + φ) + c·t [N], t in s.

    Defaults A = 3 N, ω = 40 rad/s, φ = 400 rad, c = 0.5 N/s, applied over
    ``VERIFICATION_DURATION`` = 1.6 s. (φ is reduced modulo 2π before use, which changes nothing
    mathematically and keeps float32 accurate.)

    Attributes:
        amplitude: A [N]; omega: ω [rad/s]; phase: φ [rad]; slope: c [N/s]; all shape ``()``.
    """

    amplitude: Float[ArrayLike, ""]
    omega: Float[ArrayLike, ""]
    phase: Float[ArrayLike, ""]
    slope: Float[ArrayLike, ""]

    def __init__(
        self,
        amplitude: ArrayLike = 3.0,
        omega: ArrayLike = 40.0,
        phase: ArrayLike = 400.0,
        slope: ArrayLike = 0.5,
    ):
        self.amplitude = param(amplitude, "amplitude", "VerificationInput")
        self.omega = param(omega, "omega", "VerificationInput")
        self.phase = param(phase, "phase", "VerificationInput")
        self.slope = param(slope, "slope", "VerificationInput")

    def __check_init__(self):
        for name in ("amplitude", "omega", "phase", "slope"):
            check_finite(getattr(self, name), name, "VerificationInput")

    def __call__(self, t):
        t = jnp.asarray(t, jnp.result_type(float))
        phase = jnp.mod(jnp.asarray(self.phase, t.dtype), 2 * jnp.pi)
        return self.amplitude * jnp.cos(self.omega * t + phase) + self.slope * t


#: The paper's operating points x₁, x₂, x₃ [m] (Table 2).
PAPER_OPERATING_POINTS = (-0.020, 0.0, 0.020)

#: Four distinct sine sets for the paper's "four sine inputs per operating point", designed for
#: the centring PD (K_p = 200 N/m, K_d = 1 N·s/m) around an operating point. Closed-loop gain
#: |x/F| of eq. (13) is ≈ 5 mm/N up to 2 Hz in region 2, so each set moves the axis ≈ ±4–5 mm
#: (region 2; ±2.5–5 mm in regions 1 and 3), staying within one region:
#:
#: 1. 0.8 N at 0.5 Hz (slow, nearly quasi-static);
#: 2. 0.9 N at 1.5 Hz (near the closed-loop bandwidth);
#: 3. 0.5 N at 0.7 Hz + 0.5 N at 3.1 Hz, phases (0, π/2);
#: 4. 0.35 N at 1.0 Hz + 0.35 N at 2.3 Hz + 0.6 N at 4.7 Hz, phases (0, π/2, π).
PAPER_SINE_SETS: tuple[SineSum, ...] = (
    SineSum(0.8, 0.5),
    SineSum(0.9, 1.5),
    SineSum((0.5, 0.5), (0.7, 3.1), (0.0, math.pi / 2)),
    SineSum((0.35, 0.35, 0.6), (1.0, 2.3, 4.7), (0.0, math.pi / 2, math.pi)),
)


__all__ = [
    "AbstractExcitation",
    "Chirp",
    "PAPER_OPERATING_POINTS",
    "PAPER_SINE_SETS",
    "PRBS",
    "SineSum",
    "VERIFICATION_DURATION",
    "VerificationInput",
    "multisine",
]
