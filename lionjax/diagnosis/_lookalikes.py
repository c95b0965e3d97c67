"""The out-of-library look-alikes a named stack must beat (:class:`LookAlikes`, mixed into
the fitter): a dead zone's input, a force quadratic in the velocity and a force periodic in
position (cogging)."""

from __future__ import annotations

import math

import numpy as np

from .._models import Augmented, MassDamper
from ._candidates import ForceClip, VelocityDrag
from ._filtering import edge_pad, filter_columns
from ._fit import (
    Regressors,
    TooWide,
    fit_batch,
    residual,
    rss_fixed_with_columns,
    rss_with_columns,
    solve_grams,
)
from ._settings import (
    DEAD_ZONE_QUANTILES,
    PERIOD_BINS,
    PERIOD_CYCLES,
    PERIOD_OVER_NOISE,
    PERIOD_OVERSAMPLE,
    PERIOD_PEAKS,
)
from ._statistics import _position_noise
from ._streaming import FilteredColumns, Filters
from ._structures import _effects_of


def _sinusoid(regs: Regressors, x_lo: float, R: float, k: float, f):
    """The raw signal m·f(2πκξ), ξ = (x − x_lo)/R (m the force mask), per rows."""
    x, m = regs.x, regs.force_mask

    def raw(k0, k1):
        v = f(2 * math.pi * k * ((x[k0:k1] - x_lo) / R))
        return v if m is None else m[k0:k1] * v

    return raw


def _adjoint_histograms(regs: Regressors, model, c, n: int, m, bins, nb: int) -> np.ndarray:
    """(n + 2, nb) position histograms (``bins`` of each sample) of Λ*[g]·m for g the
    structure's training residual r = Wc + y and each of its n columns, then of m itself:
    Λ* the filter's adjoint (the causal filter run on the time-reversed signal, reversed back).
    Streamed regressors visit the chunks backwards, each chunk's design recomputed from the
    filter states a forward pass left at its start."""
    T = regs.T
    if not regs.streamed:
        A = regs.design(model)
        W = A[:T, :n]
        r = W @ c[:n] + A[:T, -1]
        U = np.concatenate([r[:, None], W], 1)[::-1].T
        back = filter_columns(
            regs.dsc,
            np.stack([edge_pad(u, regs.Tp) for u in U]),
            np.zeros(U.shape[0]),
            np.zeros(U.shape[0], np.int64),
            T,
        )[:, ::-1]
        return np.stack([np.bincount(bins, weights=g * m, minlength=nb) for g in [*back, m]])
    d = regs.design_pass(model)
    states = []
    for k0, k1 in regs.spans:  # the filters' states at each chunk's start
        states.append(d.state())
        d.block(k0, k1)
    back = Filters(regs.dsc, T, regs.chunk, {i: (None, 0.0) for i in range(n + 1)})
    H = np.zeros((n + 2, nb))
    for (k0, k1), st in reversed(list(zip(regs.spans, states, strict=True))):
        d.restore(st)
        A = d.block(k0, k1)
        W = A[:, :n]
        U = np.concatenate([(W @ c[:n] + A[:, -1])[:, None], W], 1)[::-1].T
        g = back.step_values(U, last=k0 == 0)[:, 0, ::-1]
        for i in range(n + 1):
            H[i] += np.bincount(bins[k0:k1], weights=g[i] * m[k0:k1], minlength=nb)
    H[-1] = np.bincount(bins, weights=m, minlength=nb)
    return H


