"""Look-alikes: effects outside the library that a named stack must beat. Fitted like
candidates but never named nor stacked, each may refuse a candidate's step
(:meth:`~AbstractLookalike.veto`) or overrule a named stack (:meth:`~AbstractLookalike.test`),
turning the verdict ``unexplained``: a dead zone (:class:`DeadZoneLookalike`: the sign of the
force where friction has the velocity's), fluid drag (:class:`DragLookalike`: it lowers the
response to the largest forces as a saturation does, but follows the velocity) and a force
periodic in position (:class:`PeriodicLookalike`: cogging, found by a screen over every period).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from ..._models import Augmented, MassDamper
from .._lstsq import fit_batch, residual, rss_fixed_with_columns, rss_with_columns, solve_grams
from .._regressors import DesignPass, Regressors, TooWide
from .._streaming import FilteredColumns, Filters, scaled
from ._base import AbstractCandidate, Design, OneColumnEffect
from ._friction import AbstractFriction

#: Quantiles of the training |F| at which the dead-zone look-alike's width d is tried.
DEAD_ZONE_QUANTILES = tuple(float(q) for q in np.geomspace(0.01, 0.8, 16))
#: The periodic look-alike's screen: the cycles κ across both records' positions it searches
#: (the period above PERIOD_OVER_NOISE times the position noise), its position bins, its κ steps
#: per cycle (a sinusoid whose cycle count is off by δ loses its coherence at δ ≈ 1/2), and the
#: peaks that are fitted.
PERIOD_CYCLES = (1.5, 128.0)
PERIOD_OVER_NOISE = 10.0
PERIOD_BINS = 4096
PERIOD_OVERSAMPLE = 8
PERIOD_PEAKS = 6
#: The family-wise level at which a force periodic in position is reported in ``where``.
FINDING_ALPHA = 0.01


@dataclasses.dataclass(frozen=True)
class LookalikeTest:
    """A look-alike fitted beside a stack: its validated mean square ``ms`` of ε₁, whether it
    overrules the named stack (``overrules_none``: also where nothing is named), its score as
    evidence against the stack (``rival``) or None, its share of what the stack leaves, its
    entries in the report's ``final`` and its ``where`` finding (or None)."""

    ms: float
    overrules: bool = False
    overrules_none: bool = False
    rival: float | None = None
    share: float = 0.0
    final: dict = dataclasses.field(default_factory=dict)
    finding: dict | None = None


def structure_key(structure) -> tuple:
    """A structure's candidates with their fields, as a hashable key."""
    return tuple(
        (type(c), tuple((f.name, repr(getattr(c, f.name))) for f in dataclasses.fields(c)))
        for c in structure
    )


class AbstractLookalike(AbstractCandidate):
    """An effect outside the library, fitted only to guard the names (module docstring)."""

    def veto(self, run, cur, new, ks, score: float) -> str:
        """Why the step of candidates ``ks`` from fit ``cur`` to ``new`` (scoring ``score``)
        describes this look-alike rather than them ("" by default)."""
        return ""

    def test(self, run, stk) -> LookalikeTest:
        """This look-alike fitted beside the stack ``stk`` (:class:`LookalikeTest`)."""
        raise NotImplementedError


class ForceClip(OneColumnEffect):
    """A dead zone's input u = F − clip(F, ±d) (d [N]): column −(1/Λ)[clip(F, ±d)] beside F's,
    its coefficient b for the dead zone exactly."""

    param, sign, hold = "b_clip", -1.0, "zoh"
    d: float

    @property
    def signal(self) -> str:
        return f"clip_F@{self.d:.9g}"

    def raw(self, rs):
        return np.clip(np.asarray(rs.F, np.float64), -self.d, self.d)


class VelocityDrag(OneColumnEffect):
    """Fluid drag −c₂·v̂|v̂| [N]: column +(1/Λ)[v̂|v̂|], parameter b·c₂."""

    param, phys, signal = "b_c2", "c2", "v_abs_v"

    def raw(self, rs):
        v = rs.v
        return lambda k0, k1: v[k0:k1] * np.abs(v[k0:k1])


