"""The diagnosis' stages up to the stack (:func:`lionjax.diagnose`, module :mod:`._core`):
the baseline and its noise floor (:func:`prepare`), every candidate alone (:func:`fit_alone`),
the greedy stack (:func:`stack_effects`) and the parsimony pass (:func:`parsimony`). They share
one :class:`Run`: the records, the fitter, the baseline and how a fit is scored."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._errors import InputError
from .._record import Record
from ._candidates import AbstractCandidate, Limits
from ._criteria import Criteria
from ._filtering import impulse_gains
from ._fit import TooWide
from ._fitter import _Fitter
from ._force_effects import check_library
from ._result import EffectScore
from ._settings import Settings, settings
from ._statistics import _check_memory, _feedback, _position_noise, _robust_diff_std
from ._structures import Fitted, _has_mode

#: How messages name the two records (the command line puts the file names in).
ROLES = {
    "train": "training record (argument 'train')",
    "valid": "validation record (argument 'valid')",
}


@dataclasses.dataclass
class Run:
    """What the stages of one diagnosis share: the records and settings, the fitter, the
    baseline fit and its noise floor, and the scoring of one fit against another. ``fit_floor``
    (the floor mean squares count from) is lowered as fits come in (:meth:`lowered`)."""

    train: Record
    valid: Record
    st: Settings
    crit: Criteria
    candidates: tuple[AbstractCandidate, ...]
    fitter: _Fitter
    base: Fitted
    sx: float  # position noise of the validation record [m]
    sF: float  # force noise [N]
    floor: float  # the estimated floor of ε₁
    force_rms: float  # rms of ε₁'s input term b·F/Λ on validation
    feedback: float
    F_ref: np.ndarray  # F less the controller's answer to x
    closed_loop: bool
    limits: Limits
    dominant: bool  # the baseline is qualitatively wrong: a ≤ 0 or b ≤ 0
    outside: dict[str, float]
    fit_floor: float = math.inf
    #: each candidate's fit alone under each of its variants, chosen or not (:func:`fit_alone`)
    variant_fits: dict = dataclasses.field(default_factory=dict)

    @functools.cached_property
    def measured_F_rms(self) -> float:
        """The RMS [N] of the validation record's measured F (mean included), against which a
        measurement artefact is sized."""
        return float(np.sqrt(np.mean(np.square(np.asarray(self.valid.F, np.float64)))))

    @functools.cached_property
    def x_std(self) -> float:
        """The validation record's position spread [m] (at least 1e-300), against which a
        candidate is sized by the simulated gap it removes."""
        return max(float(np.std(np.asarray(self.valid.x, np.float64))), 1e-300)

    @functools.cached_property
    def hold_gap(self) -> float:
        """The gap [m] of holding each window's start position (``_Fitter.hold_gap``): a
        reference simulation that predicts no motion, once the baseline has set the window."""
        return self.fitter.hold_gap()

    @functools.cached_property
    def stuck_share(self) -> float:
        """The share of the validation samples where the axis sticks (``_Fitter.stuck``)."""
        return float(np.mean(self.fitter.stuck_masks[1]))

    def by_simulation(self, cands) -> bool:
        """Whether ``cands`` are judged by the windowed simulation as well as the equation
        error: the baseline is qualitatively wrong (:attr:`dominant`) and the simulation models
        every one of them."""
        return self.dominant and bool(cands) and all(k.simulated for k in cands)

    @property
    def by_name(self) -> dict[str, AbstractCandidate]:
        return {c.name: c for c in self.candidates}

    def score_ms(self, cur: Fitted, ms_new: float, p: int, lo_rms: float) -> float:
        """−ΔBIC of a validated mean square ``ms_new`` against ``cur``'s with ``p`` more
        parameters; mean squares below lo_rms² (a floor) count as lo_rms²: a gain there is on
        noise. N_eff is the residual's the comparison starts from: after a first effect the
        residual is whiter than the baseline's (a spring's misfit dominated it), and the
        baseline's N_eff would deflate the evidence for a second effect (a closed-loop delay
        under a spring, τ within 4 % of the truth, scored 4.6 with the baseline's N_eff ≈ 110)."""
        lo = max(lo_rms**2, 1e-300)
        gain = math.log(max(cur.ms_valid, lo) / max(ms_new, lo))
        ne = cur.n_eff
        return ne * gain - p * math.log(ne)

    def score_of(self, cur: Fitted, new: Fitted, p: int, lo_rms: float) -> float:
        return self.score_ms(cur, new.ms_valid, p, lo_rms)

    def sim_score(self, cur: Fitted, new: Fitted, p: int) -> float:
        """−ΔBIC of the windowed simulation's gap, each scored window one sample (a window
        restarts from the record's states: the windows' errors are nearly independent, the
        samples within one are not): n_w·ln(gap_cur²/gap_new²) − p·ln n_w; −inf where either
        simulation diverged. Where the baseline is qualitatively wrong the equation error is no
        measure of an effect (below)."""
        n_w = (new.n_sim - new.gap_from) // self.fitter.H
        if not (math.isfinite(cur.gap) and math.isfinite(new.gap) and new.gap > 0 and n_w > 1):
            return -math.inf
        return n_w * 2 * math.log(cur.gap / new.gap) - p * math.log(n_w)

    def lowered(self, rms: float, fits) -> float:
        """The floor rms bounded by the validation error of each (structure, fit) without the
        flexible mode (whose columns can cancel position noise: a gain on noise)."""
        return math.sqrt(min([rms**2, *(f.ms_valid for cands, f in fits if not _has_mode(cands))]))

    def floor_of(self, cands) -> float:
        return self.floor if _has_mode(cands) else self.fit_floor

    def excess(self, ms: float) -> float:
        return max(ms - self.fit_floor**2, 0.0)

    def params(self, cands) -> int:
        return sum(self.fitter.params(k) for k in cands)

    def evidence(self, cur: Fitted, new: Fitted, ks: tuple, lo_rms: float) -> float:
        """The score of ``new`` (``cur`` plus the candidates ``ks``) against ``cur``: the
        validated −ΔBIC (:meth:`score_of`), or the windowed simulation's where that is higher
        and the baseline is qualitatively wrong (:meth:`by_simulation`)."""
        sc = self.score_of(cur, new, self.params(ks), lo_rms)
        if self.by_simulation(ks):
            # the baseline is qualitatively wrong: the equation error can grow with the true
            # effect (a spring at 83 Hz above a 40 Hz corner, k within 0.1 %, carried the
            # encoder's steps through b·k·x/Λ at 5× the baseline's mean square and scored −201
            # while removing 97 % of the simulated gap), so the simulation's evidence counts
            sc = max(sc, self.sim_score(cur, new, self.params(ks)))
        return sc

    def assess(self, cur: Fitted, new: Fitted, cand, lo_rms: float) -> EffectScore:
        """``new`` (``cur`` plus ``cand``: one candidate or a tuple added together) scored
        against ``cur``: significant, or why not (:class:`~lionjax.diagnosis.Criteria`)."""
        crit = self.crit
        ks = cand if isinstance(cand, tuple) else (cand,)
        sc = self.evidence(cur, new, ks, lo_rms)
        by_sim = self.by_simulation(ks)
        ex0 = self.excess(cur.ms_valid)
        share = 1 - self.excess(new.ms_valid) / ex0 if ex0 > 0 else 0.0
        why = self._implausible(cur, new, ks, sc)
        plausible = not why
        # an effect the windowed simulation models must not make the simulated gap worse: an
        # equation-error fit that does (an out-of-library dead zone taken for a polynomial
        # b(x)) describes the residual, not the device (a diverging simulation is worse) —
        # where the current model's simulation is a reference at all: one that predicts the
        # motion worse than holding each window's start position does not (a LuGre stiction
        # record sticking 74 % of the time, baseline b 45× too small: Coulomb friction at 1.04
        # F_c, 112 on validation, moved where static friction held and was refused). Nor is a
        # simulated smoothed sign a reference for friction where the axis sticks for
        # Criteria.stuck_share of the record: without static friction it slides where the axis
        # stuck (only a diverging simulation is then worse)
        hold = self.hold_gap
        simulated = all(k.simulated for k in ks)
        sticks = all(k.masks_stick for k in ks) and self.stuck_share >= crit.stuck_share
        worse = (
            simulated
            and math.isfinite(cur.gap)
            and not cur.gap >= hold
            and not new.gap <= (1 + crit.max_worsening) * cur.gap
            and not (sticks and math.isfinite(new.gap))
        )
        size = math.sqrt(max(cur.ms_valid - new.ms_valid, 0.0)) / self.force_rms
        # a measurement artefact lives in F, where the filter's passband does not bound it: it
        # is sized against F too (a 50 Hz line at f_s = 256 Hz, 0.12 of F's RMS, reached ε₁
        # through the 10 Hz corner as 0.0014 of the filtered input term, and was called
        # `none` at 1.00)
        own = [
            self.fitter.resolve(k).measured_rms(new.physical, self.valid, self.fitter.v_valid)
            for k in ks
        ]
        if all(r is not None for r in own):
            size = max(size, sum(own) / max(self.measured_F_rms, 1e-300))
        if by_sim and math.isfinite(new.gap):  # likewise: the simulated gap it removes
            size = max(size, math.sqrt(max(cur.gap**2 - new.gap**2, 0.0)) / self.x_std)
        # where the baseline is qualitatively wrong, the share of the equation error is no
        # measure of an effect: the simulated gap's share stands in for it; after a first
        # effect, whose misfit the equation error keeps, it may too (Criteria.later_sim_share)
        least = crit.min_share_deep if len(cur.names) >= 2 else crit.min_share
        shares = (
            share >= least
            or (by_sim and sim_share(new.gap, cur.gap) >= crit.dominant_sim_share)
            or (
                bool(cur.names)
                and simulated
                and sim_share(new.gap, cur.gap) >= crit.later_sim_share
            )
        )
        sig = sc > crit.threshold and shares and size >= crit.min_size and plausible and not worse
        if plausible:
            why = (
                "significant"
                if sig
                else f"score {sc:.3g} ≤ {crit.threshold}"
                if sc <= crit.threshold
                else "removes too little"
                if not shares
                else f"too small ({size:.2g} of the input's term, least {crit.min_size})"
                if size < crit.min_size
                else f"makes the simulated gap worse ({new.gap:.3g} m against {cur.gap:.3g} m)"
            )
        return EffectScore(
            name=ks[0].name,
            params={n: v for k in ks for n, v in k.report(new.physical).items()},
            gap=new.gap,
            shrink=shrink(new.gap, self.base.gap),
            equation_gap=new.equation_gap,
            equation_shrink=1 - new.equation_gap / self.base.equation_gap,
            score=sc,
            share=share,
            significant=bool(sig),
            reason=why,
            plausible=plausible,
            size=size,
            simulation=new.simulation,
        )

    def _implausible(self, cur: Fitted, new: Fitted, ks, sc: float) -> str:
        """Why ``ks`` fitted in ``new`` do not describe the device ("" when they may)."""
        why = next((w for k in ks if (w := k.implausible(new.physical, self.limits))), "")
        if (
            not why
            and sc > self.crit.threshold
            and any(k.dead_zone_lookalike for k in ks)
            and cur.ms_valid
            - self.fitter.dead_zone_lookalike(
                [self.by_name[n] for n in cur.names], (cur.tau, cur.fmax)
            )
            > self.crit.dead_zone_lookalike_gain * (cur.ms_valid - new.ms_valid)
        ):
            # friction acts with the sign of the velocity: where a dead zone's input, acting with
            # the sign of the force, validates clearly better on the same structure, the fit
            # describes the input (six of 40 held-out dead zones were named Coulomb friction)
            why = (
                "the residual follows the sign of the force rather than of the velocity: a dead "
                "zone's input F − clip(F, ±d) validates clearly better than friction"
            )
        loop = [k.loop_noise_shrink for k in ks if k.loop_noise_shrink is not None]
        if not why and self.limits.loop_noise and loop and not new.gap <= (1 - max(loop)) * cur.gap:
            why = (
                "closed loop at the noise floor: it cancels the position noise the controller "
                f"feeds into F and removes less than {max(loop):.0%} of the simulated gap "
                f"({new.gap:.3g} m against {cur.gap:.3g} m)"
            )
        return why


