"""Least squares of a structure on ε₁, and the windowed simulation.

A structure is the mass–damper ẍ + aẋ = b·u plus linear effect columns plus an input map
u = sat_Fmax(F(t − τ)) (profiled on a grid). The fit uses the first equation error
ε₁ = V₃ + aV₂ − bQ₁ + … alone: ε₂ = dε₁/dt weights by frequency and, with unmodelled
high-frequency dynamics, biases the viscous term. The float64 augmented Gram [W | y]ᵀ[W | y],
accumulated over the record's chunks with the filter's initial-state columns, goes to the
core's one solver (:func:`lionjax._least_squares.gram_lstsq`).

Compiled programs see bucketed shapes and traced settings only: designs of :data:`P_MAX`
columns, a structure's unused ones unit vectors outside the record (orthogonal to the data,
singular value 1: the fit, its Gram inverse and the used columns' condition unchanged), Grams
solved in batches of :data:`GRID_SMALL` or :data:`GRID`: a program per batch size fits every
structure at any record length.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._least_squares import gram_lstsq
from .._models import AbstractModel
from ..twin._windows import window_span, windowed_errors
from ._filtering import P_MAX, _f, _i, padded_length
from ._regressors import Regressors, TooWide, columns_of
from ._statistics import STREAM_ABOVE
from ._streaming import as_source, grid_columns

#: Gram systems solved per call (:func:`solve_grams`; a batch is padded with identity systems to
#: the least of GRID_SMALL that holds it, else to a multiple of GRID: one program per size, and
#: a search's few points are not solved as 32). Each system's numbers are the same in any batch.
GRID = 32
GRID_SMALL = (4, 8)
#: Grid points (τ, F_max) whose F-dependent columns one pass over the record filters.
GRID_PASS = 16


@jax.jit
def _gram_fits(G, n_rows):
    P = G.shape[-1] - 1
    fit = jax.vmap(gram_lstsq, in_axes=(0, 0, 0, None))(
        G[:, :P, :P], G[:, :P, P], G[:, P, P], n_rows
    )
    return fit.coef, fit.rss, fit.gram_inverse, fit.condition


def solve_grams(G: np.ndarray, n_rows: int):
    """(coef, RSS, Gram inverse, condition) of min ‖Wc + y‖² for each augmented Gram
    G = [W | y]ᵀ[W | y] (leading batch), by :func:`lionjax.extend.gram_lstsq` in float64 whether
    or not ``jax_enable_x64`` is on (the RSS feeds likelihood ratios; a float32 Gram loses the
    small singular values)."""
    G = np.asarray(G, np.float64)
    n = G.shape[0]
    size = next((b for b in GRID_SMALL if b >= n), -(-n // GRID) * GRID)
    eye = np.broadcast_to(np.eye(G.shape[-1]), (size - n,) + G.shape[1:])
    with jax.enable_x64(True):
        out = _gram_fits(np.concatenate([G, eye]), np.float64(n_rows))
        return tuple(np.asarray(o)[:n] for o in out)


def _solve_small_grams(g: np.ndarray, n_rows: int):
    """:func:`solve_grams` of augmented Grams g (m, j + 1, j + 1), j ≤ P_MAX, placed in the
    solver's size (P_MAX + 1)² with unit diagonals in the unused slots (one program whatever j);
    the coefficients' first j slots are g's."""
    m, j = g.shape[0], g.shape[-1] - 1
    G = np.broadcast_to(np.eye(P_MAX + 1), (m, P_MAX + 1, P_MAX + 1)).copy()
    idx = np.r_[np.arange(j), P_MAX]
    G[:, idx[:, None], idx[None, :]] = g
    return solve_grams(G, n_rows)


def _gram_from_blocks(G0: np.ndarray, C: np.ndarray, D: np.ndarray, O: np.ndarray) -> np.ndarray:
    """Augmented Grams (m, P + 1, P + 1) of a design's Gram G0 with K columns V placed by the
    one-hot O (K, P + 1), from C = VᵀA and D = VᵀV."""
    OC = np.einsum("kp,mkq->mpq", O, C)
    return G0 + OC + np.swapaxes(OC, 1, 2) + np.einsum("kp,mkl,lq->mpq", O, D, O)


def fit_batch(regs: Regressors, model: AbstractModel, inputs):
    """ε₁ least squares of ``model`` on ``regs`` for each input map (τ, F_max) of ``inputs``:
    θ (G, p), the RSS (G,), σ²(WᵀW)⁻¹ (G, p, p) and the condition numbers (G,).

    Along the grid only the K F-dependent columns change: their Gram blocks with the fixed
    columns are accumulated over the record, one pass per :data:`GRID_PASS` points."""
    p = len(columns_of(model))
    if len(inputs) == 1 and float(inputs[0][0]) == 0 and float(inputs[0][1]) == np.inf:
        coef, rss, gi, cond = solve_grams(regs.design_gram(model)[None], regs.T)
    else:
        onehot = regs.plan(model).onehot
        G0 = regs.design_gram(model, grid=True)
        O = np.concatenate([onehot, np.zeros((onehot.shape[0], 1))], 1)  # (K, P + 1)
        Gs = []
        for i in range(0, len(inputs), GRID_PASS):
            C, D = regs.cross(model, grid_columns(regs, model, inputs[i : i + GRID_PASS]), True)
            Gs.append(_gram_from_blocks(G0, C, D, O))
        coef, rss, gi, cond = solve_grams(np.concatenate(Gs), regs.T)
    s2 = rss / max(regs.T - regs.width(model), 1)
    return coef[:, :p], rss, s2[:, None, None] * gi[:, :p, :p], cond


def rss_with_columns(regs: Regressors, model: AbstractModel, cols, coef: bool = False):
    """Training RSS (m,) of ``model`` (u = F) with K more ε₁ columns, for each of m sets
    ``cols`` (m, K, T) or a :class:`~._streaming.ColumnSource` (filtered, signs included): a
    column family profiled over a nonlinear parameter without a design per point. The new
    columns take the first K unused slots; only their Gram blocks are new. With ``coef``:
    (coefficients (m, n + K), RSS, n), n the structure's columns and initial-state columns."""
    n = regs.width(model)
    C, D = regs.cross(model, as_source(cols))
    K = D.shape[1]
    if n + K > P_MAX:
        raise TooWide(f"structure with {n + K} columns exceeds P_MAX = {P_MAX}")
    O = np.zeros((K, P_MAX + 1))
    O[np.arange(K), n + np.arange(K)] = 1.0
    c, rss = solve_grams(_gram_from_blocks(regs.design_gram(model, n_free=K), C, D, O), regs.T)[:2]
    return (c[:, : n + K], rss, n) if coef else rss


