"""The record in chunks: the diagnosis' filters with their states carried from chunk to chunk,
and column sources whose products a streamed fit accumulates (:class:`~._streamed.Streamed`).

A long record's filtered signals, designs and profile columns are never held whole: every
product the fits read (Grams, cross products with a profile's columns, a validation residual's
refitted part) is a sum over rows, so it is accumulated chunk by chunk of :data:`CHUNK` samples.
Each chunk runs the same recursion as a whole record (:func:`~._filtering.filter_from`,
:func:`~._filtering.mode_cascade_from`) from the state the previous chunk ended in; the first
starts from the steady state before the record, as the whole-record filter does, and the
hold correction of each chunk reads its neighbours' samples (:func:`held`). So a chunked pass
gives the whole record's numbers, rounded differently in the last bits.

Raw signals are functions of a row range, ``raw(k0, k1) -> (k1 − k0,)`` (:func:`rows` of a held
array, or computed per chunk: a profile's sinusoids, an input map): a pass holds one chunk of
each.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ._filtering import (
    Discrete,
    _seed_discretes,
    filter_from,
    mode_cascade_from,
    padded_length,
    seed_design,
    seed_mode,
)

#: Samples per chunk of a streamed pass. A chunk of 32 signals holds (32, 2¹⁶, 4) float64
#: outputs (67 MB); the passes' cost per sample does not depend on it above a few 10⁴.
CHUNK = 1 << 16
#: Signals filtered per call of a chunk's filter (the smallest that holds them; one program per
#: batch and chunk length).
BATCHES = (1, 2, 4, 8, 16, 32)

Raw = Callable[[int, int], np.ndarray]


def rows(a) -> Raw:
    """The raw signal of a held array ``a`` (T,), or ``a`` itself where it is one already."""
    if callable(a):
        return a
    a = np.asarray(a, np.float64)
    return lambda k0, k1: a[k0:k1]


def scaled(m, raw: Raw) -> Raw:
    """``m·raw`` for a multiplier ``m`` (a force mask, a position's multiplier), held (T,) or
    a raw signal."""
    m = rows(m)
    return lambda k0, k1: m(k0, k1) * raw(k0, k1)


def spans(T: int, chunk: int) -> list[tuple[int, int]]:
    """The row ranges [k0, k1) of ``T`` samples in chunks of ``chunk``."""
    return [(k, min(k + chunk, T)) for k in range(0, T, chunk)]


def chunk_length(T: int) -> int:
    """The chunk of a record of ``T`` samples: :data:`CHUNK`, or the record's own padded length
    where that is shorter (a short record is one chunk, on the in-memory path's bucket)."""
    return min(CHUNK, padded_length(T))


def held(raw: Raw, k0: int, k1: int, T: int, foh: float):
    """(u (c,), u held (c,), its steps (c,)) of rows [k0, k1) of a signal of ``T`` samples, as
    :func:`~._filtering._filt` forms them on the whole record: u − foh·Δ²u/12
    (:func:`~._filtering.hold_corrected`: Δ² of the first sample is the second's, samples beyond
    the record repeat its last) and foh·(next held − held)."""
    lo, hi = max(k0 - 1, 0), min(k1 + 2, T)
    w = np.asarray(raw(lo, hi), np.float64)
    parts = [w[:1]] if k0 == 0 else []  # a stand-in for u[−1], whose Δ² is replaced
    parts += [w, np.repeat(w[-1:], k1 + 2 - hi)]
    w = np.concatenate(parts)  # u[k0 − 1 … k1 + 1]
    d2 = w[2:] - 2.0 * w[1:-1] + w[:-2]  # Δ² at k0 … k1
    if k0 == 0:
        d2[0] = d2[1]
    h = w[1:-1] - foh * d2 / 12.0
    return w[1:-2], h[:-1], foh * (h[1:] - h[:-1])


@jax.jit
def _filter_window(dsc: Discrete, W, foh, first, z0):
    """Outputs (B, 4, C) and end states (B, n) of signals given by their windows W (B, C + 3) =
    u[k0 − 1 … k0 + C + 1]: held (:func:`held`'s arithmetic) and filtered from ``z0``, or with
    ``first`` from the steady state of the first held sample."""
    c_last = dsc.c_last

    def one(w, f, z):
        d2 = w[2:] - 2.0 * w[1:-1] + w[:-2]  # Δ² at k0 … k0 + C
        d2 = d2.at[0].set(jnp.where(first, d2[1], d2[0]))
        h = w[1:-1] - f * d2 / 12.0
        z = jnp.where(first, jnp.zeros_like(z).at[0].set(h[0] / c_last), z)
        V, end = filter_from(dsc, w[1:-2], h[:-1], f * (h[1:] - h[:-1]), z)
        return V.T, end

    return jax.vmap(one)(W, foh, z0)


@jax.jit
def _filter_chunk(dsc: Discrete, u_at, u, du, z0):
    return jax.vmap(filter_from, in_axes=(None, 0, 0, 0, 0))(dsc, u_at, u, du, z0)


@jax.jit
def _mode_chunk(stages, zeta, lam, Vx, u, du, VF, F, p0):
    return mode_cascade_from(stages, zeta, lam, Vx, u, du, VF, F, p0)


def _pad_rows(a: np.ndarray, n: int) -> np.ndarray:
    """``a`` (…, c) padded with zeros to (…, n) along its last axis."""
    if a.shape[-1] == n:
        return a
    return np.concatenate([a, np.zeros(a.shape[:-1] + (n - a.shape[-1],))], -1)


class Filters:
    """Signals filtered chunk by chunk through one bank, their states carried
    (:func:`~._filtering.filter_from`); :meth:`step` filters the next chunk of every signal.

    ``inputs``: {name: (raw, foh)}, ``foh`` 1.0 (first-order hold of the hold-corrected
    samples) or 0.0 (zero-order hold). The first chunk starts from the steady state of its
    first (held) sample, as the whole-record filter does."""

    def __init__(self, dsc: Discrete, T: int, chunk: int, inputs: dict[str, tuple[Raw, float]]):
        self.dsc, self.T, self.chunk = dsc, T, chunk
        self.names = list(inputs)
        self.inputs = inputs
        self.z: np.ndarray | None = None  # (S, n) states before the next chunk
        self.c_last = float(np.asarray(dsc.c_last))

    def step(self, k0: int, k1: int) -> dict:
        """{name: (4, c) outputs V₁…V₄} of rows [k0, k1), in order (one compiled call per
        batch of :data:`BATCHES`: each signal's window u[k0 − 1 … k0 + chunk + 1] held and
        filtered inside it, :func:`_filter_window`)."""
        if not self.names:
            return {}
        c, C, T = k1 - k0, self.chunk, self.T
        lo, hi = max(k0 - 1, 0), min(k0 + C + 2, T)
        off = 1 if k0 == 0 else 0  # u[−1]: a stand-in (the first Δ² is the second's)
        n = np.asarray(self.dsc.Phi).shape[0]
        first = self.z is None
        z = np.zeros((len(self.names), n)) if first else self.z
        V = {}
        z_next = np.empty_like(z)
        items = list(self.inputs.values())
        top = BATCHES[-1]
        for i in range(0, len(items), top):
            part = items[i : i + top]
            b = next(b for b in BATCHES if b >= len(part))
            W = np.zeros((b, C + 3))
            for s, (raw, _) in enumerate(part):
                w = np.asarray(raw(lo, hi), np.float64)
                W[s, off : off + w.size] = w
                W[s, off + w.size :] = w[-1]  # beyond the record: its last sample
                if off:
                    W[s, 0] = w[0]
            foh = np.zeros(b)
            foh[: len(part)] = [f for _, f in part]
            z0 = np.zeros((b, n))
            z0[: len(part)] = z[i : i + len(part)]
            out, end = _filter_window(self.dsc, W, foh, np.bool_(first), z0)
            out = np.asarray(out)
            for s in range(len(part)):
                V[self.names[i + s]] = out[s, :, :c]
            z_next[i : i + len(part)] = np.asarray(end)[: len(part)]
        self.z = z_next  # after a short (last) chunk: never read
        return V

    def step_held(self, Ua, Uh, dU, last: bool) -> np.ndarray:
        """(S, c, 4) outputs of the next chunk from its samples, held samples and steps (S, c)
        each. A short chunk is padded behind where it is the ``last`` (its end state is never
        read) and in front otherwise (a first chunk: its held first sample repeated, the state
        steady there, so that its end state is the one after its c samples)."""
        S, c = Ua.shape
        C = self.chunk
        n = np.asarray(self.dsc.Phi).shape[0]
        if self.z is None:  # steady before the record
            self.z = np.zeros((S, n))
            self.z[:, 0] = Uh[:, 0] / self.c_last
        front = 0 if (c == C or last) else C - c
        if front:
            Ua, Uh = (np.concatenate([np.repeat(a[:, :1], front, 1), a], 1) for a in (Ua, Uh))
            dU = np.concatenate([np.zeros((S, front)), dU], 1)
        V = np.empty((S, c, 4))
        z_next = np.empty_like(self.z)
        top = BATCHES[-1]
        for i in range(0, S, top):
            j = min(i + top, S)
            b = next(b for b in BATCHES if b >= j - i)
            args = [_pad_rows(a[i:j], C) for a in (Ua, Uh, dU)]
            args = [np.concatenate([a, np.zeros((b - (j - i), C))]) for a in args]
            z0 = np.concatenate([self.z[i:j], np.zeros((b - (j - i), n))])
            out, end = _filter_chunk(self.dsc, *args, z0)
            V[i:j] = np.asarray(out)[: j - i, front : front + c]
            z_next[i:j] = np.asarray(end)[: j - i]
        self.z = z_next
        return V


class ModeStages:
    """The flexible mode's stages (:func:`~._filtering.mode_cascade_from`) of modes ``stages``
    (a batch, :func:`~._filtering._mode_stages`) chunk by chunk, their states carried; fed each
    chunk's filtered x and F and x's held samples."""

    def __init__(self, stages, zeta: np.ndarray, lam: float, chunk: int):
        self.stages, self.zeta, self.lam, self.chunk = stages, zeta, lam, chunk
        self.p: np.ndarray | None = None

    def step(self, Vx, Vf, x: np.ndarray, F: np.ndarray, k0: int, k1: int):
        """(x's columns (m, c), F's columns (m, c)) of rows [k0, k1); ``Vx``, ``Vf`` the
        filtered x and F of the chunk ((4, c) each, :meth:`Filters.step`), ``x``, ``F`` the
        records."""
        c, C = k1 - k0, self.chunk
        m = self.zeta.shape[0]
        _, h, du = held(rows(x), k0, k1, x.size, 1.0)
        if self.p is None:  # x steady at 0 in p, F steady at F[0]: p = (F[0], 0)
            self.p = np.zeros((2 * m, 2))
            self.p[m:, 0] = F[k0]
        pad = lambda a: _pad_rows(a, C).T  # noqa: E731
        cx, cF, end = _mode_chunk(
            self.stages,
            self.zeta,
            np.float64(self.lam),
            pad(Vx),
            _pad_rows(h, C),
            _pad_rows(du, C),
            pad(Vf),
            _pad_rows(np.asarray(F[k0:k1], np.float64), C),
            self.p,
        )
        self.p = np.asarray(end)
        return np.asarray(cx)[:, :c], np.asarray(cF)[:, :c]


class FreeRows:
    """V₁ of the unforced filter from each unit state (:func:`~._filtering._free`) at any rows:
    C·Φʲ·Φᵏ⁰ for rows k0 + j of a chunk (Φʲ for j < chunk computed once); zeros where Φᵏ⁰ has
    decayed to nothing."""

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
        """(k1 − k0, n) rows [k0, k1)."""
        if k0 == 0:
            return self.row[:k1].copy()
        P = np.linalg.matrix_power(self.Phi, k0)
        if not np.any(P):
            return np.zeros((k1 - k0, self.Phi.shape[0]))
        return self.row[: k1 - k0] @ P


def mode_free_blocks(modes, dt: float, k0: int, k1: int) -> np.ndarray:
    """(m, 2, c) of :func:`~._filtering.mode_free_responses` at rows [k0, k1)."""
    modes = np.asarray(modes, np.float64).reshape(-1, 2)
    w, z = modes[:, :1], modes[:, 1:]
    t = np.arange(k0, k1) * float(dt)
    wd = w * np.sqrt(np.maximum(1.0 - z * z, 0.0))
    env = np.exp(-z * w * t)
    return np.stack([env * np.cos(wd * t), env * np.sin(wd * t)], 1)


def input_map(F: np.ndarray, dt: float, tau: float, fmax: float, k0: int, k1: int) -> np.ndarray:
    """Rows [k0, k1) of u = sat_Fmax(F(t − τ)) (:func:`~._fit._apply_input`'s formula: τ/dt =
    n + φ, F_d[k] = (1 − φ)F[k − n] + φF[k − n − 1], F before the record = F[0]; F_max < 0
    the soft saturation)."""
    T = F.shape[0]
    s = tau / dt
    n = np.floor(s)
    phi = s - n
    k = np.arange(k0, k1)
    i0 = np.clip(k - int(n), 0, T - 1)
    i1 = np.clip(i0 - 1, 0, T - 1)
    Fd = (1 - phi) * F[i0] + phi * F[i1]
    m = abs(fmax)
    if fmax < 0:
        return m * np.tanh(Fd / (m if np.isfinite(m) else 1.0))
    return np.clip(Fd, -m, m)


class ColumnSource:
    """Columns (m, K, ·) of a profile (m points, K columns each) that a fit adds to a
    structure's design: whole (:meth:`full`, the in-memory path's numbers) or chunk by chunk
    (:meth:`blocks`, one (m, K, c) block per chunk of the streamed path)."""

    def shape(self, regs) -> tuple[int, int]:
        """(m, K)."""
        raise NotImplementedError

    def full(self, regs) -> np.ndarray:
        raise NotImplementedError

    def blocks(self, regs) -> Iterator[np.ndarray]:
        raise NotImplementedError


class HeldColumns(ColumnSource):
    """Columns given whole (m, K, T)."""

    def __init__(self, cols: np.ndarray):
        self.cols = np.asarray(cols, np.float64)

    def shape(self, regs) -> tuple[int, int]:
        return self.cols.shape[:2]

    def full(self, regs) -> np.ndarray:
        return self.cols

    def blocks(self, regs) -> Iterator[np.ndarray]:
        for k0, k1 in regs.spans:
            yield self.cols[:, :, k0:k1]


def as_source(cols) -> ColumnSource:
    return cols if isinstance(cols, ColumnSource) else HeldColumns(cols)


class FilteredColumns(ColumnSource):
    """Filtered raw signals, one output each, signed: ``signals`` [[(raw, foh, order, sign)
    × K] × m] (the raw signals computed per chunk). :meth:`full` filters them whole (the
    in-memory path's :func:`~._filtering.filter_columns`), :meth:`blocks` chunk by chunk."""

    def __init__(self, signals: Sequence[Sequence[tuple[Raw, float, int, float]]]):
        self.signals = [list(s) for s in signals]

    def _flat(self):
        return [s for point in self.signals for s in point]

    def shape(self, regs) -> tuple[int, int]:
        return len(self.signals), len(self.signals[0])

    def full(self, regs) -> np.ndarray:
        """Filtered whole, a filter batch at a time (only a batch's raw signals held)."""
        from ._filtering import S_BUCKETS, _buckets, edge_pad, filter_columns

        flat = self._flat()
        m, K = self.shape(regs)
        V = np.empty((len(flat), regs.T))
        per = _buckets(S_BUCKETS, regs.Tp)[-1]
        for i in range(0, len(flat), per):
            part = flat[i : i + per]
            U = np.stack([edge_pad(raw(0, regs.T), regs.Tp) for raw, _, _, _ in part])
            foh = np.array([f for _, f, _, _ in part])
            V[i : i + per] = filter_columns(regs.dsc, U, foh, [o for _, _, o, _ in part], regs.T)
        return V.reshape(m, K, regs.T) * np.array([s for *_, s in flat]).reshape(m, K, 1)

    def blocks(self, regs) -> Iterator[np.ndarray]:
        flat = self._flat()
        m, K = len(self.signals), len(self.signals[0])
        filt = Filters(
            regs.dsc, regs.T, regs.chunk, {i: (raw, foh) for i, (raw, foh, _, _) in enumerate(flat)}
        )
        orders = [o for _, _, o, _ in flat]
        signs = np.array([s for *_, s in flat])[:, None]
        for k0, k1 in regs.spans:
            out = filt.step(k0, k1)
            V = np.stack([out[i][orders[i]] for i in range(len(flat))]) * signs
            yield V.reshape(m, K, k1 - k0)


@jax.jit
def _systems_chunk(dsc: Discrete, u_at, u, du, z0):
    return jax.vmap(filter_from)(dsc, u_at, u, du, z0)


def mode_seed_streamed(x, F, dt: float, lam: float, chunk: int):
    """:func:`~._filtering.mode_seed` chunk by chunk: the Gram of its fit accumulated, solved
    on its scaled normal equations (the whole record's fit solves the scaled rows)."""
    x, F = np.asarray(x, np.float64), np.asarray(F, np.float64)
    T = x.size
    dsc = _seed_discretes(np.float64(lam), np.float64(dt))
    c_last = np.asarray(dsc.c_last)
    n0 = min(int(math.ceil(10.0 / (lam * dt))), T // 4)
    M = np.zeros((7, 7))
    z = None
    for k0, k1 in spans(T, chunk):
        c = k1 - k0
        parts = [held(rows(x), k0, k1, T, 1.0), held(rows(F), k0, k1, T, 0.0)]
        Ua, Uh, dU = (np.stack([_pad_rows(p[i], chunk) for p in parts]) for i in range(3))
        if z is None:
            z = np.zeros((2, 5))
            z[:, 0] = Uh[:, 0] / c_last
        V, z = _systems_chunk(dsc, Ua, Uh, dU, z)
        V, z = np.asarray(V, np.float64)[:, :c], np.asarray(z)
        lo = max(n0 - k0, 0)
        if lo < c:
            A, y = seed_design(V[0, lo:], V[1, lo:])
            B = np.concatenate([A, y[:, None]], 1)
            M += B.T @ B
    N = T - n0
    scale = np.maximum(np.sqrt(np.diag(M)[:6] / N), 1e-300)
    G = M[:6, :6] / np.outer(scale, scale)
    c = np.linalg.lstsq(G, M[:6, 6] / scale, rcond=None)[0] / scale
    return seed_mode(c)


@jax.jit
def _dahl_chunk(d, zs, zeta0):
    def step(zeta, dk):
        s = jnp.sign(dk)
        zeta = s + (zeta - s) * jnp.exp(-jnp.abs(dk) / zs)
        return zeta, zeta

    end, out = jax.lax.scan(step, zeta0, d)
    return out.T, end


def dahl_chunked(v, dt: float, zs, chunk: int) -> np.ndarray:
    """(m, T) :func:`~lionjax._model_effects.dahl_states` of v̂ at the distances ``zs``, chunk
    by chunk (the states carried; distances in batches of 1, 2, 4 or 8)."""
    v = np.asarray(v, np.float64)
    T, zs = v.size, np.asarray(zs, np.float64)
    out = np.empty((zs.size, T))
    for i in range(0, zs.size, 8):
        part = zs[i : i + 8]
        b = next(b for b in (1, 2, 4, 8) if b >= part.size)
        zp = np.concatenate([part, np.repeat(part[-1:], b - part.size)])
        zeta = np.zeros(b)
        for k0, k1 in spans(T, chunk):
            prev = v[k0 - 1 : k1 - 1] if k0 else np.concatenate([v[:1], v[: k1 - 1]])
            d = 0.5 * (v[k0:k1] + prev) * dt
            if k0 == 0:
                d[0] = 0.0
            Z, zeta = _dahl_chunk(_pad_rows(d, chunk), zp, zeta)
            out[i : i + part.size, k0:k1] = np.asarray(Z)[: part.size, : k1 - k0]
            zeta = np.asarray(zeta)
    return out


def zero_phase_streamed(dsc: Discrete, x: np.ndarray, dt: float, chunk: int = CHUNK):
    """:func:`~._filtering.zero_phase` of a long record chunk by chunk: V₁ of the record
    filtered forwards, then of that filtered backwards (both under the first-order hold of the
    hold-corrected samples, from steady states), then central differences (one-sided at the
    ends); (x smoothed, v̂) (T,) each."""
    T = x.size
    fwd = np.empty(T)
    f = Filters(dsc, T, chunk, {0: (rows(x), 1.0)})
    for k0, k1 in spans(T, chunk):
        fwd[k0:k1] = f.step(k0, k1)[0][0]
    rev = fwd[::-1]
    sm = np.empty(T)
    b = Filters(dsc, T, chunk, {0: (rows(rev), 1.0)})
    for k0, k1 in spans(T, chunk):
        sm[k0:k1] = b.step(k0, k1)[0][0]
    sm = sm[::-1].copy()
    g = np.empty(T)
    g[1:-1] = (sm[2:] - sm[:-2]) / (2 * dt)
    g[0] = (sm[1] - sm[0]) / dt
    g[-1] = (sm[-1] - sm[-2]) / dt
    return sm, g