def sim_share(gap: float, before: float) -> float:
    """The share of the simulated gap ``before`` that ``gap`` removes: 1 − gap/before (1 where
    only ``before`` diverged, 0 where ``gap`` did)."""
    if not math.isfinite(gap):
        return 0.0
    if not math.isfinite(before):
        return 1.0
    return 1.0 - gap / before if before > 0 else 0.0


def shrink(gap: float, base_gap: float) -> float:
    """1 − gap/base_gap; NaN (null in JSON) where either simulation diverged."""
    if not (math.isfinite(gap) and math.isfinite(base_gap)):
        return math.nan
    return 1 - gap / base_gap if base_gap > 0 else 0.0


def prepare(
    train: Record,
    valid: Record,
    candidates: tuple[AbstractCandidate, ...],
    crit: Criteria,
    filter_hz: float | None,
    window_s: float | None,
    max_memory_gb: float | None,
    streamed: bool | None = None,
) -> Run:
    """Settings, the baseline fit, the noise floor of ε₁ and the record-level facts (closed
    loop, limits, a qualitatively wrong baseline) that every later stage reads."""
    st = settings(train, filter_hz=filter_hz, window_s=window_s)
    # 20 time constants 1/λ of the filter (s + λ)³, λ = 2π·filter_hz
    min_len = int(math.ceil(20 / (2 * math.pi * st.filter_hz * st.dt)))
    for nm, rec in (("train", train), ("valid", valid)):
        if rec.n_samples < max(min_len, 200):
            raise InputError(
                f"diagnose: the {ROLES[nm]} has {rec.n_samples} samples; at least "
                f"{max(min_len, 200)} are needed (20 filter time constants)."
            )
    streamed = _check_memory(train.n_samples, valid.n_samples, max_memory_gb, streamed)
    fitter = _Fitter(train, valid, st, streamed=streamed)
    base = fitter.fit([])
    a, b = base.physical["a"], base.physical["b"]
    # noise floor of ε₁ on the validation record (with the encoder's count: else a clean
    # record's gap is taken for an effect)
    sx = _position_noise(np.asarray(valid.x))
    sF = _robust_diff_std(np.asarray(valid.F))
    gx, gF = impulse_gains(fitter.bank, st.dt, a)
    floor = math.sqrt(sx**2 * gx + (b * sF) ** 2 * gF)
    # the scale of ε₁'s input term b·F/Λ on validation, against which an effect's size counts
    Fv = np.asarray(valid.F, np.float64)
    hF = fitter.rva.mean_square(Fv - np.mean(Fv), "zoh", 0)
    force_rms = max(abs(b) * float(np.sqrt(hF)), 1e-300)
    # in closed loop the controller feeds the position noise into F, so a regressor built from
    # F can cancel the noise's path through x in ε₁: at or below the estimated floor a delay of
    # a few samples does (a clean record named `delay` at 1.00), and is not taken as the device's
    # unless it also removes part of the simulated gap (``loop_noise_shrink``)
    feedback, F_ref = _feedback(np.asarray(valid.x), np.asarray(valid.F))
    closed_loop = feedback >= crit.feedback_share
    limits = Limits(
        float(min(np.max(np.abs(np.asarray(train.F))), np.max(np.abs(Fv)))),
        st.dt,
        sx,
        closed_loop=closed_loop,
        loop_noise=closed_loop and base.ms_valid <= floor**2,
        mode_band=(st.mode_grid[0], st.mode_grid[-1]),
        x_range=_common_range(np.asarray(train.x), np.asarray(valid.x)),
        train_range=(float(np.min(np.asarray(train.x))), float(np.max(np.asarray(train.x)))),
    )
    fitter.limits = limits
    return Run(
        train=train,
        valid=valid,
        st=st,
        crit=crit,
        candidates=candidates,
        fitter=fitter,
        base=base,
        sx=sx,
        sF=sF,
        floor=floor,
        force_rms=force_rms,
        feedback=feedback,
        F_ref=F_ref,
        closed_loop=closed_loop,
        limits=limits,
        # a dominant effect (a spring with its natural frequency above the filter corner,
        # friction that sticks the axis) leaves the mass–damper nothing physical to fit
        dominant=not (a > 0 and b > 0),
        outside=_outside(train, valid, fitter.v_train, fitter.v_valid),
    )


