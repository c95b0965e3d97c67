"""The batched law as one Pallas kernel: the whole time loop inside the kernel, one record per
lane, a block of records per program (``lj.Execution(kernel="pallas")``).

Layer 1 (core). :func:`pallas_kernel` has the signature of the fused XLA loop
(:func:`lionjax._batched.kernel.split_kernel`) and runs the same per-sample work
(:class:`lionjax._kernel_core._Core`: the filter maps, the exact step, every accumulator of
:mod:`lionjax._outputs`), so every option of :func:`lionjax.lion_batched` is supported: fixed
and auto gain (one per record too), per-record filters and sampling intervals, ``lengths``,
:class:`~lionjax.LSStatistics`, :class:`~lionjax.ConvergenceTime`,
:class:`~lionjax.TailStatistics`, :class:`~lionjax.Trajectory`, both steppers, the
series/closed-form evaluation of E. Differences from the XLA loop, all for GPU kernels:

- θ is carried as p real arrays (no complex pairs) and the increments' guard multiplies as a real
  number (:func:`lionjax._phi.real_guard`);
- the records are transposed once to ``(T, B)`` outside the kernel, so a program reads each
  sample of its block of records as one contiguous row (``x_ref[k, :]``: R consecutive values,
  coalesced);
- each step reads only the row after next and carries the two rows it steps between (a
  register double buffer: every row is read once, and its latency overlaps a step of
  arithmetic);
- values common to the batch (the shared filter maps, G, the accumulators' scalars) are read as
  scalars from whole-array refs, per-record values as ``(rows,)`` lanes of their block;
- each record's signals at its last valid sample (for J) are gathered outside the kernel.

Sums are kept per slab of ``Execution.chunk`` samples and added to the totals per slab, and
the trajectory is saved every ``save_blocks`` slabs, exactly as in the XLA loop, so results
agree to rounding.

Backend. The kernel is pinned to Pallas' Triton backend (:data:`TRITON_PARAMS`, Triton's own
compiler parameters: the GPU lowering picks its backend by the type of ``compiler_params``,
so a change of JAX's default GPU backend cannot reroute it). Its memory pattern suits Triton
and not Mosaic GPU: a block is a ``(T, R)`` window of the records in global memory, from which
Triton loads one row per step, whereas Mosaic GPU stages whole blocks in shared memory (at
T = 8000, R = 128 and float32: 8.2 MB, against 232 KB). Whether it is compiled or interpreted
is chosen by the platform the program is lowered for (``jax.lax.platform_dependent``, not the
default backend at trace time): Triton for ``cuda`` and ``rocm``, so ``jax.export`` to
``cuda`` on a machine without GPU lowers the real kernel (tests/test_gpu_lowering.py), and
interpret mode elsewhere (slow, for testing the kernel on CPU). Where JAX has no GPU plugin at
all, nothing can be lowered for a GPU, and only the interpreted kernel is traced. A
multi-platform export that includes ``cpu`` is not possible (Pallas lowers a compiled kernel
for every platform it exports to).

Launch parameters (:data:`TRITON_PARAMS`): ``num_warps = 4``, 128 threads per program, one
record per thread for the R = 128 lanes of :data:`ROWS_GPU` (every ``(R,)`` value is one
register per thread, the fewest registers per record, and each warp reads 32 consecutive
records' sample as one 128-byte transaction in float32) — the decomposition of the CUDA
reference kernel in ``benchmarks/throughput.py``. ``num_stages = 1``: no software pipelining
by Triton; the row loads are prefetched one step ahead by the kernel itself (above), and
Triton's pipeliner would only stage those per-thread scalars through shared memory.
Unmeasured: Triton's compilation and speed need a GPU (``benchmarks/gpu_check.py``).
"""

from __future__ import annotations

import functools
import pkgutil

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pltriton

from ._kernel_core import _Core, _Out
from ._phi import real_guard

#: Records per program on a GPU (the lane block; a power of two, one record per thread).
ROWS_GPU = 128
#: Records per program in interpret mode (small: the tests cover several programs and padding).
ROWS_INTERPRET = 4
#: Triton's compiler parameters of the kernel (they also pin it to Triton; see the module
#: docstring): 4 warps = 128 threads, one per record of :data:`ROWS_GPU`; no pipelining stages.
TRITON_PARAMS = pltriton.CompilerParams(num_warps=4, num_stages=1)


@functools.cache
def _gpu_plugin() -> bool:
    """Whether JAX has a GPU plugin here (``jax_plugins.xla_cuda*`` / ``xla_rocm*``), i.e. whether
    any program can be lowered for ``cuda`` or ``rocm`` (the Triton lowering needs it)."""
    try:
        import jax_plugins
    except ImportError:
        return False
    names = [m.name for m in pkgutil.iter_modules(jax_plugins.__path__)]
    return any("cuda" in n or "rocm" in n for n in names)


