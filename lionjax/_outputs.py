"""What the batched estimator accumulates while it streams: the output accumulator Modules.

:func:`lionjax.lion_batched` never stores the regressors; everything it reports besides θ(T) is
accumulated sample by sample inside its fused kernel. Each quantity is an *accumulator* Module
passed in ``outputs=(...)``:

- :class:`LSStatistics`: ΦᵀΦ, Φᵀy, yᵀy and the sample count after the filter transient, so
  θ_LS = −(ΦᵀΦ)⁻¹Φᵀy (= ``lionjax.least_squares(..., initial="discard")``) needs no regressor;
- :class:`ConvergenceTime`: the last sample at which θ is outside the ``tolerance`` band around
  a reference (θ_LS by default) and a smooth surrogate of that time (for gradients);
- :class:`TailStatistics`: Σθ, Σθ² over the last quarter of each record (noise in θ);
- :class:`Trajectory`: θ every ``every`` samples.

An accumulator says what it keeps and how (abstract :meth:`AbstractOutput.init`,
:meth:`~AbstractOutput.update`, :meth:`~AbstractOutput.finalise`); the kernel loops over the
requested ones inside its one per-sample step, so adding one adds only its own work. Its state
is an :class:`Accumulated` (``carry``: values carried from sample to sample; ``sums``: running
sums, which the kernel adds up per slab of samples for accuracy). :meth:`~AbstractOutput.finalise`
turns the state into a result Module (:class:`LSResult`, :class:`ConvergenceResult`,
:class:`TailResult`, :class:`TrajectoryResult`), found on the solution by
``solution.output(LSStatistics)``.

Accumulators that need no estimate (``needs_theta = False``: :class:`LSStatistics`) run in a
statistics pass before the estimation pass, since a data-dependent gain (:class:`AutoGain`:
G = rate·R⁻¹, R = ΦᵀΦ/n) and the default reference of :class:`ConvergenceTime` need θ_LS first.
"""

# No ``from __future__ import annotations``: equinox reads AbstractVar annotations at runtime.
import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from equinox import AbstractClassVar, AbstractVar
from jaxtyping import Array, ArrayLike, Float, PyTree

from ._errors import InputError
from ._filters import FilterBank
from ._least_squares import gram_lstsq
from ._solution_tools import (
    band_scale,
    default_transient,
    outside_band,
    relative_errors,
    settle_time,
)


class Accumulated(eqx.Module):
    """The state of one accumulator in the kernel (every array has the batch axis last).

    Attributes:
        carry: values carried from sample to sample (e.g. the last sample outside the band).
        sums: running sums; the kernel accumulates them per slab of samples and adds the slab's
            partial sums to the totals (shorter sums in float32).
    """

    carry: PyTree
    sums: PyTree


@dataclasses.dataclass(frozen=True)
class Context:
    """What accumulators see outside the kernel (batch axis first; trace-time only).

    Attributes:
        dtype: the records' float dtype; p, names: the parameters.
        dt: sampling interval per record [s], ``(B,)``; t0: first sample time [s], ``(B,)``.
        length: valid samples per record, ``(B,)`` (T where not padded).
        bank: the filter (``coeffs`` ``(n,)`` or ``(B, n)``).
        least_squares: the streamed LS answer (:class:`LSResult`) once the statistics pass has
            run, else None.
    """

    dtype: Any
    p: int
    names: tuple[str, ...]
    dt: Array
    t0: Array
    length: Array
    bank: FilterBank
    least_squares: "LSResult | None" = None


