"""The fast batched estimator: a streaming, fused filter + Lion kernel over many records.

Layer 1 (core). :func:`lion_batched` runs Lion's law θ̇ = −G Wᵀε / (1 + μ‖W‖²) (the exact step of
:class:`lionjax.ExactStep`) over a batch of B records in one jitted call, without ever storing
the regressors: every record's filter states z (n per raw signal) and θ are carried from sample
to sample, so memory is O(B) whatever the record length T. In the same stream it can accumulate

- the least-squares sufficient statistics ΦᵀΦ, Φᵀy, yᵀy over the samples after the filter
  transient, so θ_LS = −(ΦᵀΦ)⁻¹Φᵀy needs no stored regressors either (this is exactly
  ``lionjax.least_squares(..., initial="discard")``);
- the convergence time: the first time after which every parameter stays within ``tolerance``
  (2 % by default) of a reference θ_ref (the LS answer by default);
- a smooth surrogate of that time (for gradients), and the mean and spread of θ(t) over the last
  quarter of the record (noise amplification);
- a decimated trajectory θ(t) every ``save_every`` samples.

Performance (GUIDE §9; measured on the 2-core CPU, B = 4096, T = 8000, float32). One kernel
(:func:`_kernel`) serves every option, each adding work only when asked for:

- the records are read in their own ``(B, T)`` layout, one ``(C + 1)``-sample slab per block
  transposed in cache (C = ``chunk``, 64): the batch is never transposed as a whole;
- the carry is flat (B,) arrays; the filter update and the regressors at the step's midpoint
  come from linear maps of (z_k, u_k, u_{k+1}) precomputed per filter (:func:`_maps`), so the
  θ step never recomputes the filter;
- XLA:CPU has no multi-output fusion and re-computes a shared value inside every consumer; the
  θ increments are therefore packed in complex pairs and divided by a runtime 1 (it never
  duplicates an expensive producer, :func:`lionjax._phi.materialise`), and θ itself is carried
  in complex pairs, so the whole step is one fusion updated in place;
- E(hS) by its series alone while tr(hS) ≤ 1/2 (a free guard: beyond it the divisor is 0 and
  the record comes back non-finite), the records that fail re-run with the closed form;
- one CPU device runs independent loops concurrently, so the batch is split into one loop per
  core over its own rows (:func:`_split_kernel`, no copy); records placed over several devices
  with :func:`shard_records` are sharded with ``jax.shard_map``.

Together: 107 M sample-updates/s on one device, 164 with the records placed over two host
devices (the previous design: 64–79).

The exact step (:mod:`lionjax._phi`). With S = W G Wᵀ (2×2 symmetric PSD), over one interval h
with frozen W: θ ← θ − h·G Wᵀ E(hS) (Wθ + W₀), E(Z) = (I − e^{−Z}) Z⁻¹, the same function
(:func:`lionjax._phi.phi_sym2`) as in :func:`lionjax.lion`.

Parallel in time: θₖ₊₁ = Aₖθₖ + cₖ is linear, Aₖ = I − hGWₖᵀE Wₖ, cₖ = −hGWₖᵀE W₀ₖ, so
:func:`lion_parallel` composes the affine maps with ``lax.associative_scan`` (O(log T) depth,
for long records on accelerators; it stores the regressors).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec
from jaxtyping import Array, ArrayLike, Float, Int

from ._errors import RESULTS, InputError
from ._estimators import AbstractGain, AutoGain, ExactStep, default_bank
from ._filters import FilterBank
from ._models import AbstractModel, Regressors
from ._phi import _phi_series, exact_step, materialise, phi_sym2
from ._record import Record
from ._solution import default_transient, finish

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

    Do it once for data that is estimated several times (a study, a benchmark): otherwise every
    call copies the records onto the devices (measured 0.06–0.17 s per 131 MB signal on a
    2-core CPU). With one device, or a batch that is not a multiple of the device count, the
    records come back unchanged.
    """
    if not isinstance(records, Record) or records.x.ndim != 2:
        raise InputError(
            "shard_records: expected a batch Record with x of shape (B, T), got "
            f"{type(records).__name__}"
            + (f" with x of shape {records.x.shape}" if isinstance(records, Record) else "")
            + ". Stack records with lionjax.stack_records."
        )
    mesh = _mesh()
    if mesh is None or records.x.shape[0] % mesh.size:
        return records
    from jax.sharding import NamedSharding

    B = records.x.shape[0]
    place = lambda a, spec: jax.device_put(a, NamedSharding(mesh, spec))
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


def _shard_here(records: Record, shard: bool) -> bool:
    """Whether to shard this call: on CPU only records already laid out over the devices
    (:func:`shard_records`) are sharded — copying them there costs more than the split loops of
    one device save; on accelerators always (one device would leave the others idle)."""
    if not shard or _mesh() is None or jax.default_backend() != "cpu":
        return shard
    x = records.x
    if isinstance(x, jax.core.Tracer) or not isinstance(x, jax.Array):
        return True  # traced (inside an outer jit): the layout is the caller's
    return len(x.sharding.device_set) > 1


def _mesh() -> Mesh | None:
    devs = jax.local_devices()
    if len(devs) < 2:
        return None
    return Mesh(np.array(devs), ("batch",))


# ----------------------------------------------------------------------------------------------
# Solution