def _load(ref, scalars: bool, ndim: int):
    """A ref as :class:`lionjax._kernel_core._Core` indexes it
    (:func:`lionjax._kernel_core._nested`): nested lists of scalar loads (values shared by the
    batch; a 0-d value arrives as ``(1,)``) or of ``(rows,)`` lane loads (per-record values,
    batch last)."""
    if scalars and ndim == 0:
        return ref[0]
    stop = ndim if scalars else ndim - 1

    def rec(idx):
        if len(idx) == stop:
            return ref[idx] if scalars else ref[idx + (slice(None),)]
        return [rec(idx + (i,)) for i in range(ref.shape[len(idx)])]

    return rec(())


def _pad_last(a, n: int):
    """Pad the last (batch) axis to ``n`` by repeating the last record (its results are
    dropped; repeating keeps the padding finite)."""
    extra = n - a.shape[-1]
    if not extra:
        return a
    return jnp.concatenate([a, jnp.repeat(a[..., -1:], extra, axis=-1)], axis=-1)


def pallas_kernel(plan, X, shared, per, parts=1, *, rows: int | None = None, interpret=None):
    """The batch through one Pallas kernel; arguments and result as
    :func:`lionjax._batched.kernel.split_kernel` (``parts`` is ignored: the grid of programs
    replaces the split loops). ``rows``: records per program (default :data:`ROWS_GPU` compiled,
    :data:`ROWS_INTERPRET` in interpret mode). ``interpret``: None (default) chooses by the
    platform the program is lowered for (``jax.lax.platform_dependent``): compiled by Triton
    for ``cuda`` and ``rocm``, interpret mode elsewhere; True or False forces one."""
    if interpret is None and not _gpu_plugin():
        interpret = True  # nothing here can lower for a GPU: trace the interpreted kernel only
    if interpret is not None:
        return _pallas_kernel(plan, X, shared, per, rows, interpret)
    compiled = lambda: _pallas_kernel(plan, X, shared, per, rows, False)
    return jax.lax.platform_dependent(
        cuda=compiled,
        rocm=compiled,
        default=lambda: _pallas_kernel(plan, X, shared, per, rows, True),
    )


