"""The fast batched estimator: a streaming, fused filter + Lion kernel over many records.

Layer 1 (core). :func:`lion_batched` runs Lion's law θ̇ = −G Wᵀε / (1 + μ‖W‖²) (a per-sample
stepper of :mod:`lionjax._estimators`, the exact step by default) over a batch of B records in
one jitted call, without ever storing the regressors: every record's filter states z (n per raw
signal) and θ are carried from sample to sample, so memory is O(B) whatever the record length T.
Everything else it reports is accumulated in the same stream by the output accumulators of
:mod:`lionjax._outputs` (least-squares statistics, convergence time, tail statistics, a
decimated trajectory), passed as ``outputs=(...)``; :func:`least_squares_batched` is the
statistics pass alone (no estimate, no gain).

The call is made of strategy Modules, as diffrax's ``diffeqsolve`` is: the filter
(:class:`lionjax.FilterBank`, one per record when its ``coeffs`` are ``(B, n)``), the gain
(:class:`lionjax.AbstractGain`, one per record when its value is ``(B,)``), the stepper
(:class:`lionjax.extend.AbstractSampleStepper`, which owns the normalisation μ), the outputs and the
performance knobs (:class:`Execution`).

Performance (measured on the 2-core CPU, B = 4096, T = 8000, float32). One kernel
(:func:`_kernel`) serves every option, each adding work only when asked for:

- the records are read in their own ``(B, T)`` layout, one ``(C + 1)``-sample slab per block
  transposed in cache (C = ``Execution.chunk``, 128): the batch is never transposed as a whole;
- the carry is flat (B,) arrays in typed Modules; the filter update and the regressors at the
  step's midpoint come from linear maps of (z_k, u_k, u_{k+1}) precomputed per filter
  (:func:`_maps`), so the θ step never recomputes the filter; with a shared filter the states
  are carried in the midpoint basis w = λₙ(I + Φ)z/2, where each midpoint output V₁…V_n is
  wⱼ plus its input terms (two products instead of n + 2);
- XLA:CPU has no multi-output fusion and re-computes a shared value inside every consumer; the
  θ increments are therefore packed in complex pairs and divided by a runtime 1 (it never
  duplicates an expensive producer, :func:`lionjax._phi.materialise`), and θ itself is carried
  in complex pairs, so the whole step is one fusion updated in place. Where no accumulator
  reads θ the increments' guard multiplies them as reals (XLA's complex division costs about
  ten vector divisions per record and sample);
- one filter per record (``FilterBank`` coeffs ``(B, n)``, or one ``dt`` per record): the
  kernel reads the compact per-record filter (Φ, Γ₀, Γ₁, λ: :class:`_Filter`) and forms the
  outputs at the step's start, midpoint and end from z_k and z_{k+1}, instead of the composed
  maps of every signal (free as shared scalars; as per-record arrays five times the reads);
- E(hS) by its series alone while tr(hS) ≤ 1/2 (a free guard: beyond it the guard is NaN and
  the record comes back non-finite), the records that fail re-run with the closed form
  (``Execution(phi="series")``, the default);
- one CPU device runs independent loops concurrently, so the batch is split into one loop per
  core over its own rows (:func:`_split_kernel`, no copy; ``Execution.split``); with several
  host devices the records are laid out over them as views of their memory
  (:func:`shard_records`, done by :func:`lion_batched` itself for unplaced records) and
  sharded with ``jax.shard_map`` (``Execution.shard``) — on the 2-core machine of 2026-11-24
  2.6–3.1× the one-device loops, which lose time handing each step's fusions between threads.

Together (2026-11-24, one run of ``benchmarks/throughput.py``, 2-core Xeon with AVX-512):
402 M sample-updates/s on records as they come over two host devices, 130 on one device;
numba's scalar kernel of the same law and algebra, 132.

The exact step (:mod:`lionjax._phi`). With S = W G Wᵀ (2×2 symmetric PSD), over one interval h
with frozen W: θ ← θ − h·G Wᵀ E(hS) (Wθ + W₀), E(Z) = (I − e^{−Z}) Z⁻¹, the same function
(:func:`lionjax._phi.phi_sym2`) as in :func:`lionjax.lion`.

Parallel in time: θₖ₊₁ = Aₖθₖ + cₖ is linear, Aₖ = I − hGWₖᵀE Wₖ, cₖ = −hGWₖᵀE W₀ₖ, so
:func:`lion_parallel` composes the affine maps with ``lax.associative_scan`` (O(log T) depth,
for long records on accelerators; it stores the regressors).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec
from jaxtyping import Array, ArrayLike, Float, Int

from ._errors import RESULTS, IdentificationError, InputError
from ._estimators import AbstractGain, AbstractSampleStepper, AutoGain, ExactStep, default_bank
from ._filters import FilterBank
from ._kernel_core import (
    _Core,
    _filter,
    _Inputs,
    _maps,
    _midpoint_basis,
    _Out,
    _Plan,
    _State,
)
from ._linalg import matmul, matvec
from ._models import AbstractModel
from ._outputs import (
    AbstractOutput,
    Accumulated,
    Context,
    ConvergenceTime,
    LSResult,
    LSStatistics,
    TailStatistics,
    Trajectory,
)
from ._pallas import pallas_kernel
from ._phi import fast_series_terms, phi_sym2
from ._record import Record
from ._scan import affine_scan, filter_states
from ._solution_tools import by_name, finish, is_traced, transient_mask
from ._validity import (
    MAX_MOMENT_CONDITION,
    batch_reference,
    check_duration,
    check_filter_speed,
    check_padding,
    check_record,
    check_theta0,
    column_reference,
    confirm_raw_unexcited,
    dead_columns,
    explain_unexcited,
    flag_bad_data,
    not_identified,
    raw_unexcited,
    unexcited,
    unexcited_names,
)

# ----------------------------------------------------------------------------------------------
# Devices


def host_devices(n: int | None = None) -> int:
    """Ask XLA for ``n`` host (CPU) devices (default: the number of cores), before JAX starts.

    Not needed for speed on one machine: :func:`lion_batched` already uses every core of one
    CPU device (``split``). Host devices are for sharding records placed once with
    :func:`shard_records` (measured faster for data estimated many times) and for testing the
    sharded path. This only edits ``XLA_FLAGS`` and has no effect once JAX's backend is
    initialised. Returns the count asked.
    """
    n = (os.cpu_count() or 1) if n is None else int(n)
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()
    return n


def shard_records(records: Record) -> Record:
    """Place a batch of records in the layout :func:`lion_batched` shards it into: the batch axis
    of ``x``, ``F`` (and of ``(B,)`` ``dt``/``t0``) split over ``jax.local_devices()``.

    On CPU host devices share the memory, so each device's rows are a view of the batch where
    the rows start on 64-byte boundaries (no copy: 0.2 ms for a 131 MB signal, against
    0.07–0.3 s copied); :func:`lion_batched` places unplaced records this way itself. Elsewhere
    the records are copied onto the devices: do it once for data that is estimated several
    times. With one device, or a batch that is not a multiple of the device count, the records
    come back unchanged.
    """
    if not isinstance(records, Record) or records.x.ndim != 2:
        raise InputError(
            "shard_records: expected a batch Record with x of shape (B, T), got "
            f"{type(records).__name__}"
            + (f" with x of shape {records.x.shape}" if isinstance(records, Record) else "")
            + ". Stack records with lionjax.stack_records."
        )
    placed = _place_views(records)
    if placed is not None:
        return placed
    mesh = _mesh()
    if mesh is None or records.x.shape[0] % mesh.size:
        return records
    from jax.sharding import NamedSharding

    return _by_batch(
        records,
        lambda a, spec: jax.device_put(a, NamedSharding(mesh, spec)),
    )


def _by_batch(records: Record, place) -> Record:
    """``place(leaf, spec)`` on the leaves with the batch axis first ((B, T) and (B,))."""
    B = records.x.shape[0]
    row = PartitionSpec("batch", None)
    return jax.tree.map(
        lambda a: (
            place(a, row)
            if a.ndim == 2 and a.shape[0] == B
            else place(a, PartitionSpec("batch"))
            if a.ndim == 1 and a.shape[0] == B
            else a
        ),
        records,
    )


def _place_views(records: Record) -> Record | None:
    """``records`` over the host devices as views of their memory (CPU), or None where that is
    not possible without a copy: not CPU, fewer than two devices, a batch that is not a multiple
    of the device count, arrays that are traced, already spread over devices, or whose
    per-device rows would not start on 64-byte boundaries (the host buffer's alignment, below
    which the runtime copies). Each device's rows are checked to alias the batch's memory."""
    mesh = _mesh()
    if mesh is None or jax.default_backend() != "cpu":
        return None
    B = records.x.shape[0]
    n = mesh.size
    if B % n:
        return None
    big = [a for a in jax.tree.leaves(records) if getattr(a, "ndim", 0) == 2 and a.shape[0] == B]
    for a in big:
        if isinstance(a, jax.core.Tracer) or not isinstance(a, jax.Array | np.ndarray):
            return None
        if isinstance(a, jax.Array) and len(a.sharding.device_set) > 1:
            return None
    from jax.sharding import NamedSharding

    devs = list(mesh.devices.flat)
    aliased = True

    def place(a, spec):
        nonlocal aliased
        if a.ndim == 1:  # (B,) per-record scalars: a copy costs nothing
            return jax.device_put(a, NamedSharding(mesh, spec))
        h = np.asarray(a)
        m = h.shape[0] // n
        if not h.flags.c_contiguous or h.ctypes.data % 64 or h[:m].nbytes % 64:
            aliased = False  # the runtime would copy a device's rows: no view possible
            return a
        parts = [jax.device_put(h[i * m : (i + 1) * m], d) for i, d in enumerate(devs)]
        aliased &= all(
            p.unsafe_buffer_pointer() == h[i * m :].ctypes.data for i, p in enumerate(parts)
        )
        return jax.make_array_from_single_device_arrays(h.shape, NamedSharding(mesh, spec), parts)

    placed = _by_batch(records, place)
    return placed if aliased else None


def _shard_here(records: Record, shard: bool) -> tuple[Record, bool]:
    """(records, shard) for this call. On CPU records already laid out over the devices
    (:func:`shard_records`) are sharded, and so are records that can be laid out as views of
    their memory (:func:`_place_views`: no copy); others run on one device, the batch split into
    loops over its cores (copying them over the devices costs about as much as it saves). On
    accelerators always (one device would leave the others idle)."""
    if not shard or _mesh() is None or jax.default_backend() != "cpu":
        return records, shard
    x = records.x
    if isinstance(x, jax.core.Tracer) or not isinstance(x, jax.Array):
        return records, True  # traced (inside an outer jit): the layout is the caller's
    if len(x.sharding.device_set) > 1:
        return records, True
    placed = _place_views(records)
    return (records, False) if placed is None else (placed, True)


def _mesh() -> Mesh | None:
    devs = jax.local_devices()
    if len(devs) < 2:
        return None
    return Mesh(np.array(devs), ("batch",))


# ----------------------------------------------------------------------------------------------
# Execution

#: Kernel implementations :class:`Execution` accepts (``"auto"``: the best for the backend).
KERNELS = ("auto", "xla", "pallas")
_BLOCK = 128  # samples per slab read from the (B, T) records (transposed in cache, per block)


class Execution(eqx.Module):
    """How :func:`lion_batched` and :func:`least_squares_batched` run: the performance knobs
    (results are the same, to rounding, whatever they are).

    Attributes:
        chunk: samples per slab read from the ``(B, T)`` records per inner loop (default 128;
            each slab is transposed in cache, the batch never is as a whole).
        split: independent loops per device, each over its own rows of the batch (XLA:CPU runs
            them concurrently: this is how one CPU device uses every core without copying the
            records). None (default): on CPU the cores per device (≥ 64 records per loop),
            else 1.
        shard: shard the batch over ``jax.local_devices()`` (default True; the batch size must
            be a multiple of the device count, else it runs unsharded). On CPU host devices
            records are sharded when already placed by :func:`shard_records` or when they can
            be laid out over the devices as views of their memory (rows starting on 64 bytes:
            no copy); others run on one device, whose ``split`` loops use the cores.
        kernel: the kernel implementation, one of :data:`KERNELS`: ``"auto"`` (default:
            ``"xla"`` everywhere), ``"xla"`` (the fused XLA loop) or ``"pallas"`` (the whole
            time loop in one Pallas kernel, one record per lane: :mod:`lionjax._pallas`; off a
            GPU it runs in Pallas' interpret mode — slow, for testing). On an H200 the Pallas
            kernel agrees with the XLA loop bitwise and runs 1.65–23× faster on batches, 46× on
            one long record (``benchmarks/results/2026-11-27_gpu_h200.md``): pass ``"pallas"``
            on a GPU. ``"auto"`` does not choose it there until that choice has run on one.
        phi: how E(hS) = (I − e^{−hS})(hS)⁻¹ is evaluated: ``"series"`` (default: its series
            alone, 8 terms in float32, 14 in float64, while tr(hS) ≤ 1/2 — truncation below the
            unit roundoff — and the records where some sample exceeds the bound, or θ is not
            finite, re-run with the closed form, gathered B/16 at a time: one closed-form
            program, compiled once; a loop, so forward-mode differentiable only) or
            ``"closed"`` (the closed form throughout; also for reverse-mode gradients).
    """

    chunk: int = eqx.field(static=True, default=_BLOCK)
    split: int | None = eqx.field(static=True, default=None)
    shard: bool = eqx.field(static=True, default=True)
    kernel: str = eqx.field(static=True, default="auto")
    phi: Literal["series", "closed"] = eqx.field(static=True, default="series")

    def __check_init__(self):
        if self.kernel not in KERNELS:
            raise InputError(
                f"Execution: kernel must be one of {KERNELS}, got {self.kernel!r}. Use "
                "kernel='auto' (the best kernel for the backend)."
            )
        if not (isinstance(self.chunk, int) and self.chunk >= 1):
            raise InputError(
                f"Execution: chunk must be a positive int (samples per slab), got {self.chunk!r}."
            )
        if self.split is not None and not (isinstance(self.split, int) and self.split >= 1):
            raise InputError(
                f"Execution: split must be a positive int (loops per device) or None, got "
                f"{self.split!r}."
            )
        if not isinstance(self.shard, bool):
            raise InputError(f"Execution: shard must be True or False, got {self.shard!r}.")
        if self.phi not in ("series", "closed"):
            raise InputError(
                f"Execution: phi must be 'series' (fast, with a closed-form fallback) or "
                f"'closed', got {self.phi!r}."
            )

    def kernel_function(self):
        """The kernel implementation this resolves to (``"auto"``: ``"xla"``; see ``kernel``)."""
        kernel = "xla" if self.kernel == "auto" else self.kernel
        if kernel == "pallas":
            return pallas_kernel
        return _split_kernel


#: The default :class:`Execution` (every knob at its default).
DEFAULT_EXECUTION = Execution()


# ----------------------------------------------------------------------------------------------
# Solutions


class BatchedSolution(eqx.Module):
    """What :func:`lion_batched` returns for a batch of B records (p parameters).

    Attributes:
        theta: final estimates θ(T), shape ``(B, p)``.
        J: final cost ½εᵀε at the last sample, shape ``(B,)``.
        gain: the gain matrices G, shape ``(B, p, p)``.
        outputs: the finalised accumulators, one per ``outputs`` argument and in its order
            (:class:`lionjax.solutions.LSResult`, :class:`lionjax.solutions.ConvergenceResult`,
            :class:`lionjax.solutions.TailResult`, :class:`lionjax.solutions.TrajectoryResult`);
            by type with            :meth:`output`, or through the shortcuts below.
        kinds: the accumulator types of ``outputs``.
        names: parameter names; result: a :class:`RESULTS` code per record, ``(B,)``.

    Shortcuts (each raises :class:`InputError` naming the accumulator when it was not
    requested): ``theta_ls``, ``ls_condition`` (:class:`LSStatistics`); ``theta_ref``,
    ``t_converged``, ``time_outside`` (:class:`ConvergenceTime`); ``tail_mean``, ``tail_std``
    (:class:`TailStatistics`); ``t_saved``, ``trajectory`` (:class:`Trajectory`).
    """

    theta: Float[Array, "B p"]
    J: Float[Array, " B"]
    gain: Float[Array, "B p p"]
    outputs: tuple[eqx.Module, ...]
    kinds: tuple[type, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS
    unexcited: Array | None = None  # (B, p): parameters a record does not identify

    def params(self) -> dict[str, Array]:
        """Final estimates by name, each ``(B,)``."""
        return by_name(self.names, self.theta)

    def output(self, kind: type[AbstractOutput]) -> eqx.Module:
        """The finalised accumulator of type ``kind`` (e.g. ``sol.output(lj.LSStatistics)``
        is the :class:`lionjax.solutions.LSResult`)."""
        for k, out in zip(self.kinds, self.outputs, strict=True):
            if k is kind:
                return out
        name = getattr(kind, "__name__", repr(kind))
        raise InputError(
            f"BatchedSolution: no {name} output; lion_batched ran with outputs "
            f"{tuple(k.__name__ for k in self.kinds)}. Pass outputs=(..., lionjax.{name}()) to "
            "lion_batched."
        )

    @property
    def theta_ls(self) -> Float[Array, "B p"]:
        """The streamed LS answer ``(B, p)`` (:class:`LSStatistics`)."""
        return self.output(LSStatistics).theta

    @property
    def ls_condition(self) -> Float[Array, " B"]:
        """Condition number of the column-normalised Φ, ``(B,)`` (:class:`LSStatistics`)."""
        return self.output(LSStatistics).condition

    @property
    def theta_ref(self) -> Float[Array, "B p"]:
        """The reference of the convergence time ``(B, p)`` (:class:`ConvergenceTime`)."""
        return self.output(ConvergenceTime).reference

    @property
    def t_converged(self) -> Float[Array, " B"]:
        """Convergence time [s], ``inf`` if not settled (:class:`ConvergenceTime`)."""
        return self.output(ConvergenceTime).t_converged

    @property
    def time_outside(self) -> Float[Array, " B"]:
        """Smooth surrogate of ``t_converged`` [s] (:class:`ConvergenceTime`)."""
        return self.output(ConvergenceTime).time_outside

    @property
    def tail_mean(self) -> Float[Array, "B p"]:
        """Mean of θ(t) over the last quarter of each record (:class:`TailStatistics`)."""
        return self.output(TailStatistics).mean

    @property
    def tail_std(self) -> Float[Array, "B p"]:
        """Standard deviation of θ(t) over the last quarter (:class:`TailStatistics`)."""
        return self.output(TailStatistics).std

    @property
    def t_saved(self) -> Float[Array, " K"]:
        """Times of the decimated trajectory [s] (:class:`Trajectory`)."""
        return self.output(Trajectory).t

    @property
    def trajectory(self) -> Float[Array, "K B p"]:
        """θ every ``Trajectory.every`` samples, ``(K, B, p)`` (:class:`Trajectory`)."""
        return self.output(Trajectory).theta


class LSBatchedSolution(eqx.Module):
    """Batch least squares from streamed sufficient statistics (:func:`least_squares_batched`).

    Attributes:
        theta: θ_LS = −(ΦᵀΦ)⁻¹Φᵀy, shape ``(B, p)``.
        covariance: σ²(ΦᵀΦ)⁻¹ with σ² = RSS/(N − p), N = 2·n_used rows (as
            :func:`lionjax.least_squares`), ``(B, p, p)``; std: its diagonal's square root.
        condition: condition number of the column-normalised Φ (inf if ΦᵀΦ is singular), ``(B,)``.
        rms: root-mean-square equation error, ``(B,)``; n_used: samples used, ``(B,)``;
        names; result: :class:`RESULTS` per record.
    """

    theta: Float[Array, "B p"]
    covariance: Float[Array, "B p p"]
    std: Float[Array, "B p"]
    condition: Float[Array, " B"]
    rms: Float[Array, " B"]
    n_used: Float[Array, " B"]
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS
    unexcited: Array | None = None  # (B, p): parameters a record does not identify

    def params(self) -> dict[str, Array]:
        return by_name(self.names, self.theta)


# ----------------------------------------------------------------------------------------------
# The kernel (one shard; batch axis last on every per-record array)


def _split_kernel(plan: _Plan, X, shared: _Inputs, per: _Inputs, parts: int) -> _Out:
    """:func:`_kernel` over ``parts`` row ranges of the batch as independent loops in one program.

    XLA:CPU runs independent loops concurrently, one per core, so this is how one device uses
    every core — without copying the records: each loop reads its rows of the same ``(B, T)``
    buffers. (Sharding a single-device batch over host devices instead copies it every call:
    measured 0.06–0.17 s per 131 MB signal, about half of the run at 4096 × 8000.)
    """
    Bs = X[0].shape[0]
    cuts = [Bs * i // parts for i in range(parts + 1)]
    outs = [
        _kernel(plan, X, shared, jax.tree.map(lambda a, r0=r0, r1=r1: a[..., r0:r1], per), (r0, r1))
        for r0, r1 in zip(cuts[:-1], cuts[1:], strict=True)
        if r1 > r0
    ]
    return jax.tree.map(lambda *a: jnp.concatenate(a, axis=-1), *outs)


def _kernel(plan: _Plan, X, shared: _Inputs, per: _Inputs, rows=None) -> _Out:
    """Run the records ``rows`` (default all) of the batch. ``X``: tuple of S raw signals, each
    ``(B, T)`` (the records' own layout: each slab of ``plan.block`` samples is read and
    transposed inside the loop, the whole batch never is). ``per`` holds the per-record inputs
    with the batch last (already restricted to ``rows``), ``shared`` the values common to the
    batch (scalars in the kernel), including the accumulators, whose ``init``/``update`` are
    called for the rows. Returns an :class:`_Out`, batch last."""
    r0, r1 = (0, X[0].shape[0]) if rows is None else rows
    Bs, T = r1 - r0, X[0].shape[1]
    dtype = X[0].dtype
    core = _Core(plan, shared, per, dtype)

    def run_slab(c: _State, k0, slab) -> _State:
        """``slab``: S arrays (L + 1, Bs), the samples k0 … k0 + L: L steps from sample k0."""
        L = slab[0].shape[0] - 1

        def body(j, ca):
            row = lambda i: [sl[i] for sl in slab]
            return core.step(ca[0], jnp.asarray(k0 + j, jnp.int32), row(j), row(j + 1), ca[1])

        c, part = jax.lax.fori_loop(0, L, body, (c, core.zero_sums(c)))
        return core.add_sums(c, part)

    C = plan.block
    nb, rem = divmod(T - 1, C)
    # the (C + 1)-sample slab of block i, transposed in cache (the batch never is as a whole)
    read = lambda i: tuple(jax.lax.dynamic_slice(Xs, (r0, i * C), (Bs, C + 1)).T for Xs in X)

    def blocks(c, idx):
        if idx.shape[0] == 0:
            return c
        return jax.lax.scan(lambda cc, i: (run_slab(cc, i * C, read(i)), None), c, idx)[0]

    c = core.init(jnp.zeros((Bs,), dtype))
    snapshots = None
    if plan.save_blocks:
        g = plan.save_blocks
        ng = nb // g

        def group(cc, j):
            cc = blocks(cc, j * g + jnp.arange(g))
            return cc, jnp.stack(core.from_pairs(cc.theta))

        c, snapshots = jax.lax.scan(group, c, jnp.arange(ng))
        c = blocks(c, jnp.arange(ng * g, nb))
    else:
        c = blocks(c, jnp.arange(nb))
    if rem:
        c = run_slab(c, nb * C, tuple(Xs[r0:r1, nb * C :].T for Xs in X))

    theta_out = J = None
    if plan.estimate:
        last = (per.length - 1) if plan.masked else jnp.full((Bs,), T - 1, jnp.int32)
        u_end = [Xs[r0 + jnp.arange(Bs), last] for Xs in X]
        th, J = core.final(c, u_end)
        theta_out = jnp.stack(th)
    return _Out(theta_out, J, c.valid, c.outputs, snapshots)


# ----------------------------------------------------------------------------------------------
# The stream: a batch prepared for the kernel


def _plan_for(
    model: AbstractModel, record0: Record, bank: FilterBank, align: bool = False, **flags
) -> _Plan:
    """The :class:`_Plan` of ``model``'s signals and columns; ``align``: carry the filter states
    in the midpoint basis (:func:`_midpoint_basis`) when the pass estimates θ with midpoint
    regressors (shared filter maps only: the compact per-record filter stays in z)."""
    sigs = model.signals(record0)
    if "x" not in sigs:
        raise InputError(f"{type(model).__name__}.signals must provide 'x' (for W₀).")
    names = list(sigs)
    cols = tuple((names.index(c.signal), c.order, float(c.sign)) for c in model.columns())
    for _, order, _ in cols:
        if order + 2 > 4 or order < 0:
            raise InputError("lion_batched: column orders must be 0…2 (outputs V₁…V₄).")
    if bank.order < 3:
        raise InputError(
            f"lion_batched: the filter must have order n ≥ 3 (V₄ = s³/Λ·x must be proper), "
            f"got n = {bank.order}."
        )
    aligned = align and flags.get("estimate", False) and flags.get("midpoint", True)
    return _Plan(
        signals=tuple((k, sigs[k][1]) for k in names),
        columns=cols,
        x_index=names.index("x"),
        n=bank.order,
        aligned=aligned,
        **flags,
    )


def _parts(split: int | None, rows: int, sharded: bool) -> int:
    """Independent loops per device (:func:`_split_kernel`): ``split``, or by default on CPU the
    cores per device (at least 64 records per loop), elsewhere 1."""
    if split is not None:
        return max(1, min(int(split), rows))
    if jax.default_backend() != "cpu":
        return 1
    ndev = len(jax.local_devices()) if sharded else 1
    cores = max(1, (os.cpu_count() or 1) // ndev)
    return max(1, min(cores, rows // 64))


def _slab(every: int | None, chunk: int) -> tuple[int, int]:
    """(samples per slab, slabs per snapshot): the slab divides ``every`` exactly."""
    if every is None:
        return chunk, 0
    C = max(d for d in range(1, min(chunk, every) + 1) if every % d == 0)
    return C, every // C


def _kernel_view(tree, dtype):
    """A strategy Module as the kernel sees it: scalar leaves as arrays of the records' dtype
    (runtime values, replicated over shards), per-record arrays dropped (they reach the kernel
    through the accumulators' ``prepare``, sliced with the batch)."""

    def leaf(v):
        if isinstance(v, bool | np.bool_):
            return v
        if isinstance(v, int | float) or (isinstance(v, jax.Array | np.ndarray) and v.ndim == 0):
            return jnp.asarray(v, dtype)
        return None

    return jax.tree.map(leaf, tree)


class _Stream:
    """A batch of records prepared for the kernel (trace-time): the raw signals in their
    ``(B, T)`` layout, the filter maps (shared or one per record), initial filter states, the
    :class:`Context` of the accumulators."""

    def __init__(self, model, records, bank, lengths, execution, one):
        B, T = records.x.shape
        dtype = records.x.dtype
        rec0 = jax.tree.map(lambda a: a[0] if a.ndim >= 1 else a, records)
        full = Record(
            records.x,
            records.F,
            jnp.broadcast_to(records.dt, (B,)),
            jnp.broadcast_to(records.t0, (B,)),
            records.extras,
        )
        sigs0 = model.signals(rec0)
        order = list(sigs0)  # the plan's signal order (a dict out of vmap is sorted)
        sig_vals = jax.vmap(lambda r: {k: v[0] for k, v in model.signals(r).items()})(full)
        self.X = tuple(sig_vals[k].astype(dtype) for k in order)  # (B, T), never transposed
        self.masked = lengths is not None
        dt = jnp.broadcast_to(jnp.asarray(records.dt, dtype), (B,))
        length = (
            jnp.full((B,), T, jnp.int32) if lengths is None else jnp.asarray(lengths, jnp.int32)
        )
        # filter maps: shared (one dt, one filter) or one per record
        holds = [sigs0[k][1] == "foh" for k in order]
        per_bank = bool(bank.batch_shape)
        shared_coeffs = not per_bank and jnp.ndim(records.dt) == 0
        if shared_coeffs:  # scalars in the kernel: the composed maps cost nothing to read
            maps = tuple(_maps(bank, jnp.asarray(records.dt, dtype), f) for f in holds)
        else:  # per-record arrays: the compact form, a quarter of the values read per sample
            maps = jax.vmap(_filter, in_axes=(0 if per_bank else None, 0))(bank, dt)
        maps = jax.tree.map(lambda a: jnp.asarray(a, dtype), maps)
        z0 = jnp.stack(
            [
                jax.vmap(lambda b, u0: b.steady_state(u0), in_axes=(0 if per_bank else None, 0))(
                    bank, sig_vals[k][:, 0]
                )
                for k in order
            ],
            axis=1,
        ).astype(dtype)  # (B, S, n)
        # the same in the midpoint basis w = A z (shared maps only; passes that estimate θ with
        # midpoint regressors, :func:`_plan_for`)
        self.aligned = None
        if shared_coeffs:
            lam_rev = bank.coeffs[::-1].astype(dtype)
            basis = [_midpoint_basis(m, lam_rev) for m in maps]
            w0 = jnp.stack([matvec(A, z0[:, s]) for s, (_, A) in enumerate(basis)], 1)
            self.aligned = (tuple(m for m, _ in basis), w0)
        self.per = _Inputs(
            maps=None if shared_coeffs else maps,
            h=None if shared_coeffs else dt,
            length=length,
            z0=z0,
        )
        self.shared = _Inputs(
            maps=maps if shared_coeffs else None,
            h=jnp.asarray(records.dt, dtype) if shared_coeffs else None,
            one=one,
        )
        self.ctx = Context(
            dtype=dtype,
            p=len(model.names),
            names=tuple(model.names),
            dt=dt,
            t0=jnp.broadcast_to(jnp.asarray(records.t0, dtype), (B,)),
            length=length,
            bank=bank,
        )
        self.plan = lambda **kw: _plan_for(
            model, rec0, bank, align=shared_coeffs, masked=self.masked, **kw
        )
        self.execution = execution

    def run(
        self, plan, outputs, inputs, *, theta0=None, G=None, G_shared=None, stepper=None, idx=None
    ) -> _Out:
        """The kernel over the batch (or over the records ``idx`` of it), batch-first outputs.

        ``outputs``: the accumulators of this pass; ``inputs``: their prepared per-record
        inputs (batch first); ``G``: per-record gains ``(B, p, p)`` or ``G_shared`` ``(p, p)``."""
        dtype = self.ctx.dtype
        per = dataclasses.replace(self.per, G=G, theta0=theta0, outputs=tuple(inputs))
        maps = self.shared.maps
        if plan.aligned:  # the states carried in the midpoint basis w = A z
            maps, w0 = self.aligned
            per = dataclasses.replace(per, z0=w0)
        shared = dataclasses.replace(
            self.shared,
            maps=maps,
            G=G_shared,
            outputs=tuple(_kernel_view(o, dtype) for o in outputs),
            stepper=None if stepper is None else _kernel_view(stepper, dtype),
        )
        xs = self.X
        if idx is not None:
            per = jax.tree.map(lambda a: a[idx], per)
            xs = tuple(a[idx] for a in xs)
        perT = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), per)  # batch axis last
        ex = self.execution
        mesh = _mesh() if ex.shard else None
        sharded = mesh is not None and xs[0].shape[0] % mesh.size == 0
        parts = _parts(ex.split, xs[0].shape[0] // (mesh.size if sharded else 1), sharded)
        kernel = ex.kernel_function()
        f = lambda xs, pe, sh: kernel(plan, xs, sh, pe, parts)
        if sharded:
            spec_last = lambda a: PartitionSpec(*([None] * (a.ndim - 1) + ["batch"]))
            in_specs = (
                tuple(PartitionSpec("batch", None) for _ in xs),
                jax.tree.map(spec_last, perT),
                jax.tree.map(lambda a: PartitionSpec(), shared),
            )
            out_shape = jax.eval_shape(f, xs, perT, shared)
            out_specs = jax.tree.map(
                lambda a: spec_last(a) if a.ndim else PartitionSpec(), out_shape
            )
            f = jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
        out = f(xs, perT, shared)
        return jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0) if a.ndim else a, out)

    def statistics(self, outputs) -> tuple[Accumulated, ...]:
        """The statistics pass (no estimate): the final states of ``outputs``, batch first."""
        inputs = tuple(o.prepare(self.ctx) for o in outputs)
        plan = self.plan(estimate=False, block=self.execution.chunk)
        return self.run(plan, outputs, inputs).outputs


