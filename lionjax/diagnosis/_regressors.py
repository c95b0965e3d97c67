"""ε₁ regressors of one record (:class:`Regressors`): the fits' statistics accumulated chunk by
chunk (:mod:`._streaming`). A short record is a long one in a single chunk, plus a cache."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numpy as np

from .._filters import FilterBank
from .._model_effects import LOCAL_F_MULTIPLIERS, MAX_POSITION_DEGREE, position_terms
from .._models import AbstractModel
from .._record import Record
from ._filtering import P_MAX, Discrete, mode_free_responses
from ._streaming import (
    ColumnSource,
    Filters,
    FreeRows,
    ModeStages,
    chunk_length,
    filtered,
    rows,
    scaled,
    spans,
)


class TooWide(ValueError):
    """A structure with more columns (its own and its initial-state ones) than :data:`P_MAX`
    (the default library's widest stack of three has 12 + 5)."""


#: Slots for a structure's F-dependent signals (most have F alone, or F and ξF): the smallest
#: bucket that holds them, one program per bucket.
K_BUCKETS = (1, 2, 4)

#: Signals (a function of x) × F, in which the input map u replaces F: {name: the multiplier's
#: raw signal (None for F itself)}.
F_DEP = {"F": None} | {
    f: m for f, m in (position_terms(k)[1:] for k in range(1, MAX_POSITION_DEGREE + 1))
}


def f_dependent(signal: str) -> bool:
    """Whether ``signal`` is (a function of x) × F (:data:`F_DEP`, or a localized position's)."""
    return signal in F_DEP or signal.startswith(tuple(LOCAL_F_MULTIPLIERS))


def f_multiplier(signal: str) -> str | None:
    """The raw signal of an F-dependent signal's multiplier (None for F itself)."""
    if signal in F_DEP:
        return F_DEP[signal]
    pre = next(p for p in LOCAL_F_MULTIPLIERS if signal.startswith(p))
    return LOCAL_F_MULTIPLIERS[pre] + signal[len(pre) :]


class _Plan(NamedTuple):
    """A structure's slots in the design (:meth:`Regressors.plan`)."""

    p: int  # its columns
    fdep: tuple[str, ...]  # the signals of its F-dependent columns, in slot order
    onehot: np.ndarray  # (K, P_MAX): the F-dependent columns' slots and signs


#: Cache keys held per structure (dropped with the signals they use).
_PER_STRUCTURE = ("plan", "gram", "design", "width")

#: (model, its columns, its key) by id(model): the fits ask a structure for its columns many
#: times, at ~0.5 ms each (equinox Modules). Holding the model keeps its id from being reused.
_COLUMNS: dict[int, tuple] = {}


def _columns_and_key(model) -> tuple[tuple, tuple]:
    hit = _COLUMNS.get(id(model))
    if hit is None or hit[0] is not model:
        cols = tuple(model.columns())
        if len(_COLUMNS) >= 4096:
            _COLUMNS.clear()
        hit = _COLUMNS[id(model)] = (model, cols, tuple((c.signal, c.order, c.sign) for c in cols))
    return hit[1], hit[2]


def columns_of(model) -> tuple:
    """``model.columns()``, once per model object."""
    return _columns_and_key(model)[0]


def model_key(model) -> tuple:
    """The structure's columns as (signal, order, sign): the key of its cached plan and Gram."""
    return _columns_and_key(model)[1]


@dataclasses.dataclass(frozen=True, eq=False)
class RecordSignals:
    """A record as the effects' ``signals(rs)`` read it: ``x`` [m], ``F`` [N] in float64, the
    zero-phase velocity ``v`` [m/s] (every friction column reads the same v̂), the chunk it is
    read in, a ``memo`` of costly raw signals (Dahl's states) its regressors share, and its
    ``role`` ("train", where the parameters are fitted, or "valid"; "" for another record)."""

    record: Record
    x: np.ndarray
    F: np.ndarray
    v: np.ndarray
    chunk: int
    memo: dict = dataclasses.field(default_factory=dict)
    role: str = ""

    @property
    def dt(self) -> float:
        return float(self.record.dt)

    @property
    def n_samples(self) -> int:
        return int(self.x.size)


class Regressors:
    """ε₁ regressors of :class:`~lionjax.Augmented` structures on one record, from the models'
    :meth:`columns` and their effects' ``signals`` on :class:`RecordSignals`; every product the
    fits read accumulated over chunks of ``chunk`` samples. A record of one chunk
    (:attr:`whole`) keeps its filtered signals by name and its structures' designs.

    ``force_mask``: optional (T,) weights m ∈ {0, 1}: while the axis sticks (m = 0) static
    friction balances every force on it, ẍ + aẋ = 0 there, and each force column (order 0: the
    input, an offset, a spring, friction) is built from m·(signal). The input map
    u = sat_Fmax(F(t − τ)) replaces F in every F-dependent signal (F, ξ·F), whose columns are
    built per input map (:func:`~._streaming.grid_columns`).
    """

    def __init__(self, rs: RecordSignals, bank: FilterBank, force_mask=None, chunk=None, lam=None):
        self.rs, self.record, self.lam = rs, rs.record, lam
        self.force_mask = None if force_mask is None else np.asarray(force_mask, np.float64)
        self.T = rs.n_samples
        self.dt = float(rs.dt)
        self.dsc = Discrete.of(bank, self.dt)
        self.x, self.F = rs.x, rs.F
        self.cache: dict = {}
        #: raw signals {name: (samples (T,) or a raw signal, hold)}, kept
        self.known: dict = {}
        #: signals whose columns are computed, not filtered: {name: (ω, ζ, "x" | "F")} of the
        #: flexible modes' columns (an effect's signal of hold ``"mode"``)
        self.derived: dict[str, tuple[float, float, str]] = {}
        self.chunk = int(chunk or chunk_length(self.T))
        self.spans = spans(self.T, self.chunk)
        self.free = FreeRows(self.dsc, self.chunk)
        #: filtered outputs {name: (4, T)} of a record of one chunk (None: not kept)
        self.outputs: dict | None = {} if self.whole else None

    @property
    def whole(self) -> bool:
        return len(self.spans) == 1

    def drop(self, names) -> None:
        """Forget signals ``names`` and every cached plan, design and Gram that uses them (a
        profile's grid point's, which would otherwise stay in memory)."""
        names = set(names)
        for n in names:
            self.known.pop(n, None)
            self.derived.pop(n, None)
            if self.outputs is not None:
                for k in (n, f"{n}|stick", f"{n}·F"):
                    self.outputs.pop(k, None)
        for k in [k for k in self.cache if isinstance(k, tuple) and k[0] in _PER_STRUCTURE]:
            if any(signal in names for signal, _, _ in k[1]):
                del self.cache[k]

    def _cached(self, key, make):
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]

    def width(self, model: AbstractModel) -> int:
        """The design slots the structure fills: its columns and its initial-state columns (the
        filter's free response and each effect's own, a flexible mode's)."""

        def make():
            return len(columns_of(model)) + self.nuisance_rows(model, 0, 1).shape[1]

        return self._cached(("width", model_key(model)), make)

    def plan(self, model: AbstractModel) -> _Plan:
        """The structure's slots in the design (:class:`_Plan`), cached per structure."""

        def make():
            cols = columns_of(model)
            p = len(cols)
            n_nuis = self.width(model) - p
            if p + n_nuis > P_MAX:
                raise TooWide(
                    f"structure with {p} columns and {n_nuis} initial-state columns exceeds "
                    f"P_MAX = {P_MAX}"
                )
            fdep = [(j, c) for j, c in enumerate(cols) if f_dependent(c.signal)]
            if len(fdep) > K_BUCKETS[-1] or any(c.order != 0 for _, c in fdep):
                raise ValueError(f"unsupported F-dependent columns {[c for _, c in fdep]}")
            K = next(k for k in K_BUCKETS if k >= len(fdep))
            onehot = np.zeros((K, P_MAX))
            for kk, (j, c) in enumerate(fdep):
                onehot[kk, j] = c.sign
            return _Plan(p=p, fdep=tuple(c.signal for _, c in fdep), onehot=onehot)

        return self._cached(("plan", model_key(model)), make)

    def _raw(self, model: AbstractModel, names: Sequence[str]) -> dict:
        """{name: (raw, hold)} of signals ``names``: kept, else the owning effect's ``signals``
        on the record, then kept; a signal of hold ``"mode"`` goes to :attr:`derived` instead."""
        missing = {n for n in names if n not in self.known and n not in self.derived}
        for e in model.effects:
            own = {c.signal for c in e.columns()} & missing
            if own:
                sig = e.signals(self.rs)
                for n in own:
                    u, hold = sig[n]
                    if hold == "mode":
                        self.derived[n] = u
                    else:
                        self.known[n] = (u if callable(u) else np.asarray(u, np.float64), hold)
        return {n: self.known.get(n, (None, None)) for n in names if n not in self.derived}

    def multiplier(self, model, signal: str):
        """g(x) of an F-dependent signal g(x)·F times the force mask, held (T,) or raw; None for
        1. g is kept, else the owning effect's signal on a record with F = 1."""
        name, g = f_multiplier(signal), None
        if name is not None and name not in self.known:
            ones = Record(self.record.x, np.ones(np.shape(self.record.x)), self.record.dt)
            owner = next(
                (e for e in model.effects if signal in {c.signal for c in e.columns()}),
                model,
            )
            g = owner.signals(ones)[signal][0]
            self.known[name] = g if callable(g) else np.asarray(g, np.float64)
        if name is not None:
            g = self.known[name]
        if self.force_mask is not None:
            g = self.force_mask if g is None else scaled(self.force_mask, rows(g))
        return g

    def nuisance_rows(self, model, k0: int, k1: int) -> np.ndarray:
        """Rows [k0, k1) of the structure's initial-state columns: the filter's free response
        from each unit state, then each effect's own (a flexible mode's)."""
        own = (e.free_response(self.dt, k1, k0) for e in model.effects)
        return np.concatenate([self.free(k0, k1), *(r for r in own if r is not None)], 1)

    def mean_square(self, u, hold: str, order: int) -> float:
        """The mean square of output ``order`` (V₁…V₄) of ``u`` (T,) under ``hold``."""
        V = filtered(self.dsc, u, 1.0 if hold == "foh" else 0.0, self.chunk, (order,))[0]
        return float(np.sum(V**2)) / self.T

    def design_blocks(self, model, grid: bool = False) -> Iterator[np.ndarray]:
        """[W | ε₁'s x column] (c, P_MAX + 1) of each chunk, the unused slots 0: W the design
        with u = F, or with ``grid`` its fixed columns only (the F-dependent slots 0)."""
        if self.whole:
            key = ("design", model_key(model), grid)
            yield self._cached(key, lambda: DesignPass(self, model, grid).block(*self.spans[0]))
            return
        d = DesignPass(self, model, grid)
        for k0, k1 in self.spans:
            yield d.block(k0, k1)

    def design_gram(self, model, *, grid: bool = False, n_free: int = 0) -> np.ndarray:
        """G = AᵀA (P_MAX + 1)² of the design plus a unit diagonal in the unused slots (unit
        columns outside the record: one system size, the unused coefficients 0), except the
        ``n_free`` slots after the structure's, left 0 for :func:`~._lstsq.rss_with_columns`.
        Cached per structure: the profiles reuse it."""

        def make():
            G = np.zeros((P_MAX + 1, P_MAX + 1))
            for A in self.design_blocks(model, grid):
                G += A.T @ A
            return G

        G = self._cached(("gram", model_key(model), grid), make).copy()
        n = self.width(model)
        unused = np.arange(n, P_MAX)
        pads = unused[unused >= n + n_free]
        G[pads, pads] += 1.0
        return G

    def cross(self, model, source: ColumnSource, grid: bool = False):
        """(C = VᵀA (m, K, P_MAX + 1), D = VᵀV (m, K, K)) of the structure's design A and the
        columns V of ``source``, accumulated over chunks."""
        C = D = None
        for A, V in zip(self.design_blocks(model, grid), source.blocks(self), strict=True):
            m, K, T = V.shape
            # one product for the batch (A read once; a batched V @ A multiplies m thin blocks)
            c = (V.reshape(m * K, T) @ A).reshape(m, K, -1)
            d = V @ np.swapaxes(V, 1, 2)
            C, D = (c, d) if C is None else (C + c, D + d)
        return C, D

    def added_columns(self, model, base):
        """The columns ``model`` adds to ``base`` (a :class:`DesignColumns`), or None where it
        adds more than columns of its own signals or lacks one of ``base``'s."""
        have = set(model_key(base))
        keys = model_key(model)
        js = [j for j, k in enumerate(keys) if k not in have]
        new = [columns_of(model)[j] for j in js]
        if (
            len(keys) - len(new) != len(have)
            or any(f_dependent(c.signal) for c in new)
            or self.width(model) - len(keys) != self.width(base) - len(have)
        ):
            return None
        return DesignColumns(model, js)