class BatchedSolution(eqx.Module):
    """What :func:`lion_batched` returns for a batch of B records (p parameters).

    Attributes:
        theta: final estimates θ(T), shape ``(B, p)``.
        J: final cost ½εᵀε at the last sample, shape ``(B,)``.
        gain: the gain matrices G, shape ``(B, p, p)``.
        theta_ls: LS answer from the streamed sufficient statistics, ``(B, p)`` (None unless
            requested); ls_condition: condition number of the column-normalised ΦᵀΦ, ``(B,)``.
        theta_ref: the reference of the convergence time, ``(B, p)`` (None if not tracked).
        t_converged: seconds from the record start after which every |θᵢ − θ_refᵢ| ≤
            tolerance·|θ_refᵢ| until the end; ``inf`` if not settled at the end. ``(B,)``.
        time_outside: smooth surrogate of ``t_converged``: Σₖ h·σ((log rₖ − log tol)/s),
            rₖ = maxᵢ-smooth relative error (see :func:`lion_batched`), ``(B,)``.
        tail_mean, tail_std: mean and standard deviation of θ(t) over the last quarter of
            each record, ``(B, p)`` (noise amplification).
        t_saved: times of the decimated trajectory [s], ``(K,)`` (from the first record).
        trajectory: θ at ``t_saved``, shape ``(K, B, p)`` (None unless ``save_every``).
        names: parameter names; result: a :class:`RESULTS` code per record, ``(B,)``.
    """

    theta: Float[Array, "B p"]
    J: Float[Array, " B"]
    gain: Float[Array, "B p p"]
    theta_ls: Float[Array, "B p"] | None
    ls_condition: Float[Array, " B"] | None
    theta_ref: Float[Array, "B p"] | None
    t_converged: Float[Array, " B"] | None
    time_outside: Float[Array, " B"] | None
    tail_mean: Float[Array, "B p"] | None
    tail_std: Float[Array, "B p"] | None
    t_saved: Float[Array, " K"] | None
    trajectory: Float[Array, "K B p"] | None
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS

    def params(self) -> dict[str, Array]:
        """Final estimates by name, each ``(B,)``."""
        return {n: self.theta[..., i] for i, n in enumerate(self.names)}


# ----------------------------------------------------------------------------------------------
# The kernel (one shard; batch axis last on every per-element array)

# The hot path's φ: the series alone, E ≈ Σ_{n<K} (−Z)ⁿ/(n+1)!, valid while every tr(hS) ≤ r
# (tr ≥ ρ for the PSD hS): the remainder is ≤ rᴷ/(K+1)! — 1.1e-8 (float32, K = 8) and 4.7e-17
# (float64, K = 14) for r = 1/2, below the unit roundoff. Gains in practice stay below it
# (AutoGain(1) on the twin: tr(hS) ≈ 0.02; the benchmark's gain: ≤ 0.5 on all 4096 records).
# A sample beyond the bound turns its record non-finite on purpose (exact_step's divisor) and
# the caller re-runs those records with the closed form (:func:`phi_sym2`): results never
# depend on the bound, only the run time does.
_SERIES_BOUND = 0.5


def _fast_series_terms(dtype) -> int:
    return 8 if jnp.dtype(dtype) == jnp.float32 else 14


_BLOCK = 64  # samples per slab read from the (B, T) records (transposed in cache, per block)


class _Plan(eqx.Module):
    """Static description of one kernel run: which signals, columns and outputs."""

    signals: tuple[tuple[str, str], ...] = eqx.field(static=True)  # (name, hold)
    columns: tuple[tuple[int, int, float], ...] = eqx.field(static=True)  # (sig, order, sign)
    x_index: int = eqx.field(static=True)
    n: int = eqx.field(static=True)
    midpoint: bool = eqx.field(static=True)
    normalised: bool = eqx.field(static=True)
    estimate: bool = eqx.field(static=True)
    ls: bool = eqx.field(static=True)
    track: bool = eqx.field(static=True)
    masked: bool = eqx.field(static=True)
    block: int = eqx.field(static=True)  # samples per slab
    save_blocks: int = eqx.field(static=True)  # 0: no trajectory; else slabs between saves
    series_terms: int = eqx.field(static=True, default=0)  # 0: closed-form φ (phi_sym2)


def _maps(bank: FilterBank, dt: Array, foh: bool) -> dict[str, Array]:
    """Linear maps from (z_k, u_k, u_{k+1}) — columns ``n + 2`` — to the filter's next state and
    outputs, for one signal under its hold (exact discretisation, :meth:`FilterBank.discretise`).

    - ``"next"`` (n, n+2): z_{k+1} = Φ z_k + Γ₀ u_k + Γ₁ (u_{k+1} − u_k) (Γ₁ only under foh);
    - ``"start"``, ``"mid"``, ``"end"`` (n+1, n+2): the outputs V₁…V_{n+1} (Vⱼ = sʲ⁻¹/Λ u,
      V_{n+1} = u − Σ λ z; times λₙ under unit DC gain) at sample k, at the midpoint (state and
      input averaged over the interval: :class:`lionjax.ExactStep`'s regressors) and at k+1.

    Precomputing them keeps the per-sample work of the kernel to one dot product per output
    (the θ step never recomputes the filter update).
    """
    Phi, G0, G1 = bank.discretise(dt)
    n = bank.order
    dtype = Phi.dtype
    G1 = G1 if foh else jnp.zeros_like(G1)
    z = jnp.zeros((n, 1), dtype)
    start = jnp.concatenate([jnp.eye(n, dtype=dtype), z, z], -1)
    nxt = jnp.concatenate([Phi, (G0 - G1)[:, None], G1[:, None]], -1)
    lam_rev = bank.coeffs[::-1].astype(dtype)  # coefficient of zᵢ in V_{n+1} is λ_{n−i}

    def outputs(state, u_row):
        V = jnp.concatenate([state, (u_row - lam_rev @ state)[None]], 0)
        return V * bank.coeffs[-1] if bank.unit_dc_gain else V

    unit = lambda a, b: jnp.concatenate([jnp.zeros((n,), dtype), jnp.array([a, b], dtype)])
    return {
        "next": nxt,
        "start": outputs(start, unit(1.0, 0.0)),
        "mid": outputs(0.5 * (start + nxt), unit(0.5, 0.5)),
        "end": outputs(nxt, unit(0.0, 1.0)),
    }