def _pallas_kernel(plan, X, shared, per, rows, interpret: bool) -> _Out:
    B, T = X[0].shape
    S = len(X)
    dtype = X[0].dtype
    R = rows or (ROWS_INTERPRET if interpret else ROWS_GPU)
    if interpret:
        R = min(R, B)
    nprog = -(-B // R)
    Bp = nprog * R
    p = len(plan.columns)

    # each record's signals at its last valid sample (J), gathered here: (S, B)
    last = (per.length - 1) if plan.masked else jnp.full((B,), T - 1, jnp.int32)
    u_end = jnp.stack([Xs[jnp.arange(B), last] for Xs in X])

    per_leaves, per_def = jax.tree.flatten(per)
    per_leaves = [_pad_last(a, Bp) for a in per_leaves + [u_end]]
    sh_all, sh_def = jax.tree.flatten(shared)  # arrays become inputs, the rest stays static
    sh_is = [eqx.is_array(a) for a in sh_all]
    sh_leaves = [a for a, is_arr in zip(sh_all, sh_is, strict=True) if is_arr]
    sh_ndim = [a.ndim for a in sh_leaves]
    sh_leaves = [a.reshape(1) if a.ndim == 0 else a for a in sh_leaves]
    Xt = tuple(_pad_last(Xs.T, Bp) for Xs in X)  # (T, Bp): one row per sample

    C = plan.block
    nb, rem = divmod(T - 1, C)
    g = plan.save_blocks
    ng = nb // g if g else 0

    def outputs_of(core, c, u_end_rows):
        th, J = core.final(c, u_end_rows) if plan.estimate else (None, None)
        valid = None if c.valid is None else c.valid.astype(jnp.int32)
        return (th, J, valid, c.outputs)

    # the structure of the kernel's results: one small step of the same core, traced only
    # (on the padded arrays: R lanes even when B < R)
    def probe():
        per_r = jax.tree.unflatten(per_def, [a[..., :R] for a in per_leaves[:-1]])
        with real_guard():
            core = _Core(plan, shared, per_r, dtype, pairs=False)
            c = core.init(jnp.zeros((R,), dtype))
            row = lambda k: [Xs[k, :R] for Xs in Xt]
            c, part = core.step(c, jnp.int32(0), row(0), row(min(1, T - 1)), core.zero_sums(c))
            c = core.add_sums(c, part)
            return outputs_of(core, c, list(per_leaves[-1][:, :R]))

    out_struct = jax.eval_shape(probe)
    out_leaves_sd, out_def = jax.tree.flatten(out_struct)
    for sd in out_leaves_sd:
        assert sd.shape == (R,), sd.shape  # every result is one value per record

    def kernel(*refs):
        xr = refs[:S]
        i = S
        pr = refs[i : i + len(per_leaves)]
        i += len(per_leaves)
        sr = refs[i : i + len(sh_leaves)]
        i += len(sh_leaves)
        orefs = refs[i : i + len(out_leaves_sd)]
        snap_ref = refs[i + len(out_leaves_sd)] if g else None
        with real_guard():
            loaded = [_load(r, False, r.ndim) for r in pr]
            per_v = jax.tree.unflatten(per_def, loaded[:-1])
            u_end_rows = loaded[-1]
            sh_loaded = iter([_load(r, True, nd) for r, nd in zip(sr, sh_ndim, strict=True)])
            sh_v = jax.tree.unflatten(
                sh_def,
                [next(sh_loaded) if is_arr else a for a, is_arr in zip(sh_all, sh_is, strict=True)],
            )
            core = _Core(plan, sh_v, per_v, dtype, pairs=False)
            read = lambda k: [x[k, :] for x in xr]

            def run(c, k0, L):  # L steps from sample k0 (k0 + L ≤ T − 1)
                # rows k0 and k0 + 1 are read before the loop; each step reads the row after
                # next (clamped to the last sample) and uses it one step later: its
                # global-memory latency overlaps a step of arithmetic (a double buffer in
                # registers), and every row is read once
                def body(j, ca):
                    c, part, u0, u1 = ca
                    k = (k0 + j).astype(jnp.int32)
                    u2 = read(jnp.minimum(k + 2, T - 1))
                    c, part = core.step(c, k, u0, u1, part)
                    return c, part, u1, u2

                init = (c, core.zero_sums(c), read(k0), read(k0 + 1))
                c, part, _, _ = jax.lax.fori_loop(0, L, body, init)
                return core.add_sums(c, part)

            def blocks(c, b0, b1):  # the slabs b0 … b1 − 1 (none when b1 ≤ b0)
                return jax.lax.fori_loop(
                    b0, b1, lambda b, cc: run(cc, jnp.int32(C) * b.astype(jnp.int32), C), c
                )

            c = core.init(jnp.zeros((R,), dtype))
            if g:

                def group(j, cc):
                    cc = blocks(cc, j * g, j * g + g)
                    th = core.from_pairs(cc.theta)
                    for q in range(p):
                        snap_ref[j, q, :] = th[q]
                    return cc

                c = jax.lax.fori_loop(0, ng, group, c)
                c = blocks(c, ng * g, nb)
            else:
                c = blocks(c, 0, nb)
            if rem:
                c = run(c, jnp.int32(nb * C), rem)
            vals = jax.tree.leaves(outputs_of(core, c, u_end_rows))
            for r, v in zip(orefs, vals, strict=True):
                r[...] = v.astype(r.dtype)

    def lanes(a):  # a per-record array, batch last: blocks of R records
        nd = a.ndim
        return pl.BlockSpec(a.shape[:-1] + (R,), lambda i, nd=nd: (0,) * (nd - 1) + (i,))

    def whole(a):
        nd = a.ndim
        return pl.BlockSpec(a.shape, lambda i, nd=nd: (0,) * nd)

    in_specs = (
        [pl.BlockSpec((T, R), lambda i: (0, i)) for _ in Xt]
        + [lanes(a) for a in per_leaves]
        + [whole(a) for a in sh_leaves]
    )
    out_shape = [jax.ShapeDtypeStruct((Bp,), sd.dtype) for sd in out_leaves_sd]
    out_specs = [pl.BlockSpec((R,), lambda i: (i,)) for _ in out_leaves_sd]
    if g:
        out_shape.append(jax.ShapeDtypeStruct((ng, p, Bp), dtype))
        out_specs.append(pl.BlockSpec((ng, p, R), lambda i: (0, 0, i)))
    res = pl.pallas_call(
        kernel,
        out_shape=out_shape,
        grid=(nprog,),
        in_specs=in_specs,
        out_specs=out_specs,
        interpret=interpret,
        name="lion_batched",
        compiler_params=TRITON_PARAMS,
    )(*Xt, *per_leaves, *sh_leaves)
    res = [a[..., :B] for a in res]
    snapshots = res.pop() if g else None
    res = [
        a.astype(sd.dtype) if sd.dtype != a.dtype else a
        for a, sd in zip(res, out_leaves_sd, strict=True)
    ]
    th, J, valid, outs = jax.tree.unflatten(out_def, res)
    return _Out(
        theta=None if th is None else jnp.stack(th),
        J=J,
        valid=None if valid is None else valid.astype(bool),
        outputs=outs,
        snapshots=snapshots,
    )