class DeadZoneLookalike(AbstractLookalike):
    """A dead zone's input F − clip(F, ±d) in place of F (:class:`ForceClip`, its coefficient
    free; d the quantile of the training |F| of least training RSS). It refuses a friction step
    it explains clearly better on the same structure (``Criteria.dead_zone_lookalike_gain``),
    and overrules a named stack where, on the baseline, it validates below
    ``Criteria.dead_zone_lookalike_share`` of the stack's mean square. Its free columns F and
    clip(F, ±d) span a hard saturation at d = F_max, so a stack holding a saturation fitted at
    its clip validates as well as it and is not overruled."""

    name: ClassVar[str] = "dead_zone_lookalike"
    n_params: ClassVar[int] = 2

    def ms(self, problem, structure, design, inp=(0.0, math.inf)) -> float:
        """Its validated mean square with ``structure`` (input map ``inp``)."""
        key = ("dead zone", structure_key(structure), tuple(inp))
        if key not in problem.memo:
            rtr, rva = problem.regressors(design)
            Fa = np.abs(np.asarray(problem.train.F, np.float64))
            ds = np.unique(np.quantile(Fa, np.asarray(DEAD_ZONE_QUANTILES)))
            effects = problem.model(structure).effects
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
            problem.memo[key] = best[1]
        return problem.memo[key]

    def veto(self, run, cur, new, ks, score) -> str:
        crit = run.crit
        if not (score > crit.threshold and any(isinstance(k, AbstractFriction) for k in ks)):
            return ""
        ms = self.ms(run.problem, cur.structure, cur.design, (cur.design.tau, cur.design.fmax))
        if cur.ms_valid - ms > crit.dead_zone_lookalike_gain * (cur.ms_valid - new.ms_valid):
            return (
                "the residual follows the sign of the force rather than of the velocity: a dead "
                "zone's input F − clip(F, ±d) validates clearly better than friction"
            )
        return ""

    def test(self, run, stk) -> LookalikeTest:
        cur = stk.fit
        judged = bool(stk.cands)
        ms = self.ms(run.problem, (), Design()) if judged else math.inf
        return LookalikeTest(
            ms,
            overrules=bool(ms < run.crit.dead_zone_lookalike_share * cur.ms_valid),
            rival=_rival(run, stk, ms, self.n_params),
            final={"dead_zone_lookalike_ratio": ms / cur.ms_valid if judged else None},
        )


class DragLookalike(AbstractLookalike):
    """Fluid drag (:class:`VelocityDrag`) on the baseline: it overrules a named stack where it
    validates below ``Criteria.drag_lookalike_share`` of the stack's mean square."""

    name: ClassVar[str] = "drag_lookalike"
    n_params: ClassVar[int] = 1

    def effects(self, st):
        return (VelocityDrag(),)

    def test(self, run, stk) -> LookalikeTest:
        cur, problem = stk.fit, run.problem
        ms = math.inf
        if stk.cands:
            if ("drag",) not in problem.memo:  # fitted on train, scored on validation
                rtr, rva = problem.regressors(Design())
                model, inp = Augmented(MassDamper(), (VelocityDrag(),)), (0, math.inf)
                r = residual(rva, model, fit_batch(rtr, model, [inp])[0][0], inp)
                problem.memo["drag",] = float(np.mean(r**2))
            ms = problem.memo["drag",]
        return LookalikeTest(
            ms,
            overrules=bool(ms < run.crit.drag_lookalike_share * cur.ms_valid),
            rival=_rival(run, stk, ms, self.n_params),
            final={"drag_lookalike_ratio": ms / cur.ms_valid if math.isfinite(ms) else None},
        )


def _rival(run, stk, ms: float, k: int) -> float | None:
    """A look-alike's score from the baseline (``k`` parameters; N_eff and floor as the stack's
    :meth:`~.._run.Run.joint`) where it has no more parameters and scores above the stack's
    joint score (an explanation as simple that fits better is evidence against the stack); None
    otherwise, or against a stack the windowed simulation confirms where the baseline is
    qualitatively wrong (there the equation error is no measure)."""
    if not stk.cands or run.confirmed(stk) or not math.isfinite(ms):
        return None
    if k > run.params(stk.cands):
        return None
    s = run.score_ms(run.base, ms, k, run.fit_floor)
    return s if s > run.joint(stk) else None