def _structural(mode: str, foh: bool, n: int, row: int, col: int) -> bool:
    """Whether entry (row, col) of a :func:`_maps` matrix can be non-zero (static sparsity)."""
    if mode == "start":  # Vⱼ = z_{j−1}; V_{n+1} = u_k − Σ λ z
        return col == row if row < n else col <= n
    if col == n + 1 and not foh:  # a zoh state never sees u_{k+1}; V_{n+1} at mid/end does
        return row == n and mode != "next"
    return True


def _split_kernel(plan: _Plan, X, shared, per, parts: int):
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


def _kernel(plan: _Plan, X, shared, per, rows: tuple[int, int] | None = None):
    """Run the records ``rows`` (default all) of the batch. ``X``: tuple of S raw signals, each
    ``(B, T)`` (the records' own layout: each slab of ``plan.block`` samples is read and
    transposed inside the loop, the whole batch never is). Per-element inputs in ``per`` carry
    the batch last (already restricted to ``rows``); ``shared`` holds the values common to the
    batch (scalars in the kernel). Returns a dict of outputs, batch last."""
    S = len(X)
    r0, r1 = (0, X[0].shape[0]) if rows is None else rows
    Bs, T = r1 - r0, X[0].shape[1]
    dtype = X[0].dtype
    n, p = plan.n, len(plan.columns)
    get = lambda key: per[key] if key in per else shared[key]
    maps = [
        {k: [[M[i, j] for j in range(M.shape[1])] for i in range(M.shape[0])] for k, M in m.items()}
        for m in get("maps")
    ]
    h = get("h")
    foh = [hold == "foh" for _, hold in plan.signals]
    zero = jnp.zeros((Bs,), dtype)

    def lin(s, mode, row, z, uk, uk1):
        M = maps[s][mode][row]
        terms = [
            M[c] * (z[c] if c < n else uk if c == n else uk1)
            for c in range(n + 2)
            if _structural(mode, foh[s], n, row, c)
        ]
        return sum(terms[1:], terms[0])

    def regressors(mode, z, uk, uk1):
        """W rows (W1, W2) and W₀ = (y1, y2) from the maps, elementwise."""
        cache: dict = {}

        def V(s, j):  # j = 1…4
            if (s, j) not in cache:
                cache[s, j] = lin(s, mode, j - 1, z[s], uk[s], uk1[s])
            return cache[s, j]

        W1 = [sign * V(s, order + 1) for s, order, sign in plan.columns]
        W2 = [sign * V(s, order + 2) for s, order, sign in plan.columns]
        return W1, W2, V(plan.x_index, 3), V(plan.x_index, 4)

    if plan.estimate:
        Gm = get("G")
        Gl = [[Gm[i, j] for j in range(p)] for i in range(p)]
    if plan.track:
        ref = per["ref"]
        inv = [1.0 / jnp.where(jnp.abs(r) > 0, jnp.abs(r), 1.0) for r in ref]
        tol = shared["tol"]
        log_tol = jnp.log(tol)
    length = per["length"] if plan.masked else None
    tiny = jnp.finfo(dtype).tiny

    def phi(zp, zq, zr):
        if plan.series_terms:
            return _phi_series(zp, zq, zr, plan.series_terms)
        return phi_sym2(zp, zq, zr)

    # θ is carried as complex pairs (θ₀ + iθ₁, …): the update of a pair is one fusion

    def to_pairs(th):
        th = list(th) + ([jnp.zeros_like(th[0])] if p % 2 else [])
        return [jax.lax.complex(a, b) for a, b in zip(th[::2], th[1::2], strict=True)]

    def from_pairs(tc):
        return [f(v) for v in tc for f in (jnp.real, jnp.imag)][:p]

    def step(c, k, uk, uk1, acc):
        """Sample k → k+1 (``acc``: this slab's partial sums, added to the totals per slab)."""
        z = c["z"]
        zn = [[lin(s, "next", i, z[s], uk[s], uk1[s]) for i in range(n)] for s in range(S)]
        new = dict(c)
        acc = dict(acc)
        act = None
        if plan.masked:
            act = (k + 1) < length
            zn = [
                [jnp.where(act, a, b) for a, b in zip(zs, zo, strict=True)]
                for zs, zo in zip(zn, z, strict=True)
            ]
        new["z"] = zn
        if plan.ls:  # statistics of sample k+1 (sample 0 is inside every transient)
            W1, W2, y1, y2 = regressors("end", z, uk, uk1)
            W1, W2, y1, y2 = _split(materialise(W1 + W2 + [y1, y2], shared["one"]), p)
            w = (k + 1 >= per["tr_k"]).astype(dtype)
            if act is not None:
                w = w * act.astype(dtype)
            terms = [W1[i] * W1[j] + W2[i] * W2[j] for i in range(p) for j in range(i, p)]
            terms += [W1[i] * y1 + W2[i] * y2 for i in range(p)] + [y1 * y1 + y2 * y2, 1.0]
            acc["ls"] = [a + w * t for a, t in zip(acc["ls"], terms, strict=True)]
        if plan.estimate:
            theta = from_pairs(c["theta"])
            W1, W2, y1, y2 = regressors("mid" if plan.midpoint else "start", z, uk, uk1)
            cn = None
            if plan.normalised:
                cn = 1.0 / (1.0 + shared["mu"] * sum(v * v for v in W1 + W2))
            one = shared["one"]
            if plan.series_terms:  # the series is valid while tr(hS) ≤ bound; else 1/0 → inf
                divisor = lambda tr_hs: jnp.where(tr_hs <= _SERIES_BOUND, one, 0.0)
            else:
                divisor = one
            d = exact_step(theta, W1, W2, y1, y2, Gl, h, cn, phi=phi, divisor=divisor)
            tc = [t - v for t, v in zip(c["theta"], to_pairs(d), strict=True)]
            if act is not None:
                tc = [jnp.where(act, a, b) for a, b in zip(tc, c["theta"], strict=True)]
            new["theta"] = tc
            if plan.track:
                th = from_pairs(tc)
                rel = [(a - r) * iv for a, r, iv in zip(th, ref, inv, strict=True)]
                out = functools.reduce(jnp.logical_or, [jnp.abs(r) > tol for r in rel])
                if act is not None:
                    out = out & act
                new["last_out"] = jnp.where(out, k + 1, c["last_out"])
                # smooth max over parameters: r² = Σ rᵢ⁴ / Σ rᵢ² ≤ max rᵢ²
                r2 = sum(r * r for r in rel)
                r4 = sum(r * r * r * r for r in rel)
                lr = 0.5 * jnp.log(r4 / (r2 + tiny) + tiny)
                sig = jax.nn.sigmoid((lr - log_tol) / shared["softness"])
                wk = h if act is None else h * act.astype(dtype)
                acc["surr"] = acc["surr"] + wk * sig
                wt = (k + 1 >= per["tail_k"]).astype(dtype)
                if act is not None:
                    wt = wt * act.astype(dtype)
                tl = [wt * a for a in th] + [wt * a * a for a in th] + [wt]
                acc["tail"] = [a + b for a, b in zip(acc["tail"], tl, strict=True)]
        return new, acc

    sums: dict[str, int] = {}
    if plan.ls:
        sums["ls"] = p * (p + 1) // 2 + p + 2  # ΦᵀΦ (upper), Φᵀy, yᵀy, count
    if plan.track:
        sums["surr"] = 0
        sums["tail"] = 2 * p + 1

    def zeros_acc():
        return {k: [zero] * m if m else zero for k, m in sums.items()}

    def run_slab(c, k0, slab):
        """``slab``: S arrays (L + 1, Bs), the samples k0 … k0 + L: L steps from sample k0."""
        L = slab[0].shape[0] - 1

        def body(j, ca):
            row = lambda i: [sl[i] for sl in slab]
            return step(ca[0], jnp.asarray(k0 + j, jnp.int32), row(j), row(j + 1), ca[1])

        c, acc = jax.lax.fori_loop(0, L, body, (c, zeros_acc()))
        c = dict(c)
        for key, m in sums.items():
            c[key] = (
                [a + b for a, b in zip(c[key], acc[key], strict=True)] if m else c[key] + acc[key]
            )
        return c

    C = plan.block
    nb, rem = divmod(T - 1, C)
    # the (C + 1)-sample slab of block i, transposed in cache (the batch never is as a whole)
    read = lambda i: tuple(jax.lax.dynamic_slice(Xs, (r0, i * C), (Bs, C + 1)).T for Xs in X)

    def blocks(c, idx):
        if idx.shape[0] == 0:
            return c
        return jax.lax.scan(lambda cc, i: (run_slab(cc, i * C, read(i)), None), c, idx)[0]

    c = {"z": [[per["z0"][s, i] for i in range(n)] for s in range(S)]}
    c.update(zeros_acc())
    if plan.estimate:
        c["theta"] = to_pairs([per["theta0"][i] for i in range(p)])
        if plan.track:
            c["last_out"] = jnp.full((Bs,), -1, jnp.int32)
    traj = None
    if plan.save_blocks:
        g = plan.save_blocks
        ng = nb // g

        def group(cc, j):
            cc = blocks(cc, j * g + jnp.arange(g))
            return cc, jnp.stack(from_pairs(cc["theta"]))

        c, traj = jax.lax.scan(group, c, jnp.arange(ng))
        c = blocks(c, jnp.arange(ng * g, nb))
    else:
        c = blocks(c, jnp.arange(nb))
    if rem:
        c = run_slab(c, nb * C, tuple(Xs[r0:r1, nb * C :].T for Xs in X))

    out: dict[str, Any] = {}
    if plan.estimate:
        last = (length - 1) if plan.masked else jnp.full((Bs,), T - 1, jnp.int32)
        u_end = [Xs[r0 + jnp.arange(Bs), last] for Xs in X]
        W1, W2, y1, y2 = regressors("start", c["z"], u_end, u_end)
        th = from_pairs(c["theta"])
        e1 = sum(a * b for a, b in zip(W1, th, strict=True)) + y1
        e2 = sum(a * b for a, b in zip(W2, th, strict=True)) + y2
        out["theta"] = jnp.stack(th)
        out["J"] = 0.5 * (e1 * e1 + e2 * e2)
        if traj is not None:
            out["trajectory"] = traj
    if plan.ls:
        out["ls"] = jnp.stack(c["ls"])
    if plan.track:
        out["last_out"] = c["last_out"]
        out["surr"] = c["surr"]
        out["tail"] = jnp.stack(c["tail"])
    return out


