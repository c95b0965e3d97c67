"""Fitting and scoring one model structure on recorded data (no twin: layer 3 of the package).

A *structure* is the mass–damper ẍ + aẋ = b·u plus linear effect columns
(:mod:`lionjax._model_effects`) plus an input map u = sat_Fmax(F(t − τ)) that is nonlinear in τ
and F_max (profiled on a grid).

Least squares on the first equation error only. ε₁ = V₃ + aV₂ − bQ₁ + … is the filtered equation
of motion; the core's :func:`lionjax.least_squares` also stacks ε₂ = dε₁/dt (the paper's second
row), which weights the fit by frequency and, on real data with unmodelled high-frequency
dynamics, biases the viscous term (EMPS at λ = 40 Hz: Fv +86 % with both rows, +0.7 % with ε₁).
So the diagnosis solves the ε₁ rows (plus the filter's initial-state nuisance columns, as the core
does) with the core's filter bank and the core's one solver: the float64 augmented Gram
[W | y]ᵀ[W | y] of each design, accumulated over the record's chunks
(:class:`~._regressors.Regressors`), goes to :func:`lionjax._least_squares.gram_lstsq` (the
spectral solve of :func:`lionjax.linear_lstsq` from normal-equation statistics, as the streamed
estimators use it). No factorisation of its own.

Compilation. Every compiled program here sees only *bucketed* shapes and *traced* settings:

- a record is read in chunks of a power of two (a short record in one chunk of its padded
  length :func:`~._filtering.padded_length`), the last padded with the record's last value;
- dt, the filter's poles, v_ε, τ and F_max are arrays, never Python constants, so a new sample
  rate, filter corner or grid does not recompile;
- the least-squares design has a fixed number of columns (:data:`P_MAX`): a structure's unused
  columns are unit vectors outside the record (orthogonal to the data, singular value 1, so the
  fit, its Gram inverse and the condition number of the used columns are unchanged), and Grams
  are solved in batches of :data:`GRID`. So one program fits every candidate and every stack,
  and the solve (on (P + 1)² Grams) does not depend on the record length at all;
- batches come in a few sizes: signals filtered 1 … 32 at a time
  (:data:`~._streaming.BATCHES`), modes 1, 2 or 4 (:data:`~._filtering.MODE_BUCKETS`),
  F-dependent slots 1, 2 or 4 (:data:`~._regressors.K_BUCKETS`).
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from .._least_squares import gram_lstsq
from .._models import AbstractModel
from ..twin._windows import window_span, windowed_errors
from ._filtering import MIN_PADDED, P_MAX, _capacity, _f, _i, padded_length
from ._regressors import Regressors, TooWide, columns_of
from ._streaming import GridColumns, as_source

__all__ = ["TooWide"]


#: Batch of Gram systems solved at once (:func:`solve_grams`): a batch is padded to a multiple
#: of it with identity systems.
GRID = 32
#: Grid points (τ, F_max) whose F-dependent columns one pass over the record filters.
GRID_PASS = 16
#: Host memory a diagnosis of records of one chunk holds at its peak per padded sample of each
#: record [bytes]: its filtered signals and its structures' designs are kept. Peak RSS less the
#: process' own 0.8 GB, over train's + valid's padded length (2026-11-28,
#: benchmarks/results/2026-11-28_diagnosis_lengths.md): 5.1–5.7 kB on offset records, 3.5–5.35 kB
#: on flexible-mode, triple and friction records (friction's stick-masked signals the most);
#: 6.5 kB keeps 21 % over the heaviest (the command line's heap holds about 5 % more).
BYTES_PER_SAMPLE_CACHED = 6_500


#: Padded lengths above this are diagnosed streamed (in chunks: :class:`~._regressors.Regressors`)
#: unless the caller says otherwise: in memory a diagnosis of records of up to 2¹⁷ samples peaks
#: below 2 GB (1.25–1.64 GB measured at 10⁵ training samples), one of 2¹⁸ up to 2.7 GB; streamed,
#: about 1.1 GB whatever the length, at up to twice the time (a friction record of 2 × 5·10⁵
#: samples: 198 s and 1.21 GB streamed, 104 s and 3.86 GB in memory). The blind benchmark's records
#: (at most 2¹⁶ padded samples) are diagnosed in memory.
STREAM_ABOVE = 1 << 17
#: Host memory a streamed diagnosis holds per sample of each record [bytes], over
#: :data:`STREAM_FIXED`: its raw per-sample signals (x, F, v̂, the start states, the stick
#: mask, an effect's whole-record signals while it is profiled). Measured at 10 kHz
#: (2026-11-28, benchmarks/results/2026-11-28_streamed_diagnosis.md): 1.06 GB for 1.2·10⁵
#: samples, 1.75 GB (an offset) and 1.88 GB (spring, delay and friction, the command line) for
#: 7.2·10⁶: 96–115 B per sample over the short record's; 160 B keeps 25 % over the heaviest.
BYTES_PER_SAMPLE_STREAMED = 160
#: Host memory a streamed diagnosis holds whatever the length [bytes]: the process, its compiled
#: programs and a chunk's intermediates (1.06 GB measured at 1.2·10⁵ samples).
STREAM_FIXED = 1_200_000_000


def streamed_by_default(*n_samples: int) -> bool:
    """Whether records of ``n_samples`` samples are diagnosed streamed by default: where one's
    padded length exceeds :data:`STREAM_ABOVE`."""
    return max(padded_length(int(n)) for n in n_samples) > STREAM_ABOVE


def memory_estimate_streamed(*n_samples: int) -> int:
    """Peak host memory [bytes] of a streamed diagnosis of records of ``n_samples`` samples."""
    return STREAM_FIXED + BYTES_PER_SAMPLE_STREAMED * sum(int(n) for n in n_samples)


def _record_bytes(Tp: int) -> int:
    return BYTES_PER_SAMPLE_CACHED * Tp


def memory_estimate(*n_samples: int, streamed: bool | None = None) -> int:
    """Peak host memory [bytes] a diagnosis of records of ``n_samples`` samples needs: streamed
    (``streamed``, by default where :func:`streamed_by_default`),
    :func:`memory_estimate_streamed`; in one chunk :data:`BYTES_PER_SAMPLE_CACHED` per padded
    sample."""
    if streamed is None:
        streamed = streamed_by_default(*n_samples)
    if streamed:
        return memory_estimate_streamed(*n_samples)
    return sum(_record_bytes(padded_length(int(n))) for n in n_samples)


def longest_records(budget: float, count: int = 2, streamed: bool | None = None) -> int:
    """The most samples each of ``count`` records of one length may have for
    :func:`memory_estimate` to stay within ``budget`` [bytes]; 0 when even the shortest bucket
    does not fit. (Every padded length is tried: the estimate drops where the caches stop, and
    again where the records are streamed.)"""
    fits = [
        _capacity(Tp)
        for Tp in (MIN_PADDED << k for k in range(29))
        if memory_estimate(*[_capacity(Tp)] * count, streamed=streamed) <= budget
    ]
    if streamed is not False:
        n = int((budget - STREAM_FIXED) // (BYTES_PER_SAMPLE_STREAMED * count))
        if n > 0 and (streamed or streamed_by_default(n)):
            fits.append(n)
    return max(fits, default=0)


def decimation_to_fit(budget: float, *n_samples: int, streamed: bool | None = None) -> int:
    """The least factor r ≥ 1 for which records of ``n_samples`` samples, decimated by r
    (:meth:`lionjax.Record.decimate`: ⌊n/r⌋ samples each), fit :func:`memory_estimate` within
    ``budget`` [bytes]; 0 when none does (not even the shortest bucket fits)."""
    r = 1
    while True:
        n = [int(k) // r for k in n_samples]
        if memory_estimate(*n, streamed=streamed) <= budget:
            return r
        if max(n) <= _capacity(MIN_PADDED):  # already in the shortest bucket: none helps
            return 0
        r += 1


def physical_memory() -> int | None:
    """This machine's physical memory [bytes], or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