def rss_fixed_with_columns(
    regs: Regressors, model: AbstractModel, cols, coef: np.ndarray, n_fixed: int
) -> np.ndarray:
    """ε₁'s RSS (m,) on ``regs`` (validation) of ``model`` with K more columns ``cols``
    (m, K, T), for each of m coefficient vectors ``coef`` (m, n + K) fitted on another record
    (:func:`rss_with_columns`): the structure's p columns and the first ``n_fixed`` new ones held
    at ``coef``, the initial-state columns and the other new ones (a mode's free response)
    refitted here, as :func:`residual` does."""
    p, n = regs.plan(model).p, regs.width(model)
    coef = np.asarray(coef, np.float64)
    src = as_source(cols)
    Gb = sum(
        _refit_gram(A, V, coef, p, n, n_fixed)
        for A, V in zip(regs.design_blocks(model), src.blocks(regs), strict=True)
    )
    return _solve_small_grams(Gb, regs.T)[1]


def _refit_gram(A, cols, coef, p: int, n: int, n_fixed: int) -> np.ndarray:
    """[B | r]ᵀ[B | r] (m, q + k + 1, q + k + 1) of the refitted columns B = [N | g] and the held
    residual r = W·c + y on a design block A (·, P + 1) and ``cols`` (m, K, ·), by blocks (N
    shared: a batched product of [B | r] with itself is slower)."""
    r = A[:, :p] @ coef[:, :p].T + A[:, P_MAX][:, None]  # (T, m)
    r += np.sum(coef[:, n : n + n_fixed, None] * cols[:, :n_fixed], 1).T
    N, g = A[:, p:n], np.ascontiguousarray(cols[:, n_fixed:])  # (T, q), (m, k, T)
    m, q, k = g.shape[0], n - p, g.shape[1]
    Gb = np.empty((m, q + k + 1, q + k + 1))
    Gb[:, :q, :q] = N.T @ N
    Gb[:, q : q + k, :q] = g @ N
    Gb[:, :q, q : q + k] = np.swapaxes(Gb[:, q : q + k, :q], 1, 2)
    Gb[:, q : q + k, q : q + k] = g @ np.swapaxes(g, 1, 2)
    Gb[:, :-1, -1] = Gb[:, -1, :-1] = np.concatenate(
        [(N.T @ r).T, (g @ r.T[:, :, None])[..., 0]], 1
    )
    Gb[:, -1, -1] = np.sum(r * r, 0)
    return Gb


