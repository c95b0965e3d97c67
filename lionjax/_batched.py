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

Performance (GUIDE §9): the batch is the contiguous inner axis, the carry is a flat tuple of
(B,) arrays, every update is elementwise (no tiny matmuls), the time loop is an outer
``lax.scan`` over chunks of ``chunk`` samples unrolled in Python, and the batch is sharded over
all local devices with ``jax.shard_map`` (one XLA CPU device runs a loop on one core; start
Python with ``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>`` — see
:func:`lionjax.host_devices` — to use every core).

The hot path (:func:`_fast_kernel`, default ``fast=True``): for the common case — one
``dt`` and filter for the batch, one fixed gain, θ only — the kernel reads the records in
their ``(B, T)`` layout, one ``(B, 64)`` slab per outer scan step transposed in place (the
(B,T)→(T,B) transpose of the whole batch cost ≈ 45 % of the run; a per-sample strided column
read instead slows down as T grows), carries one flat tuple of (B,) arrays through an inner
``unroll=1`` scan, and evaluates φ by the series alone while carrying max tr(hS) ≥ ρ(hS); only
if that exceeds 1 somewhere is the general kernel (both φ branches) run instead. Measured
(shared 2-core machine, B = 4096, T = 8000, f32, 2 host devices, same run): 115–134 M
sample-updates/s against 50–70 for the general kernel (T = 2000: 165 against 85). Python-
unrolled chunks of 8 samples with optimisation barriers took ≈ 5 min to compile on XLA:CPU.

The exact step. With S = W G Wᵀ (2×2 symmetric PSD), over one interval h with frozen W:

    θ ← θ − h·G Wᵀ E(hS) (Wθ + W₀),     E(Z) = (I − e^{−Z}) Z⁻¹,

and :func:`phi_sym2` evaluates E for a symmetric 2×2 Z elementwise in closed form: a Horner
series reduced by Cayley–Hamilton for spectral radius ρ ≤ 1, the eigen-split
E = ē I + g (Z − mI) with a guarded near-degenerate limit above. It is the same function as
:func:`lionjax._estimators.phi_2x2` (tested to 1e-13 in float64), written to be cheap per
element.

