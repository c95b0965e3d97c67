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
[W | y]ᵀ[W | y] of each design (one pass over the record, on the host) goes to
:func:`lionjax._least_squares.gram_lstsq` (the spectral solve of :func:`lionjax.linear_lstsq`
from normal-equation statistics, as the streamed estimators use it). No factorisation of its own.

Compilation. Every compiled program here sees only *bucketed* shapes and *traced* settings:

- a record of T samples is padded (edge values) to Tp = the next power of two ≥ T + 16, and
  every row ≥ T is masked out of the least squares (so one program serves every length in the
  bucket); the filters are causal, so rows < T are exactly those of the unpadded record, and the
  zero-phase filter reverses only the first T samples (exact as well);
- dt, the filter's poles, v_ε, τ and F_max are arrays, never Python constants, so a new sample
  rate, filter corner or grid does not recompile;
- the least-squares design has a fixed number of columns (:data:`P_MAX`): a structure's unused
  columns are unit vectors on padded rows (orthogonal to the data, singular value 1, so the fit,
  its Gram inverse and the condition number of the used columns are unchanged), and Grams are
  solved in batches of :data:`GRID`. So one program fits every candidate and every stack, and
  the solve (on (P + 1)² Grams) does not depend on the record length at all;
- batches come in a few sizes: signals filtered 1, 2 or 8 at a time (:data:`S_BUCKETS`), modes
  1, 2 or 4 (:data:`MODE_BUCKETS`), F-dependent slots 1, 2 or 4 (:data:`K_BUCKETS`), profile
  grids 8 points per call (:data:`GRID_BATCH`): a call filters what it needs, not a fixed batch
  of zeros, at a few programs per length bucket.

Long records are streamed (:class:`~._streamed.Streamed`, above :data:`STREAM_ABOVE` padded
samples): the same Grams, grid products and residuals, accumulated over chunks of the record
(:mod:`._streaming`) instead of from whole designs; the functions here take either kind of
regressors and the profile columns whole or as a :class:`~._streaming.ColumnSource`.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._filters import FilterBank
from .._least_squares import gram_lstsq
from .._model_effects import LOCAL_F_MULTIPLIERS, MAX_POSITION_DEGREE, position_terms
from .._models import AbstractModel
from .._record import Record
from ..twin._windows import window_span, windowed_errors
from ._filtering import (
    MIN_PADDED,
    P_MAX,
    Discrete,
    _capacity,
    _f,
    _filt,
    _free,
    _i,
    edge_pad,
    filter_signals,
    padded_length,
)
from ._streaming import GridColumns, as_source


class TooWide(ValueError):
    """A structure with more columns (its own and the refitted initial-state ones) than
    :data:`P_MAX`: the default library's widest stack of three (a cubic a(x), b(x), asymmetric
    friction and a flexible mode) has 12 + 5."""


#: Batch of Gram systems solved at once (:func:`solve_grams`): a batch is padded to a multiple
#: of it with identity systems.
GRID = 32
#: Grid points (τ, F_max) whose F-dependent columns one call of :func:`_grid_columns` filters: a
#: profile grid runs in batches of this size (the last one padded), so one program serves every
#: grid length and a grid of 8 or 15 points filters 8 or 16, not 32.
GRID_BATCH = 8
#: Padded lengths above this filter a profile grid 2 points at a time and rebuild each
#: structure's dense (T, ·) design from the cached signals instead of caching it (memory; its
#: small Gram is kept at every length). A 10-minute
#: record at 1 kHz (padded to 2²⁰) took 243 s and 17.9 GB with them cached, 245 s and 5.8 GB
#: without (the same diagnosis to six digits): above a few 10⁵ samples the cache buys no time.
BIG = 1 << 18
#: Host memory a diagnosis holds at its peak per padded sample of each record [bytes], with and
#: without the per-structure designs cached: peak RSS less the process' own 0.8 GB, over train's
#: + valid's padded length (2026-11-28, benchmarks/results/2026-11-28_diagnosis_lengths.md).
#: Cached (up to 2¹⁸): 5.1–5.7 kB on offset records, 3.5–5.35 kB on flexible-mode, triple and
#: friction records (friction's stick-masked signals the most); 6.5 kB keeps 21 % over the
#: heaviest (the command line's heap holds about 5 % more). Not cached (2026-11-28, after the
#: long records' filter calls took two signals, benchmarks/results/2026-11-28_long_records.md):
#: 1.4–1.7 kB on offset records from 2¹⁹ to 2²¹, 2.7–2.9 kB on friction, triple and
#: flexible-mode records at 2 × 2¹⁹ (friction the most); 3.6 kB keeps 24 % over the heaviest.
BYTES_PER_SAMPLE_CACHED = 6_500
BYTES_PER_SAMPLE = 3_600


