"""The record in chunks: the diagnosis' filters with their states carried from chunk to chunk,
and the column sources whose products a fit accumulates (:class:`~._regressors.Regressors`).

Every product the fits read is a sum over rows, so it is accumulated chunk by chunk: a long
record's filtered signals are never held whole, and a short record is one chunk. Each chunk runs
the recursion from the state the previous one ended in (the first from the steady state before
the record), its hold correction reading the neighbouring samples (:func:`window`): the chunk
length changes the numbers only in their last bits. Raw signals are functions of a row range,
``raw(k0, k1) -> (k1 − k0,)`` (:func:`rows` of a held array, or computed per chunk).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._filters import FilterBank
from ._filtering import (
    Discrete,
    _f,
    _mode_stages,
    filter_from,
    mode_cascade_from,
    padded_length,
    seed_discrete,
)

#: Samples per chunk of a long record: 32 signals' outputs take 67 MB, and the cost per sample
#: does not depend on it above a few 10⁴.
CHUNK = 1 << 16
#: Signals filtered per call, and modes whose stages one call computes: the smallest batch that
#: holds them (one program per batch).
BATCHES = (1, 2, 4, 8, 16, 32)
MODE_BUCKETS = (1, 2, 4)
#: The most signal samples (signals × chunk) one filter call holds, and mode samples (modes ×
#: chunk) one mode-stage call: beyond them a call's arrays leave the processor's caches and its
#: cost per sample rises 2–5× (:func:`batch_top`).
FILTER_SAMPLES = 1 << 19
MODE_SAMPLES = 1 << 17

Raw = Callable[[int, int], np.ndarray]


def batch_top(buckets: Sequence[int], samples: int, chunk: int) -> int:
    """The largest of ``buckets`` whose calls on chunks of ``chunk`` samples hold at most
    ``samples`` (the smallest where none does). Each signal's or mode's numbers are the same in
    any batch, bit for bit at XLA's default optimisation level: the batch sets only the cost."""
    fit = [b for b in buckets if b * chunk <= samples]
    return fit[-1] if fit else buckets[0]


def rows(a) -> Raw:
    """The raw signal of a held array ``a`` (T,), or ``a`` itself where it is one already."""
    if callable(a):
        return a
    a = np.asarray(a, np.float64)
    return lambda k0, k1: a[k0:k1]


def scaled(m, raw: Raw) -> Raw:
    """``m·raw`` for a multiplier ``m`` (a force mask, a position's), held (T,) or raw."""
    m = rows(m)
    return lambda k0, k1: m(k0, k1) * raw(k0, k1)


def spans(T: int, chunk: int) -> list[tuple[int, int]]:
    """The row ranges [k0, k1) of ``T`` samples in chunks of ``chunk``."""
    return [(k, min(k + chunk, T)) for k in range(0, T, chunk)]


def chunk_length(T: int) -> int:
    """The chunk of a record of ``T`` samples: :data:`CHUNK`, or the record's padded length
    where that is shorter (a short record is one chunk)."""
    return min(CHUNK, padded_length(T))


def window(raw: Raw, k0: int, T: int, C: int) -> np.ndarray:
    """u[k0 − 1 … k0 + C + 1] (C + 3,) of a signal of ``T`` samples: the rows a chunk of ``C``
    samples from ``k0`` reads for its hold correction; beyond the record its last sample
    repeated, u[−1] a stand-in (:func:`_held` replaces its Δ²)."""
    lo, hi = max(k0 - 1, 0), min(k0 + C + 2, T)
    w = np.asarray(raw(lo, hi), np.float64)
    off = 1 if k0 == 0 else 0
    out = np.empty(C + 3)
    out[off : off + w.size] = w
    out[off + w.size :] = w[-1]
    out[:off] = w[:1]
    return out