def residual(regs: Regressors, model: AbstractModel, theta, inp) -> np.ndarray:
    """ε₁ (T,) on ``regs`` (validation) for θ held: r₀ = Wθ + y chunk by chunk with the Gram of
    [N | r₀], then r₀ + Nη, the initial-state coefficients η refitted on this record."""
    plan = regs.plan(model)
    p, n, onehot = plan.p, regs.width(model), plan.onehot
    mapped = bool(np.any(onehot)) and (inp[0] != 0 or inp[1] != np.inf)
    theta = np.asarray(theta, np.float64)
    r0 = np.empty(regs.T)
    g = np.zeros((n - p + 1, n - p + 1))
    mapped_cols = grid_columns(regs, model, [inp]).blocks(regs) if mapped else None
    for (k0, k1), A in zip(regs.spans, regs.design_blocks(model, grid=mapped), strict=True):
        W = A[:, :p]
        if mapped_cols is not None:
            W = W + (next(mapped_cols)[0].T @ onehot)[:, :p]
        r = W @ theta + A[:, P_MAX]
        B = np.concatenate([A[:, p:n], r[:, None]], 1)
        g += B.T @ B
        r0[k0:k1] = r
    eta = _solve_small_grams(g[None], regs.T)[0][0, : n - p]
    for k0, k1 in regs.spans:
        r0[k0:k1] += regs.nuisance_rows(model, k0, k1) @ eta
    return r0


#: Samples (whole windows) a long record's windowed simulation runs at once.
SIM_SEGMENT = 1 << 16


def simulate_windows(
    p, u, x_meas, x_start, v_start, dt, H: int, extra=None, t0: float = 0.0, mode=None
) -> np.ndarray:
    """Windowed simulation error x_sim − x_meas [m] (T,) of the twin's exact-hold simulator
    (:func:`lionjax.twin._windows.windowed_errors`), each window of ``H`` samples started from
    (x_start, v_start) at its first sample, 0 after the last whole window; a long record in
    segments of whole windows (independent: the same steps). ``extra``: an optional force term
    ``extra(x, v, u, t)`` [N], elementwise, t = t0 + k·dt. ``mode``: an optional (ModeTerm,
    its start states (T, 4))."""
    signals = [np.asarray(a, np.float64) for a in (u, x_meas, x_start, v_start)]
    if mode is not None:
        signals.append(np.asarray(mode[1], np.float64))
    T, H = signals[0].size, int(H)
    Tn = (T // H) * H
    long = padded_length(T) > STREAM_ABOVE and Tn > 2 * SIM_SEGMENT
    seg = max(SIM_SEGMENT // H, 1) * H if long else max(Tn, 1)
    pj = {k: _f(v) for k, v in p.items()}
    e = np.zeros(T)
    for s0 in range(0, Tn, seg):
        n = min(seg, Tn - s0)
        Tp = padded_length(n)
        args = [
            np.concatenate([a[s0 : s0 + n], a[s0 + n - 1 : s0 + n].repeat(Tp - n, 0)])
            for a in signals
        ]
        t = None
        if extra is not None:
            t = jnp.asarray(float(t0) + float(dt) * np.arange(s0, s0 + Tp), jnp.float64)
        kw = {} if mode is None else {"mode": mode[0], "s_start": args.pop()}
        out = windowed_errors(pj, *args, _f(dt), _i(H), _i(n), extra, t, span=window_span(H), **kw)
        e[s0 : s0 + n] = np.asarray(out)[:n]
    return e