def fit_alone(run: Run) -> dict[str, Fitted]:
    """Every candidate alone on the baseline, its variants (the degree of the position
    dependence, the flexible mode with or without its input-share column …) chosen by their
    validated score (among those whose fit is plausible, where the variants are nested:
    ``nested_variants``), each paying its own parameters, then fixed; the mode counts from the
    estimated floor, the others from nothing yet. Sets ``run.fit_floor``. (A held-out
    collocated mode, μ 0.58 at 29.4 Hz, fitted μ 0.55 at 29.7 Hz with κ held at 0, and κ
    −0.64, μ 0.30 at 38 Hz with κ free, which scored higher and was refused.)"""
    fitter, fitted, friction_chosen = run.fitter, {}, False
    for c in run.candidates:
        variants = c.variants(
            fitter.variant,
            friction_open=not friction_chosen,
            sticks=fitter.sticks,
            outside=run.outside["position"] > 0,
        )
        friction_chosen = friction_chosen or (c.friction_form and len(variants) > 1)
        tries = []
        for var in variants:
            fitter.variant = var
            f = fitter.fit([c])
            lo = run.floor if _has_mode([c]) else 0.0
            tries.append((run.score_of(run.base, f, fitter.params(c), lo), f, var))
        run.variant_fits[c.name] = [(var, f) for _, f, var in tries]
        if c.nested_variants:
            tries = [t for t in tries if not c.implausible(t[1].physical, run.limits)] or tries
        _, fitted[c.name], var = max(tries, key=lambda t: t[0])
        fitter.variant = var
    # the floor scores and shares count from: the estimate above is an upper bound only for
    # white, independent noise on x and F — in closed loop F carries the controller's answer to
    # the position noise, which partly cancels the noise's path through x in ε₁, and a quantised
    # position is not white at high sample rates — while the validation error of any fitted
    # model bounds the true floor from above. A fit with the flexible mode's columns counts from
    # the estimate: a column with high-frequency content of x can cancel part of the position
    # noise that ε₁ carries through s²/Λ — a gain on noise, not on the gap.
    run.fit_floor = run.lowered(
        min(run.floor, run.base.equation_gap), [([c], fitted[c.name]) for c in run.candidates]
    )
    return fitted