def _held(w, foh, first):
    """(u, u held, its steps) (C,) each of a :func:`window` ``w`` (C + 3,): uₖ − foh·Δ²uₖ/12
    (on the ``first`` chunk the first Δ² is the second's) and foh·(next held − held).

    ``foh`` 1.0: a smooth signal under a first-order hold; 0.0: a zero-order-held input (F).
    A smooth u(t) differs from its linear interpolant by ½ü(t − tₖ)(t − tₖ₊₁), of mean −h²ü/12:
    a low-pass filter sees u − (h²/12)ü, an equation error ∝ (ωh)²/12 that looks like a flexible
    mode at a few hundred Hz. Subtracting Δ²u/12 leaves O(h⁴) (Simpson against the trapezoid).
    The last sample's Δ² sees the padding: one row, off by up to Δx/12."""
    d2 = w[2:] - 2.0 * w[1:-1] + w[:-2]  # Δ² at k0 … k0 + C
    d2 = d2.at[0].set(jnp.where(first, d2[1], d2[0]))
    h = w[1:-1] - foh * d2 / 12.0
    return w[1:-2], h[:-1], foh * (h[1:] - h[:-1])


def _window_filter(dsc: Discrete, w, foh, first, z):
    """(outputs (r, C), end state (n,)) of one signal's :func:`window` ``w`` held and filtered
    from the state ``z``, or with ``first`` from the steady state of its first held sample."""
    u_at, h, du = _held(w, foh, first)
    z = jnp.where(first, jnp.zeros_like(z).at[0].set(h[0] / dsc.c_last), z)
    V, end = filter_from(dsc, u_at, h, du, z)
    return V.T, end


@jax.jit
def _filter_window(dsc: Discrete, W, foh, first, z0):
    """:func:`_window_filter` of signals W (B, C + 3) through one filter: (B, r, C), (B, n)."""
    return jax.vmap(_window_filter, in_axes=(None, 0, 0, None, 0))(dsc, W, foh, first, z0)


@jax.jit
def _mode_chunk(stages, zeta, lam, Vx, wx, VF, F, p0, first):
    _, h, du = _held(wx, 1.0, first)
    return mode_cascade_from(stages, zeta, lam, Vx, h, du, VF, F, p0)


class Filters:
    """Signals ``inputs`` {name: (raw, foh)} filtered chunk by chunk through one bank, their
    states carried (the first chunk from the steady state of its first held sample). ``kept``
    (a record of one chunk): outputs {name: (4, T)} read instead of filtered again, where each
    new one is kept (a name stands for its samples)."""

    def __init__(self, dsc: Discrete, T: int, chunk: int, inputs: dict, kept: dict | None = None):
        self.dsc, self.T, self.chunk, self.inputs, self.kept = dsc, T, chunk, inputs, kept
        self.names = list(inputs)
        self.z: np.ndarray | None = None  # (S, n) states before the next chunk

    def step(self, k0: int, k1: int) -> dict:
        """{name: (r, c) outputs (V₁…V₄ of the diagnosis' bank)} of rows [k0, k1), in order."""
        kept = {} if self.kept is None else self.kept
        todo = [n for n in self.names if n not in kept]
        out = {}
        if todo:
            W = np.stack([window(self.inputs[n][0], k0, self.T, self.chunk) for n in todo])
            foh = np.array([self.inputs[n][1] for n in todo])
            out = dict(zip(todo, self.step_windows(W, foh, k1 - k0), strict=True))
            if self.kept is not None:
                self.kept.update(out)
        return {n: out[n] if n in out else kept[n] for n in self.names}

    def step_windows(self, W: np.ndarray, foh: np.ndarray, c: int, front: int = 0) -> np.ndarray:
        """(S, r, c) outputs of the next chunk from the signals' windows W (S, chunk + 3), its c
        samples from ``front`` on, in batches of :data:`BATCHES`; the states carried."""
        S = W.shape[0]
        n = np.asarray(self.dsc.Phi).shape[0]
        first = self.z is None
        z = np.zeros((S, n)) if first else self.z
        V = np.empty((S, np.shape(self.dsc.C)[0], c))
        z_next = np.empty_like(z)
        top = batch_top(BATCHES, FILTER_SAMPLES, W.shape[1] - 3)
        for i in range(0, S, top):
            j = min(i + top, S)
            b = next(b for b in BATCHES if b >= j - i)
            pad = ((0, b - (j - i)), (0, 0))
            args = (np.pad(W[i:j], pad), np.pad(foh[i:j], pad[0]), np.bool_(first))
            out, end = _filter_window(self.dsc, *args, np.pad(z[i:j], pad))
            V[i:j] = np.asarray(out)[: j - i, :, front : front + c]
            z_next[i:j] = np.asarray(end)[: j - i]
        self.z = z_next
        return V

    def step_values(self, U: np.ndarray, last: bool) -> np.ndarray:
        """(S, r, c) outputs of the next chunk of zero-order-held values U (S, c) (handed over by
        a pass backwards in time). A short chunk is padded behind where it is the ``last``, else
        in front with its first value (the state steady there: its end state is the one after
        its c values)."""
        S, c = U.shape
        front = 0 if (c == self.chunk or last) else self.chunk - c
        pre, post = U[:, :1].repeat(front + 1, 1), U[:, -1:].repeat(self.chunk + 2 - front - c, 1)
        return self.step_windows(np.concatenate([pre, U, post], 1), np.zeros(S), c, front)