# ----------------------------------------------------------------------------- least squares


@jax.jit
def _gram_fits(G, n_rows):
    """:func:`lionjax.extend.gram_lstsq` (the package's one solve, from normal-equation
    statistics) on each augmented Gram G = [W | y]ᵀ[W | y] of a batch: coef, RSS, (WᵀW)⁻¹,
    condition."""
    P = G.shape[-1] - 1
    fit = jax.vmap(gram_lstsq, in_axes=(0, 0, 0, None))(
        G[:, :P, :P], G[:, :P, P], G[:, P, P], n_rows
    )
    return fit.coef, fit.rss, fit.gram_inverse, fit.condition


def solve_grams(G: np.ndarray, n_rows: int):
    """coef, RSS, Gram inverse and condition of min ‖Wc + y‖² for each augmented Gram
    G = [W | y]ᵀ[W | y] (leading batch), by :func:`lionjax.extend.gram_lstsq` in float64 whether or
    not the caller enabled ``jax_enable_x64`` (the RSS feeds likelihood ratios, and a float32
    Gram would lose the small singular values). The batch is padded to a multiple of
    :data:`GRID` with identity systems, so one compiled program serves every grid length."""
    G = np.asarray(G, np.float64)
    n = G.shape[0]
    eye = np.broadcast_to(np.eye(G.shape[-1]), (-n % GRID,) + G.shape[1:])
    with jax.enable_x64(True):
        out = _gram_fits(np.concatenate([G, eye]), np.float64(n_rows))
        return tuple(np.asarray(o)[:n] for o in out)