class DesignColumns(ColumnSource):
    """Columns ``js`` of a structure's design (u = F), one point (1, K, ·)."""

    def __init__(self, model, js):
        self.model, self.js = model, list(js)

    def blocks(self, regs: Regressors) -> Iterator[np.ndarray]:
        for A in regs.design_blocks(self.model):
            yield A[:, self.js].T[None]


class DesignPass:
    """A structure's design chunk by chunk, its filters' and mode stages' states carried;
    :meth:`state` and :meth:`restore` let a pass revisit chunks."""

    def __init__(self, regs: Regressors, model, grid: bool):
        self.regs, self.model = regs, model
        self.plan = plan = regs.plan(model)
        self.cols, self.n = columns_of(model), regs.width(model)
        fixed = sorted({c.signal for c in self.cols if not f_dependent(c.signal)} - {"x"})
        raw = regs._raw(model, fixed)
        missing = [s for s, (u, _) in raw.items() if u is None]
        if missing:
            raise KeyError(f"no raw signal {missing[0]!r} for the design")
        raw["x"] = (regs.x, "foh")
        inputs = {nm: (rows(u), 1.0 if h == "foh" else 0.0) for nm, (u, h) in raw.items()}
        m = regs.force_mask
        self.masked = set()
        if m is not None:
            self.masked = {c.signal for c in self.cols if c.order == 0 and c.signal in raw}
            for nm in self.masked:
                inputs[f"{nm}|stick"] = (scaled(m, inputs[nm][0]), inputs[nm][1])
        self.fdep = []
        if plan.fdep and not grid:
            for k, s in enumerate(plan.fdep):
                g = regs.multiplier(model, s)
                u = rows(regs.F) if g is None else scaled(g, rows(regs.F))
                nm = f"{s}·F"
                inputs[nm] = (u, 0.0)
                self.fdep.append((k, int(np.flatnonzero(plan.onehot[k])[0]), nm))
        self.modes = modes = sorted(
            {regs.derived[c.signal][:2] for c in self.cols if c.signal in regs.derived}
        )
        self.stages = None
        if modes:
            inputs.setdefault("F", (rows(regs.F), 0.0))
            self.stages = ModeStages(modes, regs.lam, regs.dt, regs.chunk)
        self.filters = Filters(regs.dsc, regs.T, regs.chunk, inputs, regs.outputs)

    def state(self):
        return (self.filters.z, None if self.stages is None else self.stages.p)

    def restore(self, state) -> None:
        self.filters.z = state[0]
        if self.stages is not None:
            self.stages.p = state[1]

    def block(self, k0: int, k1: int) -> np.ndarray:
        regs, plan = self.regs, self.plan
        out = self.filters.step(k0, k1)
        mode_cols = {}
        if self.stages is not None:
            cx, cF = self.stages.step(out["x"], out["F"], regs.x, regs.F, k0, k1)
            for i, (w, z) in enumerate(self.modes):
                mode_cols[(w, z, "x")], mode_cols[(w, z, "F")] = cx[i], cF[i]
        At = np.zeros((P_MAX + 1, k1 - k0))  # filled by rows: A = Atᵀ (column-major)
        for j, c in enumerate(self.cols):
            if f_dependent(c.signal):
                continue
            if c.signal in regs.derived:
                # the mode's columns read x's order 2 and F's order 0 (ModeColumns.columns)
                At[j] = c.sign * mode_cols[regs.derived[c.signal]]
                continue
            nm = f"{c.signal}|stick" if c.order == 0 and c.signal in self.masked else c.signal
            At[j] = c.sign * out[nm][c.order]
        for k, j, nm in self.fdep:
            At[j] = plan.onehot[k, j] * out[nm][0]
        At[plan.p : self.n] = regs.nuisance_rows(self.model, k0, k1).T
        At[P_MAX] = out["x"][2]
        return At.T