class ModeStages:
    """Flexible modes' stages (:func:`~._filtering.mode_cascade_from`) of modes (ω [rad/s], ζ)
    (m, 2) chunk by chunk, their states carried; in groups of up to four (fewer where a chunk is
    long: :data:`MODE_SAMPLES`), the last padded to a bucket of :data:`MODE_BUCKETS` by
    repeating its last mode (one program per bucket)."""

    def __init__(self, modes, lam: float, dt: float, chunk: int, groups: list | None = None):
        modes = np.asarray(modes, np.float64).reshape(-1, 2)
        self.m, self.lam, self.chunk = len(modes), float(lam), chunk
        #: (stages, ζ) of each group: ``groups`` where given (another record's at the same dt
        #: and chunk), else sampled here
        self.groups = self.sampled(modes, lam, dt, chunk) if groups is None else groups
        self.p: list | None = None  # each group's states (2b, 2)

    @staticmethod
    def sampled(modes: np.ndarray, lam: float, dt: float, chunk: int) -> list:
        """The groups' sampled stages (stages, ζ) of ``modes`` (m, 2)."""
        groups = []
        top = batch_top(MODE_BUCKETS, MODE_SAMPLES, chunk)
        for i in range(0, len(modes), top):
            g = modes[i : i + top]
            full = np.concatenate([g, np.repeat(g[-1:], top - len(g), 0)])
            b = next(b for b in MODE_BUCKETS if b >= len(g))
            st = _mode_stages(full[:, 0], full[:, 1], _f(lam), _f(dt))
            groups.append((tuple(np.asarray(a)[:b] for a in st), full[:b, 1]))
        return groups

    def step(self, Vx, Vf, x: np.ndarray, F: np.ndarray, k0: int, k1: int):
        """(x's columns (m, c), F's columns (m, c)) of rows [k0, k1), from the chunk's filtered
        x and F ``Vx``, ``Vf`` (4, c) and the records ``x``, ``F``."""
        c, C = k1 - k0, self.chunk
        first = self.p is None
        if first:  # x steady at 0 in p, F steady at F[0]: p = (F[0], 0)
            self.p = [np.zeros((2 * len(z), 2)) for _, z in self.groups]
            for p, (_, z) in zip(self.p, self.groups, strict=True):
                p[len(z) :, 0] = F[k0]
        wx = window(rows(x), k0, x.size, C)
        Vx, Vf = (np.pad(V, ((0, 0), (0, C - c))).T for V in (Vx, Vf))
        Fc = np.pad(np.asarray(F[k0:k1], np.float64), (0, C - c))
        out = [
            _mode_chunk(st, zeta, np.float64(self.lam), Vx, wx, Vf, Fc, p, np.bool_(first))
            for (st, zeta), p in zip(self.groups, self.p, strict=True)
        ]
        self.p = [np.asarray(end) for *_, end in out]  # a new list: a saved state stays valid
        cx, cF = (np.concatenate([np.asarray(o[i])[:, :c] for o in out])[: self.m] for i in (0, 1))
        return cx, cF