def _result(ok, finite, valid=None):
    res = RESULTS.where(ok, RESULTS.successful, RESULTS.unidentifiable)
    if valid is not None:
        res = RESULTS.where(valid | ~ok, res, RESULTS.unstable_step)
    return RESULTS.where(finite | ~(res == RESULTS.successful), res, RESULTS.nonfinite)


# ----------------------------------------------------------------------------------------------
# Public entry points


def _check_common(what, model, records, bank, lengths, execution) -> None:
    """Argument checks shared by :func:`lion_batched` and :func:`least_squares_batched`."""
    for arg, val, typ in (
        ("model", model, AbstractModel),
        ("records", records, Record),
        ("bank", bank, FilterBank),
        ("execution", execution, Execution),
    ):
        if not isinstance(val, typ):
            raise InputError(f"{what}: {arg} must be a {typ.__name__}, got {type(val).__name__}.")
    if records.x.ndim != 2:
        raise InputError(
            f"{what}: records must be a batch with x of shape (B, T), got {records.x.shape}."
            " Stack single records with lionjax.stack_records([...])."
        )
    B = records.x.shape[0]
    if bank.batch_shape not in ((), (B,)):
        raise InputError(
            f"{what}: bank must be one filter (coeffs (n,)) or one per record (coeffs ({B}, n)) "
            f"for {B} records, got coeffs of shape {bank.coeffs.shape}."
        )
    if lengths is not None and jnp.shape(lengths) != (B,):
        raise InputError(
            f"{what}: lengths must have shape ({B},) (valid samples per record), got "
            f"{jnp.shape(lengths)}. lionjax.stack_records returns them."
        )