@dataclasses.dataclass
class Stack:
    """The greedy stack: its candidates in the order added, the steps' scores, its fit, which
    stand-in replaced which candidate (:func:`parsimony`), and the score of each step that
    added candidates together (a stand-in or a pair), under the first of them (``together``:
    their joint evidence, which none of them has alone, and the names of that step), and
    the stand-ins among those steps (``laws``: the candidates that stand in for one implausible
    or unneeded candidate, one law in several columns: Coulomb friction and an offset for
    asymmetric friction)."""

    cands: list[AbstractCandidate]
    steps: list[EffectScore]
    fit: Fitted
    stands_for: dict[str, str] = dataclasses.field(default_factory=dict)
    together: dict[str, tuple[float, tuple[str, ...]]] = dataclasses.field(default_factory=dict)
    laws: list[tuple[str, ...]] = dataclasses.field(default_factory=list)

    @property
    def size(self) -> int:
        """The effects the stack holds, against ``Criteria.max_effects``: a candidate another
        stacked one contains (an offset beside a spring, whose equilibrium holds a constant
        force) adds no column and takes no place (a held-out open-loop triple of Stribeck
        friction, a spring and a delay stacked Coulomb friction + offset, the stand-in of
        asymmetric friction, then the spring, and had no room left for the delay)."""
        inside = {n for k in self.cands for n in k.subsumes}
        return sum(c.name not in inside for c in self.cands)