class FreeRows:
    """V₁ of the unforced filter from each unit state, C·Φʲ·Φᵏ⁰ at rows k0 + j of a chunk (Φʲ
    computed once)."""

    def __init__(self, dsc: Discrete, chunk: int):
        self.Phi = np.asarray(dsc.Phi, np.float64)
        n = self.Phi.shape[0]
        Pw = np.empty((chunk, n, n))
        Pw[0] = np.eye(n)
        m = 1
        while m < chunk:  # Φʲ by doubling: Φ^(m + j) = Φʲ·Φᵐ
            k = min(m, chunk - m)
            Pw[m : m + k] = Pw[:k] @ (self.Phi @ Pw[m - 1])
            m += k
        self.row = np.asarray(dsc.C, np.float64)[0] @ Pw  # (chunk, n): C·Φʲ

    def __call__(self, k0: int, k1: int) -> np.ndarray:
        if k0 == 0:
            return self.row[:k1].copy()
        P = np.linalg.matrix_power(self.Phi, k0)
        if not np.any(P):
            return np.zeros((k1 - k0, self.Phi.shape[0]))
        return self.row[: k1 - k0] @ P


def input_map(F, dt: float, tau: float, fmax: float, k0: int = 0, k1: int | None = None):
    """Rows [k0, k1) (default all) of u = sat_Fmax(F(t − τ)) [N] for a force F held between
    samples: with τ = (n + φ)·dt the delayed force averaged over each interval is
    F_d[k] = (1 − φ)F[k − n] + φF[k − n − 1] (F before the record = F[0], after it F[T − 1]:
    τ < 0 reads ahead). F_max > 0 the hard clip; F_max < 0 the soft saturation
    |F_max|·tanh(F/|F_max|) (one grid holds both)."""
    F = np.asarray(F, np.float64)
    T = F.shape[0]
    k1 = T if k1 is None else k1
    s = tau / dt
    n = np.floor(s)
    phi = s - n
    k = np.arange(k0, k1)
    j = k - int(n)
    i0, i1 = np.clip(j, 0, T - 1), np.clip(j - 1, 0, T - 1)
    Fd = (1 - phi) * F[i0] + phi * F[i1]
    m = abs(fmax)
    if fmax < 0:
        return m * np.tanh(Fd / (m if np.isfinite(m) else 1.0))
    return np.clip(Fd, -m, m)


class ColumnSource:
    """Columns of m points, K columns each, that a fit adds to a structure's design:
    :meth:`blocks` yields one (m, K, c) block per chunk of ``regs.spans``."""

    def blocks(self, regs) -> Iterator[np.ndarray]:
        raise NotImplementedError


class HeldColumns(ColumnSource):
    def __init__(self, cols: np.ndarray):
        self.cols = np.asarray(cols, np.float64)

    def blocks(self, regs) -> Iterator[np.ndarray]:
        for k0, k1 in regs.spans:
            yield self.cols[:, :, k0:k1]


def as_source(cols) -> ColumnSource:
    return cols if isinstance(cols, ColumnSource) else HeldColumns(cols)


class FilteredColumns(ColumnSource):
    """Raw signals filtered, one output each, signed: ``signals`` [[(raw, foh, order, sign)
    × K] × m]."""

    def __init__(self, signals: Sequence[Sequence[tuple[Raw, float, int, float]]]):
        self.signals = [list(s) for s in signals]

    def blocks(self, regs) -> Iterator[np.ndarray]:
        flat = [s for point in self.signals for s in point]
        m, K = len(self.signals), len(self.signals[0])
        filt = Filters(
            regs.dsc, regs.T, regs.chunk, {i: (raw, foh) for i, (raw, foh, _, _) in enumerate(flat)}
        )
        signs = np.array([s for *_, s in flat])[:, None]
        for k0, k1 in regs.spans:
            out = filt.step(k0, k1)
            V = np.stack([out[i][order] for i, (_, _, order, _) in enumerate(flat)]) * signs
            yield V.reshape(m, K, k1 - k0)