def _solve_ls(stats: Array, p: int):
    """θ_LS, the condition number of the column-normalised ΦᵀΦ, A = ΦᵀΦ and (ΦᵀΦ)⁻¹ from the
    streamed statistics. A zero or indefinite normalised ΦᵀΦ (a flat record) has condition inf."""
    npp = p * (p + 1) // 2
    A = jnp.zeros(stats.shape[:-1] + (p, p), stats.dtype)
    idx = 0
    for i in range(p):
        for j in range(i, p):
            A = A.at[..., i, j].set(stats[..., idx]).at[..., j, i].set(stats[..., idx])
            idx += 1
    b = stats[..., npp : npp + p]
    tiny = jnp.finfo(A.dtype).tiny
    d = jnp.sqrt(jnp.clip(jnp.diagonal(A, axis1=-2, axis2=-1), tiny, None))
    An = A / d[..., :, None] / d[..., None, :]
    ev = jnp.linalg.eigvalsh(An)
    cond = jnp.where(
        ev[..., 0] > 0, jnp.sqrt(ev[..., -1] / jnp.clip(ev[..., 0], tiny, None)), jnp.inf
    )
    An_inv = jnp.linalg.inv(An)
    theta = -jnp.einsum("...ij,...j->...i", An_inv, b / d) / d
    return theta, cond, A, An_inv / d[..., :, None] / d[..., None, :]


# ----------------------------------------------------------------------------------------------
# Public entry point