def lion_batched(
    model: AbstractModel,
    records: Record,
    *,
    bank: FilterBank | None = None,
    gain: AbstractGain | None = None,
    stepper: AbstractSampleStepper | None = None,
    theta0: Float[ArrayLike, "*B p"] | None = None,
    lengths: Int[ArrayLike, " B"] | None = None,
    outputs: Sequence[AbstractOutput] = (),
    execution: Execution = DEFAULT_EXECUTION,
    throw: bool = True,
) -> BatchedSolution:
    """Lion's estimator over a batch of records in one streaming, fused, sharded call.

    The same law and step as ``lionjax.lion(model, record, gain=gain, stepper=stepper)`` for
    every record (tested equal), but with the regressors never stored: memory is O(B) in the
    record length T (plus ``(T/every, B, p)`` for a :class:`Trajectory`).

    Arguments:
        model: a model structure (``MassDamper()``, ``Piecewise(...)``, ``Augmented(...)``).
        records: a batch of records, ``x``/``F`` of shape ``(B, T)``, ``dt`` and ``t0`` of
            shape ``(B,)`` or ``()`` (build with :func:`stack_records`).
        bank: the filter (default :func:`lionjax.default_bank`); ``coeffs`` of shape
            ``(B, n)`` give every record its own filter (pole studies,
            :func:`lionjax.studies.stack_banks`).
        gain: an :class:`AbstractGain`: :class:`AutoGain` (default, rate 1/s; G from a first
            streamed pass of the LS statistics) or :class:`FixedGain`; a value of shape ``(B,)``
            (``FixedGain(g)``, ``AutoGain(rate)``) gives every record its own gain.
        stepper: an :class:`AbstractSampleStepper`: ``ExactStep()`` (default;
            ``regressors="midpoint"`` or ``"zoh"``, ``normalisation=μ`` for
            θ̇ = −G Wᵀε/(1 + μ‖W‖²)) or ``EulerStep()``.
        theta0: initial estimate, ``(p,)`` or ``(B, p)`` (default zeros).
        lengths: number of valid samples per record, ``(B,)``; samples at or after a record's
            length are padding and contribute nothing (θ, filter states and sums frozen).
            Without it, a batch in which a record ends in :func:`stack_records`' padding (its
            last x and F repeated exactly over more than 1 % of the samples, under a nonzero
            force) is refused (:class:`InputError`): pass the lengths ``stack_records``
            returns (or ``np.full(B, T)`` for records that really end that way).
        outputs: accumulators streamed in the same call, each at most once:
            :class:`LSStatistics` (θ_LS, condition), :class:`ConvergenceTime` (time to within
            a tolerance of θ_LS or a given reference, and its smooth surrogate),
            :class:`TailStatistics` (mean and spread of θ over the last quarter),
            :class:`Trajectory` (θ every n samples). Found on the solution by type
            (``sol.output(LSStatistics)``) or by the shortcuts (``sol.theta_ls`` …).
        execution: the performance knobs (:class:`Execution`: slab length, loops per device,
            sharding, kernel, evaluation of E); results do not depend on them beyond rounding.
        throw: raise on failure (unexcited parameters, whatever the gain; non-finite θ; an
            unstable Euler step); with False the failures are in ``result`` per record.

    The validity layer (:mod:`lionjax._validity`): a filter too fast for the sampling warns or
    is refused (default filter: :func:`lionjax.default_bank` of the largest dt), ``theta0``
    must be finite; a record whose parameters are not all identified is ``unidentifiable``
    (from the streamed statistics R when they are computed — AutoGain, LSStatistics,
    ConvergenceTime — else from windows of the raw signals, and every sample of a record they
    flag) and ``unexcited`` names them; a failed record with non-finite or out-of-range data is
    ``nonfinite``.

    Returns:
        a :class:`BatchedSolution`.
    """
    if bank is None:
        bank = default_bank(records.dt if isinstance(records, Record) else None)
    gain = AutoGain() if gain is None else gain
    stepper = ExactStep() if stepper is None else stepper
    _check_common("lion_batched", model, records, bank, lengths, execution)
    if not isinstance(gain, AbstractGain):
        raise InputError(
            f"lion_batched: gain must be an AbstractGain (lionjax.AutoGain(rate) or "
            f"lionjax.FixedGain(g)), got {type(gain).__name__}."
        )
    if not isinstance(stepper, AbstractSampleStepper):
        raise InputError(
            f"lion_batched: stepper must be an AbstractSampleStepper (lionjax.ExactStep(), "
            f"lionjax.EulerStep()), got {type(stepper).__name__}. Use lionjax.lion for "
            "DiffraxStep (it needs the continuous signals, not samples)."
        )
    B, p = records.x.shape[0], len(model.names)
    if gain.batch_shape not in ((), (B,)):
        raise InputError(
            f"lion_batched: gain must hold one value or one per record ({B},), got batch shape "
            f"{gain.batch_shape}."
        )
    check_theta0(theta0, p, model.names, "lion_batched", batch=B)
    check_filter_speed(bank, records.dt, "lion_batched")
    lengths = check_padding("lion_batched", records, lengths)
    outputs = tuple(outputs)
    for i, o in enumerate(outputs):
        if not isinstance(o, AbstractOutput):
            raise InputError(
                f"lion_batched: outputs[{i}] must be an accumulator (lionjax.LSStatistics(), "
                "ConvergenceTime(), TailStatistics(), Trajectory(every)), got "
                f"{type(o).__name__}."
            )
    kinds = [type(o) for o in outputs]
    if len(set(kinds)) != len(kinds):
        raise InputError(
            f"lion_batched: each accumulator type at most once in outputs, got "
            f"{tuple(k.__name__ for k in kinds)}."
        )
    records, shard = _shard_here(records, execution.shard)
    execution = dataclasses.replace(execution, shard=shard)
    one = jnp.ones((), records.x.dtype)
    sol = _lion_batched(
        model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one
    )
    if not gain.uses_data:
        sol = confirm_raw_unexcited(sol, model, records, lengths)
    sol = flag_bad_data(sol, records)
    return finish(sol, throw, what="lion_batched", explain=explain_unexcited)


