"""Throughput of Lion's batched estimator: lionjax against numba, numpy and naive JAX, in ONE run.

The benchmark law (every implementation runs exactly this): the mass–damper ẍ + aẋ = bF,
Λ = (s + 4)³ with unit DC gain, x filtered under a first-order hold, F under a zero-order hold
(exact discretisation), midpoint regressors and the exact closed-form θ step
θ ← θ − h·G Wᵀ E(hWGWᵀ)(Wθ + W₀), E(Z) = (I − e^{−Z})Z⁻¹ (``law = "exact"``), fixed G.

    python benchmarks/throughput.py --batch 4096 --samples 8000 --dtype float32 --json out.json

msps = million sample-updates per second = datasets × samples / seconds (min of ≥ 5 repeats
after a warm-up, ``block_until_ready``). Compile time is reported separately; peak memory is the
process's resident-set growth over each stage. Results of numba/numpy must equal lionjax's final
θ within the stated tolerance (float64: 1e-9 relative, float32: 2e-3 relative).
"""

from __future__ import annotations

import os
import sys

if "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    # one XLA CPU device runs a loop on one core: give XLA one host device per core
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + f" --xla_force_host_platform_device_count={os.cpu_count() or 1}"
    ).strip()

# benchmark the checkout this script lives in, not a possibly stale installed copy
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import argparse
import json
import platform
import resource
import time

import numpy as np

ROOFLINE_MSPS = 1000.0  # ~1 G sample-updates/s: the memory-bandwidth bound of the 2-core machine


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def best_time(fn, repeats: int) -> float:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return min(ts)


# ----------------------------------------------------------------------------------------------
# data: a mass–damper per dataset (a, b spread ±20 %), multisine + noise force, exact zoh sim