def _solve_small_grams(g: np.ndarray, n_rows: int):
    """:func:`solve_grams` of augmented Grams g (m, j + 1, j + 1), j ≤ P_MAX, each placed in
    the solver's fixed size (P_MAX + 1)² with unit diagonals in the unused slots (the Gram of
    unit columns outside the record, as :meth:`Regressors.design_gram` places them): one
    compiled program whatever j. The coefficients' first j slots are g's."""
    m, j = g.shape[0], g.shape[-1] - 1
    G = np.broadcast_to(np.eye(P_MAX + 1), (m, P_MAX + 1, P_MAX + 1)).copy()
    idx = np.r_[np.arange(j), P_MAX]
    G[:, idx[:, None], idx[None, :]] = g
    return solve_grams(G, n_rows)


def _solve_grid(regs: Regressors, model: AbstractModel, inputs):
    """coef, RSS, Gram inverse, condition (each leading G) of the masked LS of ``model`` on
    ``regs`` (y = ε₁'s x column) per input map (τ, F_max) in ``inputs``: only the K
    F-dependent columns change along the grid, so their Gram blocks with the fixed columns are
    accumulated over the record (a pass per :data:`GRID_PASS` points)."""
    if len(inputs) == 1 and float(inputs[0][0]) == 0 and float(inputs[0][1]) == np.inf:
        return solve_grams(regs.design_gram(model)[None], regs.T)
    onehot = regs.plan(model).onehot
    G0 = regs.design_gram(model, grid=True)
    O = np.concatenate([onehot, np.zeros((onehot.shape[0], 1))], 1)  # (K, P + 1)
    Gs = []
    for i in range(0, len(inputs), GRID_PASS):
        C, D = regs.cross(model, GridColumns(model, inputs[i : i + GRID_PASS]), grid=True)
        Gs.append(_gram_from_blocks(G0, C, D, O))
    return solve_grams(np.concatenate(Gs), regs.T)