class LookAlikes:
    """The look-alikes of :class:`~._fitter._Fitter` (its records, regressors, structures and
    variant; ``_lookalike`` caches each once per structure and variant)."""

    def dead_zone_lookalike(self, cands, inp=(0.0, math.inf)) -> float:
        """Validated mean square of ε₁ of the structure ``cands`` (input map ``inp`` = (τ,
        F_max)) with a dead zone's input u = F − clip(F, ±d) in place of F (column
        −(1/Λ)[clip(F, ±d)], its coefficient free; d profiled on the training RSS over
        :data:`DEAD_ZONE_QUANTILES` of |F|): an out-of-library look-alike of friction. Friction
        acts with the sign of the velocity, a dead zone with the sign of the force; friction
        that this explains better describes the input, not friction."""
        # (the baseline structure does not depend on the profiled variant)
        key = (tuple(c.name for c in cands), self.variant if cands else None, tuple(inp))
        if key not in self._lookalike:
            Fa = np.abs(np.asarray(self.train.F, np.float64))
            ds = np.unique(np.quantile(Fa, np.asarray(DEAD_ZONE_QUANTILES)))
            rtr, rva = self._regs(cands)
            effects = _effects_of(cands, self._context())
            best = (math.inf, math.inf)
            for d in ds[ds > 0]:
                clip = ForceClip(float(d))
                model = Augmented(MassDamper(), (*effects, clip))
                try:
                    th, rss, _, _ = fit_batch(rtr, model, [inp])
                    if float(rss[0]) < best[0]:
                        r = residual(rva, model, th[0], inp)
                        best = (float(rss[0]), float(np.mean(r**2)))
                except TooWide:
                    pass
                for regs in (rtr, rva):  # one structure per width: not kept
                    regs.drop([clip.signal])
            self._lookalike[key] = best[1]
        return self._lookalike[key]

    def drag_lookalike(self) -> float:
        """Validated mean square of ε₁ of the baseline with a force quadratic in the velocity
        (:class:`~._candidates.VelocityDrag`, its coefficient free): an out-of-library
        look-alike of the input maps and of friction."""
        key = ("drag",)
        if key not in self._lookalike:
            model = Augmented(MassDamper(), (VelocityDrag(),))
            th, _, _, _ = fit_batch(self.rtr, model, [(0.0, math.inf)])
            r = residual(self.rva, model, th[0], (0.0, math.inf))
            self._lookalike[key] = float(np.mean(r**2))
        return self._lookalike[key]

    def periodic_lookalike(self, cands) -> tuple[float, float]:
        """(validated mean square of ε₁, period p [m]) of the structure ``cands`` (u = F) with a
        force periodic in position, A·sin(2πx/p + φ) — columns (1/Λ)[sin 2πκξ], (1/Λ)[cos
        2πκξ], ξ = (x − x_lo)/R over the range R of both records' positions, κ = R/p cycles —
        an out-of-library look-alike (cogging: a force that repeats with the magnet pitch).

        κ is found on the *training* record in two stages. A screen: the correlation of the
        structure's training residual r with each pair of columns is ⟨Λ*[r], e^{2πiκξ}⟩ (Λ* the
        filter's adjoint, run backwards in time once), which the position histogram of Λ*[r]
        gives for every κ at once by one FFT (:data:`PERIOD_BINS` bins, κ in steps of
        1/:data:`PERIOD_OVERSAMPLE`), over :data:`PERIOD_CYCLES` and periods above
        :data:`PERIOD_OVER_NOISE` times the position noise; its :data:`PERIOD_PEAKS` highest
        peaks (and their neighbours 1/16 cycle off) are fitted with the structure (training
        RSS), then 9 points 1/64 cycle apart around the best. Only the chosen κ is
        fitted on train and scored on validation, so a sinusoid fitted to the training record's
        noise is not counted. ``(inf, nan)`` when there is no period to search."""
        key = ("periodic", tuple(c.name for c in cands), self.variant if cands else None)
        if key in self._lookalike:
            return self._lookalike[key]
        rtr, rva = self._regs(cands)
        model = self._model(cands)
        x_lo = min(float(np.min(self.train.x)), float(np.min(self.valid.x)))
        R = max(float(np.max(self.train.x)), float(np.max(self.valid.x))) - x_lo
        sx = _position_noise(np.asarray(self.valid.x))
        k_hi = min(PERIOD_CYCLES[1], R / max(PERIOD_OVER_NOISE * sx, 1e-300))
        out = (math.inf, math.nan)
        if k_hi > PERIOD_CYCLES[0]:

            def columns(regs: Regressors, ks) -> FilteredColumns:
                # (m, 2, T) filtered sine and cosine of each κ (not kept in the cache; built a
                # filter batch or a chunk at a time); forces held at 0 where the structure's
                # force columns are masked
                return FilteredColumns(
                    [
                        [
                            (_sinusoid(regs, x_lo, R, float(k), f), 1.0, 0, 1.0)
                            for f in (np.sin, np.cos)
                        ]
                        for k in ks
                    ]
                )

            # each peak and its neighbours 1/16 cycle off, then 9 points 1/64 cycle apart
            # around the best: two batched fits (a call costs more than its columns here)
            peaks = self._period_screen(rtr, model, x_lo, R, k_hi)
            try:
                if peaks.size:  # (none where every force is masked)
                    ks = (peaks[:, None] + np.array([-1.0, 0.0, 1.0]) / 16).ravel()
                    k0 = ks[int(np.argmin(rss_with_columns(rtr, model, columns(rtr, ks))))]
                    ks = k0 + np.arange(-4, 5) / 64
                    coef, rss, _ = rss_with_columns(rtr, model, columns(rtr, ks), coef=True)
                    i = int(np.argmin(rss))
                    r = rss_fixed_with_columns(
                        rva, model, columns(rva, ks[i : i + 1]), coef[i : i + 1], 2
                    )
                    out = (float(r[0]) / self.valid.n_samples, R / float(ks[i]))
            except TooWide:
                pass
        self._lookalike[key] = out
        return out

    def _period_screen(self, regs: Regressors, model, x_lo: float, R: float, k_hi: float):
        """The :data:`PERIOD_PEAKS` cycle counts κ (of :meth:`periodic_lookalike`) whose
        columns C = Λ[m·(cos, sin)(2πκξ)] (m the force mask) would reduce the training RSS of
        the structure W the most, estimated for every κ at once: the reduction is
        bᵀ(C⊥ᵀC⊥)⁻¹b, b = Cᵀr (r the structure's residual, ⊥ W) and C⊥ᵀC⊥ = CᵀC −
        CᵀW(WᵀW)⁻¹WᵀC. Every inner product with a filtered column is one with the raw sinusoid
        of the filter's adjoint (Λ run backwards in time) of r and of W's columns, which the
        position histogram of those gives for every κ by one FFT each; CᵀC is taken as the
        unfiltered sinusoids' Gram (from the mask's histogram at 2κ) times the filter's mean
        loss Σₜm²|Λ(jκ·2π|v̂ₜ|/R)|²/Σₜm² (the sinusoid's frequency at speed v̂ is κ|v̂|/R;
        within a few % of the exact diagonal on moving records). The estimate only ranks κ:
        the chosen ones are fitted exactly. Empty where every force is masked."""
        T = regs.T
        n = regs.width(model)
        m = np.ones(T) if regs.force_mask is None else regs.force_mask[:T]
        h0 = float(np.sum(m * m))
        if h0 <= 0:
            return np.zeros(0)
        _, G = regs.design_gram(model, need_design=False)
        c = solve_grams(G[None], T)[0][0]
        nb = PERIOD_BINS
        bins = np.clip(((regs.x - x_lo) / R * nb).astype(np.int64), 0, nb - 1)
        H = _adjoint_histograms(regs, model, c, n, m, bins, nb)
        Fh = np.fft.fft(H, nb * PERIOD_OVERSAMPLE, axis=1)  # Σ g·m·e^{−2πiκξ}
        ks = np.arange(Fh.shape[1]) / PERIOD_OVERSAMPLE
        keep = np.flatnonzero((ks >= PERIOD_CYCLES[0]) & (ks <= k_hi))
        S2 = Fh[-1, 2 * keep]  # Σ m²·e^{−2πi·2κξ}: the unfiltered sinusoids' Gram
        ks, Fh = ks[keep], Fh[:-1, keep]
        P = np.stack([Fh.real, -Fh.imag], -1)  # (1 + n, K, 2): ⟨·, Λ[m cos]⟩, ⟨·, Λ[m sin]⟩
        b, Q = P[0], P[1:]
        # CᵀC from the speeds' histogram
        lam = 2 * math.pi * self.st.filter_hz
        va = np.abs(np.asarray(self.v_train, np.float64))[:T]
        v_top = max(float(np.max(va)), 1e-300)
        edges = np.geomspace(v_top * 1e-4, v_top, 257)
        cnt, _ = np.histogram(np.clip(va, edges[0], edges[-1]), edges, weights=m * m)
        vc = np.sqrt(edges[1:] * edges[:-1])
        w = 2 * math.pi * ks[:, None] * vc[None, :] / R
        D = 0.5 * ((lam * lam / (lam * lam + w * w)) ** 3) @ cnt  # (K,)
        # the unfiltered Gram [[Σcos², Σcos·sin], [·, Σsin²]] scaled by the filter's loss
        C2 = 0.5 * np.stack(
            [np.stack([h0 + S2.real, -S2.imag], -1), np.stack([-S2.imag, h0 - S2.real], -1)], -2
        )
        Gi = np.linalg.pinv(G[:n, :n])
        M = (2 * D / h0)[:, None, None] * C2 - np.einsum("nki,nm,mkj->kij", Q, Gi, Q)
        det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
        det = np.maximum(det, 1e-12 * D * D)
        # bᵀM⁻¹b for the 2×2 M
        b0, b1 = b[:, 0], b[:, 1]
        red = (b0 * b0 * M[:, 1, 1] - 2 * b0 * b1 * M[:, 0, 1] + b1 * b1 * M[:, 0, 0]) / det
        peak = (red >= np.roll(red, 1)) & (red >= np.roll(red, -1))
        idx = np.flatnonzero(peak)
        top = idx[np.argsort(-red[idx])[:PERIOD_PEAKS]]
        return ks[np.sort(top)]