class PeriodicLookalike(AbstractLookalike):
    """A force periodic in position, A·sin(2πx/p + φ), fitted with the stack (not one with an
    input map): columns (1/Λ)[sin 2πκξ], (1/Λ)[cos 2πκξ], ξ = (x − x_lo)/R over both records'
    range R, κ = R/p cycles, scored on validation with 3 parameters. It overrules the stack (and
    "no effect") where it scores above ``Criteria.periodic_score_factor`` times the threshold,
    removes ``min_share`` of what the stack leaves and holds ``periodic_over_stack`` of the
    stack's evidence (a remainder small beside a dominant effect is no rival); it is reported in
    ``where`` where it overrules or is found at the family-wise level :data:`FINDING_ALPHA`."""

    name: ClassVar[str] = "periodic_lookalike"
    n_params: ClassVar[int] = 3

    def test(self, run, stk) -> LookalikeTest:
        cur, crit = stk.fit, run.crit
        if cur.design.maps_input:
            ms, period, cycles = math.inf, math.nan, 0.0
        else:
            ms, period, cycles = self.fitted(run.problem, stk.fit.structure)
        score = run.score_ms(cur, ms, 3, 0.0) if math.isfinite(ms) and ms > 0 else -math.inf
        # its validated fit bounds the floor, as every validated fit does
        lo2 = min(run.fit_floor**2, ms)
        ex_cur = max(cur.ms_valid - lo2, 0.0)
        share = 1 - max(ms - lo2, 0.0) / ex_cur if ex_cur > 0 and math.isfinite(ms) else 0.0
        better = bool(
            score > crit.periodic_score_factor * crit.threshold
            and share >= crit.min_share
            and score >= crit.periodic_over_stack * run.bar(stk)
        )
        fin = lambda a: a if math.isfinite(a) else None
        ratio = ms / cur.ms_valid if math.isfinite(ms) else None
        info = dict(ratio=ratio, score=fin(score), share=share, period=fin(period))
        final = {"periodic_lookalike": info | {"significant": better}}
        # found: its likelihood ratio n·ln(MS/MS_p) (score + 3·ln n) beyond what the best of the
        # searched periods reaches on noise at the family-wise level FINDING_ALPHA: a χ²₂ per
        # independent period, about one per cycle searched (P(max > c) ≈ K·e^{−c/2})
        lr = score + 3 * math.log(cur.n_eff) if math.isfinite(score) else -math.inf
        found = lr > 2 * math.log(max(cycles, 1.0) / FINDING_ALPHA)
        finding = None
        if better or found:
            finding = {
                "kind": "position_period",
                "band": f"period {period:.4g} m",
                "period": period,
                "share": share,
                "score": score,
                "note": "a force periodic in position (cogging; not in the library) fitted with "
                "the stack: share = its part of the excess validation error the stack leaves; "
                + ("it overrules the stack" if better else "found, too small to overrule it"),
            }
        return LookalikeTest(
            ms, overrules=better, overrules_none=better, share=share, final=final, finding=finding
        )

    def fitted(self, problem, structure) -> tuple[float, float, float]:
        """(validated mean square of ε₁, period p [m], the cycles searched) of the structure with
        the look-alike, ``(inf, nan, 0)`` with no period to search. κ is found on the training
        record: :func:`_period_screen`'s peaks (and 1/16 cycle either side) fitted with the
        structure, then 9 points 1/64 cycle apart around the best; only the chosen κ is scored
        on validation, so a sinusoid fitted to train's noise is not counted."""
        key = ("periodic", structure_key(structure))
        if key in problem.memo:
            return problem.memo[key]
        rtr, rva = problem.regressors(structure)
        model = problem.model(structure)
        x_lo = min(float(np.min(problem.train.x)), float(np.min(problem.valid.x)))
        R = max(float(np.max(problem.train.x)), float(np.max(problem.valid.x))) - x_lo
        sx = problem.position_noise[1]
        k_hi = min(PERIOD_CYCLES[1], R / max(PERIOD_OVER_NOISE * sx, 1e-300))
        out = (math.inf, math.nan, 0.0)
        if k_hi > PERIOD_CYCLES[0]:
            m_tr, m_va = _moving(problem, rtr, 0), _moving(problem, rva, 1)

            def columns(regs: Regressors, m, ks) -> FilteredColumns:  # (m, 2, T): sin, cos of κ
                sc = lambda k: [
                    (_sinusoid(regs, x_lo, R, k, f, m), 1.0, 0, 1.0) for f in (np.sin, np.cos)
                ]
                return FilteredColumns([sc(float(k)) for k in ks])

            lam = 2 * math.pi * problem.st.filter_hz
            peaks = _period_screen(rtr, model, x_lo, R, k_hi, problem.v_train, lam, m_tr)
            try:
                if peaks.size:  # (none where every force is masked)
                    ks = (peaks[:, None] + np.array([-1.0, 0.0, 1.0]) / 16).ravel()
                    k0 = ks[int(np.argmin(rss_with_columns(rtr, model, columns(rtr, m_tr, ks))))]
                    ks = k0 + np.arange(-4, 5) / 64
                    coef, rss, _ = rss_with_columns(rtr, model, columns(rtr, m_tr, ks), coef=True)
                    i = int(np.argmin(rss))
                    r = rss_fixed_with_columns(
                        rva, model, columns(rva, m_va, ks[i : i + 1]), coef[i : i + 1], 2
                    )
                    ms = float(r[0]) / problem.valid.n_samples
                    out = (ms, R / float(ks[i]), k_hi - PERIOD_CYCLES[0])
            except TooWide:
                pass
        problem.memo[key] = out
        return out