def _gram_from_blocks(G0: np.ndarray, C: np.ndarray, D: np.ndarray, O: np.ndarray) -> np.ndarray:
    """Augmented Grams (m, P + 1, P + 1) of a fixed design's Gram G0 with K columns placed by
    the one-hot O (K, P + 1), from their blocks C = VᵀA and D = VᵀV
    (:func:`~._regressors._cross_blocks`)."""
    OC = np.einsum("kp,mkq->mpq", O, C)
    return G0 + OC + np.swapaxes(OC, 1, 2) + np.einsum("kp,mkl,lq->mpq", O, D, O)


def fit_batch(regs: Regressors, model: AbstractModel, inputs):
    """ε₁ least squares on the training record for each input map (τ, F_max) in ``inputs``.

    Returns θ ``(G, p)``, the RSS ``(G,)``, σ²(ΦᵀΦ)⁻¹ ``(G, p, p)`` and condition numbers.
    """
    p = len(columns_of(model))
    coef, rss, gi, cond = _solve_grid(regs, model, inputs)
    s2 = rss / max(regs.T - regs.width(model), 1)
    cov = s2[:, None, None] * gi[:, :p, :p]
    return coef[:, :p], rss, cov, cond


def rss_with_columns(regs: Regressors, model: AbstractModel, cols: np.ndarray, coef: bool = False):
    """Training RSS of ``model`` (u = F) with K more ε₁ columns, for each of m sets ``cols``
    (m, K, T) (filtered, signs included): the profile of a column family over a nonlinear
    parameter (the flexible mode's ω, ζ) without building a design per grid point. The new
    columns take the K first unused slots (in place of their unit columns); only their
    Gram blocks are new. With ``coef``: (the fitted coefficients (m, n + K), the RSS, n), n the
    structure's columns and initial-state nuisance (the new columns' first slot), for
    :func:`rss_fixed_with_columns` on another record."""
    n = regs.width(model)
    src = as_source(cols)
    m, K = src.shape(regs)
    if n + K > P_MAX:
        raise TooWide(f"structure with {n + K} columns exceeds P_MAX = {P_MAX}")
    O = np.zeros((K, P_MAX + 1))
    O[np.arange(K), n + np.arange(K)] = 1.0
    G = _gram_from_blocks(regs.design_gram(model, n_free=K), *regs.cross(model, src), O)
    c, rss = solve_grams(G, regs.T)[:2]
    return (c[:, : n + K], rss, n) if coef else rss


def rss_fixed_with_columns(
    regs: Regressors, model: AbstractModel, cols: np.ndarray, coef: np.ndarray, n_fixed: int
) -> np.ndarray:
    """ε₁'s RSS on ``regs.record`` (validation) of ``model`` (u = F) with K more columns
    ``cols`` (m, K, T), for each of m coefficient vectors ``coef`` (m, n + K) fitted on another
    record (:func:`rss_with_columns` with ``coef=True``; n the structure's p columns and its
    initial-state nuisance): the p columns and the first ``n_fixed`` new ones are held at
    ``coef``; the nuisance and the other new columns (a flexible mode's free response) are
    refitted on this record, as :func:`residual` does. The held part of the residual is formed
    directly (one product with the structure's design); only the refitted columns' small
    augmented Gram is built."""
    p, n = regs.plan(model).p, regs.width(model)
    T = regs.T
    coef = np.asarray(coef, np.float64)
    src = as_source(cols)
    Gb = None
    for A, V in zip(regs.design_blocks(model), regs.blocks(src), strict=True):
        g = _refit_gram(A, V, coef, p, n, n_fixed)
        Gb = g if Gb is None else Gb + g
    return _solve_small_grams(Gb, T)[1]


