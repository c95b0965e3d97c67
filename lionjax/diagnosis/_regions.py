"""Where the gap lies: regions of the validation record searched in the data, at a stated
family-wise error rate (:func:`find_regions`, :class:`Region`).

A region is a set of validation samples where the dynamics depart from the rest of the record:
a half-line or an interval of one variable z ∈ {x, v, |v|, F, |F|, t}. The search is the idea of
model-based recursive partitioning (Zeileis, Hothorn & Hornik 2008, partykit's ``mob``): fit a
model to the whole record, test whether its parameters change across a partitioning variable,
split where they change most. Here the model is a correction of the baseline's filtered
equation error ε₁ (``residual_base``, the mass–damper fitted on the training record):

1. ε₁ is averaged over blocks of m samples (``n_points`` points at most) and regressed on the
   columns C = L[1, F, v, sgn v, sgn F, t] (L = λ³/(s + λ)³ at ``filter_hz``, ε₁'s own
   filter): the record-wide correction, r₀ = ε₁ − Cβ̂. Its six columns absorb whatever acts on
   the whole record alike (a gain or damping error, Coulomb friction, an offset, a linear
   drift), which is not a region.
2. A region I adds its own correction D_I = L[c·1_I], the same columns gated to I *before* the
   filter: an effect confined to I reaches ε₁ through the filter, so its misfit trails I's
   samples by the filter's lag. A clip above F_max or a dead zone changes the gain on F and adds
   a term in sgn F inside; friction on a stretch of rail adds sgn v there; a payload scales the
   F and v terms from a moment on; a drift adds a growing constant. The statistic is the
   Lagrange-multiplier (Chow) statistic of adding D_I,
   Λ_I = gᵀ(D_IᵀMD_I)⁻¹g / σ̂², g = D_Iᵀr₀, M the residual maker of C, σ̂² the mean square of
   r₀: the misfit that I's own correction removes, in residual variances. Candidates lie on
   ``bins`` quantile bins of z (D_I is the sum of its bins' gated columns, so every candidate
   costs a few prefix sums): half-lines of v, |v|, F and |F| (a force or velocity effect sets in
   at a level: a clip, a dead zone, stiction, drag) and intervals and half-lines of x and t (a
   spot on the rail, an episode), each side holding at least ``min_share`` of the points and an
   interval at most half of them.
3. Calibration: each variable's largest Λ is compared with its largest Λ on resamples of the
   residual, the covariates held: circular shifts of the residual's series against x, v, F
   (which keep the autocorrelation of both; under the null the residual process is
   independent of the covariates' process), and for t permutations of blocks of
   max(0.25 s, 20/λ) (a shift moves a time profile whole and cannot test one; the blocks keep
   the residual's short-range dependence). The tail of the resampled maxima is a Gumbel law
   fitted by moments (Abrams, Kleinman & Kulldorff 2010: small p-values from few resamples), and
   the six variables' p-values are adjusted by Šidák (their scans are positively dependent: a
   conservative combination). Of the variables significant at ``alpha``, the region is the one
   whose correction removes the most misfit.
4. Several regions: the iterative scan (Zhang, Assunção & Kulldorff 2010): the accepted
   region's points (and the filter's lag after them) are set aside and the search runs again on
   the rest with fresh resamples, until a step is not significant (p-values kept non-decreasing
   along the steps) or its region explains less than ``min_explained`` of the first step's
   misfit Σr₀².
5. A half-line splits the record in two regimes; the region is the side holding fewer samples:
   the record-wide fit follows the majority, so the minority departs from it (by the
   least-squares weights, a side holding a share π of the points departs (1 − π)/π times as
   far as the other). Each edge is then refined over ``SUB_BINS`` quantile steps across the two
   bins next to it.
6. Effect sizes: ``gap_share`` is the region's share of the baseline's misfit Σε₁² less the
   mean excess share (share − sample share) of the regions the search selects on the
   resamples: the selection's own bias, so that the worst slice is not overstated.

The search is for structure in the model's error, so structure of the measurement is found too:
encoder quantisation's error in ε₁ depends on the speed (resolved steps at low |v|, aliasing
where the axis moves a whole number of counts per sample), and a closed loop on a quantised
position limit-cycles at rest. Those regions are significant and explain little of the
misfit: ``min_explained`` (default 5 %) is the least share of it a region must explain to be
reported. On 60 clean development records of both simulators (benchmarks/regions_blind.py),
20 had a significant region, each explaining 0.3–2.4 % of the misfit; 150 of 151 planted
regions found explained 15–100 % (the other 1.5 %).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

import equinox as eqx
import numpy as np
from threadpoolctl import threadpool_limits

from .._errors import InputError

#: The variables searched, their units, and those searched for thresholds only.
VARIABLES = ("x", "v", "|v|", "F", "|F|", "t")
UNITS = {"x": "m", "v": "m/s", "|v|": "m/s", "F": "N", "|F|": "N", "t": "s"}
THRESHOLD_ONLY = ("v", "|v|", "F", "|F|")
#: the shortest block of the time permutation [s]
BLOCK_S = 0.25


class Region(eqx.Module):
    """One region of the validation record where the dynamics depart from the rest.

    Attributes:
        variable: one of ``x``, ``v``, ``|v|``, ``F``, ``|F|``, ``t``.
        low, high: the bounds [SI units: m, m/s, N, s; t in the validation record's own time];
            ``None`` for an open side.
        gap_share: the region's share of the baseline's validation misfit (Σ ε₁²), less the
            selection's bias (see the module).
        sample_share: its share of the validation samples. The shares of a later region count
            the samples the earlier regions leave (the search's later steps run on those).
        p_value: adjusted for all variables, candidates and earlier steps.
        stack_removes: 1 − Σε₁²(stack)/Σε₁²(baseline) over the region's samples: how far the
            verdict's stack shrinks the misfit there (``None``: no stack given).
        simulation_share: the region's share of the baseline's windowed-simulation error
            (Σ e_sim²), or ``None``.
        statistic: the region's Lagrange-multiplier (Chow) statistic Λ: the misfit its own
            correction removes, in residual variances.
    """

    variable: str
    low: float | None
    high: float | None
    gap_share: float
    sample_share: float
    p_value: float
    stack_removes: float | None
    simulation_share: float | None
    statistic: float

    def mask(self, signals: Mapping[str, np.ndarray]) -> np.ndarray:
        """The samples of ``signals`` (t, x, v, F) the region covers: low ≤ z < high."""
        return _within(_covariate(self.variable, signals), self.low, self.high)

    def to_json(self) -> dict:
        """The JSON fields (``units`` added: SI, of ``variable``)."""
        return {
            "variable": self.variable,
            "low": self.low,
            "high": self.high,
            "units": UNITS[self.variable],
            "gap_share": self.gap_share,
            "sample_share": self.sample_share,
            "p_value": self.p_value,
            "stack_removes": self.stack_removes,
            "simulation_share": self.simulation_share,
            "statistic": self.statistic,
        }

    def describe(self) -> str:
        """One line, e.g. ``|F| > 0.71 N: 24 % of samples, 68 % of the gap, p < 0.001; the
        stack removes 81 % of it``."""
        u, z = UNITS[self.variable], self.variable
        if self.low is not None and self.high is not None:
            where = f"{self.low:.3g} ≤ {z} < {self.high:.3g} {u}"
        elif self.low is not None:
            where = f"{z} > {self.low:.3g} {u}"
        else:
            where = f"{z} < {self.high:.3g} {u}"
        p = "p < 0.001" if self.p_value < 0.001 else f"p = {self.p_value:.3f}"
        head = (
            f"{where}: {100 * self.sample_share:.0f} % of samples, "
            f"{100 * self.gap_share:.0f} % of the gap, {p}"
        )
        if self.stack_removes is None:
            return f"{head}; no effect is stacked"
        if self.stack_removes < 0:
            return f"{head}; the stack adds {-100 * self.stack_removes:.0f} % to it"
        return f"{head}; the stack removes {100 * self.stack_removes:.0f} % of it"


def _covariate(name, s) -> np.ndarray:
    if name in ("|v|", "|F|"):
        return np.abs(np.asarray(s[name[1]], np.float64))
    return np.asarray(s[name], np.float64)


# ------------------------------------------------------------------------------------- input

_REQUIRED = ("t", "x", "v", "F", "residual_base")
#: the fewest samples a search needs: 20 points per side of the smallest region
MIN_SAMPLES = 200


def _validated(signals) -> dict[str, np.ndarray]:
    """The signals as float64 arrays of one length T, checked."""
    if not isinstance(signals, Mapping):
        raise InputError(
            "find_regions: argument 'signals' must be a mapping of arrays (t, x, v, F, "
            f"residual_base; optionally residual_final, sim_base), got {type(signals).__name__}."
        )
    out = {}
    for k in (*_REQUIRED, "residual_final", "sim_base"):
        if k not in signals or signals[k] is None:
            if k in _REQUIRED:
                raise InputError(
                    f"find_regions: signals lack {k!r}; expected the arrays t [s], x [m], "
                    "v [m/s], F [N] and residual_base (ε₁ [m/s²]) of one length."
                )
            continue
        a = np.asarray(signals[k], np.float64)
        if a.ndim != 1:
            raise InputError(f"find_regions: signals[{k!r}] must be 1-D, got shape {a.shape}.")
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            raise InputError(
                f"find_regions: signals[{k!r}] holds {bad.size} non-finite values (first at "
                f"sample {int(bad[0])}); remove or repair them before the search."
            )
        out[k] = a
    T = out["t"].size
    for k, a in out.items():
        n_ok = a.size <= T if k == "sim_base" else a.size == T
        if not n_ok:
            raise InputError(
                f"find_regions: signals[{k!r}] has {a.size} samples, t has {T}; pass arrays of "
                "one length (sim_base may be shorter: the windowed simulation's whole windows)."
            )
    if T < MIN_SAMPLES:
        raise InputError(f"find_regions: needs at least {MIN_SAMPLES} samples, got {T}.")
    if not np.all(np.diff(out["t"]) > 0):
        raise InputError("find_regions: signals['t'] must increase strictly (sample times [s]).")
    return out


# ------------------------------------------------------------------------------------- points


def _block_means(a: np.ndarray, m: int) -> np.ndarray:
    n = a.size // m * m
    head = a[:n].reshape(-1, m).mean(1)
    return np.append(head, a[n:].mean()) if n < a.size else head


def _kernel(lam: float, h: float) -> np.ndarray:
    """λ³/(s + λ)³ sampled every h [s]: its impulse response's mass over each sample interval,
    from the Gamma(3, λ) distribution function (DC gain 1)."""
    K = int(math.ceil(15.0 / max(lam * h, 1e-12))) + 1
    x = np.concatenate([[0.0], (np.arange(K) + 0.5) * h]) * lam
    w = np.diff(1.0 - np.exp(-x) * (1.0 + x + x**2 / 2))
    return w / w.sum()


def _filtered(U: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Each column of U (N, n) through the kernel w, causally, each held at its first value
    before the start (an FFT convolution)."""
    N, K = U.shape[0], w.size
    n = 1 << int(math.ceil(math.log2(N + K)))
    y = np.fft.irfft(np.fft.rfft(U, n, axis=0) * np.fft.rfft(w, n)[:, None], n, axis=0)[:N]
    tail = 1.0 - np.cumsum(w)  # the kernel's mass on the samples before the start
    return y + np.pad(tail, (0, max(0, N - K)))[:N, None] * U[:1]


class _Points(NamedTuple):
    """The search's data: block means of m samples (the last block may be shorter)."""

    r: np.ndarray  # ε₁ [m/s²], (N,)
    raw: np.ndarray  # the columns before the filter: 1, F, v, sgn v, sgn F, t (scaled), (N, 6)
    C: np.ndarray  # the columns through ε₁'s filter and its three free responses, (N, 9)
    z: dict  # variable name -> (N,) block means
    w: np.ndarray  # ε₁'s filter at the points' spacing
    h: float  # point spacing [s]
    lam: float  # the filter's λ [1/s]
    lag: int  # the filter's mean lag 3/λ, in points


def _points(sig: dict, filter_hz: float, n_points: int) -> _Points:
    T = sig["t"].size
    m = max(1, -(-T // n_points))
    dt = float(sig["t"][-1] - sig["t"][0]) / (T - 1)
    h, lam = m * dt, 2 * math.pi * filter_hz
    F, v, t = sig["F"], sig["v"], sig["t"]
    tt = (t - t.mean()) / max(float(np.ptp(t)), 1e-300)
    raw = np.stack([_block_means(u, m) for u in (np.ones(T), F, v, np.sign(v), np.sign(F), tt)], 1)
    w = _kernel(lam, h)
    z = {name: _block_means(_covariate(name, sig), m) for name in VARIABLES}
    lag = int(math.ceil(3.0 / lam / h))
    r = _block_means(sig["residual_base"], m)
    # the filter's free responses (λt)ʲ/j!·e^(−λt), j = 0, 1, 2: ε₁'s start from the filter's
    # initial state, which the diagnosis fits and no region should
    lt = lam * _block_means(t - t[0], m)
    free = np.stack([lt**j / math.factorial(j) * np.exp(-lt) for j in range(3)], 1)
    return _Points(r, raw, np.concatenate([_filtered(raw, w), free], 1), z, w, h, lam, lag)


# ------------------------------------------------------------------------------------- search


class _Binned(NamedTuple):
    """One variable's bins on the active points, with the columns gated to each bin before
    ε₁'s filter, L[c·1_b]: an effect confined to a region enters ε₁ so (its misfit follows the
    region's samples through the filter), and a region's columns are the sum over its bins."""

    b: np.ndarray  # bin of each active point, (N,)
    edges: np.ndarray  # inner edges, (bins − 1,)
    D: np.ndarray  # L[c·1_b] on the active points, (N, bins·k)
    P2: np.ndarray  # prefix sums over (b, b') of DᵀD, (bins + 1, bins + 1, k, k)
    PE: np.ndarray  # prefix sums over b of DᵀC, (bins + 1, k, columns of C)
    counts: np.ndarray  # prefix counts, (bins + 1,)


def _binned(pts: _Points, idx: np.ndarray, z: np.ndarray, edges: np.ndarray) -> _Binned:
    nb, k = edges.size + 1, pts.raw.shape[1]
    b = np.searchsorted(edges, z, side="right")
    U = np.zeros((pts.r.size, nb, k))
    U[idx, b] = pts.raw[idx]  # inactive points gate no bin
    D = _filtered(U.reshape(pts.r.size, nb * k), pts.w)[idx]
    A = (D.T @ D).reshape(nb, k, nb, k).transpose(0, 2, 1, 3)
    P2 = np.zeros((nb + 1, nb + 1, k, k))
    P2[1:, 1:] = A.cumsum(0).cumsum(1)
    kc = pts.C.shape[1]
    PE = np.zeros((nb + 1, k, kc))
    PE[1:] = (D.T @ pts.C[idx]).reshape(nb, k, kc).cumsum(0)
    counts = np.concatenate([[0], np.cumsum(np.bincount(b, minlength=nb))])
    return _Binned(b, edges, D, P2, PE, counts)


def _schur_inverse(bn: _Binned, lo, hi, CtC: np.ndarray) -> np.ndarray:
    """(D_Iᵀ M D_I)⁻¹ for each candidate I = bins [lo, hi), M the residual maker of the
    record-wide columns C: the information of the region's own correction beyond C's."""
    P2 = bn.P2
    Q = P2[hi, hi] - P2[lo, hi] - P2[hi, lo] + P2[lo, lo]
    E = bn.PE[hi] - bn.PE[lo]
    return _sym_inv(Q - E @ _sym_inv(CtC) @ np.swapaxes(E, -1, -2))


def _gains(Y0, s2, bn: _Binned, lo, hi, Qinv) -> np.ndarray:
    """Λ_I = g_Iᵀ(D_IᵀMD_I)⁻¹g_I/σ̂², g_I = D_Iᵀr₀, for each row of Y0 (R, N): (R, n_cand)."""
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


def _candidates(pts, idx, name: str, bins: int, min_n: int, CtC) -> _Candidates:
    z = pts.z[name][idx]
    bn = _binned(pts, idx, z, np.quantile(z, np.arange(1, bins) / bins))
    lo, hi = (a.ravel() for a in np.triu_indices(bins + 1, 1))
    keep = ~((lo == 0) & (hi == bins))
    if name in THRESHOLD_ONLY:
        keep &= (lo == 0) | (hi == bins)
    n = bn.counts[hi] - bn.counts[lo]
    keep &= (n >= min_n) & (z.size - n >= min_n)
    # a region is the minority regime: an interval inside the range holds at most half the
    # points (a half-line is reported on its smaller side, see _flipped)
    keep &= (lo == 0) | (hi == bins) | (2 * n <= z.size)
    lo, hi, n = lo[keep], hi[keep], n[keep]
    return _Candidates(bn, lo, hi, _schur_inverse(bn, lo, hi, CtC), n)


def _sym_inv(M: np.ndarray) -> np.ndarray:
    k = M.shape[-1]
    tr = np.trace(M, axis1=-2, axis2=-1)[..., None, None] / k
    return np.linalg.inv(M + (1e-12 * tr + 1e-300) * np.eye(k))


def _cumulative(S: np.ndarray) -> np.ndarray:
    """Sums over bins (..., bins) → cumulative with a leading 0 (..., bins + 1)."""
    return np.concatenate([np.zeros(S.shape[:-1] + (1,)), np.cumsum(S, -1)], -1)


def _one_hot(b: np.ndarray, bins: int) -> np.ndarray:
    M = np.zeros((b.size, bins))
    M[np.arange(b.size), b] = 1.0
    return M


def _shift_rows(rng, N: int, P: int) -> np.ndarray:
    """P circular shifts of a series of N points, by at least N/20 either way."""
    lo = max(1, N // 20)
    sh = rng.integers(lo, N - lo + 1, P)
    return (np.arange(N)[None, :] + sh[:, None]) % N


def _block_rows(rng, N: int, P: int, L: int) -> np.ndarray:
    """P permutations of blocks of L points, each from a random circular offset."""
    K = -(-N // L)
    out = np.empty((P, N), np.int64)
    for i in range(P):
        order = rng.permutation(K)
        idx = (order[:, None] * L + np.arange(L)[None, :]).ravel()
        out[i] = (idx[idx < N] + rng.integers(N)) % N
    return out


class _Found(NamedTuple):
    """One step's winner on the active points (before the edges' refinement)."""

    name: str
    cand: _Candidates
    c: int  # the winning candidate's index
    statistic: float
    p_value: float
    bias: float  # the null's mean excess share of the selected region
    explained: float  # Λ·σ̂²: the misfit (Σr₀²) the region's own correction removes
    total: float  # Σr₀² over the active points


def _excess_share(Y, cand: _Candidates, best: np.ndarray) -> np.ndarray:
    """Per row of Y (R, N): share of Σy² in the row's selected candidate minus its point share,
    the candidate taken on its minority side (as the region is reported)."""
    E = _cumulative((Y * Y) @ _one_hot(cand.bn.b, cand.bn.edges.size + 1))
    rows = np.arange(Y.shape[0])
    inside = (E[rows, cand.hi[best]] - E[rows, cand.lo[best]]) / np.maximum(E[:, -1], 1e-300)
    frac = cand.n[best] / cand.bn.b.size
    return np.where(_flipped(cand, best), frac - inside, inside - frac)


def _flipped(cand: _Candidates, c) -> np.ndarray:
    """Whether a candidate is reported as its complement: a half-line holding the majority."""
    half = (cand.lo[c] == 0) | (cand.hi[c] == cand.bn.edges.size + 1)
    return half & (cand.n[c] > cand.bn.b.size / 2)


def _gumbel_p(x: np.ndarray, null: np.ndarray) -> np.ndarray:
    """P(M ≥ x) for the maximum M of a scan, from a Gumbel law fitted by moments to its
    resampled maxima ``null`` (P, V) (the approximation of Abrams, Kleinman & Kulldorff 2010 for
    scan statistics: small p-values from few resamples)."""
    beta = np.maximum(null.std(0), 1e-300) * math.sqrt(6.0) / math.pi
    mu = null.mean(0) - 0.5772156649015329 * beta
    return -np.expm1(-np.exp(-(x - mu) / beta))


def _step(pts: _Points, active, rng, cfg: _Settings, block: int) -> _Found | None:
    """The strongest candidate region on the active points and its adjusted p-value."""
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
    obs, null, keep = np.full(len(VARIABLES), -np.inf), np.full((P, len(VARIABLES)), -np.inf), {}
    for i, name in enumerate(VARIABLES):
        cand = _candidates(pts, idx, name, cfg.bins, min_n, CtC)
        if not cand.lo.size:
            continue
        # the observed row, then the variable's resamples: block permutations for t, else shifts
        rows = np.r_[0, (P + 1 + np.arange(P)) if name == "t" else 1 + np.arange(P)]
        g = _gains(Y0[rows], s2[rows], cand.bn, cand.lo, cand.hi, cand.Qinv)
        best = g.argmax(1)
        obs[i], null[:, i] = g[0, best[0]], g[1:][np.arange(P), best[1:]]
        keep[name] = (
            cand,
            int(best[0]),
            float(np.mean(_excess_share(Y[rows[1:]], cand, best[1:]))),
        )
    if not keep:
        return None
    # each variable's p-value, adjusted over the variables (Šidák: their scans are positively
    # dependent, so this is conservative)
    p = np.ones(len(VARIABLES))
    on = np.isfinite(obs)
    p_one = np.minimum(_gumbel_p(obs[on], null[:, on]), 1.0 - 1e-16)
    p[on] = -np.expm1(len(VARIABLES) * np.log1p(-p_one))
    # the strongest region: of the significant ones, the one that explains the most misfit
    sig = np.flatnonzero(p <= cfg.alpha)
    i = int(sig[np.argmax(obs[sig])]) if sig.size else int(np.argmin(p))
    cand, c, bias = keep[VARIABLES[i]]
    total = float(s2[0]) * N
    return _Found(VARIABLES[i], cand, c, float(obs[i]), float(p[i]), bias, obs[i] * s2[0], total)


# ------------------------------------------------------------------------------------- edges


#: sub-bins of the two bins next to an edge, where the edge's refinement looks
SUB_BINS = 16


def _refine(pts: _Points, active, found: _Found):
    """The winner's edges, each moved to the best of ``SUB_BINS`` quantile steps across the two
    bins next to it, as (low, high) values of the variable, on the side with fewer points."""
    idx = np.flatnonzero(active)
    z, C, r = pts.z[found.name][idx], pts.C[idx], pts.r[idx]
    CtC = C.T @ C
    r0 = r - C @ (_sym_inv(CtC) @ (C.T @ r))
    cand, nb = found.cand, found.cand.bn.edges.size + 1
    edges = cand.bn.edges
    lo, hi = int(cand.lo[found.c]), int(cand.hi[found.c])
    bounds = [None if lo == 0 else edges[lo - 1], None if hi == nb else edges[hi - 1]]
    for side, j in ((0, lo), (1, hi)):
        if bounds[side] is None:  # an open end
            continue
        # the two bins next to the edge: between the edges either side of it
        left = edges[j - 2] if j >= 2 else -np.inf
        right = edges[j] if j < nb - 1 else np.inf
        near = z[(z >= left) & (z < right)]
        steps = np.quantile(near, np.arange(1, SUB_BINS) / SUB_BINS) if near.size else []
        grid = np.unique(np.concatenate([np.delete(edges, j - 1), steps]))
        bn = _binned(pts, idx, z, grid)
        at = np.searchsorted(grid, steps) + 1  # each step as a bin boundary of the new grid
        other = bounds[1 - side]
        fixed = (
            (0 if side == 1 else grid.size + 1)
            if other is None
            else np.searchsorted(grid, other) + 1
        )
        a_, b_ = (at, np.full_like(at, fixed)) if side == 0 else (np.full_like(at, fixed), at)
        n = bn.counts[b_] - bn.counts[a_]
        ok = (b_ > a_) & (n > 0) & (n < z.size)
        if ok.any():
            Qinv = _schur_inverse(bn, a_[ok], b_[ok], CtC)
            s2 = np.array([max(float(np.mean(r0 * r0)), 1e-300)])
            g = _gains(r0[None], s2, bn, a_[ok], b_[ok], Qinv)[0]
            bounds[side] = float(np.asarray(steps)[ok][int(np.argmax(g))])
    low, high = bounds
    if _flipped(cand, found.c):  # a half-line holding the majority: the other side
        low, high = (high, None) if low is None else (None, low)
    return (None if low is None else float(low)), (None if high is None else float(high))


def _within(z: np.ndarray, low, high) -> np.ndarray:
    return (z >= (-np.inf if low is None else low)) & (z < (np.inf if high is None else high))


def _beside(name: str, low, high, earlier: list[Region]):
    """The bounds less an earlier half-line of the same variable that they overlap: a later
    step searches the samples the earlier regions leave (v < 0.04 after v < −0.02 is
    −0.02 ≤ v < 0.04)."""
    for r in earlier:
        if r.variable != name or (r.low is None) == (r.high is None):
            continue
        if r.low is None and (low is None or low < r.high) and (high is None or high > r.high):
            low = r.high
        elif r.high is None and (high is None or high > r.low) and (low is None or low < r.low):
            high = r.low
    return low, high


def _region(sig: dict, found: _Found, low, high, p_value: float, taken: np.ndarray) -> Region:
    """The region's shares over the validation samples that earlier regions left (``taken``:
    theirs)."""
    inside = _within(_covariate(found.name, sig), low, high) & ~taken
    e = sig["residual_base"] ** 2
    raw = float(e[inside].sum() / max(e.sum(), 1e-300))
    removes = None
    if "residual_final" in sig:
        ef = sig["residual_final"][inside] ** 2
        removes = float(1.0 - ef.sum() / max(e[inside].sum(), 1e-300))
    sim = None
    if "sim_base" in sig and sig["sim_base"].size:
        es = sig["sim_base"] ** 2
        sim = float(es[inside[: es.size]].sum() / max(es.sum(), 1e-300))
    return Region(
        variable=found.name,
        low=low,
        high=high,
        gap_share=float(np.clip(raw - found.bias, 0.0, 1.0)),
        sample_share=float(np.mean(inside)),
        p_value=p_value,
        stack_removes=removes,
        simulation_share=sim,
        statistic=found.statistic,
    )


# ------------------------------------------------------------------------------------- entry


class _Settings(NamedTuple):
    alpha: float
    min_explained: float
    P: int  # resamples per step
    max_regions: int
    bins: int
    min_share: float
    n_points: int


def _checked(cfg: _Settings) -> _Settings:
    if not (isinstance(cfg.alpha, int | float) and 0 < cfg.alpha < 1):
        raise InputError(
            f"find_regions: expected 0 < alpha < 1 (a family-wise level), got {cfg.alpha!r}."
        )
    for name, val, least in (
        ("n_resamples", cfg.P, 19),
        ("max_regions", cfg.max_regions, 1),
        ("bins", cfg.bins, 4),
        ("n_points", cfg.n_points, 64),
    ):
        if not (isinstance(val, int) and val >= least):
            raise InputError(f"find_regions: expected an integer {name} ≥ {least}, got {val!r}.")
    if not 0 < cfg.min_share < 0.5:
        raise InputError(f"find_regions: expected 0 < min_share < 0.5, got {cfg.min_share!r}.")
    if not 0 <= cfg.min_explained < 1:
        raise InputError(
            f"find_regions: expected 0 ≤ min_explained < 1, got {cfg.min_explained!r}."
        )
    return cfg


def find_regions(
    signals: Mapping[str, np.ndarray],
    *,
    alpha: float = 0.05,
    seed: int = 0,
    filter_hz: float | None = None,
    min_explained: float = 0.05,
    n_resamples: int = 199,
    max_regions: int = 3,
    bins: int = 32,
    min_share: float = 0.05,
    n_points: int = 2048,
) -> list[Region]:
    """The regions of the validation record where the dynamics depart from the rest, strongest
    first, each significant at the family-wise level ``alpha`` (method: the module docstring).

    Arguments:
        signals: arrays of one length T: ``t`` [s], ``x`` [m], ``v`` [m/s], ``F`` [N] of the
            validation record and ``residual_base`` (the baseline's ε₁ [m/s²]); optionally
            ``residual_final`` (the stacked model's ε₁, for ``stack_removes``) and ``sim_base``
            (the baseline's windowed-simulation error [m], ≤ T samples). Other keys are ignored.
        alpha: the family-wise error rate over variables, candidates and steps.
        seed: the resamples' seed (same inputs and seed, same answer).
        filter_hz: the corner of ε₁'s filter [Hz] (default min(f_s/25, 40 Hz), the diagnosis').
        min_explained: the least share of the misfit a region must explain (Λ/N: the mean
            square its own correction removes over that of the record-wide one) to be reported.
        n_resamples: resamples per step.
        max_regions: the most regions reported.
        bins: quantile bins of each variable (the candidates' grid before the edges' refinement).
        min_share: the least share of the points on each side of a candidate.
        n_points: the most points searched (ε₁ and the columns averaged over blocks of
            ⌈T/n_points⌉ samples).

    Returns:
        a list of :class:`Region` (``[]``: no region is significant).
    """
    cfg = _checked(
        _Settings(alpha, min_explained, n_resamples, max_regions, bins, min_share, n_points)
    )
    sig = _validated(signals)
    dt = float(sig["t"][-1] - sig["t"][0]) / (sig["t"].size - 1)
    fh = min(1.0 / (25.0 * dt), 40.0) if filter_hz is None else filter_hz
    if not (isinstance(fh, int | float) and math.isfinite(fh) and fh > 0):
        raise InputError(f"find_regions: expected filter_hz > 0 [Hz], got {filter_hz!r}.")
    # the search's products are thin (resamples × points by a few hundred columns): one BLAS
    # thread computes them fastest, and more contend with the host's other work
    with threadpool_limits(limits=1, user_api="blas"):
        return _search(_points(sig, float(fh), n_points), sig, np.random.default_rng(seed), cfg)


def _search(pts: _Points, sig: dict, rng, cfg: _Settings) -> list[Region]:
    """The iterative search: a region per step while one is significant."""
    block = max(8, int(math.ceil(max(BLOCK_S, 20.0 / pts.lam) / pts.h)))
    active = np.ones(pts.r.size, bool)
    out: list[Region] = []
    total, taken = None, np.zeros(sig["t"].size, bool)
    for _ in range(cfg.max_regions):
        found = _step(pts, active, rng, cfg, block)
        if found is None:
            break
        total = found.total if total is None else total
        p = max(found.p_value, out[-1].p_value) if out else found.p_value
        # a region explains at least min_explained of the record's misfit (after the
        # record-wide correction): later steps count against the first step's whole
        if p > cfg.alpha or found.explained < cfg.min_explained * total:
            break
        low, high = _beside(found.name, *_refine(pts, active, found), out)
        out.append(_region(sig, found, low, high, p, taken))
        taken |= out[-1].mask(sig)
        gone = _within(pts.z[found.name], low, high)
        # the filter carries an effect into ε₁ for about its mean lag after the region
        for j in range(1, pts.lag + 1):
            gone[j:] |= gone[:-j].copy()
        active &= ~gone
    return out