def _plan_for(model: AbstractModel, record0: Record, bank: FilterBank, **flags) -> _Plan:
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
    return _Plan(
        signals=tuple((k, sigs[k][1]) for k in names),
        columns=cols,
        x_index=names.index("x"),
        n=bank.order,
        **flags,
    )


def _gain_from_R(gain: AbstractGain, R: Array, p: int, names) -> tuple[Array, Array]:
    """G from the mean of WᵀW over the record (what :class:`AutoGain` uses), per element.

    The gain Module sees regressors whose mean outer product is exactly R: W = Lᵀ with
    LLᵀ = R (one pseudo-sample), so every gain rule is reused unchanged.
    """
    L = jnp.linalg.cholesky(R + 0.0)
    regs = Regressors(jnp.swapaxes(L, -1, -2)[None], jnp.zeros((1, p), R.dtype), names)
    return gain(regs, jnp.ones((1,), R.dtype))


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


def _slab(save_every: int | None, chunk: int) -> tuple[int, int]:
    """(samples per slab, slabs per saved θ): the slab divides ``save_every`` exactly."""
    if save_every is None:
        return chunk, 0
    C = max(d for d in range(1, min(chunk, save_every) + 1) if save_every % d == 0)
    return C, save_every // C


def lion_batched(
    model: AbstractModel,
    records: Record,
    *,
    bank: FilterBank | None = None,
    gain: AbstractGain | None = None,
    stepper: ExactStep | None = None,
    normalisation: float | None = None,
    theta0: ArrayLike | None = None,
    lengths: Int[ArrayLike, " B"] | None = None,
    ls: bool = False,
    convergence: bool = False,
    theta_ref: ArrayLike | None = None,
    tolerance: float = 0.02,
    softness: float = 0.25,
    transient: float | ArrayLike | None = None,
    save_every: int | None = None,
    chunk: int = _BLOCK,
    batched_bank: bool = False,
    batched_gain: bool = False,
    shard: bool = True,
    split: int | None = None,
    throw: bool = True,
    fast: bool = True,
) -> BatchedSolution:
    """Lion's estimator over a batch of records in one streaming, fused, sharded call.

    The same law and step as ``lionjax.lion(model, record, stepper=ExactStep())`` for every
    record (tested equal), but with the regressors never stored: memory is O(B) in the record
    length T (plus ``(T/save_every, B, p)`` for an optional trajectory).

    Arguments:
        model: a model structure (``MassDamper()``, ``Piecewise(...)``, ``Augmented(...)``).
        records: a batch of records, ``x``/``F`` of shape ``(B, T)``, ``dt`` and ``t0`` of
            shape ``(B,)`` or ``()`` (build with ``jax.tree.map(jnp.stack, ...)`` or
            :func:`stack_records`).
        bank: the filter (default :func:`lionjax.default_bank`); with ``batched_bank=True`` its
            ``coeffs`` have shape ``(B, n)`` (one filter per record: pole studies).
        gain: :class:`FixedGain` or :class:`AutoGain` (default, rate 1/s; computed from a first
            streamed pass of the LS statistics); with ``batched_gain=True`` the gain Module's
            array leaves have a leading ``B`` axis (one gain per record).
        stepper: ``ExactStep()`` (default; ``regressors="midpoint"`` or ``"zoh"``).
        normalisation: μ of θ̇ = −G Wᵀε/(1 + μ‖W‖²) (None or 0: plain law).
        theta0: initial estimate, ``(p,)`` or ``(B, p)`` (default zeros).
        lengths: number of valid samples per record, ``(B,)``; samples at or after a record's
            length are padding and contribute nothing (θ, filter states and sums frozen).
        ls: also stream the LS statistics and return ``theta_ls`` (samples after ``transient``).
        convergence: track the convergence time to within ``tolerance`` of ``theta_ref``
            (default: the streamed LS answer), its smooth surrogate and the tail statistics.
        theta_ref: reference ``(p,)`` or ``(B, p)`` for the convergence time.
        tolerance: relative band of the convergence time (default 2 %).
        softness: width of the sigmoid in log-error of the surrogate ``time_outside``.
        transient: seconds excluded from the LS statistics and from the gain's R (default
            3·λₙ₋₁/λₙ, as everywhere in lionjax).
        save_every: keep θ every ``save_every`` samples (exactly; the slab length becomes the
            largest divisor of ``save_every`` not above ``chunk``).
        chunk: samples per slab read from the ``(B, T)`` records per inner loop (a performance
            knob: each slab is transposed in cache, the whole batch never is).
        shard: shard the batch over ``jax.local_devices()`` (default True; the batch size must
            be a multiple of the device count, else it runs unsharded). On CPU host devices only
            records already placed by :func:`shard_records` are sharded (else they would be
            copied on every call; one device's ``split`` loops use the cores instead).
        split: independent loops per device, each over its own rows of the batch (XLA:CPU
            runs them concurrently: this is how one CPU device uses every core without copying
            the records). Default: on CPU the cores per device (≥ 64 records per loop), else 1.
        throw: raise on failure (unexcited parameters under AutoGain, non-finite θ); with
            False the failures are in ``result`` per record.
        fast: evaluate E(hS) by its series alone while tr(hS) ≤ 1/2 (8 terms in float32, 14
            in float64: truncation below the unit roundoff) and re-run only the records where
            some sample exceeds the bound (or θ is not finite) with the closed form
            (:func:`phi_sym2`), gathered into a batch of B/16 (the whole batch if more fail).
            ``False`` always uses the closed form (same results to rounding).

    Returns:
        a :class:`BatchedSolution`.
    """
    bank = default_bank() if bank is None else bank
    gain = AutoGain() if gain is None else gain
    stepper = ExactStep() if stepper is None else stepper
    for arg, val, typ in (
        ("model", model, AbstractModel),
        ("records", records, Record),
        ("bank", bank, FilterBank),
        ("gain", gain, AbstractGain),
        ("stepper", stepper, ExactStep),
    ):
        if not isinstance(val, typ):
            raise InputError(
                f"lion_batched: {arg} must be a {typ.__name__}, got {type(val).__name__}."
                + (" Use lionjax.lion for EulerStep/DiffraxStep." if arg == "stepper" else "")
            )
    if records.x.ndim != 2:
        raise InputError(
            f"lion_batched: records must be a batch with x of shape (B, T), got {records.x.shape}."
            " Stack single records with lionjax.stack_records([...])."
        )
    if not (isinstance(chunk, int) and chunk >= 1):
        raise InputError(f"lion_batched: chunk must be a positive int, got {chunk!r}.")
    if save_every is not None and not (isinstance(save_every, int) and save_every >= 1):
        raise InputError(f"lion_batched: save_every must be a positive int, got {save_every!r}.")
    if not (0 < tolerance < 1):
        raise InputError(f"lion_batched: tolerance must be in (0, 1), got {tolerance!r}.")
    sol = _lion_batched(
        model,
        records,
        bank,
        gain,
        dict(
            midpoint=stepper.regressors == "midpoint",
            normalisation=normalisation,
            theta0=theta0,
            lengths=lengths,
            ls=ls,
            convergence=convergence,
            theta_ref=theta_ref,
            tolerance=tolerance,
            softness=softness,
            transient=transient,
            save_every=save_every,
            chunk=chunk,
            batched_bank=batched_bank,
            batched_gain=batched_gain,
            shard=_shard_here(records, shard),
            split=split,
            fast=fast,
            one=jnp.ones((), records.x.dtype),
        ),
    )
    return finish(sol, throw, what="lion_batched")


