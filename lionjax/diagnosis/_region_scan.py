"""The regions' scan statistic and its null (:func:`step`, :func:`refine`), on block means.

Points: ε₁ [m/s²] and the covariates averaged over blocks of m samples, at most ``n_points``.
The record-wide columns C = L[1, F, v, sgn v, sgn F, t] and the three free responses of
L = λ³/(s + λ)³ (ε₁'s own filter, whose initial state the diagnosis fits) absorb what acts on
the whole record alike. A candidate I, bins [lo, hi) of one variable's quantile bins, adds
D_I = L[c·1_I], the columns gated to I *before* the filter (an effect confined to I reaches ε₁
through it). Its Lagrange-multiplier (Chow) statistic, the misfit I's own correction removes in
residual variances, is

    Λ_I = gᵀ(D_IᵀMD_I)⁻¹g / σ̂²,   g = D_Iᵀr₀,   r₀ = Mε₁,

M the residual maker of C, σ̂² the mean square of r₀; D_I is the sum of its bins' columns, so a
candidate costs a few prefix sums. Each variable's largest Λ is compared with its largest on
resamples of ε₁ (circular shifts against x, v, F; block permutations for t), their tail a
generalised extreme-value law (:func:`_extreme_p`), the six p-values combined by Šidák:
docs/diagnosis.md, "Where the gap lies", states why each.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

#: The variables searched, and those searched for half-lines only (an effect of force or speed
#: sets in at a level: a clip, a dead zone, stiction, drag).
VARIABLES = ("x", "v", "|v|", "F", "|F|", "t")
THRESHOLD_ONLY = ("v", "|v|", "F", "|F|")
#: sub-bins of the two bins next to an edge, where :func:`refine` looks
SUB_BINS = 16


def covariate(name: str, s) -> np.ndarray:
    """The variable ``name`` of the signals ``s`` (t, x, v, F), float64."""
    if name in ("|v|", "|F|"):
        return np.abs(np.asarray(s[name[1]], np.float64))
    return np.asarray(s[name], np.float64)


def within(z: np.ndarray, low, high) -> np.ndarray:
    """low ≤ z < high (``None``: open)."""
    return (z >= (-np.inf if low is None else low)) & (z < (np.inf if high is None else high))


class Settings(NamedTuple):
    alpha: float  # the family-wise level
    min_explained: float  # the least share of the first step's Σr₀² a region explains
    P: int  # resamples per step
    max_regions: int
    bins: int  # quantile bins of each variable
    min_share: float  # the least share of the points on each side of a candidate
    n_points: int  # the most points


def _block_means(a: np.ndarray, m: int) -> np.ndarray:
    n = a.size // m * m
    head = a[:n].reshape(-1, m).mean(1)
    return np.append(head, a[n:].mean()) if n < a.size else head


def _kernel(lam: float, h: float) -> np.ndarray:
    """λ³/(s + λ)³ sampled every h [s]: its impulse response's mass over each interval, from the
    Gamma(3, λ) distribution function (DC gain 1)."""
    K = int(math.ceil(15.0 / max(lam * h, 1e-12))) + 1
    x = np.concatenate([[0.0], (np.arange(K) + 0.5) * h]) * lam
    w = np.diff(1.0 - np.exp(-x) * (1.0 + x + x**2 / 2))
    return w / w.sum()


def _filtered(U: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Each column of U (N, n) through the kernel w, causally, held at its first value before
    the start (an FFT convolution)."""
    N, K = U.shape[0], w.size
    n = 1 << int(math.ceil(math.log2(N + K)))
    y = np.fft.irfft(np.fft.rfft(U, n, axis=0) * np.fft.rfft(w, n)[:, None], n, axis=0)[:N]
    tail = 1.0 - np.cumsum(w)  # the kernel's mass on the samples before the start
    return y + np.pad(tail, (0, max(0, N - K)))[:N, None] * U[:1]