class Sample:
    """One step k → k+1 of the kernel, as accumulators see it (trace-time, batch last).

    Attributes:
        k: the step's first sample index (int32 scalar; the new sample is k + 1).
        active: (Bs,) bool, False on padding samples (``lengths``), or None (no padding).
        h: the sampling interval [s] (scalar, or (Bs,) with one dt per record).
        dtype: the float dtype.
    """

    def __init__(self, k, active, h, dtype, end, theta):
        self.k, self.active, self.h, self.dtype = k, active, h, dtype
        self._end, self._theta, self._cache = end, theta, {}

    def end_regressors(self) -> tuple[list[Array], list[Array], Array, Array]:
        """(W1, W2, y1, y2) at sample k + 1 (rows of W, p arrays each, and W₀), computed once."""
        if "end" not in self._cache:
            self._cache["end"] = self._end()
        return self._cache["end"]

    def theta(self) -> list[Array]:
        """θ after the step (p arrays); only in the estimation pass."""
        if self._theta is None:
            raise InputError("Sample.theta: no estimate in the statistics pass (needs_theta).")
        if "theta" not in self._cache:
            self._cache["theta"] = self._theta()
        return self._cache["theta"]

    def weight(self, first: Array) -> Array:
        """1.0 where sample k + 1 is at or after index ``first`` (per record) and real."""
        w = (self.k + 1 >= first).astype(self.dtype)
        return w if self.active is None else w * self.active.astype(self.dtype)


class AbstractOutput(eqx.Module):
    """An accumulator streamed by :func:`lionjax.lion_batched` (module docstring).

    Concrete accumulators are final classes; the kernel calls, per batch of rows, ``init``
    once, ``update`` at every sample and, outside the kernel, ``finalise`` once.
    """

    #: False: accumulated in the statistics pass, before any estimate exists.
    needs_theta: AbstractClassVar[bool]
    #: Samples between snapshots of θ handed to :meth:`finalise` (None: no snapshots).
    every: AbstractVar[int | None]

    @property
    @abc.abstractmethod
    def needs_least_squares(self) -> bool:
        """Whether :meth:`prepare` needs the LS answer (``Context.least_squares``)."""

    @abc.abstractmethod
    def prepare(self, ctx: Context) -> PyTree:
        """Per-record inputs of the kernel, every array with the batch axis first (or None)."""

    @abc.abstractmethod
    def init(self, inputs: PyTree, p: int, theta0: list[Array] | None, zero: Array) -> Accumulated:
        """The state before the first step; ``inputs`` as from :meth:`prepare` (batch last),
        p the number of parameters, ``theta0`` the initial estimate (p arrays; None in the
        statistics pass), ``zero`` a (Bs,) array of zeros of the float dtype."""

    @abc.abstractmethod
    def update(self, state: Accumulated, sample: Sample, inputs: PyTree) -> Accumulated:
        """The state after one more sample (elementwise over the rows)."""

    @abc.abstractmethod
    def finalise(self, state: Accumulated, ctx: Context, snapshots: Array | None) -> eqx.Module:
        """The result Module from the final state (batch first); ``snapshots`` θ every
        ``every`` samples, ``(B, K, p)``, when ``every`` is set."""


# ----------------------------------------------------------------------------------------------
# Least squares


class LSResult(eqx.Module):
    """The least-squares answer from streamed statistics, per record (B records, p parameters).

    Attributes:
        theta: θ_LS = −(ΦᵀΦ)⁻¹Φᵀy, ``(B, p)``.
        covariance: σ²(ΦᵀΦ)⁻¹, σ² = RSS/(N − p), N = 2·n_used rows (as
            :func:`lionjax.least_squares`), ``(B, p, p)``; std: √diag, ``(B, p)``.
        condition: condition number of the column-normalised ΦᵀΦ's square root, i.e. of Φ
            (inf if ΦᵀΦ is singular), ``(B,)``.
        rms: root-mean-square equation error ``(B,)``; n_used: samples in the sums ``(B,)``.
        moments: R = ΦᵀΦ/n_used, the mean regressor outer product (what gains see), ``(B, p, p)``.
    """

    theta: Float[Array, "B p"]
    covariance: Float[Array, "B p p"]
    std: Float[Array, "B p"]
    condition: Float[Array, " B"]
    rms: Float[Array, " B"]
    n_used: Float[Array, " B"]
    moments: Float[Array, "B p p"]
    free_condition: Float[Array, " B"] | None = None
    free_weakest: Float[Array, "B q"] | None = None