def try_fit(run: Run, cands) -> Fitted | None:
    """The fit of ``cands``, or None when its design would be wider than P_MAX."""
    try:
        return run.fitter.fit(cands)
    except TooWide:
        return None


def _stand_in(run: Run, trials, pool, stk: Stack):
    """(score, fit, candidates) of the first implausible trial's stand-in (``simpler``: two or
    more candidates of the pool) that is significant as one step, in score order; or None."""
    names = {c.name: c for c in pool}
    for t in trials:
        c = t[2]
        if t[0].plausible or len(c.simpler) < 2 or not all(n in names for n in c.simpler):
            continue
        ks = tuple(names[n] for n in c.simpler)
        if stk.size + len(ks) > run.crit.max_effects:
            continue
        step = _as_one_step(run, stk, ks)
        if step is not None:
            return step
    return None


def _as_one_step(run: Run, stk: Stack, ks: tuple):
    """(score, fit, ks) of the candidates ``ks`` added to the stack together, where they are
    significant as one step; else None (also where the design would be too wide)."""
    f = _fit_on(run, stk, ks)
    return None if f is None else _step_of(run, stk, ks, f)


def _step_of(run: Run, stk: Stack, ks: tuple, f: Fitted):
    """(score, fit, ks) of the candidates ``ks`` fitted with the stack in ``f``, where they are
    significant as one step; else None."""
    sc = run.assess(stk.fit, f, ks, run.floor_of([*stk.cands, *ks]))
    return (sc, f, ks) if sc.significant else None


def _excludes(k: AbstractCandidate, c: AbstractCandidate) -> bool:
    """Whether ``k`` excludes ``c`` or a candidate ``c`` contains (asymmetric friction excludes
    an offset, so also a spring or a drifting offset, which hold one)."""
    return bool(set(k.excludes) & {c.name, *c.subsumes})


def _fits_with(c: AbstractCandidate, added) -> bool:
    """Whether ``c`` may still be stacked after the candidates ``added``: not after one that
    contains it (spring ⊃ offset) nor with one the data cannot tell apart from it or from what
    it contains (asymmetric friction and an offset; and so a drifting offset: a held-out Dahl
    triple stacked asymmetric friction, then the drift, which parsimony made an offset)."""
    return all(
        c is not k and c.name not in k.subsumes and not _excludes(k, c) and not _excludes(c, k)
        for k in added
    )


def _compatible(c: AbstractCandidate, k: AbstractCandidate) -> bool:
    """Whether ``c`` and ``k`` may be added together (neither contains nor excludes the other;
    greedy stacking, :func:`_fits_with`, lets a candidate follow one it contains)."""
    return _fits_with(c, (k,)) and k.name not in c.subsumes