#: Padded lengths above this are diagnosed streamed (:class:`~._streamed.Streamed`) unless the
#: caller says otherwise: in memory a diagnosis of records of up to 2¹⁷ samples peaks below
#: 2 GB (1.25–1.64 GB measured at 10⁵ training samples), one of 2¹⁸ up to 2.7 GB; streamed, about
#: 1.1 GB whatever the length, at up to twice the time (a friction record of 2 × 5·10⁵ samples:
#: 198 s and 1.21 GB streamed, 104 s and 3.86 GB in memory). The blind benchmark's records (at
#: most 2¹⁶ padded samples) are diagnosed in memory.
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
    return (BYTES_PER_SAMPLE_CACHED if Tp <= BIG else BYTES_PER_SAMPLE) * Tp


def memory_estimate(*n_samples: int, streamed: bool | None = None) -> int:
    """Peak host memory [bytes] a diagnosis of records of ``n_samples`` samples needs: streamed
    (``streamed``, by default where :func:`streamed_by_default`),
    :func:`memory_estimate_streamed`; in memory :data:`BYTES_PER_SAMPLE`, or
    :data:`BYTES_PER_SAMPLE_CACHED` where the record's padded length keeps the per-structure
    caches, per padded sample."""
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


#: Signals whose value is (a function of x) × F: the input map u replaces F in them; the value
#: is the name of the multiplier's raw signal (``known``), None for F itself.
F_DEP = {"F": None} | {
    f: m for f, m in (position_terms(k)[1:] for k in range(1, MAX_POSITION_DEGREE + 1))
}


def f_dependent(signal: str) -> bool:
    """Whether ``signal`` is (a function of x) × F (:data:`F_DEP`, or a localized position's,
    :data:`~lionjax._model_effects.LOCAL_F_MULTIPLIERS`)."""
    return signal in F_DEP or signal.startswith(tuple(LOCAL_F_MULTIPLIERS))


def f_multiplier(signal: str) -> str | None:
    """The raw signal name of an F-dependent signal's multiplier (None for F itself)."""
    if signal in F_DEP:
        return F_DEP[signal]
    pre = next(p for p in LOCAL_F_MULTIPLIERS if signal.startswith(p))
    return LOCAL_F_MULTIPLIERS[pre] + signal[len(pre) :]


#: Slots for F-dependent signals in one structure: the smallest bucket that holds them (one
#: compiled program per bucket; most structures have F alone, or F and ξF).
K_BUCKETS = (1, 2, 4)
K_MAX = K_BUCKETS[-1]


# ----------------------------------------------------------------------------- inputs


def _apply_input(F, dt, tau, fmax):
    """:func:`apply_input` traced: τ/dt = n + φ, F_d[k] = (1 − φ)F[k − n] + φF[k − n − 1]."""
    T = F.shape[-1]
    s = tau / dt
    n = jnp.floor(s)
    phi = s - n
    k = jnp.arange(T)
    i0 = jnp.clip(k - n.astype(k.dtype), 0, T - 1)
    i1 = jnp.clip(i0 - 1, 0, T - 1)
    Fd = (1 - phi) * F[i0] + phi * F[i1]
    m = jnp.abs(fmax)
    soft = m * jnp.tanh(Fd / jnp.where(jnp.isfinite(m), m, 1.0))
    return jnp.where(fmax < 0, soft, jnp.clip(Fd, -m, m))


def apply_input(F, dt, tau, fmax) -> np.ndarray:
    """u = sat_Fmax(F(t − τ)) at the samples, for a force held between samples [N].

    With τ = (n + φ)·dt the delayed held force averaged over each interval is
    (1 − φ)F[k − n] + φF[k − n − 1] (F before the record = F[0]). F_max > 0: the hard clip;
    F_max < 0 stands for the soft saturation |F_max|·tanh(F/|F_max|) (one profile grid holds
    both shapes).
    """
    F = np.asarray(F, np.float64)
    t = np.arange(F.size, dtype=np.float64)
    Fd = np.interp(t - float(tau) / float(dt), t, F, left=F[0], right=F[-1])
    m = abs(float(fmax))
    if fmax < 0:
        return m * np.tanh(Fd / m)
    return np.clip(Fd, -m, m)