Parallel in time: θₖ₊₁ = Aₖθₖ + cₖ is linear, Aₖ = I − hGWₖᵀE Wₖ, cₖ = −hGWₖᵀE W₀ₖ, so
:func:`lion_parallel` composes the affine maps with ``lax.associative_scan`` (O(log T) depth,
for long records on accelerators; it stores the regressors).
"""

from __future__ import annotations

import math
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
from ._record import Record
from ._solution import default_transient, finish

# ----------------------------------------------------------------------------------------------
# The exact 2×2 step, elementwise.


def _series_terms(dtype) -> int:
    return 9 if jnp.dtype(dtype) == jnp.float32 else 17


def phi_sym2(zp: ArrayLike, zq: ArrayLike, zr: ArrayLike) -> tuple[Array, Array, Array]:
    """E(Z) = (I − e^{−Z}) Z⁻¹ for Z = [[zp, zq], [zq, zr]] symmetric PSD, elementwise.

    Returns the entries (p, q, r) of the symmetric E. Two branches, both cheap per element:

    - ρ = m + d ≤ 1 (m = (zp + zr)/2, d² = ((zp − zr)/2)² + zq²): the series
      E = Σₙ (−Z)ⁿ/(n+1)! in Horner form, each power reduced by Cayley–Hamilton
      (Z² = tr Z·Z − det Z·I), so E = αI + βZ with scalar recurrences (9 terms in float32,
      17 in float64: truncation below the unit roundoff);
    - ρ > 1: the eigen-split E = ē I + g (Z − mI), ē = (E(m+d) + E(m−d))/2,
      g = (E(m+d) − E(m−d))/(2d), E(λ) = −expm1(−λ)/λ; for d < 0.03·m (float32; 10⁻³·m in
      float64) the Taylor limits ē ≈ E(m) + E''(m)d²/2, g ≈ E'(m) + E'''(m)d²/6.

    Values and gradients are finite everywhere on PSD inputs (including Z = 0).
    """
    zp, zq, zr = jnp.asarray(zp), jnp.asarray(zq), jnp.asarray(zr)
    dtype = jnp.result_type(zp, zq, zr)
    f32 = jnp.dtype(dtype) == jnp.float32
    m = 0.5 * (zp + zr)
    hd = 0.5 * (zp - zr)
    d2 = hd * hd + zq * zq
    d = jnp.sqrt(d2 + jnp.finfo(dtype).tiny)  # tiny: finite gradient at d = 0
    rho = m + d
    small = rho <= 1.0
    # --- series branch: M ← I + (−Z)M/k, M = aI + bZ; Z² = tr·Z − det·I.
    tr = jnp.where(small, zp + zr, 0.0)
    det = jnp.where(small, zp * zr - zq * zq, 0.0)
    a, b = _series(tr, det, dtype)
    s_p, s_q, s_r = a + b * zp, b * zq, a + b * zr
    # --- eigen branch (values where ρ > 1; guarded inputs elsewhere).
    mm = jnp.where(small, 2.0, m)
    dd = jnp.where(small, 0.5, d)
    lp = mm + dd
    lm = mm - dd

    def E(lam):
        tiny = lam < 1e-6
        ls = jnp.where(tiny, 1.0, lam)
        return jnp.where(tiny, 1.0 - 0.5 * lam, -jnp.expm1(-ls) / ls)

    thr = 3e-2 if f32 else 1e-3
    near = dd < thr * mm
    ddf = jnp.where(near, 1.0, dd)
    ep, em = E(lp), E(lm)
    ebar_far = 0.5 * (ep + em)
    g_far = (ep - em) / (2.0 * ddf)
    e = jnp.exp(-mm)
    im = 1.0 / mm
    E0 = (1.0 - e) * im  # m > 1/2 here: no cancellation
    E1 = (e - E0) * im
    E2 = (-e - 2.0 * E1) * im
    E3 = (e - 3.0 * E2) * im
    dn2 = jnp.where(near, dd * dd, 0.0)
    ebar = jnp.where(near, E0 + 0.5 * E2 * dn2, ebar_far)
    g = jnp.where(near, E1 + E3 * dn2 / 6.0, g_far)
    hh = jnp.where(small, 0.0, hd)
    qq = jnp.where(small, 0.0, zq)
    e_p, e_q, e_r = ebar + g * hh, g * qq, ebar - g * hh
    return (
        jnp.where(small, s_p, e_p),
        jnp.where(small, s_q, e_q),
        jnp.where(small, s_r, e_r),
    )


def _phi_switch(zp, zq, zr):
    """:func:`phi_sym2`, evaluating only the series when every element of the batch is in its
    range (ρ ≤ 1, the usual case h·‖GWᵀW‖ ≪ 1); the same values, fewer operations."""
    small = jnp.all(0.5 * (zp + zr) + jnp.sqrt(0.25 * (zp - zr) ** 2 + zq * zq) <= 1.0)
    return jax.lax.cond(small, _phi_series, phi_sym2, zp, zq, zr)


def _phi_series(zp, zq, zr):
    a, b = _series(zp + zr, zp * zr - zq * zq, jnp.result_type(zp, zq, zr))
    return a + b * zp, b * zq, a + b * zr


def _series(tr, det, dtype):
    """E(Z) = αI + βZ from the series Σ (−Z)ⁿ/(n+1)! in Horner form (Cayley–Hamilton)."""
    a = jnp.ones_like(tr)
    b = jnp.zeros_like(tr)
    for k in range(_series_terms(dtype), 1, -1):
        # (−Z)(aI + bZ) = −aZ − b(tr Z − det I) = b·det I − (a + b·tr) Z
        a, b = 1.0 + (b * det) * (1.0 / k), (a + b * tr) * (-1.0 / k)
    return a, b


def exact_step(theta, W1, W2, y1, y2, G, h, c=None, phi=None, pack=False):
    """One exact step of θ̇ = −c·G Wᵀ(Wθ + W₀) over h, elementwise over any batch shape.

    Arguments (lists of arrays, all broadcastable): ``theta`` (p entries), ``W1``/``W2`` the
    two rows of W (p entries each), ``y1``/``y2`` = W₀, ``G`` a p×p nested list (symmetric),
    ``h`` the interval [s], ``c`` the normalisation 1/(1 + μ‖W‖²) or None. Returns the new θ.
    """
    p = len(theta)
    GW1 = [sum(G[i][j] * W1[j] for j in range(p)) for i in range(p)]
    GW2 = [sum(G[i][j] * W2[j] for j in range(p)) for i in range(p)]
    if c is not None:
        GW1 = [c * v for v in GW1]
        GW2 = [c * v for v in GW2]
    S11 = sum(W1[i] * GW1[i] for i in range(p))
    S12 = sum(W1[i] * GW2[i] for i in range(p))
    S22 = sum(W2[i] * GW2[i] for i in range(p))
    e1 = sum(W1[i] * theta[i] for i in range(p)) + y1
    e2 = sum(W2[i] * theta[i] for i in range(p)) + y2
    ep, eq, er = (phi_sym2 if phi is None else phi)(h * S11, h * S12, h * S22)
    f1 = h * (ep * e1 + eq * e2)
    f2 = h * (eq * e1 + er * e2)
    if pack:
        # XLA:CPU has no multi-output loop fusion: each θᵢ would re-compute φ. Materialising
        # (f1, f2) as ONE complex buffer makes φ run once per sample (measured ≈2× faster).
        fc = jax.lax.optimization_barrier(jax.lax.complex(f1, f2))
        f1, f2 = jnp.real(fc), jnp.imag(fc)
    return [theta[i] - (GW1[i] * f1 + GW2[i] * f2) for i in range(p)]


# ----------------------------------------------------------------------------------------------
# Devices


def host_devices(n: int | None = None) -> int:
    """Ask XLA for ``n`` host (CPU) devices (default: the number of cores), before JAX starts.

    One XLA CPU device runs a ``lax.scan`` on one core; :func:`lion_batched` shards the batch
    over ``jax.local_devices()``, so on a CPU-only machine several host devices are how every
    core works. This only edits ``XLA_FLAGS`` and has no effect once JAX's backend is
    initialised (then it returns the device count already in force). Returns the count asked.
    """
    n = os.cpu_count() or 1 if n is None else int(n)
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()
    return n


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


class _Plan(eqx.Module):
    """Static description of one kernel: which signals, columns and outputs."""

    signals: tuple[tuple[str, str], ...] = eqx.field(static=True)  # (name, hold)
    columns: tuple[tuple[int, int, float], ...] = eqx.field(static=True)  # (sig, order, sign)
    x_index: int = eqx.field(static=True)
    n: int = eqx.field(static=True)
    unit_dc: bool = eqx.field(static=True)
    midpoint: bool = eqx.field(static=True)
    normalised: bool = eqx.field(static=True)
    estimate: bool = eqx.field(static=True)
    ls: bool = eqx.field(static=True)
    track: bool = eqx.field(static=True)
    masked: bool = eqx.field(static=True)
    chunk: int = eqx.field(static=True)
    save_chunks: int = eqx.field(static=True)  # 0: no trajectory


def _outputs(plan: _Plan, z, u, lam, cdc):
    """(V₁…V₄) needed by the columns, per signal, from states z (n arrays) and input u."""

    def V(zs, us, j):  # j = 1…4
        if j <= plan.n:
            out = zs[j - 1]
        else:  # n == 3, j == 4: s³/Λ u = u − Σ λ z
            out = us - sum(lam[plan.n - 1 - i] * zs[i] for i in range(plan.n))
        return out if cdc is None else cdc * out

    return V


def _regressors(plan: _Plan, V, z, u):
    """W rows (W1, W2) and W₀ (y1, y2) from filter states, elementwise."""
    W1, W2 = [], []
    for s, order, sign in plan.columns:
        W1.append(sign * V(z[s], u[s], order + 1))
        W2.append(sign * V(z[s], u[s], order + 2))
    xi = plan.x_index
    return W1, W2, V(z[xi], u[xi], 3), V(z[xi], u[xi], 4)


def _kernel(plan: _Plan, U, shared, per):
    """Run one shard. U: (T, S, Bs) raw signals (time-major). Returns a dict of outputs."""
    T, S, Bs = U.shape
    dtype = U.dtype
    n, p = plan.n, len(plan.columns)
    coef = per["coef"] if "coef" in per else shared["coef"]  # dict of filter coefficients
    Phi, G0, G1, lam = coef["Phi"], coef["G0"], coef["G1"], coef["lam"]
    cdc = lam[n - 1] if plan.unit_dc else None
    h = per["h"] if "h" in per else shared["h"]
    Gm = per.get("G", shared.get("G"))
    V = _outputs(plan, None, None, lam, cdc)
    foh = [hold == "foh" for _, hold in plan.signals]

    def filt(zs, uk, uk1, is_foh):
        du = uk1 - uk
        out = []
        for i in range(n):
            v = sum(Phi[i][j] * zs[j] for j in range(n)) + G0[i] * uk
            if is_foh:
                v = v + G1[i] * du
            out.append(v)
        return out

    if plan.track:
        ref = per["ref"]
        inv = [1.0 / jnp.where(jnp.abs(r) > 0, jnp.abs(r), 1.0) for r in ref]
        tol = shared["tol"]
        log_tol = jnp.log(tol)
    length = per["length"] if plan.masked else None
    tr_k = per["tr_k"]  # first sample index counted by LS
    tail_k = per["tail_k"]  # first sample index of the tail statistics

    # carry: dict of lists of (Bs,) arrays
    z0 = per["z0"]  # (S, n, Bs)
    carry = {
        "z": [[z0[s, i] for i in range(n)] for s in range(S)],
        "u": [U[0, s] for s in range(S)],
        "k": jnp.zeros((), jnp.int32),
    }
    zero = jnp.zeros((Bs,), dtype)
    if plan.estimate:
        carry["theta"] = [per["theta0"][i] for i in range(p)]
    if plan.ls:
        npp = p * (p + 1) // 2
        carry["ls"] = [zero] * (npp + p + 2)
    if plan.track:
        carry["last_out"] = jnp.full((Bs,), -1, jnp.int32)
        carry["surr"] = zero
        carry["tail"] = [zero] * (2 * p + 1)

    def ls_terms(W1, W2, y1, y2):
        out = []
        for i in range(p):
            for j in range(i, p):
                out.append(W1[i] * W1[j] + W2[i] * W2[j])
        for i in range(p):
            out.append(W1[i] * y1 + W2[i] * y2)
        out.append(y1 * y1 + y2 * y2)
        return out

    def one(c, uk1, local):
        """Sample k → k+1. ``local`` holds per-chunk partial sums (better rounding)."""
        k = c["k"]
        z, u = c["z"], c["u"]
        zn = [filt(z[s], u[s], uk1[s], foh[s]) for s in range(S)]
        if plan.masked:
            act = (k + 1) < length
            zn = [
                [jnp.where(act, a, b) for a, b in zip(zs, zo, strict=True)]
                for zs, zo in zip(zn, z, strict=True)
            ]
            uk1 = [jnp.where(act, a, b) for a, b in zip(uk1, u, strict=True)]
        new = {"z": zn, "u": list(uk1), "k": k + 1}
        if plan.ls:
            # statistics of sample k+1 (sample 0 is inside every transient)
            W1, W2, y1, y2 = _regressors(plan, V, zn, uk1)
            w = (k + 1 >= tr_k).astype(dtype)
            if plan.masked:
                w = w * act.astype(dtype)
            terms = ls_terms(W1, W2, y1, y2)
            local["ls"] = [a + w * t for a, t in zip(local["ls"], terms, strict=True)]
            local["n"] = local["n"] + w
        if plan.estimate:
            theta = c["theta"]
            if plan.midpoint:
                zm = [[0.5 * (a + b) for a, b in zip(z[s], zn[s], strict=True)] for s in range(S)]
                um = [0.5 * (a + b) for a, b in zip(u, uk1, strict=True)]
                W1, W2, y1, y2 = _regressors(plan, V, zm, um)
            else:
                W1, W2, y1, y2 = _regressors(plan, V, z, u)
            cn = None
            if plan.normalised:
                cn = 1.0 / (1.0 + shared["mu"] * sum(w * w for w in W1 + W2))
            Gl = [[Gm[i, j] for j in range(p)] for i in range(p)]
            big = []

            def phi_opt(zp, zq, zr):
                if mode == "full":
                    return phi_sym2(zp, zq, zr)
                big.append(0.5 * (zp + zr) + jnp.sqrt(0.25 * (zp - zr) ** 2 + zq * zq) > 1.0)
                return _phi_series(zp, zq, zr)

            th = exact_step(theta, W1, W2, y1, y2, Gl, h, cn, phi=phi_opt, pack=True)
            if big:
                new["big"] = c["big"] | big[0]
            if plan.masked:
                th = [jnp.where(act, a, b) for a, b in zip(th, theta, strict=True)]
            new["theta"] = th
            if plan.track:
                rel = [(a - r) * iv for a, r, iv in zip(th, ref, inv, strict=True)]
                out = jnp.zeros((Bs,), bool)
                for r in rel:
                    out = out | (jnp.abs(r) > tol)
                if plan.masked:
                    out = out & act
                new["last_out"] = jnp.where(out, k + 1, c["last_out"])
                # smooth max over parameters: r² = Σ rᵢ⁴ / Σ rᵢ² ≤ max rᵢ²
                r2 = sum(r * r for r in rel)
                r4 = sum(r * r * r * r for r in rel)
                rr = r4 / (r2 + jnp.finfo(dtype).tiny)
                lr = 0.5 * jnp.log(rr + jnp.finfo(dtype).tiny)
                sig = jax.nn.sigmoid((lr - log_tol) / shared["softness"])
                wk = h if not plan.masked else h * act.astype(dtype)
                local["surr"] = local["surr"] + wk * sig
                wt = (k + 1 >= tail_k).astype(dtype)
                if plan.masked:
                    wt = wt * act.astype(dtype)
                tl = [wt * a for a in th] + [wt * a * a for a in th] + [wt]
                local["tail"] = [a + b for a, b in zip(local["tail"], tl, strict=True)]
        for key in ("last_out", "big"):
            if key in c and key not in new:
                new[key] = c[key]
        return new

    def run_chunk(c, ublk):
        """ublk: (L, S, Bs) inputs u[k+1] for the L steps of this chunk."""
        L = ublk.shape[0]
        local = {}
        if plan.ls:
            local["ls"] = [zero] * (len(c["ls"]) - 1)  # npp + p + 1 sums (then n)
            local["n"] = zero
        if plan.track:
            local["surr"] = zero
            local["tail"] = [zero] * (2 * p + 1)
        cc = dict(c)
        for j in range(L):
            cc = one(cc, [ublk[j, s] for s in range(S)], local)
            if L > 1:  # materialise the carry: XLA would otherwise re-fuse (and re-compute)
                cc, local = jax.lax.optimization_barrier((cc, local))
        if plan.ls:
            cc["ls"] = [a + b for a, b in zip(c["ls"], local["ls"] + [local["n"]], strict=True)]
        if plan.track:
            cc["surr"] = c["surr"] + local["surr"]
            cc["tail"] = [a + b for a, b in zip(c["tail"], local["tail"], strict=True)]
        return cc

    def scan_all(carry, mode_):
        nonlocal mode
        mode = mode_
        C = plan.chunk
        steps = T - 1
        nc, rem = divmod(steps, C)
        body_in = U[1 : 1 + nc * C].reshape(nc, C, S, Bs)
        traj = None
        if plan.save_chunks:
            g = plan.save_chunks
            ng, nrest = divmod(nc, g)

            def group(c, blk):  # blk: (g, C, S, Bs)
                c, _ = jax.lax.scan(lambda cc, b: (run_chunk(cc, b), None), c, blk)
                return c, jnp.stack(c["theta"])

            grp = body_in[: ng * g].reshape(ng, g, C, S, Bs)
            carry, traj = jax.lax.scan(group, carry, grp)
            rest = body_in[ng * g :]
        else:
            rest = body_in
        if rest.shape[0]:
            carry, _ = jax.lax.scan(lambda cc, b: (run_chunk(cc, b), None), carry, rest)
        if rem:
            carry = run_chunk(carry, U[1 + nc * C :])
        return carry, traj

    mode = "full"
    if plan.estimate:
        # optimistic: the cheap series φ everywhere, and a full re-run (exact φ with both
        # branches) only for a shard where some sample had ρ(hS) > 1 (large gains).
        carry["big"] = jnp.zeros((Bs,), bool)
        res_series = scan_all(carry, "series")
        carry, traj = jax.lax.cond(
            jnp.any(res_series[0]["big"]),
            lambda: scan_all(carry, "full"),
            lambda: res_series,
        )
    else:
        carry, traj = scan_all(carry, "full")

    out: dict[str, Any] = {}
    z, u = carry["z"], carry["u"]
    W1, W2, y1, y2 = _regressors(plan, V, z, u)
    if plan.estimate:
        th = carry["theta"]
        e1 = sum(a * b for a, b in zip(W1, th, strict=True)) + y1
        e2 = sum(a * b for a, b in zip(W2, th, strict=True)) + y2
        out["theta"] = jnp.stack(th)
        out["J"] = 0.5 * (e1 * e1 + e2 * e2)
        if traj is not None:
            out["trajectory"] = traj
    if plan.ls:
        out["ls"] = jnp.stack(carry["ls"])
    if plan.track:
        out["last_out"] = carry["last_out"]
        out["surr"] = carry["surr"]
        out["tail"] = jnp.stack(carry["tail"])
    return out


_FAST_PACK = True  # one φ per sample (see exact_step)
_FAST_BLOCK = 64  # samples per slab of the hot path's blocked transpose


def _fast_kernel(plan: _Plan, X, shared, per):
    """The hot path: θ only (no LS, tracking, masks or trajectory), shared filter and gain.

    X: tuple of S raw signals, each ``(Bs, T)`` in the caller's record-major layout: every step
    reads column k+1 with a dynamic index inside the scan, so the (B, T) → (T, B) transpose of
    the whole record is never materialised (it cost ≈ 45 % of the run). The carry is one flat
    tuple of (Bs,) arrays, ``unroll=1`` (Python-unrolled chunks compiled for minutes and were
    not faster), φ is the series only, and the running max of tr(hS) ≥ ρ(hS) tells the caller
    whether the series was valid everywhere (else it re-runs the general kernel).
    Returns (theta (p, Bs), J (Bs,), trmax (Bs,)).
    """
    S = len(X)
    Bs, T = X[0].shape
    dtype = X[0].dtype
    n, p = plan.n, len(plan.columns)
    coef = shared["coef"]
    Phi, G0, G1, lam = coef["Phi"], coef["G0"], coef["G1"], coef["lam"]
    cdc = lam[n - 1] if plan.unit_dc else None
    h = shared["h"]
    Gm = shared["G"]
    Gl = [[Gm[i, j] for j in range(p)] for i in range(p)]
    mu = shared.get("mu")
    V = _outputs(plan, None, None, lam, cdc)
    foh = [hold == "foh" for _, hold in plan.signals]
    z0 = per["z0"]  # (S, n, Bs)

    def filt(zs, uk, uk1, is_foh):
        out = []
        for i in range(n):
            v = sum(Phi[i][j] * zs[j] for j in range(n)) + G0[i] * uk
            if is_foh:
                v = v + G1[i] * (uk1 - uk)
            out.append(v)
        return out

    def pack(z, u, th, mx):
        return tuple(v for zs in z for v in zs) + tuple(u) + tuple(th) + (mx,)

    def unpack(c):
        z = [list(c[s * n : (s + 1) * n]) for s in range(S)]
        u = list(c[S * n : S * n + S])
        th = list(c[S * n + S : S * n + S + p])
        return z, u, th, c[-1]

    def body(c, u1):
        z, u, th, mx = unpack(c)
        u1 = list(u1)
        zn = [filt(z[s], u[s], u1[s], foh[s]) for s in range(S)]
        if plan.midpoint:
            zm = [[0.5 * (a + b) for a, b in zip(z[s], zn[s], strict=True)] for s in range(S)]
            um = [0.5 * (a + b) for a, b in zip(u, u1, strict=True)]
            W1, W2, y1, y2 = _regressors(plan, V, zm, um)
        else:
            W1, W2, y1, y2 = _regressors(plan, V, z, u)
        cn = None
        if mu is not None:
            cn = 1.0 / (1.0 + mu * sum(w * w for w in W1 + W2))
        trs = []

        def phi(zp, zq, zr):
            trs.append(zp + zr)
            return _phi_series(zp, zq, zr)

        thn = exact_step(th, W1, W2, y1, y2, Gl, h, cn, phi=phi, pack=_FAST_PACK)
        return pack(zn, u1, thn, jnp.maximum(mx, trs[0])), None

    th0 = [per["theta0"][i] for i in range(p)]
    c0 = pack(
        [[z0[s, i] for i in range(n)] for s in range(S)],
        [Xs[:, 0] for Xs in X],
        th0,
        jnp.zeros((Bs,), dtype),
    )
    C = _FAST_BLOCK
    nc, rem = divmod(T - 1, C)

    def block(c, i):
        # one (Bs, C) slab per signal, transposed here (C·4 contiguous bytes per row read)
        slabs = tuple(jax.lax.dynamic_slice_in_dim(Xs, 1 + i * C, C, axis=1).T for Xs in X)
        return jax.lax.scan(body, c, slabs)[0], None

    c, _ = jax.lax.scan(block, c0, jnp.arange(nc))
    if rem:
        c, _ = jax.lax.scan(body, c, tuple(Xs[:, 1 + nc * C :].T for Xs in X))
    z, u, th, mx = unpack(c)
    W1, W2, y1, y2 = _regressors(plan, V, z, u)
    e1 = sum(a * b for a, b in zip(W1, th, strict=True)) + y1
    e2 = sum(a * b for a, b in zip(W2, th, strict=True)) + y2
    return jnp.stack(th), 0.5 * (e1 * e1 + e2 * e2), mx


def _solve_ls(stats: Array, p: int):
    """θ_LS and the condition number of the normalised ΦᵀΦ from the streamed statistics."""
    npp = p * (p + 1) // 2
    A = jnp.zeros(stats.shape[:-1] + (p, p), stats.dtype)
    idx = 0
    for i in range(p):
        for j in range(i, p):
            A = A.at[..., i, j].set(stats[..., idx]).at[..., j, i].set(stats[..., idx])
            idx += 1
    b = stats[..., npp : npp + p]
    d = jnp.sqrt(jnp.clip(jnp.diagonal(A, axis1=-2, axis2=-1), jnp.finfo(A.dtype).tiny, None))
    An = A / d[..., :, None] / d[..., None, :]
    ev = jnp.linalg.eigvalsh(An)
    cond = jnp.sqrt(ev[..., -1] / jnp.clip(ev[..., 0], jnp.finfo(A.dtype).tiny, None))
    theta = -jnp.linalg.solve(An, (b / d)[..., None])[..., 0] / d
    return theta, cond, A, stats[..., -1]


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
    return _Plan(
        signals=tuple((k, sigs[k][1]) for k in names),
        columns=cols,
        x_index=names.index("x"),
        n=bank.order,
        unit_dc=bank.unit_dc_gain,
        **flags,
    )


def _coefficients(bank: FilterBank, dt: Array) -> dict:
    """Φ, Γ₀, Γ₁ and λ as nested lists of arrays (shape () or (B,) each)."""
    Phi, G0, G1 = bank.discretise(dt)
    n = bank.order
    return {
        "Phi": [[Phi[i, j] for j in range(n)] for i in range(n)],
        "G0": [G0[i] for i in range(n)],
        "G1": [G1[i] for i in range(n)],
        "lam": [bank.coeffs[i] for i in range(n)],
    }


def _batched_coefficients(bank: FilterBank, dt: Array, batched: bool) -> dict:
    if not batched:
        return _coefficients(bank, dt)
    out = jax.vmap(_coefficients)(bank, dt)
    return out


def _gain_from_R(gain: AbstractGain, R: Array, p: int, names) -> tuple[Array, Array]:
    """G from the mean of WᵀW over the record (what :class:`AutoGain` uses), per element.

    The gain Module sees regressors whose mean outer product is exactly R: W = Lᵀ with
    LLᵀ = R (one pseudo-sample), so every gain rule is reused unchanged.
    """
    L = jnp.linalg.cholesky(R + 0.0)
    regs = Regressors(jnp.swapaxes(L, -1, -2)[None], jnp.zeros((1, p), R.dtype), names)
    return gain(regs, jnp.ones((1,), R.dtype))


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
    chunk: int = 1,
    batched_bank: bool = False,
    batched_gain: bool = False,
    shard: bool = True,
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
        save_every: keep θ every ``save_every`` samples (rounded up to a multiple of ``chunk``).
        chunk: samples per unrolled inner block (performance knob; 1, the default, was fastest
            on a 2-core CPU: XLA re-materialises the carry per step either way).
        shard: shard the batch over ``jax.local_devices()`` (default True).
        throw: raise on failure (unexcited parameters under AutoGain, non-finite θ); with
            False the failures are in ``result`` per record.
        fast: use the specialised hot path when it applies (shared ``dt`` and filter, one
            fixed gain, no ``lengths``/``convergence``/``save_every``): reads the ``(B, T)``
            records in place (no transpose), flat carry, series φ; the general kernel is
            re-run only if some tr(h·WGWᵀ) > 1. Same results; ``False`` forces the general
            kernel (for comparisons).

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
    save_chunks = 0
    if save_every is not None:
        if not (isinstance(save_every, int) and save_every >= 1):
            raise InputError(
                f"lion_batched: save_every must be a positive int, got {save_every!r}."
            )
        save_chunks = max(1, math.ceil(save_every / chunk))
    if not (0 < tolerance < 1):
        raise InputError(f"lion_batched: tolerance must be in (0, 1), got {tolerance!r}.")
    sol = _lion_batched(
        model,
        records,
        bank,
        gain,
        stepper.regressors == "midpoint",
        normalisation,
        theta0,
        lengths,
        ls,
        convergence,
        theta_ref,
        tolerance,
        softness,
        transient,
        save_chunks,
        chunk,
        batched_bank,
        batched_gain,
        shard,
        fast=fast,
    )
    return finish(sol, throw, what="lion_batched")


@eqx.filter_jit
def _lion_batched(
    model,
    records,
    bank,
    gain,
    midpoint,
    normalisation,
    theta0,
    lengths,
    ls,
    convergence,
    theta_ref,
    tolerance,
    softness,
    transient,
    save_chunks,
    chunk,
    batched_bank,
    batched_gain,
    shard,
    only_ls=False,
    max_condition=1e7,
    fast=True,
):
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
    sig_vals = jax.vmap(lambda r: {k: v[0] for k, v in model.signals(r).items()})(full)
    order = list(model.signals(rec0))  # the plan's signal order (a dict out of vmap is sorted)
    masked = lengths is not None
    dt = jnp.broadcast_to(jnp.asarray(records.dt, dtype), (B,))
    length = jnp.full((B,), T, jnp.int32) if lengths is None else jnp.asarray(lengths, jnp.int32)
    # per-record transient (LS window) and tail window, as sample indices
    if transient is None:
        tr = default_transient(bank).astype(dtype)
    else:
        tr = jnp.asarray(transient, dtype)
    tr = jnp.broadcast_to(tr, (B,)) if jnp.ndim(tr) <= 1 else tr
    # first k with k·dt ≥ tr, computed as lionjax.lion's transient mask does
    kk = jnp.ceil(tr / dt)
    kk = jnp.where(dt * (kk - 1) >= tr, kk - 1, kk)
    kk = jnp.where(dt * kk < tr, kk + 1, kk)
    tr_k = jnp.maximum(kk, 0).astype(jnp.int32)
    tail_k = (3 * length) // 4
    # filter coefficients
    coeffs_shared = not batched_bank and jnp.ndim(records.dt) == 0
    if coeffs_shared:
        coef = _coefficients(bank, jnp.asarray(records.dt, dtype))
    else:
        if batched_bank:
            coef = jax.vmap(_coefficients)(bank, dt)
        else:
            coef = jax.vmap(lambda d: _coefficients(bank, d))(dt)
    coef = jax.tree.map(lambda a: jnp.asarray(a, dtype), coef)
    z0 = jnp.stack(
        [
            jax.vmap(lambda b, u0: b.steady_state(u0), in_axes=(0 if batched_bank else None, 0))(
                bank, sig_vals[k][:, 0]
            )
            for k in order
        ]
    ).astype(dtype)  # (S, B, n)
    # time-major (T, S, B): one transpose, then every step reads contiguous (B,) rows
    # (built lazily inside each general run, so the fast path never materialises it)
    make_U = lambda: jnp.stack([sig_vals[k].T for k in order], axis=1).astype(dtype)

    def plan(**kw):
        base = dict(
            midpoint=midpoint,
            normalised=normalisation is not None,
            masked=masked,
            chunk=chunk,
            save_chunks=0,
        )
        base.update(kw)
        return _plan_for(model, rec0, bank, **base)

    def run(pl: _Plan, per: dict, shared: dict):
        per = dict(per)
        per.setdefault("coef", None)
        if per["coef"] is None:
            per.pop("coef")
        # everything per-element: batch axis last
        perT = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), per)
        UT = make_U()
        perT["z0"] = jnp.moveaxis(z0, 1, -1)  # (S, n, B)
        mesh = _mesh() if shard else None
        f = lambda u, pe, sh: _kernel(pl, u, sh, pe)
        if mesh is not None and B % mesh.size == 0:
            spec_last = lambda a: PartitionSpec(*([None] * (a.ndim - 1) + ["batch"]))
            in_specs = (
                PartitionSpec(None, None, "batch"),  # (T, S, B)
                jax.tree.map(spec_last, perT),
                jax.tree.map(lambda a: PartitionSpec(), shared),
            )
            out_shape = jax.eval_shape(f, UT, perT, shared)
            out_specs = jax.tree.map(
                lambda a: spec_last(a) if a.ndim else PartitionSpec(), out_shape
            )
            f = jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
        out = f(UT, perT, shared)
        return jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0) if a.ndim else a, out)

    def run_fast(pl: _Plan, per: dict, shared: dict):
        X = tuple(sig_vals[k].astype(dtype) for k in order)  # (B, T) each: no transpose
        perT = {"theta0": jnp.moveaxis(per["theta0"], 0, -1), "z0": jnp.moveaxis(z0, 1, -1)}
        mesh = _mesh() if shard else None
        f = lambda xs, pe, sh: _fast_kernel(pl, xs, sh, pe)
        if mesh is not None and B % mesh.size == 0:
            spec_last = lambda a: PartitionSpec(*([None] * (a.ndim - 1) + ["batch"]))
            in_specs = (
                tuple(PartitionSpec("batch", None) for _ in X),
                jax.tree.map(spec_last, perT),
                jax.tree.map(lambda a: PartitionSpec(), shared),
            )
            out_specs = (
                PartitionSpec(None, "batch"),
                PartitionSpec("batch"),
                PartitionSpec("batch"),
            )
            f = jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
        th, J, trmax = f(X, perT, shared)
        return {"theta": th.T, "J": J}, trmax

    base_per = {"length": length, "tr_k": tr_k, "tail_k": tail_k}
    shared: dict = {"tol": jnp.asarray(tolerance, dtype), "softness": jnp.asarray(softness, dtype)}
    if coeffs_shared:
        shared["coef"] = coef
        shared["h"] = jnp.asarray(records.dt, dtype)
    else:
        base_per["coef"] = coef
        base_per["h"] = dt
    if normalisation is not None:
        shared["mu"] = jnp.asarray(normalisation, dtype)

    need_ls = only_ls or ls or (convergence and theta_ref is None) or not _fixed(gain)
    theta_ls = cond = None
    ok = jnp.ones((B,), bool)
    if need_ls:
        o = run(plan(estimate=False, ls=True, track=False), base_per, shared)
        theta_ls, cond, A, _ = _solve_ls(o["ls"], p)
        n_used = jnp.clip(o["ls"][:, -1], 1.0, None)
        R = A / n_used[:, None, None]
    else:
        R = jnp.broadcast_to(jnp.eye(p, dtype=dtype), (B, p, p))
    if only_ls:
        th = theta_ls
        rss = jnp.einsum("bp,bpq,bq->b", th, A, th) + 2 * jnp.sum(th * o["ls"][:, -p - 2 : -2], -1)
        rss = jnp.clip(rss + o["ls"][:, -2], 0.0, None)
        return LSBatchedSolution(
            theta=th,
            condition=cond,
            rms=jnp.sqrt(rss / (2 * n_used)),
            n_used=o["ls"][:, -1],
            names=names,
            result=jax.vmap(_result)(cond < max_condition, jnp.all(jnp.isfinite(th), -1)),
        )
    gfun = lambda g, r: _gain_from_R(g, r, p, names)
    G, gain_ok = jax.vmap(gfun, in_axes=(0 if batched_gain else None, 0))(gain, R)
    G = G.astype(dtype)
    ok = ok & gain_ok
    if theta0 is None:
        th0 = jnp.zeros((B, p), dtype)
    else:
        th0 = jnp.broadcast_to(jnp.asarray(theta0, dtype), (B, p))
    per = dict(base_per, theta0=th0)
    if _fixed(gain) and not batched_gain:
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
    pl = plan(estimate=True, ls=False, track=track, save_chunks=save_chunks)
    if fast and "G" in shared and coeffs_shared and not (track or save_chunks or masked):
        # hot path; the general kernel (exact φ) only if some tr(hS) > 1 (then ρ may be > 1)
        o_fast, trmax = run_fast(pl, per, shared)
        o = jax.lax.cond(jnp.any(trmax > 1.0), lambda: run(pl, per, shared), lambda: o_fast)
    else:
        o = run(pl, per, shared)
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
    if save_chunks:
        traj = jnp.moveaxis(o["trajectory"], 0, 1)  # kernel (K, p, B) → (B, K, p) → (K, B, p)
        K = traj.shape[0]
        step = save_chunks * chunk
        t_saved = jnp.asarray(records.t0, dtype).reshape(-1)[0] + dt[0] * step * jnp.arange(
            1, K + 1, dtype=dtype
        )
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
        theta: θ_LS = −(ΦᵀΦ)⁻¹Φᵀy, shape ``(B, p)``; condition: condition number of the
        column-normalised Φ, ``(B,)``; rms: root-mean-square equation error, ``(B,)``;
        n_used: samples used, ``(B,)``; names; result: :class:`RESULTS` per record.
    """

    theta: Float[Array, "B p"]
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

    sol = _lion_batched(
        model,
        records,
        bank,
        FixedGain(1.0),
        True,
        None,
        None,
        lengths,
        True,
        False,
        None,
        0.02,
        0.25,
        transient,
        0,
        1,
        batched_bank,
        False,
        shard,
        True,
        max_condition,
    )
    return finish(sol, throw, what="least_squares_batched")


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