def _refit_gram(A, cols, coef, p: int, n: int, n_fixed: int) -> np.ndarray:
    """The augmented Grams (m, q + k + 1, q + k + 1) of :func:`rss_fixed_with_columns`' refitted
    columns B = [N | g] and residual r on the rows of the design A (·, P + 1) and columns
    ``cols`` (m, K, ·): a sum over rows, so a streamed record adds its chunks'."""
    # r = W·c + y with the held columns; the refitted ones B = [N | g] (nuisance, free
    # response) by least squares on each set's augmented Gram [B | r]ᵀ[B | r], built by blocks
    # (N is shared: a batched product of [B | r] with itself made the diagnosis measurably slower)
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
    """ε₁ on ``regs.record`` for fixed θ (validation): only the filter's initial-state
    nuisance coefficients are refitted on this record. r₀ = Wθ + y chunk by chunk, with the
    Gram of [N | r₀] for the nuisance's least squares, then r₀ + Nη."""
    plan = regs.plan(model)
    p, n, onehot = plan.p, regs.width(model), plan.onehot
    mapped = bool(np.any(onehot)) and (inp[0] != 0 or inp[1] != np.inf)
    theta = np.asarray(theta, np.float64)
    r0 = np.empty(regs.T)
    g = np.zeros((n - p + 1, n - p + 1))
    mapped_cols = regs.blocks(GridColumns(model, [inp])) if mapped else None
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


# ----------------------------------------------------------------------------- simulation


def simulate_windows(
    p, u, x_meas, x_start, v_start, dt, H: int, extra=None, t0: float = 0.0
) -> np.ndarray:
    """Windowed simulation error x_sim − x_meas [m], restarting every ``H`` samples; the
    samples after the last whole window are 0.

    The twin's exact-hold simulator (:func:`lionjax.twin._windows.windowed_errors`: model,
    sticking, restarts) on the record padded to its length bucket, its windows stepped side by
    side (``span``: the least power of two ≥ H): H, dt and the parameters are traced, so one
    program serves every record of a bucket whose windows share that power of two. Each window
    starts from the estimated state (x_start, v_start) at its first sample. ``extra``: an
    optional force term ``extra(x, v, u, t)`` [N] (:class:`~.effects.SimulatedForce`,
    elementwise in its arguments), with t = t0 + k·dt.
    """
    T = int(np.asarray(u).shape[0])
    H = int(H)
    Tn = (T // H) * H
    if padded_length(T) > STREAM_ABOVE and Tn > 2 * SIM_SEGMENT:
        # a long record in segments of whole windows (each window simulated alone, from its
        # own start state: the same steps, a segment's arrays held at a time)
        seg = max(SIM_SEGMENT // H, 1) * H
        e = np.zeros(T)
        for s0 in range(0, Tn, seg):
            s1 = min(s0 + seg, Tn)
            e[s0:s1] = _simulate_segment(
                p, (a[s0:s1] for a in (u, x_meas, x_start, v_start)), dt, H, extra, t0, s0
            )
        return e
    return _simulate_segment(p, (u, x_meas, x_start, v_start), dt, H, extra, t0, 0)[:T]


#: Samples (whole windows) a long record's windowed simulation runs at once.
SIM_SEGMENT = 1 << 16


def _simulate_segment(p, signals, dt, H: int, extra, t0: float, k0: int) -> np.ndarray:
    """:func:`simulate_windows` of samples starting at ``k0`` (a multiple of H; their times
    t0 + (k0 + k)·dt): the whole windows of ``signals`` (u, x, x_start, v_start), on the
    padded length bucket; (Tp,) errors."""
    signals = [np.asarray(a, np.float64) for a in signals]
    T = signals[0].size
    Tn = (T // H) * H
    Tp = padded_length(T)
    args = [np.concatenate([a, np.full(Tp - T, a[-1])]) for a in signals]  # edge-padded
    pj = {k: _f(v) for k, v in p.items()}
    t = None
    if extra is not None:
        t = jnp.asarray(float(t0) + float(dt) * np.arange(k0, k0 + Tp), jnp.float64)
    e = windowed_errors(pj, *args, _f(dt), _i(H), _i(Tn), extra, t, span=window_span(H))
    return np.asarray(e)[:T]
