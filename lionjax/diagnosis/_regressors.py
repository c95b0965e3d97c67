"""ε₁ regressors of one record (:class:`Regressors`): the fits' statistics accumulated chunk by
chunk (:mod:`._streaming`). A record of one chunk keeps what it filtered (its signals' outputs,
its structures' designs): a short record is a long one in a single chunk, plus a cache."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numpy as np

from .._filters import FilterBank
from .._model_effects import LOCAL_F_MULTIPLIERS, MAX_POSITION_DEGREE, position_terms
from .._models import AbstractModel
from .._record import Record
from ._filtering import P_MAX, Discrete, _f, _mode_stages, mode_free_responses, padded_length
from ._streaming import (
    ColumnSource,
    Filters,
    FreeRows,
    ModeStages,
    chunk_length,
    rows,
    scaled,
    spans,
)


class TooWide(ValueError):
    """A structure with more columns (its own and the refitted initial-state ones) than
    :data:`P_MAX`: the default library's widest stack of three (a cubic a(x), b(x), asymmetric
    friction and a flexible mode) has 12 + 5."""


#: Modes whose stages one call computes: the smallest bucket that holds them (one compiled
#: program per bucket).
MODE_BUCKETS = (1, 2, 4)
#: Slots for F-dependent signals in one structure: the smallest bucket that holds them (one
#: compiled program per bucket; most structures have F alone, or F and ξF).
K_BUCKETS = (1, 2, 4)
K_MAX = K_BUCKETS[-1]


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


class _Plan(NamedTuple):
    """A structure's slots in the design (:meth:`Regressors.plan`)."""

    p: int  # its columns
    fdep: tuple[str, ...]  # the signals of its F-dependent columns, in slot order
    onehot: np.ndarray  # (K, P_MAX): the F-dependent columns' slots and signs


#: Cache keys held per structure (dropped with the signals they use).
_PER_STRUCTURE = ("plan", "gram", "design", "width")

#: (model, its columns, its key) by id(model): the fits ask a structure for its columns many
#: times (a profile grid, a plan, a design, a Gram), and building them costs ~0.5 ms (each
#: column an equinox Module). Holding the model keeps its id from being reused; bounded.
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
    """The structure's columns as (signal, order, sign) tuples: the cache key of its plan,
    design and Gram."""
    return _columns_and_key(model)[1]


@dataclasses.dataclass(frozen=True, eq=False)
class RecordSignals:
    """A record as the diagnosis' effects read it (their ``signals(rs)``): ``x`` [m] and ``F``
    [N] in float64, the zero-phase velocity ``v`` [m/s], ``dt`` and ``t0`` [s], the chunk the
    record is read in, and a ``memo`` of costly raw signals (Dahl's states) shared by the
    record's regressors."""

    record: Record
    x: np.ndarray
    F: np.ndarray
    v: np.ndarray
    chunk: int
    memo: dict = dataclasses.field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.record.dt)

    @property
    def t0(self) -> float:
        return float(self.record.t0)

    @property
    def n_samples(self) -> int:
        return int(self.x.size)