def grid_columns(regs, model, inputs) -> FilteredColumns:
    """A structure's F-dependent columns for each input map (τ, F_max) of ``inputs``, unsigned:
    (m, K, ·), K the structure's slots (zero beyond its F-dependent signals)."""
    plan = regs.plan(model)
    mult = [regs.multiplier(model, s) for s in plan.fdep]

    def signal(tau: float, fmax: float, k: int) -> Raw:
        if k >= len(mult):
            return lambda k0, k1: np.zeros(k1 - k0)
        u = lambda k0, k1: input_map(regs.F, regs.dt, tau, fmax, k0, k1)  # noqa: E731
        return u if mult[k] is None else scaled(mult[k], u)

    K = plan.onehot.shape[0]
    points = [(float(t), float(f)) for t, f in inputs]
    return FilteredColumns([[(signal(t, f, k), 0.0, 0, 1.0) for k in range(K)] for t, f in points])


def mode_seed(x, F, dt: float, lam: float, chunk: int):
    """A first guess of a flexible mode's (ω [rad/s], ζ) from one linear fit, or None.

    With the mode, ẍ + aẋ − μ·s²h[x] = b(u − κh[u]) (h = (s²/D)[·], D = s² + 2ζωs + ω²) is,
    multiplied by D, (1 − μ)s⁴x + (a + Z)s³x + (W + aZ)s²x + aW·sx = b(1 − κ)s²u + bZ·su + bW·u
    (W = ω², Z = 2ζω): linear in its six coefficients over 1 − μ, fitted by equation-error least
    squares through 1/(s + λ)⁵ (the first 10/λ seconds dropped), its Gram accumulated chunk by
    chunk. Then r = Z/W = c₅/c₆ and W = c₃/(c₁ + r²c₃ − rc₂). Biased by noise and by any other
    effect, it only starts the profile's search, whose RSS valley in (ω, ζ) is a few per cent
    wide for a lightly damped mode (a coarse grid misses it)."""
    T = np.size(x)
    dsc = seed_discrete(np.float64(lam), np.float64(dt))
    f = Filters(dsc, T, chunk, {"x": (rows(x), 1.0), "F": (rows(F), 0.0)})
    n0 = min(int(math.ceil(10.0 / (lam * dt))), T // 4)
    M = np.zeros((7, 7))
    for k0, k1 in spans(T, chunk):
        out = f.step(k0, k1)
        lo = max(n0 - k0, 0)
        if lo < k1 - k0:
            X, Fv = out["x"][1:, lo:], out["F"][:4, lo:]  # x's s¹…s⁴, F's s⁰…s³
            B = np.stack([-X[2], -X[1], -X[0], Fv[2], Fv[1], Fv[0], X[3]], 1)
            M += B.T @ B
    N = T - n0
    scale = np.maximum(np.sqrt(np.diag(M)[:6] / N), 1e-300)
    G = M[:6, :6] / np.outer(scale, scale)
    c1, c2, c3, _, c5, c6 = np.linalg.lstsq(G, M[:6, 6] / scale, rcond=None)[0] / scale
    with np.errstate(all="ignore"):
        r = c5 / c6
        W = c3 / (c1 + r * r * c3 - r * c2)
        zeta = r * math.sqrt(W) / 2 if W > 0 else math.nan
    if not (math.isfinite(W) and W > 0 and math.isfinite(zeta) and zeta > 0):
        return None
    return math.sqrt(W), zeta


def filtered(dsc: Discrete, u, foh: float, chunk: int | None = None, orders=(0, 1, 2, 3)):
    """(len(orders), T) outputs ``orders`` of one signal u (T,) under the hold ``foh``, in chunks
    of ``chunk`` samples (default :func:`chunk_length`)."""
    T = np.size(u)
    chunk = chunk or chunk_length(T)
    f = Filters(dsc, T, chunk, {0: (rows(u), foh)})
    out = np.empty((len(orders), T))
    for k0, k1 in spans(T, chunk):
        out[:, k0:k1] = f.step(k0, k1)[0][list(orders)]
    return out


def zero_phase(x, dt: float, omega: float, chunk: int | None = None):
    """(x smoothed, v̂) (T,) each: x forwards, then backwards through (ω/(s + ω))³ (unit DC
    gain, first-order hold), then central differences (one-sided at the ends)."""
    bank = FilterBank.from_poles(np.full(3, -float(omega)), unit_dc_gain=True)
    dsc = Discrete.of(bank, dt)
    fwd = filtered(dsc, np.asarray(x, np.float64), 1.0, chunk, (0,))[0]
    sm = filtered(dsc, fwd[::-1], 1.0, chunk, (0,))[0][::-1].copy()
    g = np.empty(sm.size)
    g[1:-1] = (sm[2:] - sm[:-2]) / (2 * dt)
    g[0] = (sm[1] - sm[0]) / dt
    g[-1] = (sm[-1] - sm[-2]) / dt
    return sm, g


def _mode_bank(dt: float, w: float, z: float) -> Discrete:
    """The bank Λ = (s + ω)·D, D = s² + 2ζωs + ω² (ω [rad/s]), discretised at dt: its outputs
    V₁ … V₄ = sʲ/Λ give a mode's filters exactly."""
    wd = w * math.sqrt(max(1.0 - z * z, 0.0))
    bank = FilterBank.from_poles(np.asarray([-w + 0j, -z * w + 1j * wd, -z * w - 1j * wd]))
    return Discrete.of(bank, dt)


def mode_filtered(u, foh: float, dt: float, omega: float, zeta: float) -> np.ndarray:
    """h = (s²/D)[u] (T,), D = s² + 2ζωs + ω² (ω [rad/s]), under the hold ``foh``: V₄ + ωV₃ of
    the bank (s + ω)·D, exactly."""
    w = float(omega)
    V = filtered(_mode_bank(dt, w, float(zeta)), u, foh)
    return V[3] + w * V[2]


def mode_states(x, x_start, v_start, u, dt: float, omega: float, zeta: float) -> np.ndarray:
    """A flexible mode's states (d, ḋ, z₁, z₂) at every sample (T, 4), where the windowed
    simulation restarts them (:class:`~lionjax.twin._windows.ModeTerm`): the load's position
    y = ((2ζωs + ω²)/D)[x] and ẏ from the measured x (first-order hold; causal, as the load
    answers the axis' past), d = x_start − y, ḋ = v_start − ẏ at the axis' start states; the
    input's z₁ = (1/D)[u], z₂ = (s/D)[u] (held). Outputs of the bank Λ = (s + ω)·D, exactly."""
    w, z = float(omega), float(zeta)
    dsc = _mode_bank(dt, w, z)
    V = filtered(dsc, np.asarray(x, np.float64), 1.0)
    # (2ζωs + ω²)(s + ω) = 2ζω·s² + (2ζω² + ω²)·s + ω³
    c2, c1, c0 = 2 * z * w, 2 * z * w * w + w * w, w**3
    y = c2 * V[2] + c1 * V[1] + c0 * V[0]
    y_dot = c2 * V[3] + c1 * V[2] + c0 * V[1]
    U = filtered(dsc, np.asarray(u, np.float64), 0.0)
    z1, z2 = U[1] + w * U[0], U[2] + w * U[1]
    return np.stack([np.asarray(x_start) - y, np.asarray(v_start) - y_dot, z1, z2], axis=1)


def impulse_gains(bank: FilterBank, dt, a) -> tuple[float, float]:
    """(Σh_x², Σh_F²) of ε₁'s responses to unit white noise on x (foh) and F (zoh): as
    ε₁ ∋ (s² + as)/Λ[x] − b/Λ[F], noises σ_x, σ_F add σ_x²Σh_x² + b²σ_F²Σh_F² to its variance."""
    c = np.asarray(bank.coeffs)
    T = int(round(float(20 * c[-2] / c[-1] / dt))) + 64
    d = np.zeros(T)
    d[1] = 1.0
    dsc = Discrete.of(bank, dt)
    Vx, VF = filtered(dsc, d, 1.0), filtered(dsc, d, 0.0)
    hx = Vx[2] + a * Vx[1]
    return float(np.sum(hx * hx)), float(np.sum(VF[0] * VF[0]))