_OPTIONS = dict(
    midpoint=True,
    normalisation=None,
    theta0=None,
    lengths=None,
    ls=False,
    convergence=False,
    theta_ref=None,
    tolerance=0.02,
    softness=0.25,
    transient=None,
    save_every=None,
    chunk=_BLOCK,
    batched_bank=False,
    batched_gain=False,
    shard=True,
    split=None,
    fast=True,
    only_ls=False,
    max_condition=1e7,
    one=None,  # a runtime 1 (an argument, not a constant): see materialise
)


@eqx.filter_jit
def _lion_batched(model, records, bank, gain, options):
    o_ = dict(_OPTIONS, **options)
    unknown = set(options) - set(_OPTIONS)
    if unknown:
        raise TypeError(f"_lion_batched: unknown options {sorted(unknown)}")
    B, T = records.x.shape
    dtype = records.x.dtype
    rec0 = jax.tree.map(lambda a: a[0] if a.ndim >= 1 else a, records)
    p = len(model.names)
    names = model.names
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
    X = tuple(sig_vals[k].astype(dtype) for k in order)  # (B, T) each, never transposed whole
    lengths, batched_bank = o_["lengths"], o_["batched_bank"]
    masked = lengths is not None
    dt = jnp.broadcast_to(jnp.asarray(records.dt, dtype), (B,))
    length = jnp.full((B,), T, jnp.int32) if lengths is None else jnp.asarray(lengths, jnp.int32)
    # per-record transient (LS window) and tail window, as sample indices
    if o_["transient"] is None:
        tr = default_transient(bank).astype(dtype)
    else:
        tr = jnp.asarray(o_["transient"], dtype)
    tr = jnp.broadcast_to(tr, (B,)) if jnp.ndim(tr) <= 1 else tr
    # first k with k·dt ≥ tr, computed as lionjax.lion's transient mask does
    kk = jnp.ceil(tr / dt)
    kk = jnp.where(dt * (kk - 1) >= tr, kk - 1, kk)
    kk = jnp.where(dt * kk < tr, kk + 1, kk)
    tr_k = jnp.maximum(kk, 0).astype(jnp.int32)
    # filter maps: shared (one dt, one filter) or one per record
    holds = [sigs0[k][1] == "foh" for k in order]
    coeffs_shared = not batched_bank and jnp.ndim(records.dt) == 0
    if coeffs_shared:
        maps = [_maps(bank, jnp.asarray(records.dt, dtype), f) for f in holds]
    else:
        bank_axis = 0 if batched_bank else None
        maps = [jax.vmap(_maps, in_axes=(bank_axis, 0, None))(bank, dt, f) for f in holds]
    maps = jax.tree.map(lambda a: jnp.asarray(a, dtype), maps)
    z0 = jnp.stack(
        [
            jax.vmap(lambda b, u0: b.steady_state(u0), in_axes=(0 if batched_bank else None, 0))(
                bank, sig_vals[k][:, 0]
            )
            for k in order
        ]
    ).astype(dtype)  # (S, B, n)
    block, save_blocks = _slab(o_["save_every"], o_["chunk"])

    def plan(**kw):
        flags = dict(
            midpoint=o_["midpoint"],
            normalised=o_["normalisation"] is not None,
            masked=masked,
            block=block,
            save_blocks=0,
            estimate=False,
            ls=False,
            track=False,
        )
        flags.update(kw)
        return _plan_for(model, rec0, bank, **flags)

    def run(pl: _Plan, per: dict, shared: dict, idx: Array | None = None):
        """The kernel over the batch (or over the records ``idx`` of it), batch-first outputs."""
        xs, zz = X, z0
        if idx is not None:
            per = jax.tree.map(lambda a: a[idx], per)
            xs, zz = tuple(a[idx] for a in X), z0[:, idx]
        perT = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), per)  # batch axis last
        perT["z0"] = jnp.moveaxis(zz, 1, -1)  # (S, n, B)
        mesh = _mesh() if o_["shard"] else None
        sharded = mesh is not None and xs[0].shape[0] % mesh.size == 0
        parts = _parts(o_["split"], xs[0].shape[0] // (mesh.size if sharded else 1), sharded)
        f = lambda xs, pe, sh: _split_kernel(pl, xs, sh, pe, parts)
        if sharded:
            spec_last = lambda a: PartitionSpec(*([None] * (a.ndim - 1) + ["batch"]))
            in_specs = (
                tuple(PartitionSpec("batch", None) for _ in X),
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

    base_per: dict = {"length": length, "tr_k": tr_k, "tail_k": (3 * length) // 4}
    shared: dict = {
        "tol": jnp.asarray(o_["tolerance"], dtype),
        "softness": jnp.asarray(o_["softness"], dtype),
    }
    if coeffs_shared:
        shared["maps"] = maps
        shared["h"] = jnp.asarray(records.dt, dtype)
    else:
        base_per["maps"] = maps
        base_per["h"] = dt
    shared["one"] = jnp.ones((), dtype) if o_["one"] is None else jnp.asarray(o_["one"], dtype)
    if o_["normalisation"] is not None:
        shared["mu"] = jnp.asarray(o_["normalisation"], dtype)

    only_ls, convergence, theta_ref = o_["only_ls"], o_["convergence"], o_["theta_ref"]
    need_ls = only_ls or o_["ls"] or (convergence and theta_ref is None) or not _fixed(gain)
    theta_ls = cond = None
    ok = jnp.ones((B,), bool)
    if need_ls:
        stats = run(plan(ls=True), base_per, shared)["ls"]
        theta_ls, cond, A, A_inv = _solve_ls(stats, p)
        n_used = stats[:, -1]
        R = A / jnp.clip(n_used, 1.0, None)[:, None, None]
    else:
        R = jnp.broadcast_to(jnp.eye(p, dtype=dtype), (B, p, p))
    if only_ls:
        th = theta_ls
        rss = jnp.einsum("bp,bpq,bq->b", th, A, th) + 2 * jnp.sum(th * stats[:, -p - 2 : -2], -1)
        rss = jnp.clip(rss + stats[:, -2], 0.0, None)
        sigma2 = rss / jnp.clip(2 * n_used - p, 1.0, None)
        cov = sigma2[:, None, None] * A_inv
        return LSBatchedSolution(
            theta=th,
            covariance=cov,
            std=jnp.sqrt(jnp.clip(jnp.diagonal(cov, axis1=-2, axis2=-1), 0.0, None)),
            condition=cond,
            rms=jnp.sqrt(rss / jnp.clip(2 * n_used, 1.0, None)),
            n_used=n_used,
            names=names,
            result=jax.vmap(_result)(cond < o_["max_condition"], jnp.all(jnp.isfinite(th), -1)),
        )
    gfun = lambda g, r: _gain_from_R(g, r, p, names)
    G, gain_ok = jax.vmap(gfun, in_axes=(0 if o_["batched_gain"] else None, 0))(gain, R)
    G = G.astype(dtype)
    ok = ok & gain_ok
    if o_["theta0"] is None:
        th0 = jnp.zeros((B, p), dtype)
    else:
        th0 = jnp.broadcast_to(jnp.asarray(o_["theta0"], dtype), (B, p))
    per = dict(base_per, theta0=th0)
    if _fixed(gain) and not o_["batched_gain"]:
        shared["G"] = G[0]  # one gain for every record: scalars in the kernel
    else:
        per["G"] = G
    track = bool(convergence)
    ref = None
    if track:
        ref = (
            theta_ls
            if theta_ref is None
            else jnp.broadcast_to(jnp.asarray(theta_ref, dtype), (B, p))
        )
        ref = jnp.where(jnp.isfinite(ref), ref, 0.0)
        per["ref"] = ref
    flags = dict(estimate=True, track=track, save_blocks=save_blocks)
    if o_["fast"]:
        # the short series where tr(hS) ≤ 1/2 (records beyond it come back non-finite), then the
        # closed form for those records only: up to Bf of them gathered into one small batch,
        # the whole batch if more (Bf: a 16th of the batch, a multiple of the device count)
        o = run(plan(series_terms=_fast_series_terms(dtype), **flags), per, shared)
        bad = ~jnp.all(jnp.isfinite(o["theta"]), axis=-1)
        ndev = len(jax.local_devices()) if o_["shard"] else 1
        Bf = min(B, ndev * -(-max(1, B // 16) // ndev))
        idx = jnp.nonzero(bad, size=Bf, fill_value=-1)[0]
        idx = jnp.where(idx < 0, idx[0], idx)  # pad with a failed record (same values)

        def some():
            sub = run(plan(**flags), per, shared, idx)
            return jax.tree.map(lambda a, b: a.at[idx].set(b), o, sub)

        n_bad = jnp.sum(bad)
        branch = jnp.where(n_bad == 0, 0, jnp.where(n_bad <= Bf, 1, 2))
        o = jax.lax.switch(branch, [lambda: o, some, lambda: run(plan(**flags), per, shared)])
    else:
        o = run(plan(**flags), per, shared)
    theta = o["theta"]
    finite = jnp.all(jnp.isfinite(theta), axis=-1)
    result = jax.vmap(_result)(ok, finite)
    t_conv = surr = tmean = tstd = traj = t_saved = None
    if track:
        last = o["last_out"]
        t_conv = jnp.where(last >= length - 1, jnp.inf, (last + 1).astype(dtype) * dt)
        surr = o["surr"]
        tail = o["tail"]
        wsum = jnp.clip(tail[:, -1:], 1.0, None)
        tmean = tail[:, :p] / wsum
        tstd = jnp.sqrt(jnp.clip(tail[:, p : 2 * p] / wsum - tmean**2, 0.0, None))
    if save_blocks:
        traj = jnp.moveaxis(o["trajectory"], 0, 1)  # kernel (K, p, B) → (B, K, p) → (K, B, p)
        K = traj.shape[0]
        t_saved = jnp.asarray(records.t0, dtype).reshape(-1)[0] + dt[0] * o_[
            "save_every"
        ] * jnp.arange(1, K + 1, dtype=dtype)
    return BatchedSolution(
        theta=theta,
        J=o["J"],
        gain=G,
        theta_ls=theta_ls,
        ls_condition=cond,
        theta_ref=ref,
        t_converged=t_conv,
        time_outside=surr,
        tail_mean=tmean,
        tail_std=tstd,
        t_saved=t_saved,
        trajectory=traj,
        names=names,
        result=result,
    )


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

    def params(self) -> dict[str, Array]:
        return {n: self.theta[..., i] for i, n in enumerate(self.names)}


def least_squares_batched(
    model: AbstractModel,
    records: Record,
    *,
    bank: FilterBank | None = None,
    lengths: Int[ArrayLike, " B"] | None = None,
    transient: float | ArrayLike | None = None,
    max_condition: float = 1e7,
    batched_bank: bool = False,
    shard: bool = True,
    throw: bool = True,
) -> LSBatchedSolution:
    """Batch least squares for B records from ΦᵀΦ, Φᵀy accumulated in one streamed pass.

    Equals ``lionjax.least_squares(model, record, initial="discard", transient=...)`` for each
    record (the samples of the first ``transient`` seconds get weight 0), without storing any
    regressor: memory O(B). Normal equations are solved on the column-normalised ΦᵀΦ (its
    condition number is the square of Φ's; in float32 prefer well-excited records).
    Arguments as :func:`lion_batched`; ``max_condition`` bounds cond(Φ) (unidentifiable above).
    """
    bank = default_bank() if bank is None else bank
    if not isinstance(model, AbstractModel) or not isinstance(records, Record):
        raise InputError(
            "least_squares_batched: expected (model, records) — an AbstractModel "
            f"and a batched Record, got {type(model).__name__}, "
            f"{type(records).__name__}."
        )
    if records.x.ndim != 2:
        raise InputError(
            "least_squares_batched: records must have x of shape (B, T), got "
            f"{records.x.shape}. Stack records with lionjax.stack_records."
        )
    from ._estimators import FixedGain

    options = dict(
        lengths=lengths,
        transient=transient,
        batched_bank=batched_bank,
        shard=_shard_here(records, shard),
        only_ls=True,
        max_condition=max_condition,
        one=jnp.ones((), records.x.dtype),
    )
    sol = _lion_batched(model, records, bank, FixedGain(1.0), options)
    return finish(sol, throw, what="least_squares_batched")


def _split(v: list, p: int):
    """(W1, W2, y1, y2) from the flat list W1 + W2 + [y1, y2]."""
    return v[:p], v[p : 2 * p], v[2 * p], v[2 * p + 1]


def _result(ok, finite):
    res = RESULTS.where(ok, RESULTS.successful, RESULTS.unidentifiable)
    return RESULTS.where(finite | ~ok, res, RESULTS.nonfinite)


def _fixed(gain: AbstractGain) -> bool:
    from ._estimators import FixedGain

    return isinstance(gain, FixedGain)


def stack_records(records: Sequence[Record], pad_to: int | None = None) -> tuple[Record, Array]:
    """Stack records into one batch, padding shorter ones; returns ``(batch, lengths)``.

    Padding repeats each record's last sample (so even a consumer that ignores ``lengths``
    sees a signal at rest), and ``lengths`` (B,) tells :func:`lion_batched` which samples are
    real. ``dt`` and ``t0`` become ``(B,)``.
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


@eqx.filter_jit
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

    θₖ₊₁ = Aₖθₖ + cₖ, Aₖ = I − h·GWₖᵀE(hSₖ)Wₖ, cₖ = −h·GWₖᵀE(hSₖ)W₀ₖ (Wₖ the midpoint
    regressors, as :class:`lionjax.ExactStep`), so θₖ = (Aₖ₋₁…A₀)θ₀ + … is a prefix product of
    affine maps, composed pairwise: (A₂, c₂)∘(A₁, c₁) = (A₂A₁, A₂c₁ + c₂). Depth O(log T) —
    for long records on accelerators; on a CPU the sequential :func:`lion_batched` is faster.
    Stores the regressors (memory O(T·p²)). ``G`` is the gain matrix (p×p), e.g. from
    ``lionjax.lion(...).gain``. vmap it for many records.
    """
    bank = default_bank() if bank is None else bank
    regs = model.regressors(record, bank)
    W, W0 = regs.W, regs.W0
    T, _, p = W.shape
    dtype = W.dtype
    if midpoint:
        Ws, W0s = 0.5 * (W[:-1] + W[1:]), 0.5 * (W0[:-1] + W0[1:])
    else:
        Ws, W0s = W[:-1], W0[:-1]
    G = jnp.asarray(G, dtype)
    h = record.dt.astype(dtype)
    GW = jnp.einsum("pq,tiq->tpi", G, Ws)  # (T-1, p, 2)
    S = jnp.einsum("tip,tpj->tij", Ws, GW)
    ep, eq, er = phi_sym2(h * S[:, 0, 0], h * 0.5 * (S[:, 0, 1] + S[:, 1, 0]), h * S[:, 1, 1])
    E = jnp.stack([jnp.stack([ep, eq], -1), jnp.stack([eq, er], -1)], -2)
    K = h * jnp.einsum("tpi,tij->tpj", GW, E)  # (T-1, p, 2)
    A = jnp.eye(p, dtype=dtype) - jnp.einsum("tpj,tjq->tpq", K, Ws)
    c = -jnp.einsum("tpj,tj->tp", K, W0s)

    def compose(first, second):
        A1, c1 = first
        A2, c2 = second
        return A2 @ A1, jnp.einsum("...pq,...q->...p", A2, c1) + c2

    Acum, ccum = jax.lax.associative_scan(compose, (A, c))
    th0 = jnp.zeros((p,), dtype) if theta0 is None else jnp.asarray(theta0, dtype)
    thetas = jnp.einsum("tpq,q->tp", Acum, th0) + ccum
    thetas = jnp.concatenate([th0[None], thetas])
    return ParallelSolution(theta=thetas, theta_final=thetas[-1], names=regs.names)