def _pair(run: Run, trials, stk: Stack):
    """(score, fit, candidates) of the best pair of plausible trials that gain on the current
    stack (share > 0) and are significant together as one step, or None: of the 2n best (n =
    :data:`~._criteria.Criteria.pair_from`), the n(n − 1)/2 compatible pairs of the highest
    summed scores are tried; not tried once the stack removes ``explained_full`` of
    the baseline's excess. Effects that hide each other — a spring under a 15 ms
    delay, neither significant alone, the residual of either so correlated that 12 effective
    samples remain — are found together."""
    if stk.size + 2 > run.crit.max_effects:
        return None
    # a stack that already removes explained_full of the excess needs no pair (nor does a
    # record without excess): each pair is a fit, with its profiles
    ex0 = run.excess(run.base.ms_valid)
    if not ex0 > 0 or run.excess(stk.fit.ms_valid) <= (1 - run.crit.explained_full) * ex0:
        return None
    n = run.crit.pair_from
    top = [t for t in trials if t[0].plausible and t[0].share > 0][: 2 * n]
    pairs = [
        (ti, tj) for i, ti in enumerate(top) for tj in top[i + 1 :] if _compatible(ti[2], tj[2])
    ]
    # the n(n − 1)/2 compatible pairs of the highest summed scores: near-duplicates (an offset,
    # a drifting offset, a spring) cannot pair with each other and would fill the best n
    pairs.sort(key=lambda p: -(p[0][0].score + p[1][0].score))
    found = []
    for ti, tj in pairs[: n * (n - 1) // 2]:
        step = _as_one_step(run, stk, (ti[2], tj[2]))
        if step is not None:
            found.append(step)
    return max(found, key=lambda t: t[0].score, default=None)


def _hidden(run: Run, trials, stk: Stack):
    """(score, fit, candidates) of effects that hide each other, or None: where nothing is
    significant on the stack, alone or as :func:`_pair`'s pairs, the stack's error lies above
    ``floor_factor`` times the floor and two more effects fit, every compatible pair of the
    device candidates (fitted alone plausibly or with implausible parameters: one's misfit can
    bias another's sign; the flexible mode's columns left out, as they fit any residual shape in
    part) is fitted on the stack, then the ``pair_from`` best pairs each with every compatible
    third. The best combination that is significant as one step and removes at least
    ``explained_full`` of the stack's excess is taken: effects hidden so are a whole explanation
    together. Held-out open-loop triples, each effect changing the response 10–50 %, scored −8
    to 7 alone, the baseline's residual so correlated that 10–21 effective samples remained;
    Coulomb friction with a spring scored 40–51 and removed all the excess, an offset, a delay
    and LuGre friction 22 together and 6 at best as a pair. After a spring, a 9 ms delay and
    Stribeck friction fitted alone gave F_c < 0. An out-of-library effect fitted so leaves more
    (dead zones, backlash and cogging left 58–70 % to a named stack)."""
    crit = run.crit
    room = crit.max_effects - stk.size
    if not crit.pair_from or room < 2 or stk.fit.equation_gap <= crit.floor_factor * run.floor:
        return None
    # a candidate refused alone for what the record shows against it (a dead zone's look-alike
    # that validates better, the loop's noise), not for its own fitted parameters, stays out
    pool = [
        t[2]
        for t in trials
        if t[2].acts_on == "device"
        and not t[2].holds_mode
        and (t[0].plausible or t[2].implausible(t[1].physical, run.limits))
    ]

    def fitted(combos) -> dict:
        return {ks: f for ks in combos if (f := _fit_on(run, stk, ks)) is not None}

    def whole(fits: dict) -> list:
        steps = (_step_of(run, stk, ks, f) for ks, f in fits.items())
        return [s for s in steps if s is not None and s[0].share >= crit.explained_full]

    fits = fitted((a, b) for i, a in enumerate(pool) for b in pool[i + 1 :] if _compatible(a, b))
    found = whole(fits)
    if not found and room >= 3:
        best = sorted(fits, key=lambda ks: fits[ks].ms_valid)[: crit.pair_from]
        thirds = {
            tuple(sorted((*ks, c), key=pool.index))
            for ks in best
            for c in pool
            if all(_compatible(c, k) for k in ks)
        }
        found = whole(fitted(sorted(thirds, key=lambda ks: [c.name for c in ks])))
    return max(found, key=lambda t: t[0].score, default=None)


def stack_effects(
    run: Run, alone: dict[str, tuple[EffectScore, Fitted]], start: Stack | None = None
) -> Stack:
    """Greedy stacking: the best significant candidate on the current stack (empty, or
    ``start``: after :func:`parsimony` put a stand-in in, what the candidate it replaced
    excluded may join), until none is. When none is, or when an implausible candidate outranks the
    best one, the stand-in pair of an implausible candidate that is significant as one step is
    tried, and the better score is taken (asymmetric friction with F⁺ < 0 < F⁻ is Coulomb
    friction and an offset larger than it: a closed-loop record with F_c = 0.12 N and F₀ =
    0.17 N, Coulomb alone 3.6, the offset 6.2, the pair 38)."""
    stk = Stack([], [], run.base) if start is None else start
    # (a candidate a stand-in replaced does not come back: its own parameters were not needed)
    gone = set(stk.stands_for.values())
    pool = [c for c in run.candidates if _fits_with(c, stk.cands) and c.name not in gone]
    while pool and stk.size < run.crit.max_effects:
        fits = [(c, alone[c.name][1] if not stk.cands else _fit_on(run, stk, (c,))) for c in pool]
        fits = [(c, f) for c, f in fits if f is not None]
        if not fits:
            break
        # every validated fit bounds the floor from above, this step's too: else the first
        # effect's fit is the floor and no second effect can gain on it (a spring under a
        # closed-loop delay, k within 11 % of the truth, scored −5)
        run.fit_floor = run.lowered(run.fit_floor, [([*stk.cands, c], f) for c, f in fits])
        trials = [(run.assess(stk.fit, f, c, run.floor_of([*stk.cands, c])), f, c) for c, f in fits]
        trials.sort(key=lambda t: -t[0].score)
        best = next((t for t in trials if t[0].significant), None)
        # an implausible candidate that outranks the best significant one puts up its stand-in
        # too, and the better score is taken (a closed-loop Stribeck record with an offset:
        # asymmetric friction with F⁻ < 0 scored 935, the spring 281 and was named at 1.00; the
        # stand-in Coulomb + offset fitted F₀ within 4 %)
        above = [t for t in trials if best is None or t[0].score > best[0].score]
        alt = _stand_in(run, above, pool, stk) if above else None
        if best is not None and (alt is None or alt[0].score <= best[0].score):
            stk.steps.append(best[0])
            added: tuple[AbstractCandidate, ...] = (best[2],)
        else:
            best = alt or _pair(run, trials, stk) or _hidden(run, trials, stk)
            if best is None:
                break
            added = best[2]
            names = tuple(k.name for k in added)
            stk.together[added[0].name] = (best[0].score, names)
            if best is alt:
                stk.laws.append(names)
            for k in added:
                others = ", ".join(o.name for o in added if o is not k)
                stk.steps.append(
                    dataclasses.replace(
                        best[0],
                        name=k.name,
                        params=k.report(best[1].physical),
                        reason=f"significant together with {others} (not alone)",
                    )
                )
        stk.cands.extend(added)
        stk.fit = best[1]
        if best[1] is not alone[added[0].name][1]:  # a fit on the stack: its variant stays
            run.fitter.variant = best[1].variant
        pool = [c for c in pool if _fits_with(c, added)]
    return stk


def _fit_on(run: Run, stk: Stack, ks: tuple) -> Fitted | None:
    """The candidates ``ks`` fitted on the stack under each combination of their
    :meth:`~AbstractCandidate.stack_variants`: the best validated fit, which carries its
    variant (None where the design is too wide). The fitter's variant is left as it was."""
    now = run.fitter.variant
    variants = [now]
    for k in ks:
        variants = list(dict.fromkeys(w for v in variants for w in k.stack_variants(v)))
    fits = []
    for var in variants:
        run.fitter.variant = var
        fits.append(try_fit(run, [*stk.cands, *ks]))
    run.fitter.variant = now
    return min((f for f in fits if f is not None), key=lambda f: f.ms_valid, default=None)


def parsimony(run: Run, stk: Stack) -> Stack:
    """A candidate with a simpler stand-in (spring → offset: in closed loop a constant force
    shifts the equilibrium; asymmetric friction → Coulomb + offset: while the axis moves, a
    direction-dependent level is a constant force) is replaced by it unless its own extra
    parameters are significant on validation data. The stand-in must itself explain the gap
    (significant where the candidate stood). Where the windowed simulation models both, the
    candidate must not make the simulated gap worse than its stand-in, and with no more
    parameters than it, it must make it better: asymmetric friction with F⁺, F⁻ > 0 and
    Coulomb friction with an offset |F₀| < F_c are one law (levels F_c ∓ F₀), which only the
    smoothed sign near reversals tells apart in ε₁ (a Coulomb + offset record kept as
    asymmetric friction by 11 on ε₁, both simulated within 1 %)."""
    by_name, fitter, crit = run.by_name, run.fitter, run.crit
    for c in list(stk.cands):
        names_now = [k.name for k in stk.cands]
        missing = [n for n in c.simpler if n not in names_now]
        if not missing or any(n not in by_name for n in missing):
            continue  # nothing to stand in, or a stand-in outside the library
        simpler = [by_name[n] for n in missing]
        i = stk.cands.index(c)
        alt = [*stk.cands[:i], *simpler, *stk.cands[i + 1 :]]
        f_alt = fitter.fit(alt)
        n_simple = run.params(simpler)
        rest = [k for k in stk.cands if k is not c]
        prev = fitter.fit(rest) if rest else run.base
        cur = stk.fit
        extra = fitter.params(c) - n_simple
        keep = run.score_of(f_alt, cur, extra, run.floor_of(stk.cands)) > crit.threshold
        if c.simulated and all(k.simulated for k in simpler) and math.isfinite(f_alt.gap):
            keep = keep and cur.gap <= (1 + crit.max_worsening) * f_alt.gap
            if extra <= 0:
                keep = keep and cur.gap < (1 - crit.max_worsening) * f_alt.gap
        if run.score_of(prev, f_alt, n_simple, run.floor_of(alt)) > crit.threshold and not keep:
            stk.cands, stk.fit = alt, f_alt
            stk.stands_for[simpler[0].name] = c.name
            if len(simpler) > 1:
                stk.laws.append(tuple(k.name for k in simpler))
            j = [s.name for s in stk.steps].index(c.name)
            stk.steps = [
                *stk.steps[:j],
                *(
                    dataclasses.replace(stk.steps[j], name=k.name, params=k.report(f_alt.physical))
                    for k in simpler
                ),
                *stk.steps[j + 1 :],
            ]
    return stk


def prune(run: Run, stk: Stack) -> Stack:
    """Backward elimination: while some stacked candidate's evidence given all the others
    (:meth:`Run.evidence` of the stack against the stack without it) is at most the threshold,
    the weakest is dropped. A candidate stacked early can lose its place to later ones that
    explain what it stood in for (a closed-loop spring under a 15 ms delay: the delay alone
    fitted b ≤ 0, b(x) and the spring were stacked as a pair, then the delay at 1139; b(x) was
    named at 1.00). A dropped candidate's joint step (``Stack.together``) passes its evidence to
    the step's next member. The candidates of a stand-in (``Stack.laws``) are one law and are
    kept: an asymmetric friction's offset is its asymmetry, weak alone (held-out asymmetric
    friction records lost their offset, and the verdict's confidence fell from 1.00 to 0.82)."""
    in_law = {n for law in stk.laws for n in law}
    while len(stk.cands) > 1:
        weakest = None
        for c in stk.cands:
            if c.name in in_law:
                continue
            rest = [k for k in stk.cands if k is not c]
            f = try_fit(run, rest)
            if f is None:
                continue
            sc = run.evidence(f, stk.fit, (c,), run.floor_of(stk.cands))
            if sc <= run.crit.threshold and (weakest is None or sc < weakest[0]):
                weakest = (sc, c, f)
        if weakest is None:
            break
        sc, c, f = weakest
        stk.cands = [k for k in stk.cands if k is not c]
        stk.fit = f
        stk.steps = [
            dataclasses.replace(s, reason=f"{s.reason}; {c.name} dropped ({sc:.3g} given the rest)")
            for s in stk.steps
            if s.name != c.name
        ]
        stk.stands_for.pop(c.name, None)
        if c.name in stk.together:  # the joint step's evidence passes to its next member
            score, names = stk.together.pop(c.name)
            left = tuple(n for n in names if n != c.name)
            if left:
                stk.together[left[0]] = (score, left)
    return stk


def check_candidates(candidates: Sequence[Any], reserved) -> tuple[AbstractCandidate, ...]:
    """The library as a tuple, or an :class:`~lionjax.InputError` naming what is wrong."""
    candidates = tuple(candidates)
    bad = [c for c in candidates if not isinstance(c, AbstractCandidate)]
    if bad:
        raise InputError(
            "diagnose: argument 'candidates' must hold lionjax.diagnosis candidates (instances "
            f"of AbstractCandidate, e.g. a ForceEffect subclass), got {bad[0]!r}."
        )
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(
            f"diagnose: argument 'candidates': the name(s) {dup} are used by more than one "
            f"candidate ({', '.join(type(c).__name__ for c in candidates if c.name in dup)}); "
            "give each candidate its own name (a candidate added twice: pass it once)."
        )
    try:
        check_library(candidates, reserved)
    except ValueError as e:
        raise InputError(f"diagnose: argument 'candidates': {e}") from None
    return candidates


def _common_range(x_train: np.ndarray, x_valid: np.ndarray) -> tuple[float, float]:
    """The positions both records cover; train's range where they do not overlap."""
    lo = max(float(np.min(x_train)), float(np.min(x_valid)))
    hi = min(float(np.max(x_train)), float(np.max(x_valid)))
    return (lo, hi) if hi > lo else (float(np.min(x_train)), float(np.max(x_train)))


def _outside(train: Record, valid: Record, v_train, v_valid) -> dict[str, float]:
    """Shares of the validation samples outside the training record's range: position x [m]
    and velocity v̂ [m/s] outside [min, max] of train, force with |F| above train's largest.

    A model fitted on train extrapolates there: an effect that acts only where train never went
    (a clip above its largest force, a position dependence beyond its positions) cannot be
    fitted on train, and its validation error is reported as ``unexplained``, with a confidence
    of at most 1 − the largest of these shares."""

    def share(tr, va, absolute=False):
        tr, va = np.asarray(tr, np.float64), np.asarray(va, np.float64)
        if absolute:
            return float(np.mean(np.abs(va) > np.max(np.abs(tr))))
        return float(np.mean((va < np.min(tr)) | (va > np.max(tr))))

    return {
        "position": share(train.x, valid.x),
        "velocity": share(v_train, v_valid),
        "force": share(train.F, valid.F, absolute=True),
    }