# ----------------------------------------------------------------------------- least squares


def _design(dsc, Wfix, F, mult, onehot, dt, tau, fmax, T):
    """The design W (Tp, P) for one input map: fixed columns + the F-dependent ones."""
    Tp = F.shape[0]
    k = jnp.arange(Tp)
    u = _apply_input(F, dt, tau, fmax)
    u = jnp.where(k < T, u, u[T - 1])
    V = jax.vmap(_filt, in_axes=(None, 0, None))(dsc, mult * u[None, :], 0.0)[:, :, 0]
    return Wfix + V.T @ onehot


def _augmented_gram(W: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The augmented Gram [W | y]ᵀ[W | y] (…, P + 1, P + 1) of masked designs, in float64 on
    the host: the tall products are the only pass over the record, and float64 keeps the
    squaring of the condition number (cond(Gram) = cond(W)²) far from the rounding floor
    (cond(W) up to ~1e6 leaves 1e-4 relative accuracy in the Gram's smallest eigenvalue)."""
    A = _augmented_design(W, y)
    return np.swapaxes(A, -1, -2) @ A


def _augmented_design(W: np.ndarray, y: np.ndarray) -> np.ndarray:
    """[W | y] in float64."""
    W = np.asarray(W, np.float64)
    y = np.broadcast_to(np.asarray(y, np.float64), W.shape[:-1])
    return np.concatenate([W, y[..., None]], -1)


@jax.jit
def _gram_fits(G, n_rows):
    """:func:`lionjax.gram_lstsq` (the package's one solve, from normal-equation statistics) on
    each augmented Gram G = [W | y]ᵀ[W | y] of a batch: coef, RSS, (WᵀW)⁻¹, condition."""
    P = G.shape[-1] - 1
    fit = jax.vmap(gram_lstsq, in_axes=(0, 0, 0, None))(
        G[:, :P, :P], G[:, :P, P], G[:, P, P], n_rows
    )
    return fit.coef, fit.rss, fit.gram_inverse, fit.condition


def solve_grams(G: np.ndarray, n_rows: int):
    """coef, RSS, Gram inverse and condition of min ‖Wc + y‖² for each augmented Gram
    G = [W | y]ᵀ[W | y] (leading batch), by :func:`lionjax.gram_lstsq` in float64 whether or
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
    unit columns outside the record, as :meth:`Regressors.gram` places them): one
    compiled program whatever j. The coefficients' first j slots are g's."""
    m, j = g.shape[0], g.shape[-1] - 1
    G = np.broadcast_to(np.eye(P_MAX + 1), (m, P_MAX + 1, P_MAX + 1)).copy()
    idx = np.r_[np.arange(j), P_MAX]
    G[:, idx[:, None], idx[None, :]] = g
    return solve_grams(G, n_rows)


@jax.jit
def _grid_columns(dsc, F, mult, mask, dt, taus, fmaxs, T):
    """Masked F-dependent columns (GRID, K, Tp) of the input maps (τᵢ, F_maxᵢ), unsigned: every
    grid point's signals filtered in one batched scan."""
    Tp = F.shape[0]
    k = jnp.arange(Tp)
    U = jax.vmap(_apply_input, in_axes=(None, None, 0, 0))(F, dt, taus, fmaxs)
    U = jnp.where(k < T, U, U[:, T - 1][:, None])
    S = (mult[None, :, :] * U[:, None, :]).reshape(-1, Tp)  # (G·K, Tp)
    V = jax.vmap(_filt, in_axes=(None, 0, None))(dsc, S, 0.0)[:, :, 0] * mask[None, :]
    return V.reshape(taus.shape[0], mult.shape[0], Tp)


class Regressors:
    """ε₁ regressors of :class:`~lionjax.Augmented` structures on one record, built from the
    models' own :meth:`columns` and the signals of :meth:`signals`, with every raw signal
    filtered once and cached: many structures and profile grids share them.

    The input u = sat_Fmax(F(t − τ)) replaces F in every signal that uses it (``"F"`` and the
    position-dependent ``ξ·F``); those columns are built inside the compiled fit, per grid point.

    ``known``: precomputed raw signals {name: (samples (T,), hold)} (the diagnosis supplies the
    smoothed sign of its zero-phase velocity, so that no effect recompiles its own filter).

    ``force_mask``: optional (T,) weights m ∈ {0, 1} of the forces: while the axis sticks
    (m = 0) static friction balances every force on it, ẍ + aẋ = 0 there, and each force
    column (order 0: the input u, an offset, a spring, friction) is built from m·(signal).
    The columns of x's derivatives and the nuisance are unchanged.
    """

    #: Whether the regressors are streamed (:class:`~._streamed.Streamed`): no design held.
    streamed = False

    def __init__(
        self,
        record: Record,
        bank: FilterBank,
        known: dict | None = None,
        force_mask: np.ndarray | None = None,
    ):
        self._record(record, bank, force_mask)
        self.Fp = jnp.asarray(edge_pad(self.F, self.Tp))
        self.mask = np.zeros(self.Tp)
        self.mask[: self.T] = 1.0
        self.known = dict(known or {})
        self.N = np.asarray(_free(self.dsc, np.zeros(self.Tp)))  # (Tp, n)
        self.W0 = self.filtered({"x": (self.x, "foh")})["x"][:, 2]

    def _record(self, record: Record, bank: FilterBank, force_mask) -> None:
        """The record, its filter and force mask, and an empty cache."""
        self.record, self.bank = record, bank
        self.force_mask = None if force_mask is None else np.asarray(force_mask, np.float64)
        self.T = record.n_samples
        self.Tp = padded_length(self.T)
        self.dt = float(record.dt)
        self.dsc = Discrete.of(bank, self.dt)
        self.x = np.asarray(record.x, np.float64)
        self.F = np.asarray(record.F, np.float64)
        self.cache: dict = {}

    def filtered(self, raw: dict) -> dict:
        """{name: (Tp, 4)} for raw signals {name: (samples, hold)}, cached by name."""
        todo = [n for n in raw if n not in self.cache]
        if todo:
            U = np.stack([edge_pad(np.asarray(raw[n][0])[: self.T], self.Tp) for n in todo])
            foh = np.array([1.0 if raw[n][1] == "foh" else 0.0 for n in todo])
            for n, v in zip(todo, filter_signals(self.dsc, U, foh), strict=True):
                self.cache[n] = v
        return {n: self.cache[n] for n in raw}

    def mean_square(self, u, hold: str, order: int) -> float:
        """The mean over the record of the square of output ``order`` (V₁…V₄) of the raw
        signal ``u`` (T,) under ``hold`` (not cached)."""
        V = filter_signals(
            self.dsc, edge_pad(u, self.Tp)[None], np.array([1.0 if hold == "foh" else 0.0])
        )[0]
        return float(np.mean(V[: self.T, order] ** 2))

    def drop(self, names) -> None:
        """Forget raw and filtered signals ``names`` and every cached plan, design, Gram and
        nuisance that uses them (profiled columns: one structure per grid point would otherwise
        stay in memory)."""
        names = set(names)
        for n in names:
            self.known.pop(n, None)
            self.cache.pop(n, None)
        for k in [k for k in self.cache if isinstance(k, tuple) and k[0] in _PER_STRUCTURE]:
            if any(signal in names for signal, _, _ in k[1]):
                del self.cache[k]

    def nuisance(self, model: AbstractModel) -> np.ndarray:
        """(Tp, n) initial-state columns of a structure, refitted on every record: the filter's
        free response :attr:`N`, plus each effect's own (``free_response``: a flexible mode's
        decaying oscillation, which its columns carry from an unknown initial deflection);
        cached per structure."""
        key = ("nuisance", _model_key(model))
        if key not in self.cache:
            responses = (e.free_response(self.dt, self.Tp) for e in getattr(model, "effects", ()))
            extra = [np.asarray(r, np.float64) for r in responses if r is not None]
            self.cache[key] = np.concatenate([self.N, *extra], 1) if extra else self.N
        return self.cache[key]

    def width(self, model: AbstractModel) -> int:
        """The structure's columns and its initial-state (:meth:`nuisance`) columns: the slots
        of the design it fills."""
        return len(_columns(model)) + self.nuisance(model).shape[1]

    def _raw(self, model: AbstractModel, names: Sequence[str]) -> dict:
        missing = {n for n in names if n not in self.known and n not in self.cache}
        for e in getattr(model, "effects", ()):  # signals the diagnosis does not precompute:
            own = {c.signal for c in e.columns()} & missing  # the effect's own code
            if own:
                sig = e.signals(self.record)
                for n in own:
                    u, hold = sig[n]
                    self.known[n] = (np.asarray(u, np.float64), hold)
        return {n: self.known.get(n, (None, None)) for n in names}

    def plan(self, model: AbstractModel) -> _Plan:
        """The structure's slots in the design (:class:`_Plan`; small, cached per structure):
        its column count and its F-dependent columns' signals, slots and signs (its width with
        the initial-state columns is :meth:`width`). No (Tp, ·) array is held per structure:
        the design is built from the cached signals when a product needs it (:meth:`design`),
        and the fits read the structure's Gram (:meth:`gram`)."""
        key = ("plan", _model_key(model))
        if key not in self.cache:
            cols = _columns(model)
            p = len(cols)
            n_nuis = self.width(model) - p
            if p + n_nuis > P_MAX:
                raise TooWide(
                    f"structure with {p} columns and {n_nuis} initial-state columns exceeds "
                    f"P_MAX = {P_MAX}"
                )
            fdep = [(j, c) for j, c in enumerate(cols) if f_dependent(c.signal)]
            for _, c in fdep:
                if c.order != 0:
                    raise ValueError(f"unsupported F-dependent column {c}")
            if len(fdep) > K_MAX:
                raise ValueError(f"unsupported F-dependent column {fdep[K_MAX][1]}")
            K = next(k for k in K_BUCKETS if k >= len(fdep))
            onehot = np.zeros((K, P_MAX))
            for kk, (j, c) in enumerate(fdep):
                onehot[kk, j] = c.sign
            self.cache[key] = _Plan(p=p, fdep=tuple(c.signal for _, c in fdep), onehot=onehot)
        return self.cache[key]

    def multipliers(self, model: AbstractModel) -> np.ndarray:
        """(K, Tp) multipliers g(x) of the structure's F-dependent columns g(x)·u (1 for u
        itself; times the force mask where there is one), edge-padded; rows beyond the
        structure's columns are 0."""
        plan = self.plan(model)
        mult = np.zeros((plan.onehot.shape[0], self.Tp))
        for kk, signal in enumerate(plan.fdep):
            g = np.ones(self.T) if f_multiplier(signal) is None else self._multiplier(model, signal)
            if self.force_mask is not None:
                g = g * self.force_mask
            mult[kk] = edge_pad(g, self.Tp)
        return mult

    def columns_padded(self, model: AbstractModel, *, grid: bool = False) -> np.ndarray:
        """(Tp, P_MAX) design of the structure on the padded record: its columns (the
        F-dependent ones for u = F, or 0 with ``grid``), its initial-state columns, then 0 in
        the unused slots."""
        plan = self.plan(model)
        cols = _columns(model)
        fixed = self.fixed_columns(model, cols)
        W = np.zeros((self.Tp, P_MAX))
        for j, v in fixed.items():
            W[:, j] = v
        if plan.fdep and not grid:
            # the design for u = F: each F-dependent signal g·F filtered (cached by name), in
            # one batch with the K slots' unused rows as zero signals: the batched filter may
            # round a signal's last bit differently in a batch of another size, and this batch
            # gives the columns the benchmarks were measured with
            mult = self.multipliers(model)
            K = plan.onehot.shape[0]
            names = [f"{n}·F" for n in plan.fdep] + [f"_zero{k}" for k in range(len(plan.fdep), K)]
            raw = {nm: (mult[k, : self.T] * self.F, "zoh") for k, nm in enumerate(names)}
            filt = self.filtered(raw)
            for k, nm in enumerate(names[: len(plan.fdep)]):
                j = int(np.flatnonzero(plan.onehot[k])[0])
                W[:, j] = plan.onehot[k, j] * filt[nm][:, 0]
        W[:, plan.p : self.width(model)] = self.nuisance(model)
        return W

    def fixed_columns(self, model: AbstractModel, cols: Sequence) -> dict[int, np.ndarray]:
        """{j: (Tp,) filtered column} of the columns ``cols`` of ``model`` that do not depend on
        F, signs included; with a force mask, each force column (order 0) is built from
        m·signal (those held only filtered, a mode's, stay whole)."""
        fixed = sorted({c.signal for c in cols if not f_dependent(c.signal)})
        raw = self._raw(model, [s for s in fixed if s != "x"])
        raw["x"] = (self.x, "foh")
        filt = self.filtered(raw)
        m = self.force_mask
        masked = {}
        if m is not None:
            forces = {
                c.signal
                for c in cols
                if c.order == 0 and c.signal in raw and raw[c.signal][0] is not None
            }
            masked = self.filtered({f"{n}|stick": (m * raw[n][0], raw[n][1]) for n in forces})
        out = {}
        for j, c in enumerate(cols):
            if not f_dependent(c.signal):
                V = masked.get(f"{c.signal}|stick") if c.order == 0 else None
                out[j] = c.sign * (filt[c.signal] if V is None else V)[:, c.order]
        return out

    def added_columns(self, model: AbstractModel, base: AbstractModel) -> np.ndarray | None:
        """(1, K, T) filtered columns (signs included) that ``model`` adds to ``base``, for
        :func:`rss_with_columns` on ``base``; None where it adds more than columns of its own
        signals (an F-dependent column, initial-state columns) or lacks one of ``base``'s."""
        have = set(_model_key(base))
        keys = _model_key(model)
        new = [c for c, k in zip(_columns(model), keys, strict=True) if k not in have]
        if (
            len(keys) - len(new) != len(have)
            or any(f_dependent(c.signal) for c in new)
            or self.nuisance(model).shape[1] != self.nuisance(base).shape[1]
        ):
            return None
        cols = self.fixed_columns(model, new)
        return np.stack([cols[j][: self.T] for j in range(len(new))])[None]

    def _multiplier(self, model, signal: str) -> np.ndarray:
        """g(x) of an F-dependent signal g(x)·F: from ``known``, else from the signals of the
        effect that owns it on a record with F = 1 (then kept in ``known``: a long record
        rebuilds its designs)."""
        name = f_multiplier(signal)
        if name not in self.known:
            ones = Record(self.record.x, np.ones(np.shape(self.record.x)), self.record.dt)
            owner = next(
                (
                    e
                    for e in getattr(model, "effects", ())
                    if signal in {c.signal for c in e.columns()}
                ),
                model,
            )
            self.known[name] = np.asarray(owner.signals(ones)[signal][0], np.float64)
        return self.known[name]

    def _cached(self, key, make, small: bool = False):
        """``make()`` cached under ``key`` (a per-structure key, see :meth:`drop`), except on a
        long record where it is a dense (T, ·) array: there it is rebuilt rather than held.
        ``small`` results (independent of the length) are cached at every length."""
        if self.Tp > BIG and not small:
            return make()
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]

    def design(self, model, *, grid: bool = False) -> np.ndarray:
        """A = [W | ε₁'s x column] on the record's T samples (T, P_MAX + 1), the unused slots
        0: W is the design with u = F, or with ``grid`` its fixed columns only (the
        F-dependent slots 0, filled per input map by :func:`_solve_grid`). Cached per
        structure up to :data:`BIG` padded samples, rebuilt from the cached signals above."""

        def make():
            W = self.columns_padded(model, grid=grid)
            return _augmented_design(W[: self.T], self.W0[: self.T])

        return self._cached(("design", _model_key(model), grid), make)

    def gram(self, model, *, grid: bool = False, n_free: int = 0) -> np.ndarray:
        """G = AᵀA of :meth:`design` (P_MAX + 1)² plus a unit diagonal in the unused slots (the
        Gram of unit columns outside the record: the solver's system keeps one size, and the
        unused coefficients come out 0), except the ``n_free`` slots after the structure's
        columns, left 0 for :func:`rss_with_columns` to fill. Cached per structure at every
        length (it is small): the τ and F_max profiles and the flexible mode's (ω, ζ) profile
        reuse it at every point."""
        return self.design_gram(model, grid=grid, n_free=n_free, need_design=False)[1]

    def design_gram(
        self, model, *, grid: bool = False, n_free: int = 0, need_design: bool = True
    ) -> tuple[np.ndarray | None, np.ndarray]:
        """(:meth:`design`, :meth:`gram`) of a structure, the design built once where both are
        new (a long record rebuilds it); the design None without ``need_design`` where the
        Gram is cached."""
        A = self.design(model, grid=grid) if need_design else None

        def make():
            D = self.design(model, grid=grid) if A is None else A
            return D.T @ D

        G = self._cached(("gram", _model_key(model), grid), make, small=True).copy()
        n = self.width(model)
        unused = np.arange(n, P_MAX)
        pads = unused[unused >= n + n_free]
        G[pads, pads] += 1.0
        return A, G


class _Plan(NamedTuple):
    """A structure's slots in the design (:meth:`Regressors.plan`)."""

    p: int  # its columns
    fdep: tuple[str, ...]  # the signals of its F-dependent columns, in slot order
    onehot: np.ndarray  # (K, P_MAX): the F-dependent columns' slots and signs


#: Cache keys held per structure (dropped with the signals they use).
_PER_STRUCTURE = ("plan", "nuisance", "gram", "design")


#: (model, its columns, its key) by id(model): the fits ask a structure for its columns many
#: times (a profile grid, a plan, a design, a Gram, a nuisance), and building them costs
#: ~0.5 ms (each column an equinox Module). Holding the model keeps its id from being reused;
#: bounded.
_COLUMNS: dict[int, tuple] = {}


def _columns_and_key(model) -> tuple[tuple, tuple]:
    hit = _COLUMNS.get(id(model))
    if hit is None or hit[0] is not model:
        cols = tuple(model.columns())
        if len(_COLUMNS) >= 4096:
            _COLUMNS.clear()
        hit = _COLUMNS[id(model)] = (model, cols, tuple((c.signal, c.order, c.sign) for c in cols))
    return hit[1], hit[2]


def _columns(model) -> tuple:
    """``model.columns()``, once per model object."""
    return _columns_and_key(model)[0]


def _model_key(model) -> tuple:
    """The structure's columns as (signal, order, sign) tuples: the cache key of its plan,
    design, Gram and nuisance."""
    return _columns_and_key(model)[1]


def _solve_grid(regs: Regressors, model: AbstractModel, inputs):
    """coef, RSS, Gram inverse, condition (each leading G) of the masked LS of ``model`` on
    ``regs`` (y = ε₁'s x column) per input map (τ, F_max) in ``inputs``."""
    taus = np.array([float(t) for t, _ in inputs], np.float64)
    fmaxs = np.array([float(f) for _, f in inputs], np.float64)
    onehot = regs.plan(model).onehot
    if len(inputs) == 1 and taus[0] == 0 and fmaxs[0] == np.inf:
        Gs = [regs.gram(model)[None]]
    elif regs.streamed:
        G0 = regs.design_gram(model, grid=True, need_design=False)[1]
        O = np.concatenate([onehot, np.zeros((onehot.shape[0], 1))], 1)  # (K, P + 1)
        Gs = []
        for i in range(0, len(inputs), 2 * GRID_BATCH):  # a pass each: a chunk held per point
            C, D = regs.cross(model, GridColumns(model, inputs[i : i + 2 * GRID_BATCH]), grid=True)
            Gs.append(_gram_from_blocks(G0, C, D, O))
    else:
        # only the K F-dependent columns change along the grid: Gram blocks in float64
        A, G0 = regs.design_gram(model, grid=True)
        mult = regs.multipliers(model)
        O = np.concatenate([onehot, np.zeros((onehot.shape[0], 1))], 1)  # (K, P + 1)
        Gs = []
        gb = GRID_BATCH if regs.Tp <= BIG else 2  # long records: bounded memory
        for i in range(0, len(inputs), gb):
            t, f = taus[i : i + gb], fmaxs[i : i + gb]
            m = t.size
            t = np.concatenate([t, np.zeros(gb - m)])
            f = np.concatenate([f, np.full(gb - m, np.inf)])
            V = _grid_columns(
                regs.dsc,
                regs.Fp,
                mult,
                regs.mask,
                _f(regs.dt),
                t,
                f,
                _i(regs.T),
            )
            V = np.asarray(V, np.float64)[:m, :, : regs.T]
            Gs.append(_gram_with_columns(G0, A, V, O))
    return solve_grams(np.concatenate(Gs), regs.T)


def _gram_with_columns(G0: np.ndarray, A: np.ndarray, V: np.ndarray, O: np.ndarray) -> np.ndarray:
    """Augmented Grams (m, P + 1, P + 1) of [A + VᵀO]: the fixed design A = [W | y] (T, P + 1)
    whose Gram is G0, plus K columns V (m, K, T) placed by the one-hot O (K, P + 1). Only the
    new blocks AᵀV and VᵀV are computed (float64): a profile grid shares the fixed columns."""
    return _gram_from_blocks(G0, *_cross_blocks(A, V), O)


def _cross_blocks(A: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(VᵀA (m, K, P + 1), VᵀV (m, K, K)) of a design A (T, P + 1) and columns V (m, K, T)."""
    m, K, T = V.shape
    # one product for the whole batch (A read once; a batched V @ A multiplies m thin blocks)
    C = (V.reshape(m * K, T) @ A).reshape(m, K, -1)  # (m, K, P + 1)
    D = V @ np.swapaxes(V, 1, 2)  # (m, K, K)
    return C, D


def _gram_from_blocks(G0: np.ndarray, C: np.ndarray, D: np.ndarray, O: np.ndarray) -> np.ndarray:
    """Augmented Grams (m, P + 1, P + 1) of a fixed design's Gram G0 with K columns placed by
    the one-hot O (K, P + 1), from their blocks C = VᵀA and D = VᵀV (:func:`_cross_blocks`)."""
    OC = np.einsum("kp,mkq->mpq", O, C)
    return G0 + OC + np.swapaxes(OC, 1, 2) + np.einsum("kp,mkl,lq->mpq", O, D, O)


def fit_batch(regs: Regressors, model: AbstractModel, inputs):
    """ε₁ least squares on the training record for each input map (τ, F_max) in ``inputs``.

    Returns θ ``(G, p)``, the RSS ``(G,)``, σ²(ΦᵀΦ)⁻¹ ``(G, p, p)`` and condition numbers.
    """
    p = len(_columns(model))
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
    if regs.streamed:
        G0 = regs.design_gram(model, n_free=K, need_design=False)[1]
        G = _gram_from_blocks(G0, *regs.cross(model, src), O)
    else:
        A, G0 = regs.design_gram(model, n_free=K)
        G = _gram_with_columns(G0, A, np.asarray(src.full(regs), np.float64), O)
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
    if regs.streamed:
        Gb = None
        for A, V in zip(regs.design_blocks(model), src.blocks(regs), strict=True):
            g = _refit_gram(A, V, coef, p, n, n_fixed)
            Gb = g if Gb is None else Gb + g
    else:
        Gb = _refit_gram(regs.design(model)[:T], src.full(regs), coef, p, n, n_fixed)
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
    nuisance coefficients are refitted on this record."""
    plan = regs.plan(model)
    p, onehot = plan.p, plan.onehot
    mapped = np.any(onehot) and (inp[0] != 0 or inp[1] != np.inf)
    if regs.streamed:
        return _residual_streamed(regs, model, theta, inp, mapped)
    W = np.ascontiguousarray(regs.columns_padded(model, grid=mapped)[:, :p])
    if mapped:
        mult = regs.multipliers(model)
        u = edge_pad(apply_input(regs.F, regs.dt, inp[0], inp[1]), regs.Tp)
        V = filter_signals(regs.dsc, mult * u[None, :], np.zeros(mult.shape[0]))[:, :, 0]
        W += (V.T @ onehot)[:, :p]
    r0 = W @ np.asarray(theta) + regs.W0
    nuis = regs.nuisance(model)
    n = nuis.shape[1]
    # the nuisance's least squares on the masked record
    g = _augmented_gram(nuis[: regs.T], r0[: regs.T])
    eta = _solve_small_grams(g[None], regs.T)[0][0, :n]
    return (r0 + nuis @ eta)[: regs.T]


def _residual_streamed(regs, model, theta, inp, mapped: bool) -> np.ndarray:
    """:func:`residual` of streamed regressors: r₀ = Wθ + y chunk by chunk, with the Gram of
    [N | r₀] for the nuisance's least squares, then r₀ + Nη."""
    plan = regs.plan(model)
    p, n, onehot = plan.p, regs.width(model), plan.onehot
    theta = np.asarray(theta, np.float64)
    r0 = np.empty(regs.T)
    g = np.zeros((n - p + 1, n - p + 1))
    mapped_cols = GridColumns(model, [inp]).blocks(regs) if mapped else None
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
    optional force term ``extra(x, v, u, t)`` [N] (:class:`~._force_effects.SimulatedForce`,
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
    args = [edge_pad(a, Tp) for a in signals]
    pj = {k: _f(v) for k, v in p.items()}
    t = None
    if extra is not None:
        t = jnp.asarray(float(t0) + float(dt) * np.arange(k0, k0 + Tp), jnp.float64)
    e = windowed_errors(pj, *args, _f(dt), _i(H), _i(Tn), extra, t, span=window_span(H))
    return np.asarray(e)[:T]