class Regressors:
    """ε₁ regressors of :class:`~lionjax.Augmented` structures on one record, built from the
    models' own :meth:`columns` and the signals of :meth:`signals`, every product the fits read
    (Grams, cross products with a profile's columns, a validation residual's refitted part)
    accumulated over chunks of ``chunk`` samples (default :func:`~._streaming.chunk_length`).

    The effects' raw signals come from their ``signals`` on the record as the diagnosis reads
    it (:class:`RecordSignals`: with its zero-phase velocity v̂, so that every friction column
    reads the same v̂).

    ``force_mask``: optional (T,) weights m ∈ {0, 1} of the forces: while the axis sticks
    (m = 0) static friction balances every force on it, ẍ + aẋ = 0 there, and each force
    column (order 0: the input u, an offset, a spring, friction) is built from m·(signal).

    The input u = sat_Fmax(F(t − τ)) replaces F in every F-dependent signal (``"F"`` and the
    position-dependent ``ξ·F``); those columns are built per input map
    (:class:`~._streaming.GridColumns`).

    A record of one chunk (:attr:`whole`) keeps its signals' filtered outputs by name and its
    structures' designs: the same numbers, computed once.
    """

    def __init__(
        self,
        rs: RecordSignals,
        bank: FilterBank,
        force_mask: np.ndarray | None = None,
        chunk: int | None = None,
        lam: float | None = None,
    ):
        self.rs, self.record, self.bank = rs, rs.record, bank
        self.force_mask = None if force_mask is None else np.asarray(force_mask, np.float64)
        self.T = rs.n_samples
        self.Tp = padded_length(self.T)
        self.dt = float(rs.dt)
        self.dsc = Discrete.of(bank, self.dt)
        self.x, self.F = rs.x, rs.F
        self.cache: dict = {}
        #: raw signals {name: (samples (T,) or a raw signal of rows, hold)}, from the effects'
        #: ``signals`` on :attr:`rs`, kept
        self.known: dict = {}
        #: signals whose columns are computed, not filtered: {name: (ω, ζ, "x" | "F")} of the
        #: flexible modes' exact columns (an effect's signal of hold ``"mode"``)
        self.derived: dict[str, tuple[float, float, str]] = {}
        self.lam = lam
        self.chunk = int(chunk or chunk_length(self.T))
        self.spans = spans(self.T, self.chunk)
        self.free = FreeRows(self.dsc, self.chunk)
        self.n_bank = int(np.asarray(self.dsc.Phi).shape[0])
        #: filtered outputs {name: (4, T)} of a record of one chunk (None: not kept)
        self.outputs: dict | None = {} if self.whole else None

    @property
    def whole(self) -> bool:
        """Whether the record is one chunk (then its filtered signals and designs are kept)."""
        return len(self.spans) == 1

    # ------------------------------------------------------------------ structures

    def drop(self, names) -> None:
        """Forget raw and filtered signals ``names`` and every cached plan, design and Gram
        that uses them (profiled columns: one structure per grid point would otherwise stay in
        memory)."""
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
        """The structure's columns and its initial-state columns (the filter's free response
        and each effect's own, a flexible mode's): the slots of the design it fills."""

        def make():
            extra = self._extra_free(model, 0, 1)
            return len(columns_of(model)) + self.n_bank + sum(np.shape(r)[1] for r in extra)

        return self._cached(("width", model_key(model)), make)

    def plan(self, model: AbstractModel) -> _Plan:
        """The structure's slots in the design (:class:`_Plan`; small, cached per structure):
        its column count and its F-dependent columns' signals, slots and signs."""

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
            for _, c in fdep:
                if c.order != 0:
                    raise ValueError(f"unsupported F-dependent column {c}")
            if len(fdep) > K_MAX:
                raise ValueError(f"unsupported F-dependent column {fdep[K_MAX][1]}")
            K = next(k for k in K_BUCKETS if k >= len(fdep))
            onehot = np.zeros((K, P_MAX))
            for kk, (j, c) in enumerate(fdep):
                onehot[kk, j] = c.sign
            return _Plan(p=p, fdep=tuple(c.signal for _, c in fdep), onehot=onehot)

        return self._cached(("plan", model_key(model)), make)

    def _raw(self, model: AbstractModel, names: Sequence[str]) -> dict:
        """Raw signals ``names``: kept, else the owning effect's ``signals`` on the record
        (:class:`RecordSignals`), then kept; a signal of hold ``"mode"`` (a flexible mode's
        column) is registered in :attr:`derived` instead. {name: (raw, hold)} of the others."""
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

    def _multiplier(self, model, signal: str):
        """g(x) of an F-dependent signal g(x)·F: from ``known``, else from the signals of the
        effect that owns it on a record with F = 1 (then kept in ``known``)."""
        name = f_multiplier(signal)
        if name not in self.known:
            ones = Record(self.record.x, np.ones(np.shape(self.record.x)), self.record.dt)
            owner = next(
                (e for e in model.effects if signal in {c.signal for c in e.columns()}),
                model,
            )
            g = owner.signals(ones)[signal][0]
            self.known[name] = g if callable(g) else np.asarray(g, np.float64)
        return self.known[name]

    def multiplier(self, model, signal: str):
        """g(x) of an F-dependent signal times the force mask, held (T,) or a raw signal; None
        for 1."""
        g = None if f_multiplier(signal) is None else self._multiplier(model, signal)
        if self.force_mask is not None:
            g = self.force_mask if g is None else scaled(self.force_mask, rows(g))
        return g

    def _extra_free(self, model, k0: int, k1: int) -> list[np.ndarray]:
        """Rows [k0, k1) of each effect's own initial-state columns (a mode's free response)."""
        out = []
        for e in model.effects:
            r = e.free_response(self.dt, k1, k0)
            if r is not None:
                out.append(np.asarray(r, np.float64))
        return out

    def nuisance_rows(self, model, k0: int, k1: int) -> np.ndarray:
        """Rows [k0, k1) of the structure's initial-state columns: the filter's free response
        from each unit state, then each effect's own."""
        extra = self._extra_free(model, k0, k1)
        N = self.free(k0, k1)
        return np.concatenate([N, *extra], 1) if extra else N

    # ------------------------------------------------------------------ passes over the record

    def mean_square(self, u, hold: str, order: int) -> float:
        """The mean over the record of the square of output ``order`` (V₁…V₄) of the raw
        signal ``u`` (T,) under ``hold``."""
        filt = Filters(self.dsc, self.T, self.chunk, {0: (rows(u), 1.0 if hold == "foh" else 0.0)})
        return (
            sum(float(np.sum(filt.step(k0, k1)[0][order] ** 2)) for k0, k1 in self.spans) / self.T
        )

    def design_pass(self, model, grid: bool = False) -> _DesignPass:
        return _DesignPass(self, model, grid)

    def design_blocks(self, model, grid: bool = False) -> Iterator[np.ndarray]:
        """[W | ε₁'s x column] (c, P_MAX + 1) of each chunk: W the design with u = F, or with
        ``grid`` its fixed columns only (the F-dependent slots 0, filled per input map); the
        unused slots 0. A record of one chunk keeps each structure's."""
        if self.whole:
            key = ("design", model_key(model), grid)
            if key not in self.cache:
                self.cache[key] = self.design_pass(model, grid).block(*self.spans[0])
            yield self.cache[key]
            return
        d = self.design_pass(model, grid)
        for k0, k1 in self.spans:
            yield d.block(k0, k1)

    def design_gram(self, model, *, grid: bool = False, n_free: int = 0) -> np.ndarray:
        """G = AᵀA of the design (P_MAX + 1)² plus a unit diagonal in the unused slots (the Gram
        of unit columns outside the record: the solver's system keeps one size, and the unused
        coefficients come out 0), except the ``n_free`` slots after the structure's columns,
        left 0 for :func:`~._lstsq.rss_with_columns` to fill. Cached per structure (it is small):
        the τ and F_max profiles and the flexible mode's (ω, ζ) profile reuse it."""

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

    def blocks(self, source: ColumnSource) -> Iterator[np.ndarray]:
        """The (m, K, c) blocks of a profile's columns, chunk by chunk (a record of one chunk:
        the source's one block, which the source may keep)."""
        if self.whole:
            yield source.full(self)
        else:
            yield from source.blocks(self)

    def cross(self, model, source: ColumnSource, grid: bool = False):
        """(C = VᵀA (m, K, P_MAX + 1), D = VᵀV (m, K, K)) of the structure's design A and the
        columns V of ``source``, accumulated over chunks."""
        C = D = None
        for A, V in zip(self.design_blocks(model, grid), self.blocks(source), strict=True):
            c, d = _cross_blocks(A, V)
            C, D = (c, d) if C is None else (C + c, D + d)
        return C, D

    def added_columns(self, model, base):
        """A :class:`~._streaming.ColumnSource` of the columns ``model`` adds to ``base``, for
        :func:`~._lstsq.rss_with_columns` on ``base``; None where it adds more than columns of
        its own signals (an F-dependent column, initial-state columns) or lacks one of
        ``base``'s."""
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