@eqx.filter_jit
def _lion_batched(model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one):
    # every matrix product traced here (the filter's expm, the gain's R⁻¹, the LS solve) at full
    # precision: float32 dots run at TF32 on GPUs otherwise (explicit in the jaxpr; tested)
    with jax.default_matmul_precision("highest"):
        return _lion_batched_body(
            model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one
        )


def _lion_batched_body(
    model, records, bank, gain, stepper, theta0, lengths, outputs, execution, one
):
    st = _Stream(model, records, bank, lengths, execution, one)
    ctx = st.ctx
    B = records.x.shape[0]
    p, dtype = ctx.p, ctx.dtype
    results: list[Any] = [None] * len(outputs)
    # the statistics pass: accumulators that need no estimate, and the LS answer when the gain
    # (R) or a convergence reference needs it
    pre = [i for i, o in enumerate(outputs) if not o.needs_theta]
    ls_at = next((i for i in pre if isinstance(outputs[i], LSStatistics)), None)
    need_ls = gain.uses_data or any(o.needs_least_squares for o in outputs)
    if pre or need_ls:
        accs = [outputs[i] for i in pre]
        if ls_at is None and need_ls:
            accs = [LSStatistics()] + accs  # the default window, not reported
        states = st.statistics(accs)
        done = [a.finalise(s, ctx, None) for a, s in zip(accs, states, strict=True)]
        for i, r in zip(pre, done[len(accs) - len(pre) :], strict=True):
            results[i] = r
        ls = next((r for r in done if isinstance(r, LSResult)), None)
        ctx = dataclasses.replace(ctx, least_squares=ls)
    R = (
        ctx.least_squares.moments
        if need_ls
        else jnp.broadcast_to(jnp.eye(p, dtype=dtype), (B, p, p))
    )
    G, ok = jax.vmap(lambda g, r: g(r, ctx.names), in_axes=(0 if gain.batch_shape else None, 0))(
        gain, R
    )
    G = G.astype(dtype)
    # the validity layer, whatever the gain: from the gain's R (after the transient), or for a
    # fixed gain (whose law uses every sample) from the raw signals of every sample
    if gain.uses_data:
        ref = batch_reference(model, records, bank, lengths).astype(dtype)
        unexc = jax.vmap(lambda r, f: unexcited(r, f, MAX_MOMENT_CONDITION))(R, ref)
    else:
        unexc = raw_unexcited(model, records, lengths)
    ok = ok & ~jnp.any(unexc, axis=-1)
    th0 = (
        jnp.zeros((B, p), dtype)
        if theta0 is None
        else jnp.broadcast_to(jnp.asarray(theta0, dtype), (B, p))
    )
    one_gain = not gain.uses_data and not gain.batch_shape  # scalars in the kernel
    # the estimation pass, with the accumulators that follow θ
    post = [i for i, o in enumerate(outputs) if o.needs_theta]
    accs = [outputs[i] for i in post]
    every = sorted({a.every for a in accs if a.every is not None})
    if len(every) > 1:
        raise InputError(f"lion_batched: one snapshot interval at most, got every={every}.")
    block, save_blocks = _slab(every[0] if every else None, execution.chunk)
    inputs = tuple(a.prepare(ctx) for a in accs)
    plan = lambda terms: st.plan(
        estimate=True,
        midpoint=stepper.regressors == "midpoint",
        block=block,
        save_blocks=save_blocks,
        series_terms=terms,
    )
    run = lambda pl, idx=None: st.run(
        pl,
        accs,
        inputs,
        theta0=th0,
        G=None if one_gain else G,
        G_shared=G[0] if one_gain else None,
        stepper=stepper,
        idx=idx,
    )
    if execution.phi == "series":
        # the short series where tr(hS) ≤ 1/2 (records beyond it come back non-finite), then the
        # closed form for those records only, gathered Bf at a time into a small batch (Bf: a
        # 16th of the batch, a multiple of the device count): one closed-form program, compiled
        # once, whatever the number of failures (a loop with no failure runs no iteration)
        o = run(plan(fast_series_terms(dtype)))
        bad = ~jnp.all(jnp.isfinite(o.theta), axis=-1)
        ndev = len(jax.local_devices()) if execution.shard else 1
        Bf = min(B, ndev * -(-max(1, B // 16) // ndev))
        closed = plan(0)

        def redo(carry):
            o, todo = carry
            idx = jnp.nonzero(todo, size=Bf, fill_value=-1)[0]
            idx = jnp.where(idx < 0, idx[0], idx)  # pad with a failed record (same values)
            sub = run(closed, idx)
            o = jax.tree.map(lambda a, b: a.at[idx].set(b), o, sub)
            return o, todo.at[idx].set(False)

        o, _ = jax.lax.while_loop(lambda c: jnp.any(c[1]), redo, (o, bad))
    else:
        o = run(plan(0))
    for i, a, s in zip(post, accs, o.outputs, strict=True):
        results[i] = a.finalise(s, ctx, o.snapshots if a.every is not None else None)
    finite = jnp.all(jnp.isfinite(o.theta), axis=-1)
    valid = o.valid
    result = (
        jax.vmap(_result)(ok, finite, valid) if valid is not None else jax.vmap(_result)(ok, finite)
    )
    return BatchedSolution(
        theta=o.theta,
        J=o.J,
        gain=G,
        outputs=tuple(results),
        kinds=tuple(type(a) for a in outputs),
        names=ctx.names,
        result=result,
        unexcited=unexc,
    )


def least_squares_batched(
    model: AbstractModel,
    records: Record,
    *,
    bank: FilterBank | None = None,
    lengths: Int[ArrayLike, " B"] | None = None,
    transient: float | ArrayLike | None = None,
    max_condition: float = 1e7,
    execution: Execution = DEFAULT_EXECUTION,
    throw: bool = True,
) -> LSBatchedSolution:
    """Batch least squares for B records from ΦᵀΦ, Φᵀy accumulated in one streamed pass.

    The statistics pass of :func:`lion_batched` alone (``outputs=(LSStatistics(transient),)``,
    no estimate and no gain). Equals ``lionjax.least_squares(model, record,
    initial="discard", transient=...)`` for each record (the samples of the first
    ``transient`` seconds get weight 0), without storing any regressor: memory O(B). Normal
    equations are solved on the column-normalised ΦᵀΦ (its condition number is the square of
    Φ's; in float32 prefer well-excited records).

    Arguments:
        model, records, bank, lengths, execution, throw: as :func:`lion_batched` (``bank`` one
            filter or one per record).
        transient: seconds excluded at each record's start, a number or ``(B,)`` (default
            3·λₙ₋₁/λₙ of each filter).
        max_condition: bound on cond(Φ); records at or above it are ``unidentifiable``, and so
            are records with a column that is not excited at all (:mod:`lionjax._validity`;
            ``unexcited`` names the parameters), and float64 records where cond([Φ, N]) is, N
            the filter's free responses after the transient, streamed with Φ
            (``LSStatistics(free_response=True)``: what ``least_squares(initial="discard")``
            refuses, a parameter excited only through the filter's own transient).

    The validity layer as in :func:`lion_batched` (filter speed, padding without lengths,
    failed records with bad data flagged ``nonfinite``).
    """
    if bank is None:
        bank = default_bank(records.dt if isinstance(records, Record) else None)
    _check_common("least_squares_batched", model, records, bank, lengths, execution)
    if not (max_condition > 1):
        raise InputError(
            f"least_squares_batched: max_condition must be a number > 1, got {max_condition!r}."
        )
    check_filter_speed(bank, records.dt, "least_squares_batched")
    lengths = check_padding("least_squares_batched", records, lengths)
    records, shard = _shard_here(records, execution.shard)
    execution = dataclasses.replace(execution, shard=shard)
    one = jnp.ones((), records.x.dtype)
    # [Φ, N]'s conditioning (N the filter's free responses) as least_squares(initial="discard")
    # checks it; float64 only: a float32 Gram cannot resolve that condition number
    ls = LSStatistics(transient, free_response=records.x.dtype == jnp.float64)
    sol = _least_squares_batched(model, records, bank, lengths, ls, execution, one, max_condition)
    sol = flag_bad_data(sol, records)
    return finish(sol, throw, what="least_squares_batched", explain=explain_unexcited)


@eqx.filter_jit
def _least_squares_batched(model, records, bank, lengths, ls, execution, one, max_condition):
    with jax.default_matmul_precision("highest"):  # as _lion_batched
        st = _Stream(model, records, bank, lengths, execution, one)
        (state,) = st.statistics((ls,))
        r = ls.finalise(state, st.ctx, None)
    finite = jnp.all(jnp.isfinite(r.theta), -1)
    # the validity layer: columns not excited at all fail; ill-conditioned directions named
    ref = batch_reference(model, records, bank, lengths).astype(r.moments.dtype)
    dead = jax.vmap(dead_columns)(r.moments, ref)
    bad = jax.vmap(lambda m, f: unexcited(m, f, max_condition**2))(r.moments, ref)
    ok = (r.condition < max_condition) & ~jnp.any(dead, axis=-1)
    if r.free_condition is not None:  # a parameter excited only through the free response
        free_ok = r.free_condition < max_condition
        ok = ok & free_ok
        bad = bad | (~free_ok[:, None] & (jnp.abs(r.free_weakest[:, : st.ctx.p]) > 0.3))
    return LSBatchedSolution(
        theta=r.theta,
        covariance=r.covariance,
        std=r.std,
        condition=r.condition,
        rms=r.rms,
        n_used=r.n_used,
        names=st.ctx.names,
        result=jax.vmap(_result)(ok, finite),
        unexcited=bad,
    )


def stack_records(records: Sequence[Record], pad_to: int | None = None) -> tuple[Record, Array]:
    """Stack records into one batch, padding shorter ones; returns ``(batch, lengths)``.

    Padding repeats each record's last sample, and ``lengths`` (B,) tells :func:`lion_batched`
    which samples are real: pass it on (``lion_batched(model, batch, lengths=lengths)``). A
    held force under a resting position contradicts the model, so :func:`lion_batched` and
    :func:`least_squares_batched` refuse a batch that ends in such padding without
    ``lengths``. ``dt`` and ``t0`` become ``(B,)``.
    """
    records = list(records)
    if not records:
        raise InputError("stack_records: got no records; pass at least one.")
    lens = [int(r.n_samples) for r in records]
    T = max(lens) if pad_to is None else int(pad_to)
    if T < max(lens):
        raise InputError(
            f"stack_records: pad_to={pad_to} is shorter than the longest record "
            f"({max(lens)} samples)."
        )

    def pad(a, n):
        a = np.asarray(a)
        return np.concatenate([a, np.repeat(a[-1:], T - n)]) if n < T else a

    x = np.stack([pad(r.x, n) for r, n in zip(records, lens, strict=True)])
    F = np.stack([pad(r.F, n) for r, n in zip(records, lens, strict=True)])
    dt = np.array([float(r.dt) for r in records])
    t0 = np.array([float(r.t0) for r in records])
    dtype = records[0].x.dtype
    batch = Record(
        jnp.asarray(x, dtype), jnp.asarray(F, dtype), jnp.asarray(dt, dtype), jnp.asarray(t0, dtype)
    )
    return batch, jnp.asarray(lens, jnp.int32)


# ----------------------------------------------------------------------------------------------
# Parallel in time


class ParallelSolution(eqx.Module):
    """θ at every sample from :func:`lion_parallel`: ``theta`` (T, p), ``theta_final`` (p,)."""

    theta: Float[Array, "T p"]
    theta_final: Float[Array, " p"]
    names: tuple[str, ...] = eqx.field(static=True)


def lion_parallel(
    model: AbstractModel,
    record: Record,
    G: Float[ArrayLike, "p p"],
    *,
    bank: FilterBank | None = None,
    theta0: ArrayLike | None = None,
    midpoint: bool = True,
) -> ParallelSolution:
    """Lion's exact-step estimator for one record, parallel in time (``lax.associative_scan``).

    Both recurrences are parallel: the filter bank (z_{k+1} = Φz_k + Γu, time-invariant:
    :func:`lionjax._scan.filter_states`) and the estimate, θₖ₊₁ = Aₖθₖ + cₖ,
    Aₖ = I − h·GWₖᵀE(hSₖ)Wₖ, cₖ = −h·GWₖᵀE(hSₖ)W₀ₖ (Wₖ the midpoint regressors, as
    :class:`lionjax.ExactStep`), a prefix product of affine maps composed pairwise:
    (A₂, c₂)∘(A₁, c₁) = (A₂A₁, A₂c₁ + c₂). Depth O(log T) — for long records on accelerators;
    on a CPU the sequential :func:`lion_batched` is faster. Stores the regressors (memory
    O(T·p²)). The regressors are built as :func:`lion_batched` builds them (the model's signals,
    holds and columns); every small matrix product is elementwise (:mod:`lionjax._linalg`), so
    float32 runs at float32 precision on every backend. ``G`` is the gain matrix (p×p), e.g.
    from ``lionjax.lion(...).gain``. vmap it for many records.

    The validity layer runs on concrete arguments (skipped under ``jit``/``vmap``): ``theta0``
    finite, the filter's speed against dt (default :func:`lionjax.default_bank` of dt), the
    record's duration and data (:class:`InputError`), and every parameter identified
    (:class:`lionjax.IdentificationError` naming the others), as :func:`lionjax.lion`.
    """
    if bank is None and isinstance(record, Record):
        bank = default_bank(record.dt)
    if isinstance(record, Record) and isinstance(bank, FilterBank) and not bank.batch_shape:
        check_theta0(theta0, len(model.names), model.names, "lion_parallel")
        check_filter_speed(bank, record.dt, "lion_parallel")
        check_duration(record, bank, "lion_parallel")
        check_record(record, "lion_parallel")
    sol, bad = _lion_parallel_jit(model, record, G, bank, theta0, midpoint)
    if not is_traced(bad) and np.any(np.asarray(bad)):
        raise IdentificationError(
            f"lion_parallel: {not_identified(unexcited_names(sol.names, bad))} Use a richer "
            "excitation, fewer parameters, or region bounds the record visits."
        )
    return sol


@eqx.filter_jit
def _lion_parallel_jit(model, record, G, bank, theta0, midpoint):
    with jax.default_matmul_precision("highest"):  # any dot a model traces (tests/test_parallel)
        return _lion_parallel(model, record, G, bank, theta0, midpoint)


def _lion_parallel(model, record, G, bank, theta0, midpoint):
    bank = default_bank(record.dt) if bank is None else bank
    if bank.batch_shape:
        raise InputError(
            "lion_parallel: one record, one filter (coeffs (n,)); vmap lion_parallel over "
            f"records and banks for many, got coeffs of shape {bank.coeffs.shape}."
        )
    dtype = jnp.asarray(record.x).dtype
    plan = _plan_for(model, record, bank, masked=False, block=1)
    sigs = model.signals(record)
    h = jnp.asarray(record.dt, dtype)

    def outputs(name, hold):  # V₁ … V_{n+1} at every sample, (T, n + 1)
        u = jnp.asarray(sigs[name][0]).astype(dtype)
        z = filter_states(bank, u, record.dt, hold, dtype)
        lam_rev = bank.coeffs[::-1].astype(dtype)
        V = jnp.concatenate([z, (u - jnp.sum(z * lam_rev, -1))[:, None]], -1)
        return V * bank.coeffs[-1].astype(dtype) if bank.unit_dc_gain else V

    V = [outputs(name, hold) for name, hold in plan.signals]
    W = jnp.stack(
        [
            jnp.stack([sign * V[s][:, order + r] for s, order, sign in plan.columns], -1)
            for r in (0, 1)
        ],
        1,
    )  # (T, 2, p)
    W0 = V[plan.x_index][:, 2:4]  # (T, 2)
    p = W.shape[-1]
    if midpoint:
        Ws, W0s = 0.5 * (W[:-1] + W[1:]), 0.5 * (W0[:-1] + W0[1:])
    else:
        Ws, W0s = W[:-1], W0[:-1]
    G = jnp.asarray(G, dtype)
    GW = matmul(G, jnp.swapaxes(Ws, -1, -2))  # (T-1, p, 2)
    S = matmul(Ws, GW)  # (T-1, 2, 2)
    ep, eq, er = phi_sym2(h * S[:, 0, 0], h * 0.5 * (S[:, 0, 1] + S[:, 1, 0]), h * S[:, 1, 1])
    E = jnp.stack([jnp.stack([ep, eq], -1), jnp.stack([eq, er], -1)], -2)
    K = h * matmul(GW, E)  # (T-1, p, 2)
    A = jnp.eye(p, dtype=dtype) - matmul(K, Ws)
    c = -matvec(K, W0s)
    th0 = jnp.zeros((p,), dtype) if theta0 is None else jnp.asarray(theta0, dtype)
    thetas = jnp.concatenate([th0[None], affine_scan(A, c, th0)])
    # the validity layer (as lion): R after the transient, every parameter identified
    mask = transient_mask(record, bank).astype(dtype)
    R = jnp.sum(mask[:, None, None] * jnp.sum(W[:, :, :, None] * W[:, :, None, :], 1), 0)
    R = R / jnp.maximum(jnp.sum(mask), 1.0)
    bad = unexcited(R, column_reference(model, record, bank).astype(dtype), MAX_MOMENT_CONDITION)
    sol = ParallelSolution(theta=thetas, theta_final=thetas[-1], names=tuple(model.names))
    return sol, bad
