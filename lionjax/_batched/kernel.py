"""The kernel of :func:`lionjax.lion_batched` over one shard (batch axis last on every
per-record array): Lion's exact step and the output accumulators, sample by sample, in one
fused XLA loop.

Performance (measured on the 2-core CPU, B = 4096, T = 8000, float32). One kernel
(:func:`_kernel`; the per-sample work is :class:`lionjax._kernel_core._Core`, shared with the
Pallas kernel) serves every option, each adding work only when asked for:

- the records are read in their own ``(B, T)`` layout, one ``(C + 1)``-sample slab per block
  transposed in cache (C = ``Execution.chunk``, 128): the batch is never transposed as a whole;
- the carry is flat (B,) arrays in typed Modules; the filter update and the regressors at the
  step's midpoint come from linear maps of (z_k, u_k, u_{k+1}) precomputed per filter
  (:func:`lionjax._kernel_core._maps`), so the θ step never recomputes the filter; with a
  shared filter the states are carried in the midpoint basis w = λₙ(I + Φ)z/2, where each
  midpoint output V₁…V_n is wⱼ plus its input terms (two products instead of n + 2);
- XLA:CPU has no multi-output fusion and re-computes a shared value inside every consumer; the
  θ increments are therefore packed in complex pairs and divided by a runtime 1 (it never
  duplicates an expensive producer, :func:`lionjax._phi.materialise`), and θ itself is carried
  in complex pairs, so the whole step is one fusion updated in place. Where no accumulator
  reads θ the increments' guard multiplies them as reals (XLA's complex division costs about
  ten vector divisions per record and sample);
- one filter per record (``FilterBank`` coeffs ``(B, n)``, or one ``dt`` per record): the
  kernel reads the compact per-record filter (Φ, Γ₀, Γ₁, λ:
  :class:`lionjax._kernel_core._Filter`) and forms the outputs at the step's start, midpoint
  and end from z_k and z_{k+1}, instead of the composed maps of every signal (free as shared
  scalars; as per-record arrays five times the reads);
- E(hS) by its series alone while tr(hS) ≤ 1/2 (a free guard: beyond it the guard is NaN and
  the record comes back non-finite), the records that fail re-run with the closed form
  (``Execution(phi="series")``, the default);
- one CPU device runs independent loops concurrently, so the batch is split into one loop per
  core over its own rows (:func:`split_kernel`, no copy; ``Execution.split``); with several
  host devices the records are laid out over them as views of their memory
  (:func:`lionjax.shard_records`, done by :func:`lionjax.lion_batched` itself for unplaced
  records) and sharded with ``jax.shard_map`` (``Execution.shard``) — on the 2-core machine
  of 2026-11-24 2.6–3.1× the one-device loops, which lose time handing each step's fusions
  between threads.

Together (2026-11-24, one run of ``benchmarks/throughput.py``, 2-core Xeon with AVX-512):
402 M sample-updates/s on records as they come over two host devices, 130 on one device;
numba's scalar kernel of the same law and algebra, 132.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._kernel_core import (
    _Core,
    _Inputs,
    _Out,
    _Plan,
    _State,
)


def split_kernel(plan: _Plan, X, shared: _Inputs, per: _Inputs, parts: int) -> _Out:
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