def _cross_blocks(A: np.ndarray, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(VᵀA (m, K, P + 1), VᵀV (m, K, K)) of a design A (T, P + 1) and columns V (m, K, T)."""
    m, K, T = V.shape
    # one product for the whole batch (A read once; a batched V @ A multiplies m thin blocks)
    C = (V.reshape(m * K, T) @ A).reshape(m, K, -1)  # (m, K, P + 1)
    D = V @ np.swapaxes(V, 1, 2)  # (m, K, K)
    return C, D


class DesignColumns(ColumnSource):
    """Columns ``js`` of a structure's design (u = F), one point (1, K, ·)."""

    def __init__(self, model, js):
        self.model, self.js = model, list(js)

    def shape(self, regs) -> tuple[int, int]:
        return 1, len(self.js)

    def full(self, regs: Regressors) -> np.ndarray:
        (A,) = regs.design_blocks(self.model)
        return A[:, self.js].T[None]

    def blocks(self, regs: Regressors) -> Iterator[np.ndarray]:
        for A in regs.design_blocks(self.model):
            yield A[:, self.js].T[None]


class _DesignPass:
    """A structure's design chunk by chunk (:meth:`Regressors.design_blocks`), its filters' and
    mode stages' states held between chunks; :meth:`state` and :meth:`restore` let a pass
    revisit chunks (the periodic screen reads them backwards)."""

    def __init__(self, regs: Regressors, model, grid: bool):
        self.regs, self.model, self.grid = regs, model, grid
        plan = regs.plan(model)
        self.plan = plan
        self.cols = columns_of(model)
        self.n = regs.width(model)
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
        modes = sorted({regs.derived[c.signal][:2] for c in self.cols if c.signal in regs.derived})
        self.modes = modes
        self.stages = None
        if modes:
            inputs.setdefault("F", (rows(regs.F), 0.0))
            self.stages = _mode_stages_of(modes, regs.lam, regs.dt, regs.chunk)
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
    """The flexible mode's columns for each mode (ω [rad/s], ζ) of ``modes``: −(s²/Λ)[h_x],
    (1/Λ)[h_F] and the mode's free response (2), (m, 4, ·), then the columns ``keep``: the
    mode's stages chunk by chunk (a record of one chunk: computed once for every ``keep``)."""

    def __init__(self, modes, lam: float, dt: float, keep=slice(None)):
        self.modes = np.asarray(modes, np.float64).reshape(-1, 2)
        self.lam, self.dt, self.keep = float(lam), float(dt), keep
        self._full: dict = {}

    def select(self, keep) -> ModeProfileColumns:
        """The same modes' columns ``keep`` (sharing what :meth:`full` computed)."""
        out = ModeProfileColumns(self.modes, self.lam, self.dt, keep)
        out._full = self._full
        return out

    def shape(self, regs) -> tuple[int, int]:
        return len(self.modes), len(np.arange(4)[self.keep])

    def full(self, regs: Regressors) -> np.ndarray:
        if id(regs) not in self._full:
            (blk,) = self._blocks(regs)
            self._full[id(regs)] = (regs, blk)
        return self._full[id(regs)][1][:, self.keep]

    def blocks(self, regs: Regressors) -> Iterator[np.ndarray]:
        for blk in self._blocks(regs):
            yield blk[:, self.keep]

    def _blocks(self, regs: Regressors) -> Iterator[np.ndarray]:
        filt = Filters(
            regs.dsc,
            regs.T,
            regs.chunk,
            {"x": (rows(regs.x), 1.0), "F": (rows(regs.F), 0.0)},
            regs.outputs,
        )
        top = MODE_BUCKETS[-1]
        stages = [
            (_mode_stages_of(self.modes[i : i + top], self.lam, regs.dt, regs.chunk), i)
            for i in range(0, len(self.modes), top)
        ]
        for k0, k1 in regs.spans:
            out = filt.step(k0, k1)
            cx, cF = [], []
            for ms, i in stages:
                a, b = ms.step(out["x"], out["F"], regs.x, regs.F, k0, k1)
                m = min(top, len(self.modes) - i)
                cx.append(a[:m])
                cF.append(b[:m])
            blk = np.empty((len(self.modes), 4, k1 - k0))
            blk[:, 0], blk[:, 1] = -np.concatenate(cx), np.concatenate(cF)
            blk[:, 2:] = mode_free_responses(self.modes, self.dt, k1, k0)
            yield blk


def _mode_stages_of(modes, lam: float, dt: float, chunk: int) -> ModeStages:
    """The stages of modes (ω, ζ) (m ≤ 4, 2), padded to a bucket of :data:`MODE_BUCKETS` by
    repeating the last (computed for four, one compiled program)."""
    modes = np.asarray(modes, np.float64).reshape(-1, 2)
    full = np.concatenate([modes, np.repeat(modes[-1:], MODE_BUCKETS[-1] - len(modes), 0)])
    b = next(b for b in MODE_BUCKETS if b >= len(modes))
    st = _mode_stages(full[:, 0], full[:, 1], _f(lam), _f(dt))
    return ModeStages(tuple(np.asarray(a)[:b] for a in st), full[:b, 1], float(lam), chunk)