def _moving(problem, regs: Regressors, i: int) -> np.ndarray | None:
    """(T,) the mask m ∈ {0, 1} of a force of position on record ``i`` (0 train, 1 valid): 0
    where the axis sticks, whatever the structure's own force columns are. At rest static
    friction balances every force on the axis, so a force of position is seen only where the
    axis moves; fitted at rest it would describe where the axis stopped (each rest's static
    friction), not a force. None where the axis never sticks and no force is masked."""
    m = regs.force_mask
    if problem.sticks:
        moving = 1.0 - np.asarray(problem.stuck[i], np.float64)
        m = moving if m is None else m * moving
    return m


def _sinusoid(regs: Regressors, x_lo: float, R: float, k: float, f, m):
    """The raw signal m·f(2πκξ), ξ = (x − x_lo)/R (m the mask, :func:`_moving`), per rows."""
    x = regs.x
    raw = lambda k0, k1: f(2 * math.pi * k * ((x[k0:k1] - x_lo) / R))
    return raw if m is None else scaled(m, raw)


def _adjoint_histograms(regs: Regressors, model, c, n: int, m, bins, nb: int) -> np.ndarray:
    """(n + 2, nb) position histograms (``bins``) of Λ*[g]·m for g the structure's training
    residual r = Wc + y and each of its n columns, then of m: Λ* the filter's adjoint (the
    causal filter on the time-reversed signal, reversed back). The chunks are visited backwards,
    each one's design recomputed from the states a forward pass left at its start."""
    T = regs.T
    d = DesignPass(regs, model, False)
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


def _period_screen(
    regs: Regressors, model, x_lo: float, R: float, k_hi: float, v_train, lam: float, mask
) -> np.ndarray:
    """The :data:`PERIOD_PEAKS` cycle counts κ whose columns C = Λ[m·(cos, sin)(2πκξ)] (m the
    ``mask`` of :func:`_moving`, ones where None) would reduce the training RSS of the
    structure W most, estimated for every κ at once: the reduction is bᵀ(C⊥ᵀC⊥)⁻¹b, b = Cᵀr
    (r the residual, ⊥ W), C⊥ᵀC⊥ = CᵀC − CᵀW(WᵀW)⁻¹WᵀC. A product with a filtered column is
    one of the raw sinusoid with the filter's adjoint of r and of W's columns, which their
    position histograms give for every κ by one FFT each; CᵀC is the unfiltered sinusoids'
    Gram (the mask's histogram at 2κ) times the filter's mean loss Σₜm²|Λ(jκ·2π|v̂ₜ|/R)|²/Σₜm².
    It only ranks κ (empty where every force is masked)."""
    T = regs.T
    n = regs.width(model)
    m = np.ones(T) if mask is None else np.asarray(mask)[:T]
    h0 = float(np.sum(m * m))
    if h0 <= 0:
        return np.zeros(0)
    G = regs.design_gram(model)
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
    va = np.abs(np.asarray(v_train, np.float64))[:T]
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


#: The default look-alikes a named stack must beat.
DEFAULT_LOOKALIKES: tuple[AbstractLookalike, ...] = (
    DeadZoneLookalike(),
    DragLookalike(),
    PeriodicLookalike(),
)