class Points(NamedTuple):
    """The search's data: block means of m samples (the last block may be shorter)."""

    r: np.ndarray  # ε₁ [m/s²], (N,)
    raw: np.ndarray  # the columns before the filter: 1, F, v, sgn v, sgn F, t (scaled), (N, 6)
    C: np.ndarray  # the record-wide columns: raw through L and L's free responses, (N, 9)
    z: dict  # variable name -> (N,)
    w: np.ndarray  # L at the points' spacing
    h: float  # point spacing [s]
    lam: float  # L's λ [1/s]
    lag: int  # L's mean lag 3/λ, in points


def points(sig: dict, filter_hz: float, n_points: int) -> Points:
    """The :class:`Points` of the validated signals (t, x, v, F, residual_base)."""
    t, T = sig["t"], sig["t"].size
    m = max(1, -(-T // n_points))
    h, lam = m * (float(t[-1] - t[0]) / (T - 1)), 2 * math.pi * filter_hz
    F, v, span = sig["F"], sig["v"], max(float(np.ptp(t)), 1e-300)
    means = (  # one (T,) temporary at a time: a long record's signals are large
        _block_means(np.ones(T), m),
        _block_means(F, m),
        _block_means(v, m),
        _block_means(np.sign(v), m),
        _block_means(np.sign(F), m),
        _block_means((t - t.mean()) / span, m),
    )
    raw = np.stack(means, 1)
    w = _kernel(lam, h)
    lt = lam * _block_means(t - t[0], m)
    free = np.stack([lt**j / math.factorial(j) * np.exp(-lt) for j in range(3)], 1)
    r, C = _block_means(sig["residual_base"], m), np.concatenate([_filtered(raw, w), free], 1)
    z = {name: _block_means(covariate(name, sig), m) for name in VARIABLES}
    return Points(r, raw, C, z, w, h, lam, lag=int(math.ceil(3.0 / lam / h)))


class _Binned(NamedTuple):
    """One variable's bins on the active points and the columns gated to each, D = L[c·1_b]."""

    b: np.ndarray  # bin of each active point, (N,)
    edges: np.ndarray  # inner edges, (bins − 1,)
    D: np.ndarray  # (N, bins·k)
    P2: np.ndarray  # prefix sums over (b, b') of DᵀD, (bins + 1, bins + 1, k, k)
    PE: np.ndarray  # prefix sums over b of DᵀC, (bins + 1, k, columns of C)
    counts: np.ndarray  # prefix counts, (bins + 1,)


def _binned(pts: Points, idx: np.ndarray, z: np.ndarray, edges: np.ndarray) -> _Binned:
    nb, k, kc = edges.size + 1, pts.raw.shape[1], pts.C.shape[1]
    b = np.searchsorted(edges, z, side="right")
    U = np.zeros((pts.r.size, nb, k))
    U[idx, b] = pts.raw[idx]  # inactive points gate no bin
    D = _filtered(U.reshape(pts.r.size, nb * k), pts.w)[idx]
    P2 = np.zeros((nb + 1, nb + 1, k, k))
    P2[1:, 1:] = (D.T @ D).reshape(nb, k, nb, k).transpose(0, 2, 1, 3).cumsum(0).cumsum(1)
    PE = np.zeros((nb + 1, k, kc))
    PE[1:] = (D.T @ pts.C[idx]).reshape(nb, k, kc).cumsum(0)
    counts = np.concatenate([[0], np.cumsum(np.bincount(b, minlength=nb))])
    return _Binned(b, edges, D, P2, PE, counts)


def _sym_inv(M: np.ndarray) -> np.ndarray:
    k = M.shape[-1]
    tr = np.trace(M, axis1=-2, axis2=-1)[..., None, None] / k
    return np.linalg.inv(M + (1e-12 * tr + 1e-300) * np.eye(k))


def _schur_inverse(bn: _Binned, lo, hi, CtC: np.ndarray) -> np.ndarray:
    """(D_IᵀMD_I)⁻¹ for each candidate I = bins [lo, hi), (n_cand, k, k)."""
    Q = bn.P2[hi, hi] - bn.P2[lo, hi] - bn.P2[hi, lo] + bn.P2[lo, lo]
    E = bn.PE[hi] - bn.PE[lo]
    return _sym_inv(Q - E @ _sym_inv(CtC) @ np.swapaxes(E, -1, -2))


def _cumulative(S: np.ndarray) -> np.ndarray:
    """Sums over bins (..., bins) → cumulative with a leading 0 (..., bins + 1)."""
    return np.concatenate([np.zeros(S.shape[:-1] + (1,)), np.cumsum(S, -1)], -1)


def _gains(Y0, s2, bn: _Binned, lo, hi, Qinv) -> np.ndarray:
    """Λ_I of each row of Y0 (R, N: r₀ and its resamples, σ̂² ``s2`` (R,)): (R, n_cand)."""
    nb, k = bn.edges.size + 1, Qinv.shape[-1]
    G = _cumulative((Y0 @ bn.D).reshape(-1, nb, k).transpose(0, 2, 1))
    g = (G[:, :, hi] - G[:, :, lo]).transpose(2, 0, 1)  # (n_cand, R, k)
    return ((g @ Qinv) * g).sum(-1).T / s2[:, None]


class _Candidates(NamedTuple):
    """The candidate regions of one variable: bins [lo, hi), their inverses and point counts."""

    bn: _Binned
    lo: np.ndarray
    hi: np.ndarray
    Qinv: np.ndarray
    n: np.ndarray


def _candidates(pts: Points, idx, name: str, bins: int, min_n: int, CtC) -> _Candidates:
    """Half-lines of every variable, intervals of x and t holding at most half the points (a
    region is the minority regime); at least ``min_n`` points on each side."""
    z = pts.z[name][idx]
    bn = _binned(pts, idx, z, np.quantile(z, np.arange(1, bins) / bins))
    lo, hi = (a.ravel() for a in np.triu_indices(bins + 1, 1))
    half = (lo == 0) | (hi == bins)
    n = bn.counts[hi] - bn.counts[lo]
    keep = ~((lo == 0) & (hi == bins)) & (n >= min_n) & (z.size - n >= min_n)
    keep &= half if name in THRESHOLD_ONLY else half | (2 * n <= z.size)
    lo, hi, n = lo[keep], hi[keep], n[keep]
    return _Candidates(bn, lo, hi, _schur_inverse(bn, lo, hi, CtC), n)


def flipped(cand: _Candidates, c) -> np.ndarray:
    """Whether candidate c is reported as its complement: a half-line holding the majority (the
    record-wide fit follows the majority: a side holding a share π of the points departs
    (1 − π)/π times as far as the other)."""
    half = (cand.lo[c] == 0) | (cand.hi[c] == cand.bn.edges.size + 1)
    return half & (cand.n[c] > cand.bn.b.size / 2)


def _excess_share(Y, cand: _Candidates, best: np.ndarray) -> np.ndarray:
    """Per row of Y (R, N): the share of Σy² in the row's selected candidate (on its minority
    side, as reported) less its share of the points."""
    E = _cumulative((Y * Y) @ np.eye(cand.bn.edges.size + 1)[cand.bn.b])
    rows = np.arange(Y.shape[0])
    inside = (E[rows, cand.hi[best]] - E[rows, cand.lo[best]]) / np.maximum(E[:, -1], 1e-300)
    frac = cand.n[best] / cand.bn.b.size
    return np.where(flipped(cand, best), frac - inside, inside - frac)


def _shift_rows(rng, N: int, P: int) -> np.ndarray:
    """P circular shifts of N points, by at least N/20 either way, (P, N): the null of x, v and
    F (ε₁ independent of the covariates), each series' autocorrelation kept."""
    lo = max(1, N // 20)
    sh = rng.integers(lo, N - lo + 1, P)
    return (np.arange(N)[None, :] + sh[:, None]) % N


def _block_rows(rng, N: int, P: int, L: int) -> np.ndarray:
    """P permutations of blocks of L points, each from a random circular offset, (P, N): the null
    of t, which a shift cannot test (it moves a time profile whole)."""
    K = -(-N // L)
    out = np.empty((P, N), np.int64)
    for i in range(P):
        idx = (rng.permutation(K)[:, None] * L + np.arange(L)[None, :]).ravel()
        out[i] = (idx[idx < N] + rng.integers(N)) % N
    return out


def _extreme_p(x: np.ndarray, null: np.ndarray) -> np.ndarray:
    """P(M ≥ x) for the maximum M of a scan (x (V,)), from a generalised extreme-value law
    fitted by L-moments (Hosking, Wallis & Wood 1985) to its resampled maxima ``null`` (P, V),
    so that p-values below 1/P come from P resamples: Gumbel's law (shape k = 0, Abrams,
    Kleinman & Kulldorff 2010) where the tail is Gumbel's, a bounded tail (k > 0) or a heavy one
    (k < 0) where the resamples show one. Hosking's rational approximation of k is accurate
    within 9·10⁻⁴ for |k| ≤ 0.5, the range k is held to."""
    s = np.sort(null, 0)
    n = s.shape[0]
    i = np.arange(n)[:, None]
    b0 = s.mean(0)
    b1 = (i / (n - 1) * s).mean(0)
    b2 = (i * (i - 1) / ((n - 1) * (n - 2)) * s).mean(0)
    l2 = np.maximum(2 * b1 - b0, 1e-300)
    t3 = (6 * b2 - 6 * b1 + b0) / l2
    c = 2 / (3 + t3) - math.log(2) / math.log(3)
    k = np.clip(7.8590 * c + 2.9554 * c * c, -0.5, 0.5)
    p = np.empty(np.shape(x))
    for j, (kj, l1, l2j, xj) in enumerate(zip(k, b0, l2, x, strict=True)):
        if abs(kj) < 1e-6:  # Gumbel
            a = l2j / math.log(2)
            p[j] = -math.expm1(-math.exp(-(xj - (l1 - 0.5772156649015329 * a)) / a))
            continue
        g = math.gamma(1 + kj)
        a = l2j * kj / ((1 - 2.0**-kj) * g)
        y = 1 - kj * (xj - (l1 + a * (g - 1) / kj)) / a
        p[j] = -math.expm1(-(y ** (1 / kj))) if y > 0 else float(kj < 0)
    return p


class Found(NamedTuple):
    """One step's winner on the active points (before :func:`refine`)."""

    name: str
    cand: _Candidates
    c: int  # the winning candidate's index
    statistic: float
    p_value: float  # adjusted over the variables and candidates
    bias: float  # the null's mean excess share of the selected region
    explained: float  # Λ·σ̂²: the misfit (Σr₀²) the region's own correction removes
    total: float  # Σr₀² over the active points


def step(pts: Points, active, rng, cfg: Settings, block: int) -> Found | None:
    """The strongest candidate region on the ``active`` points (bool, (N,)) and its p-value;
    ``block``: the time permutation's block, in points. None: no candidate fits."""
    idx = np.flatnonzero(active)
    N, P = idx.size, cfg.P
    r, C = pts.r[idx], pts.C[idx]
    min_n = max(2 * pts.raw.shape[1] + 2, int(math.ceil(cfg.min_share * N)))
    if N < 2 * min_n + 2:
        return None
    CtC = C.T @ C
    Y = np.concatenate([r[None], r[_shift_rows(rng, N, P)], r[_block_rows(rng, N, P, block)]])
    Y0 = Y - ((Y @ C) @ _sym_inv(CtC)) @ C.T
    s2 = np.maximum((Y0 * Y0).mean(1), 1e-300)
    V = len(VARIABLES)
    obs, null, keep = np.full(V, -np.inf), np.full((P, V), -np.inf), {}
    for i, name in enumerate(VARIABLES):
        cand = _candidates(pts, idx, name, cfg.bins, min_n, CtC)
        if not cand.lo.size:
            continue
        rows = np.r_[0, (P + 1 + np.arange(P)) if name == "t" else 1 + np.arange(P)]
        g = _gains(Y0[rows], s2[rows], cand.bn, cand.lo, cand.hi, cand.Qinv)
        best = g.argmax(1)
        obs[i], null[:, i] = g[0, best[0]], g[1:][np.arange(P), best[1:]]
        bias = float(np.mean(_excess_share(Y[rows[1:]], cand, best[1:])))
        keep[name] = cand, int(best[0]), bias
    if not keep:
        return None
    p, on = np.ones(V), np.isfinite(obs)
    # beyond a bounded tail's end the law gives 0; the end is an estimate: 10⁻¹⁶, not 0
    p_one = np.clip(_extreme_p(obs[on], null[:, on]), 1e-16, 1.0 - 1e-16)
    p[on] = -np.expm1(V * np.log1p(-p_one))  # Šidák: conservative, the scans positively dependent
    # of the significant variables, the region whose correction removes the most misfit
    sig = np.flatnonzero(p <= cfg.alpha)
    i = int(sig[np.argmax(obs[sig])]) if sig.size else int(np.argmin(p))
    cand, c, bias = keep[VARIABLES[i]]
    s = float(s2[0])
    return Found(VARIABLES[i], cand, c, float(obs[i]), float(p[i]), bias, obs[i] * s, s * N)


def refine(pts: Points, active, found: Found) -> tuple[float | None, float | None]:
    """The winner's (low, high), each closed edge moved to the best of :data:`SUB_BINS`
    quantile steps across the two bins next to it, on its minority side."""
    idx = np.flatnonzero(active)
    z, C, r = pts.z[found.name][idx], pts.C[idx], pts.r[idx]
    CtC = C.T @ C
    r0 = r - C @ (_sym_inv(CtC) @ (C.T @ r))
    s2 = np.array([max(float(np.mean(r0 * r0)), 1e-300)])
    cand, edges = found.cand, found.cand.bn.edges
    nb, lo, hi = edges.size + 1, int(cand.lo[found.c]), int(cand.hi[found.c])
    bounds = [None if lo == 0 else edges[lo - 1], None if hi == nb else edges[hi - 1]]
    for side, j in ((0, lo), (1, hi)):
        if bounds[side] is None:
            continue
        near = z[within(z, edges[j - 2] if j >= 2 else None, edges[j] if j < nb - 1 else None)]
        steps = np.quantile(near, np.arange(1, SUB_BINS) / SUB_BINS) if near.size else np.zeros(0)
        grid = np.unique(np.concatenate([np.delete(edges, j - 1), steps]))
        bn = _binned(pts, idx, z, grid)
        at = np.searchsorted(grid, steps) + 1  # each step as a bin boundary of the new grid
        other = bounds[1 - side]
        fixed = (
            np.searchsorted(grid, other) + 1 if other is not None else 0 if side else grid.size + 1
        )
        a_, b_ = (at, np.full_like(at, fixed)) if side == 0 else (np.full_like(at, fixed), at)
        n = bn.counts[b_] - bn.counts[a_]
        ok = (b_ > a_) & (n > 0) & (n < z.size)
        if ok.any():
            Qinv = _schur_inverse(bn, a_[ok], b_[ok], CtC)
            g = _gains(r0[None], s2, bn, a_[ok], b_[ok], Qinv)[0]
            bounds[side] = float(steps[ok][int(np.argmax(g))])
    low, high = bounds
    if flipped(cand, found.c):
        low, high = (high, None) if low is None else (None, low)
    return (None if low is None else float(low)), (None if high is None else float(high))
