"""Regressors of a long record, streamed (:class:`Streamed`): the fits' statistics accumulated
chunk by chunk (:mod:`._streaming`), no filtered signal, design or profile column held whole."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from .._filters import FilterBank
from .._models import AbstractModel
from .._record import Record
from ._filtering import MODE_BUCKETS, P_MAX, _batches, _f, _mode_stages, mode_free_responses
from ._fit import Regressors, _columns, _model_key, f_dependent
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


class Streamed(Regressors):
    """:class:`~._fit.Regressors` of a record that is streamed: the same structures, Grams and
    fits, every product accumulated over chunks of ``chunk`` samples (default
    :func:`~._streaming.chunk_length`). What it holds grows with the record only by its raw
    per-sample signals (x, F, the effects' raw signals); every filtered column is computed in
    the chunk that reads it. The fits read it through :meth:`design_blocks` (the in-memory
    path's :meth:`~._fit.Regressors.design`, one chunk at a time) and the profile columns
    through :class:`~._streaming.ColumnSource`."""

    streamed = True

    def __init__(
        self,
        record: Record,
        bank: FilterBank,
        known: dict | None = None,
        force_mask: np.ndarray | None = None,
        chunk: int | None = None,
        lam: float | None = None,
    ):
        self._record(record, bank, force_mask)
        self.known = {} if known is None else known  # shared with the record's other regressors
        # signals whose columns are computed, not filtered: {name: (ω, ζ, "x" | "F")} of the
        # flexible modes' exact columns (:meth:`add_mode`)
        self.derived: dict[str, tuple[float, float, str]] = {}
        self.lam = lam
        self.chunk = int(chunk or chunk_length(self.T))
        self.spans = spans(self.T, self.chunk)
        self.free = FreeRows(self.dsc, self.chunk)
        self.n_bank = int(np.asarray(self.dsc.Phi).shape[0])

    # ------------------------------------------------------------------ what is not held

    def filtered(self, raw: dict) -> dict:
        raise TypeError("streamed regressors hold no filtered signal; read a pass's blocks")

    def design(self, model, *, grid: bool = False):
        raise TypeError("streamed regressors hold no design; read design_blocks()")

    def columns_padded(self, model, *, grid: bool = False):
        raise TypeError("streamed regressors hold no design; read design_blocks()")

    def nuisance(self, model: AbstractModel):
        raise TypeError("streamed regressors hold no nuisance columns; read nuisance_rows()")

    def width(self, model: AbstractModel) -> int:
        key = ("width", _model_key(model))
        if key not in self.cache:
            self.cache[key] = (
                len(_columns(model))
                + self.n_bank
                + sum(np.shape(r)[1] for r in self._extra_free(model, 0, 1))
            )
        return self.cache[key]

    def mean_square(self, u, hold: str, order: int) -> float:
        filt = Filters(self.dsc, self.T, self.chunk, {0: (rows(u), 1.0 if hold == "foh" else 0.0)})
        return (
            sum(float(np.sum(filt.step(k0, k1)[0][order] ** 2)) for k0, k1 in self.spans) / self.T
        )

    # ------------------------------------------------------------------ chunks

    def add_mode(self, modes, lam: float) -> list[str]:
        """Make the flexible-mode columns of ``modes`` (ω [rad/s], ζ) signals of this record
        (computed per chunk by the mode's stages, :func:`~._filtering.mode_cascade_from`);
        their names."""
        from ._mode import mode_signal_names

        self.lam = lam
        names = []
        for w, z in modes:
            nx, nF = mode_signal_names(w, z)
            self.derived[nx], self.derived[nF] = (w, z, "x"), (w, z, "F")
            names += [nx, nF]
        return names

    def drop(self, names) -> None:
        super().drop(names)
        for n in set(names):
            self.derived.pop(n, None)
        for k in [k for k in self.cache if isinstance(k, tuple) and k[0] == "width"]:
            if any(signal in set(names) for signal, _, _ in k[1]):
                del self.cache[k]

    def _extra_free(self, model, k0: int, k1: int) -> list[np.ndarray]:
        """Rows [k0, k1) of each effect's own initial-state columns (a mode's free response)."""
        from ._mode import ModeColumns

        out = []
        for e in getattr(model, "effects", ()):
            if isinstance(e, ModeColumns):
                out.append(mode_free_responses([(e.omega, e.zeta)], self.dt, k1, k0)[0].T)
            else:
                r = e.free_response(self.dt, k1)
                if r is not None:
                    out.append(np.asarray(r, np.float64)[k0:k1])
        return out

    def nuisance_rows(self, model, k0: int, k1: int) -> np.ndarray:
        """Rows [k0, k1) of the structure's initial-state columns (in-memory
        :meth:`~._fit.Regressors.nuisance`)."""
        extra = self._extra_free(model, k0, k1)
        N = self.free(k0, k1)
        return np.concatenate([N, *extra], 1) if extra else N

    def multiplier(self, model, signal: str):
        """g(x) of an F-dependent signal times the force mask, held (T,) or a raw signal; None
        for 1."""
        from ._fit import f_multiplier

        g = None if f_multiplier(signal) is None else self._multiplier(model, signal)
        if self.force_mask is not None:
            g = self.force_mask if g is None else scaled(self.force_mask, rows(g))
        return g

    def design_pass(self, model, grid: bool = False) -> _DesignPass:
        return _DesignPass(self, model, grid)

    def design_blocks(self, model, grid: bool = False) -> Iterator[np.ndarray]:
        """[W | ε₁'s x column] (c, P_MAX + 1) of each chunk: :meth:`~._fit.Regressors.design`
        chunk by chunk."""
        d = self.design_pass(model, grid)
        for k0, k1 in self.spans:
            yield d.block(k0, k1)

    def design_gram(self, model, *, grid: bool = False, n_free: int = 0, need_design=True):
        if need_design:
            raise TypeError("streamed regressors hold no design; read design_blocks()")

        def make():
            G = np.zeros((P_MAX + 1, P_MAX + 1))
            for A in self.design_blocks(model, grid):
                G += A.T @ A
            return G

        G = self._cached(("gram", _model_key(model), grid), make, small=True).copy()
        n = self.width(model)
        unused = np.arange(n, P_MAX)
        pads = unused[unused >= n + n_free]
        G[pads, pads] += 1.0
        return None, G

    def cross(self, model, source: ColumnSource, grid: bool = False):
        """(C = VᵀA (m, K, P_MAX + 1), D = VᵀV (m, K, K)) of the structure's design A and the
        columns V of ``source``, accumulated over chunks."""
        from ._fit import _cross_blocks

        C = D = None
        for A, V in zip(self.design_blocks(model, grid), source.blocks(self), strict=True):
            c, d = _cross_blocks(A, V)
            C, D = (c, d) if C is None else (C + c, D + d)
        return C, D

    def added_columns(self, model, base):
        """A :class:`~._streaming.ColumnSource` of the columns ``model`` adds to ``base`` (as
        :meth:`~._fit.Regressors.added_columns`), or None."""
        have = set(_model_key(base))
        keys = _model_key(model)
        js = [j for j, k in enumerate(keys) if k not in have]
        new = [_columns(model)[j] for j in js]
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

    def shape(self, regs) -> tuple[int, int]:
        return 1, len(self.js)

    def blocks(self, regs: Streamed) -> Iterator[np.ndarray]:
        for A in regs.design_blocks(self.model):
            yield A[:, self.js].T[None]


class _DesignPass:
    """A structure's design chunk by chunk (:meth:`Streamed.design_blocks`), its filters' and
    mode stages' states held between chunks; :meth:`state` and :meth:`restore` let a pass
    revisit chunks (the periodic screen reads them backwards)."""

    def __init__(self, regs: Streamed, model, grid: bool):
        self.regs, self.model, self.grid = regs, model, grid
        plan = regs.plan(model)
        self.plan = plan
        self.cols = _columns(model)
        self.n = regs.width(model)
        fixed = sorted(
            {c.signal for c in self.cols if not f_dependent(c.signal)} - set(regs.derived)
        )
        raw = regs._raw(model, [s for s in fixed if s != "x"])
        missing = [s for s, (u, _) in raw.items() if u is None]
        if missing:
            raise KeyError(f"no raw signal {missing[0]!r} for the streamed design")
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
                inputs[f"{s}·F"] = (u, 0.0)
                self.fdep.append((k, int(np.flatnonzero(plan.onehot[k])[0]), f"{s}·F"))
        modes = sorted({regs.derived[c.signal][:2] for c in self.cols if c.signal in regs.derived})
        self.modes = modes
        self.stages = None
        if modes:
            inputs.setdefault("F", (rows(regs.F), 0.0))
            (whole, _), *_ = _batches(np.asarray(modes, np.float64), MODE_BUCKETS[-1:])
            b = next(b for b in MODE_BUCKETS if b >= len(modes))
            st = _mode_stages(whole[:, 0], whole[:, 1], _f(regs.lam), _f(regs.dt))
            zeta = np.concatenate(
                [whole[: len(modes), 1], np.repeat(whole[-1:, 1], b - len(modes))]
            )
            stages = tuple(np.asarray(a)[:b] for a in st)
            self.stages = ModeStages(stages, zeta, float(regs.lam), regs.chunk)
        self.filters = Filters(regs.dsc, regs.T, regs.chunk, inputs)

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
    (1/Λ)[h_F] and the mode's free response (2), (m, 4, ·), then the columns ``keep``
    (:meth:`~._fitter._Fitter._profile_mode`). Whole: :func:`~._filtering.mode_columns` (held
    once for every ``keep``); streamed: the mode's stages chunk by chunk."""

    def __init__(self, modes, lam: float, dt: float, keep=slice(None), T_free: int = 0):
        self.modes = np.asarray(modes, np.float64).reshape(-1, 2)
        self.lam, self.dt, self.keep, self.T_free = float(lam), float(dt), keep, T_free
        self._full: dict = {}

    def select(self, keep) -> ModeProfileColumns:
        """The same modes' columns ``keep`` (sharing what :meth:`full` computed)."""
        out = ModeProfileColumns(self.modes, self.lam, self.dt, keep, self.T_free)
        out._full = self._full
        return out

    def shape(self, regs) -> tuple[int, int]:
        return len(self.modes), len(np.arange(4)[self.keep])

    def full(self, regs) -> np.ndarray:
        from ._filtering import mode_columns

        if id(regs) not in self._full:
            cx, cF = mode_columns(regs, self.modes, self.lam)
            free = mode_free_responses(self.modes, self.dt, max(self.T_free, regs.T))
            out = np.empty((len(self.modes), 4, regs.T))
            out[:, 0], out[:, 1] = -cx[:, : regs.T], cF[:, : regs.T]
            out[:, 2:] = free[:, :, : regs.T]
            self._full[id(regs)] = (regs, out)
        return self._full[id(regs)][1][:, self.keep]

    def blocks(self, regs: Streamed) -> Iterator[np.ndarray]:
        filt = Filters(
            regs.dsc, regs.T, regs.chunk, {"x": (rows(regs.x), 1.0), "F": (rows(regs.F), 0.0)}
        )
        stages = []
        for chunk, m in _batches(self.modes, MODE_BUCKETS):
            b = len(chunk)
            (whole, _), *_ = _batches(chunk, MODE_BUCKETS[-1:])
            st = _mode_stages(whole[:, 0], whole[:, 1], _f(self.lam), _f(regs.dt))
            st = tuple(np.asarray(a)[:b] for a in st)
            stages.append((ModeStages(st, chunk[:, 1], self.lam, regs.chunk), m))
        for k0, k1 in regs.spans:
            out = filt.step(k0, k1)
            cx, cF = [], []
            for ms, m in stages:
                a, b = ms.step(out["x"], out["F"], regs.x, regs.F, k0, k1)
                cx.append(a[:m])
                cF.append(b[:m])
            blk = np.empty((len(self.modes), 4, k1 - k0))
            blk[:, 0], blk[:, 1] = -np.concatenate(cx), np.concatenate(cF)
            blk[:, 2:] = mode_free_responses(self.modes, self.dt, k1, k0)
            yield blk[:, self.keep]