class ModeProfileColumns(ColumnSource):
    """A flexible mode's columns −(s²/Λ)[h_x], (1/Λ)[h_F] and its free response (2) for each
    mode (ω [rad/s], ζ) of ``modes``, (m, 4, ·), its columns ``keep`` taken (a record of one
    chunk: computed once for every ``keep``). ``rows``: the longest record of one chunk it will
    see, whose free responses serve every such record (0: each record's own length)."""

    def __init__(self, modes, lam: float, dt: float, keep=slice(None), rows: int = 0):
        self.modes = np.asarray(modes, np.float64).reshape(-1, 2)
        self.lam, self.dt, self.keep, self.rows = float(lam), float(dt), keep, rows
        self._full: dict = {}

    def select(self, keep) -> ModeProfileColumns:
        """The same modes' columns ``keep`` (sharing a record of one chunk's block)."""
        out = ModeProfileColumns(self.modes, self.lam, self.dt, keep, self.rows)
        out._full = self._full
        return out

    def blocks(self, regs: Regressors) -> Iterator[np.ndarray]:
        if not regs.whole:
            for blk in self._blocks(regs):
                yield blk[:, self.keep]
            return
        if id(regs) not in self._full:
            self._full[id(regs)] = (regs, next(self._blocks(regs)))
        yield self._full[id(regs)][1][:, self.keep]

    def _blocks(self, regs: Regressors) -> Iterator[np.ndarray]:
        xF = {"x": (rows(regs.x), 1.0), "F": (rows(regs.F), 0.0)}
        filt = Filters(regs.dsc, regs.T, regs.chunk, xF, regs.outputs)
        key = ("stages", float(regs.dt), regs.chunk)  # the same sampled stages for both records
        stages = ModeStages(self.modes, self.lam, regs.dt, regs.chunk, self._full.get(key))
        self._full[key] = stages.groups
        for k0, k1 in regs.spans:
            out = filt.step(k0, k1)
            cx, cF = stages.step(out["x"], out["F"], regs.x, regs.F, k0, k1)
            blk = np.empty((len(self.modes), 4, k1 - k0))
            blk[:, 0], blk[:, 1] = -cx, cF
            if regs.whole:
                blk[:, 2:] = self._free(k1)
            else:
                blk[:, 2:] = mode_free_responses(self.modes, self.dt, k1, k0)
            yield blk

    def _free(self, T: int) -> np.ndarray:
        """The free responses of a record of one chunk, T rows: the first rows of those of
        ``rows`` rows (each row depends on its time alone), computed once for both records."""
        kept = self._full.get("free")
        if kept is None or kept.shape[-1] < T:
            kept = self._full["free"] = mode_free_responses(self.modes, self.dt, max(T, self.rows))
        return kept[..., :T]