class LSStatistics(AbstractOutput):
    """Stream ΦᵀΦ, Φᵀy, yᵀy over the samples at or after ``transient`` seconds from each
    record's start (regressors at the samples, as :func:`lionjax.least_squares` with
    ``initial="discard"``); finalised to an :class:`LSResult`.

    Attributes:
        transient: [s], a number or one per record ``(B,)``; default 3·λₙ₋₁/λₙ of each filter.
            Also the window of a data-dependent gain's R and of :class:`ConvergenceTime`'s
            default reference.
        free_response: also stream the cross products with the filter's n free responses N
            (the initial-state error's columns, :meth:`lionjax.FilterBank.free_response`: ΦᵀN,
            NᵀN, Nᵀy, N carried as the powers of the filter's map, Φ_fᵏ⁺¹ = Φ_f·Φ_fᵏ), and
            report the condition number and weakest direction of [Φ, N] (``free_condition``,
            ``free_weakest``): after the transient a parameter excited only through the free
            response is not identified by the record (:func:`lionjax.least_squares`' check with
            ``initial="discard"``).
    """

    transient: float | Array | None = None
    free_response: bool = eqx.field(static=True, default=False)
    needs_theta: ClassVar[bool] = False
    every: ClassVar[None] = None

    @property
    def needs_least_squares(self) -> bool:
        return False

    def prepare(self, ctx):
        dtype, dt = ctx.dtype, ctx.dt
        if self.transient is None:
            tr = default_transient(ctx.bank).astype(dtype)
        else:
            tr = jnp.asarray(self.transient, dtype)
        if tr.ndim > 1 or (tr.ndim == 1 and tr.shape != dt.shape):
            raise InputError(
                f"LSStatistics: transient must be seconds, a number or one per record "
                f"{dt.shape}, got shape {tr.shape}."
            )
        tr = jnp.broadcast_to(tr, dt.shape)
        # first k with k·dt ≥ tr, computed as lionjax.lion's transient mask does
        kk = jnp.ceil(tr / dt)
        kk = jnp.where(dt * (kk - 1) >= tr, kk - 1, kk)
        kk = jnp.where(dt * kk < tr, kk + 1, kk)
        first = jnp.maximum(kk, 0).astype(jnp.int32)
        if not self.free_response:
            return first
        return (first, *_free_maps(ctx))

    @staticmethod
    def _size(p: int) -> int:
        return p * (p + 1) // 2 + p + 2  # ΦᵀΦ (upper), Φᵀy, yᵀy, count

    def init(self, inputs, p, theta0, zero):
        if not self.free_response:
            return Accumulated(None, [zero] * self._size(p))
        n = _order(inputs[1])
        eye = [zero + float(i == j) for i in range(n) for j in range(n)]  # Φ_f⁰ = I
        return Accumulated(eye, [zero] * (self._size(p) + p * n + n * (n + 1) // 2 + n))

    def update(self, state, sample, inputs):
        W1, W2, y1, y2 = sample.end_regressors()
        p = len(W1)
        first = inputs[0] if self.free_response else inputs
        w = sample.weight(first)  # statistics of sample k+1 (sample 0 is in every transient)
        terms = [W1[i] * W1[j] + W2[i] * W2[j] for i in range(p) for j in range(i, p)]
        terms += [W1[i] * y1 + W2[i] * y2 for i in range(p)] + [y1 * y1 + y2 * y2, 1.0]
        carry = state.carry
        if self.free_response:
            carry, (N1, N2) = _free_step(state.carry, inputs[1], inputs[2])
            n = len(N1)
            terms += [W1[j] * N1[i] + W2[j] * N2[i] for j in range(p) for i in range(n)]
            terms += [N1[i] * N1[m] + N2[i] * N2[m] for i in range(n) for m in range(i, n)]
            terms += [N1[i] * y1 + N2[i] * y2 for i in range(n)]
        return Accumulated(carry, [a + w * t for a, t in zip(state.sums, terms, strict=True)])

    def finalise(self, state, ctx, snapshots):
        stats = jnp.stack(state.sums, -1)
        p = ctx.p
        out = _ls_result(stats[:, : self._size(p)], p)
        if not self.free_response:
            return out
        n = ctx.bank.order
        fit = jax.vmap(gram_lstsq)(*_augmented(stats, p, n), 2 * out.n_used)
        return dataclasses.replace(out, free_condition=fit.condition, free_weakest=fit.weakest)


def _order(flat) -> int:
    """n from the n² entries of a flattened n × n matrix (a list or an array)."""
    return int(round(len(flat) ** 0.5))


def _free_maps(ctx) -> tuple[Array, Array]:
    """Per record: the filter's sampled map Φ_f (B, n²) and the rows C₁, C₂ of V₁, V₂
    (B, 2n), from which the kernel steps the free responses."""
    B, n = ctx.dt.shape[0], ctx.bank.order
    coeffs = jnp.broadcast_to(ctx.bank.coeffs, (B, n))

    def maps(c, h):
        bank = dataclasses.replace(ctx.bank, coeffs=c)
        Phi, _, _ = bank.discretise(h)
        _, _, C, _ = bank.state_space()
        return Phi.reshape(-1), C[:2].reshape(-1)

    Phi, C = jax.vmap(maps)(coeffs, ctx.dt)
    return Phi.astype(ctx.dtype), C.astype(ctx.dtype)


def _free_step(Z, Phi, C):
    """Φ_fᵏ⁺¹ = Φ_f·Φ_fᵏ (``Z``: n² lanes, row major) and the free responses' V₁, V₂ at sample
    k + 1 (n lanes each): column i of C·Φ_fᵏ⁺¹ (:meth:`FilterBank.free_response`)."""
    n = _order(Z)
    Zn = [sum(Phi[i * n + m] * Z[m * n + j] for m in range(n)) for i in range(n) for j in range(n)]
    N1 = [sum(C[m] * Zn[m * n + i] for m in range(n)) for i in range(n)]
    N2 = [sum(C[n + m] * Zn[m * n + i] for m in range(n)) for i in range(n)]
    return Zn, (N1, N2)


def _augmented(stats: Array, p: int, n: int):
    """(Gram, cross, yᵀy) of [Φ, N] from the streamed sums (B, m) of :class:`LSStatistics`."""
    q = p + n
    B = stats.shape[0]
    A = jnp.zeros((B, q, q), stats.dtype)
    idx = 0
    for i in range(p):
        for j in range(i, p):
            A = A.at[:, i, j].set(stats[:, idx]).at[:, j, i].set(stats[:, idx])
            idx += 1
    cross = stats[:, idx : idx + p]
    yy = stats[:, idx + p]
    idx = LSStatistics._size(p)
    for j in range(p):
        for i in range(n):
            A = A.at[:, j, p + i].set(stats[:, idx]).at[:, p + i, j].set(stats[:, idx])
            idx += 1
    for i in range(n):
        for m in range(i, n):
            A = A.at[:, p + i, p + m].set(stats[:, idx]).at[:, p + m, p + i].set(stats[:, idx])
            idx += 1
    cross = jnp.concatenate([cross, stats[:, idx : idx + n]], axis=-1)
    return A, cross, yy


def _ls_result(stats: Array, p: int) -> LSResult:
    """The :class:`LSResult` of statistics ``(B, m)`` (ΦᵀΦ upper, Φᵀy, yᵀy, count), solved by
    :func:`lionjax.linear_lstsq`'s spectral step on ΦᵀΦ (two rows, ε₁ and ε₂, per sample)."""
    npp = p * (p + 1) // 2
    A = jnp.zeros(stats.shape[:-1] + (p, p), stats.dtype)
    idx = 0
    for i in range(p):
        for j in range(i, p):
            A = A.at[..., i, j].set(stats[..., idx]).at[..., j, i].set(stats[..., idx])
            idx += 1
    n_used = stats[:, -1]
    fit = jax.vmap(gram_lstsq)(A, stats[:, npp : npp + p], stats[:, -2], 2 * n_used)
    sigma2 = fit.rss / jnp.clip(2 * n_used - p, 1.0, None)
    cov = sigma2[:, None, None] * fit.gram_inverse
    return LSResult(
        theta=fit.coef,
        covariance=cov,
        std=jnp.sqrt(jnp.clip(jnp.diagonal(cov, axis1=-2, axis2=-1), 0.0, None)),
        condition=fit.condition,
        rms=jnp.sqrt(fit.rss / jnp.clip(2 * n_used, 1.0, None)),
        n_used=n_used,
        moments=A / jnp.clip(n_used, 1.0, None)[:, None, None],
    )


# ----------------------------------------------------------------------------------------------
# Convergence time


class ConvergenceResult(eqx.Module):
    """The convergence time per record (B records).

    Attributes:
        t_converged: seconds from the record start after which every
            |θᵢ − θ_refᵢ| ≤ tolerance·|θ_refᵢ| until the end; ``inf`` if θ is outside the band
            at the last sample, ``(B,)``.
        time_outside: its smooth surrogate [s], Σₖ h·σ((log rₖ − log tol)/s) over the samples,
            rₖ² = Σᵢ rᵢ⁴/Σᵢ rᵢ² (a smooth max over parameters of the relative errors
            rᵢ = (θᵢ − θ_refᵢ)/|θ_refᵢ|), s = ``softness``, ``(B,)``.
        reference: θ_ref, ``(B, p)``.
    """

    t_converged: Float[Array, " B"]
    time_outside: Float[Array, " B"]
    reference: Float[Array, "B p"]


class _BandInputs(eqx.Module):
    reference: Array  # (B, p) outside the kernel, (p, Bs) inside
    scale: Array  # 1/|θ_ref|, same shape


class ConvergenceTime(AbstractOutput):
    """Track the convergence time: the first time after which θ stays within ``tolerance`` of
    ``reference`` until the end of the record (the one definition of lionjax:
    :meth:`lionjax.solutions.LionSolution.convergence_time` evaluates it on a stored trajectory),
    and its smooth surrogate; finalised to a :class:`ConvergenceResult`.

    Attributes:
        reference: θ_ref, ``(p,)`` or ``(B, p)``; None (default): each record's streamed LS
            answer (:class:`LSStatistics`, with its transient when one is among the outputs).
        tolerance: the relative band, in (0, 1) (default 0.02 = 2 %).
        softness: width s > 0 of the surrogate's sigmoid in log relative error (default 0.25).
    """

    reference: Float[ArrayLike, "*B p"] | None = None
    tolerance: float | Array = 0.02
    softness: float | Array = 0.25
    needs_theta: ClassVar[bool] = True
    every: ClassVar[None] = None

    def __check_init__(self):
        for name, ok, want in (
            ("tolerance", lambda v: 0 < v < 1, "in (0, 1) (0.02 = 2 %)"),
            ("softness", lambda v: v > 0, "> 0"),
        ):
            v = getattr(self, name)
            if not isinstance(v, jax.core.Tracer) and not (jnp.ndim(v) == 0 and ok(float(v))):
                raise InputError(f"ConvergenceTime: {name} must be a number {want}, got {v!r}.")

    @property
    def needs_least_squares(self) -> bool:
        return self.reference is None

    def _reference(self, ctx):
        B = ctx.dt.shape[0]
        if self.reference is None:
            ref = ctx.least_squares.theta
        else:
            ref = jnp.asarray(self.reference, ctx.dtype)
            if ref.shape not in ((ctx.p,), (B, ctx.p)):
                raise InputError(
                    f"ConvergenceTime: reference must have shape ({ctx.p},) or ({B}, {ctx.p}) "
                    f"for parameters {ctx.names}, got {ref.shape}."
                )
            ref = jnp.broadcast_to(ref, (B, ctx.p))
        return jnp.where(jnp.isfinite(ref), ref, 0.0)

    def prepare(self, ctx):
        ref = self._reference(ctx)
        return _BandInputs(ref, jnp.stack(band_scale(list(ref.T)), -1))

    def init(self, inputs, p, theta0, zero):
        ref, scale = list(inputs.reference), list(inputs.scale)
        out0 = outside_band(relative_errors(theta0, ref, scale), self.tolerance)
        return Accumulated(jnp.where(out0, 0, -1).astype(jnp.int32), zero)

    def update(self, state, sample, inputs):
        th = sample.theta()
        rel = relative_errors(th, list(inputs.reference), list(inputs.scale))
        out = outside_band(rel, self.tolerance)
        if sample.active is not None:
            out = out & sample.active
        last_out = jnp.where(out, sample.k + 1, state.carry)
        # smooth max over parameters: r² = Σ rᵢ⁴ / Σ rᵢ² ≤ max rᵢ²
        tiny = jnp.finfo(sample.dtype).tiny
        r2 = sum(r * r for r in rel)
        r4 = sum(r * r * r * r for r in rel)
        lr = 0.5 * jnp.log(r4 / (r2 + tiny) + tiny)
        sig = jax.nn.sigmoid((lr - jnp.log(self.tolerance)) / self.softness)
        h = sample.h
        wk = h if sample.active is None else h * sample.active.astype(sample.dtype)
        return Accumulated(last_out, state.sums + wk * sig)

    def finalise(self, state, ctx, snapshots):
        t = settle_time(state.carry, ctx.length, lambda i: i.astype(ctx.dtype) * ctx.dt)
        return ConvergenceResult(t, state.sums, self._reference(ctx))


# ----------------------------------------------------------------------------------------------
# Tail statistics


class TailResult(eqx.Module):
    """Mean and standard deviation of θ(t) over the last quarter of each record, ``(B, p)``
    (in the units of θ; the population standard deviation: the noise θ keeps once converged)."""

    mean: Float[Array, "B p"]
    std: Float[Array, "B p"]


class TailStatistics(AbstractOutput):
    """Stream Σθ, Σθ² and the count over the samples from ⌊3·length/4⌋ on (the last quarter of
    each record); finalised to a :class:`TailResult`."""

    needs_theta: ClassVar[bool] = True
    every: ClassVar[None] = None

    @property
    def needs_least_squares(self) -> bool:
        return False

    def prepare(self, ctx):
        return (3 * ctx.length) // 4

    def init(self, inputs, p, theta0, zero):
        return Accumulated(None, [zero] * (2 * p + 1))

    def update(self, state, sample, inputs):
        th = sample.theta()
        wt = sample.weight(inputs)
        tl = [wt * a for a in th] + [wt * a * a for a in th] + [wt]
        return Accumulated(None, [a + b for a, b in zip(state.sums, tl, strict=True)])

    def finalise(self, state, ctx, snapshots):
        p = ctx.p
        tail = jnp.stack(state.sums, -1)
        wsum = jnp.clip(tail[:, -1:], 1.0, None)
        mean = tail[:, :p] / wsum
        std = jnp.sqrt(jnp.clip(tail[:, p : 2 * p] / wsum - mean**2, 0.0, None))
        return TailResult(mean, std)


# ----------------------------------------------------------------------------------------------
# Trajectory


class TrajectoryResult(eqx.Module):
    """θ every ``every`` samples: ``t`` [s] ``(K,)`` (times of the first record: t₀ + k·h for
    k = every, 2·every, …), ``theta`` ``(K, B, p)``."""

    t: Float[Array, " K"]
    theta: Float[Array, "K B p"]


class Trajectory(AbstractOutput):
    """Keep θ every ``every`` samples (exactly: the kernel's slab length becomes the largest
    divisor of ``every`` not above ``Execution.chunk``); finalised to a
    :class:`TrajectoryResult`. Memory ``(T/every, B, p)``.

    Attributes:
        every: samples between saved estimates, a positive int.
    """

    every: int = eqx.field(static=True)
    needs_theta: ClassVar[bool] = True

    def __check_init__(self):
        if not (isinstance(self.every, int) and self.every >= 1):
            raise InputError(f"Trajectory: every must be a positive int, got {self.every!r}.")

    @property
    def needs_least_squares(self) -> bool:
        return False

    def prepare(self, ctx):
        return None

    def init(self, inputs, p, theta0, zero):
        return Accumulated(None, None)

    def update(self, state, sample, inputs):
        return state

    def finalise(self, state, ctx, snapshots):
        traj = jnp.moveaxis(snapshots, 0, 1)  # (B, K, p) → (K, B, p)
        K = traj.shape[0]
        t0 = ctx.t0.reshape(-1)[0]
        t = t0 + ctx.dt[0] * self.every * jnp.arange(1, K + 1, dtype=ctx.dtype)
        return TrajectoryResult(t, traj)