def make_data(B: int, T: int, dt: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    a = 22.0 * (1 + 0.2 * rng.uniform(-1, 1, B))
    b = 1.916 * (1 + 0.2 * rng.uniform(-1, 1, B))
    t = np.arange(T) * dt
    freqs = np.array([0.7, 2.3, 5.1, 9.7])
    ph = rng.uniform(0, 2 * np.pi, (B, 4))
    F = np.zeros((B, T))
    for j, f in enumerate(freqs):
        F += 0.3 / (1 + j) * np.sin(2 * np.pi * f * t[None] + ph[:, j : j + 1])
    F += 0.02 * rng.normal(size=(B, T))
    # exact zero-order-hold step of (x, v): v' = -a v + b F
    e = np.exp(-a * dt)
    x = np.zeros((B, T))
    xk = np.zeros(B)
    vk = np.zeros(B)
    for k in range(T):
        x[:, k] = xk
        u = F[:, k]
        vinf = b * u / a
        dv = vk - vinf
        xk = xk + vinf * dt + dv * (1 - e) / a
        vk = vinf + dv * e
    return x, F


# ----------------------------------------------------------------------------------------------
# numba: one dataset per thread, scalar code, the same exact-step math (fastmath off)

NUMBA_SRC = """
@njit(parallel=True, fastmath=False, cache=False)
def lion_numba(x, F, Phi, G0, G1, lam, cdc, Gm, h, theta_out):
    B, T = x.shape
    # h folded into the gain, as lionjax does (hS = W(hG)Wᵀ, Δθ = (hG)Wᵀ E ε)
    G00 = h * Gm[0, 0]; G01 = h * Gm[0, 1]; G10 = h * Gm[1, 0]; G11 = h * Gm[1, 1]
    for bi in prange(B):
        zx0 = x[bi, 0] / lam[2]; zx1 = R(0.0); zx2 = R(0.0)
        zf0 = F[bi, 0] / lam[2]; zf1 = R(0.0); zf2 = R(0.0)
        th0 = R(0.0); th1 = R(0.0)
        ux = x[bi, 0]; uf = F[bi, 0]
        for k in range(T - 1):
            ux1 = x[bi, k + 1]; uf1 = F[bi, k + 1]
            dux = ux1 - ux
            nx0 = Phi[0, 0] * zx0 + Phi[0, 1] * zx1 + Phi[0, 2] * zx2 + G0[0] * ux + G1[0] * dux
            nx1 = Phi[1, 0] * zx0 + Phi[1, 1] * zx1 + Phi[1, 2] * zx2 + G0[1] * ux + G1[1] * dux
            nx2 = Phi[2, 0] * zx0 + Phi[2, 1] * zx1 + Phi[2, 2] * zx2 + G0[2] * ux + G1[2] * dux
            nf0 = Phi[0, 0] * zf0 + Phi[0, 1] * zf1 + Phi[0, 2] * zf2 + G0[0] * uf
            nf1 = Phi[1, 0] * zf0 + Phi[1, 1] * zf1 + Phi[1, 2] * zf2 + G0[1] * uf
            nf2 = Phi[2, 0] * zf0 + Phi[2, 1] * zf1 + Phi[2, 2] * zf2 + G0[2] * uf
            # midpoint regressors
            mx0 = R(0.5) * (zx0 + nx0); mx1 = R(0.5) * (zx1 + nx1); mx2 = R(0.5) * (zx2 + nx2)
            mf0 = R(0.5) * (zf0 + nf0); mf1 = R(0.5) * (zf1 + nf1)
            mux = R(0.5) * (ux + ux1)
            w11 = cdc * mx1; w21 = cdc * mx2
            w12 = -cdc * mf0; w22 = -cdc * mf1
            y1 = cdc * mx2
            y2 = cdc * (mux - (lam[2] * mx0 + lam[1] * mx1 + lam[0] * mx2))
            g11 = G00 * w11 + G01 * w12; g21 = G10 * w11 + G11 * w12
            g12 = G00 * w21 + G01 * w22; g22 = G10 * w21 + G11 * w22
            zp = w11 * g11 + w12 * g21
            zq = w11 * g12 + w12 * g22
            zr = w21 * g12 + w22 * g22
            e1 = w11 * th0 + w12 * th1 + y1
            e2 = w21 * th0 + w22 * th1 + y2
            m = R(0.5) * (zp + zr); hd = R(0.5) * (zp - zr)
            tr = zp + zr; det = zp * zr - zq * zq; d = R(0.0)
            # the same tiers as lionjax: short series while tr ≤ bound, the ρ ≤ 1 series, eigen
            nt = 0
            if tr <= R({bound}):
                nt = {nfast}
            else:
                d = np.sqrt(hd * hd + zq * zq)
                if m + d <= R(1.0):
                    nt = {nslow}
            if nt > 0:
                # Horner on Y = −Z with the constant coefficients CF[n] = 1/(n+1)!, as lionjax
                a = CF[nt - 2]; b = CF[nt - 1]
                for n in range(nt - 3, -1, -1):
                    a, b = CF[n] - b * det, a - b * tr
                ep = a - b * zp; eq = -b * zq; er = a - b * zr
            else:
                if d < R({thr}) * m:
                    e = np.exp(-m); im = R(1.0) / m
                    E0 = (R(1.0) - e) * im; E1 = (e - E0) * im
                    E2 = (-e - R(2.0) * E1) * im; E3 = (e - R(3.0) * E2) * im
                    ebar = E0 + R(0.5) * E2 * d * d; g = E1 + E3 * d * d / R(6.0)
                else:
                    lp = m + d; lm = m - d
                    ep_ = -np.expm1(-lp) / lp
                    em_ = R(1.0) - R(0.5) * lm if lm < R(1e-6) else -np.expm1(-lm) / lm
                    ebar = R(0.5) * (ep_ + em_); g = (ep_ - em_) / (R(2.0) * d)
                ep = ebar + g * hd; eq = g * zq; er = ebar - g * hd
            f1 = ep * e1 + eq * e2; f2 = eq * e1 + er * e2
            th0 = th0 - (g11 * f1 + g12 * f2)
            th1 = th1 - (g21 * f1 + g22 * f2)
            zx0 = nx0; zx1 = nx1; zx2 = nx2; zf0 = nf0; zf1 = nf1; zf2 = nf2
            ux = ux1; uf = uf1
        theta_out[bi, 0] = th0
        theta_out[bi, 1] = th1
"""


def phi_tiers(dtype) -> dict:
    """lionjax's evaluation of E(hS), so every reference runs the same algorithm: the short series
    (``nfast`` terms) while tr(hS) ≤ ``bound``, the ρ ≤ 1 series (``nslow``), else the eigen-split
    (near-degenerate threshold ``thr``)."""
    import jax.numpy as jnp

    from lionjax import _phi

    f32 = dtype == "float32"
    return {
        "bound": _phi.SERIES_BOUND,
        "nfast": _phi.fast_series_terms(jnp.dtype(dtype)),
        "nslow": _phi._series_terms(jnp.dtype(dtype)),
        "thr": 3e-2 if f32 else 1e-3,
    }


def series_coeffs(dtype) -> np.ndarray:
    """cₙ = 1/(n+1)!, n = 0…19: the series' constant coefficients (E = Σ cₙ(−Z)ⁿ)."""
    import math

    return np.array([1.0 / math.factorial(n + 1) for n in range(20)], dtype)


def build_numba(dtype):
    import numba  # noqa: F401
    from numba import njit, prange

    ns = {
        "njit": njit,
        "prange": prange,
        "np": np,
        "R": getattr(np, dtype),
        "CF": series_coeffs(dtype),
    }
    src = NUMBA_SRC.format(**phi_tiers(dtype))
    exec(src, ns)  # noqa: S102 — the kernel is written once above, typed per dtype
    return ns["lion_numba"]


# ----------------------------------------------------------------------------------------------
# CUDA (GPU only): an independent CuPy RawKernel of the same law, one thread per dataset, the
# records in (T, B) layout (coalesced: each sample of 32 consecutive datasets is one transaction;
# the transpose is done once and not timed — the reference gets its preferred layout), the same
# scalar code as numba. Written without a GPU at hand: UNMEASURED until run on one.

CUDA_SRC = r"""
typedef {ctype} R;
#define EXP {exp}
#define EXPM1 {expm1}
#define SQRT {sqrt}
extern "C" __global__ void lion_cuda(const R* __restrict__ xt, const R* __restrict__ Ft,
                                     const int B, const int T, const R* __restrict__ P,
                                     R* __restrict__ theta_out)
{{
    const int bi = blockIdx.x * blockDim.x + threadIdx.x;
    if (bi >= B) return;
    // P: Phi (9, row-major), G0 (3), G1 (3), lam (3), cdc, Gm (4, row-major), h
    const R p00 = P[0], p01 = P[1], p02 = P[2], p10 = P[3], p11 = P[4], p12 = P[5];
    const R p20 = P[6], p21 = P[7], p22 = P[8];
    const R a0 = P[9], a1 = P[10], a2 = P[11], c0 = P[12], c1 = P[13], c2 = P[14];
    const R l0 = P[15], l1 = P[16], l2 = P[17], cdc = P[18];
    const R h = P[23];  // h folded into the gain, as lionjax does
    const R G00 = h * P[19], G01 = h * P[20], G10 = h * P[21], G11 = h * P[22];
    const R CF[20] = {{{coeffs}}};  // 1/(n+1)!
    R ux = xt[bi], uf = Ft[bi];
    R zx0 = ux / l2, zx1 = (R)0, zx2 = (R)0;
    R zf0 = uf / l2, zf1 = (R)0, zf2 = (R)0;
    R th0 = (R)0, th1 = (R)0;
    for (int k = 0; k < T - 1; ++k) {{
        const R ux1 = xt[(size_t)(k + 1) * B + bi];
        const R uf1 = Ft[(size_t)(k + 1) * B + bi];
        const R dux = ux1 - ux;
        const R nx0 = p00 * zx0 + p01 * zx1 + p02 * zx2 + a0 * ux + c0 * dux;
        const R nx1 = p10 * zx0 + p11 * zx1 + p12 * zx2 + a1 * ux + c1 * dux;
        const R nx2 = p20 * zx0 + p21 * zx1 + p22 * zx2 + a2 * ux + c2 * dux;
        const R nf0 = p00 * zf0 + p01 * zf1 + p02 * zf2 + a0 * uf;
        const R nf1 = p10 * zf0 + p11 * zf1 + p12 * zf2 + a1 * uf;
        const R nf2 = p20 * zf0 + p21 * zf1 + p22 * zf2 + a2 * uf;
        const R mx0 = (R)0.5 * (zx0 + nx0), mx1 = (R)0.5 * (zx1 + nx1);
        const R mx2 = (R)0.5 * (zx2 + nx2);
        const R mf0 = (R)0.5 * (zf0 + nf0), mf1 = (R)0.5 * (zf1 + nf1);
        const R mux = (R)0.5 * (ux + ux1);
        const R w11 = cdc * mx1, w21 = cdc * mx2, w12 = -cdc * mf0, w22 = -cdc * mf1;
        const R y1 = cdc * mx2;
        const R y2 = cdc * (mux - (l2 * mx0 + l1 * mx1 + l0 * mx2));
        const R g11 = G00 * w11 + G01 * w12, g21 = G10 * w11 + G11 * w12;
        const R g12 = G00 * w21 + G01 * w22, g22 = G10 * w21 + G11 * w22;
        const R zp = w11 * g11 + w12 * g21;
        const R zq = w11 * g12 + w12 * g22;
        const R zr = w21 * g12 + w22 * g22;
        const R e1 = w11 * th0 + w12 * th1 + y1;
        const R e2 = w21 * th0 + w22 * th1 + y2;
        const R m = (R)0.5 * (zp + zr), hd = (R)0.5 * (zp - zr);
        const R tr = zp + zr, det = zp * zr - zq * zq;
        R d = (R)0, ep, eq, er;
        int nt = 0;
        if (tr <= (R){bound}) {{
            nt = {nfast};
        }} else {{
            d = SQRT(hd * hd + zq * zq);
            if (m + d <= (R)1) nt = {nslow};
        }}
        if (nt > 0) {{
            R a = CF[nt - 2], b = CF[nt - 1];  // Horner on Y = -Z, as lionjax
            for (int n = nt - 3; n >= 0; --n) {{
                const R an = CF[n] - b * det;
                b = a - b * tr;
                a = an;
            }}
            ep = a - b * zp; eq = -b * zq; er = a - b * zr;
        }} else {{
            R ebar, g;
            if (d < (R){thr} * m) {{
                const R e = EXP(-m), im = (R)1 / m;
                const R E0 = ((R)1 - e) * im, E1 = (e - E0) * im;
                const R E2 = (-e - (R)2 * E1) * im, E3 = (e - (R)3 * E2) * im;
                ebar = E0 + (R)0.5 * E2 * d * d; g = E1 + E3 * d * d / (R)6;
            }} else {{
                const R lp = m + d, lm = m - d;
                const R epp = -EXPM1(-lp) / lp;
                const R emm = lm < (R)1e-6 ? (R)1 - (R)0.5 * lm : -EXPM1(-lm) / lm;
                ebar = (R)0.5 * (epp + emm); g = (epp - emm) / ((R)2 * d);
            }}
            ep = ebar + g * hd; eq = g * zq; er = ebar - g * hd;
        }}
        const R f1 = ep * e1 + eq * e2, f2 = eq * e1 + er * e2;
        th0 = th0 - (g11 * f1 + g12 * f2);
        th1 = th1 - (g21 * f1 + g22 * f2);
        zx0 = nx0; zx1 = nx1; zx2 = nx2; zf0 = nf0; zf1 = nf1; zf2 = nf2;
        ux = ux1; uf = uf1;
    }}
    theta_out[2 * bi] = th0;
    theta_out[2 * bi + 1] = th1;
}}
"""


def build_cuda(dtype):
    """The CuPy RawKernel of :data:`CUDA_SRC` for ``dtype`` and a runner
    ``run(xt, Ft, params, theta)`` (device arrays; ``xt``/``Ft`` (T, B)). ImportError without
    CuPy."""
    import cupy as cp

    f32 = dtype == "float32"
    src = CUDA_SRC.format(
        ctype="float" if f32 else "double",
        exp="expf" if f32 else "exp",
        expm1="expm1f" if f32 else "expm1",
        sqrt="sqrtf" if f32 else "sqrt",
        coeffs=", ".join(repr(float(c)) for c in series_coeffs(dtype)),
        **phi_tiers(dtype),
    )
    kern = cp.RawKernel(src, "lion_cuda", options=("--std=c++14",))  # fast-math off (default)

    def run(xt, Ft, params, theta):
        T, B = xt.shape
        threads = 128
        kern(
            ((B + threads - 1) // threads,),
            (threads,),
            (xt, Ft, np.int32(B), np.int32(T), params, theta),
        )
        cp.cuda.get_current_stream().synchronize()

    return run


# ----------------------------------------------------------------------------------------------
# numpy: vectorised over the batch, Python loop over time (same math; both φ branches only when
# some element needs the eigen branch)


def lion_numpy(x, F, Phi, G0, G1, lam, cdc, Gm, h, tiers):
    R = x.dtype.type
    B, T = x.shape
    xt = np.ascontiguousarray(x.T)
    Ft = np.ascontiguousarray(F.T)
    zx = [xt[0] / lam[2], np.zeros(B, x.dtype), np.zeros(B, x.dtype)]
    zf = [Ft[0] / lam[2], np.zeros(B, x.dtype), np.zeros(B, x.dtype)]
    th0 = np.zeros(B, x.dtype)
    th1 = np.zeros(B, x.dtype)
    half = R(0.5)
    Gh = h * Gm  # h folded into the gain, as lionjax does
    CF = series_coeffs(x.dtype)  # Horner on Y = −Z with constant coefficients, as lionjax
    for k in range(T - 1):
        ux, ux1, uf = xt[k], xt[k + 1], Ft[k]
        dux = ux1 - ux
        nx = [
            Phi[i, 0] * zx[0] + Phi[i, 1] * zx[1] + Phi[i, 2] * zx[2] + G0[i] * ux + G1[i] * dux
            for i in range(3)
        ]
        nf = [
            Phi[i, 0] * zf[0] + Phi[i, 1] * zf[1] + Phi[i, 2] * zf[2] + G0[i] * uf for i in range(3)
        ]
        mx = [half * (a + b) for a, b in zip(zx, nx, strict=True)]
        mf = [half * (a + b) for a, b in zip(zf[:2], nf[:2], strict=True)]
        mux = half * (ux + ux1)
        w11, w21 = cdc * mx[1], cdc * mx[2]
        w12, w22 = -cdc * mf[0], -cdc * mf[1]
        y1 = cdc * mx[2]
        y2 = cdc * (mux - (lam[2] * mx[0] + lam[1] * mx[1] + lam[0] * mx[2]))
        g11 = Gh[0, 0] * w11 + Gh[0, 1] * w12
        g21 = Gh[1, 0] * w11 + Gh[1, 1] * w12
        g12 = Gh[0, 0] * w21 + Gh[0, 1] * w22
        g22 = Gh[1, 0] * w21 + Gh[1, 1] * w22
        zp = w11 * g11 + w12 * g21
        zq = w11 * g12 + w12 * g22
        zr = w21 * g12 + w22 * g22
        e1 = w11 * th0 + w12 * th1 + y1
        e2 = w21 * th0 + w22 * th1 + y2
        m = half * (zp + zr)
        hd = half * (zp - zr)
        d = np.sqrt(hd * hd + zq * zq)
        small = m + d <= 1.0
        tr = zp + zr
        det = zp * zr - zq * zq
        nt = tiers["nfast"] if (tr <= tiers["bound"]).all() else tiers["nslow"]
        a = np.full_like(zp, CF[nt - 2])
        b = np.full_like(zp, CF[nt - 1])
        for n in range(nt - 3, -1, -1):
            a, b = CF[n] - b * det, a - b * tr
        ep, eq, er = a - b * zp, -b * zq, a - b * zr
        if not small.all():
            with np.errstate(all="ignore"):
                e = np.exp(-m)
                im = R(1.0) / m
                E0 = (R(1.0) - e) * im
                E1 = (e - E0) * im
                E2 = (-e - R(2.0) * E1) * im
                E3 = (e - R(3.0) * E2) * im
                lp, lm = m + d, m - d
                epp = -np.expm1(-lp) / lp
                emm = np.where(lm < 1e-6, R(1.0) - half * lm, -np.expm1(-lm) / lm)
                near = d < tiers["thr"] * m
                ebar = np.where(near, E0 + half * E2 * d * d, half * (epp + emm))
                g = np.where(near, E1 + E3 * d * d / R(6.0), (epp - emm) / (R(2.0) * d))
            ep = np.where(small, ep, ebar + g * hd)
            eq = np.where(small, eq, g * zq)
            er = np.where(small, er, ebar - g * hd)
        f1 = ep * e1 + eq * e2
        f2 = eq * e1 + er * e2
        th0 = th0 - (g11 * f1 + g12 * f2)
        th1 = th1 - (g21 * f1 + g22 * f2)
        zx, zf = nx, nf
    return np.stack([th0, th1], axis=1)


# ----------------------------------------------------------------------------------------------


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=8000)
    ap.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--rounds", type=int, default=3, help="interleaved rounds of lionjax/numba/numpy (0: none)"
    )
    ap.add_argument("--json", metavar="OUT.json")
    ap.add_argument("--small-batch", type=int, default=2, help="batch of solve_ivp / diffrax")
    ap.add_argument(
        "--small-samples", type=int, default=1000, help="samples per record of solve_ivp / diffrax"
    )
    ap.add_argument("--naive-batch", type=int, default=256, help="batch of the naive vmap")
    ap.add_argument("--small-repeats", type=int, default=2, help="repeats of the slow paths")
    ap.add_argument("--skip", default="", help="comma list of implementations to skip")
    ap.add_argument(
        "--long-samples",
        type=int,
        default=1_000_000,
        help="samples of the one long record timed parallel in time vs sequential (GPU only)",
    )
    args = ap.parse_args(argv)
    skip = set(filter(None, args.skip.split(",")))

    import jax

    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    import lionjax as lj

    B, T, dt = args.batch, args.samples, 1e-3
    dtype = np.dtype(args.dtype)
    rtol = 1e-9 if args.dtype == "float64" else 2e-3
    x64, F64 = make_data(B, T, dt)
    x, F = x64.astype(dtype), F64.astype(dtype)
    model = lj.MassDamper()
    bank = lj.default_bank()
    # one fixed gain for all: AutoGain (rate 2/s) of the first dataset
    xg, Fg = make_data(1, max(T, 4000), dt)
    rec0 = lj.Record(jnp.asarray(xg[0], dtype), jnp.asarray(Fg[0], dtype), jnp.asarray(dt, dtype))
    G = np.asarray(lj.lion(model, rec0, gain=lj.AutoGain(2.0), save_every=T).gain, np.float64)
    G = 0.5 * (G + G.T)
    Phi, Gam0, Gam1 = (np.asarray(a, dtype) for a in bank.discretise(jnp.asarray(dt)))
    lam = np.asarray(bank.coeffs, dtype)
    cdc = dtype.type(lam[2])
    Gd = G.astype(dtype)
    h = dtype.type(dt)
    N = B * T
    out: dict = {
        "config": {
            "batch": B,
            "samples": T,
            "dtype": args.dtype,
            "law": "exact",
            "repeats": args.repeats,
            "gain": G.tolist(),
            "filter": "(s+4)^3, unit DC gain; x foh, F zoh; midpoint regressors",
            "tolerance_rel": rtol,
        },
        "environment": {
            "python": platform.python_version(),
            "jax": jax.__version__,
            "numpy": np.__version__,
            "devices": [str(d) for d in jax.local_devices()],
            "cpu_count": os.cpu_count(),
            "machine": platform.machine(),
            "processor": platform.processor(),
        },
    }

    def record(name, seconds, n_updates, **extra):
        msps = n_updates / seconds / 1e6
        out[name] = {"msps": msps, "seconds": seconds, **extra}
        print(f"{name:>10}: {msps:9.4g} M sample-updates/s  ({seconds * 1e3:.1f} ms)", flush=True)

    gpu = jax.default_backend() == "gpu"
    # --- lionjax: the records placed once over the host devices (lj.shard_records, timed
    # separately as placement_s), then lion_batched with its defaults
    gain = lj.FixedGain(jnp.asarray(Gd))
    t0 = time.perf_counter()
    recs = lj.shard_records(lj.Record(x, F, jnp.asarray(dt, dtype)))
    jax.block_until_ready(recs)
    placement = time.perf_counter() - t0
    run = lambda: lj.lion_batched(model, recs, gain=gain, throw=False).theta.block_until_ready()
    m0 = rss_mb()
    t0 = time.perf_counter()
    theta_lj = np.asarray(run())
    first = time.perf_counter() - t0
    secs = best_time(run, args.repeats)
    timed = {"lionjax": run}  # re-timed in interleaved rounds below
    record(
        "lionjax",
        secs,
        N,
        law="exact",
        compile_s=max(first - secs, 0.0),
        placement_s=placement,
        peak_rss_growth_mb=rss_mb() - m0,
        roofline_fraction=N / secs / 1e6 / ROOFLINE_MSPS,
        devices=len(jax.local_devices()),
        kernel="xla",  # Execution(kernel="auto") resolves to XLA on every backend today
    )

    def unplaced(name, bank_used, run_with=None, **extra):
        """Time lion_batched on records as they come (one device's arrays, not placed by the
        caller): by default on one device, the batch split into one loop per core inside one
        program (``Execution(shard=False)``). Returns θ."""
        recs1 = lj.Record(jnp.asarray(x), jnp.asarray(F), jnp.asarray(dt, dtype))
        ex = lj.Execution(shard=False) if run_with is None else run_with
        run1 = lambda: lj.lion_batched(
            model, recs1, bank=bank_used, gain=gain, execution=ex, throw=False
        ).theta.block_until_ready()
        t0 = time.perf_counter()
        th1 = np.asarray(run1())
        first = time.perf_counter() - t0
        secs = best_time(run1, args.repeats)
        timed[name] = run1
        record(
            name,
            secs,
            N,
            law="exact",
            compile_s=max(first - secs, 0.0),
            roofline_fraction=N / secs / 1e6 / ROOFLINE_MSPS,
            **extra,
        )
        return th1

    def check(name, theta, n=None):
        ref = theta_lj[: theta.shape[0]] if n is None else n
        err = float(np.max(np.abs(theta - ref) / np.maximum(np.abs(ref), 1e-12)))
        out[name]["max_rel_diff_vs_lionjax"] = err
        out[name]["agrees"] = bool(err <= rtol)
        print(f"{'':>10}  max relative difference to lionjax {err:.2e} (tolerance {rtol:g})")

    # --- lionjax with its defaults on records as they come: on CPU with several host devices it
    # lays them out over the devices as views of their memory (no copy) and shards
    if "unplaced" not in skip:
        thu = unplaced(
            "lionjax_unplaced", bank, run_with=lj.Execution(), execution="defaults, unplaced"
        )
        check("lionjax_unplaced", thu)

    # --- lionjax on one device with the shared filter
    if "one_device" not in skip:
        th1 = unplaced("lionjax_one_device", bank)
        check("lionjax_one_device", th1)

    # --- lionjax with one filter per record (a FilterBank with coeffs (B, n), as lj.study
    # builds for pole grids; here every record gets the benchmark's filter, so θ must equal the
    # shared-filter run's), defaults, records as they come: compare with lionjax_unplaced (the
    # same execution with the shared filter)
    if "per_record" not in skip:
        per_bank = lj.FilterBank(
            jnp.broadcast_to(bank.coeffs, (B, bank.order)), unit_dc_gain=bank.unit_dc_gain
        )
        thp = unplaced(
            "lionjax_per_record_filters",
            per_bank,
            run_with=lj.Execution(),
            execution="defaults, records as they come",
        )
        check("lionjax_per_record_filters", thp)

    # --- numba
    if "numba" not in skip:
        try:
            kern = build_numba(args.dtype)
        except ImportError:
            print("      numba: not installed (pip install lionjax[bench]); skipped")
            kern = None
        if kern is not None:
            th = np.zeros((B, 2), dtype)
            fn = lambda: kern(x, F, Phi, Gam0, Gam1, lam, cdc, Gd, h, th)
            m0 = rss_mb()
            t0 = time.perf_counter()
            fn()
            first = time.perf_counter() - t0
            secs = best_time(fn, args.repeats)
            timed["numba"] = fn
            import numba

            record(
                "numba",
                secs,
                N,
                law="exact",
                compile_s=max(first - secs, 0.0),
                peak_rss_growth_mb=rss_mb() - m0,
                threads=numba.get_num_threads(),
                version=numba.__version__,
            )
            check("numba", th.copy())

    # --- GPU only: the fused XLA loop for comparison with the Pallas kernel ("auto" on a GPU),
    # and the independent CUDA reference (CuPy RawKernel, one thread per dataset)
    if gpu and "xla" not in skip:
        xla = lj.Execution(kernel="xla")
        runx = lambda: lj.lion_batched(
            model, recs, gain=gain, execution=xla, throw=False
        ).theta.block_until_ready()
        thx = np.asarray(runx())
        secs = best_time(runx, args.repeats)
        timed["lionjax_xla"] = runx
        record("lionjax_xla", secs, N, law="exact", kernel="xla")
        check("lionjax_xla", thx)
    if gpu and "cuda" not in skip:
        try:
            import cupy as cp

            cuda_run = build_cuda(args.dtype)
        except ImportError:
            print("   cuda_ref: CuPy not installed; skipped")
            cuda_run = None
        if cuda_run is not None:
            xt = cp.asarray(np.ascontiguousarray(x.T))  # (T, B), placed once, not timed
            Ft = cp.asarray(np.ascontiguousarray(F.T))
            params = cp.asarray(
                np.concatenate([Phi.ravel(), Gam0, Gam1, lam, [cdc], Gd.ravel(), [h]]).astype(dtype)
            )
            thc = cp.zeros((B, 2), dtype)
            fn = lambda: cuda_run(xt, Ft, params, thc)
            t0 = time.perf_counter()
            fn()
            first = time.perf_counter() - t0
            secs = best_time(fn, args.repeats)
            timed["cuda_ref"] = fn
            record("cuda_ref", secs, N, law="exact", compile_s=max(first - secs, 0.0))
            check("cuda_ref", cp.asnumpy(thc))

    # --- numpy
    if "numpy" not in skip:
        fn = lambda: lion_numpy(x, F, Phi, Gam0, Gam1, lam, cdc, Gd, h, phi_tiers(args.dtype))
        m0 = rss_mb()
        th = fn()
        secs = best_time(fn, max(1, min(args.repeats, 5)))
        timed["numpy"] = fn
        record("numpy", secs, N, law="exact", peak_rss_growth_mb=rss_mb() - m0)
        check("numpy", th)

    # --- the same implementations again in interleaved rounds (one call each per round): the
    # machine's speed drifts, and the ratios must compare like with like. Each keeps its best.
    if args.rounds:
        print(f"interleaved rounds ({args.rounds}): " + ", ".join(timed), flush=True)
        for _ in range(args.rounds):
            for name, fn in timed.items():
                t0 = time.perf_counter()
                fn()
                dt_run = time.perf_counter() - t0
                if dt_run < out[name]["seconds"]:
                    out[name]["seconds"] = dt_run
                    out[name]["msps"] = N / dt_run / 1e6
                    if "roofline_fraction" in out[name]:
                        out[name]["roofline_fraction"] = N / dt_run / 1e6 / ROOFLINE_MSPS
        for name in timed:
            print(f"{name:>10}: {out[name]['msps']:9.2f} M sample-updates/s (best overall)")

    # --- naive vmap of the per-dataset lax.scan (lionjax.lion, regressors stored)
    if "vmap" not in skip:
        nb = min(B, args.naive_batch)
        sub = lj.Record(
            jnp.asarray(x[:nb]),
            jnp.asarray(F[:nb]),
            jnp.full((nb,), dt, dtype),
            jnp.zeros((nb,), dtype),
        )
        fv = jax.jit(
            jax.vmap(lambda r: lj.lion(model, r, gain=gain, save_every=T, throw=False).theta_final)
        )
        fn = lambda: fv(sub).block_until_ready()
        m0 = rss_mb()
        t0 = time.perf_counter()
        th = np.asarray(fn())
        first = time.perf_counter() - t0
        secs = best_time(fn, args.repeats)
        record(
            "vmap_scan",
            secs,
            nb * T,
            law="exact",
            batch=nb,
            compile_s=max(first - secs, 0.0),
            peak_rss_growth_mb=rss_mb() - m0,
        )
        check("vmap_scan", th)

    # --- the continuous-time references run on a small batch of shorter records (Ts samples);
    # their reference is lj.lion (the exact step, = lion_batched) on the same records
    nb, Ts = min(B, args.small_batch), min(T, args.small_samples)
    small = lj.Record(
        jnp.asarray(x[:nb, :Ts]),
        jnp.asarray(F[:nb, :Ts]),
        jnp.full((nb,), dt, dtype),
        jnp.zeros((nb,), dtype),
    )
    theta_small = np.asarray(
        jax.jit(jax.vmap(lambda r: lj.lion(model, r, gain=gain, save_every=Ts).theta_final))(small)
    )

    # --- diffrax path (continuous-time joint ODE) at a small batch
    if "diffrax" not in skip:
        f32 = args.dtype == "float32"  # tolerances the dtype can reach
        stepper = lj.DiffraxStep(rtol=1e-5 if f32 else 1e-8, atol=1e-9 if f32 else 1e-10)
        fd = jax.jit(
            jax.vmap(
                lambda r: (
                    lj.lion(
                        model, r, gain=gain, stepper=stepper, save_every=Ts, throw=False
                    ).theta_final
                )
            )
        )
        fn = lambda: fd(small).block_until_ready()
        t0 = time.perf_counter()
        th = np.asarray(fn())
        first = time.perf_counter() - t0
        secs = best_time(fn, args.small_repeats)
        record(
            "diffrax",
            secs,
            nb * Ts,
            law="continuous",
            batch=nb,
            samples=Ts,
            rtol=stepper.rtol,
            compile_s=max(first - secs, 0.0),
        )
        err = float(np.max(np.abs(th - theta_small) / np.abs(theta_small)))
        out["diffrax"]["max_rel_diff_vs_lionjax"] = err
        print(f"{'':>10}  continuous vs exact-step law: max relative difference {err:.2e}")

    # --- scipy solve_ivp per dataset at a small batch (same joint ODE, RK45)
    if "scipy" not in skip:
        try:
            from scipy.integrate import solve_ivp
        except ImportError:
            solve_ivp = None
        if solve_ivp is not None:
            A, Bv, _, _ = (np.asarray(a, np.float64) for a in bank.state_space())
            c3 = float(lam[2])
            G64 = G.astype(np.float64)

            def one(i):
                xs, Fs = x64[i], F64[i]

                def rhs(t, y):
                    s = min(t / dt, Ts - 1 - 1e-9)
                    k = int(s)
                    fr = s - k
                    ux = xs[k] + fr * (xs[k + 1] - xs[k])
                    uf = Fs[k]
                    zx, zf, th = y[0:3], y[3:6], y[6:8]
                    W = c3 * np.array([[zx[1], -zf[0]], [zx[2], -zf[1]]])
                    W0 = c3 * np.array(
                        [zx[2], ux - lam[2] * zx[0] - lam[1] * zx[1] - lam[0] * zx[2]]
                    )
                    dth = -G64 @ (W.T @ (W @ th + W0))
                    return np.concatenate([A @ zx + Bv * ux, A @ zf + Bv * uf, dth])

                y0 = np.concatenate([[xs[0] / c3, 0, 0], [Fs[0] / c3, 0, 0], [0, 0]])
                sol = solve_ivp(
                    rhs, (0, (Ts - 1) * dt), y0, method="RK45", rtol=1e-8, atol=1e-12, max_step=dt
                )
                return sol.y[6:8, -1]

            t0 = time.perf_counter()
            th = np.stack([one(i) for i in range(nb)])
            secs = time.perf_counter() - t0  # single run (seconds each)
            record("scipy", secs, nb * Ts, law="continuous", batch=nb, samples=Ts, repeats=1)
            err = float(np.max(np.abs(th - theta_small) / np.abs(theta_small)))
            out["scipy"]["max_rel_diff_vs_lionjax"] = err
            print(f"{'':>10}  continuous vs exact-step law: max relative difference {err:.2e}")

    # --- least squares: streamed sufficient statistics (lionjax), and numpy lstsq reference
    if "ls" not in skip:
        fl = lambda: lj.least_squares_batched(model, recs, throw=False).theta.block_until_ready()
        t0 = time.perf_counter()
        th = np.asarray(fl())
        first = time.perf_counter() - t0
        secs = best_time(fl, args.repeats)
        record("ls_stream", secs, N, compile_s=max(first - secs, 0.0))
        nb = min(B, 64)
        fv = jax.jit(
            jax.vmap(lambda r: lj.least_squares(model, r, initial="discard", throw=False).theta)
        )
        sub = lj.Record(
            jnp.asarray(x[:nb]),
            jnp.asarray(F[:nb]),
            jnp.full((nb,), dt, dtype),
            jnp.zeros((nb,), dtype),
        )
        secs = best_time(lambda: fv(sub).block_until_ready(), args.repeats)
        record("ls_vmap", secs, nb * T, batch=nb)
        ref = np.asarray(fv(sub))
        # records where least_squares gave an estimate (throw=False leaves no finite, nonzero
        # θ where a record is too short for its discarded transient: none to compare with)
        rows = np.all(np.isfinite(ref) & (ref != 0), axis=-1)
        if rows.any():
            err = float(np.max(np.abs(th[:nb][rows] - ref[rows]) / np.abs(ref[rows])))
            note = f"max relative difference {err:.2e} ({int(rows.sum())} of {nb} records)"
        else:
            err = None
            note = "not compared: least_squares gave no estimate on these records"
        out["ls_stream"]["max_rel_diff_vs_least_squares"] = err
        out["ls_stream"]["compared_records"] = int(rows.sum())
        print(f"{'':>10}  streamed LS vs lionjax.least_squares: {note}")

    # --- GPU only: one long record, parallel in time (lion_parallel: associative scans of the
    # filter and of θ) against the sequential loop (lion_batched with B = 1)
    if gpu and "parallel" not in skip:
        Tl = args.long_samples
        xl, Fl = make_data(1, Tl, dt, seed=1)
        rl = lj.Record(jnp.asarray(xl[0], dtype), jnp.asarray(Fl[0], dtype), jnp.asarray(dt, dtype))
        rb = jax.tree.map(lambda a: a[None] if a.ndim else a, rl)
        Gj = jnp.asarray(Gd)
        fp = lambda: lj.lion_parallel(model, rl, Gj).theta_final.block_until_ready()
        fs = lambda: lj.lion_batched(model, rb, gain=gain, throw=False).theta.block_until_ready()
        thp, ths = np.asarray(fp()), np.asarray(fs())[0]
        sp, ss = best_time(fp, args.repeats), best_time(fs, args.repeats)
        record("parallel_in_time", sp, Tl, samples=Tl)
        record("sequential_one_record", ss, Tl, samples=Tl)
        err = float(np.max(np.abs(thp - ths) / np.maximum(np.abs(ths), 1e-12)))
        out["parallel_in_time"]["max_rel_diff_vs_sequential"] = err
        out["parallel_in_time"]["speedup_vs_sequential"] = ss / sp
        print(f"{'':>10}  parallel/sequential speed-up {ss / sp:.1f}x, max rel diff {err:.2e}")

    lj_msps = out["lionjax"]["msps"]
    ratios = {
        k: lj_msps / out[k]["msps"]
        for k in ("numba", "numpy", "vmap_scan", "diffrax", "scipy", "cuda_ref")
        if k in out
    }
    out["ratios"] = {f"lionjax/{k}": v for k, v in ratios.items()}
    out["roofline_msps"] = ROOFLINE_MSPS
    out["peak_rss_mb"] = rss_mb()
    print("ratios: " + ", ".join(f"lionjax/{k} = {v:.2f}x" for k, v in ratios.items()))
    if "lionjax_one_device" in out or "lionjax_unplaced" in out:
        r1 = {
            f"{u}/{k}": out[u]["msps"] / out[k]["msps"]
            for u in ("lionjax_unplaced", "lionjax_one_device")
            for k in ("numba", "numpy")
            if k in out and u in out
        }
        out["ratios"].update(r1)
        print("ratios without placement: " + ", ".join(f"{k} = {v:.2f}x" for k, v in r1.items()))
    if "lionjax_per_record_filters" in out:
        per = out["lionjax_per_record_filters"]["msps"]
        rp = {
            f"lionjax_per_record_filters/{k}": per / out[k]["msps"]
            for k in ("lionjax_unplaced", "lionjax_one_device", "lionjax", "numba")
            if k in out
        }
        out["ratios"].update(rp)
        print("per-record filters: " + ", ".join(f"{k} = {v:.2f}x" for k, v in rp.items()))
    print(
        f"lionjax at {out['lionjax']['roofline_fraction']:.1%} of the ~{ROOFLINE_MSPS:.0f} "
        "M/s roofline"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
        print(f"wrote {args.json}")
    return out


if __name__ == "__main__":
    main()
    sys.exit(0)
